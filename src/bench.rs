//! `bifirst bench`: every kernel on a deformed mesh, on the CPU (its twin, the reference) and on
//! a GPU adapter in f64 and f32: time per call, throughput, bytes moved per call and the largest
//! relative error against the CPU in f64. The criterion benches use the same cases.

use crate::assembly::{element_out_stride, DofMap, GatherMap, StiffnessPattern};
use crate::contact::uzawa::{self, Acceleration, Colours, Delassus, Fallback, Local, NodalMap, Problem, Sweep};
use crate::cpu;
use crate::element::{Formulation, ReferenceGeometry};
use crate::gpu::peak::{measure as measure_peaks, Peaks, FMA_FLOPS_PER_VALUE};
use crate::gpu::types::{Coefficients, DofOut, DofStep};
use crate::gpu::uzawa_step::{UzawaPoint, UzawaStepKernel};
use crate::gpu::uzawa_sweep::UzawaSweeps;
use crate::gpu::{Evaluation, Gpu, GpuError, GpuWorld, WorldKernel};
use crate::material::{Entry, Model};
use crate::mesh::{generate, ElementKind, Mesh};
use crate::precision::{Precision, Real};
use crate::solver::PhaseTimes;
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

mod newton;

pub use newton::dense_inverse;

/// Every material model with its example parameters (`material::Law::EXAMPLE`), as benchmarks use them.
pub fn bench_models() -> Vec<Model> {
    Model::ENTRIES.iter().map(Entry::example_model).collect()
}

pub const KINDS: [ElementKind; 4] = [ElementKind::Tri3, ElementKind::Quad4, ElementKind::Tet4, ElementKind::Hex8];

/// The element kernels the bench measures: every kind as a displacement element, and the F-bar
/// element of Quad4 and Hex8.
pub fn bench_elements() -> Vec<(ElementKind, Formulation)> {
    KINDS.iter().flat_map(|&kind| std::iter::once((kind, Formulation::Displacement)).chain(Formulation::fbar_applies(kind).then_some((kind, Formulation::Fbar)))).collect()
}

/// An element's name in the bench rows: the kind, with `+fbar` for the F-bar element.
pub fn element_label(kind: ElementKind, formulation: Formulation) -> String {
    match formulation {
        Formulation::Displacement => kind.name().to_string(),
        Formulation::Fbar => format!("{}+fbar", kind.name()),
    }
}

/// A body's data for the kernels: a mesh of about `elements` elements of `kind` in a smooth,
/// moderate deformation (a twist and a stretch), with the step inputs of `assemble_residual`.
pub struct BenchCase {
    pub mesh: Mesh,
    pub model: Model,
    pub formulation: Formulation,
    pub geometry: ReferenceGeometry,
    pub dofs: DofMap,
    pub pattern: StiffnessPattern,
    pub gather: GatherMap,
    pub u: Vec<Real>,
    pub step: Vec<DofStep<Real>>,
    pub coefficients: Coefficients<Real>,
}

impl BenchCase {
    pub fn new(kind: ElementKind, formulation: Formulation, model: Model, elements: usize) -> Self {
        let n = elements as f64;
        let mesh = match kind {
            ElementKind::Tri3 => generate::rectangle([0.0; 2], [1.0; 2], [side(n / 2.0, 2), side(n / 2.0, 2)], kind),
            ElementKind::Quad4 => generate::rectangle([0.0; 2], [1.0; 2], [side(n, 2); 2], kind),
            ElementKind::Tet4 => generate::cuboid([0.0; 3], [1.0; 3], [side(n / 6.0, 3); 3], kind),
            ElementKind::Hex8 => generate::cuboid([0.0; 3], [1.0; 3], [side(n, 3); 3], kind),
        };
        let dim = kind.dim();
        let u: Vec<Real> = mesh
            .nodes
            .iter()
            .flat_map(|x| {
                let d = [0.1 * x[0] + 0.05 * x[1] * x[2], -0.03 * x[1] + 0.04 * x[0] * x[2], 0.02 * x[2] - 0.05 * x[0] * x[1]];
                d.into_iter().take(dim)
            })
            .collect();
        let dofs = DofMap::new(dim, &vec![false; u.len()]);
        let pattern = StiffnessPattern::new(&mesh, &dofs);
        let gather = GatherMap::new(&mesh, dim, &pattern);
        let geometry = ReferenceGeometry::new(&mesh).expect("generated meshes are valid");
        let step = u.iter().enumerate().map(|(d, &x)| DofStep { mass: 1.0 + (d % 7) as Real * 0.1, u_pred: 0.9 * x, f_int_t: 0.0, f_ext: 0.1 }).collect();
        Self { mesh, model, formulation, geometry, dofs, pattern, gather, u, step, coefficients: Coefficients { factor: 0.5, c1: 1e4, motion: 0.0 } }
    }

    pub fn elements(&self) -> usize {
        self.mesh.element_count()
    }

    /// `element_force_tangent` of every element on the CPU.
    pub fn cpu_elements(&self, results: &mut [Real]) {
        cpu::dispatch_element_force_tangent(&self.model, &self.mesh, &self.geometry, self.formulation, None, &self.u, true, results).expect("valid deformation");
    }

    /// The CPU twin of the `forces` entry point: each element's forces, no tangent.
    pub fn cpu_forces(&self, results: &mut [Real]) {
        cpu::dispatch_element_force_tangent(&self.model, &self.mesh, &self.geometry, self.formulation, None, &self.u, false, results).expect("valid deformation");
    }

    pub fn results_len(&self) -> usize {
        self.elements() * element_out_stride(self.pattern.element_dofs)
    }

    /// What a GPU world takes of the case's body.
    pub fn world_body(&self) -> crate::gpu::WorldBody<'_> {
        crate::gpu::WorldBody { mesh: &self.mesh, geometry: &self.geometry, model: &self.model, formulation: self.formulation, pattern: &self.pattern, gather: &self.gather, dofs: &self.dofs, viscous: false }
    }

    /// A GPU world of this one body, with its step inputs uploaded.
    pub fn on(&self, gpu: &Arc<Gpu>) -> Result<GpuWorld, GpuError> {
        let mut world = GpuWorld::new(gpu.clone(), &[self.world_body()])?;
        world.set_step_inputs(&[(0, &self.step[..])]);
        world.take_traffic();
        Ok(world)
    }

    /// The displacement with every entry one ulp away: a Newton iteration's next state, for
    /// timings that must upload it (a world sends only displacements that changed).
    pub fn nudged(&self) -> Vec<Real> {
        self.u.iter().map(|x| Real::from_bits(x.to_bits() + 1)).collect()
    }

    /// One device pass over the case's body at `u`: forces and residual, with the tangent and
    /// the stiffness values if `tangent`. The error names a rejected state.
    pub fn evaluate_on(&self, world: &mut GpuWorld, u: &[Real], tangent: bool, values: &mut [Real], dof_out: &mut [DofOut<Real>]) -> Result<(), GpuError> {
        let mut list = [Evaluation { body: 0, u, tangent, values, dof_out: Some(dof_out), failure: None }];
        world.evaluate(&mut list, self.coefficients, &mut PhaseTimes::default())?;
        match list[0].failure {
            None => Ok(()),
            Some(f) => Err(GpuError::Kernel { kernel: "element_force_tangent".into(), message: format!("the bench state was rejected: {f:?}") }),
        }
    }
}

fn side(n: f64, dim: i32) -> usize {
    (n.powf(1.0 / dim as f64).round() as usize).max(1)
}

/// One line of the table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BenchRow {
    pub kernel: String,
    pub element: String,
    pub material: String,
    /// Elements, or contact points for `uzawa_step`, `uzawa_sweep` and `uzawa_solve`.
    pub items: usize,
    /// `cpu f64`, `gpu f64` or `gpu f32`.
    pub backend: String,
    pub seconds_per_call: f64,
    pub items_per_second: f64,
    /// Bytes between host and device per call (0 on the CPU).
    pub bytes_per_call: u64,
    /// Largest relative error against the CPU in f64 (max norm, per element for element
    /// results, over the body for assembled values).
    pub max_relative_error: f64,
    /// Device-memory traffic and arithmetic achieved ([`kernel_cost`] over the time per call),
    /// on a GPU, for the kernels with a cost model.
    pub gbytes_per_second: Option<f64>,
    pub gflops_per_second: Option<f64>,
    /// Those as fractions of the adapter's measured peaks (`peak_copy`, `peak_fma`).
    pub peak_bandwidth_fraction: Option<f64>,
    pub peak_flops_fraction: Option<f64>,
}

/// What to run.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// About this many elements (and 4x as many contact points) per case.
    pub elements: usize,
    /// Only kernels whose name contains this.
    pub kernel: Option<String>,
    /// Only element rows whose element (`hex8`, `quad4+fbar`) contains this.
    pub element: Option<String>,
    /// Only element rows whose material (`blatz_ko`, `ogden`) contains this.
    pub material: Option<String>,
    /// Seconds of calls per measurement (at least three calls).
    pub min_time: f64,
    /// Every element with every material; otherwise, unless `material` filters, each element
    /// with the paper's Blatz-Ko foam only (the models differ in their stress, not in the
    /// kernels' data flow: `--all` measures them).
    pub all: bool,
}

/// Seconds per call, and the number of calls made (the warm-up included).
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    pub per_call: f64,
    pub calls: u64,
}

/// Mean seconds per call over at least three calls and `min_time`, after one warm-up call.
pub fn time_calls(min_time: f64, mut call: impl FnMut()) -> Timing {
    call();
    let start = Instant::now();
    let mut calls = 0;
    while calls < 3 || start.elapsed().as_secs_f64() < min_time {
        call();
        calls += 1;
    }
    Timing { per_call: start.elapsed().as_secs_f64() / calls as f64, calls: calls + 1 }
}

/// `max |a - b| / max |b|` over each block of `stride` entries.
fn blockwise_error(a: &[Real], b: &[Real], stride: usize) -> f64 {
    a.chunks(stride)
        .zip(b.chunks(stride))
        .map(|(x, y)| {
            let scale = y.iter().fold(Real::MIN_POSITIVE, |m, v| m.max(v.abs()));
            x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0, Real::max) / scale
        })
        .fold(0.0, Real::max)
}

// The element rows' kernel names: `--kernel` matches a part of these, the whole name included.
const FORCE_TANGENT: &str = "element_force_tangent";
/// The kernel's `forces` entry point alone: what a Newton iteration that keeps its
/// factorisation evaluates.
const FORCES: &str = "element_force_tangent/forces";
const ASSEMBLY: &str = "assemble_csr+assemble_residual";
const EVALUATE: &str = "evaluate (all kernels, transfers)";
const ENERGY: &str = "element_energy";

/// Every kernel row's name, in the order the bench measures them.
const KERNELS: [&str; 11] = ["peak_copy", "peak_fma", FORCE_TANGENT, FORCES, ASSEMBLY, EVALUATE, ENERGY, newton::NEWTON_ITERATION, "uzawa_step", "uzawa_sweep", "uzawa_solve"];

/// A filter that matches no kernel, element or material is a mistake, said before anything
/// runs (an empty table with exit 0 read as a benchmark that measured nothing).
pub fn check_filters(options: &BenchOptions) -> Result<(), String> {
    let elements: Vec<String> = bench_elements().into_iter().map(|(k, f)| element_label(k, f)).collect();
    let materials: Vec<&str> = bench_models().iter().map(|m| m.name()).collect();
    let kernels: Vec<String> = KERNELS.iter().map(|k| k.to_string()).collect();
    for (flag, filter, names) in [("--kernel", &options.kernel, kernels), ("--element", &options.element, elements), ("--material", &options.material, materials.iter().map(|m| m.to_string()).collect())] {
        if let Some(f) = filter {
            if !names.iter().any(|n| n.contains(f.as_str())) {
                return Err(format!("{flag} `{f}` matches none of: {}", names.join(", ")));
            }
        }
    }
    Ok(())
}

fn wanted(options: &BenchOptions, kernel: &str) -> bool {
    options.kernel.as_ref().is_none_or(|k| kernel.contains(k.as_str()))
}

/// The CPU reference of a case: element results, stiffness values, residual and energy.
struct Reference {
    results: Vec<Real>,
    values: Vec<Real>,
    dof_out: Vec<DofOut<Real>>,
    energy: Real,
}

/// Elements of the case's kind that one device buffer can hold the element results of.
fn fitting_elements(gpu: &Gpu, case: &BenchCase) -> usize {
    let limits = gpu.device.limits();
    let largest = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) as usize;
    largest / (element_out_stride(case.pattern.element_dofs) * gpu.precision.size())
}

/// The CPU twins' results on a case: what the GPU rows are compared with.
fn cpu_reference(case: &BenchCase) -> Reference {
    let mut reference = Reference { results: vec![0.0; case.results_len()], values: vec![0.0; case.pattern.nnz()], dof_out: vec![DofOut::default(); case.u.len()], energy: 0.0 };
    case.cpu_elements(&mut reference.results);
    let g = &case.gather;
    cpu::assemble_csr(&reference.results, &g.csr_start, &g.csr, case.coefficients, &mut reference.values);
    cpu::assemble_residual(&reference.results, &g.dof_start, &g.dof, case.coefficients, &case.u, &case.step, &mut reference.dof_out);
    reference.energy = element_energies(case).iter().sum();
    reference
}

fn element_energies(case: &BenchCase) -> Vec<Real> {
    (0..case.elements()).map(|e| cpu::element_energy(&case.model, case.geometry.element_points(e), &case.mesh.element_displacements(&case.u, e), case.mesh.dim(), case.formulation)).collect()
}

/// Runs the benchmark; `gpus` are the devices to compare with the CPU (f64 and/or f32).
/// `progress` hears of each case as it starts (the peaks, each element and material, the Newton
/// and Uzawa kernels).
pub fn run_bench(options: &BenchOptions, gpus: &[Arc<Gpu>], mut row: impl FnMut(BenchRow), mut progress: impl FnMut(&str)) -> Result<(), GpuError> {
    progress("peaks");
    let peaks = peak_rows(options, gpus, &mut row)?;
    let element_kernels = [FORCE_TANGENT, FORCES, ASSEMBLY, EVALUATE, ENERGY].iter().any(|k| wanted(options, k));
    let matches = |filter: &Option<String>, name: &str| filter.as_ref().is_none_or(|f| name.contains(f.as_str()));
    let models: Vec<Model> = bench_models().into_iter().filter(|m| matches(&options.material, m.name())).collect();
    let models = if options.all || options.material.is_some() { models } else { models.into_iter().take(1).collect() };
    for (kind, formulation) in bench_elements().into_iter().filter(|_| element_kernels) {
        let label = element_label(kind, formulation);
        if !matches(&options.element, &label) {
            continue;
        }
        for model in models.iter().cloned() {
            progress(&format!("{label} {}", model.name()));
            let case = BenchCase::new(kind, formulation, model, options.elements);
            let n = case.elements();
            let make = |kernel: &str, backend: String, timing: Timing, traffic: u64, error: f64| BenchRow::new(kernel, &label, case.model.name(), n, backend, timing, traffic, error);
            // The CPU twins, and the reference.
            let mut reference = Reference { results: vec![0.0; case.results_len()], values: vec![0.0; case.pattern.nnz()], dof_out: vec![DofOut::default(); case.u.len()], energy: 0.0 };
            let t = time_calls(options.min_time, || case.cpu_elements(&mut reference.results));
            if wanted(options, FORCE_TANGENT) {
                row(make(FORCE_TANGENT, "cpu f64".into(), t, 0, 0.0));
            }
            let g = &case.gather;
            let t = time_calls(options.min_time, || {
                cpu::assemble_csr(&reference.results, &g.csr_start, &g.csr, case.coefficients, &mut reference.values);
                cpu::assemble_residual(&reference.results, &g.dof_start, &g.dof, case.coefficients, &case.u, &case.step, &mut reference.dof_out);
            });
            if wanted(options, ASSEMBLY) {
                row(make(ASSEMBLY, "cpu f64".into(), t, 0, 0.0));
            }
            let t = time_calls(options.min_time, || reference.energy = element_energies(&case).iter().sum());
            if wanted(options, ENERGY) {
                row(make(ENERGY, "cpu f64".into(), t, 0, 0.0));
            }
            if wanted(options, FORCES) {
                let mut forces = vec![0.0; case.results_len()];
                let t = time_calls(options.min_time, || case.cpu_forces(&mut forces));
                row(make(FORCES, "cpu f64".into(), t, 0, 0.0));
            }
            for (gpu, peaks) in gpus.iter().zip(&peaks) {
                device_element_rows(options, gpu, peaks, (kind, formulation), (&case, &reference), &label, &mut row)?;
            }
        }
    }
    if wanted(options, newton::NEWTON_ITERATION) {
        progress(newton::NEWTON_ITERATION);
        newton::newton_rows(options, gpus, &peaks, &mut row)?;
    }
    if wanted(options, "uzawa_step") {
        progress("uzawa_step");
        uzawa_rows(options, gpus, &mut row)?;
    }
    if wanted(options, "uzawa_sweep") {
        progress("uzawa_sweep");
        uzawa_sweep_rows(options, gpus, &mut row)?;
    }
    if wanted(options, "uzawa_solve") {
        progress("uzawa_solve");
        uzawa_solve_rows(options, gpus, &mut row)?;
    }
    Ok(())
}

/// The rows of one element case's kernels on one device, each with its error against the CPU
/// twins' `reference`.
fn device_element_rows(options: &BenchOptions, gpu: &Arc<Gpu>, peaks: &Peaks, (kind, formulation): (ElementKind, Formulation), (case, reference): (&BenchCase, &Reference), label: &str, row: &mut impl FnMut(BenchRow)) -> Result<(), GpuError> {
    let backend = format!("gpu {}", gpu.precision.name());
    let real = gpu.precision.size();
    // A body the device cannot bind (its element results past the largest storage
    // buffer) is measured at the largest size that fits, against its own reference.
    let fitting = fitting_elements(gpu, case);
    let smaller = (fitting < case.elements()).then(|| {
        let small = BenchCase::new(kind, formulation, case.model.clone(), fitting * 9 / 10);
        let reference = cpu_reference(&small);
        (small, reference)
    });
    let (case, reference) = smaller.as_ref().map_or((case, reference), |(c, r)| (c, r));
    let make = |kernel: &str, backend: String, timing: Timing, traffic: u64, error: f64| BenchRow::new(kernel, label, case.model.name(), case.elements(), backend, timing, traffic, error);
    let mut world = case.on(gpu)?;
    let stride = element_out_stride(case.pattern.element_dofs);
    let mut values = vec![0.0; case.pattern.nnz()];
    let mut dof_out = vec![DofOut::default(); case.u.len()];
    // A whole evaluation first: the displacements and the active list are on the
    // device, so the kernel rows below time the kernels alone (nothing moves).
    case.evaluate_on(&mut world, &case.u, true, &mut values, &mut dof_out)?;
    world.take_traffic();
    // The passes below alternate the two, so that each uploads its displacement.
    let states = [case.nudged(), case.u.clone()];
    if wanted(options, FORCE_TANGENT) {
        let results = world.element_results(0)?;
        world.take_traffic();
        let error = blockwise_error(&results, &reference.results, stride);
        let mut result = Ok(());
        let t = time_calls(options.min_time, || result = world.replay(WorldKernel::ForceTangent));
        result?;
        row(make(FORCE_TANGENT, backend.clone(), t, 0, error).with_roofline(kernel_cost(Costed::ForceTangent, case, real), peaks));
    }
    if wanted(options, ASSEMBLY) {
        let residual: Vec<Real> = dof_out.iter().map(|d| d.g).collect();
        let expected: Vec<Real> = reference.dof_out.iter().map(|d| d.g).collect();
        let error = blockwise_error(&values, &reference.values, values.len().max(1)).max(blockwise_error(&residual, &expected, residual.len().max(1)));
        let mut result = Ok(());
        let t = time_calls(options.min_time, || result = world.replay(WorldKernel::Assembly));
        result?;
        row(make(ASSEMBLY, backend.clone(), t, 0, error).with_roofline(kernel_cost(Costed::Assembly, case, real), peaks));
    }
    if wanted(options, EVALUATE) {
        // What a refactorising Newton iteration costs the device: upload, kernels,
        // read-back of the stiffness values and residual.
        let (mut result, mut k) = (Ok(()), 0);
        let t = time_calls(options.min_time, || {
            result = case.evaluate_on(&mut world, &states[k % 2], true, &mut values, &mut dof_out);
            k += 1;
        });
        result?;
        let traffic = world.take_traffic().total();
        row(make(EVALUATE, backend.clone(), t, traffic, 0.0));
    }
    if wanted(options, ENERGY) {
        let (mut energies, mut k) = (Ok(Vec::new()), 0);
        let t = time_calls(options.min_time, || {
            energies = world.element_energies(&[(0, &states[k % 2][..])], &mut PhaseTimes::default());
            k += 1;
        });
        energies?;
        let traffic = world.take_traffic().total();
        let energy: Real = world.element_energies(&[(0, &case.u[..])], &mut PhaseTimes::default())?[0].iter().sum();
        let error = (energy - reference.energy).abs() / reference.energy.abs();
        row(make(ENERGY, backend.clone(), t, traffic, error).with_roofline(kernel_cost(Costed::Energy, case, real), peaks));
    }
    if wanted(options, FORCES) {
        // Last: its pass leaves the members in the forces-only mode, which the
        // rows above would not replay.
        case.evaluate_on(&mut world, &case.u, false, &mut values, &mut dof_out)?;
        let (results, ndof) = (world.element_results(0)?, case.pattern.element_dofs);
        world.take_traffic();
        let only_forces = |r: &[Real]| r.chunks(stride).flat_map(|e| e[..ndof].to_vec()).collect::<Vec<Real>>();
        let error = blockwise_error(&only_forces(&results), &only_forces(&reference.results), ndof);
        let mut result = Ok(());
        let t = time_calls(options.min_time, || result = world.replay(WorldKernel::Forces));
        result?;
        row(make(FORCES, backend.clone(), t, 0, error).with_roofline(kernel_cost(Costed::Forces, case, real), peaks));
    }
    Ok(())
}

/// The kernels with a cost model.
#[derive(Debug, Clone, Copy)]
enum Costed {
    ForceTangent,
    Forces,
    Assembly,
    Energy,
}

/// Device-memory bytes (each input read once, each output written once) and floating-point
/// operations (a multiply-add counts 2) of one call of a kernel on a case, counted from the
/// shader loops: the inputs of the roofline columns.
fn kernel_cost(kernel: Costed, case: &BenchCase, real: usize) -> (f64, f64) {
    let kind = case.mesh.kind;
    let (n, nen, dim) = (case.elements() as f64, kind.nodes() as f64, kind.dim() as f64);
    let nqp = crate::element::shape::quadrature(kind).len() as f64;
    let stride = element_out_stride(case.pattern.element_dofs) as f64;
    let (tangent_flops, stress_flops, energy_flops) = case.model.row().flops;
    let real = real as f64;
    let element_inputs = real * (nqp * (3.0 * nen + 1.0) + nen * dim) + 4.0 * nen;
    match kernel {
        Costed::ForceTangent => {
            let pairs = nen * (nen + 1.0) / 2.0;
            // Phase 1 per point: F, det F, E, the material, the weighting.
            let per_point = 18.0 * nen + 116.0 + tangent_flops;
            let (per_point, per_pair) = match case.formulation {
                // Then the pair tensor, one (L, N) block F C Fᵀ of two 3 x 3 products (90 flops)
                // for each of the w = DIM² blocks, and dV F S; per point and node pair the DIM²
                // entries g_a · A_ij g_b.
                Formulation::Displacement => {
                    let w = dim * dim;
                    (per_point + w * 90.0 + 63.0, w * dim * (2.0 * dim + 2.0))
                }
                // F-bar: every point's J for θ and α in phase 1; per point and pair D B_b, the
                // geometric term and B_aᵀ (D B_b), then F⁻¹ twice, h_a, h_b, θ's sums and second
                // derivative, C, S̄ : C, the β and r terms.
                Formulation::Fbar => (per_point + 20.0 * nqp + 30.0, 36.0 * dim + 236.0 + 12.0 * dim * dim + dim + 300.0 + 12.0 * dim + 10.0 * dim * dim),
            };
            (n * (element_inputs + real * stride), n * nqp * (per_point + pairs * per_pair + nen * 36.0))
        }
        // Per point F, det F, E, the stress, dV F S and its product with each node's gradient;
        // F-bar adds θ, α and the β terms (about 60 per node).
        Costed::Forces => {
            let fbar = if case.formulation == Formulation::Fbar { 20.0 * nqp + 60.0 * nen } else { 0.0 };
            (n * (element_inputs + real * nen * dim), n * nqp * (18.0 * nen + 116.0 + stress_flops + 63.0 + 2.0 * dim * 3.0 * nen + fbar))
        }
        Costed::Assembly => {
            let g = &case.gather;
            let (nnz, dofs) = (case.pattern.nnz() as f64, case.u.len() as f64);
            let (csr, dof) = (g.csr.len() as f64, g.dof.len() as f64);
            let bytes = (real + 4.0) * (csr + dof) + 4.0 * (nnz + dofs) + real * nnz + real * 7.0 * dofs;
            (bytes, 2.0 * csr + dof + 10.0 * dofs)
        }
        Costed::Energy => (n * (element_inputs + real), n * nqp * (18.0 * nen + 54.0 + energy_flops)),
    }
}

/// The rows of the peak kernels (`peak_copy`, `peak_fma`) on the CPU and on each device, and
/// each device's peaks for the roofline columns of the other rows.
fn peak_rows(options: &BenchOptions, gpus: &[Arc<Gpu>], row: &mut impl FnMut(BenchRow)) -> Result<Vec<Peaks>, GpuError> {
    let (copy_shown, fma_shown) = (wanted(options, "peak_copy"), wanted(options, "peak_fma"));
    let make = |kernel: &str, items: usize, backend: String, seconds: f64| BenchRow::new(kernel, "-", "-", items, backend, Timing { per_call: seconds, calls: 1 }, 0, 0.0);
    if copy_shown || fma_shown {
        // The CPU twins on every thread, on 2^24 values.
        let n = 1 << 24;
        let source = vec![1.0; n];
        let mut target = vec![0.0; n];
        let t = time_calls(options.min_time, || cpu::peak_copy(&source, &mut target));
        let bytes = 2.0 * (n * 8) as f64;
        let flops = FMA_FLOPS_PER_VALUE * (n / 16) as f64;
        let cpu_peaks = |copy: f64, fma: f64| Peaks { bytes_per_second: copy, flops_per_second: fma, copy_values: n, copy_seconds: 0.0, fma_values: n / 16, fma_seconds: 0.0 };
        if copy_shown {
            row(make("peak_copy", n, "cpu f64".into(), t.per_call).with_roofline((bytes, 0.0), &cpu_peaks(bytes / t.per_call, f64::INFINITY)));
        }
        let mut values = vec![1.0; n / 16];
        let t = time_calls(options.min_time, || cpu::peak_fma(&mut values));
        if fma_shown {
            row(make("peak_fma", n / 16, "cpu f64".into(), t.per_call).with_roofline((0.0, flops), &cpu_peaks(f64::INFINITY, flops / t.per_call)));
        }
    }
    let mut all = Vec::with_capacity(gpus.len());
    for gpu in gpus {
        let peaks = measure_peaks(gpu, 0.02)?;
        let backend = format!("gpu {}", gpu.precision.name());
        if copy_shown {
            let copy_bytes = 2.0 * (peaks.copy_values * gpu.precision.size()) as f64;
            row(make("peak_copy", peaks.copy_values, backend.clone(), peaks.copy_seconds).with_roofline((copy_bytes, 0.0), &peaks));
        }
        if fma_shown {
            let fma_flops = FMA_FLOPS_PER_VALUE * peaks.fma_values as f64;
            row(make("peak_fma", peaks.fma_values, backend, peaks.fma_seconds).with_roofline((0.0, fma_flops), &peaks));
        }
        all.push(peaks);
    }
    Ok(all)
}

/// Contact points over every regime of the law (separated, sticking, sliding, frictionless),
/// from a fixed linear congruential sequence.
pub fn bench_contact_points(n: usize) -> Vec<UzawaPoint<Real>> {
    let mut uniform = sequence(0);
    let mut next = move || uniform() * 2.0 - 1.0;
    (0..n)
        .map(|i| {
            let mu = if i % 4 == 0 { 0.0 } else { (next() + 1.0) * 0.6 };
            UzawaPoint { r: [next().abs() * 10.0, next() * 3.0, next() * 3.0], v: [next(), next(), next()], mu, rho: (next() + 1.5) * 4.0, status: 0.0 }
        })
        .collect()
}

fn uzawa_rows(options: &BenchOptions, gpus: &[Arc<Gpu>], row: &mut impl FnMut(BenchRow)) -> Result<(), GpuError> {
    let n = 4 * options.elements;
    let inputs = bench_contact_points(n);
    let mut reference = inputs.clone();
    let make = |backend: String, timing: Timing, traffic: u64, error: f64| BenchRow::new("uzawa_step", "-", "-", n, backend, timing, traffic, error);
    let t = time_calls(options.min_time, || {
        for (out, p) in reference.iter_mut().zip(&inputs) {
            *out = p.stepped_on_cpu();
        }
    });
    row(make("cpu f64".into(), t, 0, 0.0));
    for gpu in gpus {
        let kernel = UzawaStepKernel::new(gpu)?;
        let mut points = inputs.clone();
        let (mut traffic, mut result) = (0, Ok(()));
        let t = time_calls(options.min_time, || {
            points.copy_from_slice(&inputs);
            match kernel.run(gpu, &mut points) {
                Ok(bytes) => traffic += 2 * bytes as u64,
                Err(e) => result = Err(e),
            }
        });
        result?;
        let error = points
            .iter()
            .zip(&reference)
            .map(|(g, c)| {
                let scale = c.r.iter().fold(Real::MIN_POSITIVE, |m, x| m.max(x.abs()));
                (0..3).map(|k| (g.r[k] - c.r[k]).abs()).fold(0.0, Real::max) / scale.max(1e-12)
            })
            .fold(0.0, Real::max);
        row(make(format!("gpu {}", gpu.precision.name()), t, traffic, error));
    }
    Ok(())
}

/// A fixed linear congruential sequence of reals in [0, 1).
fn sequence(seed: u64) -> impl FnMut() -> Real {
    let mut state: u64 = 0x2545_f491_4f6c_dd1d ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    move || {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as Real / (1u64 << 53) as Real
    }
}

/// A contact problem like a grain packing's, for the Uzawa sweeps.
pub struct ContactProblem {
    pub w: Delassus,
    pub colours: Colours,
    pub local: Vec<Local>,
    pub nodal: NodalMap,
    /// Warm-start reactions.
    pub r: Vec<[Real; 3]>,
}

impl ContactProblem {
    /// The problem starting from the reactions `r` (a copy of `self.r`) with this stopping rule.
    pub fn with<'a>(&'a self, r: &'a mut [[Real; 3]], tolerance: Real, floor: Real, max_iterations: usize) -> Problem<'a> {
        Problem { w: &self.w, colours: &self.colours, local: &self.local, nodal: &self.nodal, r, tolerance, floor, max_iterations, acceleration: Acceleration::None, fallback: Fallback::None, dim: 3, pairs: &[] }
    }
}

/// `points` contact points on `bodies` bodies: each touches one body (an obstacle contact) or,
/// with probability 0.6, two (a contact between grains), and every pair of points on a body has
/// a block of W. W is symmetric with dominant diagonal blocks, so that Gauss-Seidel converges;
/// the free velocities mostly close the gaps, with every friction regime.
pub fn bench_contact_problem(seed: u64, bodies: usize, points: usize) -> ContactProblem {
    let mut next = sequence(seed);
    let mut pick = |n: usize| ((next() * n as Real) as usize).min(n - 1);
    let touching: Vec<Vec<usize>> = (0..points)
        .map(|_| {
            let (a, b, pair) = (pick(bodies), pick(bodies), pick(10) < 6);
            if b != a && pair {
                vec![a, b]
            } else {
                vec![a]
            }
        })
        .collect();
    let mut next = sequence(seed + 1);
    let mut within = |lo: Real, hi: Real| lo + (hi - lo) * next();
    let mut lists: Vec<Vec<usize>> = vec![Vec::new(); bodies];
    for (i, t) in touching.iter().enumerate() {
        for &b in t {
            lists[b].push(i);
        }
    }
    let mut w = Delassus { rows: vec![Vec::new(); points], ..Default::default() };
    let mut index: std::collections::HashMap<(usize, usize), usize> = std::collections::HashMap::new();
    let mut block = |w: &mut Delassus, l: usize, k: usize| -> usize {
        *index.entry((l, k)).or_insert_with(|| {
            w.rows[l].push((k as u32, w.blocks.len() as u32));
            w.blocks.push([0.0; 9]);
            w.blocks.len() - 1
        })
    };
    for list in &lists {
        for (x, &l) in list.iter().enumerate() {
            let own = block(&mut w, l, l);
            for a in 0..3 {
                w.blocks[own][4 * a] += within(0.5, 1.5);
            }
            for &k in &list[x + 1..] {
                let m: [Real; 9] = std::array::from_fn(|_| within(-0.03, 0.03));
                let (lk, kl) = (block(&mut w, l, k), block(&mut w, k, l));
                for a in 0..3 {
                    for c in 0..3 {
                        w.blocks[lk][3 * a + c] += m[3 * a + c];
                        w.blocks[kl][3 * c + a] += m[3 * a + c];
                    }
                }
            }
        }
    }
    w.stamp();
    let colours = Colours::of(&w);
    let local = (0..points)
        .map(|i| {
            let mu = [0.0, 0.3, 0.6][((within(0.0, 3.0)) as usize).min(2)];
            let v_free = [within(-1.0, 0.4), within(-1.0, 1.0), within(-1.0, 1.0)];
            Local { v_free, shift: within(-0.01, 0.01), mu, rho: w.rho(i, 3, Sweep::GaussSeidel) }
        })
        .collect();
    let r = (0..points).map(|_| if within(0.0, 1.0) < 0.5 { [within(0.0, 0.5), within(-0.1, 0.1), 0.0] } else { [0.0; 3] }).collect();
    // Each point's own node, and a node of its second body with the opposite sign.
    let terms = touching.iter().enumerate().map(|(i, t)| if t.len() == 2 { vec![(i as u32, 1.0), ((points + i) as u32, -1.0)] } else { vec![(i as u32, 1.0)] }).collect();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let nodal = NodalMap { terms, frames: vec![identity; points], nodes: 2 * points };
    ContactProblem { w, colours, local, nodal, r }
}

/// Sweeps per call of the `uzawa_sweep` rows.
pub const BENCH_SWEEPS: usize = 8;

/// `uzawa_sweep`: [`BENCH_SWEEPS`] Gauss-Seidel sweeps (colour by colour) of a grain-like
/// problem of `4 x elements` points on a quarter as many bodies, on the CPU (the thread pool
/// within large colours) and on each GPU in f64.
fn uzawa_sweep_rows(options: &BenchOptions, gpus: &[Arc<Gpu>], row: &mut impl FnMut(BenchRow)) -> Result<(), GpuError> {
    let n = 4 * options.elements;
    let p = bench_contact_problem(1, (n / 4).max(1), n);
    let make = |backend: String, timing: Timing, traffic: u64, error: f64| BenchRow::new("uzawa_sweep", "-", "-", n, backend, timing, traffic, error);
    let mut reference = p.r.clone();
    let t = time_calls(options.min_time, || {
        reference.copy_from_slice(&p.r);
        uzawa::solve(&mut p.with(&mut reference, 0.0, 1e-3, BENCH_SWEEPS), Sweep::GaussSeidel, None);
    });
    row(make("cpu f64".into(), t, 0, 0.0));
    for gpu in gpus.iter().filter(|g| g.precision == Precision::F64) {
        let mut sweeps = UzawaSweeps::new(gpu.clone())?;
        // W keeps its version: after the first (untimed) call it stays on the device, as within
        // a step whose bodies keep their factorisations.
        let mut r = p.r.clone();
        let mut result = Ok(());
        let t = time_calls(options.min_time, || {
            r.copy_from_slice(&p.r);
            if let Err(e) = sweeps.solve(&mut [p.with(&mut r, 0.0, 1e-3, BENCH_SWEEPS)], None) {
                result = Err(e);
            }
        });
        result?;
        let scale = reference.iter().flatten().fold(Real::MIN_POSITIVE, |m, x| m.max(x.abs()));
        let error = r.iter().flatten().zip(reference.iter().flatten()).map(|(a, b)| (a - b).abs()).fold(0.0, Real::max) / scale;
        let traffic = sweeps.traffic.total();
        row(make(format!("gpu {}", gpu.precision.name()), t, traffic, error));
    }
    Ok(())
}

/// Points and bodies of one problem of the `uzawa_solve` rows: a cluster of a few grains.
const CLUSTER_POINTS: usize = 16;
const CLUSTER_BODIES: usize = 4;

/// `uzawa_solve`: [`BENCH_SWEEPS`] Gauss-Seidel sweeps of each of the many small problems of a
/// grain packing (`4 x elements` points in clusters of [`CLUSTER_POINTS`] on
/// [`CLUSTER_BODIES`] bodies), on the CPU (the problems in parallel, as the groups of a Newton
/// round) and on each GPU in f64, where each problem is solved whole by one workgroup.
fn uzawa_solve_rows(options: &BenchOptions, gpus: &[Arc<Gpu>], row: &mut impl FnMut(BenchRow)) -> Result<(), GpuError> {
    let clusters = (4 * options.elements).div_ceil(CLUSTER_POINTS);
    let n = clusters * CLUSTER_POINTS;
    let problems: Vec<ContactProblem> = (0..clusters).into_par_iter().map(|k| bench_contact_problem(1000 + k as u64, CLUSTER_BODIES, CLUSTER_POINTS)).collect();
    let make = |backend: String, timing: Timing, traffic: u64, error: f64| BenchRow::new("uzawa_solve", "-", "-", n, backend, timing, traffic, error);
    let mut reference: Vec<Vec<[Real; 3]>> = problems.iter().map(|p| p.r.clone()).collect();
    let t = time_calls(options.min_time, || {
        problems.par_iter().zip(&mut reference).for_each(|(p, r)| {
            r.copy_from_slice(&p.r);
            uzawa::solve(&mut p.with(r, 0.0, 1e-3, BENCH_SWEEPS), Sweep::GaussSeidel, None);
        });
    });
    row(make("cpu f64".into(), t, 0, 0.0));
    for gpu in gpus.iter().filter(|g| g.precision == Precision::F64) {
        let mut sweeps = UzawaSweeps::new(gpu.clone())?;
        let mut r: Vec<Vec<[Real; 3]>> = problems.iter().map(|p| p.r.clone()).collect();
        let mut result = Ok(());
        let t = time_calls(options.min_time, || {
            let mut list: Vec<Problem> = problems
                .iter()
                .zip(&mut r)
                .map(|(p, r)| {
                    r.copy_from_slice(&p.r);
                    p.with(r, 0.0, 1e-3, BENCH_SWEEPS)
                })
                .collect();
            if let Err(e) = sweeps.solve(&mut list, None) {
                result = Err(e);
            }
        });
        result?;
        let scale = reference.iter().flatten().flatten().fold(Real::MIN_POSITIVE, |m, x| m.max(x.abs()));
        let error = r.iter().flatten().flatten().zip(reference.iter().flatten().flatten()).map(|(a, b)| (a - b).abs()).fold(0.0, Real::max) / scale;
        row(make(format!("gpu {}", gpu.precision.name()), t, sweeps.traffic.total(), error));
    }
    Ok(())
}

/// The table `bifirst bench` prints.
pub fn table_header() -> String {
    format!("{:<32} {:<10} {:<12} {:>8} {:<8} {:>12} {:>12} {:>12} {:>10} {:>9} {:>9} {:>7} {:>7}", "kernel", "elem", "material", "items", "backend", "time/call", "items/s", "bytes/call", "max rel err", "GB/s", "GFLOP/s", "%bw", "%flop")
}

impl BenchRow {
    /// A row from a measurement: `traffic` is the bytes moved over all `timing.calls`.
    #[allow(clippy::too_many_arguments)]
    fn new(kernel: &str, element: &str, material: &str, items: usize, backend: String, timing: Timing, traffic: u64, error: f64) -> Self {
        Self {
            kernel: kernel.into(),
            element: element.into(),
            material: material.into(),
            items,
            backend,
            seconds_per_call: timing.per_call,
            items_per_second: items as f64 / timing.per_call,
            bytes_per_call: traffic / timing.calls,
            max_relative_error: error,
            gbytes_per_second: None,
            gflops_per_second: None,
            peak_bandwidth_fraction: None,
            peak_flops_fraction: None,
        }
    }

    /// Adds the roofline columns from the bytes and operations of one call and the peaks.
    fn with_roofline(mut self, cost: (f64, f64), peaks: &Peaks) -> Self {
        let (bytes, flops) = (cost.0 / self.seconds_per_call, cost.1 / self.seconds_per_call);
        self.gbytes_per_second = Some(bytes * 1e-9);
        self.gflops_per_second = Some(flops * 1e-9);
        self.peak_bandwidth_fraction = Some(bytes / peaks.bytes_per_second);
        self.peak_flops_fraction = Some(flops / peaks.flops_per_second);
        self
    }

    pub fn line(&self) -> String {
        let column = |x: Option<f64>, scale: f64| x.map_or("-".to_string(), |v| format!("{:.1}", v * scale));
        format!(
            "{:<32} {:<10} {:<12} {:>8} {:<8} {:>10.3}ms {:>12.3e} {:>12} {:>10.1e} {:>9} {:>9} {:>7} {:>7}",
            self.kernel,
            self.element,
            self.material,
            self.items,
            self.backend,
            self.seconds_per_call * 1e3,
            self.items_per_second,
            self.bytes_per_call,
            self.max_relative_error,
            column(self.gbytes_per_second, 1.0),
            column(self.gflops_per_second, 1.0),
            column(self.peak_bandwidth_fraction, 100.0),
            column(self.peak_flops_fraction, 100.0)
        )
    }
}

/// Devices for the GPU columns: the adapter (best, or named) in f64 when it has it, and in f32.
pub fn bench_devices(adapter: Option<&str>) -> Result<Vec<Arc<Gpu>>, GpuError> {
    let first = crate::gpu::open(adapter, None)?;
    let mut devices = Vec::new();
    if first.precision == Precision::F64 {
        devices.push(Arc::new(first));
        devices.push(Arc::new(crate::gpu::open(adapter, Some(Precision::F32))?));
    } else {
        devices.push(Arc::new(first));
    }
    Ok(devices)
}
