//! `newton_iteration`: one Newton iteration of many small bodies that keep their factorisation
//! (grains in free flight), as the device takes it (`newton_update`, the `forces` entry point,
//! `assemble_residual`, `newton_judge`, `newton_compact`: one [`GpuWorld::newton`] call of one
//! increment, its uploads and read-back included) and as the CPU twins of those kernels take it,
//! body after body on the thread pool.

use super::{blockwise_error, time_calls, BenchCase, BenchOptions, BenchRow};
use crate::assembly::{element_out_stride, StiffnessPattern};
use crate::cpu;
use crate::element::Formulation;
use crate::gpu::peak::Peaks;
use crate::gpu::types::{Active, DofOut, MemberRange, NewtonMember, NewtonState, MODE_FORCES, NEWTON_ITERATING};
use crate::gpu::{Gpu, GpuError, GpuWorld, NewtonCall};
use crate::material::{BlatzKo, Model};
use crate::mesh::ElementKind;
use crate::precision::{Precision, Real};
use crate::solver::PhaseTimes;
use rayon::prelude::*;
use std::sync::Arc;

/// The row's name.
pub const NEWTON_ITERATION: &str = "newton_iteration";
/// Elements of each body: a grain-sized Tri3 square (81 nodes, 162 free dofs).
const BODY_ELEMENTS: usize = 128;
/// The bodies' `K̄⁻¹` (the same for all: they are copies) stay within this many bytes.
const INVERSE_BYTES: usize = 256 << 20;

/// The rows: `elements / 128` bodies (at least one), on the CPU twins and on each f64 device.
/// The roofline columns count the product with `K̄⁻¹` (`2 n²` operations and `n²` reals read
/// per body), the iteration's largest traffic.
pub(super) fn newton_rows(options: &BenchOptions, gpus: &[Arc<Gpu>], peaks: &[Peaks], row: &mut impl FnMut(BenchRow)) -> Result<(), GpuError> {
    let case = BenchCase::new(ElementKind::Tri3, Formulation::Displacement, Model::BlatzKo(BlatzKo { g: 1000.0 }), BODY_ELEMENTS);
    let n = case.dofs.free_count;
    let bodies = (options.elements / BODY_ELEMENTS).clamp(1, INVERSE_BYTES / (n * n * 8));
    let inverse = effective_inverse(&case);
    let free: Vec<u32> = case.dofs.free_pairs().map(|(d, _)| d as u32).collect();
    let member = NewtonMember { free_count: n as u32, budget: 1, ..NewtonMember::default() };
    let start = vec![0.0; case.u.len()];
    let first = residual(&case, &case.u);
    let residual0 = free.iter().map(|&d| first[d as usize].g.powi(2)).sum::<Real>().sqrt();
    let initial = NewtonState { status: NEWTON_ITERATING, residual: residual0, previous_residual: residual0, ..NewtonState::default() };
    let make = |backend: String, timing, traffic, error| BenchRow::new(NEWTON_ITERATION, "tri3", "blatz_ko", bodies, backend, timing, traffic, error);
    let cost = (bodies as f64 * (n * n * 8) as f64, bodies as f64 * 2.0 * (n * n) as f64);

    let mut reference: Vec<(Vec<Real>, Vec<DofOut<Real>>)> = vec![(case.u.clone(), first.clone()); bodies];
    let range = [MemberRange { dof_start: 0, dofs: case.u.len() as u32, ..MemberRange::default() }];
    let no_contact = vec![0.0; case.u.len()];
    let t = time_calls(options.min_time, || {
        reference.par_iter_mut().for_each(|(u, out)| {
            u.copy_from_slice(&case.u);
            let mut state = [initial];
            cpu::newton_update(&inverse, &free, &[member], &mut state, &first, u, &range, &no_contact, 0);
            *out = residual(&case, u);
            cpu::newton_judge(&free, &[member], &mut state, out, u, &start, &case.step, case.coefficients, &[u32::MAX; 2], &range, &no_contact, 0);
            let call = [Active { member: 0, mode: MODE_FORCES }];
            cpu::newton_compact(&call, &state, &mut [Active::default()], call.len());
        });
    });
    row(make("cpu f64".into(), t, 0, 0.0));

    for (gpu, peaks) in gpus.iter().zip(peaks).filter(|(g, _)| g.precision == Precision::F64) {
        let bodies_on_device: Vec<_> = (0..bodies).map(|_| case.world_body()).collect();
        let mut world = GpuWorld::new(gpu.clone(), &bodies_on_device)?;
        world.set_step_inputs(&(0..bodies).map(|b| (b, &case.step[..])).collect::<Vec<_>>());
        if !(0..bodies).all(|b| world.newton_capable(b)) {
            continue;
        }
        let mut states: Vec<(Vec<Real>, Vec<DofOut<Real>>)> = vec![(case.u.clone(), first.clone()); bodies];
        let mut result = Ok(());
        let mut iterate = |world: &mut GpuWorld| {
            let mut calls: Vec<NewtonCall> = states
                .iter_mut()
                .enumerate()
                .map(|(b, (u, out))| {
                    u.copy_from_slice(&case.u);
                    out.copy_from_slice(&first);
                    let inverse = (!world.newton_inverse_current(b, 1)).then(|| crate::gpu::Inverse::Dense(inverse.clone()));
                    NewtonCall {
                        body: b,
                        taken: 0,
                        factor: 1,
                        inverse,
                        member,
                        residual: Some(residual0),
                        u,
                        dof_out: out,
                        u_start: &start,
                        inputs: &case.step,
                        contact_force: None,
                        keep: false,
                        positions: false,
                        summary: None,
                        outcome: NewtonState::default(),
                        strain_energy: None,
                        failure: None,
                        tangent_held: false,
                    }
                })
                .collect();
            if let Err(e) = world.newton(&mut calls, &mut [], &mut [], &mut [], case.coefficients, (2, 1.0), None, &mut PhaseTimes::default()) {
                result = Err(e);
            }
        };
        // The inverses go up once, as after a factorisation; the timed calls move what an
        // iteration moves.
        iterate(&mut world);
        world.take_traffic();
        let t = time_calls(options.min_time, || iterate(&mut world));
        result?;
        let traffic = world.take_traffic().total();
        let error = states.iter().zip(&reference).map(|((u, _), (expected, _))| blockwise_error(u, expected, u.len())).fold(0.0, f64::max);
        row(make(format!("gpu {}", gpu.precision.name()), t, traffic, error).with_roofline(cost, peaks));
    }
    Ok(())
}

/// Forces and residuals of the case's body at `u` on the CPU twins.
fn residual(case: &BenchCase, u: &[Real]) -> Vec<DofOut<Real>> {
    let mut results = vec![0.0; case.elements() * element_out_stride(case.pattern.element_dofs)];
    cpu::dispatch_element_force_tangent(&case.model, &case.mesh, &case.geometry, case.formulation, None, u, false, &mut results).expect("valid deformation");
    let mut out = vec![DofOut::default(); u.len()];
    let g = &case.gather;
    cpu::assemble_residual(&results, &g.dof_start, &g.dof, case.coefficients, u, &case.step, &mut out);
    out
}

/// `K̄ = ξ K + c1 M` of the case's free dofs at its displacement, inverted densely (row by
/// row; what `Body::effective_inverse` gives from faer's factors).
fn effective_inverse(case: &BenchCase) -> Vec<Real> {
    let mut results = vec![0.0; case.results_len()];
    case.cpu_elements(&mut results);
    let mut values = vec![0.0; case.pattern.nnz()];
    cpu::assemble_csr(&results, &case.gather.csr_start, &case.gather.csr, case.coefficients, &mut values);
    let mut diagonal = vec![0.0; case.pattern.n];
    for (d, f) in case.dofs.free_pairs() {
        diagonal[f] = case.coefficients.c1 * case.step[d].mass;
    }
    dense_inverse(&case.pattern, &values, &diagonal)
}

/// The inverse, row by row, of the symmetric matrix whose lower triangle `values` fills
/// `pattern`, with `diagonal` added to its diagonal: `K̄⁻¹` from `ξ K` and `c1 M`, as
/// `Body::effective_inverse` gives it (the oracle of the device Newton iterations).
pub fn dense_inverse(pattern: &StiffnessPattern, values: &[Real], diagonal: &[Real]) -> Vec<Real> {
    let mut k = values.to_vec();
    for (&at, &x) in pattern.diagonal.iter().zip(diagonal) {
        k[at as usize] += x;
    }
    crate::solver::linear::dense_inverse(&pattern.col_ptr, &pattern.row_idx, &k).expect("K̄ is positive definite")
}
