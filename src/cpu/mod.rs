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
//! | `reduce_sum` | [`reduce_sum`] |
//! | `uzawa_step` | [`uzawa_step`] |

pub use crate::contact::law::uzawa_step;
pub use crate::element::{element_energy, element_force_tangent};

use crate::assembly::element_out_stride;
use crate::element::{ElementError, ElementOutput, ReferenceGeometry};
use crate::gpu::types::{Coefficients, DofOut, DofStep};
use crate::material::Hyperelastic;
use crate::mesh::Mesh;
use crate::precision::Real;

/// The grid of `element_force_tangent`: one call per element at displacement `u` (every dof),
/// into `results` (`element_out_stride` entries per element; forces only without the tangent).
/// The error names the first element that failed.
pub fn dispatch_element_force_tangent<M: Hyperelastic>(
    model: &M,
    mesh: &Mesh,
    geometry: &ReferenceGeometry,
    u: &[Real],
    with_tangent: bool,
    scratch: &mut ElementOutput,
    results: &mut [Real],
) -> Result<(), (usize, ElementError)> {
    let dim = mesh.dim();
    let ndof = mesh.kind.nodes() * dim;
    let stride = element_out_stride(ndof);
    let mut ue = Vec::with_capacity(mesh.kind.nodes());
    for e in 0..mesh.element_count() {
        mesh.element_displacements_into(u, e, &mut ue);
        element_force_tangent(model, geometry.element_points(e), &ue, dim, with_tangent, scratch).map_err(|error| (e, error))?;
        let out = &mut results[e * stride..(e + 1) * stride];
        out[..ndof].copy_from_slice(&scratch.force);
        if with_tangent {
            out[ndof..].copy_from_slice(&scratch.tangent);
        }
    }
    Ok(())
}

/// Stiffness values of the sparse pattern: for every non-zero `k`, the sum of `factor *` the
/// element tangent entries that the gather map lists for it (`gather[gather_start[k]..]`).
pub fn assemble_csr(element_out: &[Real], gather_start: &[u32], gather: &[u32], coefficients: Coefficients<Real>, values: &mut [Real]) {
    for (k, value) in values.iter_mut().enumerate() {
        let mut sum = 0.0;
        for j in gather_start[k]..gather_start[k + 1] {
            sum += coefficients.factor * element_out[gather[j as usize] as usize];
        }
        *value = sum;
    }
}

/// Internal force of every dof (the element forces the gather map lists for it) and the
/// theta-method residual `g = c1 m (u - u_pred) - (1-ξ)(f_ext - f_int,t) - ξ (f_ext - f_int)`.
pub fn assemble_residual(
    element_out: &[Real],
    gather_start: &[u32],
    gather: &[u32],
    coefficients: Coefficients<Real>,
    u: &[Real],
    step: &[DofStep<Real>],
    dof_out: &mut [DofOut<Real>],
) {
    for (d, out) in dof_out.iter_mut().enumerate() {
        let f = gather_sum(element_out, gather_start, gather, d);
        let xi = coefficients.factor;
        let s = step[d];
        let inertia = coefficients.c1 * s.mass * (u[d] - s.u_pred);
        *out = DofOut { f_int: f, g: inertia - (1.0 - xi) * (s.f_ext - s.f_int_t) - xi * (s.f_ext - f) };
    }
}

/// The sum of the entries a gather map lists for output `k`, in its order.
fn gather_sum(element_out: &[Real], gather_start: &[u32], gather: &[u32], k: usize) -> Real {
    let mut f = 0.0;
    for j in gather_start[k]..gather_start[k + 1] {
        f += element_out[gather[j as usize] as usize];
    }
    f
}

/// Width of one block of `reduce_sum` (its workgroup size).
pub const REDUCE_WIDTH: usize = 256;

/// The sum of `input` in the order of the `reduce_sum` kernel: blocks of [`REDUCE_WIDTH`] values
/// summed by halving, pass after pass, until one value is left.
pub fn reduce_sum(input: &[Real]) -> Real {
    let mut values = input.to_vec();
    loop {
        values = values.chunks(REDUCE_WIDTH).map(reduce_block).collect();
        if values.len() <= 1 {
            return values.first().copied().unwrap_or(0.0);
        }
    }
}

/// One workgroup of `reduce_sum`: pairs at distance 128, 64, ..., 1.
fn reduce_block(block: &[Real]) -> Real {
    let mut scratch = [0.0; REDUCE_WIDTH];
    scratch[..block.len()].copy_from_slice(block);
    let mut width = REDUCE_WIDTH / 2;
    while width > 0 {
        for lane in 0..width {
            scratch[lane] += scratch[lane + width];
        }
        width /= 2;
    }
    scratch[0]
}
