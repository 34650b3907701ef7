//! Sparse symmetric solves with faer: the symbolic LDL^T analysis (AMD ordering, supernodal) is
//! computed once per sparsity pattern and reused for every numeric factorization.

use super::FemError;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LdltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};

/// A reusable LDL^T solver for one sparsity pattern (full symmetric CSC; the lower half is read).
pub struct LdltSolver {
    pattern: SymbolicSparseColMat<usize>,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    mem: MemBuffer,
    par: Par,
    factored: bool,
    /// Numeric factorizations done so far.
    pub factorizations: usize,
}

impl LdltSolver {
    /// Symbolic analysis of the pattern `col_ptr`/`row_idx` (rows sorted within each column),
    /// with the elimination order `order` (`order[k]` = the unknown eliminated k-th) or, if
    /// `None`, approximate minimum degree.
    pub fn new(
        n: usize,
        col_ptr: Vec<usize>,
        row_idx: Vec<usize>,
        order: Option<Vec<usize>>,
    ) -> Result<Self, FemError> {
        let pattern = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let perm = match order {
            Some(fwd) => {
                if fwd.len() != n {
                    return Err(FemError::LinearSolver(format!(
                        "ordering has {} entries for {n} unknowns",
                        fwd.len()
                    )));
                }
                let mut inv = vec![usize::MAX; n];
                for (k, &i) in fwd.iter().enumerate() {
                    if i >= n || inv[i] != usize::MAX {
                        return Err(FemError::LinearSolver(format!(
                            "ordering is not a permutation (entry {k} = {i})"
                        )));
                    }
                    inv[i] = k;
                }
                Some((fwd, inv))
            }
            None => None,
        };
        let ordering = match &perm {
            Some((fwd, inv)) => {
                SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(fwd, inv, n))
            }
            None => SymmetricOrdering::Amd,
        };
        let symbolic = factorize_symbolic_cholesky(
            pattern.as_ref(),
            Side::Lower,
            ordering,
            Default::default(),
        )
        .map_err(|e| FemError::LinearSolver(format!("symbolic analysis failed: {e:?}")))?;
        let par = if rayon::current_num_threads() > 1 {
            Par::rayon(rayon::current_num_threads())
        } else {
            Par::Seq
        };
        let req = symbolic
            .factorize_numeric_ldlt_scratch::<f64>(par, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(2, par));
        let mem = MemBuffer::try_new(req).map_err(|_| {
            FemError::LinearSolver("out of memory for the factorization workspace".into())
        })?;
        let l_values = vec![0.0; symbolic.len_val()];
        Ok(Self {
            pattern,
            symbolic,
            l_values,
            mem,
            par,
            factored: false,
            factorizations: 0,
        })
    }

    /// Number of stored entries of the factor L.
    pub fn factor_nnz(&self) -> usize {
        self.l_values.len()
    }

    /// Numeric LDL^T factorization of the matrix with `values` on the pattern.
    pub fn factorize(&mut self, values: &[f64]) -> Result<(), FemError> {
        self.factored = false;
        let a = SparseColMatRef::new(self.pattern.as_ref(), values);
        let stack = MemStack::new(&mut self.mem);
        self.symbolic
            .factorize_numeric_ldlt(
                &mut self.l_values,
                a,
                Side::Lower,
                LdltRegularization::default(),
                self.par,
                stack,
                Default::default(),
            )
            .map_err(|e| FemError::LinearSolver(format!("LDL^T factorization failed: {e:?}")))?;
        self.factorizations += 1;
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = rhs` in place with the last factorization.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        if !self.factored {
            return Err(FemError::LinearSolver(
                "solve before a successful factorization".into(),
            ));
        }
        let n = rhs.len();
        let ldlt = LdltRef::new(&self.symbolic, &self.l_values);
        let stack = MemStack::new(&mut self.mem);
        ldlt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            self.par,
            stack,
        );
        if rhs.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(FemError::LinearSolver(
                "solution is not finite (singular tangent?)".into(),
            ))
        }
    }
}
