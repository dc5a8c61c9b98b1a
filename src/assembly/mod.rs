//! Assembly of a body's internal force and effective stiffness.
//!
//! The stiffness is stored as the lower triangle of a CSC matrix over the free degrees of
//! freedom. Its pattern, a per-element scatter map (local entry -> value index) and the inverse
//! gather map (value -> local entries) are built once, so each Newton iteration only adds
//! numbers. Both backends assemble by gathering (`assemble_csr`, `assemble_residual`).

use crate::mesh::Mesh;

/// Numbering of a body's degrees of freedom: `node * dim + component`.
#[derive(Debug, Clone)]
pub struct DofMap {
    pub dim: usize,
    /// Index among the free dofs, or `None` for a prescribed dof.
    pub free: Vec<Option<u32>>,
    pub free_count: usize,
}

impl DofMap {
    pub fn new(dim: usize, prescribed: &[bool]) -> Self {
        let mut next = 0u32;
        let free = prescribed
            .iter()
            .map(|&p| {
                (!p).then(|| {
                    next += 1;
                    next - 1
                })
            })
            .collect();
        Self { dim, free, free_count: next as usize }
    }

    /// `(dof, index among the free dofs)` for every free dof, in dof order.
    pub fn free_pairs(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.free.iter().enumerate().filter_map(|(d, f)| f.map(|f| (d, f as usize)))
    }
}

/// Sentinel for a local entry that is not stored (upper triangle or prescribed dof).
pub const SKIP: u32 = u32::MAX;

/// Lower-triangular CSC pattern of the free-dof stiffness with the element scatter maps.
#[derive(Debug, Clone)]
pub struct StiffnessPattern {
    pub n: usize,
    pub col_ptr: Vec<u32>,
    pub row_idx: Vec<u32>,
    /// Value index of each free dof's diagonal entry.
    pub diagonal: Vec<u32>,
    /// Per element, `(nen*dim)²` entries in row-major local order.
    pub scatter: Vec<u32>,
    pub element_dofs: usize,
}

impl StiffnessPattern {
    pub fn new(mesh: &Mesh, dofs: &DofMap) -> Self {
        let dim = dofs.dim;
        let nen = mesh.kind.nodes();
        let ndof = nen * dim;
        let n = dofs.free_count;
        let local_free = |e: usize| -> Vec<Option<u32>> { mesh.element(e).iter().flat_map(|&node| (0..dim).map(move |i| node as usize * dim + i)).map(|g| dofs.free[g]).collect() };
        // Each column's rows, repeated as often as elements share them.
        let (starts, mut rows) = flattened(n, |emit| {
            for c in 0..n {
                emit(c, c as u32); // every free dof has its diagonal (mass), even if isolated
            }
            for e in 0..mesh.element_count() {
                let f = local_free(e);
                for r in f.iter().flatten() {
                    for c in f.iter().flatten() {
                        if r >= c {
                            emit(*c as usize, *r);
                        }
                    }
                }
            }
        });
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(rows.len());
        col_ptr.push(0u32);
        for c in 0..n {
            let col = &mut rows[starts[c] as usize..starts[c + 1] as usize];
            col.sort_unstable();
            let first = row_idx.len();
            for &r in col.iter() {
                if row_idx.len() == first || row_idx.last() != Some(&r) {
                    row_idx.push(r);
                }
            }
            col_ptr.push(row_idx.len() as u32);
        }
        row_idx.shrink_to_fit();
        let position = |r: u32, c: u32| -> u32 {
            let (s, e) = (col_ptr[c as usize] as usize, col_ptr[c as usize + 1] as usize);
            s as u32 + row_idx[s..e].binary_search(&r).expect("entry in pattern") as u32
        };
        let diagonal = (0..n as u32).map(|i| position(i, i)).collect();
        let mut scatter = Vec::with_capacity(mesh.element_count() * ndof * ndof);
        for e in 0..mesh.element_count() {
            let f = local_free(e);
            for r in &f {
                for c in &f {
                    scatter.push(match (r, c) {
                        (Some(r), Some(c)) if r >= c => position(*r, *c),
                        _ => SKIP,
                    });
                }
            }
        }
        Self { n, col_ptr, row_idx, diagonal, scatter, element_dofs: ndof }
    }

    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    pub fn element_scatter(&self, e: usize) -> &[u32] {
        let m = self.element_dofs * self.element_dofs;
        &self.scatter[e * m..(e + 1) * m]
    }
}

/// Entries per element of the element results (`element_force_tangent`'s output): `ndof`
/// forces, then the upper triangle of the symmetric `ndof x ndof` tangent packed row by row
/// ([`packed_index`]).
pub fn element_out_stride(element_dofs: usize) -> usize {
    element_dofs + element_dofs * (element_dofs + 1) / 2
}

/// Where tangent entry (`row`, `col`) of an element with `ndof` dofs lies in the packed upper
/// triangle (either order: the tangent is symmetric).
pub fn packed_index(ndof: usize, row: usize, col: usize) -> usize {
    let (r, c) = (row.min(col), row.max(col));
    r * ndof - r * (r + 1) / 2 + c
}

/// For every stiffness non-zero and every dof, the element-result entries that sum into it, in
/// element order: the kernels gather instead of scattering, so no two invocations write the same
/// value and the sums are deterministic. Built once per body.
#[derive(Debug, Clone)]
pub struct GatherMap {
    /// `csr[csr_start[k]..csr_start[k + 1]]` are the tangent entries of non-zero `k`.
    pub csr_start: Vec<u32>,
    pub csr: Vec<u32>,
    /// `dof[dof_start[d]..dof_start[d + 1]]` are the force entries of dof `d`.
    pub dof_start: Vec<u32>,
    pub dof: Vec<u32>,
}

impl GatherMap {
    pub fn new(mesh: &Mesh, dim: usize, pattern: &StiffnessPattern) -> Self {
        let ndof = pattern.element_dofs;
        let stride = element_out_stride(ndof);
        let (csr_start, csr) = flattened(pattern.nnz(), |emit| {
            for e in 0..mesh.element_count() {
                let base = e * stride;
                for (local, &idx) in pattern.element_scatter(e).iter().enumerate() {
                    if idx != SKIP {
                        emit(idx as usize, (base + ndof + packed_index(ndof, local / ndof, local % ndof)) as u32);
                    }
                }
            }
        });
        let (dof_start, dof) = flattened(mesh.nodes.len() * dim, |emit| {
            for e in 0..mesh.element_count() {
                for (a, &node) in mesh.element(e).iter().enumerate() {
                    for i in 0..dim {
                        emit(node as usize * dim + i, (e * stride + a * dim + i) as u32);
                    }
                }
            }
        });
        Self { csr_start, csr, dof_start, dof }
    }
}

/// The lists of values per target, flattened (start offsets, values): `each` gives the (target,
/// value) pairs, in the order each list keeps, to the function it is passed. It runs twice,
/// once to count and once to fill, so that building the lists allocates two vectors, not one
/// per target (a grain packing has millions of targets).
fn flattened(targets: usize, each: impl Fn(&mut dyn FnMut(usize, u32))) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; targets + 1];
    each(&mut |target, _| start[target + 1] += 1);
    for t in 0..targets {
        start[t + 1] += start[t];
    }
    let mut next = start[..targets].to_vec();
    let mut flat = vec![0u32; start[targets] as usize];
    each(&mut |target, value| {
        flat[next[target] as usize] = value;
        next[target] += 1;
    });
    (start, flat)
}
