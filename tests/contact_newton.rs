//! The semi-smooth Newton solve of a contact problem (`contact::semismooth`, `contact.fallback =
//! "newton"`): the Gauss-Seidel answer where the sweeps converge, an answer where they stall.

#[path = "common/run.rs"]
mod common_run;

use bifirst::contact::semismooth::{natural_map, semismooth_solve};
use bifirst::contact::uzawa::{solve, Acceleration, Colours, Delassus, Fallback, Local, NodalMap, Outcome, Problem, Sweep};
use bifirst::scene::load_scene;
use bifirst::solver::build_simulation;

/// A fixed linear congruential generator in [-1, 1).
struct Numbers(u64);

impl Numbers {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// A contact problem with its own node per point (so that nodal forces are the reactions).
struct Case {
    w: Delassus,
    colours: Colours,
    local: Vec<Local>,
    nodal: NodalMap,
    dim: usize,
}

impl Case {
    /// `entry(p, q)` of a symmetric positive definite matrix over the unknowns `dim i + a`,
    /// kept in the blocks of the point pairs `coupled` says are coupled.
    fn new(n: usize, dim: usize, entry: impl Fn(usize, usize) -> f64, coupled: impl Fn(usize, usize) -> bool, mut local: Vec<Local>) -> Self {
        let mut w = Delassus { rows: vec![Vec::new(); n], ..Default::default() };
        for i in 0..n {
            for j in (0..n).filter(|&j| coupled(i, j)) {
                let mut block = [0.0; 9];
                for a in 0..dim {
                    for b in 0..dim {
                        block[3 * a + b] = entry(dim * i + a, dim * j + b);
                    }
                }
                w.rows[i].push((j as u32, w.blocks.len() as u32));
                w.blocks.push(block);
            }
        }
        for (i, l) in local.iter_mut().enumerate() {
            l.rho = w.rho(i, dim, Sweep::GaussSeidel);
        }
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let nodal = NodalMap { terms: (0..n).map(|i| vec![(i as u32, 1.0)]).collect(), frames: vec![identity; n], nodes: n };
        Self { colours: Colours::of(&w), w, local, nodal, dim }
    }

    fn solve(&self, r: &mut [[f64; 3]], fallback: Fallback, tolerance: f64, max_iterations: usize) -> Outcome {
        let mut p = Problem { w: &self.w, colours: &self.colours, local: &self.local, nodal: &self.nodal, r, tolerance, floor: 1e-12, max_iterations, acceleration: Acceleration::Anderson, fallback, dim: self.dim, pairs: &[] };
        solve(&mut p, Sweep::GaussSeidel, None)
    }

    /// The largest natural-map residual over the largest reaction.
    fn residual(&self, r: &[[f64; 3]]) -> f64 {
        let f = natural_map(&self.w, &self.local, r, self.dim, None);
        let norm = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        f.iter().map(norm).fold(0.0, f64::max) / r.iter().map(norm).fold(0.0, f64::max)
    }
}

/// Every pair coupled through `W = A Aᵀ / m + I`, friction 0, 0.3 and 0.8, points closing,
/// opening and sliding.
fn random_case(n: usize, dim: usize, seed: u64) -> Case {
    let mut numbers = Numbers(seed);
    let m = n * dim;
    let a: Vec<f64> = (0..m * m).map(|_| numbers.next()).collect();
    let local = (0..n).map(|i| Local { v_free: [numbers.next() - 0.3, numbers.next(), if dim == 3 { numbers.next() } else { 0.0 }], shift: 0.0, mu: [0.0, 0.3, 0.8][i % 3], rho: 0.0 }).collect();
    let entry = move |p: usize, q: usize| (0..m).map(|k| a[p * m + k] * a[q * m + k]).sum::<f64>() / m as f64 + if p == q { 1.0 } else { 0.0 };
    Case::new(n, dim, entry, |_, _| true, local)
}

#[test]
fn the_newton_solve_finds_the_gauss_seidel_answer_on_small_problems() {
    let mut compared = 0;
    for dim in [2, 3] {
        for seed in 1..25 {
            let case = random_case(6, dim, seed);
            let mut swept = vec![[0.0; 3]; 6];
            let outcome = case.solve(&mut swept, Fallback::None, 1e-12, 20_000);
            if !outcome.converged {
                continue;
            }
            let mut r = vec![[0.0; 3]; 6];
            let solved = semismooth_solve(&case.w, &case.local, &case.nodal, &mut r, dim, 1e-12, 1e-12, None);
            assert!(solved.converged, "dim {dim} seed {seed}: {solved:?}");
            let scale = swept.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
            for (a, b) in r.iter().zip(&swept) {
                for k in 0..3 {
                    assert!((a[k] - b[k]).abs() <= 1e-8 * scale, "dim {dim} seed {seed}: Newton {a:?}, Gauss-Seidel {b:?}");
                }
            }
            compared += 1;
        }
    }
    assert!(compared >= 40, "the sweeps converged on {compared} of 48 problems");
}

/// A chain of points each pressed against its neighbours (the Delassus operator of a column of
/// grains, `W` a discrete Laplacian plus a small stiffness to ground): Gauss-Seidel contracts
/// at about `1 - π² / n²` per sweep, 0.9999 for 300 points.
fn jammed_chain(n: usize, mu: f64) -> Case {
    let dim = 2;
    let entry = |p: usize, q: usize| {
        let (i, a, j, b) = (p / dim, p % dim, q / dim, q % dim);
        if a != b {
            0.0
        } else if i == j {
            2.0 + 1e-5
        } else if i.abs_diff(j) == 1 {
            -1.0
        } else {
            0.0
        }
    };
    let local = (0..n).map(|i| Local { v_free: [-1.0, 0.2 * ((i % 7) as f64 - 3.0), 0.0], shift: 0.0, mu, rho: 0.0 }).collect();
    Case::new(n, dim, entry, |i, j| i.abs_diff(j) <= 1, local)
}

#[test]
fn a_jammed_chain_stalls_the_sweeps_and_the_newton_solve_converges() {
    for mu in [0.0, 0.3] {
        let case = jammed_chain(300, mu);
        let mut swept = vec![[0.0; 3]; 300];
        let stalled = case.solve(&mut swept, Fallback::None, 1e-9, 5000);
        assert!(!stalled.converged, "mu {mu}: the sweeps converged in {} sweeps", stalled.iterations);
        let mut r = vec![[0.0; 3]; 300];
        let outcome = case.solve(&mut r, Fallback::Newton, 1e-9, 5000);
        assert!(outcome.converged && outcome.newton_iterations > 0, "mu {mu}: {outcome:?}");
        assert!(outcome.iterations <= 300, "mu {mu}: {} sweeps before the Newton solve took over", outcome.iterations);
        assert!(case.residual(&r) < 1e-9, "mu {mu}: natural-map residual {}", case.residual(&r));
        // Small per sweep is not small an error: the stalled sweeps are far from the answer.
        let scale = r.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
        let error = swept.iter().zip(&r).flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs())).fold(0.0, f64::max) / scale;
        assert!(error > 1e-5, "mu {mu}: the stalled sweeps are {error:.2e} from the answer");
    }
}

/// 30 grains of grains_many pressed at ten times the wall speed, with each fallback: the Newton
/// solves take over some stalled problems (the counter says so), the energy balance closes, and
/// the total energy stays near the sweeps' (a packing is chaotic: reactions that differ within
/// the contact tolerance part by up to 2e-4 of the energy).
#[test]
fn the_newton_fallback_keeps_the_answers_of_the_sweeps_in_a_packing() {
    let run = |fallback: &str| {
        // Pressed at ten times the wall speed: with the mirrored pairs solved as one, the 60
        // grains to t = 0.5 at the scene's speed this took no longer stall, nor these 30 to
        // t = 0.15 once the sub-step doubled back after 16 easy sub-steps (not 4 scene steps).
        let sets = ["packing.count=30".to_string(), "packing.wall_velocity=20.0".into(), "time.end=0.25".into(), "output.scene_every=0".into(), format!("contact.fallback=\"{fallback}\"")];
        let mut sim = build_simulation(&load_scene(&common_run::scene_path("grains_many"), &sets).unwrap()).unwrap();
        sim.start();
        let (mut newton, mut sweeps) = (0, 0);
        while !sim.finished() {
            let report = sim.advance().unwrap();
            newton += report.contact_newton_iterations;
            sweeps += report.uzawa_iterations;
        }
        let energies = sim.energies();
        assert!(energies.energy_balance_error < 1e-9, "{fallback}: energy balance error {}", energies.energy_balance_error);
        (energies.total, newton, sweeps)
    };
    let (swept, none, sweeps_alone) = run("none");
    let (solved, newton, sweeps) = run("newton");
    assert_eq!(none, 0, "no Newton solve without the fallback");
    assert!(newton > 0, "the Newton solve took over no stalled problem ({sweeps} sweeps against {sweeps_alone})");
    // Both converge every solve to the same tolerance; by t = 0.25 the jammed packing's paths
    // have parted by 5.2e-3 of the total energy (1e-3 held to t = 0.15).
    assert!(((solved - swept) / swept).abs() < 1e-2, "total energy {solved} with the fallback, {swept} without");
}
