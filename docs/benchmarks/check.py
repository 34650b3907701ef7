#!/usr/bin/env python3
"""Checks the benchmark pages.

1. Every Markdown link in BENCHMARKS.md, README.md, docs/*.md and docs/benchmarks/history/*.md
   that points into the repository resolves: the file exists and, for `file#anchor` or `#anchor`,
   the target has a heading with that GitHub anchor (or an explicit `<a id>`/`<a name>`).
2. The history logs hold the old BENCHMARKS.md word for word: the chunks marked
   `<!-- verbatim: BENCHMARKS.md <commit> lines A-B -->` put back in line order give the file at
   that commit, every line exactly once (needs the commit in the git history; skipped otherwise).

Usage: python3 docs/benchmarks/check.py [REPO_ROOT]. Exit status 1 on any failure.
"""

import re
import subprocess
import sys
from pathlib import Path

LINK = re.compile(r"(?<!!)\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
VERBATIM = re.compile(r"^<!-- verbatim: BENCHMARKS\.md (\w+) lines (\d+)-(\d+) -->$")


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"<[^>]+>", "", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set:
    """Every anchor a Markdown file defines (headings outside code fences, explicit ids)."""
    found, seen, fenced = set(), {}, False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
        if m:
            base = github_anchor(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
        for m in re.finditer(r"<a\s+(?:id|name)=\"([^\"]+)\"", line):
            found.add(m.group(1))
    return found


def links(path: Path):
    """(line number, target) of every link and image outside code fences and inline code."""
    fenced = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        line = re.sub(r"`[^`]*`", "", line)
        for pattern in (LINK, IMAGE):
            for m in pattern.finditer(line):
                yield number, m.group(1)


def check_links(root: Path, files) -> list:
    problems, checked = [], 0
    cache = {}
    for path in files:
        for number, target in links(path):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            checked += 1
            file_part, _, anchor = target.partition("#")
            dest = (path.parent / file_part).resolve() if file_part else path.resolve()
            where = f"{path.relative_to(root)}:{number}: {target}"
            if not dest.exists():
                problems.append(f"{where}: no such file")
                continue
            if anchor:
                if dest.is_dir() or dest.suffix != ".md":
                    problems.append(f"{where}: anchor into a non-Markdown target")
                    continue
                if dest not in cache:
                    cache[dest] = anchors(dest)
                if anchor not in cache[dest]:
                    problems.append(f"{where}: no anchor #{anchor} in {dest.relative_to(root)}")
    return checked, problems


def check_history(root: Path) -> list:
    history = sorted((root / "docs/benchmarks/history").glob("*.md"))
    chunks = {}  # commit -> {first line: lines}
    for path in history:
        lines = path.read_text(encoding="utf-8").split("\n")
        if lines and lines[-1] == "":
            lines = lines[:-1]  # the file's final newline
        starts = [i for i, l in enumerate(lines) if VERBATIM.match(l)]
        for k, i in enumerate(starts):
            commit, a, b = VERBATIM.match(lines[i]).groups()
            end = starts[k + 1] if k + 1 < len(starts) else len(lines)
            body = lines[i + 1 : end]
            a, b = int(a), int(b)
            if len(body) != b - a + 1:
                return [f"{path.name}: chunk {a}-{b} holds {len(body)} lines, not {b - a + 1}"]
            chunks.setdefault(commit, {})[a] = (b, body, path.name)
    problems = []
    for commit, parts in chunks.items():
        shown = subprocess.run(
            ["git", "show", f"{commit}:BENCHMARKS.md"], cwd=root, capture_output=True, text=True
        )
        if shown.returncode != 0:
            print(f"history: commit {commit} not in this clone, verbatim check skipped")
            continue
        original = shown.stdout.split("\n")
        if original and original[-1] == "":
            original = original[:-1]
        rebuilt, expected_next = [], 1
        for a in sorted(parts):
            b, body, name = parts[a]
            if a != expected_next:
                problems.append(f"history: lines {expected_next}-{a - 1} of {commit} missing or repeated (next chunk in {name})")
            rebuilt.extend(body)
            expected_next = b + 1
        if expected_next != len(original) + 1:
            problems.append(f"history: lines {expected_next}-{len(original)} of {commit} missing")
        if rebuilt != original:
            bad = next((i for i, (x, y) in enumerate(zip(rebuilt, original)) if x != y), None)
            problems.append(f"history: the chunks differ from BENCHMARKS.md at {commit} (first at line {bad + 1 if bad is not None else min(len(rebuilt), len(original)) + 1})")
        else:
            print(f"history: {len(parts)} chunks in {len(history)} files give BENCHMARKS.md at {commit} exactly ({len(original)} lines)")
    return problems


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[2]).resolve()
    files = [root / "BENCHMARKS.md", root / "README.md"]
    files += sorted((root / "docs").glob("*.md"))
    files += sorted((root / "docs/benchmarks/history").glob("*.md"))
    checked, problems = check_links(root, files)
    print(f"links: {checked} links in {len(files)} files checked")
    problems += check_history(root)
    for p in problems:
        print(f"FAIL {p}")
    print("ok" if not problems else f"{len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
