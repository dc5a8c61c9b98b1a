//! Whole runs on a GPU adapter (lavapipe in CI) against the CPU backend: the energies of every
//! step agree within 1e-9 in f64 and 1e-4 in f32, relative to the largest total energy of the
//! CPU run. Without an adapter the tests fail in CI and say SKIPPED elsewhere.

#[path = "common/run.rs"]
mod common;

use bifirst::backend::{BackendChoice, BackendRequest};
use bifirst::precision::Precision;
use bifirst::run::RunOptions;
use common::{run_with, scene_path, temp_path, Log};
use std::path::Path;

/// A reduced Love-Laursen-like impact: a small LVF block (Hex8) hits a larger one at an angle,
/// with friction, so it sticks and slides; paper parameters, coarse mesh, 25 steps.
const IMPACT_3D: &str = r#"
name = "impact_3d_reduced"

[time]
end = 0.25
dt = 0.01
xi = 0.5
theta = 0.5

[material.rubber]
model = "lvf"
G = 5000.0
K = 3333.0
a1 = 50.0
a2 = 50.0
a3 = 0.0
a4 = 2000.0
a5 = 100.0
density = 1.0

[body.lower]
material = "rubber"
mesh = { generator = "box", element = "hex8", origin = [0.0, 0.0, 0.0], size = [1.0, 1.0, 0.5], divisions = [3, 3, 2] }

[body.upper]
material = "rubber"
mesh = { generator = "box", element = "hex8", origin = [0.2, 0.2, 0.52], size = [0.6, 0.6, 0.4], divisions = [2, 2, 2] }
initial_velocity = [2.0, 0.5, -4.0]

[contact]
friction = 0.3
"#;

fn gpu_available(test: &str) -> bool {
    match bifirst::gpu::open(None, None) {
        Ok(_) => true,
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{test}: no GPU in CI: {e}"),
        Err(e) => {
            eprintln!("SKIPPED {test}: {e}");
            false
        }
    }
}

fn options(choice: BackendChoice, precision: Option<Precision>) -> RunOptions {
    RunOptions { backend: BackendRequest { choice, adapter: None, precision }, ..Default::default() }
}

/// Runs `path` on the CPU and on the GPU in both precisions; checks every step's energies.
fn compare_backends(test: &str, path: &Path, sets: &[&str]) {
    if !gpu_available(test) {
        return;
    }
    let cpu = run_with(path, sets, &format!("{test}_cpu"), &options(BackendChoice::Cpu, None));
    assert_eq!(cpu.topics["/run"][0]["backend"], "cpu");
    assert!(cpu.series("/contact", "active").iter().any(|&a| a > 0.0), "{test}: the bodies touch");
    for (precision, tolerance) in [(Precision::F64, 1e-9), (Precision::F32, 1e-4)] {
        let gpu = run_with(path, sets, &format!("{test}_gpu_{}", precision.name()), &options(BackendChoice::Gpu, Some(precision)));
        assert_eq!(gpu.topics["/run"][0]["backend"], "gpu");
        assert_eq!(gpu.topics["/run"][0]["precision"], precision.name());
        assert!(gpu.topics["/summary"][0]["bytes_moved"].as_u64().unwrap() > 0, "the GPU run moved data");
        let worst = energy_difference(&cpu, &gpu);
        let newton = |log: &Log| log.topics["/summary"][0]["newton_iterations"].as_u64().unwrap();
        eprintln!("{test} {}: max relative energy difference {worst:.2e} over {} states; Newton iterations {} (CPU {})", precision.name(), cpu.topics["/energy"].len(), newton(&gpu), newton(&cpu));
        assert!(worst <= tolerance, "{test} {}: {worst:.3e}", precision.name());
    }
}

/// Largest difference of the kinetic, strain and total energies over all logged states, relative
/// to the CPU run's largest total energy.
fn energy_difference(cpu: &Log, gpu: &Log) -> f64 {
    let fields = ["kinetic", "strain", "total"];
    let scale = cpu.series("/energy", "total").iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert_eq!(cpu.topics["/energy"].len(), gpu.topics["/energy"].len(), "same number of states");
    fields
        .iter()
        .flat_map(|f| cpu.series("/energy", f).into_iter().zip(gpu.series("/energy", f)))
        .map(|(a, b)| (a - b).abs() / scale)
        .fold(0.0, f64::max)
}

#[test]
fn bar_impact_on_the_gpu_matches_the_cpu_backend() {
    // Every step logged, so every step is compared.
    compare_backends("bar_impact_gpu", &scene_path("bar_impact"), &["output.every=1", "output.scene_every=0"]);
}

#[test]
fn reduced_3d_impact_on_the_gpu_matches_the_cpu_backend() {
    let path = temp_path("impact_3d_reduced.toml");
    std::fs::write(&path, IMPACT_3D).unwrap();
    compare_backends("impact_3d_gpu", &path, &["output.every=1", "output.scene_every=0"]);
    let friction = run_with(&path, &["output.scene_every=0"], "impact_3d_friction", &options(BackendChoice::Cpu, None)).series("/energy", "friction_dissipation");
    assert!(friction.last().unwrap() > &0.0, "the blocks slide on each other");
}
