//! Assembly of the total potential `W_dev + U_vol - p V` on 10-node tetrahedra with a
//! mean-dilatation volumetric energy per element, `U_e = V0_e kappa/2 (v_e/V0_e - 1)^2`
//! (`v_e` the exact current element volume).
//!
//! Why P2/P0 (quadratic displacement, one condensed pressure per element): it satisfies the
//! inf-sup condition in 2D and 3D (the edge nodes control the flux through every face), so it
//! does not lock at nu -> 1/2, and the pressure is local, so it condenses exactly into the element
//! tangent `(kappa/V0) dv dv^T + kappa (J - 1) d2v`: no global pressure unknowns, and the
//! potential is still a function of `x`, so the tangent is exactly symmetric. The matrix is the
//! plain displacement Hessian (positive definite at stable equilibria), factorized by LDL^T.

use super::assembly::{BlockPattern, Evaluation};
use super::model::FemModel;
use super::tet10::Tet10Reference;
use super::FemError;
use rayon::prelude::*;

/// Sparsity pattern and reference data of a 10-node model.
pub struct Tet10System {
    n_nodes: usize,
    refs: Vec<Tet10Reference>,
    pattern: BlockPattern,
}

const CHUNK: usize = 1024;

type ElemOut = (f64, f64, [f64; 30], Option<Box<[[f64; 30]; 30]>>);

impl Tet10System {
    /// Precomputes reference data and the tangent's sparsity pattern.
    pub fn new(model: &FemModel) -> Result<Self, FemError> {
        model.validate()?;
        let n = model.rest_positions_m.len();
        let x0 = &model.rest_positions_m;
        let mut refs = Vec::with_capacity(model.tets.len());
        for t in 0..model.tets.len() {
            let nodes = model.tet10_nodes(t);
            let r = Tet10Reference::new(&nodes.map(|i| x0[i as usize])).ok_or_else(|| {
                FemError::Mesh(format!(
                    "10-node tetrahedron {t} ({nodes:?}) is degenerate or inverted in the rest mesh"
                ))
            })?;
            refs.push(r);
        }
        let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); n];
        for t in 0..model.tets.len() {
            let nodes = model.tet10_nodes(t);
            for &a in &nodes {
                nbrs[a as usize].extend_from_slice(&nodes);
            }
        }
        for (i, j) in model.cavity.coupled_pairs() {
            nbrs[j as usize].push(i);
        }
        let mut nbr_ptr = vec![0usize; n + 1];
        let mut nbr_idx = Vec::new();
        for (v, list) in nbrs.iter_mut().enumerate() {
            list.push(v as u32);
            list.sort_unstable();
            list.dedup();
            nbr_idx.extend_from_slice(list);
            nbr_ptr[v + 1] = nbr_idx.len();
        }
        drop(nbrs);
        let mut col_ptr = Vec::with_capacity(3 * n + 1);
        let mut row_idx = Vec::new();
        let mut diag_pos = vec![0usize; 3 * n];
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
                col_ptr.push(row_idx.len());
            }
        }
        Ok(Self {
            n_nodes: n,
            refs,
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

    /// Number of displacement unknowns (3 per node).
    pub fn n_dofs(&self) -> usize {
        3 * self.n_nodes
    }

    /// Stored entries of the (full symmetric) tangent.
    pub fn nnz(&self) -> usize {
        self.pattern.row_idx.len()
    }

    /// Column pointers of the tangent.
    pub fn col_ptr(&self) -> &[usize] {
        &self.pattern.col_ptr
    }

    /// Row indices of the tangent, sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.pattern.row_idx
    }

    /// Nested-dissection elimination order, each node's three displacements kept together.
    pub fn elimination_order(&self, model: &FemModel) -> Vec<usize> {
        super::ordering::nested_dissection(
            &model.rest_positions_m,
            &self.pattern.nbr_ptr,
            &self.pattern.nbr_idx,
        )
        .into_iter()
        .flat_map(|v| [3 * v as usize, 3 * v as usize + 1, 3 * v as usize + 2])
        .collect()
    }

    /// Fixed degree-of-freedom flags.
    pub fn fixed(&self) -> &[bool] {
        &self.pattern.fixed
    }

    /// Total reference volume.
    pub fn rest_volume(&self) -> f64 {
        self.refs.iter().map(|r| r.volume0).sum()
    }

    #[inline]
    fn add_block(&self, values: &mut [f64], i: u32, j: u32, blk: &[[f64; 3]; 3]) {
        self.pattern.add_block(values, i, j, blk);
    }

    fn element(
        &self,
        model: &FemModel,
        x: &[[f64; 3]],
        t: usize,
        want_k: bool,
    ) -> Result<ElemOut, FemError> {
        let nodes = model.tet10_nodes(t);
        let xs = nodes.map(|i| x[i as usize]);
        let r = &self.refs[t];
        let mat = &model.materials[model.tet_material[t] as usize];
        let v = r.volume(&xs);
        let jbar = v / r.volume0;
        if jbar.is_nan() || jbar <= 0.0 || r.min_jacobian(&xs) <= 0.0 {
            return Err(FemError::Inverted {
                tet: t,
                volume_ratio: jbar,
            });
        }
        let mut f = [0.0; 30];
        let mut kk = want_k.then(|| Box::new([[0.0; 30]; 30]));
        let w = r
            .deviatoric(mat, &xs, &mut f, kk.as_deref_mut())
            .ok_or(FemError::Inverted {
                tet: t,
                volume_ratio: jbar,
            })?;
        let kappa = mat.kappa_pa;
        let energy = w + 0.5 * kappa * r.volume0 * (jbar - 1.0) * (jbar - 1.0);
        let g = r.volume_gradient(&xs);
        let press = kappa * (jbar - 1.0);
        for d in 0..30 {
            f[d] += press * g[d];
        }
        if let Some(k) = kk.as_deref_mut() {
            r.add_volume_hessian(&xs, press, k);
            let c = kappa / r.volume0;
            for a in 0..30 {
                for b in 0..30 {
                    k[a][b] += c * g[a] * g[b];
                }
            }
        }
        Ok((energy, jbar, f, kk))
    }

    /// Evaluates the potential and its gradient at `x` under `pressure_pa`; with `tangent`, also
    /// its Hessian (length [`Self::nnz`]). Fixed degrees of freedom become identity rows scaled
    /// to the mean diagonal. Fails if any element is inverted (at a quadrature point or overall).
    pub fn evaluate(
        &self,
        model: &FemModel,
        x: &[[f64; 3]],
        pressure_pa: f64,
        mut tangent: Option<&mut [f64]>,
    ) -> Result<Evaluation, FemError> {
        let nt = model.tets.len();
        let mut energy = 0.0;
        let mut min_ratio = f64::INFINITY;
        let mut residual = vec![0.0; self.n_dofs()];
        if let Some(k) = tangent.as_deref_mut() {
            k.fill(0.0);
        }
        let want_k = tangent.is_some();
        for start in (0..nt).step_by(CHUNK) {
            let end = (start + CHUNK).min(nt);
            let outs: Vec<Result<ElemOut, FemError>> = (start..end)
                .into_par_iter()
                .map(|t| self.element(model, x, t, want_k))
                .collect();
            for (off, out) in outs.into_iter().enumerate() {
                let (w, jbar, f, kk) = out?;
                let nodes = model.tet10_nodes(start + off);
                energy += w;
                min_ratio = min_ratio.min(jbar);
                for a in 0..10 {
                    for d in 0..3 {
                        residual[3 * nodes[a] as usize + d] += f[3 * a + d];
                    }
                }
                if let (Some(k), Some(ke)) = (tangent.as_deref_mut(), kk) {
                    for a in 0..10 {
                        for b in 0..10 {
                            let blk: [[f64; 3]; 3] = std::array::from_fn(|i| {
                                std::array::from_fn(|j| ke[3 * a + i][3 * b + j])
                            });
                            self.add_block(k, nodes[a], nodes[b], &blk);
                        }
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
            min_nodal_j: min_ratio,
        })
    }

    /// `y = K x` with the assembled tangent `values`.
    pub fn multiply(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        self.pattern.multiply(values, x)
    }
}
