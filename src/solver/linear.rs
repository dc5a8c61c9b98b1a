//! Sparse Cholesky of the effective stiffness with faer: symbolic analysis once per body,
//! numeric factorisation per Newton iteration.

use crate::assembly::StiffnessPattern;
use crate::precision::Real;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::Side;

pub struct CholeskySolver {
    pattern: SymbolicSparseColMat<u32>,
    symbolic: SymbolicLlt<u32>,
    factor: Option<Llt<u32, Real>>,
}

#[derive(Debug, thiserror::Error)]
pub enum LinearError {
    #[error("the effective stiffness is not positive definite")]
    NotPositiveDefinite,
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
}

impl CholeskySolver {
    pub fn new(p: &StiffnessPattern) -> Result<Self, LinearError> {
        let pattern = SymbolicSparseColMat::new_checked(p.n, p.n, p.col_ptr.clone(), None, p.row_idx.clone());
        let symbolic = SymbolicLlt::try_new(pattern.as_ref(), Side::Lower).map_err(|e| LinearError::Symbolic(format!("{e:?}")))?;
        Ok(Self { pattern, symbolic, factor: None })
    }

    /// Numeric factorisation of the matrix with these lower-triangle values.
    pub fn factorize(&mut self, values: &[Real]) -> Result<(), LinearError> {
        let mat = SparseColMatRef::new(self.pattern.as_ref(), values);
        self.factor = None;
        let llt = Llt::try_new_with_symbolic(self.symbolic.clone(), mat, Side::Lower).map_err(|_| LinearError::NotPositiveDefinite)?;
        self.factor = Some(llt);
        Ok(())
    }

    /// Solves in place with the last factorisation.
    pub fn solve(&self, rhs: &mut [Real]) {
        let n = rhs.len();
        self.solve_columns(rhs, n);
    }

    /// Solves in place for the columns of a column-major `n x k` block (`k = rhs.len() / n`).
    pub fn solve_columns(&self, rhs: &mut [Real], n: usize) {
        let k = rhs.len() / n.max(1);
        let llt = self.factor.as_ref().expect("factorize before solve");
        llt.solve_in_place(faer::MatMut::from_column_major_slice_mut(rhs, n, k));
    }
}
