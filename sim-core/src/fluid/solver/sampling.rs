//! The velocity and the pressure at cells and at points (trilinear on the MAC grid), for the
//! scene, the particles and the case files' probes.

use super::super::CellLabel;
use super::FluidSolver;

impl FluidSolver {
    /// Velocity (m/s, along the face's +axis) on face `face` of `cell` (0..6: -x, +x, -y, +y,
    /// -z, +z).
    #[inline]
    pub fn cell_face_velocity_m_s(&self, cell: [usize; 3], face: usize) -> f32 {
        let (c, f) = self.cell_face(cell, face);
        self.u[c][f]
    }

    /// Open area fraction of face `face` of `cell` (numbered as in
    /// [`FluidSolver::cell_face_velocity_m_s`]; 1 without cut cells): its flux is this times
    /// `u h^2`.
    #[inline]
    pub fn cell_face_open_fraction(&self, cell: [usize; 3], face: usize) -> f32 {
        let (c, f) = self.cell_face(cell, face);
        self.grid.cut_fractions().map_or(1.0, |cut| cut.face[c][f])
    }

    /// Component and index of face `face` of `cell`.
    #[inline]
    fn cell_face(&self, cell: [usize; 3], face: usize) -> (usize, usize) {
        let c = face / 2;
        let mut f = cell;
        if face % 2 == 1 {
            f[c] += 1;
            if self.layout.periodic[c] && f[c] == self.grid.dims()[c] {
                f[c] = 0;
            }
        }
        (c, self.layout.face_index(c, f))
    }

    /// Cell-centred velocity (m/s): the mean of the two faces along each axis.
    #[inline]
    pub fn centred_velocity_m_s(&self, cell: [usize; 3]) -> [f32; 3] {
        std::array::from_fn(|c| {
            0.5 * (self.cell_face_velocity_m_s(cell, 2 * c)
                + self.cell_face_velocity_m_s(cell, 2 * c + 1))
        })
    }

    /// Velocity (m/s) interpolated at a point (clamped into the grid).
    pub fn sample_velocity_m_s(&self, point_m: [f64; 3]) -> [f64; 3] {
        let p = self.grid_units(point_m);
        let [u0, u1, u2] = &self.u;
        let v = self.layout.velocity([u0, u1, u2], p);
        [v[0] as f64, v[1] as f64, v[2] as f64]
    }

    /// Component `c` of the velocity (m/s) interpolated at a point (clamped into the grid): a
    /// third of [`FluidSolver::sample_velocity_m_s`]'s work.
    pub fn sample_velocity_component_m_s(&self, c: usize, point_m: [f64; 3]) -> f64 {
        let p = self.grid_units(point_m);
        f64::from(self.layout.sample(c, &self.u[c], p))
    }

    /// The interpolated velocity at a point (m/s, as [`FluidSolver::sample_velocity_m_s`]) and
    /// its curl (1/s) by central differences over one cell each way.
    pub fn velocity_and_curl(&self, point_m: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let h = self.grid.spacing_m();
        let [u0, u1, u2] = &self.u;
        let p = self.grid_units(point_m);
        // d[c][a] = u_c(p + h e_a) - u_c(p - h e_a).
        let (v, d) = match self.layout.velocity_and_cross_differences([u0, u1, u2], p) {
            Some((v, d)) => (v.map(f64::from), d.map(|r| r.map(f64::from))),
            None => (
                self.sample_velocity_m_s(point_m),
                std::array::from_fn(|c| {
                    std::array::from_fn(|a| {
                        if a == c {
                            return 0.0;
                        }
                        let (mut lo, mut hi) = (point_m, point_m);
                        lo[a] -= h;
                        hi[a] += h;
                        self.sample_velocity_component_m_s(c, hi)
                            - self.sample_velocity_component_m_s(c, lo)
                    })
                }),
            ),
        };
        let k = 0.5 / h;
        let curl = [
            (d[2][1] - d[1][2]) * k,
            (d[0][2] - d[2][0]) * k,
            (d[1][0] - d[0][1]) * k,
        ];
        (v, curl)
    }

    pub(super) fn grid_units(&self, point_m: [f64; 3]) -> [f32; 3] {
        let h = self.grid.spacing_m();
        let o = self.grid.origin_m();
        std::array::from_fn(|a| ((point_m[a] - o[a]) / h) as f32)
    }

    /// Pressure (Pa) interpolated at a point from the fluid and outflow cells around it (outflow
    /// cells count as 0 Pa); `None` if none of the eight surrounding cells is fluid or outflow.
    pub fn sample_pressure_pa(&self, point_m: [f64; 3]) -> Option<f64> {
        let p = self.grid_units(point_m);
        let dims = self.grid.dims();
        let periodic = self.grid.periodic();
        let l0 = &self.pressure.mg.levels[0];
        let mut sum = 0.0;
        let mut wsum = 0.0;
        let mut ax = [[(0usize, 0.0f64); 2]; 3];
        for a in 0..3 {
            let s = (p[a] as f64 - 0.5).clamp(
                if periodic[a] { f64::MIN } else { 0.0 },
                if periodic[a] {
                    f64::MAX
                } else {
                    (dims[a] - 1) as f64
                },
            );
            let fl = s.floor();
            let t = s - fl;
            let n = dims[a] as i64;
            let i0 = fl as i64;
            let wrap = |i: i64| {
                if periodic[a] {
                    i.rem_euclid(n) as usize
                } else {
                    i.clamp(0, n - 1) as usize
                }
            };
            ax[a] = [(wrap(i0), 1.0 - t), (wrap(i0 + 1), t)];
        }
        for &(k, wz) in &ax[2] {
            for &(j, wy) in &ax[1] {
                for &(i, wx) in &ax[0] {
                    let w = wx * wy * wz;
                    if w <= 0.0 {
                        continue;
                    }
                    let idx = self.grid.index([i, j, k]);
                    match self.grid.label_at(idx) {
                        CellLabel::Fluid => {
                            sum += w * self.pressure_pa[l0.pad(i, j, k)];
                            wsum += w;
                        }
                        CellLabel::Outflow => wsum += w,
                        _ => {}
                    }
                }
            }
        }
        (wsum > 0.0).then(|| sum / wsum)
    }

    /// Pressure (Pa) of a fluid cell; `None` for other cells.
    pub fn cell_pressure_pa(&self, cell: [usize; 3]) -> Option<f64> {
        (self.grid.label(cell)? == CellLabel::Fluid).then(|| {
            let l0 = &self.pressure.mg.levels[0];
            self.pressure_pa[l0.pad(cell[0], cell[1], cell[2])]
        })
    }
}
