//! Hertz line contact: the cylinder of `scenes/hertz_cylinder.toml` against the rigid floor,
//! judged from the per-point contact data (forces and positions of the floor's contact nodes).

#[path = "common/run.rs"]
mod common_run;
use bifirst::contact::Master;
use bifirst::scene::load_scene;
use bifirst::solver::build_simulation;

/// Plane-strain contact modulus of the neo-Hookean material's small-strain limit.
fn contact_modulus(g: f64, k: f64) -> f64 {
    let e = 9.0 * k * g / (3.0 * k + g);
    let nu = (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g));
    e / (1.0 - nu * nu)
}

fn hertz(sets: &[&str], tag: &str, g: f64, k: f64) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = load_scene(&common_run::scene_path("hertz_cylinder"), &sets).expect("scene loads");
    let mut sim = build_simulation(&loaded).expect("scene builds");
    sim.start();
    while !sim.finished() {
        sim.advance().expect("step converges");
    }
    let floor = sim.contact().as_ref().unwrap().obstacles.iter().position(|o| o.name == "floor").unwrap() as u32;
    let body = &sim.bodies()[0];
    // (x, normal force) of every floor contact point, by x.
    let mut points: Vec<(f64, f64)> = sim.contact_points().iter().filter(|c| matches!(c.master, Master::Obstacle { obstacle, .. } if obstacle == floor)).map(|c| (body.position(c.slave_node as usize)[0], c.r[0])).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    let load: f64 = points.iter().map(|p| p.1).sum();
    let center = points.iter().map(|p| p.0 * p.1).sum::<f64>() / load;
    // For p(x) = p0 sqrt(1 - x^2/a^2), the second moment of the load is a^2 / 4 of it.
    let half_width = 2.0 * (points.iter().map(|p| (p.0 - center).powi(2) * p.1).sum::<f64>() / load).sqrt();
    let peak = (1..points.len() - 1).max_by(|&i, &j| points[i].1.total_cmp(&points[j].1)).unwrap();
    let peak_pressure = points[peak].1 / (0.5 * (points[peak + 1].0 - points[peak - 1].0));
    let e_star = contact_modulus(g, k);
    let a = (4.0 * load / (std::f64::consts::PI * e_star)).sqrt();
    let p0 = 2.0 * load / (std::f64::consts::PI * a);
    let active = points.iter().filter(|p| p.1 > 0.0).count();
    let penetration = sim.contact_points().iter().map(|c| -c.end_gap).fold(0.0, f64::max);
    let h = body.length_scale();
    let reaction = sim.obstacle_reactions()[floor as usize][1];
    println!(
        "{tag}: load {load:.3} (floor reaction {reaction:.3}), half-width {half_width:.4} vs Hertz {a:.4} ({:+.2} %), peak pressure {peak_pressure:.2} vs {p0:.2} ({:+.2} %), {active} nodes in contact, penetration/h {:.1e}",
        100.0 * (half_width / a - 1.0),
        100.0 * (peak_pressure / p0 - 1.0),
        penetration / h
    );
    assert!((load - reaction).abs() <= 1e-9 * load, "the floor's reaction is the sum of its contact forces");
    assert!(active >= 9, "the contact strip must span several nodes ({active})");
    assert!((half_width - a).abs() <= 0.05 * a, "half-width {half_width} vs {a}");
    assert!((peak_pressure - p0).abs() <= 0.10 * p0, "peak pressure {peak_pressure} vs {p0}");
    assert!(penetration <= 0.01 * h, "penetration {penetration}");
}

#[test]
fn hertz_cylinder_half_width_and_peak_pressure() {
    hertz(&[], "hertz_default", 1000.0, 2000.0);
}

#[test]
fn hertz_cylinder_holds_for_a_stiffer_less_compressible_material() {
    let sets = ["material.rubber.G=2000.0", "material.rubber.K=5000.0", "obstacle.plate.velocity=[0.0, -0.004]"];
    hertz(&sets, "hertz_other", 2000.0, 5000.0);
}

/// Nearly incompressible rubber (K/G = 1000, F-bar by default): the displacement element locked
/// and the contact strip narrowed.
#[test]
fn hertz_cylinder_holds_for_nearly_incompressible_rubber() {
    hertz(&["material.rubber.K=1.0e6"], "hertz_incompressible", 1000.0, 1.0e6);
}
