//! `docs/ipc.md` is the contract renderer authors read: its layout tables must match the structs
//! byte for byte (offset, size, type and field name, in order, the total size and the alignment),
//! and wherever it states a type's size and alignment in prose, so must that.

use hydrometra_ipc::control::{ControlRequest, ControlResponse};
use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::Status;
use iceoryx2::prelude::ZeroCopySend;
use std::mem::{align_of, offset_of, size_of};

mod docs_common;
use docs_common::{doc_layout, ipc_doc, stated_sizes_and_alignments, Row};

/// A contract type as the Rust code declares it: type name, size, alignment, fields.
struct Layout {
    type_name: String,
    size: usize,
    align: usize,
    rows: Vec<Row>,
}

fn size_of_return<T, F>(_: impl Fn(&T) -> &F) -> usize {
    size_of::<F>()
}

macro_rules! layout {
    ($t:ty { $($f:ident : $ty:literal),* $(,)? }) => {{
        let rows: Vec<Row> = vec![$(
            (
                stringify!($f).to_string(),
                offset_of!($t, $f),
                size_of_return(|s: &$t| &s.$f),
                $ty.to_string(),
            )
        ),*];
        // Every field listed once, in order, covering the struct without gaps.
        let mut end = 0;
        for (name, offset, size, _) in &rows {
            assert_eq!(*offset, end, "{}: field {name} does not follow the previous one", stringify!($t));
            end = offset + size;
        }
        assert_eq!(end, size_of::<$t>(), "{}: fields do not cover the struct", stringify!($t));
        Layout {
            // SAFETY: only reads the name; this test is what checks the layout it vouches for.
            type_name: unsafe { <$t as ZeroCopySend>::type_name() }.to_string(),
            size: size_of::<$t>(),
            align: align_of::<$t>(),
            rows,
        }
    }};
}

fn layouts() -> Vec<Layout> {
    vec![
        layout!(Status {
            schema_version: "u32",
            size_bytes: "u32",
            sequence: "u64",
            run_id: "u64",
            sim_time_s: "f64",
            publish_monotonic_ns: "u64",
            link_frames: "u64",
            link_crc_errors: "u64",
            link_malformed: "u64",
            link_sequence_gaps: "u64",
            link_resyncs: "u64",
            link_reconnects: "u64",
            link_clamped_values: "u64",
            link_device_faults: "u64",
            last_sample_age_s: "f64",
            rig_device_time_us: "u64",
            rig_valve_in_opening: "f64",
            rig_valve_out_opening: "f64",
            rig_pump_set_pressure_pa: "f64",
            valve_in_opening: "f64",
            valve_out_opening: "f64",
            pump_set_pressure_pa: "f64",
            scope_tip_position_m: "f64[3]",
            scope_view_direction: "f64[3]",
            scope_orientation_wxyz: "f64[4]",
            alarm_bits: "u64",
            tick_rate_hz: "f64",
            ticks: "u64",
            deadline_misses: "u64",
            tick_work_max_s: "f64",
            latency_p50_s: "f64",
            latency_p99_s: "f64",
            latency_max_s: "f64",
            latency_samples: "u64",
            statuses_dropped: "u64",
            link_state: "u32",
            rig_sequence: "u32",
            buttons: "u32",
            scope_pose_valid: "u32",
            safe_state: "u32",
            reserved0: "u32",
            cavity_pressure_pa: "f64",
            cavity_volume_m3: "f64",
            inflow_m3_per_s: "f64",
            outflow_m3_per_s: "f64",
            leak_m3_per_s: "f64",
            absorption_m3_per_s: "f64",
            perforation_m3_per_s: "f64",
            inflow_port_velocity_m_per_s: "f64",
            outflow_port_velocity_m_per_s: "f64",
            fluid_in_m3: "f64",
            fluid_collected_m3: "f64",
            deficit_m3: "f64",
            deficit_rate_m3_per_s: "f64",
            deficit_limit_m3: "f64",
            procedure_id: "u64",
            procedure_time_s: "f64",
            deficit_warning_stage: "u64",
            hydraulic_flags: "u64",
            link_down_reason: "u32",
            link_down_detail: "u32",
            scene_state: "u64",
            scene_frames: "u64",
            scene_stage_runs: "u64[7]",
            scene_stage_skips: "u64[7]",
            scene_stage_p99_s: "f64[7]",
            scene_step_p99_s: "f64",
            view_clarity: "f64",
            cavity_surface_volume_m3: "f64",
            inflow_port_open_fraction: "f64",
            realtime_mode: "u32",
            scene_degradation: "u32",
            scene_frames_late: "u64",
            scene_frames_skipped: "u64",
            status_gap_max_s: "f64",
        }),
        layout!(MeshTopologyHeader {
            schema_version: "u32",
            vertex_count: "u32",
            triangle_count: "u32",
            reserved0: "u32",
            topology_revision: "u64",
        }),
        layout!(MeshPositionsHeader {
            schema_version: "u32",
            vertex_count: "u32",
            status_sequence: "u64",
            sim_time_s: "f64",
            topology_revision: "u64",
            cavity_pressure_pa: "f64",
            scene_frame: "u64",
            frame_late_s: "f64",
        }),
        layout!(FlowFieldHeader {
            schema_version: "u32",
            reserved0: "u32",
            dims: "u32[3]",
            cell_count: "u32",
            origin_m: "f64[3]",
            spacing_m: "f64",
            status_sequence: "u64",
            sim_time_s: "f64",
            labels_offset_bytes: "u64",
            velocities_offset_bytes: "u64",
            total_bytes: "u64",
            scene_frame: "u64",
            frame_late_s: "f64",
            fractions_offset_bytes: "u64",
        }),
        layout!(Particle {
            position_m: "f32[3]",
            velocity_m_per_s: "f32[3]",
            kind: "u32",
            age_s: "f32",
        }),
        layout!(ParticlesHeader {
            schema_version: "u32",
            particle_count: "u32",
            status_sequence: "u64",
            sim_time_s: "f64",
            view_clarity: "f64",
            scene_frame: "u64",
            frame_late_s: "f64",
        }),
        layout!(ControlRequest {
            schema_version: "u32",
            command: "u32",
            argument_len: "u32",
            reserved0: "u32",
            argument: "u8[256]",
        }),
        layout!(ControlResponse {
            schema_version: "u32",
            command: "u32",
            result: "u32",
            recording: "u32",
            procedure_id: "u64",
            recorded_messages: "u64",
            recordings_finished: "u64",
            message_len: "u32",
            recording_path_len: "u32",
            message: "u8[256]",
            recording_path: "u8[256]",
        }),
    ]
}

#[test]
fn docs_layout_tables_match_the_structs() {
    let doc = ipc_doc();
    for Layout {
        type_name,
        size,
        align,
        rows,
    } in layouts()
    {
        if std::env::var_os("PRINT_LAYOUT").is_some() {
            // Helps when editing the docs: prints the table skeleton.
            println!("`{type_name}` ({size} B, align {align}):\n");
            println!("<!-- layout: {type_name} size={size} -->");
            for (n, o, s, t) in &rows {
                println!("| {o} | {s} | {t} | `{n}` |");
            }
            continue;
        }
        let (doc_size, doc_align, doc_rows) = doc_layout(&doc, &type_name);
        assert_eq!(doc_size, size, "{type_name}: size in docs/ipc.md");
        assert_eq!(doc_align, align, "{type_name}: alignment in docs/ipc.md");
        assert_eq!(doc_rows, rows, "{type_name}: layout table in docs/ipc.md");
    }
}

#[test]
fn docs_state_the_size_and_alignment_of_every_type_as_the_structs_have_them() {
    let doc = ipc_doc();
    for layout in layouts() {
        let (type_name, size, align) = (&layout.type_name, layout.size, layout.align);
        // The services table names every payload and user-header type with its size and
        // alignment: a renderer declares its struct from them (C's `alignas`).
        let stated = stated_sizes_and_alignments(&doc, type_name);
        assert!(
            !stated.is_empty(),
            "docs/ipc.md never states `{type_name}` (N B, align A)"
        );
        for (doc_size, doc_align) in stated {
            assert_eq!(doc_size, size, "{type_name}: size stated in docs/ipc.md");
            assert_eq!(
                doc_align, align,
                "{type_name}: alignment stated in docs/ipc.md"
            );
        }
    }
}

#[test]
fn a_wrong_size_or_alignment_in_the_prose_is_found() {
    // The check above must not pass by reading nothing.
    let doc = "| `hydrometra.v1.X` (dynamic, 32 B, align 4) | `hydrometra.v1.Y` (24 B, align 8) |";
    assert_eq!(
        stated_sizes_and_alignments(doc, "hydrometra.v1.X"),
        vec![(32, 4)]
    );
    assert_eq!(
        stated_sizes_and_alignments(doc, "hydrometra.v1.Y"),
        vec![(24, 8)]
    );
    assert!(stated_sizes_and_alignments(doc, "hydrometra.v1.Z").is_empty());
    let table = "`hydrometra.v1.Y` (24 B, align 8):\n\n<!-- layout: hydrometra.v1.Y size=24 -->\n";
    assert_eq!(doc_layout(table, "hydrometra.v1.Y").1, 8);
}

// ---------------------------------------------------------------------------------------------
// The other languages: every C++ and Python declaration of a contract type in the docs and the
// examples must have the Rust struct's fields, types, offsets and size, so a field appended under
// the v1 rule cannot leave an example behind. C++ is checked by parsing (the iceoryx2 C++
// bindings are not packaged on crates.io, PyPI or Debian, so CI cannot build the example); the
// layout is computed with the C rules (each field at the next multiple of its alignment, the size
// rounded up to the largest alignment).

/// A declaration found in a source: (where, language, struct name, fields as (name, type),
/// declared type name, sizes the code asserts).
struct Declaration {
    origin: String,
    language: &'static str,
    name: String,
    fields: Vec<(String, String)>,
    type_name: Option<String>,
    asserted_sizes: Vec<usize>,
    asserted_aligns: Vec<usize>,
}

/// (size, alignment) of a scalar type in the docs' notation.
fn scalar(ty: &str) -> (usize, usize) {
    match ty {
        "u8" | "i8" => (1, 1),
        "u16" | "i16" => (2, 2),
        "u32" | "i32" | "f32" => (4, 4),
        "u64" | "i64" | "f64" => (8, 8),
        other => panic!("unknown scalar type {other}"),
    }
}

/// Size, alignment and offsets of fields laid out with the C rules; types like `f64[3]`.
fn c_layout(fields: &[(String, String)]) -> (usize, usize, Vec<Row>) {
    let (mut end, mut max_align) = (0usize, 1usize);
    let mut rows = Vec::new();
    for (name, ty) in fields {
        let (elem, count) = match ty.split_once('[') {
            Some((e, n)) => (e, n.trim_end_matches(']').parse::<usize>().unwrap()),
            None => (ty.as_str(), 1),
        };
        let (size, align) = scalar(elem);
        let offset = end.div_ceil(align) * align;
        rows.push((name.clone(), offset, size * count, ty.clone()));
        end = offset + size * count;
        max_align = max_align.max(align);
    }
    (end.div_ceil(max_align) * max_align, max_align, rows)
}

fn cpp_type(t: &str, origin: &str) -> String {
    match t {
        "uint8_t" => "u8",
        "int8_t" => "i8",
        "uint16_t" => "u16",
        "int16_t" => "i16",
        "uint32_t" => "u32",
        "int32_t" => "i32",
        "uint64_t" => "u64",
        "int64_t" => "i64",
        "float" => "f32",
        "double" => "f64",
        other => panic!("{origin}: C++ type {other} has no fixed layout; use <cstdint> types"),
    }
    .to_string()
}

/// The integers that follow each occurrence of `before` in `code` (spaces skipped; occurrences
/// not followed by a number are ignored).
fn numbers_after(code: &str, before: &str) -> Vec<usize> {
    code.match_indices(before)
        .filter_map(|(i, m)| {
            let digits: String = code[i + m.len()..]
                .trim_start()
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            digits.parse().ok()
        })
        .collect()
}

/// Every `struct NAME { ... };` in C++ code.
fn cpp_declarations(code: &str, origin: &str) -> Vec<Declaration> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(start) = rest.find("struct ") {
        let after = &rest[start + "struct ".len()..];
        let name: String = after
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let Some(open) = after.find('{') else { break };
        let Some(close) = after.find("};") else { break };
        if after[..open].trim() != name || close < open {
            rest = after;
            continue;
        }
        let body = &after[open + 1..close];
        let (mut fields, mut type_name) = (Vec::new(), None);
        let body: String = body
            .lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        for stmt in body.split(';').map(str::trim).filter(|s| !s.is_empty()) {
            if stmt.starts_with("static") {
                // Static members take no space; the type name lives here.
                if stmt.contains("IOX2_TYPE_NAME") {
                    type_name = stmt.split('"').nth(1).map(str::to_string);
                }
                continue;
            }
            let (ty, names) = stmt
                .split_once(char::is_whitespace)
                .unwrap_or_else(|| panic!("{origin}: cannot read `{stmt}` in struct {name}"));
            let ty = cpp_type(ty.trim(), origin);
            for n in names.split(',').map(str::trim) {
                match n.split_once('[') {
                    Some((n, count)) => {
                        fields.push((n.trim().to_string(), format!("{ty}[{}", count.trim())))
                    }
                    None => fields.push((n.to_string(), ty.clone())),
                }
            }
        }
        let asserted_sizes = numbers_after(code, &format!("sizeof({name}) =="));
        let asserted_aligns = numbers_after(code, &format!("alignof({name}) =="));
        out.push(Declaration {
            origin: origin.to_string(),
            language: "C++",
            name,
            fields,
            type_name,
            asserted_sizes,
            asserted_aligns,
        });
        rest = &after[close..];
    }
    out
}

fn ctypes_type(t: &str, origin: &str) -> String {
    let (base, count) = match t.split_once('*') {
        Some((b, n)) => (b.trim(), Some(n.trim())),
        None => (t.trim(), None),
    };
    let base = match base.trim_start_matches("ctypes.") {
        "c_uint8" | "c_ubyte" => "u8",
        "c_int8" | "c_byte" => "i8",
        "c_uint16" => "u16",
        "c_int16" => "i16",
        "c_uint32" => "u32",
        "c_int32" => "i32",
        "c_uint64" => "u64",
        "c_int64" => "i64",
        "c_float" => "f32",
        "c_double" => "f64",
        other => panic!("{origin}: ctypes type {other} has no fixed layout"),
    };
    match count {
        Some(n) => format!("{base}[{n}]"),
        None => base.to_string(),
    }
}

/// Every `class NAME(ctypes.Structure)` with its `_fields_` in Python code.
fn python_declarations(code: &str, origin: &str) -> Vec<Declaration> {
    let mut out = Vec::new();
    for (start, _) in code.match_indices("class ") {
        let line = code[start..].lines().next().unwrap();
        if !line.contains("ctypes.Structure") {
            continue;
        }
        let name: String = line["class ".len()..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        // The class body: up to the next line that is not indented (or the end).
        let body_start = start + line.len();
        let mut body_len = 0;
        for (i, l) in code[body_start..].split_inclusive('\n').enumerate() {
            if i > 0 && !l.trim().is_empty() && !l.starts_with(char::is_whitespace) {
                break;
            }
            body_len += l.len();
        }
        let body = &code[body_start..body_start + body_len];
        let fields_at = body
            .find("_fields_")
            .unwrap_or_else(|| panic!("{origin}: class {name} has no _fields_"));
        let list = &body[fields_at..];
        let list = &list[list.find('[').unwrap() + 1..];
        let list = &list[..list
            .find("\n    ]")
            .unwrap_or_else(|| list.rfind(']').unwrap())];
        let fields = list
            .split("),")
            .map(|e| {
                e.trim()
                    .trim_start_matches('(')
                    .trim_end_matches(')')
                    .trim()
            })
            .filter(|e| !e.is_empty())
            .map(|e| {
                let (n, t) = e
                    .split_once(',')
                    .unwrap_or_else(|| panic!("{origin}: cannot read field `{e}` of {name}"));
                (
                    n.trim().trim_matches('"').trim_matches('\'').to_string(),
                    ctypes_type(t, origin),
                )
            })
            .collect();
        let type_name = body
            .find("def type_name")
            .and_then(|i| body[i..].find("return ").map(|j| i + j))
            .and_then(|i| body[i..].split('"').nth(1))
            .map(str::to_string);
        let mut asserted_sizes = numbers_after(code, &format!("ctypes.sizeof({name}) =="));
        // A docstring that states the size ("hydrometra.v1.Status: 123 bytes") must be right too.
        let stated = format!("{}: ", type_name.as_deref().unwrap_or(&name));
        asserted_sizes.extend(numbers_after(body, &stated));
        let asserted_aligns = numbers_after(code, &format!("ctypes.alignment({name}) =="));
        out.push(Declaration {
            origin: origin.to_string(),
            language: "Python",
            name,
            fields,
            type_name,
            asserted_sizes,
            asserted_aligns,
        });
    }
    out
}

/// Fenced code blocks (language, code) of a Markdown file.
fn fenced_blocks(doc: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut lines = doc.lines();
    while let Some(line) = lines.next() {
        if let Some(lang) = line.trim_start().strip_prefix("```") {
            let lang = lang.trim().to_lowercase();
            let code: Vec<&str> = lines
                .by_ref()
                .take_while(|l| !l.trim_start().starts_with("```"))
                .collect();
            out.push((lang, code.join("\n")));
        }
    }
    out
}

/// Every C++ and Python declaration in the docs (docs/*.md, README.md) and the examples
/// (ipc/examples/**).
fn foreign_declarations() -> Vec<Declaration> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut out = Vec::new();
    let mut markdown = vec![root.join("README.md")];
    for entry in std::fs::read_dir(root.join("docs")).expect("docs/") {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") {
            markdown.push(path);
        }
    }
    for path in markdown {
        let doc = std::fs::read_to_string(&path).unwrap();
        for (i, (lang, code)) in fenced_blocks(&doc).into_iter().enumerate() {
            let origin = format!("{} (code block {})", path.display(), i + 1);
            match lang.as_str() {
                "cpp" | "c++" | "c" | "h" | "hpp" => out.extend(cpp_declarations(&code, &origin)),
                "python" | "py" => out.extend(python_declarations(&code, &origin)),
                _ => {}
            }
        }
    }
    let mut dirs = vec![root.join("ipc/examples")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
                continue;
            }
            let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
            let origin = path.display().to_string();
            match ext {
                "cpp" | "cc" | "cxx" | "hpp" | "h" => out.extend(cpp_declarations(
                    &std::fs::read_to_string(&path).unwrap(),
                    &origin,
                )),
                "py" => out.extend(python_declarations(
                    &std::fs::read_to_string(&path).unwrap(),
                    &origin,
                )),
                _ => {}
            }
        }
    }
    out
}

#[test]
fn cpp_and_python_declarations_in_docs_and_examples_match_the_structs() {
    let layouts = layouts();
    let declarations = foreign_declarations();
    let mut checked = Vec::new();
    for d in &declarations {
        let Some(Layout {
            type_name,
            size,
            align,
            rows,
        }) = layouts
            .iter()
            .find(|l| l.type_name.rsplit('.').next() == Some(d.name.as_str()))
        else {
            continue; // Not a contract type (a helper struct of the example).
        };
        let what = format!("{} {} `{}` in {}", d.language, type_name, d.name, d.origin);
        let (c_size, c_align, c_rows) = c_layout(&d.fields);
        let names = |r: &[Row]| r.iter().map(|x| x.0.clone()).collect::<Vec<_>>();
        assert_eq!(names(&c_rows), names(rows), "{what}: field names and order");
        assert_eq!(&c_rows, rows, "{what}: field types and offsets");
        assert_eq!(c_size, *size, "{what}: size");
        assert_eq!(c_align, *align, "{what}: alignment");
        for asserted in &d.asserted_sizes {
            assert_eq!(
                asserted, size,
                "{what}: the size the code asserts or states"
            );
        }
        for asserted in &d.asserted_aligns {
            assert_eq!(asserted, align, "{what}: the alignment the code asserts");
        }
        if let Some(t) = &d.type_name {
            assert_eq!(t, type_name, "{what}: type name");
        }
        checked.push((d.language, d.name.clone(), d.origin.clone()));
    }
    // The test must not pass by finding nothing: the docs' C++ subscriber and the Python
    // example both declare Status.
    for language in ["C++", "Python"] {
        assert!(
            checked
                .iter()
                .any(|(l, n, _)| *l == language && n == "Status"),
            "no {language} declaration of Status found in docs/ or ipc/examples/; found {checked:?}"
        );
    }
}
