//! The CPU twins of the WGSL kernels, one per file of `shaders/`, with the same names. Each is
//! written to read like its shader; `--backend cpu` runs them, and they are the oracle of the
//! GPU parity tests and the CPU side of the benchmarks.
//!
//! | kernel | CPU twin |
//! |---|---|
//! | `element_force_tangent` | [`element_force_tangent`] |
//! | `element_energy` | [`element_energy`] |
//! | `assemble_csr` | [`assemble_csr`] |
//! | `assemble_residual` | [`assemble_residual`] |
//! | `uzawa_step` | [`uzawa_step`] |
//! | `uzawa_sweep` | [`uzawa_sweep`] |
//! | `uzawa_judge`, `uzawa_solve` | [`uzawa_judge`], [`uzawa_solve`] |
//! | `planar_unpack` | [`planar_unpack`] |
//! | `newton_update`, `newton_judge`, `newton_compact` (`main`, `host`, `refactor`), `newton_finish`, `newton_summary`, `newton_tally`, `newton_invert` (`main`, `refactor`) | [`newton_update`], [`newton_judge`], [`newton_compact`], [`newton_compact_host`], [`newton_compact_refactor`], [`newton_finish`], [`newton_summary`], [`newton_tally`], [`newton_invert`], [`newton_invert_refactor`] |
//! | `newton_contact` (`prepare`, `forces`, `judge`, `first_forces`, `first_judge`, `delassus`, `rebuild`) | [`newton_contact_prepare`], [`newton_contact_forces`], [`newton_contact_judge`], [`newton_contact_first_forces`], [`newton_contact_first_judge`], [`newton_contact_delassus`], [`newton_contact_rebuild`] |
//! | `step_begin`, `step_commit` | [`step_begin`], [`step_commit`] |
//! | `scatter_reals` | [`scatter_reals`] |
//! | `peak_copy` | [`peak_copy`] |
//! | `peak_fma` | [`peak_fma`] |

mod newton;
mod step;
mod uzawa;

pub use crate::contact::law::uzawa_step;
pub use crate::contact::uzawa::uzawa_sweep;
pub use crate::element::{element_energy, element_force_tangent};
pub use newton::{
    newton_compact, newton_compact_host, newton_compact_refactor, newton_contact_delassus, newton_contact_first_forces, newton_contact_first_judge, newton_contact_forces, newton_contact_judge, newton_contact_prepare, newton_contact_rebuild,
    newton_finish, newton_invert, newton_invert_refactor, newton_judge, newton_summary, newton_tally, newton_update, SummaryInputs,
};
pub use step::{step_begin, step_commit, Adoption};
pub use uzawa::{planar_unpack, uzawa_judge, uzawa_solve};

use crate::assembly::element_out_stride;
use crate::element::{ElementError, ElementOutput, Formulation, ReferenceGeometry};
use crate::gpu::types::{Coefficients, DofOut, DofStep, PEAK_FMA_STEPS};
use crate::material::{Hyperelastic, Relaxation};
use crate::mesh::Mesh;
use crate::precision::Real;
use rayon::prelude::*;

/// Elements per task of [`dispatch_element_force_tangent`] on the thread pool (the CPU's
/// workgroup): large enough that scheduling costs nothing next to the elements.
const ELEMENTS_PER_TASK: usize = 128;

/// The grid of `element_force_tangent`: one call per element at displacement `u` (every dof),
/// into `results` (`element_out_stride` entries per element; forces only without the tangent),
/// on every thread of the pool, with the body's viscoelastic `relaxation` if it has one. The
/// error names the first element that failed.
#[allow(clippy::too_many_arguments)]
pub fn dispatch_element_force_tangent<M: Hyperelastic + Sync>(
    model: &M,
    mesh: &Mesh,
    geometry: &ReferenceGeometry,
    formulation: Formulation,
    relaxation: Option<Relaxation>,
    u: &[Real],
    with_tangent: bool,
    results: &mut [Real],
) -> Result<(), (usize, ElementError)> {
    let dim = mesh.dim();
    let ndof = mesh.kind.nodes() * dim;
    let stride = element_out_stride(ndof);
    let failures = results.par_chunks_mut(stride * ELEMENTS_PER_TASK).enumerate().filter_map(|(task, block)| {
        let (mut scratch, mut ue) = (ElementOutput::default(), Vec::with_capacity(mesh.kind.nodes()));
        for (k, out) in block.chunks_mut(stride).enumerate() {
            let e = task * ELEMENTS_PER_TASK + k;
            mesh.element_displacements_into(u, e, &mut ue);
            let relaxation = relaxation.map(|r| r.element(e, geometry.points_per_element));
            if let Err(error) = element_force_tangent(model, geometry.element_points(e), &ue, dim, formulation, relaxation, with_tangent, &mut scratch) {
                return Some((e, error));
            }
            out[..ndof].copy_from_slice(&scratch.force);
            if with_tangent {
                // The upper triangle, row by row: the packed layout of `element_out_stride`.
                let mut k = ndof;
                for row in 0..ndof {
                    out[k..k + ndof - row].copy_from_slice(&scratch.tangent[row * ndof + row..(row + 1) * ndof]);
                    k += ndof - row;
                }
            }
        }
        None
    });
    match failures.min_by_key(|(e, _)| *e) {
        Some(failure) => Err(failure),
        None => Ok(()),
    }
}

/// Stiffness values of the sparse pattern: for every non-zero `k`, the sum of `factor *` the
/// element tangent entries that the gather map lists for it (`gather[gather_start[k]..]`).
pub fn assemble_csr(element_out: &[Real], gather_start: &[u32], gather: &[u32], coefficients: Coefficients<Real>, values: &mut [Real]) {
    values.par_iter_mut().with_min_len(PER_TASK).enumerate().for_each(|(k, value)| {
        let mut sum = 0.0;
        for j in gather_start[k]..gather_start[k + 1] {
            sum += coefficients.factor * element_out[gather[j as usize] as usize];
        }
        *value = sum;
    });
}

/// Internal force of every dof (the element forces the gather map lists for it) and the
/// theta-method residual `g = c1 m (u - u_pred) - (1-ξ)(f_ext - f_int,t) - ξ (f_ext - f_int)`.
pub fn assemble_residual(element_out: &[Real], gather_start: &[u32], gather: &[u32], coefficients: Coefficients<Real>, u: &[Real], step: &[DofStep<Real>], dof_out: &mut [DofOut<Real>]) {
    dof_out.par_iter_mut().with_min_len(PER_TASK).enumerate().for_each(|(d, out)| {
        let f = gather_sum(element_out, gather_start, gather, d);
        *out = DofOut { f_int: f, g: step[d].residual(coefficients, u[d], f) };
    });
}

/// Outputs per task of the gather kernels on the thread pool.
const PER_TASK: usize = 8192;

/// The sum of the entries a gather map lists for output `k`, in its order.
fn gather_sum(element_out: &[Real], gather_start: &[u32], gather: &[u32], k: usize) -> Real {
    let mut f = 0.0;
    for j in gather_start[k]..gather_start[k + 1] {
        f += element_out[gather[j as usize] as usize];
    }
    f
}

/// `scatter_reals`: each of `values` into `target` at its index.
pub fn scatter_reals(indices: &[u32], values: &[Real], destination: &mut [Real]) {
    for (&i, &v) in indices.iter().zip(values) {
        destination[i as usize] = v;
    }
}

/// `peak_copy`: every value of `source` into `destination` (the kernel copies vec4s).
pub fn peak_copy(source: &[Real], destination: &mut [Real]) {
    destination.par_iter_mut().with_min_len(PER_TASK).zip(source).for_each(|(d, s)| *d = *s);
}

/// `peak_fma`: per value, eight independent chains of [`PEAK_FMA_STEPS`] multiply-adds from
/// it, summed as the kernel sums them (separate multiply and add: the target need not have
/// FMA, so the results agree with the kernel's to round-off, not bit for bit).
pub fn peak_fma(values: &mut [Real]) {
    values.par_iter_mut().with_min_len(PER_TASK).for_each(|v| {
        let x = *v;
        let mut a = [x, x + 1.0, x + 2.0, x + 3.0];
        let mut b = a.map(|y| y + 0.5);
        for _ in 0..PEAK_FMA_STEPS {
            a = a.map(|y| y * 0.999 + 0.001);
            b = b.map(|y| y * 0.999 + 0.001);
        }
        *v = (a[0] + a[1]) + (a[2] + a[3]) + ((b[0] + b[1]) + (b[2] + b[3]));
    });
}
