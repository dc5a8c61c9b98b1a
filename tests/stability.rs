//! The stress grid of doc/stability.md that must stay stable: `bifirst stability` over shipped
//! scenes, along the time step and the impact or wall speed, where the doc says they are stable.

#[path = "common/run.rs"]
mod common;

use bifirst::stability::{largest_stable, Budget, Class, Study};
use bifirst::sweep::SweepAxis;
use common::{scene_path, temp_path};
use std::process::Command;

const BUDGET: Budget = Budget { sweeps_per_step: 2000.0, wall_s: 120.0 };

fn axes(specs: &[&str]) -> Vec<SweepAxis> {
    specs.iter().map(|s| s.parse().expect("axis")).collect()
}

fn assert_all_stable(scene: &str, sets: &[&str], over: &[&str], dir: &str) -> Vec<bifirst::stability::Row> {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let axes = axes(over);
    let study = Study::plan(&scene_path(scene), &sets, &axes).expect("the grid validates");
    let rows = study.run(&temp_path(dir), BUDGET, &Default::default(), None, |_| {}).expect("the variants run");
    for r in &rows {
        assert_eq!(r.class, Class::Stable, "{scene} {}: {:?}", r.label, r.reasons);
    }
    rows
}

/// bar_impact up to 4 times its time step and 10 times its impact speed: the rebound keeps
/// its energy (none created), no overlap beyond 1 % of an element.
#[test]
fn bar_impact_is_stable_over_dt_and_impact_speed() {
    let over = ["time.dt=5e-5,2e-4", "body.bar.initial_velocity=[-0.5, 0.0],[-5.0, 0.0]"];
    let rows = assert_all_stable("bar_impact", &[], &over, "stability_bar_impact");
    let largest = largest_stable(&axes(&over), &rows);
    assert_eq!(largest[0].1.as_deref(), Some("2e-4"));
    assert_eq!(largest[1].1.as_deref(), Some("[-5.0, 0.0]"));
}

/// A small grains_many packing at twice its time step and twice its wall speed.
#[test]
fn grains_many_is_stable_over_dt_and_wall_speed() {
    assert_all_stable("grains_many", &["packing.count=16", "time.end=0.3"], &["time.dt=0.005,0.01", "packing.wall_velocity=2.0,4.0"], "stability_grains_many");
}

/// The command: table, CSV, map, the largest stable values, and exit 1 when a variant is not
/// stable (here a time step far too large for the impact speed).
#[test]
fn stability_command_writes_its_table_csv_and_map() {
    let out = temp_path("stability_command");
    let _ = std::fs::remove_dir_all(&out);
    let output = Command::new(env!("CARGO_BIN_EXE_bifirst"))
        .args(["stability", scene_path("bar_impact").to_str().unwrap(), "--over", "time.dt=1e-4,2.5e-3", "--over", "body.bar.initial_velocity=[-0.5, 0.0],[-50.0, 0.0]", "--out", out.to_str().unwrap()])
        .output()
        .expect("bifirst runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(1), "{stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains("largest stable time.dt: 1e-4"), "{stdout}");
    let csv = std::fs::read_to_string(out.join("stability.csv")).expect("stability.csv");
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(csv.lines().nth(4).unwrap().contains("failed") || csv.lines().nth(4).unwrap().contains("degraded"), "{csv}");
    let png = std::fs::read(out.join("stability.png")).expect("stability.png");
    assert_eq!(&png[1..4], b"PNG");
}
