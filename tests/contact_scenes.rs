//! The contact scenes against their known answers (see the comment block of each scene), each
//! at its defaults and at one other parameter set in the same regime.

#[path = "common/run.rs"]
mod common_run;
use common_run::{run, Log};

fn max(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
}

/// Largest penetration over the run, and the energy balance error at the end.
fn penetration_and_balance(log: &Log) -> (f64, f64) {
    (max(&log.series("/contact", "max_penetration")), *log.series("/energy", "energy_balance_error").last().unwrap())
}

/// Bar of length 1 on a wall: (contact duration, rebound velocity, energy ratio).
fn bar_impact(sets: &[&str], tag: &str, length: f64, modulus: f64, density: f64, speed: f64, h: f64) {
    let log = run("bar_impact", sets, tag);
    let t = log.series("/contact", "t");
    let active = log.series("/contact", "active");
    let dt = t[1] - t[0];
    let touching: Vec<f64> = t.iter().zip(&active).filter(|(_, &a)| a > 0.0).map(|(t, _)| *t).collect();
    let duration = touching.last().unwrap() - touching.first().unwrap() + dt;
    let expected = 2.0 * length / (modulus / density).sqrt();
    let body = &log.topics["/body/bar"];
    let last = body.last().unwrap();
    let rebound = last["linear_momentum"][0].as_f64().unwrap() / last["mass"].as_f64().unwrap();
    let total = log.series("/energy", "total");
    let restored = total.last().unwrap() / total[0];
    let (penetration, balance) = penetration_and_balance(&log);
    println!("{tag}: duration {duration:.5} (2L/c = {expected:.5}), rebound {rebound:.5} (V = {speed}), energy ratio {restored:.5}, penetration/h {:.2e}, balance {balance:.1e}", penetration / h);
    assert!((duration - expected).abs() <= 0.03 * expected, "duration {duration} vs {expected}");
    assert!((rebound - speed).abs() <= 0.02 * speed, "rebound {rebound} vs {speed}");
    assert!((restored - 1.0).abs() <= 0.01, "energy ratio {restored}");
    assert!(penetration <= 0.01 * h, "penetration {penetration}");
    assert!(balance < 1e-6, "energy balance error {balance}");
}

#[test]
fn bar_impact_lasts_2l_over_c_and_rebounds() {
    bar_impact(&[], "bar_default", 1.0, 10000.0, 1.0, 0.5, 0.005);
}

#[test]
fn bar_impact_holds_for_a_softer_heavier_faster_bar() {
    // c = sqrt((2000 + 4 * 1500 / 3) / 4) = sqrt(1000) ~ 31.6; V / c ~ 0.6 %; Courant number 1.
    let sets = ["material.bar.G=1500.0", "material.bar.K=2000.0", "material.bar.density=4.0", "body.bar.initial_velocity=[-0.2, 0.0]", "time.dt=1.5811e-4", "time.end=0.09"];
    bar_impact(&sets, "bar_other", 1.0, 4000.0, 4.0, 0.2, 0.005);
}

/// Block on a floor: stopping distance and friction dissipation against the kinetic energy lost.
fn sliding_block(sets: &[&str], tag: &str, v0: f64, mu: f64, g: f64, h: f64) {
    let log = run("sliding_block", sets, tag);
    let body = &log.topics["/body/block"];
    let x = |m: &serde_json::Value| m["center_of_mass"][0].as_f64().unwrap();
    let distance = x(body.last().unwrap()) - x(&body[0]);
    let expected = v0 * v0 / (2.0 * mu * g);
    let speed_end = body.last().unwrap()["linear_momentum"][0].as_f64().unwrap() / body[0]["mass"].as_f64().unwrap();
    let e = |field: &str| log.series("/energy", field);
    let lost = e("total")[0] - e("total").last().unwrap();
    let friction = *e("friction_dissipation").last().unwrap();
    let (penetration, balance) = penetration_and_balance(&log);
    let c = &log.topics["/contact"];
    let (sliding, sticking) = (c[5]["sliding"].as_f64().unwrap(), c.last().unwrap()["sticking"].as_f64().unwrap());
    println!(
        "{tag}: distance {distance:.5} (v0^2/(2 mu g) = {expected:.5}), end speed {speed_end:.2e}, friction {friction:.5} vs energy lost {lost:.5}, penetration/h {:.2e}, balance {balance:.1e}, sliding early {sliding}, sticking at the end {sticking}",
        penetration / h
    );
    assert!((distance - expected).abs() <= 0.02 * expected, "distance {distance} vs {expected}");
    assert!(speed_end.abs() < 1e-3 * v0, "the block must have stopped: {speed_end}");
    assert!((friction - lost).abs() <= 0.01 * lost, "friction dissipation {friction} vs kinetic energy lost {lost}");
    assert!(sliding > 0.0 && sticking > 0.0, "it slides first and sticks at the end");
    assert!(penetration <= 0.01 * h, "penetration {penetration}");
    assert!(balance < 1e-6, "energy balance error {balance}");
}

#[test]
fn sliding_block_stops_after_v0_squared_over_2_mu_g() {
    sliding_block(&[], "sliding_default", 2.0, 0.5, 9.81, 0.025);
}

#[test]
fn sliding_block_holds_for_other_speed_friction_and_gravity() {
    // d = 1.5^2 / (2 * 0.3 * 5) = 0.75, stopping time 1.0.
    let sets = ["body.block.initial_velocity=[1.5, 0.0]", "contact.friction=0.3", "gravity=[0.0, -5.0]", "time.end=1.2"];
    sliding_block(&sets, "sliding_other", 1.5, 0.3, 5.0, 0.025);
}

/// Two blocks on a floor: the floor's reaction against the weight, and no motion once settled.
fn stack_3d(sets: &[&str], tag: &str, density: f64, g: f64, h: f64) {
    let log = run("stack_3d", sets, tag);
    let weight = density * g * (1.0 * 1.0 * 0.5 + 0.6 * 0.6 * 0.4);
    let floor = log.vectors("/reaction/floor", "force");
    let reaction = floor.last().unwrap()[2];
    // Once settled (second half of the run), the upper block must not move.
    let com = log.vectors("/body/upper", "center_of_mass");
    let half = com.len() / 2;
    let drift = (0..3).map(|i| (com.last().unwrap()[i] - com[half][i]).abs()).fold(0.0, f64::max);
    let speed = log.vectors("/body/upper", "linear_momentum").last().unwrap().iter().map(|p| p.abs()).fold(0.0, f64::max);
    let (penetration, balance) = penetration_and_balance(&log);
    let reaction_spread = floor[half..].iter().map(|f| (f[2] - weight).abs() / weight).fold(0.0, f64::max);
    println!("{tag}: floor reaction {reaction:.3} (weight {weight:.3}), worst over the second half {reaction_spread:.1e}, drift {drift:.1e}, momentum {speed:.1e}, penetration/h {:.2e}, balance {balance:.1e}", penetration / h);
    assert!(reaction_spread <= 0.01, "floor reaction off the weight by {reaction_spread}");
    assert!(drift <= 1e-6 * h, "the upper block drifts by {drift}");
    assert!(penetration <= 0.01 * h, "penetration {penetration}");
    assert!(balance < 1e-6, "energy balance error {balance}");
}

#[test]
fn stack_3d_floor_carries_the_weight_without_creep() {
    stack_3d(&[], "stack_default", 1000.0, 9.81, 0.2);
}

#[test]
fn stack_3d_holds_for_a_softer_lighter_stack_in_lower_gravity() {
    let sets = ["material.rubber.G=2.0e5", "material.rubber.K=6.0e5", "material.rubber.density=500.0", "gravity=[0.0, 0.0, -3.0]", "contact.friction=0.8"];
    stack_3d(&sets, "stack_other", 500.0, 3.0, 0.2);
}
