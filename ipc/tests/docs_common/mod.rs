//! Reading docs/ipc.md in the contract tests: its text, the layout tables and the sizes and
//! alignments it states.
#![allow(dead_code)]

/// (field, offset, size, type) of one field.
pub type Row = (String, usize, usize, String);

/// Parses the table that follows `<!-- layout: NAME size=N -->` in docs/ipc.md and the caption
/// that heads it, `` `NAME` (N B, align A): ``: (size, alignment, rows). The marker keeps its
/// plain form: `record/examples/python/read_recording.py` reads the Status table by it.
pub fn doc_layout(doc: &str, type_name: &str) -> (usize, usize, Vec<Row>) {
    let marker = format!("<!-- layout: {type_name} size=");
    let start = doc
        .find(&marker)
        .unwrap_or_else(|| panic!("docs/ipc.md has no layout table for {type_name}"));
    let rest = &doc[start + marker.len()..];
    let size: usize = rest[..rest.find(" -->").unwrap()].parse().unwrap();
    // The caption: the last non-blank line before the marker, visible where the marker is not.
    let caption = doc[..start]
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("");
    let (caption_size, align) = stated_sizes_and_alignments(caption, type_name)
        .first()
        .copied()
        .unwrap_or_else(|| {
            panic!(
                "docs/ipc.md: the layout table of {type_name} is not headed by \
                 `{type_name}` (N B, align A):, found `{caption}`"
            )
        });
    assert_eq!(
        caption_size, size,
        "docs/ipc.md: {type_name}: the caption's size and the marker's differ"
    );
    let rows = rest
        .lines()
        .skip(1)
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|l| {
            let cells: Vec<&str> = l.trim_matches('|').split('|').map(str::trim).collect();
            let name = cells[3].trim_matches('`').to_string();
            (
                name,
                cells[0].parse().unwrap(),
                cells[1].parse().unwrap(),
                cells[2].to_string(),
            )
        })
        .collect();
    (size, align, rows)
}

/// The contract's text.
pub fn ipc_doc() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/ipc.md");
    std::fs::read_to_string(path).expect("docs/ipc.md")
}

/// Every `(..., N B, align A)` that follows `` `type_name` `` in `doc`: (N, A) as written.
pub fn stated_sizes_and_alignments(doc: &str, type_name: &str) -> Vec<(usize, usize)> {
    let quoted = format!("`{type_name}` (");
    doc.match_indices(&quoted)
        .filter_map(|(i, m)| {
            let inside = &doc[i + m.len()..];
            let inside = &inside[..inside.find(')')?];
            let mut size = None;
            let mut align = None;
            for part in inside.split(',').map(str::trim) {
                if let Some(n) = part.strip_suffix(" B") {
                    size = n.parse().ok();
                } else if let Some(n) = part.strip_prefix("align ") {
                    align = n.parse().ok();
                }
            }
            match (size, align) {
                (Some(s), Some(a)) => Some((s, a)),
                (None, None) => None, // a parenthesis that states neither
                _ => panic!("docs/ipc.md: `{type_name} ({inside})` states size or alignment alone"),
            }
        })
        .collect()
}
