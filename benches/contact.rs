//! Criterion benchmarks of contact:
//! - `contact_law/uzawa_step/{frictionless,coulomb}`: the local predictor/corrector of eq. (10)
//!   on 100k points with random reactions and velocities (points/s);
//! - `contact_detection/<facets>`: broad + narrow phase between two stacked Hex8 plates whose
//!   boundaries total about 1e3, 1e4 and 1e5 facets of similar sizes (facets/s; the log-log slope of time against
//!   facets is reported in doc/benchmarks.md).

use bifirst::contact::detect::detect;
use bifirst::contact::pairs::{BodyPairs, Rank};
use bifirst::contact::{uzawa_step, Configuration, ContactModel, Settings, Surface, Sweep};
use bifirst::mesh::{generate, ElementKind};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::hint::black_box;

/// Two bodies, the upper one (1) the slave on the lower one (0).
fn upper_on_lower(mu: f64) -> BodyPairs {
    let rank = Rank { length_scale: 1.0, boundary_nodes: 0 };
    let mut pairs = BodyPairs::new(vec![rank; 2], None, false);
    pairs.list(0, 1, mu, Some(1));
    pairs
}

fn law(c: &mut Criterion) {
    let mut rng = SmallRng::seed_from_u64(3);
    let n = 100_000;
    let points: Vec<([f64; 3], [f64; 3])> = (0..n).map(|_| ([rng.random_range(0.0..2.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)], [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)])).collect();
    let mut group = c.benchmark_group("contact_law");
    group.throughput(Throughput::Elements(n as u64));
    for (name, mu) in [("frictionless", 0.0), ("coulomb", 0.3)] {
        group.bench_function(BenchmarkId::new("uzawa_step", name), |b| {
            b.iter(|| {
                let mut sum = 0.0;
                for (r, v) in &points {
                    sum += uzawa_step(*r, *v, mu, 0.8).0[0];
                }
                black_box(sum)
            })
        });
    }
    group.finish();
}

fn detection(c: &mut Criterion) {
    let mut group = c.benchmark_group("contact_detection");
    group.sample_size(10);
    for cells in [15, 49, 158] {
        // Two plates of cells x cells x 1 cubic hex8, the upper one resting on the lower one
        // (facets of similar sizes, the premise of a uniform grid).
        let t = 1.0 / cells as f64;
        let lower = generate::cuboid([0.0; 3], [1.0, 1.0, t], [cells, cells, 1], ElementKind::Hex8);
        let upper = generate::cuboid([0.0, 0.0, t], [1.0, 1.0, t], [cells, cells, 1], ElementKind::Hex8);
        let surfaces = vec![Surface::of(&lower), Surface::of(&upper)];
        let facets: usize = surfaces.iter().map(Surface::facet_count).sum();
        let model = ContactModel { settings: Settings { tolerance: 1e-8, max_iterations: 1, sweep: Sweep::GaussSeidel, acceleration: Default::default(), fallback: Default::default() }, surfaces, obstacles: Vec::new(), pairs: upper_on_lower(0.3) };
        let mut config = Configuration::new(&model, vec![lower.nodes.clone(), upper.nodes.clone()]);
        let placed = |_: usize, _: &mut Vec<[f64; 3]>| unreachable!("every body is placed");
        let margin = 0.01 / cells as f64;
        let found = detect(&model, &mut config, &placed, 3, 0.0, 1e-3, margin, &mut Default::default()).len();
        assert_eq!(found, (cells + 1) * (cells + 1), "every node of the upper plate's bottom touches");
        group.throughput(Throughput::Elements(facets as u64));
        group.bench_function(BenchmarkId::from_parameter(facets), |b| b.iter(|| black_box(detect(&model, &mut config, &placed, 3, 0.0, 1e-3, margin, &mut Default::default()).len())));
    }
    group.finish();
}

criterion_group!(benches, law, detection);
criterion_main!(benches);
