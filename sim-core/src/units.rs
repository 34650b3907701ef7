//! Conversions between SI units (used inside) and clinical units (used at the edges): the
//! workspace's one copy lives in `hydrometra-units`, re-exported here.

pub use hydrometra_units::*;

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// Every `.rs` file under `dir`.
    fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir)
            .expect("a readable source tree")
            .flatten()
        {
            let path = entry.path();
            if path.is_dir() {
                sources(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }

    /// The Pa/mmHg factor exists once, in `hydrometra-units`: no source file of this crate spells
    /// it out (they convert with [`super::mmhg_to_pa`] and [`super::pa_to_mmhg`]), and the
    /// conversions here are that crate's.
    #[test]
    fn the_mmhg_factor_is_written_once_in_the_units_crate() {
        assert_eq!(super::mmhg_to_pa(1.0), hydrometra_units::PA_PER_MMHG);
        assert_eq!(super::pa_to_mmhg(super::PA_PER_MMHG), 1.0);
        // The literal, built so that this file does not contain it.
        let literal = ["133", "322"].join(".");
        let mut files = Vec::new();
        for dir in ["src", "tests", "benches", "examples"] {
            let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
            if dir.is_dir() {
                sources(&dir, &mut files);
            }
        }
        assert!(files.len() > 50, "only {} source files found", files.len());
        let copies: Vec<_> = files
            .iter()
            .filter(|f| {
                std::fs::read_to_string(f)
                    .expect("a readable source file")
                    .replace('_', "")
                    .contains(&literal)
            })
            .collect();
        assert!(
            copies.is_empty(),
            "the Pa/mmHg factor spelled out in {copies:?}"
        );
    }
}
