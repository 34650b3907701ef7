//! Assembly of the total potential `W_dev + U_vol - p V` of linear tetrahedra with a nodally
//! averaged volumetric energy: its value, gradient (the residual) and Hessian (the tangent).
//!
//! Volumetric locking of linear tetrahedra is avoided by evaluating `J` per vertex:
//! `J_n = (sum of current volumes of the adjacent tets / 4) / (same in the reference)` and
//! `U_vol = sum_n V0_n kappa_n / 2 (J_n - 1)^2` (the "average nodal pressure" family). The
//! deviatoric energy stays per element. The energy is a function of `x`, so the tangent is exactly
//! symmetric.
//!
//! Condensed, that tangent couples vertices two edges apart (`(kappa/V0) dv_n dv_n^T` spans the
//! star of `n`), which fills the factor badly. The linear system is therefore assembled in the
//! equivalent expanded form with one scaled nodal pressure unknown per vertex,
//! `[K_xx  B; B^T  -I] [dx; dq] = [r; 0]`, `B = dv_n/dx sqrt(kappa_n / V0_n)`, whose pattern is
//! the 1-ring; eliminating `dq` gives back exactly `K_xx + B B^T`. The matrix is quasi-definite
//! while `K_xx` is positive definite, so LDL^T needs no pivoting.

use super::assembly::BlockPattern;
pub use super::assembly::Evaluation;
use super::element::{add_tet_volume_hessian, tet_volume, tet_volume_gradient, TetReference};
use super::model::{Element, FemModel};
use super::system10::Tet10System;
use super::FemError;
use rayon::prelude::*;

/// The assembled problem of either element: what the Newton solver sees.
pub enum System {
    /// Linear tetrahedra, nodally averaged `J`, expanded system with nodal pressures.
    Nodal(NodalSystem),
    /// 10-node tetrahedra, mean dilatation per element.
    Tet10(Tet10System),
}

impl System {
    /// The system of `model`'s element ([`FemModel::element`]).
    pub fn new(model: &FemModel) -> Result<Self, FemError> {
        Ok(match model.element() {
            Element::Tet4 => Self::Nodal(NodalSystem::new(model)?),
            Element::Tet10 => Self::Tet10(Tet10System::new(model)?),
        })
    }

    /// Number of displacement unknowns.
    pub fn n_dofs(&self) -> usize {
        match self {
            Self::Nodal(s) => s.n_dofs(),
            Self::Tet10(s) => s.n_dofs(),
        }
    }

    /// Size of the linear system (displacements, plus nodal pressures for `Nodal`).
    pub fn n_linear(&self) -> usize {
        match self {
            Self::Nodal(s) => s.n_linear(),
            Self::Tet10(s) => s.n_dofs(),
        }
    }

    /// Stored entries of the matrix.
    pub fn nnz(&self) -> usize {
        match self {
            Self::Nodal(s) => s.nnz(),
            Self::Tet10(s) => s.nnz(),
        }
    }

    /// Column pointers of the full symmetric matrix.
    pub fn col_ptr(&self) -> &[usize] {
        match self {
            Self::Nodal(s) => s.col_ptr(),
            Self::Tet10(s) => s.col_ptr(),
        }
    }

    /// Row indices, sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        match self {
            Self::Nodal(s) => s.row_idx(),
            Self::Tet10(s) => s.row_idx(),
        }
    }

    /// Fill-reducing elimination order.
    pub fn elimination_order(&self, model: &FemModel) -> Vec<usize> {
        match self {
            Self::Nodal(s) => s.elimination_order(model),
            Self::Tet10(s) => s.elimination_order(model),
        }
    }

    /// Fixed degree-of-freedom flags.
    pub fn fixed(&self) -> &[bool] {
        match self {
            Self::Nodal(s) => s.fixed(),
            Self::Tet10(s) => s.fixed(),
        }
    }

    /// Total reference volume of the elements.
    pub fn rest_volume(&self) -> f64 {
        match self {
            Self::Nodal(s) => s.rest_volumes().sum(),
            Self::Tet10(s) => s.rest_volume(),
        }
    }

    /// Potential, residual and (optionally) tangent at `x`; see [`NodalSystem::evaluate`].
    pub fn evaluate(
        &self,
        model: &FemModel,
        x: &[[f64; 3]],
        pressure_pa: f64,
        tangent: Option<&mut [f64]>,
    ) -> Result<Evaluation, FemError> {
        match self {
            Self::Nodal(s) => s.evaluate(model, x, pressure_pa, tangent),
            Self::Tet10(s) => s.evaluate(model, x, pressure_pa, tangent),
        }
    }

    /// The Hessian of the potential applied to a displacement vector.
    pub fn multiply(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        match self {
            Self::Nodal(s) => s.multiply(values, x),
            Self::Tet10(s) => s.multiply(values, x),
        }
    }

    /// `dV/dx` of the cavity at `x`, zero at fixed degrees of freedom.
    pub fn volume_gradient(&self, model: &FemModel, x: &[[f64; 3]]) -> Vec<f64> {
        let mut g = vec![0.0; self.n_dofs()];
        model.cavity.add_gradient(x, 1.0, &mut g);
        for (v, &f) in g.iter_mut().zip(self.fixed()) {
            if f {
                *v = 0.0;
            }
        }
        g
    }
}

/// Sparsity pattern, reference data and nodal averaging data of a linear-tetrahedron model.
pub struct NodalSystem {
    n_nodes: usize,
    refs: Vec<TetReference>,
    node_tet_ptr: Vec<usize>,
    node_tet_idx: Vec<u32>,
    star_ptr: Vec<usize>,
    star_idx: Vec<u32>,
    v0_node: Vec<f64>,
    kappa_node: Vec<f64>,
    /// Pattern of the full symmetric expanded matrix: 3 displacement columns per vertex, then one
    /// pressure column per vertex.
    pattern: BlockPattern,
}

const CHUNK: usize = 2048;

impl NodalSystem {
    /// Precomputes reference data and the tangent's sparsity pattern.
    pub fn new(model: &FemModel) -> Result<Self, FemError> {
        model.validate()?;
        let n = model.rest_positions_m.len();
        let x0 = &model.rest_positions_m;
        let mut refs = Vec::with_capacity(model.tets.len());
        for (t, tet) in model.tets.iter().enumerate() {
            let xs = tet.map(|i| x0[i as usize]);
            let r = TetReference::new(&xs).ok_or_else(|| {
                FemError::Mesh(format!("tetrahedron {t} ({tet:?}) is degenerate or negatively oriented in the rest mesh"))
            })?;
            refs.push(r);
        }
        // Vertex -> tetrahedra.
        let mut count = vec![0usize; n + 1];
        for tet in &model.tets {
            for &i in tet {
                count[i as usize + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let node_tet_ptr = count.clone();
        let mut fill = count;
        let mut node_tet_idx = vec![0u32; node_tet_ptr[n]];
        for (t, tet) in model.tets.iter().enumerate() {
            for &i in tet {
                node_tet_idx[fill[i as usize]] = t as u32;
                fill[i as usize] += 1;
            }
        }
        // Stars (1-ring with the vertex itself), sorted.
        let mut star_ptr = vec![0usize; n + 1];
        let mut star_idx = Vec::new();
        for v in 0..n {
            let mut s: Vec<u32> = node_tet_idx[node_tet_ptr[v]..node_tet_ptr[v + 1]]
                .iter()
                .flat_map(|&t| model.tets[t as usize])
                .collect();
            s.push(v as u32);
            s.sort_unstable();
            s.dedup();
            star_idx.extend_from_slice(&s);
            star_ptr[v + 1] = star_idx.len();
        }
        // Nodal reference volumes and volume-weighted bulk moduli.
        let mut v0_node = vec![0.0; n];
        let mut kappa_node = vec![0.0; n];
        for (t, tet) in model.tets.iter().enumerate() {
            let v = refs[t].volume0 / 4.0;
            let k = model.materials[model.tet_material[t] as usize].kappa_pa;
            for &i in tet {
                v0_node[i as usize] += v;
                kappa_node[i as usize] += k * v;
            }
        }
        for i in 0..n {
            if v0_node[i] > 0.0 {
                kappa_node[i] /= v0_node[i];
            }
        }
        // Displacement-displacement pattern: the 1-ring (stars) plus the pressure-load couplings.
        let mut extra: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (i, j) in model.cavity.coupled_pairs() {
            extra[j as usize].push(i);
        }
        let mut nbr_ptr = vec![0usize; n + 1];
        let mut nbr_idx = Vec::new();
        let mut buf = Vec::new();
        for v in 0..n {
            buf.clear();
            buf.extend_from_slice(&star_idx[star_ptr[v]..star_ptr[v + 1]]);
            buf.extend_from_slice(&extra[v]);
            buf.sort_unstable();
            buf.dedup();
            nbr_idx.extend_from_slice(&buf);
            nbr_ptr[v + 1] = nbr_idx.len();
        }
        let mut col_ptr = Vec::with_capacity(4 * n + 1);
        let mut row_idx = Vec::new();
        let mut diag_pos = vec![0usize; 4 * n];
        col_ptr.push(0);
        for j in 0..n {
            for dj in 0..3 {
                for &i in &nbr_idx[nbr_ptr[j]..nbr_ptr[j + 1]] {
                    for di in 0..3 {
                        if i as usize == j && di == dj {
                            diag_pos[3 * j + dj] = row_idx.len();
                        }
                        row_idx.push(3 * i as usize + di);
                    }
                }
                // Pressure rows: the vertices whose star contains j (= the star of j).
                for &m in &star_idx[star_ptr[j]..star_ptr[j + 1]] {
                    row_idx.push(3 * n + m as usize);
                }
                col_ptr.push(row_idx.len());
            }
        }
        for m in 0..n {
            for &i in &star_idx[star_ptr[m]..star_ptr[m + 1]] {
                for di in 0..3 {
                    row_idx.push(3 * i as usize + di);
                }
            }
            diag_pos[3 * n + m] = row_idx.len();
            row_idx.push(3 * n + m);
            col_ptr.push(row_idx.len());
        }
        Ok(Self {
            n_nodes: n,
            refs,
            node_tet_ptr,
            node_tet_idx,
            star_ptr,
            star_idx,
            v0_node,
            kappa_node,
            pattern: BlockPattern {
                nbr_ptr,
                nbr_idx,
                col_ptr,
                row_idx,
                diag_pos,
                fixed: model.fixed_dofs.clone(),
            },
        })
    }

    /// Number of displacement unknowns (3 per vertex, fixed ones included as identity rows).
    pub fn n_dofs(&self) -> usize {
        3 * self.n_nodes
    }

    /// Size of the expanded linear system (displacements and nodal pressures).
    pub fn n_linear(&self) -> usize {
        4 * self.n_nodes
    }

    /// Number of stored entries of the expanded matrix.
    pub fn nnz(&self) -> usize {
        self.pattern.row_idx.len()
    }

    /// Fill-reducing elimination order of the expanded system: geometric nested dissection of
    /// the vertices, each vertex's three displacements and pressure kept together.
    pub fn elimination_order(&self, model: &FemModel) -> Vec<usize> {
        let nodes = super::ordering::nested_dissection(
            &model.rest_positions_m,
            &self.pattern.nbr_ptr,
            &self.pattern.nbr_idx,
        );
        let n = self.n_nodes;
        let mut order = Vec::with_capacity(4 * n);
        for v in nodes {
            let v = v as usize;
            order.extend([3 * v, 3 * v + 1, 3 * v + 2, 3 * n + v]);
        }
        order
    }

    /// Fixed degree-of-freedom flags.
    pub fn fixed(&self) -> &[bool] {
        &self.pattern.fixed
    }

    /// Reference volume of every tetrahedron.
    pub fn rest_volumes(&self) -> impl Iterator<Item = f64> + '_ {
        self.refs.iter().map(|r| r.volume0)
    }

    #[inline]
    fn add_block(&self, values: &mut [f64], i: u32, j: u32, blk: &[[f64; 3]; 3]) {
        self.pattern.add_block(values, i, j, blk);
    }

    /// Column pointers of the expanded matrix.
    pub fn col_ptr(&self) -> &[usize] {
        &self.pattern.col_ptr
    }

    /// Row indices of the expanded matrix, sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.pattern.row_idx
    }

    /// Adds `b` to the coupling of displacement `(i, d)` with pressure `m`, in both triangles.
    #[inline]
    fn add_coupling(&self, values: &mut [f64], i: u32, d: usize, m: usize, b: f64) {
        let star_m = &self.star_idx[self.star_ptr[m]..self.star_ptr[m + 1]];
        let star_i = &self.star_idx[self.star_ptr[i as usize]..self.star_ptr[i as usize + 1]];
        if let (Ok(a), Ok(c)) = (star_m.binary_search(&i), star_i.binary_search(&(m as u32))) {
            let n = self.n_nodes;
            values[self.pattern.col_ptr[3 * n + m] + 3 * a + d] += b;
            let deg = self.pattern.nbr_ptr[i as usize + 1] - self.pattern.nbr_ptr[i as usize];
            values[self.pattern.col_ptr[3 * i as usize + d] + 3 * deg + c] += b;
        }
    }

    /// Evaluates the potential and its gradient at `x` under `pressure_pa`; with `tangent`, also
    /// its Hessian into `tangent` (length [`Self::nnz`]). Fixed degrees of freedom become identity
    /// rows scaled to the mean diagonal. Fails if any tetrahedron is inverted.
    pub fn evaluate(
        &self,
        model: &FemModel,
        x: &[[f64; 3]],
        pressure_pa: f64,
        mut tangent: Option<&mut [f64]>,
    ) -> Result<Evaluation, FemError> {
        let n = self.n_nodes;
        let nt = model.tets.len();
        let gather = |t: usize| model.tets[t].map(|i| x[i as usize]);
        let vols: Vec<f64> = (0..nt)
            .into_par_iter()
            .map(|t| tet_volume(&gather(t)))
            .collect();
        let mut min_ratio = f64::INFINITY;
        for (t, &v) in vols.iter().enumerate() {
            let r = v / self.refs[t].volume0;
            if r.is_nan() || r <= 0.0 {
                return Err(FemError::Inverted {
                    tet: t,
                    volume_ratio: r,
                });
            }
            min_ratio = min_ratio.min(r);
        }
        let mut v_node = vec![0.0; n];
        for (t, tet) in model.tets.iter().enumerate() {
            for &i in tet {
                v_node[i as usize] += vols[t] / 4.0;
            }
        }
        let mut energy = 0.0;
        let mut min_j = f64::INFINITY;
        let mut p_node = vec![0.0; n];
        for i in 0..n {
            if self.v0_node[i] > 0.0 {
                let j = v_node[i] / self.v0_node[i];
                min_j = min_j.min(j);
                p_node[i] = self.kappa_node[i] * (j - 1.0);
                energy += 0.5 * self.kappa_node[i] * self.v0_node[i] * (j - 1.0) * (j - 1.0);
            }
        }
        let mut residual = vec![0.0; 3 * n];
        if let Some(k) = tangent.as_deref_mut() {
            k.fill(0.0);
        }
        let want_k = tangent.is_some();
        for start in (0..nt).step_by(CHUNK) {
            let end = (start + CHUNK).min(nt);
            type ElemOut = (f64, [f64; 12], Option<Box<[[f64; 12]; 12]>>);
            let outs: Vec<Result<ElemOut, FemError>> = (start..end)
                .into_par_iter()
                .map(|t| {
                    let xs = gather(t);
                    let mat = &model.materials[model.tet_material[t] as usize];
                    let mut f = [0.0; 12];
                    let mut kk = if want_k {
                        Some(Box::new([[0.0; 12]; 12]))
                    } else {
                        None
                    };
                    let w = self.refs[t]
                        .deviatoric(mat, &xs, &mut f, kk.as_deref_mut())
                        .ok_or(FemError::Inverted {
                            tet: t,
                            volume_ratio: 0.0,
                        })?;
                    let tet = model.tets[t];
                    let pbar = tet.iter().map(|&i| p_node[i as usize]).sum::<f64>() / 4.0;
                    let gv = tet_volume_gradient(&xs);
                    for d in 0..12 {
                        f[d] += pbar * gv[d];
                    }
                    if let Some(k) = kk.as_deref_mut() {
                        add_tet_volume_hessian(&xs, pbar, k);
                    }
                    Ok((w, f, kk))
                })
                .collect();
            for (off, out) in outs.into_iter().enumerate() {
                let (w, f, kk) = out?;
                let tet = model.tets[start + off];
                energy += w;
                for a in 0..4 {
                    for d in 0..3 {
                        residual[3 * tet[a] as usize + d] += f[3 * a + d];
                    }
                }
                if let (Some(k), Some(ke)) = (tangent.as_deref_mut(), kk) {
                    for a in 0..4 {
                        for b in 0..4 {
                            let mut blk = [[0.0; 3]; 3];
                            for i in 0..3 {
                                for j in 0..3 {
                                    blk[i][j] = ke[3 * a + i][3 * b + j];
                                }
                            }
                            self.add_block(k, tet[a], tet[b], &blk);
                        }
                    }
                }
            }
        }
        // Nodal volumetric stiffness in expanded form: B = sqrt(kappa_n / V0_n) dv_n/dx, -1 on
        // the pressure diagonal (eliminating it restores (kappa_n / V0_n) dv_n dv_n^T).
        if let Some(k) = tangent.as_deref_mut() {
            let mut g: Vec<[f64; 3]> = Vec::new();
            for v in 0..n {
                k[self.pattern.diag_pos[3 * n + v]] = -1.0;
                if self.v0_node[v] <= 0.0 {
                    continue;
                }
                let star = &self.star_idx[self.star_ptr[v]..self.star_ptr[v + 1]];
                g.clear();
                g.resize(star.len(), [0.0; 3]);
                for &t in &self.node_tet_idx[self.node_tet_ptr[v]..self.node_tet_ptr[v + 1]] {
                    let tet = model.tets[t as usize];
                    let gv = tet_volume_gradient(&gather(t as usize));
                    for a in 0..4 {
                        if let Ok(s) = star.binary_search(&tet[a]) {
                            for d in 0..3 {
                                g[s][d] += 0.25 * gv[3 * a + d];
                            }
                        }
                    }
                }
                let c = (self.kappa_node[v] / self.v0_node[v]).sqrt();
                for (a, &ia) in star.iter().enumerate() {
                    for d in 0..3 {
                        self.add_coupling(k, ia, d, v, c * g[a][d]);
                    }
                }
            }
        }
        self.pattern
            .finish(model, x, pressure_pa, &mut energy, &mut residual, tangent);
        Ok(Evaluation {
            energy_j: energy,
            residual,
            min_volume_ratio: min_ratio,
            min_nodal_j: min_j,
        })
    }

    fn multiply_expanded(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        self.pattern.multiply(values, x)
    }

    /// `y = (K_xx + B B^T) x`: the condensed tangent (the Hessian of the potential) applied to a
    /// displacement vector, from the assembled expanded values (for tests and diagnostics).
    pub fn multiply(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        let nx = self.n_dofs();
        let mut v = x.to_vec();
        v.resize(self.n_linear(), 0.0);
        let y1 = self.multiply_expanded(values, &v);
        let mut w = vec![0.0; self.n_linear()];
        w[nx..].copy_from_slice(&y1[nx..]);
        let y2 = self.multiply_expanded(values, &w);
        (0..nx).map(|i| y1[i] + y2[i]).collect()
    }
}
