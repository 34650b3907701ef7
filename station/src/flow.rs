//! The flow field reduced for the page: the mean velocity of the fluid in cubic blocks of cells,
//! one arrow per block holding fluid, the block edge chosen so that at most `max_arrows` remain.

use hydrometra_ipc::field::{label, FlowFieldHeader};

use crate::frame::FlowArrowsHeader;

/// Why a flow field could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("flow field: {0}")]
pub struct FlowError(String);

/// Whether a cell carries the fluid's velocity (or a prescribed one the fluid sees: the jet, the
/// outflow holes, the open os).
fn carries_flow(l: u8) -> bool {
    matches!(
        l,
        label::FLUID | label::INFLOW | label::OUTFLOW | label::OPEN
    )
}

/// Arrows of a flow field (`payload` as published, `h` its header).
pub fn arrows(
    h: &FlowFieldHeader,
    payload: &[u8],
    max_arrows: usize,
) -> Result<(FlowArrowsHeader, Vec<[f32; 6]>), FlowError> {
    let [nx, ny, nz] = h.dims.map(|d| d as usize);
    let cells = nx * ny * nz;
    if cells != h.cell_count as usize {
        return Err(FlowError(format!(
            "dims {:?} do not multiply to cell_count {}",
            h.dims, h.cell_count
        )));
    }
    let labels = payload
        .get(h.labels_offset_bytes as usize..)
        .and_then(|s| s.get(..cells))
        .ok_or_else(|| FlowError(format!("label section outside {} bytes", payload.len())))?;
    let vel = payload
        .get(h.velocities_offset_bytes as usize..)
        .and_then(|s| s.get(..12 * cells))
        .ok_or_else(|| FlowError(format!("velocity section outside {} bytes", payload.len())))?;
    let fluid = labels.iter().filter(|l| carries_flow(**l)).count();
    // Blocks of b³ cells: fluid / b³ <= max_arrows.
    let mut b = 1usize;
    while fluid.div_ceil(b * b * b) > max_arrows.max(1) {
        b += 1;
    }
    let (bx, by, bz) = (nx.div_ceil(b), ny.div_ceil(b), nz.div_ceil(b));
    // Per block: cells, sum of i, j, k, sum of vx, vy, vz.
    let mut sums = vec![[0f64; 7]; bx * by * bz];
    let v = |c: usize, a: usize| -> f64 {
        let o = 12 * c + 4 * a;
        f32::from_le_bytes([vel[o], vel[o + 1], vel[o + 2], vel[o + 3]]) as f64
    };
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = i + nx * (j + ny * k);
                if !carries_flow(labels[c]) {
                    continue;
                }
                let s = &mut sums[i / b + bx * (j / b + by * (k / b))];
                s[0] += 1.0;
                s[1] += i as f64;
                s[2] += j as f64;
                s[3] += k as f64;
                s[4] += v(c, 0);
                s[5] += v(c, 1);
                s[6] += v(c, 2);
            }
        }
    }
    let mut max_speed = 0f32;
    let out: Vec<[f32; 6]> = sums
        .iter()
        .filter(|s| s[0] > 0.0)
        .map(|s| {
            let n = s[0];
            let p = |a: usize| (h.origin_m[a] + h.spacing_m * s[1 + a] / n) as f32;
            let u = |a: usize| (s[4 + a] / n) as f32;
            let a = [p(0), p(1), p(2), u(0), u(1), u(2)];
            let speed = (a[3] * a[3] + a[4] * a[4] + a[5] * a[5]).sqrt();
            if speed.is_finite() {
                max_speed = max_speed.max(speed);
            }
            a
        })
        .collect();
    Ok((
        FlowArrowsHeader {
            arrow_count: out.len() as u32,
            block_m: (h.spacing_m * b as f64) as f32,
            status_sequence: h.status_sequence,
            sim_time_s: h.sim_time_s,
            max_speed_m_per_s: max_speed,
            fluid_cells: fluid as u32,
        },
        out,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4×4×4 grid: fluid in the lower half (k < 2) moving at (1, 2, 3) m/s except one cell.
    fn field() -> (FlowFieldHeader, Vec<u8>) {
        let cells = 64;
        let mut payload = vec![0u8; cells + 12 * cells];
        for k in 0..2 {
            for j in 0..4 {
                for i in 0..4 {
                    let c = i + 4 * (j + 4 * k);
                    payload[c] = label::FLUID;
                    let v: [f32; 3] = if c == 0 {
                        [5.0, 0.0, 0.0]
                    } else {
                        [1.0, 2.0, 3.0]
                    };
                    for (a, x) in v.iter().enumerate() {
                        let o = cells + 12 * c + 4 * a;
                        payload[o..o + 4].copy_from_slice(&x.to_le_bytes());
                    }
                }
            }
        }
        let h = FlowFieldHeader {
            dims: [4, 4, 4],
            cell_count: 64,
            origin_m: [0.1, 0.2, 0.3],
            spacing_m: 0.01,
            labels_offset_bytes: 0,
            velocities_offset_bytes: cells as u64,
            total_bytes: payload.len() as u64,
            ..Default::default()
        };
        (h, payload)
    }

    #[test]
    fn one_arrow_per_fluid_cell_when_they_fit() {
        let (h, p) = field();
        let (ah, a) = arrows(&h, &p, 1000).unwrap();
        assert_eq!((ah.arrow_count, ah.fluid_cells, a.len()), (32, 32, 32));
        assert!((ah.block_m - 0.01).abs() < 1e-9);
        assert_eq!(a[0], [0.1, 0.2, 0.3, 5.0, 0.0, 0.0]);
        assert_eq!(ah.max_speed_m_per_s, 5.0);
    }

    #[test]
    fn blocks_average_position_and_velocity_of_their_fluid_cells() {
        let (h, p) = field();
        // 32 fluid cells, at most 4 arrows: blocks of 2³ (32 / 8 = 4).
        let (ah, a) = arrows(&h, &p, 4).unwrap();
        assert_eq!(a.len(), 4);
        assert!((ah.block_m - 0.02).abs() < 1e-9);
        // First block: cells i, j, k in {0, 1}: mean index 0.5, mean vx (5 + 7) / 8 = 1.5.
        let first = a[0];
        assert!((first[0] - (0.1 + 0.005)).abs() < 1e-6);
        assert!((first[2] - (0.3 + 0.005)).abs() < 1e-6);
        assert!((first[3] - 1.5).abs() < 1e-6);
        assert!((first[4] - 14.0 / 8.0).abs() < 1e-6);
    }

    #[test]
    fn sections_outside_the_payload_are_an_error_not_a_panic() {
        let (mut h, p) = field();
        h.velocities_offset_bytes = 10_000;
        assert!(arrows(&h, &p, 10).is_err());
        let (mut h, p) = field();
        h.cell_count = 65;
        assert!(arrows(&h, &p, 10).is_err());
    }
}
