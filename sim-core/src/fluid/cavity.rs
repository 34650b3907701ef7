//! A voxelized ellipsoidal cavity with a scope: the stand-in benchmark geometry until the voxelizer
//! exists.
//!
//! The cavity is the ellipsoid with semi-axes [`CAVITY_SEMI_AXES_M`] centred at the origin (long axis
//! x, from the cervix at -x to the fundus at +x). A scope of radius [`SCOPE_RADIUS_M`] enters along the
//! x axis from the cervix; its tip (the last cell layer) is a `Velocity` port jetting along +x, the rest
//! of the scope is solid. Fluid leaves through `Outflow` cells around the scope near the cervix (cells of
//! the cavity within 3 mm of its -x end and more than 2.5 mm off-axis). Everything outside is solid.

use super::{CellLabel, FluidError, FluidGrid};

/// Semi-axes (m) of the benchmark cavity: 18 x 12 x 8.4 mm (volume 7.6 ml), chosen so the fluid-cell
/// counts at 0.6 and 1.2 mm voxels land near the paper's Table 1 (35179 and 3813).
pub const CAVITY_SEMI_AXES_M: [f64; 3] = [0.018, 0.012, 0.0084];
/// Radius of the scope (m).
pub const SCOPE_RADIUS_M: f64 = 0.0015;
/// How far the scope tip reaches into the cavity from its -x end (m).
pub const SCOPE_INSERTION_M: f64 = 0.006;

/// The benchmark cavity voxelized at `voxel_m`, with the jet leaving the scope tip at `jet_m_s`.
pub fn ellipsoid_cavity(voxel_m: f64, jet_m_s: f32) -> Result<FluidGrid, FluidError> {
    let [a, b, c] = CAVITY_SEMI_AXES_M;
    let h = voxel_m;
    if !(h.is_finite() && h > 0.0 && h < b) {
        return Err(FluidError::InvalidGrid(format!(
            "voxel_m = {voxel_m}: expected a finite voxel size in (0, {b})"
        )));
    }
    let dims: [usize; 3] = std::array::from_fn(|i| (2.0 * [a, b, c][i] / h).ceil() as usize + 2);
    let origin: [f64; 3] = std::array::from_fn(|i| -(dims[i] as f64) * h / 2.0);
    let mut grid = FluidGrid::new(dims, h, origin, [false; 3])?;
    let tip_x = -a + SCOPE_INSERTION_M;
    let scope_r = SCOPE_RADIUS_M.max(0.51 * h);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let [x, y, z] = grid.cell_centre_m([i, j, k]);
                let inside = (x / a).powi(2) + (y / b).powi(2) + (z / c).powi(2) <= 1.0;
                let r = (y * y + z * z).sqrt();
                let (label, vel) = if r <= scope_r && x <= tip_x {
                    if x > tip_x - h {
                        (CellLabel::Velocity, [jet_m_s, 0.0, 0.0])
                    } else {
                        (CellLabel::Solid, [0.0; 3])
                    }
                } else if !inside {
                    (CellLabel::Solid, [0.0; 3])
                } else if x < -a + 0.003 && r > 0.0025 {
                    (CellLabel::Outflow, [0.0; 3])
                } else {
                    (CellLabel::Fluid, [0.0; 3])
                };
                grid.set_label([i, j, k], label)?;
                grid.set_velocity([i, j, k], vel)?;
            }
        }
    }
    Ok(grid)
}
