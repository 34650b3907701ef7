//! A subscriber written from docs/ipc.md alone decodes the flow payload the daemon writes: the
//! header fields are read at the offsets of the docs' layout table, each section where the docs'
//! section table says (its offset field, element type and count field), the fractions by the
//! docs' unit (1/255) and presence rule. The payload is made by the daemon's own writer
//! (`FlowLayout::write_offsets`, `FlowLayout::byte`, `fraction_to_u8`).

use hydrometra_ipc::field::{fraction_to_u8, FlowFieldHeader, FlowLayout};

mod docs_common;
use docs_common::{doc_layout, ipc_doc, Row};

const TYPE_NAME: &str = "hydrometra.v1.FlowFieldHeader";

/// One row of the docs' section table: (section, offset field, element type, count field, unit).
type Section = (String, String, String, String, String);

fn doc_sections(doc: &str) -> Vec<Section> {
    let marker = format!("<!-- payload: {TYPE_NAME} -->");
    let start = doc
        .find(&marker)
        .unwrap_or_else(|| panic!("docs/ipc.md has no section table `{marker}`"));
    doc[start + marker.len()..]
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|l| {
            let c: Vec<String> = l
                .trim_matches('|')
                .split('|')
                .map(|x| x.trim().trim_matches('`').to_string())
                .collect();
            (
                c[0].clone(),
                c[1].clone(),
                c[2].clone(),
                c[3].clone(),
                c[4].clone(),
            )
        })
        .collect()
}

/// The bytes of a header as the daemon hands it over.
fn header_bytes(h: &FlowFieldHeader) -> Vec<u8> {
    // SAFETY: FlowFieldHeader is repr(C) plain data without padding (the layout test checks that
    // its fields cover it); reading its bytes is what shared memory hands a subscriber.
    unsafe {
        std::slice::from_raw_parts(
            (h as *const FlowFieldHeader).cast::<u8>(),
            size_of::<FlowFieldHeader>(),
        )
    }
    .to_vec()
}

/// A header field by the docs' table: an unsigned integer of its size at its offset.
fn field(rows: &[Row], header: &[u8], name: &str) -> u64 {
    let (_, offset, size, ty) = rows
        .iter()
        .find(|r| r.0 == name)
        .unwrap_or_else(|| panic!("docs/ipc.md: no header field {name}"));
    let b = &header[*offset..offset + size];
    match ty.as_str() {
        "u32" => u32::from_le_bytes(b.try_into().unwrap()) as u64,
        "u64" => u64::from_le_bytes(b.try_into().unwrap()),
        other => panic!("{name}: an offset or count field of type {other}"),
    }
}

/// "1/255" -> 1/255; "m/s" and the like (no number) -> None.
fn scale(unit: &str) -> Option<f64> {
    let (a, b) = unit.split_once('/')?;
    Some(a.parse::<f64>().ok()? / b.parse::<f64>().ok()?)
}

/// What the docs-only subscriber decodes: per section, its values as f64 (a `f32[3]` section
/// gives three per cell); `None` for a section the docs' presence rule says is absent.
fn decode(doc: &str, header: &[u8], payload: &[u8]) -> Vec<(String, Option<Vec<f64>>)> {
    let (_, _, rows) = doc_layout(doc, TYPE_NAME);
    let total = field(&rows, header, "total_bytes") as usize;
    assert_eq!(payload.len(), total, "total_bytes is the payload length");
    doc_sections(doc)
        .into_iter()
        .map(|(name, offset_field, element, count_field, unit)| {
            let at = field(&rows, header, &offset_field) as usize;
            let count = field(&rows, header, &count_field) as usize;
            let (bytes, per_cell) = match element.as_str() {
                "u8" => (1, 1),
                "f32[3]" => (4, 3),
                other => panic!("section {name}: element {other}"),
            };
            let end = at + bytes * per_cell * count;
            // The presence rule of "Presence of the fractions": offset 0 is no section (only the
            // labels, the first section, live at 0).
            if (at == 0 && name != "labels") || end > total {
                return (name, None);
            }
            let values = payload[at..end]
                .chunks_exact(bytes)
                .map(|b| match bytes {
                    1 => b[0] as f64 * scale(&unit).unwrap_or(1.0),
                    _ => f32::from_le_bytes(b.try_into().unwrap()) as f64,
                })
                .collect();
            (name, Some(values))
        })
        .collect()
}

#[test]
fn a_subscriber_written_from_the_docs_decodes_labels_velocities_and_fractions() {
    let doc = ipc_doc();
    // A grid whose cell count is not a multiple of 4 (padding before the velocities).
    let dims = [7usize, 5, 3];
    let cells = dims.iter().product::<usize>();
    let label = |c: usize| (c % 7) as u8;
    let velocity = |c: usize| [c as f32 * 0.25, -(c as f32), 1.0 / (1 + c) as f32];
    // Fractions as a scene has them: empty, full, cut, a merge target above 1, rounding below 0.
    let fraction = |c: usize| match c % 6 {
        0 => 0.0,
        1 => 1.0,
        2 => c as f64 / cells as f64,
        3 => 1.0 + 0.3 * (c as f64 / cells as f64),
        4 => -1e-13,
        _ => 0.5,
    };
    let layout = FlowLayout::new(cells);
    let mut header = FlowFieldHeader {
        schema_version: 1,
        dims: dims.map(|d| d as u32),
        spacing_m: 1.2e-3,
        ..FlowFieldHeader::default()
    };
    layout.write_offsets(&mut header);
    let mut payload = Vec::new();
    layout.fill(&mut payload, label, velocity, |c| {
        fraction_to_u8(fraction(c))
    });
    let decoded = decode(&doc, &header_bytes(&header), &payload);
    let names: Vec<&str> = decoded.iter().map(|d| d.0.as_str()).collect();
    assert_eq!(names, ["labels", "velocities", "fractions"]);
    let section = |name: &str| {
        decoded
            .iter()
            .find(|d| d.0 == name)
            .and_then(|d| d.1.clone())
            .unwrap_or_else(|| panic!("{name} absent"))
    };
    let (labels, velocities, fractions) = (
        section("labels"),
        section("velocities"),
        section("fractions"),
    );
    for c in 0..cells {
        assert_eq!(labels[c], label(c) as f64, "label of cell {c}");
        let v = velocity(c).map(f64::from);
        assert_eq!(&velocities[3 * c..3 * c + 3], &v, "velocity of cell {c}");
        let want = fraction(c).clamp(0.0, 1.0);
        assert!(
            (fractions[c] - want).abs() <= 0.5 / 255.0 + 1e-12,
            "fraction of cell {c}: decoded {} for {want}",
            fractions[c]
        );
    }
    // Full and empty cells are exact, so a whole-cell field's volume is exact too.
    assert_eq!((fractions[0], fractions[1]), (0.0, 1.0));

    // A payload without fractions (offset 0): the docs' rule finds none.
    header.fractions_offset_bytes = 0;
    let decoded = decode(&doc, &header_bytes(&header), &payload);
    assert!(decoded.iter().any(|d| d.0 == "fractions" && d.1.is_none()));
    assert!(decoded.iter().any(|d| d.0 == "labels" && d.1.is_some()));
}
