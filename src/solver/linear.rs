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

/// Bodies with fewer free dofs take AMD without trying nested dissection, and factorise on one
/// thread (bodies are then factorised in parallel with each other instead).
const LARGE_BODY_DOFS: usize = 3000;

pub struct CholeskySolver {
    pattern: SymbolicSparseColMat<u32>,
    symbolic: SymbolicCholesky<u32>,
    ordering: Ordering,
    /// Values of the factor `L`, overwritten by each factorisation.
    factor: Vec<Real>,
    factored: bool,
    /// Workspace of the numeric factorisation, kept across calls.
    scratch: MemBuffer,
    /// Workspace of the solves, for up to `solve_columns` right-hand sides (grown on demand).
    solve_scratch: MemBuffer,
    solve_columns: usize,
    par: Par,
}

#[derive(Debug, thiserror::Error)]
pub enum LinearError {
    #[error("the effective stiffness is not positive definite")]
    NotPositiveDefinite,
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
}

impl CholeskySolver {
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
        let scratch = MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<Real>(par, Default::default()));
        let solve_scratch = MemBuffer::new(symbolic.solve_in_place_scratch::<Real>(1, par));
        Ok(Self { pattern, factor: vec![0.0; symbolic.len_val()], symbolic, ordering, factored: false, scratch, solve_scratch, solve_columns: 1, par })
    }

    /// The ordering the factorisation uses.
    pub fn ordering(&self) -> Ordering {
        self.ordering
    }

    /// Stored entries of the factor `L` (the fill).
    pub fn factor_entries(&self) -> usize {
        self.symbolic.len_val()
    }

    /// Numeric factorisation of the matrix with these lower-triangle values.
    pub fn factorize(&mut self, values: &[Real]) -> Result<(), LinearError> {
        let mat = SparseColMatRef::new(self.pattern.as_ref(), values);
        self.factored = false;
        let stack = MemStack::new(&mut self.scratch);
        self.symbolic
            .factorize_numeric_llt(&mut self.factor, mat, Side::Lower, Default::default(), self.par, stack, Default::default())
            .map_err(|_| LinearError::NotPositiveDefinite)?;
        self.factored = true;
        Ok(())
    }

    /// Solves in place with the last factorisation.
    pub fn solve(&mut self, rhs: &mut [Real]) {
        let n = rhs.len();
        self.solve_columns(rhs, n);
    }

    /// Solves in place for the columns of a column-major `n x k` block (`k = rhs.len() / n`).
    pub fn solve_columns(&mut self, rhs: &mut [Real], n: usize) {
        assert!(self.factored, "factorize before solve");
        let k = rhs.len() / n.max(1);
        if k > self.solve_columns {
            self.solve_scratch = MemBuffer::new(self.symbolic.solve_in_place_scratch::<Real>(k, self.par));
            self.solve_columns = k;
        }
        let stack = MemStack::new(&mut self.solve_scratch);
        LltRef::new(&self.symbolic, &self.factor).solve_in_place_with_conj(Conj::No, faer::MatMut::from_column_major_slice_mut(rhs, n, k), self.par, stack);
    }
}
