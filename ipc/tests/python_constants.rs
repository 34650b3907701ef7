//! The Python examples cannot import the Rust constant; each declares `PA_PER_MMHG` once, and this
//! keeps the declarations equal to `hydrometra_units::PA_PER_MMHG` (one value for the whole project).

use std::path::Path;

#[test]
fn python_examples_declare_the_units_pa_per_mmhg() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for file in [
        "ipc/examples/python/status_subscriber.py",
        "record/examples/python/read_recording.py",
    ] {
        let text = std::fs::read_to_string(root.join(file)).expect(file);
        let value: f64 = text
            .lines()
            .find_map(|l| l.strip_prefix("PA_PER_MMHG = "))
            .and_then(|rest| rest.split_whitespace().next())
            .unwrap_or_else(|| panic!("{file}: no `PA_PER_MMHG = <value>` line"))
            .parse()
            .unwrap_or_else(|e| panic!("{file}: PA_PER_MMHG: {e}"));
        assert_eq!(value, hydrometra_units::PA_PER_MMHG, "{file}");
    }
}
