//! `--set KEY=VALUE`: the keys scripts rely on must address exactly these scene values.

#[path = "common/run.rs"]
mod common_run;

use bifirst::scene::load_scene;

#[test]
fn documented_keys_override_the_scene() {
    let sets: Vec<String> =
        ["time.dt=0.005", "time.end=0.5", "time.xi=0.6", "time.theta=0.7", "material.rubber.G=4000", "material.rubber.density=2.5", "body.beam.initial_velocity=[1, 0]", "gravity=[0,-9.81]", "solver.max_cutbacks=3"].map(String::from).to_vec();
    let loaded = load_scene(&common_run::scene_path("free_vibration_2d"), &sets).expect("overrides are valid");
    let s = &loaded.scene;
    assert_eq!((s.time.dt, s.time.end, s.time.xi, s.time.theta), (0.005, 0.5, 0.6, 0.7));
    assert_eq!(s.material["rubber"].number("G"), Some(4000.0), "integer literals are accepted for reals");
    assert_eq!(s.material["rubber"].density, 2.5);
    assert_eq!(s.body["beam"].initial_velocity, Some(vec![1.0, 0.0]));
    assert_eq!(s.gravity, Some(vec![0.0, -9.81]));
    assert_eq!(s.solver.max_cutbacks, 3);
    // The resolved scene text carries the overrides and loads again to the same values.
    let again = bifirst::scene::parse_scene(&loaded.path, loaded.resolved_toml.clone(), &[]).expect("resolved scene is valid");
    assert_eq!(again.scene.material["rubber"].number("G"), Some(4000.0));
    assert_eq!(again.scene.gravity, Some(vec![0.0, -9.81]));
}

#[test]
fn later_sets_win() {
    let sets: Vec<String> = ["time.dt=0.005", "time.dt=0.002"].map(String::from).to_vec();
    let loaded = load_scene(&common_run::scene_path("free_vibration_2d"), &sets).unwrap();
    assert_eq!(loaded.scene.time.dt, 0.002);
}
