//! The engine-core scenes against their known answers (see the comment block of each scene).

#[path = "common/run.rs"]
mod common_run;
use common_run::run;

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn max_relative_change(series: &[Vec<f64>]) -> f64 {
    let first = &series[0];
    series.iter().map(|v| norm(&v.iter().zip(first).map(|(a, b)| a - b).collect::<Vec<_>>()) / norm(first)).fold(0.0, f64::max)
}

#[test]
fn free_flight_3d_conserves_momentum() {
    let log = run("free_flight_3d", &[], "free_flight");
    let p = log.vectors("/body/block", "linear_momentum");
    let l = log.vectors("/body/block", "angular_momentum");
    assert_eq!(p.len(), 101, "initial state + 100 steps");
    let (dp, dl) = (max_relative_change(&p), max_relative_change(&l));
    println!("free flight: linear momentum drift {dp:e}, angular {dl:e}");
    assert!(dp < 1e-10, "linear momentum drift {dp:e}");
    assert!(dl < 1e-6, "angular momentum drift {dl:e}");
}

fn energy_drift(log: &common_run::Log) -> f64 {
    let total = log.series("/energy", "total");
    total.iter().map(|e| (e - total[0]).abs() / total[0]).fold(0.0, f64::max)
}

#[test]
fn free_vibration_2d_conserves_energy_at_small_amplitude() {
    let log = run("free_vibration_2d", &[], "vibration_small");
    assert_eq!(log.topics["/energy"].len(), 201);
    let drift = energy_drift(&log);
    println!("small amplitude: max energy drift {drift:e}");
    assert!(drift < 1e-3, "drift {drift:e}");
    // It really vibrates: strain energy takes a large share of the energy at some point.
    let strain = log.series("/energy", "strain");
    assert!(strain.iter().cloned().fold(0.0, f64::max) > 0.5 * log.series("/energy", "total")[0]);
}

#[test]
fn free_vibration_2d_conserves_energy_at_large_amplitude() {
    let log = run("free_vibration_2d", &["body.beam.initial_velocity=[0.0, 3.0]"], "vibration_large");
    let drift = energy_drift(&log);
    let tip = log.vectors("/probe/tip", "displacement");
    let max_tip = tip.iter().map(|d| d[1].abs()).fold(0.0, f64::max);
    println!("large amplitude: max energy drift {drift:e}, tip deflection {max_tip}");
    assert!(max_tip > 0.5, "the large-amplitude case must deflect the tip by over 1/8 of the length");
    assert!(drift < 1e-2, "drift {drift:e}");
}

#[test]
fn free_vibration_2d_with_theta_one_decays() {
    let log = run("free_vibration_2d", &["time.theta=1.0"], "vibration_theta1");
    let total = log.series("/energy", "total");
    println!("theta = 1: E(end)/E(0) = {}", total.last().unwrap() / total[0]);
    assert!(total.windows(2).all(|w| w[1] <= w[0] * (1.0 + 1e-9)), "energy must not grow");
    assert!(*total.last().unwrap() < 0.9 * total[0], "energy must decay");
}

/// Closed form of eq. (3) in uniaxial stress: nominal force G A0 (l^-1/2 - l^-3).
fn blatz_ko_uniaxial_force(g: f64, stretch: f64) -> f64 {
    g * (stretch.powf(-0.5) - stretch.powi(-3))
}

fn check_uniaxial(sets: &[&str], tag: &str, g: f64, v: f64) {
    let log = run("uniaxial_blatz_ko", sets, tag);
    let t = log.series("/reaction/pull", "t");
    let f = log.vectors("/reaction/pull", "force");
    let mut checked = 0;
    for (t, f) in t.iter().zip(&f) {
        let stretch = 1.0 + v * t;
        if (t * 10.0 - (t * 10.0).round()).abs() < 1e-9 && *t > 0.15 {
            let expected = blatz_ko_uniaxial_force(g, stretch);
            let err = (f[0] - expected).abs() / expected;
            println!("stretch {stretch:.3}: reaction {:.6e}, eq. (3) {expected:.6e}, error {err:.2e}", f[0]);
            assert!(err < 5e-3, "stretch {stretch}: error {err:e}");
            checked += 1;
        }
    }
    assert!(checked >= 5);
}

#[test]
fn uniaxial_blatz_ko_matches_eq3() {
    check_uniaxial(&[], "uniaxial_default", 1000.0, 0.5);
}

#[test]
fn uniaxial_blatz_ko_matches_eq3_at_other_parameters() {
    check_uniaxial(&["material.foam.G=40.0", "boundary.pull.velocity=[1.2, 0.0, 0.0]", "material.foam.density=0.001"], "uniaxial_other", 40.0, 1.2);
}

/// Caught in the grain packings: the residual's round-off floor was scaled by the mesh size,
/// while the inertia term's round-off grows with the distance a body has travelled, so a small
/// grain far from its start could never converge and every step was cut back.
#[test]
fn newton_converges_for_a_small_body_far_from_its_start() {
    let scene = r#"
[time]
end = 0.5
dt = 0.005
xi = 1.0
theta = 1.0

[material.rubber]
model = "blatz_ko"
G = 1000.0
density = 1.0

[body.grain]
material = "rubber"
mesh = { generator = "polygon", element = "tri3", points = [[0.0, 0.0], [0.3, 0.0], [0.1, 0.25]], divisions = [3] }
initial_velocity = [40.0, -30.0]
angular_velocity = 5.0
"#;
    let path = common_run::temp_path("far_travel.toml");
    std::fs::write(&path, scene).unwrap();
    let log = common_run::run_with(&path, &[], "far_travel", &Default::default());
    let cutbacks: f64 = log.series("/solver", "cutbacks").iter().sum();
    assert_eq!(cutbacks, 0.0, "no step is cut back for round-off");
    let travel = log.vectors("/body/grain", "center_of_mass");
    assert!((travel.last().unwrap()[0] - travel[0][0] - 20.0).abs() < 1e-6, "the grain flies 20 in x");
}
