//! The viscous step's no-slip walls at their distance, on grids whose cut fractions carry the
//! walls' distances ([`CutFractions::walls`](super::CutFractions)): second order at curved walls
//! where the labels' staircase is first order.
//!
//! Rule (Gibou, Fedkiw, Cheng and Kang 2002, with the quadratic extrapolation the staircase
//! ghosts use): where the wall crosses the arm from a face's centre to its neighbour at a
//! fraction `t` of the spacing, the neighbour is replaced by the ghost value of the quadratic
//! through the wall velocity `w` at `t`, the face `u1` and the opposite neighbour `u2` at `-1`:
//! the arm adds `2 w / (t (1 + t)) - (2 - t) / t u1 + (1 - t) / (1 + t) u2` to the Laplacian.
//! The `u1` term goes into the diagonal and the `u2` term is lagged (the field before the step), so
//! the implicit matrix keeps its symmetric off-diagonal part and stays positive definite (the
//! diagonal only grows), and a steady state satisfies the quadratic rule exactly: the rule is
//! exact for a quadratic profile, such as Hagen-Poiseuille's along every axis. Where the opposite
//! arm is not a plain neighbour (a wall, an outflow side, the box's end) the ghost is linear:
//! `(w - u1) / t`. A face whose centre lies in the solid has walls at distance 0 on every arm (its
//! velocity stays at the wall's). Distances are clamped to [`MIN_WALL_DISTANCE`].
//!
//! The arms the labels make walls keep their place where the geometry has no nearer wall: the
//! box's end and `Velocity` cells at half a cell (as the staircase), other wall cells (small cells
//! merged away, whose faces the geometry may still call fluid) at one cell. An arm is a wall when
//! either end's geometry says so, so the couplings stay symmetric. The wall velocity is the fixed
//! neighbour's (its prescribed normal velocity) or the `Velocity` cells' beside a ghost, else 0
//! (the cut surfaces are at rest).
//!
//! The explicit step is forward Euler on the same operator (so explicit and implicit steps share
//! their steady states); it runs only where it is stable with the walls' diagonal
//! ([`CutViscosity::explicit_stable`]), else the step is implicit.

use super::grid::FluidGrid;
use super::sample::Layout;
use super::topology::{
    face_cell_indices, neighbour_index, wall_velocity, FaceSet, CONST_BIT, NONE,
};
use super::viscosity::Operator;

/// Smallest wall distance the stencil uses, in cells. The rule's weights grow as `1 / t`: a
/// floor keeps the implicit system's conditioning (and the f32 sums) sound where a face centre
/// lies almost on the wall; the velocity there is within `t h |du/dn|` of the wall's anyway, so
/// the floor moves only those faces, by at most `0.05 h |du/dn|`. Measured on the tilted pipe
/// (`harness::pipe`, axis (1, 1, 1), radii 4, 8, 16 cells), flow-rate error: floor 0.01:
/// -0.84 %, -0.128 %, -0.068 %; 0.05: -0.83 %, -0.114 %, -0.048 %; 0.2: +0.84 %, +0.40 %,
/// +0.30 % (a floor that large is a first-order wall shift).
pub const MIN_WALL_DISTANCE: f32 = 0.05;

/// One wall arm of a face: the Laplacian gains `w_coef w + opp_coef u[opp]` (lagged) besides its
/// diagonal part.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WallArm {
    /// Compact face.
    pub n: u32,
    pub w_coef: f32,
    pub opp_coef: f32,
    /// Full index of the opposite neighbour (NONE: linear rule).
    pub opp: u32,
    /// The wall velocity: the value of this fixed face (full index), or else the mean of the
    /// `Velocity` cells among `cells` (NONE: none; 0 when neither).
    pub w_face: u32,
    pub cells: [u32; 2],
}

/// The viscous operator of one component with the walls at their distance.
#[derive(Default, Debug)]
pub(crate) struct CutViscosity {
    /// The labels' stencil with the wall arms NONE.
    pub stencil: Vec<[u32; 6]>,
    /// Diagonal of the negative Laplacian: coupled arms plus the walls' implicit part.
    pub diag: Vec<f32>,
    /// The wall arms.
    pub walls: Vec<WallArm>,
    /// The largest diagonal.
    pub max_diag: f32,
}

/// What the labels put on an arm.
#[derive(Clone, Copy, PartialEq)]
enum Arm {
    /// A neighbour face (stencil entry: full index, `CONST_BIT` when fixed).
    Coupled(u32),
    /// Zero gradient (outflow).
    Open,
    /// Beyond the box's end.
    BoxEnd,
    /// A ghost between wall cells, with its `Velocity` cells (NONE: not one).
    Ghost([u32; 2]),
}

impl CutViscosity {
    /// The operator of component `c` from its face set and the walls' distances (`walls`: the
    /// component's entries, sorted by face).
    pub fn build(
        &mut self,
        set: &FaceSet,
        layout: &Layout,
        grid: &FluidGrid,
        c: usize,
        walls: &[(u32, [f32; 6])],
    ) {
        self.stencil.clear();
        self.diag.clear();
        self.walls.clear();
        self.max_diag = 0.0;
        let labels = grid.labels();
        let (cdims, periodic) = (grid.dims(), grid.periodic());
        let entry = |idx: u32| {
            walls
                .binary_search_by_key(&idx, |e| e.0)
                .ok()
                .map(|k| walls[k].1)
        };
        let in_solid = |arms: &[f32; 6]| arms.iter().all(|&x| x == 0.0);
        let velocity_cell = |i: u32| {
            if i != NONE && labels[i as usize] == super::CellLabel::Velocity {
                i
            } else {
                NONE
            }
        };
        for (n, &idx) in set.active.iter().enumerate() {
            let f = layout.face_coords(c, idx as usize);
            let own = entry(idx);
            let st = set.stencil[n];
            let mut kind = [Arm::Open; 6];
            let mut dist = [None::<f32>; 6];
            for slot in 0..6 {
                let (d, dir) = (slot / 2, if slot % 2 == 0 { -1 } else { 1 });
                let gi = neighbour_index(layout, c, f, idx as usize, d, dir);
                kind[slot] = if st[slot] != NONE {
                    Arm::Coupled(st[slot])
                } else {
                    match gi {
                        None => Arm::BoxEnd,
                        Some(_) if d == c => Arm::Open,
                        Some(g) => {
                            let (li, ui) =
                                face_cell_indices(cdims, periodic, c, layout.face_coords(c, g));
                            let wall = |i: u32| labels.get(i as usize).is_none_or(|l| l.is_wall());
                            if wall(li) && wall(ui) {
                                Arm::Ghost([velocity_cell(li), velocity_cell(ui)])
                            } else {
                                Arm::Open
                            }
                        }
                    }
                };
                // The geometry's wall on this arm, seen from either end.
                let mut cross = own.and_then(|a| {
                    let x = if in_solid(&a) { 0.0 } else { a[slot] };
                    (x <= 1.0).then_some(x)
                });
                if cross.is_none() {
                    if let Some(other) = gi.and_then(|g| entry(g as u32)) {
                        if in_solid(&other) {
                            cross = Some(1.0);
                        } else if other[slot ^ 1] <= 1.0 {
                            cross = Some((1.0 - other[slot ^ 1]).max(0.0));
                        }
                    }
                }
                let half = |x: Option<f32>| Some(x.map_or(0.5, |x| x.min(0.5)));
                dist[slot] = match kind[slot] {
                    Arm::BoxEnd => half(cross),
                    Arm::Ghost(cells) if cells != [NONE, NONE] => half(cross),
                    Arm::Ghost(_) => Some(cross.unwrap_or(1.0)),
                    _ => cross,
                };
            }
            let mut row = [NONE; 6];
            let (mut coupled, mut wall_diag) = (0.0f32, 0.0f32);
            for slot in 0..6 {
                let Some(t) = dist[slot] else {
                    if let Arm::Coupled(e) = kind[slot] {
                        row[slot] = e;
                        coupled += 1.0;
                    }
                    continue;
                };
                let t = t.max(MIN_WALL_DISTANCE);
                let opp = match (kind[slot ^ 1], dist[slot ^ 1]) {
                    (Arm::Coupled(e), None) => e & !CONST_BIT,
                    _ => NONE,
                };
                let (dw, w_coef, opp_coef) = if opp != NONE {
                    ((2.0 - t) / t, 2.0 / (t * (1.0 + t)), (1.0 - t) / (1.0 + t))
                } else {
                    (1.0 / t, 1.0 / t, 0.0)
                };
                let (w_face, cells) = match kind[slot] {
                    Arm::Coupled(e) if e & CONST_BIT != 0 => (e & !CONST_BIT, [NONE; 2]),
                    Arm::Ghost(cells) => (NONE, cells),
                    _ => (NONE, [NONE; 2]),
                };
                wall_diag += dw;
                self.walls.push(WallArm {
                    n: n as u32,
                    w_coef,
                    opp_coef,
                    opp,
                    w_face,
                    cells,
                });
            }
            self.stencil.push(row);
            self.diag.push(coupled + wall_diag);
            self.max_diag = self.max_diag.max(coupled + wall_diag);
        }
    }

    /// The implicit system's operator.
    pub fn operator<'a>(&'a self, set: &'a FaceSet) -> Operator<'a> {
        Operator {
            active: &set.active,
            compact: &set.compact,
            stencil: &self.stencil,
            diag: &self.diag,
        }
    }

    /// The walls' constant and lagged terms of every compact face from the field `u` (cleared
    /// first).
    pub fn ghosts(&self, grid: &FluidGrid, c: usize, u: &[f32], g: &mut [f32]) {
        g.fill(0.0);
        for w in &self.walls {
            let wall = if w.w_face != NONE {
                u[w.w_face as usize]
            } else {
                wall_velocity(grid, c, w.cells[0], w.cells[1])
            };
            let mut v = w.w_coef * wall;
            if w.opp != NONE {
                v += w.opp_coef * u[w.opp as usize];
            }
            g[w.n as usize] += v;
        }
    }

    /// Whether the explicit (forward Euler) step is stable at `a = nu dt / h^2`: `a` times the
    /// largest Gershgorin bound (diagonal plus six unit couplings) at most 1, as
    /// [`super::EXPLICIT_LIMIT`] is for the plain stencil (`0.08 (6 + 6) < 1`). Near walls closer
    /// than the spacing the diagonal grows as `1 / t`, so cut grids turn implicit sooner.
    pub fn explicit_stable(&self, a: f64) -> bool {
        a * (self.max_diag as f64 + 6.0) <= 1.0
    }

    /// Explicit step: `out = u + a (neighbours + g - diag u)`.
    pub fn explicit(&self, set: &FaceSet, full: &[f32], g: &[f32], a: f32, out: &mut [f32]) {
        for (n, &idx) in set.active.iter().enumerate() {
            let u = full[idx as usize];
            let mut s = g[n];
            for &e in &self.stencil[n] {
                if e != NONE {
                    s += full[(e & !CONST_BIT) as usize];
                }
            }
            out[n] = u + a * (s - self.diag[n] * u);
        }
    }
}
