//! The paper's "time to traverse": tracers released over the inflow port's fluid-facing area
//! into a frozen flow, timed until they leave through the outflow holes.

use super::sources::for_each_inflow_face;
use super::spec::ParticleKind;
use super::system::{ParticleClass, ParticleSystem};
use crate::fluid::FluidSolver;
use crate::scene::scope::FACE_NORMALS;
use crate::scene::{InflowPort, VoxelKind};

/// Tracers of the time to traverse per inflow face and side: a regular 4 x 4 sub-grid.
pub const TRAVERSE_SUBGRID: usize = 4;
/// How far into the fluid the tracers start from the port's face, voxels.
pub const TRAVERSE_OFFSET_VOXELS: f64 = 0.25;

/// Result of [`time_to_traverse`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Traverse {
    /// Tracers released.
    pub released: usize,
    /// Tracers that left through the outflow holes within the time limit.
    pub reached: usize,
    /// Tracers that left through the open external os instead.
    pub open: usize,
    /// Time of the first arrival, s.
    pub first_s: Option<f64>,
    /// Time by which half of the released tracers arrived, s.
    pub median_s: Option<f64>,
}

/// Releases one tracer (no slip) at each of `starts_m` (those in a fluid cell) into the solver's current (frozen)
/// velocity and advances them with steps of `dt_s` until all left or `max_time_s`; reports when
/// they leave through [`VoxelKind::Outflow`] cells (the paper's "time to traverse").
pub fn time_to_traverse(
    solver: &FluidSolver,
    kinds: &[VoxelKind],
    starts_m: &[[f64; 3]],
    dt_s: f64,
    max_time_s: f64,
) -> Traverse {
    let mut sys = ParticleSystem::new(solver.grid(), starts_m.len().max(1), 16, [0.0, -1.0, 0.0]);
    let tracer = sys.add_class(ParticleClass {
        kind: ParticleKind::Blood,
        settle_m_s: 0.0,
        tau_s: 0.0,
        shade_m2: 0.0,
        diameter_m: 0.0,
    });
    let mut out = Traverse {
        released: 0,
        reached: 0,
        open: 0,
        first_s: None,
        median_s: None,
    };
    let Some(tracer) = tracer else {
        return out;
    };
    for &p in starts_m {
        if sys.emit(kinds, tracer, p) {
            out.released += 1;
        }
    }
    if out.released == 0 || dt_s.is_nan() || dt_s <= 0.0 {
        return out;
    }
    let mut t = 0.0;
    while t < max_time_s && !sys.is_empty() {
        sys.step(solver, kinds, None, dt_s, None);
        t += dt_s;
        let reached = sys.counts().outflow.iter().sum::<u64>() as usize;
        if reached > 0 && out.first_s.is_none() {
            out.first_s = Some(t);
        }
        if 2 * reached >= out.released && out.median_s.is_none() {
            out.median_s = Some(t);
        }
        out.reached = reached;
        out.open = sys.counts().open.iter().sum::<u64>() as usize;
    }
    out
}

/// Points spread over the inflow port's fluid-facing area: on every fluid face of a port cell
/// that the inflow crosses (`d . n > 0`, `d` the scope's direction; the others carry no flux), a
/// regular `side` x `side` sub-grid (the centres of the face's sub-squares), moved
/// [`TRAVERSE_OFFSET_VOXELS`] into the fluid cell; appended to `out` up to its capacity.
/// Deterministic, and as many points per face at every voxel size, so each face (the same
/// area in voxels) carries the same weight.
pub fn inflow_face_points(port: &InflowPort<'_>, side: usize, out: &mut Vec<[f64; 3]>) {
    let c = &port.grid;
    let h = c.spacing_m;
    let Some(dir) = port.direction else {
        return;
    };
    for_each_inflow_face(port, |[i, j, k], f| {
        let n = FACE_NORMALS[f];
        if dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2] <= 0.0 {
            return;
        }
        let centre = c.centre_m(i, j, k);
        let axis = f / 2;
        let sign = if f % 2 == 1 { 1.0 } else { -1.0 };
        let (t1, t2) = ((axis + 1) % 3, (axis + 2) % 3);
        for a in 0..side {
            for b in 0..side {
                if out.len() >= out.capacity() {
                    return;
                }
                let mut p = centre;
                p[axis] += sign * (0.5 + TRAVERSE_OFFSET_VOXELS) * h;
                p[t1] += ((a as f64 + 0.5) / side as f64 - 0.5) * h;
                p[t2] += ((b as f64 + 0.5) / side as f64 - 0.5) * h;
                out.push(p);
            }
        }
    });
}
