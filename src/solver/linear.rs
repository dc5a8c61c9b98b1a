//! Sparse Cholesky of the effective stiffness with faer: the symbolic analysis (and its
//! fill-reducing ordering) once per body, numeric factorisations into buffers kept across calls.

use super::ordering::{nested_dissection, Ordering};
use crate::assembly::StiffnessPattern;
use crate::precision::Real;
use crate::scene::OrderingChoice;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, Par, Side};
use std::sync::Arc;

/// Bodies with fewer free dofs take AMD without trying nested dissection, and factorise on one
/// thread (bodies are then factorised in parallel with each other instead).
const LARGE_BODY_DOFS: usize = 3000;

/// The symbolic analysis of a free-dof pattern: the same for every body with that pattern and
/// ordering, so bodies of one shape (a packing's grains) share one.
pub struct CholeskySymbolic {
    pattern: SymbolicSparseColMat<u32>,
    symbolic: SymbolicCholesky<u32>,
    ordering: Ordering,
    par: Par,
}

/// A body's factorisation: the (shared) symbolic analysis and its own numeric buffers.
pub struct CholeskySolver {
    symbolic: Arc<CholeskySymbolic>,
    /// Values of the factor `L`, overwritten by each factorisation.
    factor: Vec<Real>,
    factored: bool,
    /// Workspace of the numeric factorisation, kept across calls.
    scratch: MemBuffer,
    /// Workspace of the solves, for up to `solve_columns` right-hand sides (grown on demand).
    solve_scratch: MemBuffer,
    solve_columns: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum LinearError {
    #[error("the effective stiffness is not positive definite")]
    NotPositiveDefinite,
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
}

impl CholeskySymbolic {
    /// Whether the analysis depends on the pattern only (not on the nodes' coordinates), so
    /// that bodies of one pattern can share it: AMD, chosen or taken by `auto` below
    /// `LARGE_BODY_DOFS`.
    pub fn pattern_only(free_dofs: usize, choice: OrderingChoice) -> bool {
        match choice {
            OrderingChoice::Amd => true,
            OrderingChoice::Auto => free_dofs < LARGE_BODY_DOFS,
            OrderingChoice::NestedDissection => false,
        }
    }

    /// The symbolic analysis of the free-dof pattern. `coordinates` (of each free dof's node)
    /// feed the nested dissection; with `auto` it is tried on large bodies and kept over AMD
    /// when its factor is smaller.
    pub fn new(p: &StiffnessPattern, coordinates: &[[Real; 3]], choice: OrderingChoice) -> Result<Self, LinearError> {
        let pattern = SymbolicSparseColMat::new_checked(p.n, p.n, p.col_ptr.clone(), None, p.row_idx.clone());
        let analyse = |ordering: Ordering| {
            let result = match ordering {
                Ordering::Amd => factorize_symbolic_cholesky(pattern.as_ref(), Side::Lower, SymmetricOrdering::Amd, Default::default()),
                Ordering::NestedDissection => {
                    let forward = nested_dissection(&p.col_ptr, &p.row_idx, coordinates);
                    let mut inverse = vec![0u32; p.n];
                    for (k, &v) in forward.iter().enumerate() {
                        inverse[v as usize] = k as u32;
                    }
                    let perm = PermRef::new_checked(&forward, &inverse, p.n);
                    factorize_symbolic_cholesky(pattern.as_ref(), Side::Lower, SymmetricOrdering::Custom(perm), Default::default())
                }
            };
            result.map_err(|e| LinearError::Symbolic(format!("{e:?}")))
        };
        let (symbolic, ordering) = match choice {
            OrderingChoice::Amd => (analyse(Ordering::Amd)?, Ordering::Amd),
            OrderingChoice::NestedDissection => (analyse(Ordering::NestedDissection)?, Ordering::NestedDissection),
            OrderingChoice::Auto => {
                let amd = analyse(Ordering::Amd)?;
                let dissected = if p.n >= LARGE_BODY_DOFS { Some(analyse(Ordering::NestedDissection)?) } else { None };
                match dissected {
                    Some(nd) if nd.len_val() < amd.len_val() => (nd, Ordering::NestedDissection),
                    _ => (amd, Ordering::Amd),
                }
            }
        };
        let par = if p.n >= LARGE_BODY_DOFS { Par::rayon(0) } else { Par::Seq };
        Ok(Self { pattern, symbolic, ordering, par })
    }
}

impl CholeskySolver {
    /// Buffers for factorisations with a (shared) symbolic analysis.
    pub fn with(symbolic: Arc<CholeskySymbolic>) -> Self {
        let (s, par) = (&symbolic.symbolic, symbolic.par);
        let scratch = MemBuffer::new(s.factorize_numeric_llt_scratch::<Real>(par, Default::default()));
        let solve_scratch = MemBuffer::new(s.solve_in_place_scratch::<Real>(1, par));
        Self { factor: vec![0.0; s.len_val()], symbolic, factored: false, scratch, solve_scratch, solve_columns: 1 }
    }

    /// The ordering the factorisation uses.
    pub fn ordering(&self) -> Ordering {
        self.symbolic.ordering
    }

    /// Stored entries of the factor `L` (the fill).
    pub fn factor_entries(&self) -> usize {
        self.symbolic.symbolic.len_val()
    }

    /// Numeric factorisation of the matrix with these lower-triangle values.
    pub fn factorize(&mut self, values: &[Real]) -> Result<(), LinearError> {
        let s = &*self.symbolic;
        let mat = SparseColMatRef::new(s.pattern.as_ref(), values);
        self.factored = false;
        let stack = MemStack::new(&mut self.scratch);
        s.symbolic.factorize_numeric_llt(&mut self.factor, mat, Side::Lower, Default::default(), s.par, stack, Default::default()).map_err(|_| LinearError::NotPositiveDefinite)?;
        self.factored = true;
        Ok(())
    }

    /// Solves in place with the last factorisation.
    /// The lower triangle, row by row, of the inverse of the matrix whose lower triangle
    /// `values` holds (this pattern's) ([`dense_inverse`]).
    pub fn dense_inverse(&self, values: &[Real]) -> Option<Vec<Real>> {
        let pattern = &self.symbolic.pattern;
        dense_inverse(pattern.col_ptr(), pattern.row_idx(), values)
    }

    pub fn solve(&mut self, rhs: &mut [Real]) {
        let n = rhs.len();
        self.solve_columns(rhs, n);
    }

    /// Solves in place for the columns of a column-major `n x k` block (`k = rhs.len() / n`).
    pub fn solve_columns(&mut self, rhs: &mut [Real], n: usize) {
        assert!(self.factored, "factorize before solve");
        let k = rhs.len() / n.max(1);
        let s = &*self.symbolic;
        if k > self.solve_columns {
            self.solve_scratch = MemBuffer::new(s.symbolic.solve_in_place_scratch::<Real>(k, s.par));
            self.solve_columns = k;
        }
        let stack = MemStack::new(&mut self.solve_scratch);
        LltRef::new(&s.symbolic, &self.factor).solve_in_place_with_conj(Conj::No, faer::MatMut::from_column_major_slice_mut(rhs, n, k), s.par, stack);
    }
}

/// The lower triangle, row by row (`gpu::types::packed`), of the inverse of the symmetric
/// matrix whose lower triangle `values` fills the CSC
/// pattern `col_ptr`, `row_idx`, from a dense Cholesky factorisation: for a body of tens of dofs
/// (a grain) a few dense kernels, where a sparse factor's solves of the identity's columns walk
/// the factor once per column (doc/benchmarks.md, "A grain in flight in one submission a step").
/// `None` if the matrix is not positive definite.
pub fn dense_inverse(col_ptr: &[u32], row_idx: &[u32], values: &[Real]) -> Option<Vec<Real>> {
    use faer::linalg::cholesky::llt::{factor, inverse};
    let n = col_ptr.len() - 1;
    let mut a = faer::Mat::<Real>::zeros(n, n);
    for j in 0..n {
        for k in col_ptr[j] as usize..col_ptr[j + 1] as usize {
            a[(row_idx[k] as usize, j)] = values[k];
        }
    }
    let scratch = factor::cholesky_in_place_scratch::<Real>(n, Par::Seq, Default::default()).or(inverse::inverse_scratch::<Real>(n, Par::Seq));
    let mut memory = MemBuffer::new(scratch);
    let stack = MemStack::new(&mut memory);
    factor::cholesky_in_place(a.as_mut(), Default::default(), Par::Seq, stack, Default::default()).ok()?;
    let mut out = faer::Mat::<Real>::zeros(n, n);
    inverse::inverse(out.as_mut(), a.as_ref(), Par::Seq, stack);
    // The lower triangle is written; the matrix is symmetric, and the device reads half of it.
    Some(crate::gpu::types::pack_lower(n, |i, j| out[(i, j)]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A banded SPD matrix (a stiffness with neighbours one and three dofs away, and a mass on
    /// the diagonal), lower triangle in CSC.
    fn banded(n: usize) -> (Vec<u32>, Vec<u32>, Vec<Real>) {
        let (mut col_ptr, mut row_idx, mut values) = (vec![0u32], Vec::new(), Vec::new());
        for j in 0..n {
            for (offset, v) in [(0, 5.0 + (j % 4) as Real), (1, -1.0), (3, -0.5 - 0.1 * (j % 3) as Real)] {
                if j + offset < n {
                    row_idx.push((j + offset) as u32);
                    values.push(v);
                }
            }
            col_ptr.push(row_idx.len() as u32);
        }
        (col_ptr, row_idx, values)
    }

    #[test]
    fn the_dense_inverse_is_the_sparse_factors_solves_of_the_identity() {
        let n = 66;
        let (col_ptr, row_idx, values) = banded(n);
        let dense = dense_inverse(&col_ptr, &row_idx, &values).expect("positive definite");
        let pattern = StiffnessPattern { n, col_ptr: col_ptr.clone(), row_idx: row_idx.clone(), diagonal: Vec::new(), scatter: Vec::new(), element_dofs: 0 };
        let coordinates: Vec<[Real; 3]> = (0..n).map(|i| [i as Real, 0.0, 0.0]).collect();
        let mut solver = CholeskySolver::with(Arc::new(CholeskySymbolic::new(&pattern, &coordinates, OrderingChoice::Amd).unwrap()));
        solver.factorize(&values).unwrap();
        let mut columns = vec![0.0; n * n];
        for f in 0..n {
            columns[f * n + f] = 1.0;
        }
        solver.solve_columns(&mut columns, n);
        let largest = columns.iter().fold(0.0 as Real, |m, x| m.max(x.abs()));
        let solved = crate::gpu::types::pack_lower(n, |i, j| columns[j * n + i]);
        assert_eq!(dense.len(), solved.len(), "the lower triangle");
        let worst = dense.iter().zip(&solved).fold(0.0 as Real, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 1e-13 * largest, "{worst:e} against {largest:e}");
        assert_eq!(solver.dense_inverse(&values), Some(dense));
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_has_no_dense_inverse() {
        let (col_ptr, row_idx, mut values) = banded(10);
        values[col_ptr[4] as usize] = -1.0;
        assert_eq!(dense_inverse(&col_ptr, &row_idx, &values), None);
    }
}
