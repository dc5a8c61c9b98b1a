//! The local contact law on its own: the projection onto the Coulomb cone in each of its cases
//! (stick, slip, separation, the apex), the Uzawa step's fixed points, and the law at the
//! converged contact points of a real run.

#[path = "common/run.rs"]
mod common_run;
#[path = "common/random.rs"]
mod random;
use bifirst::contact::{project_on_cone, uzawa_step, Status};
use bifirst::scene::load_scene;
use bifirst::solver::build_simulation;
use rand::Rng;

fn tangential(x: &[f64; 3]) -> f64 {
    (x[1] * x[1] + x[2] * x[2]).sqrt()
}

#[test]
fn projection_keeps_points_inside_the_cone() {
    let (r, s) = project_on_cone([2.0, 0.3, -0.4], 0.5);
    assert_eq!(s, Status::Sticking);
    assert_eq!(r, [2.0, 0.3, -0.4]);
}

#[test]
fn projection_sends_the_polar_cone_to_zero() {
    // mu |tau_t| <= -tau_n: the polar cone, separation.
    let (r, s) = project_on_cone([-1.0, 1.5, 0.0], 0.5);
    assert_eq!(s, Status::Separated);
    assert_eq!(r, [0.0; 3]);
}

#[test]
fn projection_onto_the_cone_surface_is_the_nearest_point() {
    let mu = 0.4;
    let tau = [1.0, 2.0, 1.0];
    let (r, s) = project_on_cone(tau, mu);
    assert_eq!(s, Status::Sliding);
    assert!((tangential(&r) - mu * r[0]).abs() < 1e-14, "on the surface");
    // The residual tau - r is normal to the cone at r (r . (tau - r) = 0) and lies in the polar
    // cone, which characterises the Euclidean projection onto a closed convex cone.
    let d = [tau[0] - r[0], tau[1] - r[1], tau[2] - r[2]];
    assert!((r[0] * d[0] + r[1] * d[1] + r[2] * d[2]).abs() < 1e-14);
    assert!(mu * tangential(&d) <= -d[0] + 1e-14);
    // And no sampled point of the cone is nearer.
    let mut rng = random::rng(7);
    let dist = |x: [f64; 3]| ((x[0] - tau[0]).powi(2) + (x[1] - tau[1]).powi(2) + (x[2] - tau[2]).powi(2)).sqrt();
    for _ in 0..2000 {
        let n: f64 = rng.random_range(0.0..3.0);
        let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let t = mu * n * rng.random_range(0.0..=1.0);
        assert!(dist([n, t * a.cos(), t * a.sin()]) >= dist(r) - 1e-12);
    }
}

#[test]
fn projection_at_the_apex_and_without_friction() {
    assert_eq!(project_on_cone([0.0; 3], 0.3), ([0.0; 3], Status::Separated));
    // mu = 0: the cone is the normal half-line; tangential parts are dropped.
    assert_eq!(project_on_cone([2.0, 5.0, 1.0], 0.0), ([2.0, 0.0, 0.0], Status::Sliding));
    assert_eq!(project_on_cone([-2.0, 5.0, 1.0], 0.0), ([0.0; 3], Status::Separated));
}

#[test]
fn projection_result_is_always_admissible() {
    let mut rng = random::rng(11);
    for _ in 0..10_000 {
        let mu: f64 = rng.random_range(0.0..1.5);
        let tau = [rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0)];
        let (r, _) = project_on_cone(tau, mu);
        assert!(r[0] >= 0.0);
        assert!(tangential(&r) <= mu * r[0] * (1.0 + 1e-10) + 1e-300, "{r:?} outside the cone of {mu}");
    }
}

#[test]
fn uzawa_step_fixed_points_are_the_three_coulomb_states() {
    let (mu, rho) = (0.5, 0.7);
    // Stick: zero relative velocity keeps an admissible reaction.
    let r = [3.0, 0.5, -0.2];
    assert_eq!(uzawa_step(r, [0.0; 3], mu, rho), (r, Status::Sticking));
    // Slip: r_t = -mu r_n v_t / |v_t| with v_n = 0 is a fixed point.
    let vt = [0.0, 0.6, -0.8];
    let r = [2.0, -mu * 2.0 * 0.6, mu * 2.0 * 0.8];
    let (next, s) = uzawa_step(r, vt, mu, rho);
    assert_eq!(s, Status::Sliding);
    assert!((0..3).all(|i| (next[i] - r[i]).abs() < 1e-14), "{next:?} vs {r:?}");
    // Separation: a zero reaction with an opening velocity stays zero.
    assert_eq!(uzawa_step([0.0; 3], [0.3, 1.0, 0.0], mu, rho), ([0.0; 3], Status::Separated));
}

/// The law at the converged points of a run: admissible reactions, sliding points opposing
/// their slip at the full friction, sticking points at rest.
#[test]
fn converged_contact_points_satisfy_coulomb_law() {
    let loaded = load_scene(&common_run::scene_path("sliding_block"), &["time.end=0.45".into()]).unwrap();
    let mut sim = build_simulation(&loaded).unwrap();
    sim.start();
    let (mut sliding, mut sticking) = (0, 0);
    while !sim.finished() {
        sim.advance().unwrap();
        for c in sim.contact_points() {
            let (r, v, mu) = (c.r, c.v, c.friction);
            let rt = tangential(&r);
            assert!(r[0] >= 0.0);
            assert!(rt <= mu * r[0] * (1.0 + 1e-10), "|r_t| {rt} > mu r_n {}", mu * r[0]);
            let vt = tangential(&v);
            match c.status {
                Status::Sliding => {
                    sliding += 1;
                    assert!((rt - mu * r[0]).abs() <= 1e-10 * mu * r[0], "a sliding point is on the cone");
                    if vt > 1e-6 {
                        let cos = (r[1] * v[1] + r[2] * v[2]) / (rt * vt);
                        assert!(cos < -1.0 + 1e-6, "r_t opposes v_t (cos = {cos})");
                    }
                }
                Status::Sticking => {
                    sticking += 1;
                    assert!(vt < 1e-7, "a sticking point has |v_t| = {vt}");
                }
                Status::Separated => assert_eq!(r, [0.0; 3]),
            }
        }
    }
    assert!(sliding > 100 && sticking > 10, "both states occur ({sliding} sliding, {sticking} sticking)");
}

#[test]
fn colours_partition_the_points_and_no_colour_shares_a_body() {
    let p = bifirst::bench::bench_contact_problem(7, 400, 1500);
    let mut seen = vec![0; p.local.len()];
    for c in 0..p.colours.count() {
        let colour = p.colours.colour(c);
        assert!(!colour.is_empty(), "colour {c} is empty");
        let members: std::collections::HashSet<u32> = colour.iter().copied().collect();
        for &i in colour {
            seen[i as usize] += 1;
            for &(j, _) in &p.w.rows[i as usize] {
                assert!(j == i || !members.contains(&j), "points {i} and {j} share a body and colour {c}");
            }
        }
    }
    assert!(seen.iter().all(|&n| n == 1), "every point in exactly one colour");
    let widest = p.w.rows.iter().map(Vec::len).max().unwrap();
    assert!(p.colours.count() <= widest, "greedy colouring needs at most a row's length of colours: {} > {widest}", p.colours.count());
}

#[test]
fn coloured_gauss_seidel_is_the_sequential_sweep_in_colour_order() {
    use bifirst::contact::uzawa::{gauss_seidel_point, solve, Sweep, SETTLE};
    // Enough points that the first colours are swept on the thread pool (256 and more).
    let p = bifirst::bench::bench_contact_problem(11, 3000, 3000);
    assert!(p.colours.colour(0).len() >= 256, "colour 0 has {} points", p.colours.colour(0).len());
    let (tolerance, floor, sweeps) = (0.0, 1e-3, 6);
    let mut reference = p.r.clone();
    for _ in 0..sweeps {
        for &i in &p.colours.order {
            reference[i as usize] = gauss_seidel_point(&p.w, &p.local[i as usize], i as usize, &reference, SETTLE * tolerance, floor);
        }
    }
    let mut r = p.r.clone();
    let outcome = solve(&mut p.with(&mut r, tolerance, floor, sweeps), Sweep::GaussSeidel, None);
    assert_eq!((outcome.iterations, outcome.converged), (sweeps, false));
    assert_eq!(r, reference, "bit for bit");
    // And the sweeps converge to reactions that satisfy the law at every point.
    let mut r = p.r.clone();
    let outcome = solve(&mut p.with(&mut r, 1e-10, floor, 500), Sweep::GaussSeidel, None);
    assert!(outcome.converged, "{outcome:?}");
    let mut worst = 0.0f64;
    for (i, l) in p.local.iter().enumerate() {
        let wr = p.w.row_times(i, &r);
        let v = [l.v_free[0] + wr[0] + l.shift, l.v_free[1] + wr[1], l.v_free[2] + wr[2]];
        let (next, _) = uzawa_step(r[i], v, l.mu, l.rho);
        worst = worst.max((0..3).map(|k| (next[k] - r[i][k]).abs()).fold(0.0, f64::max));
    }
    assert!(worst < 1e-8, "law residual {worst:.3e} after {} sweeps", outcome.iterations);
}

#[test]
fn uzawa_judge_stops_where_the_cpu_iterations_stop() {
    // The twin of the device's judge, fed the sweeps of the CPU's Gauss-Seidel iterations, stops
    // each problem at the CPU's sweep with the CPU's outcome, and clears the live flags of that
    // problem's points only. Three problems in one gather: one that never converges
    // (tolerance 0, spent after 5 sweeps), two that converge; frames turned so that the nodal
    // forces are not the reactions.
    use bifirst::contact::uzawa::{solve, uzawa_sweep, Sweep, SETTLE};
    use bifirst::gpu::uzawa_sweep::{NodeGather, UzawaJudgeState, UzawaProblem, JUDGE_LIVE};
    let mut problems = [bifirst::bench::bench_contact_problem(5, 40, 70), bifirst::bench::bench_contact_problem(6, 200, 300), bifirst::bench::bench_contact_problem(7, 9, 12)];
    for (k, p) in problems.iter_mut().enumerate() {
        for (i, frame) in p.nodal.frames.iter_mut().enumerate() {
            let (c, s) = ((0.3 * (i + k) as f64).cos(), (0.3 * (i + k) as f64).sin());
            *frame = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]];
        }
    }
    let settings = [(0.0, 5), (1e-10, 500), (1e-12, 500)];
    let floor = 1e-3;
    let mut on_cpu = Vec::new();
    for (p, &(tolerance, max)) in problems.iter().zip(&settings) {
        let mut r = p.r.clone();
        on_cpu.push(solve(&mut p.with(&mut r, tolerance, floor, max), Sweep::GaussSeidel, None));
    }
    let mut reactions: Vec<Vec<[f64; 3]>> = problems.iter().map(|p| p.r.clone()).collect();
    let list: Vec<_> = problems.iter().zip(&settings).zip(&mut reactions).map(|((p, &(tolerance, max)), r)| p.with(r, tolerance, floor, max)).collect();
    let nodes = NodeGather::of(&list);
    drop(list);
    let mut offsets = vec![0u32];
    for p in &problems {
        offsets.push(offsets.last().unwrap() + p.local.len() as u32);
    }
    let judged: Vec<UzawaProblem<f64>> = (0..3)
        .map(|k| UzawaProblem {
            point_start: offsets[k],
            point_end: offsets[k + 1],
            node_start: nodes.node_offsets[k],
            node_end: nodes.node_offsets[k + 1],
            max_iterations: settings[k].1 as u32,
            colour_first: 0,
            colours: 0,
            pad: 0,
            tolerance: settings[k].0,
            floor,
        })
        .collect();
    let mut states: Vec<UzawaJudgeState<f64>> = judged.iter().map(UzawaJudgeState::start).collect();
    let mut live = vec![1u32; *offsets.last().unwrap() as usize];
    let mut drs: Vec<Vec<[f64; 3]>> = problems.iter().map(|p| vec![[0.0; 3]; p.local.len()]).collect();
    while states.iter().any(|s| s.status == JUDGE_LIVE) {
        for k in 0..3 {
            if states[k].status != JUDGE_LIVE {
                continue;
            }
            let p = &problems[k];
            for c in 0..p.colours.count() {
                uzawa_sweep(&p.w, &p.local, p.colours.colour(c), &mut reactions[k], &mut drs[k], SETTLE * settings[k].0, floor);
            }
        }
        let r: Vec<f64> = reactions.iter().flatten().flatten().copied().collect();
        let dr: Vec<f64> = drs.iter().flatten().flatten().copied().collect();
        for k in 0..3 {
            bifirst::cpu::uzawa_judge(&judged, &mut states, &nodes, &r, &dr, &mut live, k);
        }
        for k in 0..3 {
            let flags = &live[offsets[k] as usize..offsets[k + 1] as usize];
            assert!(flags.iter().all(|&f| f == (states[k].status == JUDGE_LIVE) as u32), "problem {k}: its points' flags follow its state");
        }
    }
    for k in 0..3 {
        let (device, cpu) = (states[k].outcome(), on_cpu[k]);
        assert_eq!((device.iterations, device.converged), (cpu.iterations, cpu.converged), "problem {k}");
        assert_eq!(device.change, cpu.change, "problem {k}: the change, to the bit");
    }
    assert!(!on_cpu[0].converged && on_cpu[1].converged && on_cpu[2].converged && on_cpu[1].iterations > 3, "{on_cpu:?}");
}
