//! `bifirst bench`: a row per kernel, element and material on each backend, with sane numbers.

use serde_json::Value;
use std::process::Command;

fn rows(args: &[&str]) -> Vec<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["bench", "--elements", "60", "--time", "0", "--json"]).args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).expect("a JSON row per line")).collect()
}

/// The material models the bench measures: every one of the registry.
const MATERIALS: usize = bifirst::material::Model::ENTRIES.len();

#[test]
fn bench_reports_every_kernel_on_the_cpu() {
    let rows = rows(&["--backend", "cpu", "--all"]);
    // 6 elements (4 kinds, and F-bar on quad4 and hex8) x every material of the registry x 4
    // kernel groups (the force and tangent, the forces alone, the assembly, the energy),
    // newton_iteration, uzawa_step, uzawa_sweep, uzawa_solve, and the two peak kernels.
    assert_eq!(rows.len(), 6 * MATERIALS * 4 + 1 + 3 + 2);
    let materials: std::collections::BTreeSet<&str> = rows.iter().filter_map(|r| r["material"].as_str()).filter(|m| *m != "-").collect();
    assert_eq!(materials.len(), MATERIALS, "{materials:?}");
    let elements: std::collections::BTreeSet<&str> = rows.iter().filter_map(|r| r["element"].as_str()).collect();
    assert!(elements.contains("quad4+fbar") && elements.contains("hex8+fbar"), "{elements:?}");
    for r in &rows {
        assert_eq!(r["backend"], "cpu f64");
        assert!(r["items"].as_u64().unwrap() > 0 && r["seconds_per_call"].as_f64().unwrap() > 0.0, "{r}");
        assert_eq!(r["max_relative_error"], 0.0, "the CPU twin is the reference");
        assert_eq!(r["bytes_per_call"], 0);
    }
    let only = self::rows(&["--backend", "cpu", "--kernel", "uzawa"]);
    let kernels: Vec<&str> = only.iter().map(|r| r["kernel"].as_str().unwrap()).collect();
    assert_eq!(kernels, ["uzawa_step", "uzawa_sweep", "uzawa_solve"]);
}

/// `--kernel element_energy` printed nothing: the filter was matched against shortened names
/// ("energy"), so a row's full name selected none of its rows.
#[test]
fn bench_kernel_filter_takes_a_rows_full_name() {
    for (filter, rows_expected) in [("element_energy", 6 * MATERIALS), ("assemble_csr+assemble_residual", 6 * MATERIALS), ("element_force_tangent/forces", 6 * MATERIALS), ("peak_fma", 1), ("peak_copy", 1)] {
        let rows = self::rows(&["--backend", "cpu", "--all", "--kernel", filter]);
        assert_eq!(rows.len(), rows_expected, "--kernel {filter}");
        assert!(rows.iter().all(|r| r["kernel"] == filter), "--kernel {filter}: {rows:?}");
    }
    // A kernel's name selects its entry points' rows too.
    let rows = self::rows(&["--backend", "cpu", "--all", "--kernel", "element_force_tangent"]);
    let kernels: std::collections::BTreeSet<&str> = rows.iter().map(|r| r["kernel"].as_str().unwrap()).collect();
    assert_eq!((rows.len(), kernels.into_iter().collect::<Vec<_>>()), (6 * MATERIALS * 2, vec!["element_force_tangent", "element_force_tangent/forces"]));
}

/// A device call has minutes, not the half hour of every element and material at a million
/// elements: `--element` and `--material` pick the element rows' cases, by part of their names.
#[test]
fn bench_element_and_material_filters_pick_the_cases() {
    let rows = self::rows(&["--backend", "cpu", "--kernel", "element_force_tangent", "--element", "hex8", "--material", "blatz_ko"]);
    let cases: Vec<(&str, &str)> = rows.iter().map(|r| (r["element"].as_str().unwrap(), r["material"].as_str().unwrap())).collect();
    assert_eq!(cases, [("hex8", "blatz_ko"), ("hex8", "blatz_ko"), ("hex8+fbar", "blatz_ko"), ("hex8+fbar", "blatz_ko")]);
    let rows = self::rows(&["--backend", "cpu", "--all", "--kernel", "element_energy", "--element", "quad4+fbar"]);
    assert_eq!(rows.len(), MATERIALS);
    assert!(rows.iter().all(|r| r["element"] == "quad4+fbar"), "{rows:?}");
}

/// Caught by the issue: `bifirst bench` at its defaults ran for 14 minutes with no sign of
/// progress. By default each element takes one material (`--all`: every one), and each case
/// is announced on stderr as it starts.
#[test]
fn bench_defaults_measure_each_element_once_and_say_each_case() {
    let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["bench", "--elements", "60", "--time", "0", "--json", "--backend", "cpu"]).output().unwrap();
    assert!(out.status.success());
    let rows: Vec<Value> = String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(rows.len(), 6 * 4 + 1 + 3 + 2);
    assert!(rows.iter().all(|r| r["material"] == "blatz_ko" || r["material"] == "-"), "{rows:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    for case in ["peaks", "tri3 blatz_ko", "hex8+fbar blatz_ko", "newton_iteration", "uzawa_solve"] {
        assert!(stderr.contains(case), "announces `{case}`: {stderr}");
    }
}

#[test]
fn bench_on_a_gpu_reports_errors_within_the_parity_tolerances() {
    if let Err(e) = bifirst::gpu::open(None, None) {
        assert!(!std::env::var("CI").is_ok_and(|v| v == "true"), "no GPU in CI: {e}");
        eprintln!("SKIPPED bench_on_a_gpu_reports_errors_within_the_parity_tolerances: {e}");
        return;
    }
    let rows = rows(&["--backend", "gpu", "--kernel", "element_force_tangent"]);
    let gpu: Vec<&Value> = rows.iter().filter(|r| r["backend"].as_str().unwrap().starts_with("gpu")).collect();
    assert!(gpu.iter().any(|r| r["kernel"] == "element_force_tangent/forces") && gpu.iter().any(|r| r["kernel"] == "element_force_tangent"));
    for r in gpu {
        let tolerance = if r["backend"] == "gpu f64" { 1e-12 } else { 1e-5 };
        assert!(r["max_relative_error"].as_f64().unwrap() <= tolerance, "{r}");
        assert_eq!(r["bytes_per_call"], 0, "the kernel alone moves nothing between host and device: {r}");
    }
    // The device's sweeps repeat the CPU's, in f64 only, colour by colour and solved whole.
    for kernel in ["uzawa_sweep", "uzawa_solve"] {
        let sweeps = self::rows(&["--backend", "gpu", "--kernel", kernel]);
        let backends: Vec<&str> = sweeps.iter().map(|r| r["backend"].as_str().unwrap()).collect();
        assert_eq!(backends, ["cpu f64", "gpu f64"], "{kernel}");
        assert!(sweeps[1]["max_relative_error"].as_f64().unwrap() <= 1e-12 && sweeps[1]["bytes_per_call"].as_u64().unwrap() > 0, "{:?}", sweeps[1]);
    }
    // A device Newton iteration repeats its CPU twins' (f64 only), and moves states up and down.
    let newton = self::rows(&["--backend", "gpu", "--kernel", "newton_iteration"]);
    let backends: Vec<&str> = newton.iter().map(|r| r["backend"].as_str().unwrap()).collect();
    assert_eq!(backends, ["cpu f64", "gpu f64"]);
    assert!(newton[1]["max_relative_error"].as_f64().unwrap() <= 1e-12 && newton[1]["bytes_per_call"].as_u64().unwrap() > 0, "{:?}", newton[1]);
    // A whole device pass moves the displacements up and the results down.
    let rows = self::rows(&["--backend", "gpu", "--kernel", "evaluate"]);
    assert!(!rows.is_empty() && rows.iter().all(|r| r["bytes_per_call"].as_u64().unwrap() > 0), "{rows:?}");
}
