#!/usr/bin/env python3
"""Fails when two source files of one crate import each other, directly or through a chain.

For every crate root of the workspace (src/lib.rs, src/main.rs, src/bin/*.rs) it builds the module
tree from the `mod name;` lines, then reads every `use` line and every path inside the code: those
that start with `crate::`, `super::` or `self::`, and the bare ones (`particles::Particles`,
`Stage::Fluid`) whose first segment is a child module or a name the module imports. Each resolves
to the file that defines the item (following `use` re-exports, so `super::FluidParams` counts as a
dependency on the file that defines `FluidParams`, not on the `mod.rs` that re-exports it). A file
depends on another when one of its paths resolves there: a child file that names `super::Scene`
and a parent that names `particles::Particles` import each other.

Not counted as dependencies: `mod` declarations and `pub use` re-exports (they shape the module
tree, they do not use anything), comments, string literals, and paths into other crates.
Known limits: `#[path]` attributes and macro-generated paths are not followed; a lone name (a type
or function used without `::`, through a `use` of its parent's re-export) is not followed; a path
naming an item through a private `use` binding of the module is followed like a re-export.

Usage: .ci/module_cycles.py [workspace_dir]   (exit status 1 and a report on any cycle)
"""

import re
import sys
from pathlib import Path

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


def strip_comments_and_strings(src):
    """Blanks comments, string and char literals, keeping offsets and newlines."""
    out = []
    i, n = 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif src.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', src[i:i + 260]) and (i == 0 or not re.match(r"\w", src[i - 1])):
            m = re.match(r'r(#*)"', src[i:])
            end = src.find('"' + m.group(1), i + len(m.group(0)))
            j = n if end < 0 else end + 1 + len(m.group(1))
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            j += 1
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == "'":
            # A char literal ('a', '\n', '\u{..}') or a lifetime ('a): blank only literals.
            m = re.match(r"'(\\.[^']*|[^'\\])'", src[i:i + 12])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def expand_use_tree(tree):
    """`a::{b, c::{d as e, self}}` -> [(['a','b'], 'b'), (['a','c','d'], 'e'), (['a','c'], 'c')]."""
    tree = re.sub(r"\s+", "", tree)
    results = []

    def split_top(s):
        parts, depth, cur = [], 0, ""
        for ch in s:
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            if ch == "," and depth == 0:
                parts.append(cur)
                cur = ""
            else:
                cur += ch
        if cur:
            parts.append(cur)
        return parts

    def walk(prefix, s):
        s = s.strip(":")
        if not s:
            return
        brace = s.find("{")
        if brace >= 0 and s.endswith("}"):
            head = [p for p in s[:brace].split("::") if p]
            for part in split_top(s[brace + 1:-1]):
                walk(prefix + head, part)
            return
        segs = [p for p in s.split("::") if p]
        if segs and segs[-1] == "self":
            segs = segs[:-1]
        full = prefix + segs
        if full:
            results.append((full, full[-1]))

    walk([], tree)
    return results


def parse_use_trees(text):
    """Yields (start_offset, is_pub, [(path_segments, bound_name)]) for every `use` item."""
    for m in re.finditer(r"(?<![\w:])(pub(?:\s*\([^)]*\))?\s+)?use\s+([^;]+);", text):
        tree = m.group(2)
        # Remove `as alias` (keeping the alias as the binding name) while whitespace still exists.
        aliases = {}

        def repl(mm):
            key = f"__alias{len(aliases)}__"
            aliases[key] = mm.group(2)
            return mm.group(1) + key

        tree2 = re.sub(r"(" + IDENT + r")\s+as\s+(" + IDENT + r"|_)", repl, tree)
        entries = []
        for segs, name in expand_use_tree(tree2):
            last = segs[-1]
            am = re.match(r"(" + IDENT + r")(__alias\d+__)$", last)
            if am:
                segs = segs[:-1] + [am.group(1)]
                name = aliases[am.group(2)]
            entries.append((segs, name))
        yield m.start(), bool(m.group(1)), entries


class Module:
    def __init__(self, path, file, parent):
        self.path = path  # tuple of names from the crate root
        self.file = file
        self.parent = parent
        self.children = {}
        self.bindings = {}  # name -> (path segments, context Module)
        self.uses = []  # (segments, is_pub, line)
        self.inline_paths = []  # (segments, line)


def line_of(text, offset):
    return text.count("\n", 0, offset) + 1


class Crate:
    def __init__(self, name, root):
        self.name = name
        self.root = root
        self.modules = {}
        self.errors = []
        self.load(root, (), None, is_mod_rs=True)

    def load(self, file, path, parent, is_mod_rs):
        src = file.read_text(encoding="utf-8")
        text = strip_comments_and_strings(src)
        root_mod = Module(path, file, parent)
        self.modules[path] = root_mod
        if parent is not None:
            parent.children[path[-1]] = root_mod
        child_dir = file.parent if is_mod_rs else file.parent / file.stem

        # Inline module ranges: (start, end, name) at brace depth.
        spans = []  # (start, end, Module)
        stack = [(None, root_mod)]
        depth = 0
        mod_at = {}
        for m in re.finditer(r"\bmod\s+(" + IDENT + r")\s*([;{])", text):
            mod_at[m.end() - 1] = (m.group(1), m.group(2), m.start())
        i = 0
        events = []  # offset -> current module
        cur_mods = [(root_mod, -1)]  # (module, depth at which it opened)
        offsets_modules = []
        while i < len(text):
            ch = text[i]
            if i in mod_at:
                name, kind, start = mod_at[i]
                owner = cur_mods[-1][0]
                if kind == ";":
                    if owner is root_mod:
                        sub = child_dir / (name + ".rs")
                        subdir = child_dir / name / "mod.rs"
                        if sub.exists():
                            self.load(sub, path + (name,), root_mod, is_mod_rs=False)
                        elif subdir.exists():
                            self.load(subdir, path + (name,), root_mod, is_mod_rs=True)
                        else:
                            self.errors.append(f"{file}: mod {name}; has no file")
                else:
                    inner = Module(owner.path + (name,), file, owner)
                    owner.children[name] = inner
                    self.modules[inner.path] = inner
                    depth += 1
                    cur_mods.append((inner, depth))
                    offsets_modules.append((i, inner))
                    i += 1
                    continue
            if ch == "{":
                depth += 1
            elif ch == "}":
                if cur_mods[-1][1] == depth and len(cur_mods) > 1:
                    cur_mods.pop()
                    offsets_modules.append((i, cur_mods[-1][0]))
                depth -= 1
            i += 1

        def module_at(offset):
            cur = root_mod
            for off, mod in offsets_modules:
                if off > offset:
                    break
                cur = mod
            return cur

        use_spans = []
        for start, is_pub, entries in parse_use_trees(text):
            mod = module_at(start)
            line = line_of(text, start)
            end = text.find(";", start)
            use_spans.append((start, end))
            for segs, name in entries:
                if segs[-1] != "*" and name != "_":
                    mod.bindings[name] = (segs, mod)
                mod.uses.append((segs, is_pub, line))
        # Paths in code: `crate::`, `super::`, `self::` ones, and bare `a::b` ones (resolved only
        # when `a` is a child module or an imported name; a field or method access `.a::` and a
        # path's tail `x::a::b` are not paths of their own).
        for m in re.finditer(r"(?<![\w:.])(" + IDENT + r"(?:\s*::\s*" + IDENT + r")+)", text):
            if any(s <= m.start() <= e for s, e in use_spans):
                continue
            segs = [seg.strip() for seg in m.group(1).split("::")]
            if segs[0] in ("Self", "std", "core", "alloc"):
                continue
            mod = module_at(m.start())
            mod.inline_paths.append((segs, line_of(text, m.start())))

    def resolve(self, segs, ctx, depth=0):
        """The file that defines what `segs` names from module `ctx`, or None (another crate)."""
        if depth > 16 or not segs:
            return None
        cur = ctx
        i = 0
        if segs[0] == "crate":
            cur, i = self.modules[()], 1
        elif segs[0] in ("self", "super"):
            while i < len(segs) and segs[i] in ("self", "super"):
                if segs[i] == "super":
                    if cur.parent is None:
                        return None
                    cur = cur.parent
                i += 1
        elif segs[0] in cur.children:
            pass
        elif segs[0] in cur.bindings and depth == 0:
            bsegs, bctx = cur.bindings[segs[0]]
            if bsegs != segs[:1]:
                return self.resolve(bsegs + segs[1:], bctx, depth + 1)
            return None
        else:
            return None
        while i < len(segs):
            s = segs[i]
            if s == "*":
                return cur.file
            if s in cur.children:
                cur = cur.children[s]
                i += 1
                continue
            if s in cur.bindings:
                bsegs, bctx = cur.bindings[s]
                target = self.resolve(bsegs + segs[i + 1:], bctx, depth + 1)
                return target if target is not None else cur.file
            return cur.file
        return cur.file

    def edges(self):
        """{(from_file, to_file): [line, ...]}"""
        out = {}
        for mod in self.modules.values():
            refs = [(segs, line) for segs, is_pub, line in mod.uses if not is_pub]
            refs += mod.inline_paths
            for segs, line in refs:
                target = self.resolve(segs, mod)
                if target is not None and target != mod.file:
                    out.setdefault((mod.file, target), []).append(line)
        return out


def strongly_connected(nodes, edges):
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]
    adj = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in adj.get(v, []):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in nodes:
        if v not in index:
            visit(v)
    return out


def crate_roots(ws):
    cargo = (ws / "Cargo.toml").read_text()
    m = re.search(r"members\s*=\s*\[([^\]]*)\]", cargo)
    members = re.findall(r'"([^"]+)"', m.group(1)) if m else ["."]
    for member in members:
        src = ws / member / "src"
        for root in [src / "lib.rs", src / "main.rs"] + sorted((src / "bin").glob("*.rs")):
            if root.exists():
                yield f"{member}:{root.relative_to(ws / member)}", root


def self_test():
    """The checker on scratch workspaces: a re-export and a test-module `super::*` are no cycle, a
    `use` each way (directly or via a re-export) is, and so is a child file naming `super::Scene`
    in code while its parent names the child's items by a bare path (`particles::step`) or by
    `self::`/`crate::` paths, with no `use` line either way."""
    import tempfile

    def cycles_of(files):
        with tempfile.TemporaryDirectory() as d:
            root = Path(d)
            for name, text in files.items():
                (root / name).parent.mkdir(parents=True, exist_ok=True)
                (root / name).write_text(text)
            crate = Crate("a", root / "a/src/lib.rs")
            nodes = sorted(m.file for m in crate.modules.values())
            found = [c for c in strongly_connected(nodes, crate.edges()) if len(c) > 1]
            return [sorted(f.relative_to(root / "a/src").as_posix() for f in c) for c in found]

    base = {
        "Cargo.toml": '[workspace]\nmembers = ["a"]\n',
        "a/src/lib.rs": "pub mod m;\npub mod n;\npub use m::Thing;\n",
        "a/src/m.rs": "use crate::n::helper;\npub struct Thing;\n#[cfg(test)]\nmod tests { use super::*; }\n",
        "a/src/n.rs": "// use super::m::Thing; (a comment is no import)\npub fn helper() {}\n",
    }
    assert not cycles_of(base), f"false cycle {cycles_of(base)}"
    # n now names Thing through the crate root's re-export: m <-> n.
    found = cycles_of({**base, "a/src/n.rs": "pub fn helper() -> crate::Thing { crate::Thing }\n"})
    assert found == [["m.rs", "n.rs"]], f"missed cycle: {found}"

    # The scene's old shape: a stage file takes `super::Scene` (in code, no `use`), the scene calls
    # the stage by a bare path.
    scene = {
        "Cargo.toml": '[workspace]\nmembers = ["a"]\n',
        "a/src/lib.rs": "pub mod scene;\n",
        "a/src/scene/mod.rs": "mod particles;\nmod types;\npub use types::Kind;\n"
        "pub struct Scene { pub kinds: Vec<Kind> }\n"
        "impl Scene { pub fn step(&self) { particles::step(self); } }\n",
        "a/src/scene/types.rs": "#[derive(Clone, Copy)]\npub enum Kind { Fluid }\n",
        "a/src/scene/particles.rs": "pub fn step(scene: &super::Scene) -> usize { scene.kinds.len() }\n",
    }
    found = cycles_of(scene)
    assert found == [["scene/mod.rs", "scene/particles.rs"]], f"missed the super:: cycle: {found}"
    # The same through `self::` and `crate::` paths in code.
    found = cycles_of({**scene, "a/src/scene/mod.rs": scene["a/src/scene/mod.rs"].replace(
        "particles::step(self)", "self::particles::step(self)")})
    assert found == [["scene/mod.rs", "scene/particles.rs"]], f"missed the self:: cycle: {found}"
    found = cycles_of({**scene, "a/src/scene/particles.rs":
                       "pub fn step(scene: &crate::scene::Scene) -> usize { scene.kinds.len() }\n"})
    assert found == [["scene/mod.rs", "scene/particles.rs"]], f"missed the crate:: cycle: {found}"
    # Fixed as the scene is now: the stage takes the shared record from the leaf (through the
    # parent's re-export: `super::Kind` resolves to types.rs), never the scene.
    fixed = {**scene, "a/src/scene/particles.rs": "pub fn step(kinds: &[super::Kind]) -> usize { kinds.len() }\n",
             "a/src/scene/mod.rs": scene["a/src/scene/mod.rs"].replace("particles::step(self)",
                                                                     "particles::step(&self.kinds)")}
    assert not cycles_of(fixed), f"false cycle {cycles_of(fixed)}"
    # A field or method named like a child module is no path: `self.particles.step()`.
    method = {**scene, "a/src/scene/mod.rs": scene["a/src/scene/mod.rs"].replace(
        "particles::step(self);", "let _ = self.kinds.len();")}
    assert not cycles_of(method), f"false cycle {cycles_of(method)}"
    print("module-cycles: self-test passed")


def main():
    if sys.argv[1:] == ["--self-test"]:
        self_test()
        return 0
    ws = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    failed = False
    checked = 0
    for name, root in crate_roots(ws):
        crate = Crate(name, root)
        for e in crate.errors:
            print(f"module-cycles: {name}: {e}")
        edges = crate.edges()
        files = {m.file for m in crate.modules.values()}
        checked += len(files)
        for comp in strongly_connected(sorted(files), edges.keys()):
            if len(comp) < 2:
                continue
            failed = True
            members = set(comp)
            print(f"module-cycles: {name}: files that import each other:")
            for (a, b), lines in sorted(edges.items()):
                if a in members and b in members:
                    where = ", ".join(str(x) for x in sorted(set(lines)))
                    print(f"  {a.relative_to(ws)} -> {b.relative_to(ws)} (lines {where})")
    if failed:
        print("module-cycles: make each dependency run one way (move the shared item to the file both use)")
        return 1
    print(f"module-cycles: no import cycle among {checked} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
