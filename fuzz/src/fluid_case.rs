//! The fluid case TOML reader (`fluid::case::Case::parse`, what `hydrometra fluid run --case`
//! runs).
//!
//! Properties: an error starts with `case file:` and says where (a TOML line, a back-quoted key
//! or the `key = value` it rejects); an accepted case yields valid solver parameters and a grid:
//! one of at most 64k cells is built with every cell labelled, and one past the grid's own limit
//! is refused without allocating it.

use hydrometra_sim::fluid::case::{Case, CaseError};

/// Largest grid the target builds, cells.
const BUILD_CELLS: usize = 1 << 16;

/// The fluid case target.
pub fn check(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Case::parse(text) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with("case file: "), "{msg}");
            let located = match &e {
                CaseError::Parse(_) => crate::position::names_a_line(&msg),
                CaseError::Invalid { key, .. } => msg.contains(&format!("`{key}` = ")),
                CaseError::Solver(_) => msg.contains('`') || msg.contains(" = "),
            };
            assert!(located, "error does not say where: {msg}");
        }
        Ok(case) => {
            let params = case
                .params()
                .unwrap_or_else(|e| panic!("accepted case has bad parameters: {e}"));
            assert!(params.density_kg_m3 > 0.0 && params.density_kg_m3.is_finite());
            let cells = case.grid.cells;
            let count = cells[0]
                .checked_mul(cells[1])
                .and_then(|n| n.checked_mul(cells[2]));
            match count {
                Some(n) if n <= BUILD_CELLS => {
                    let grid = case
                        .build_grid()
                        .unwrap_or_else(|e| panic!("grid of {n} cells refused: {e}"));
                    assert_eq!(grid.dims(), cells);
                    assert_eq!(grid.labels().len(), n);
                }
                Some(n) if n < u32::MAX as usize / 4 => {} // legal but too big to build here
                _ => {
                    let e = case
                        .build_grid()
                        .err()
                        .unwrap_or_else(|| panic!("grid of {cells:?} cells accepted"));
                    assert!(e.to_string().contains("cells"), "{e}");
                }
            }
        }
    }
}
