//! The particles' sources: the classes they emit (blood, the bubble sizes, one class per fragment
//! release), the bleeding sources placed on the cavity wall, and the emission of one step
//! (blood from the wall, bubbles beside the inflow port, fragment releases).

use super::inputs::ParticleInputs;
use super::slip::SlipFluid;
use super::spec::{BleedingSourceSpec, ParticleKind, ParticleSpec, BUBBLE_CLASSES};
use super::system::{ParticleClass, ParticleSystem};
use crate::mesh::cross;
use crate::scene::random::SeededRng;
use crate::scene::{CavityView, InflowPort, VoxelBox, VoxelKind};

/// A bleeding source placed on the cavity surface.
#[derive(Debug, Clone)]
struct Source {
    spec: BleedingSourceSpec,
    vertex: usize,
    /// Triangles around the vertex (for its normal).
    ring: Vec<u32>,
    /// Particles owed (fractional emission).
    owed: f64,
}

/// The emission's state: the class indices, the placed bleeding sources, what is owed, the
/// generator.
#[derive(Debug, Clone)]
pub(super) struct Sources {
    rng: SeededRng,
    sources: Vec<Source>,
    fragments_done: Vec<bool>,
    bubble_owed: f64,
    /// Class indices: blood, the bubble classes, then one per fragment release.
    blood_class: u8,
    bubble_class0: u8,
    fragment_class0: u8,
    emit_points: Vec<[f64; 3]>,
}

impl Sources {
    /// Adds the classes of `spec` to `sys` (their slip in `fluid`) and places the bleeding sources
    /// on the nearest vertex of the cavity's wall; `None` when the classes do not fit.
    pub fn new(
        spec: &ParticleSpec,
        sys: &mut ParticleSystem,
        cavity: &CavityView<'_>,
        fluid: SlipFluid,
    ) -> Option<Self> {
        let b = &spec.blood;
        let d = b.droplet_diameter_mm * 1e-3;
        let (settle, tau) = fluid.terminal_slip(d, b.density_kg_m3);
        let blood_class = sys.add_class(ParticleClass {
            kind: ParticleKind::Blood,
            settle_m_s: settle,
            tau_s: tau,
            shade_m2: b.attenuation_per_mm * 1e3 * b.particle_volume_ul * 1e-9,
            diameter_m: d,
        })?;
        let bs = &spec.bubbles;
        let mut bubble_class0 = 0;
        for c in 0..BUBBLE_CLASSES {
            let f = (c as f64 + 0.5) / BUBBLE_CLASSES as f64;
            let d = (bs.min_diameter_mm + f * (bs.max_diameter_mm - bs.min_diameter_mm)) * 1e-3;
            let (settle, tau) = fluid.terminal_slip(d, bs.density_kg_m3);
            let idx = sys.add_class(ParticleClass {
                kind: ParticleKind::Bubble,
                settle_m_s: settle,
                tau_s: tau,
                shade_m2: std::f64::consts::PI / 4.0 * d * d,
                diameter_m: d,
            })?;
            if c == 0 {
                bubble_class0 = idx;
            }
        }
        let fragment_class0 = sys.classes().len() as u8;
        for f in &spec.fragments {
            let d = f.diameter_mm * 1e-3;
            let (settle, tau) = fluid.terminal_slip(d, f.density_kg_m3);
            sys.add_class(ParticleClass {
                kind: ParticleKind::Fragment,
                settle_m_s: settle,
                tau_s: tau,
                shade_m2: std::f64::consts::PI / 4.0 * d * d,
                diameter_m: d,
            })?;
        }
        Some(Self {
            rng: SeededRng::new(spec.seed),
            sources: place_bleeding(&spec.blood.sources, cavity),
            fragments_done: vec![false; spec.fragments.len()],
            bubble_owed: 0.0,
            blood_class,
            bubble_class0,
            fragment_class0,
            emit_points: Vec::with_capacity(64),
        })
    }

    /// Emits this step's particles at scene time `t` (the end of the step of `dt_s`): blood,
    /// bubbles, then fragment releases.
    pub fn emit(
        &mut self,
        spec: &ParticleSpec,
        sys: &mut ParticleSystem,
        inputs: &ParticleInputs<'_>,
        t: f64,
        dt_s: f64,
    ) {
        self.emit_blood(spec, sys, inputs, t, dt_s);
        self.emit_bubbles(spec, sys, inputs, dt_s);
        self.emit_fragments(spec, sys, inputs.kinds, t);
    }

    fn emit_blood(
        &mut self,
        spec: &ParticleSpec,
        sys: &mut ParticleSystem,
        inputs: &ParticleInputs<'_>,
        t: f64,
        dt_s: f64,
    ) {
        let rng = &mut self.rng;
        let cav = &inputs.cavity;
        let h = inputs.grid.spacing_m;
        let vol = spec.blood.particle_volume_ul * 1e-9;
        for s in &mut self.sources {
            let (rate, radius, jet) = s.spec.at(t);
            s.owed += rate * dt_s / vol;
            let count = s.owed.floor();
            s.owed -= count;
            if count <= 0.0 {
                continue;
            }
            let Some(v) = cav.positions_m.get(s.vertex) else {
                continue;
            };
            let v = v.map(|x| x as f64);
            let mut n = [0.0; 3];
            for &ti in &s.ring {
                let [a, b, c] = cav.triangles[ti as usize].map(|i| cav.positions_m[i as usize]);
                let e1: [f64; 3] = std::array::from_fn(|k| (b[k] - a[k]) as f64);
                let e2: [f64; 3] = std::array::from_fn(|k| (c[k] - a[k]) as f64);
                let x = [
                    e1[1] * e2[2] - e1[2] * e2[1],
                    e1[2] * e2[0] - e1[0] * e2[2],
                    e1[0] * e2[1] - e1[1] * e2[0],
                ];
                for k in 0..3 {
                    n[k] += x[k];
                }
            }
            let m = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if m.is_nan() || m <= 0.0 {
                continue;
            }
            let mut n = n.map(|x| x / m);
            // Into the fluid: the side where a point two cells off the wall is fluid.
            let probe = |n: [f64; 3]| {
                let q: [f64; 3] = std::array::from_fn(|k| v[k] + 2.0 * h * n[k]);
                kind_at_m(&inputs.grid, inputs.kinds, q) == VoxelKind::Fluid
            };
            if !probe(n) && probe(n.map(|x| -x)) {
                n = n.map(|x| -x);
            }
            // A tangent basis.
            let a = if n[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let t1 = unit(cross(n, a));
            let t2 = cross(n, t1);
            for _ in 0..count as usize {
                let r = radius * rng.unit().sqrt();
                let phi = rng.range(0.0, std::f64::consts::TAU);
                let d = 0.75 * h + jet * rng.unit();
                let mut placed = false;
                for lift in 0..4 {
                    let along = d + lift as f64 * 0.5 * h;
                    let p: [f64; 3] = std::array::from_fn(|k| {
                        v[k] + r * (phi.cos() * t1[k] + phi.sin() * t2[k]) + along * n[k]
                    });
                    if kind_at_m(&inputs.grid, inputs.kinds, p) == VoxelKind::Fluid {
                        placed = sys.emit(inputs.kinds, self.blood_class, p);
                        break;
                    }
                }
                if !placed {
                    sys.count_rejected(1);
                }
            }
        }
    }

    fn emit_bubbles(
        &mut self,
        spec: &ParticleSpec,
        sys: &mut ParticleSystem,
        inputs: &ParticleInputs<'_>,
        dt_s: f64,
    ) {
        let per_ml = spec.bubbles.per_ml;
        if per_ml <= 0.0 {
            return;
        }
        let q_ml = inputs.inflow_m3_per_s * 1e6 * dt_s;
        self.bubble_owed += per_ml * q_ml.max(0.0);
        let count = self.bubble_owed.floor();
        if count <= 0.0 {
            return;
        }
        self.bubble_owed -= count;
        // The fluid cells next to the inflow port.
        self.emit_points.clear();
        inflow_neighbours(&inputs.inflow, &mut self.emit_points);
        let rng = &mut self.rng;
        if self.emit_points.is_empty() {
            sys.count_rejected(count as u64);
            return;
        }
        let h = inputs.inflow.grid.spacing_m;
        for _ in 0..count as usize {
            let p = self.emit_points[rng.below(self.emit_points.len())];
            let p: [f64; 3] = std::array::from_fn(|a| p[a] + rng.range(-0.45, 0.45) * h);
            let class = self.bubble_class0 + rng.below(BUBBLE_CLASSES) as u8;
            sys.emit(inputs.kinds, class, p);
        }
    }

    fn emit_fragments(
        &mut self,
        spec: &ParticleSpec,
        sys: &mut ParticleSystem,
        kinds: &[VoxelKind],
        t: f64,
    ) {
        let rng = &mut self.rng;
        for (i, f) in spec.fragments.iter().enumerate() {
            if self.fragments_done[i] || t < f.time_s {
                continue;
            }
            self.fragments_done[i] = true;
            let class = self.fragment_class0 + i as u8;
            for _ in 0..f.count {
                let d = rng.direction();
                let r = f.spread_mm * 1e-3 * rng.unit().cbrt();
                let p: [f64; 3] = std::array::from_fn(|a| f.position_mm[a] * 1e-3 + r * d[a]);
                sys.emit(kinds, class, p);
            }
        }
    }
}

/// The bleeding sources `specs` on the cavity `cav`: each at the nearest surface vertex not on
/// the os's cap, with its triangle ring (for the wall's normal); those with no such vertex are
/// dropped.
fn place_bleeding(specs: &[BleedingSourceSpec], cav: &CavityView<'_>) -> Vec<Source> {
    // Sources: the nearest surface vertex (not on the os's cap) and its triangle ring.
    let first_cap = cav.triangles.len().saturating_sub(cav.cap_triangles);
    let mut on_wall = vec![false; cav.positions_m.len()];
    for t in &cav.triangles[..first_cap] {
        for &v in t {
            if let Some(w) = on_wall.get_mut(v as usize) {
                *w = true;
            }
        }
    }
    let mut placed = Vec::with_capacity(specs.len());
    for s in specs {
        let p = s.position_mm.map(|v| v * 1e-3);
        let mut best = (f64::INFINITY, usize::MAX);
        for (i, q) in cav.positions_m.iter().enumerate() {
            if !on_wall[i] {
                continue;
            }
            let d2 = (0..3).map(|a| (q[a] as f64 - p[a]).powi(2)).sum::<f64>();
            if d2 < best.0 {
                best = (d2, i);
            }
        }
        if best.1 == usize::MAX {
            continue;
        }
        let ring = cav.triangles[..first_cap]
            .iter()
            .enumerate()
            .filter(|(_, t)| t.contains(&(best.1 as u32)))
            .map(|(i, _)| i as u32)
            .collect();
        placed.push(Source {
            spec: s.clone(),
            vertex: best.1,
            ring,
            owed: 0.0,
        });
    }
    placed
}

/// Calls `f` with the cell `(i, j, k)` of every inflow port cell and each of its faces
/// (0..6, the scope's `FACE_NORMALS`) that borders fluid.
pub(super) fn for_each_inflow_face(port: &InflowPort<'_>, mut f: impl FnMut([usize; 3], usize)) {
    let [nx, ny, _] = port.grid.dims;
    for b in port.cells {
        let n = b.cell as usize;
        let ijk = [n % nx, (n / nx) % ny, n / (nx * ny)];
        for face in 0..6 {
            if b.faces >> face & 1 == 1 {
                f(ijk, face);
            }
        }
    }
}

/// Centres of the cells next to the inflow port's fluid faces, appended to `out` up to its
/// capacity (no allocation).
fn inflow_neighbours(port: &InflowPort<'_>, out: &mut Vec<[f64; 3]>) {
    let c = &port.grid;
    for_each_inflow_face(port, |ijk, f| {
        let mut q = ijk.map(|x| x as i64);
        q[f / 2] += if f % 2 == 1 { 1 } else { -1 };
        if q.iter()
            .zip(c.dims)
            .all(|(&x, d)| x >= 0 && (x as usize) < d)
            && out.len() < out.capacity()
        {
            out.push(c.centre_m(q[0] as usize, q[1] as usize, q[2] as usize));
        }
    });
}

/// The kind of the cell of `grid` that `p` (m) lies in (solid outside the grid).
fn kind_at_m(grid: &VoxelBox, kinds: &[VoxelKind], p: [f64; 3]) -> VoxelKind {
    let c = grid;
    let mut idx = [0usize; 3];
    for a in 0..3 {
        let x = (p[a] - c.origin_m[a]) / c.spacing_m;
        if !(x >= 0.0 && x < c.dims[a] as f64) {
            return VoxelKind::Solid;
        }
        idx[a] = x as usize;
    }
    kinds[c.index(idx[0], idx[1], idx[2])]
}

/// `a` normalised (unchanged when zero).
fn unit(a: [f64; 3]) -> [f64; 3] {
    let m = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if m > 0.0 {
        a.map(|x| x / m)
    } else {
        a
    }
}
