//! docs/ipc.md's "Alarm bits" table is what renderer authors read: every bit of
//! `hydrometra_ipc::alarms::ALL` is in it with its name, nothing else is, and the reserved ranges
//! cover exactly the remaining bits.

use hydrometra_ipc::alarms;

/// (bits, name) of each row of the table; a reserved range has the name "-".
fn doc_rows() -> Vec<(std::ops::RangeInclusive<u32>, String)> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/ipc.md");
    let doc = std::fs::read_to_string(path).expect("docs/ipc.md");
    let section = doc
        .split("### Alarm bits")
        .nth(1)
        .expect("docs/ipc.md has an \"Alarm bits\" section");
    section
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let (bits, name) = (cells[1], cells[2].trim_matches('`'));
            let range = match bits.split_once('-') {
                Some((a, b)) => a.parse().expect("bit")..=b.parse().expect("bit"),
                None => {
                    let bit: u32 = bits.parse().expect("bit");
                    bit..=bit
                }
            };
            (range, name.to_string())
        })
        .collect()
}

#[test]
fn the_alarm_table_in_the_docs_lists_every_bit_with_its_name() {
    let rows = doc_rows();
    let mut covered = 0u64;
    for (range, name) in &rows {
        for bit in range.clone() {
            assert_eq!(
                covered & (1 << bit),
                0,
                "bit {bit} appears twice in the table"
            );
            covered |= 1 << bit;
            let defined = alarms::ALL.iter().find(|(b, _)| *b == 1 << bit);
            match defined {
                Some((_, code_name)) => assert_eq!(
                    name, code_name,
                    "bit {bit}: the docs say `{name}`, the code `{code_name}`"
                ),
                None => assert_eq!(
                    name, "-",
                    "bit {bit}: `{name}` in the docs, not in the code"
                ),
            }
        }
    }
    assert_eq!(covered, u64::MAX, "the table covers bits 0-63");
}
