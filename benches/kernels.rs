//! Criterion benchmarks of the CPU engine:
//! - `element/<model>/<element>`: internal force + tangent of 1000 elements (elements/s), the
//!   F-bar element as `quad4+fbar` and `hex8+fbar`;
//! - `newton_hex8_50k/{assembly,factorization,solve}`: the three phases of one Newton iteration
//!   of a 3D Hex8 block with about 50k unknowns, and `assembly_gpu_<precision>` on a GPU adapter;
//! - `gpu_element/<precision>/<model>/<element>` and `gpu_assembly/<precision>/<element>`: the
//!   element and assembly kernels on a GPU adapter (skipped, with the reason, without one).
//!
//! Results are recorded in doc/benchmarks.md.

use bifirst::bench::{bench_devices, bench_elements, bench_models, element_label, BenchCase, KINDS};
use bifirst::element::{element_force_tangent, ElementOutput, Formulation, ReferenceGeometry};
use bifirst::gpu::types::{Coefficients, DofOut};
use bifirst::gpu::{Gpu, WorldKernel};
use bifirst::material::{Model, NeoHookean};
use bifirst::mesh::{generate, ElementKind, Mesh};
use bifirst::precision::Real;
use bifirst::solver::body::{Body, Prescribed};
use bifirst::solver::topology::Topology;
use bifirst::solver::PhaseTimes;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::sync::Arc;

/// About 1000 elements of a kind.
fn mesh_of(kind: ElementKind) -> Mesh {
    match kind {
        ElementKind::Tri3 => generate::rectangle([0.0; 2], [1.0; 2], [23, 22], kind),
        ElementKind::Quad4 => generate::rectangle([0.0; 2], [1.0; 2], [32, 32], kind),
        ElementKind::Tet4 => generate::cuboid([0.0; 3], [1.0; 3], [6, 6, 5], kind),
        ElementKind::Hex8 => generate::cuboid([0.0; 3], [1.0; 3], [10, 10, 10], kind),
    }
}

/// A smooth, moderate deformation field (a twist and a stretch).
fn deform(x: [f64; 3]) -> [f64; 3] {
    [0.1 * x[0] + 0.05 * x[1] * x[2], -0.03 * x[1] + 0.04 * x[0] * x[2], 0.02 * x[2] - 0.05 * x[0] * x[1]]
}

fn element_kernels(c: &mut Criterion) {
    let mut group = c.benchmark_group("element");
    for (kind, formulation) in bench_elements() {
        let mesh = mesh_of(kind);
        let geometry = ReferenceGeometry::new(&mesh).unwrap();
        let u: Vec<Vec<[f64; 3]>> = (0..mesh.element_count())
            .map(|e| {
                mesh.element(e)
                    .iter()
                    .map(|&n| {
                        let mut d = deform(mesh.nodes[n as usize]);
                        if kind.dim() == 2 {
                            d[2] = 0.0;
                        }
                        d
                    })
                    .collect()
            })
            .collect();
        group.throughput(Throughput::Elements(mesh.element_count() as u64));
        for model in bench_models() {
            group.bench_with_input(BenchmarkId::new(model.name(), element_label(kind, formulation)), &model, |b, model| {
                let mut out = ElementOutput::default();
                b.iter(|| {
                    for (e, ue) in u.iter().enumerate() {
                        element_force_tangent(model, geometry.element_points(e), ue, kind.dim(), formulation, None, true, &mut out).unwrap();
                        black_box(&out);
                    }
                })
            });
        }
    }
    group.finish();
}

fn newton_iteration(c: &mut Criterion) {
    // 24 x 24 x 28 cells: 25 * 25 * 29 nodes, 54 375 dofs, 1875 of them clamped on z = 0.
    let mesh = generate::cuboid([0.0; 3], [1.0, 1.0, 1.2], [24, 24, 28], ElementKind::Hex8);
    let geometry = ReferenceGeometry::new(&mesh).unwrap();
    let prescribed: Vec<Prescribed> = mesh.node_sets["z_min"].iter().flat_map(|&n| (0..3).map(move |i| Prescribed { dof: n as usize * 3 + i, velocity: 0.0, set: 0, until: Real::INFINITY })).collect();
    let model = Model::NeoHookean(NeoHookean { g: 1000.0, k: 3000.0 });
    let topology = Topology::new(&mesh, &prescribed, Default::default()).unwrap();
    let mut body = Body::new("block".into(), mesh.clone(), None, geometry, model, Formulation::Displacement, 1.0, prescribed, |_| [0.0; 3], &topology);
    let u: Vec<f64> = mesh.nodes.iter().flat_map(|&x| deform(x)).collect();
    let (dt, theta, xi) = (1e-3, 0.5, 0.5);
    let c1 = 1.0 / (theta * dt * dt);
    let coefficients = Coefficients { factor: xi, c1, motion: 0.0 };
    let mut times = PhaseTimes::default();
    println!("newton_hex8_50k: {} free dofs, {} stored non-zeros", body.dofs().free_count, body.pattern().nnz());
    let mut group = c.benchmark_group("newton_hex8_50k");
    group.sample_size(10);
    group.bench_function("assembly", |b| b.iter(|| body.assemble(&u, coefficients, &mut times).unwrap()));
    group.bench_function("factorization", |b| {
        b.iter(|| {
            body.assemble(&u, coefficients, &mut times).unwrap();
            body.factorize_effective(c1, &mut times).unwrap()
        })
    });
    let rhs0: Vec<f64> = (0..body.dofs().free_count).map(|i| (i as f64).sin()).collect();
    group.bench_function("solve", |b| {
        b.iter(|| {
            let mut rhs = rhs0.clone();
            body.solve_effective(&mut rhs, &mut times);
            black_box(rhs)
        })
    });
    group.finish();
}

/// The GPU devices (f64 and f32 on the best adapter), or none, saying why.
fn devices() -> Vec<Arc<Gpu>> {
    bench_devices(None).unwrap_or_else(|e| {
        println!("GPU benchmarks SKIPPED: {e}");
        Vec::new()
    })
}

fn gpu_kernels(c: &mut Criterion) {
    for gpu in devices() {
        let precision = gpu.precision.name();
        let mut group = c.benchmark_group("gpu_element");
        for (kind, formulation) in bench_elements() {
            for model in bench_models() {
                let case = BenchCase::new(kind, formulation, model, 1000);
                let mut world = case.on(&gpu).unwrap();
                let (mut values, mut dof_out) = (vec![0.0; case.pattern.nnz()], vec![DofOut::default(); case.u.len()]);
                case.evaluate_on(&mut world, &case.u, true, &mut values, &mut dof_out).unwrap();
                group.throughput(Throughput::Elements(case.elements() as u64));
                group.bench_function(format!("{precision}/{}/{}", case.model.name(), element_label(kind, formulation)), |b| b.iter(|| world.replay(WorldKernel::ForceTangent).unwrap()));
            }
        }
        group.finish();
        let mut group = c.benchmark_group("gpu_assembly");
        for kind in KINDS {
            let case = BenchCase::new(kind, Formulation::Displacement, bench_models()[0].clone(), 1000);
            let mut world = case.on(&gpu).unwrap();
            let (mut values, mut dof_out) = (vec![0.0; case.pattern.nnz()], vec![DofOut::default(); case.u.len()]);
            group.throughput(Throughput::Elements(case.elements() as u64));
            // A whole device pass: upload (of a displacement that changed), kernels, read-back
            // of the values and residual.
            let states = [case.nudged(), case.u.clone()];
            let mut k = 0;
            group.bench_function(format!("{precision}/{}", kind.name()), |b| {
                b.iter(|| {
                    k += 1;
                    case.evaluate_on(&mut world, &states[k % 2], true, &mut values, &mut dof_out).unwrap()
                })
            });
        }
        group.finish();
    }
}

criterion_group!(benches, element_kernels, newton_iteration, gpu_kernels);
criterion_main!(benches);
