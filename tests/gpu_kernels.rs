//! WGSL kernels: every shader parses and validates with naga (no GPU), the `#[repr(C)]` types
//! match naga's layouts, and on a GPU adapter (lavapipe in CI) each kernel matches its CPU twin.

#[path = "common/random.rs"]
mod random;

use bifirst::gpu::shaders::{validate, SHADERS};
use bifirst::contact::Status;
use bifirst::gpu::uzawa_step::{UzawaPoint, UzawaStepKernel};
use bifirst::precision::Precision;
use rand::Rng;

const PRECISIONS: [Precision; 2] = [Precision::F32, Precision::F64];

#[test]
fn every_shader_file_is_registered_and_validates_in_both_precisions() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut files: Vec<String> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "wgsl")).map(|p| p.file_stem().unwrap().to_string_lossy().into_owned()).collect();
    files.sort();
    let mut registered: Vec<String> = SHADERS.iter().map(|(name, _)| name.to_string()).collect();
    registered.sort();
    assert_eq!(files, registered, "every file in shaders/ is compiled in, and nothing else");
    for (name, _) in SHADERS {
        for precision in PRECISIONS {
            if let Err(e) = validate(name, precision) {
                panic!("{name} ({}):\n{e}", precision.name());
            }
        }
    }
}

/// Byte offsets of a struct's members and its size, as naga lays them out.
fn naga_layout(module: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
    let (_, ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)).unwrap_or_else(|| panic!("struct {name}"));
    let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("{name} is a struct") };
    (members.iter().map(|m| (m.name.clone().unwrap(), m.offset)).collect(), *span)
}

#[test]
fn uzawa_point_matches_the_shader_layout() {
    for precision in PRECISIONS {
        let module = validate("uzawa_step", precision).unwrap();
        let (members, span) = naga_layout(&module, "UzawaPoint");
        let (offsets, size) = match precision {
            Precision::F32 => {
                use std::mem::offset_of;
                type P = UzawaPoint<f32>;
                (vec![offset_of!(P, r), offset_of!(P, v), offset_of!(P, mu), offset_of!(P, rho), offset_of!(P, status)], std::mem::size_of::<P>())
            }
            Precision::F64 => {
                use std::mem::offset_of;
                type P = UzawaPoint<f64>;
                (vec![offset_of!(P, r), offset_of!(P, v), offset_of!(P, mu), offset_of!(P, rho), offset_of!(P, status)], std::mem::size_of::<P>())
            }
        };
        let real = precision.size() as u32;
        let shader: Vec<(&str, u32)> = members.iter().map(|(n, o)| (n.as_str(), *o)).collect();
        assert_eq!(
            shader,
            [("r_n", 0), ("r_t1", real), ("r_t2", 2 * real), ("v_n", 3 * real), ("v_t1", 4 * real), ("v_t2", 5 * real), ("mu", 6 * real), ("rho", 7 * real), ("status", 8 * real)]
        );
        let rust: Vec<u32> = offsets.iter().map(|&o| o as u32).collect();
        assert_eq!(rust, [0, 3 * real, 6 * real, 7 * real, 8 * real], "{}", precision.name());
        assert_eq!(span, size as u32, "{}: struct size", precision.name());
    }
}

/// An adapter when there is one. Without one, a GPU test fails in CI (`CI=true`) and is
/// reported SKIPPED elsewhere, never passed silently.
fn gpu_or_skip(test: &str, precision: Precision) -> Option<bifirst::gpu::Gpu> {
    match bifirst::gpu::open(None, Some(precision)) {
        Ok(gpu) => {
            eprintln!("{test}: on {} in {}", gpu.adapter.line(), precision.name());
            Some(gpu)
        }
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{test}: no GPU in CI: {e}"),
        Err(e) => {
            eprintln!("SKIPPED {test} ({}): {e}", precision.name());
            None
        }
    }
}

/// Random points over every regime: separated, sticking, sliding, the apex, frictionless.
fn random_points(n: usize) -> Vec<UzawaPoint<f64>> {
    let mut rng = random::rng(7);
    (0..n)
        .map(|i| {
            let mut s = || rng.random_range(-1.0f64..1.0);
            let mu = match i % 4 {
                0 => 0.0,
                _ => (s() + 1.0) * 0.6,
            };
            UzawaPoint { r: [s().abs() * 10.0, s() * 3.0, s() * 3.0], v: [s(), s(), s()], mu, rho: (s() + 1.5) * 4.0, status: -1.0 }
        })
        .collect()
}

/// Distance (relative) of the predictor from the boundaries between the law's cases, where
/// round-off in f32 may pick the other case.
fn boundary_distance(p: &UzawaPoint<f64>) -> f64 {
    let vt = (p.v[1] * p.v[1] + p.v[2] * p.v[2]).sqrt();
    let tau = [p.r[0] - p.rho * (p.v[0] + p.mu * vt), p.r[1] - p.rho * p.v[1], p.r[2] - p.rho * p.v[2]];
    let tt = (tau[1] * tau[1] + tau[2] * tau[2]).sqrt();
    let scale = tau.iter().fold(1e-300, |m: f64, x| m.max(x.abs()));
    [tau[0].abs(), (tt - p.mu * tau[0]).abs(), (p.mu * tt + tau[0]).abs()].into_iter().fold(f64::INFINITY, f64::min) / scale
}

#[test]
fn uzawa_step_kernel_matches_its_cpu_twin() {
    // Relative error in the max norm over the three reaction components of each point, against
    // the largest of them: 1e-12 in f64, 1e-5 in f32.
    for (precision, tolerance) in [(Precision::F64, 1e-12), (Precision::F32, 1e-5)] {
        let Some(gpu) = gpu_or_skip("uzawa_step_kernel_matches_its_cpu_twin", precision) else { continue };
        let kernel = UzawaStepKernel::new(&gpu).expect("pipeline");
        // More than one row of workgroups (65535 x 64) is not needed to test the indexing of
        // the second row: it is the same expression.
        let inputs = random_points(20_000);
        let mut on_gpu = inputs.clone();
        let bytes = kernel.run(&gpu, &mut on_gpu).expect("kernel runs");
        assert_eq!(bytes, inputs.len() * 9 * precision.size());
        let (mut worst, mut status_flips) = (0.0f64, 0);
        for (input, gpu_point) in inputs.iter().zip(&on_gpu) {
            let cpu = input.stepped_on_cpu();
            let scale = cpu.r.iter().chain(&input.r).fold(1e-300, |m: f64, x| m.max(x.abs()));
            let error = (0..3).map(|k| (gpu_point.r[k] - cpu.r[k]).abs()).fold(0.0, f64::max) / scale;
            if Status::from_code(gpu_point.status as u32) != Status::from_code(cpu.status as u32) {
                // Only allowed on a case boundary, where both answers agree to the tolerance.
                assert!(precision == Precision::F32 && boundary_distance(input) < 1e-5, "{input:?}: GPU {gpu_point:?} CPU {cpu:?}");
                status_flips += 1;
            }
            worst = worst.max(error);
        }
        assert!(worst <= tolerance, "{}: max relative error {worst:.3e}", precision.name());
        eprintln!("{}: max relative error {worst:.3e}, status flips {status_flips}", precision.name());
        let statuses: std::collections::BTreeSet<u32> = on_gpu.iter().map(|p| p.status as u32).collect();
        assert_eq!(statuses.into_iter().collect::<Vec<_>>(), [0, 1, 2], "every regime is exercised");
    }
}
