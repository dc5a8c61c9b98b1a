//! The paper's examples (section 5) at reduced resolution: the Love-Laursen blocks swept over
//! the friction coefficient with `bifirst sweep`, and the Blatz-Ko grains compressed in a box.

#[path = "common/run.rs"]
mod common;

use common::{read_log, temp_path};
use std::process::Command;

/// The Love-Laursen scene on a coarser mesh (the striker still the finer, slave body) up to
/// t = 0.5: the impact at t = 0.1, the sliding and the rebound (contact ends near t = 0.35).
const REDUCED: [&str; 3] = ["body.base.mesh.divisions=[6,6,2]", "body.striker.mesh.divisions=[4,4,3]", "time.end=0.5"];

#[test]
fn love_laursen_sweep_conserves_without_friction_and_dissipates_with_it() {
    let out = temp_path("love_laursen_sweep");
    let _ = std::fs::remove_dir_all(&out);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_bifirst"));
    cmd.args(["sweep", "scenes/love_laursen.toml", "--over", "contact.friction=0,0.5", "--backend", "cpu", "--trace", "B,C,D", "--jobs", "2", "--out"]).arg(&out);
    for set in REDUCED {
        cmd.args(["--set", set]);
    }
    let result = cmd.current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(result.status.success(), "sweep failed:\n{stdout}\n{}", String::from_utf8_lossy(&result.stderr));
    assert!(stdout.lines().next().unwrap().contains("friction=0") && stdout.contains("friction=0.5"), "one summary column per variant:\n{stdout}");
    for plot in ["energies", "probe_A", "trace_B"] {
        assert!(out.join("plots").join(format!("{plot}.png")).is_file(), "{plot}.png is drawn");
    }

    let frictionless = read_log(&out.join("love_laursen_friction-0.mcap"));
    let total = frictionless.series("/energy", "total");
    let drift = (total.last().unwrap() - total[0]) / total[0];
    assert!(drift.abs() < 0.02, "at mu = 0 the total energy drifts by {drift:.3e} (impact of the contact nodes only)");
    assert!(frictionless.series("/contact", "active").iter().any(|&n| n > 0.0), "the blocks meet");

    let sliding = read_log(&out.join("love_laursen_friction-0.5.mcap"));
    let e0 = total[0];
    // The xi = theta = 1/2 quadrature of a nonlinear internal force is not exact: at mu = 0 it
    // moves up to about 3e-5 E0 per step between strain energy and numerical dissipation, both
    // ways. That is the tolerance for "non-increasing"; friction itself only ever removes energy.
    let scheme_tolerance = 1e-4 * e0;
    let total = sliding.series("/energy", "total");
    for (step, w) in total.windows(2).enumerate() {
        assert!(w[1] - w[0] < scheme_tolerance, "step {}: the total energy rises by {:.3e}", step + 1, w[1] - w[0]);
    }
    let friction = sliding.series("/energy", "friction_dissipation");
    assert!(friction.windows(2).all(|w| w[1] >= w[0]), "friction never gives energy back");
    assert!(friction.last().unwrap() > &(0.1 * e0), "the striker slides: friction dissipates {:.3e} of {e0:.3e}", friction.last().unwrap());
    assert!(total.last().unwrap() < &(total[0] - 0.1 * e0), "the total energy decreases with friction");
    for log in [&frictionless, &sliding] {
        let balance = log.series("/energy", "energy_balance_error").into_iter().fold(0.0, f64::max);
        assert!(balance < 0.01, "the energy balance closes: error {balance:.2e}");
    }
}

/// Depth of `x` inside body `b` of `sim` (its deformed triangles), as the distance to the
/// body's outline; `None` when `x` is outside.
fn depth_inside(sim: &bifirst::solver::Simulation, b: usize, x: [f64; 3]) -> Option<f64> {
    let body = &sim.bodies()[b];
    let inside = (0..body.mesh().element_count()).any(|e| {
        let p: Vec<[f64; 3]> = body.mesh().element(e).iter().map(|&n| body.position(n as usize)).collect();
        let cross = |a: [f64; 3], c: [f64; 3]| (c[0] - a[0]) * (x[1] - a[1]) - (c[1] - a[1]) * (x[0] - a[0]);
        (0..3).all(|i| cross(p[i], p[(i + 1) % 3]) > 0.0)
    });
    inside.then(|| {
        let surface = &sim.contact().as_ref().expect("contact scene").surfaces[b];
        (0..surface.facet_count())
            .map(|f| {
                let [a, c] = [0, 1].map(|k| body.position(surface.facet(f)[k] as usize));
                let (d, w) = ([c[0] - a[0], c[1] - a[1]], [x[0] - a[0], x[1] - a[1]]);
                let s = ((w[0] * d[0] + w[1] * d[1]) / (d[0] * d[0] + d[1] * d[1])).clamp(0.0, 1.0);
                (w[0] - s * d[0]).hypot(w[1] - s * d[1])
            })
            .fold(f64::INFINITY, f64::min)
    })
}

#[test]
fn grains_box_compresses_without_failure_penetration_or_pass_through() {
    let loaded = bifirst::scene::load_scene(&common::scene_path("grains_box"), &[]).unwrap();
    let mut sim = bifirst::solver::build_simulation(&loaded).unwrap();
    assert!(sim.bodies().len() >= 7, "at least seven grains");
    let h_min = sim.bodies().iter().map(|b| b.length_scale()).fold(f64::INFINITY, f64::min);
    let tolerance = 0.01 * h_min;
    sim.start();
    let (mut max_penetration, mut cutbacks, mut deepest) = (0.0f64, 0, 0.0f64);
    while !sim.finished() {
        let report = sim.advance().unwrap_or_else(|f| panic!("step {} failed: {}", f.step, f.failure));
        // Step control's retries (a node pressed deeper than 1 % of its element) are cut-backs
        // by design; a cut-back for any other reason is a failed step.
        cutbacks += report.cutbacks.saturating_sub(report.overlap_retries + report.energy_retries);
        max_penetration = max_penetration.max(report.contact.max_penetration);
        if !report.step.is_multiple_of(10) && !sim.finished() {
            continue;
        }
        // The box: the left wall has moved by 1.2 t.
        let (left, right, bottom, top) = (1.2 * sim.t(), 6.0, 0.0, 4.0);
        for (a, body) in sim.bodies().iter().enumerate() {
            for n in 0..body.mesh().nodes.len() {
                let x = body.position(n);
                assert!(x[0] > left - tolerance && x[0] < right + tolerance && x[1] > bottom - tolerance && x[1] < top + tolerance, "t = {}: {} node {n} at {x:?} is out of the box", sim.t(), body.name());
                for b in (0..sim.bodies().len()).filter(|&b| b != a) {
                    if let Some(depth) = depth_inside(&sim, b, x) {
                        // Single-pass node-to-segment contact holds the slave's nodes out of the
                        // master (the logged penetration); a master's corner can still sit
                        // between two slave nodes, by the sagitta of the slave's facets. A
                        // grain passing through another would be a whole element deep.
                        assert!(depth < 0.25 * h_min, "t = {}: {} node {n} is {depth:.3e} inside {}", sim.t(), body.name(), sim.bodies()[b].name());
                        deepest = deepest.max(depth);
                    }
                }
            }
        }
    }
    eprintln!("grains_box: max penetration {max_penetration:.3e}, deepest node inside another grain {deepest:.3e}, smallest element {h_min:.3e}");
    assert!(max_penetration < tolerance, "max penetration {max_penetration:.3e} vs 1 % of the smallest element {h_min:.3e}");
    assert_eq!(cutbacks, 0, "no step failed");
    // The loading compresses the grains: the bottom row carries a stress of the order of G.
    let peak = sim.bodies().iter().flat_map(|b| b.cell_fields()).map(|f| f.von_mises).fold(0.0, f64::max);
    assert!(peak > 100.0, "the grains are loaded (peak von Mises {peak:.3e})");
}

#[test]
fn grains_many_packing_is_reproducible_and_runs() {
    let load = |sets: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        bifirst::scene::load_scene(&common::scene_path("grains_many"), &sets).unwrap()
    };
    let grains = |sets: &[&str]| {
        let loaded = load(sets);
        let sim = bifirst::solver::build_simulation(&loaded).unwrap();
        sim.bodies().iter().map(|b| b.mesh().nodes.clone()).collect::<Vec<_>>()
    };
    assert_eq!(grains(&["packing.count=30"]).len(), 30);
    assert_eq!(grains(&["packing.count=30"]), grains(&["packing.count=30"]), "a seed gives one packing");
    assert_ne!(grains(&["packing.count=30"]), grains(&["packing.count=30", "packing.seed=2"]), "another seed, another packing");
    // Both shapes are drawn, and the resolved scene keeps the `[packing]` section, not its output.
    let loaded = load(&["packing.count=30"]);
    let shapes: std::collections::BTreeSet<_> = loaded.scene.body.values().map(|b| format!("{:?}", b.mesh.generator)).collect();
    assert_eq!(shapes.len(), 2, "disks and polygons: {shapes:?}");
    assert!(loaded.resolved_toml.contains("[packing]") && !loaded.resolved_toml.contains("grain_0001"));

    // No two grains overlap at t = 0, and none touches a wall.
    let sim = bifirst::solver::build_simulation(&loaded).unwrap();
    let bounds: Vec<[f64; 4]> = sim.bodies().iter().map(|b| b.mesh().nodes.iter().fold([f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY], |a, x| [a[0].min(x[0]), a[1].max(x[0]), a[2].min(x[1]), a[3].max(x[1])])).collect();
    let width = bounds.iter().map(|b| b[1]).fold(0.0, f64::max);
    for (i, a) in bounds.iter().enumerate() {
        assert!(a[0] > 0.0 && a[2] > 0.0, "grain {i} is clear of the left and bottom walls");
        for b in &bounds[i + 1..] {
            // Grains live in disjoint lattice cells, so their bounding boxes may touch only
            // across a cell edge; an overlap of boxes in both directions would mean shared room.
            assert!(a[1] <= b[0] || b[1] <= a[0] || a[3] <= b[2] || b[3] <= a[2], "grains {i} and another overlap");
        }
    }
    assert!(width > 0.0);

    let log = common::run("grains_many", &["packing.count=12", "time.end=0.1", "output.scene_every=0"], "grains_many_12");
    assert_eq!(log.series("/solver", "step").len(), 20, "every step of the small packing converges");
}

/// Building a pattern, gather map and symbolic factorisation per grain was most of the set-up
/// of a large packing and most of its memory: grains of one shape share them.
#[test]
fn grains_of_one_shape_share_their_topology() {
    let loaded = bifirst::scene::load_scene(&common::scene_path("grains_many"), &["packing.count=60".to_string()]).unwrap();
    let sim = bifirst::solver::build_simulation(&loaded).unwrap();
    let mut shapes: Vec<&Vec<u32>> = sim.bodies().iter().map(|b| &b.mesh().connectivity).collect();
    shapes.sort();
    shapes.dedup();
    let mut patterns: Vec<*const bifirst::assembly::StiffnessPattern> = sim.bodies().iter().map(|b| b.pattern() as *const _).collect();
    patterns.sort();
    patterns.dedup();
    assert_eq!(patterns.len(), shapes.len(), "one pattern per distinct connectivity");
    assert!(shapes.len() < 20, "60 grains, {} shapes", shapes.len());
}

#[test]
fn grains_3d_packing_is_reproducible_and_starts_apart() {
    let load = |sets: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        bifirst::scene::load_scene(&common::scene_path("grains_3d"), &sets).unwrap()
    };
    let grains = |sets: &[&str]| {
        let sim = bifirst::solver::build_simulation(&load(sets)).unwrap();
        sim.bodies().iter().map(|b| b.mesh().nodes.clone()).collect::<Vec<_>>()
    };
    let small = ["packing.count=64"];
    assert_eq!(grains(&small).len(), 64);
    assert_eq!(grains(&small), grains(&small), "a seed gives one packing");
    assert_ne!(grains(&small), grains(&["packing.count=64", "packing.seed=2"]), "another seed, another packing");
    // Balls and turned boxes are drawn, in Tet4 and, on request, Hex8.
    let loaded = load(&small);
    let shapes: std::collections::BTreeSet<_> = loaded.scene.body.values().map(|b| format!("{:?}", b.mesh.generator)).collect();
    assert_eq!(shapes.len(), 2, "balls and boxes: {shapes:?}");
    assert!(loaded.scene.body.values().any(|b| b.mesh.rotation.as_ref().is_some_and(|w| w.iter().any(|c| *c != 0.0))));
    assert!(loaded.resolved_toml.contains("[packing]") && !loaded.resolved_toml.contains("grain_0001"));
    let hex = bifirst::solver::build_simulation(&load(&["packing.count=8", "packing.element=\"hex8\""])).unwrap();
    assert!(hex.bodies().iter().all(|b| b.mesh().kind == bifirst::mesh::ElementKind::Hex8));

    // No two grains overlap at t = 0 and none touches a wall: each grain lies in the ball of its
    // radius about its lattice cell's point, and two such balls are apart.
    let sim = bifirst::solver::build_simulation(&loaded).unwrap();
    let spheres: Vec<([f64; 3], f64)> = sim
        .bodies()
        .iter()
        .map(|b| {
            let n = b.mesh().nodes.len() as f64;
            let c = [0, 1, 2].map(|i| b.mesh().nodes.iter().map(|x| x[i]).sum::<f64>() / n);
            let r = b.mesh().nodes.iter().map(|x| (0..3).map(|i| (x[i] - c[i]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
            (c, r)
        })
        .collect();
    for (i, (a, ra)) in spheres.iter().enumerate() {
        assert!((0..3).all(|k| a[k] - ra > 0.0), "grain {i} is clear of the left, bottom and back walls");
        for (b, rb) in &spheres[i + 1..] {
            let d = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
            assert!(d > ra + rb, "grain {i} and another overlap at t = 0");
        }
    }
    assert!(sim.overlaps().is_empty(), "the engine's overlap search agrees");
}

#[test]
fn contour_png_of_a_2d_state_and_a_clear_error_in_3d() {
    let png = temp_path("grains_box_contour.png");
    let _ = std::fs::remove_file(&png);
    let options = bifirst::run::RunOptions { contour: Some(png.clone()), ..Default::default() };
    common::run_with(&common::scene_path("grains_box"), &["time.end=0.01", "output.scene_every=0"], "grains_box_contour", &options);
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).expect("the PNG is written")));
    let info = decoder.read_info().expect("a valid PNG").info().clone();
    assert!(info.width > 1000 && info.height > 300, "{}x{}", info.width, info.height);

    let loaded = bifirst::scene::load_scene(&common::scene_path("love_laursen"), &[]).unwrap();
    let err = bifirst::run::run_scene(&loaded, &temp_path("ll_contour.mcap"), &options, &mut bifirst::run::Silent).unwrap_err();
    assert!(err.to_string().contains("2D scenes"), "{err}");
}
