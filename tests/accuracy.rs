//! `bifirst accuracy` on small grids: one row per variant, errors that fall as the time step is
//! refined for the bar impact and the sliding block (their convergence order printed), and a PNG
//! that decodes with the front drawn.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `bifirst accuracy` and returns its stdout and the CSV rows (header first).
fn accuracy(args: &[&str], out: &Path) -> (String, Vec<Vec<String>>) {
    let _ = std::fs::remove_dir_all(out);
    let o = Command::new(env!("CARGO_BIN_EXE_bifirst")).arg("accuracy").args(args).args(["--backend", "cpu", "--out"]).arg(out).current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "exit {:?}\n{stdout}\n{}", o.status.code(), String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("accuracy.csv")).unwrap();
    // No quoted commas in these grids: a plain split is the CSV.
    (stdout, csv.lines().map(|l| l.split(',').map(String::from).collect()).collect())
}

fn column(rows: &[Vec<String>], name: &str) -> Vec<f64> {
    let c = rows[0].iter().position(|h| h == name).unwrap_or_else(|| panic!("column `{name}` in {:?}", rows[0]));
    rows[1..].iter().map(|r| r[c].parse().unwrap()).collect()
}

fn out_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join(name)
}

fn assert_falls(errors: &[f64], what: &str) {
    assert!(errors.windows(2).all(|w| w[1] < w[0]), "{what}: the error falls as dt is refined: {errors:?}");
}

#[test]
fn bar_impact_error_falls_with_the_time_step_and_the_front_is_drawn() {
    let out = out_dir("accuracy_bar");
    let (stdout, rows) = accuracy(&["scenes/bar_impact.toml", "--over", "time.dt=2e-4,1e-4"], &out);
    assert_eq!(rows.len(), 3, "a header and one row per variant:\n{rows:?}");
    assert_eq!(stdout.lines().filter(|l| l.contains("dt=") && l.contains("finished")).count(), 2, "one table row per variant:\n{stdout}");
    assert_falls(&column(&rows, "error"), "bar_impact");
    let duration = column(&rows, "contact duration expected");
    assert!((duration[0] - 0.02).abs() < 1e-12, "2 L / c = 0.02 for the shipped bar: {duration:?}");
    assert!(stdout.contains("order along time.dt, 2e-4 -> 1e-4: d log(error) / d log(value) = "), "{stdout}");
    assert!(rows.iter().skip(1).all(|r| r.last().is_some()), "every variant has its error terms");
    assert!(out.join("bar_impact_dt-2e-4.mcap").is_file(), "each variant keeps its log");

    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(out.join("accuracy.png")).unwrap()));
    let mut reader = decoder.read_info().expect("a PNG");
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).expect("decodes");
    let rgb: Vec<&[u8]> = pixels.chunks(info.line_size / info.width as usize).collect();
    assert!(rgb.iter().filter(|p| p[..3] == [214, 39, 40]).count() > 100, "the front is drawn in red");
}

#[test]
fn sliding_block_error_falls_with_the_time_step() {
    let out = out_dir("accuracy_sliding");
    let (stdout, rows) = accuracy(&["scenes/sliding_block.toml", "--over", "time.dt=4e-3,2e-3,1e-3", "--set", "body.block.mesh.divisions=[4,2]"], &out);
    assert_eq!(rows.len(), 4, "{rows:?}");
    assert_falls(&column(&rows, "error"), "sliding_block");
    assert_falls(&column(&rows, "stopping distance error"), "stopping distance");
    let orders: Vec<&str> = stdout.lines().filter(|l| l.starts_with("order along time.dt")).collect();
    assert_eq!(orders.len(), 2, "{stdout}");
    // The stopping distance is first order in dt (the friction force acts from the end-of-step
    // velocity): the coarsest pair shows it.
    let distance = column(&rows, "stopping distance error");
    let order = (distance[0] / distance[1]).log2();
    assert!((order - 1.0).abs() < 0.2, "first order: {order:.2} from {distance:?}");
    assert!(stdout.contains("cheapest within 1.0e-2: variant"), "{stdout}");
}

#[test]
fn backend_and_precision_are_axes_and_unknown_scenes_are_refused() {
    let bifirst = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_bifirst"));
        c.current_dir(env!("CARGO_MANIFEST_DIR"));
        c
    };
    let o = bifirst().args(["accuracy", "scenes/grains_many.toml", "--over", "time.dt=1e-3"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("no known answer named `grains_many`; the measures are bar_impact, sliding_block, hertz_cylinder, thick_cylinder, free_vibration_2d, free_vibration_3d, free_flight_3d"), "{stderr}");
    let o = bifirst().args(["accuracy", "scenes/sliding_block.toml", "--over", "backend=cpu,tpu"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("`--over backend`: unknown backend `tpu`"), "{}", String::from_utf8_lossy(&o.stderr));

    // A renamed copy of a known-answer scene takes its measure by --measure.
    let out = out_dir("accuracy_measure");
    let (stdout, rows) = accuracy(&["scenes/free_flight_3d.toml", "--set", "name=\"spinning\"", "--set", "time.end=0.02", "--measure", "free_flight_3d", "--over", "backend=cpu"], &out);
    assert_eq!(rows.len(), 2, "{stdout}");
    assert!(column(&rows, "linear momentum drift error")[0] < 1e-10, "{stdout}");
}

/// A variant whose run fails is a row with its status and reason, off the front, and fails the
/// command; the convergence order skips it.
#[test]
fn a_variant_that_fails_is_reported_and_kept_off_the_front() {
    let out = out_dir("accuracy_failing");
    let _ = std::fs::remove_dir_all(&out);
    let o = Command::new(env!("CARGO_BIN_EXE_bifirst"))
        .args(["accuracy", "scenes/sliding_block.toml", "--over", "solver.max_iterations=1,25", "--set", "solver.max_cutbacks=0", "--set", "time.end=0.05", "--backend", "cpu", "--out"])
        .arg(&out)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(1), "{stdout}");
    assert!(stdout.contains("variant 0 (max_iterations=1): step 1 at t = 0.000000e0 failed"), "{stdout}");
    assert!(!stdout.contains("order along"), "no order from a failed run: {stdout}");
    let csv = std::fs::read_to_string(out.join("accuracy.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[1].contains(",failed,") && rows[1].contains(",false,"), "the failed variant is off the front: {csv}");
    assert!(rows[2].contains(",finished,") && rows[2].contains(",true,"), "{csv}");
}
