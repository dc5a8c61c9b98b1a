//! Mirrored two-pass pairs (`contact::mirrored`): found where two faces lie on each other with
//! matching vertices, solved as one, with the law of the sweeps.

use bifirst::contact::detect::detect;
use bifirst::contact::mirrored::{colour_pairs, mirrored_pairs, solve_mirrored_pair};
use bifirst::contact::pairs::{BodyPairs, Rank};
use bifirst::contact::semismooth::natural_map;
use bifirst::contact::uzawa::{solve, Acceleration, Colours, Delassus, Fallback, Local, NodalMap, Outcome, Problem, Sweep};
use bifirst::contact::{Configuration, ContactModel, Master, Settings, Surface};
use bifirst::mesh::generate::rectangle;
use bifirst::mesh::ElementKind;

/// Two nodes `a` and `b` (compliances `ca`, `cb`, isotropic) on faces `alpha` apart: the first
/// pass holds `a` on `b`'s face (normal `n(alpha / 2)`), the second `b` on `a`'s (normal
/// `-n(-alpha / 2)`), and a wall holds `a` from the side. `u` is `a`'s free velocity relative to
/// `b` (pressing and sliding), `side` what the wall sees.
struct Mirrored {
    w: Delassus,
    colours: Colours,
    local: Vec<Local>,
    nodal: NodalMap,
}

fn frame(angle: f64, sign: f64) -> [[f64; 3]; 3] {
    let n = [-sign * angle.sin(), sign * angle.cos(), 0.0];
    [n, [-n[1], n[0], 0.0], [0.0; 3]]
}

impl Mirrored {
    fn new(alpha: f64, mu: f64, u: [f64; 2], side: f64) -> Self {
        let (ca, cb) = (1.0, 0.7);
        // Per point: its frame and its nodes' coefficients (a, b).
        let points = [(frame(0.5 * alpha, 1.0), [1.0, -1.0]), (frame(-0.5 * alpha, -1.0), [-1.0, 1.0]), ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0; 3]], [1.0, 0.0])];
        let compliance = [ca, cb];
        let mut w = Delassus { rows: vec![Vec::new(); 3], ..Default::default() };
        for (i, (fi, hi)) in points.iter().enumerate() {
            for (j, (fj, hj)) in points.iter().enumerate() {
                let coupling: f64 = (0..2).map(|k| hi[k] * hj[k] * compliance[k]).sum();
                if (0..2).all(|k| hi[k] * hj[k] == 0.0) {
                    continue;
                }
                let mut block = [0.0; 9];
                for x in 0..2 {
                    for y in 0..2 {
                        block[3 * x + y] = coupling * (fi[x][0] * fj[y][0] + fi[x][1] * fj[y][1]);
                    }
                }
                w.rows[i].push((j as u32, w.blocks.len() as u32));
                w.blocks.push(block);
            }
        }
        let relative = |f: &[[f64; 3]; 3], sign: f64| [sign * (f[0][0] * u[0] + f[0][1] * u[1]), sign * (f[1][0] * u[0] + f[1][1] * u[1]), 0.0];
        let v_free = [relative(&points[0].0, 1.0), relative(&points[1].0, -1.0), [side, 0.0, 0.0]];
        let mut local: Vec<Local> = v_free.iter().map(|&v_free| Local { v_free, shift: 0.0, mu, rho: 0.0 }).collect();
        for (i, l) in local.iter_mut().enumerate() {
            l.rho = w.rho(i, 2, Sweep::GaussSeidel);
        }
        let nodal = NodalMap { terms: points.iter().map(|(_, h)| (0..2).filter(|&k| h[k] != 0.0).map(|k| (k as u32, h[k])).collect()).collect(), frames: points.iter().map(|p| p.0).collect(), nodes: 2 };
        Self { colours: Colours::of(&w), w, local, nodal }
    }

    fn solve(&self, r: &mut [[f64; 3]], pairs: &[[u32; 2]], max_iterations: usize) -> Outcome {
        let pairs = &colour_pairs(&self.w, pairs, self.local.len());
        let mut p = Problem { w: &self.w, colours: &self.colours, local: &self.local, nodal: &self.nodal, r, tolerance: 1e-8, floor: 1e-12, max_iterations, acceleration: Acceleration::Anderson, fallback: Fallback::None, dim: 2, pairs };
        solve(&mut p, Sweep::GaussSeidel, None)
    }

    /// Net force on node `a`.
    fn force_on_a(&self, r: &[[f64; 3]]) -> [f64; 2] {
        let mut f = [0.0; 2];
        for (i, terms) in self.nodal.terms.iter().enumerate() {
            for &(node, coef) in terms.iter().filter(|t| t.0 == 0) {
                let _ = node;
                let frame = &self.nodal.frames[i];
                for (k, fk) in f.iter_mut().enumerate() {
                    *fk += coef * (r[i][0] * frame[0][k] + r[i][1] * frame[1][k]);
                }
            }
        }
        f
    }
}

/// Faces 0.5° to 25° apart, every friction regime, pressed and pulled, sliding either way: the
/// pair's reactions make the natural map vanish at both points.
#[test]
fn a_mirrored_pair_solved_as_one_satisfies_the_law_at_both_points() {
    let mut solved = 0;
    for alpha_degrees in [0.5f64, 2.0, 8.0, 25.0] {
        for mu in [0.0, 0.3, 0.8] {
            for u in [[0.0, -1.0], [2.0, -1.0], [-2.0, -1.0], [0.3, -1.0], [1.0, 0.5]] {
                let case = Mirrored::new(alpha_degrees.to_radians(), mu, u, -0.5);
                // The wall's reaction as the sweeps would leave it, the pair from rest.
                let mut r = vec![[0.0; 3]; 3];
                r[2] = [0.5, 0.0, 0.0];
                assert!(solve_mirrored_pair(&case.w, &case.local, [0, 1], &mut r, 1e-12), "no regime at {alpha_degrees}°, mu {mu}, u {u:?}");
                let f = natural_map(&case.w, &case.local, &r, 2, None);
                for (k, fk) in f.iter().take(2).enumerate() {
                    let size = (r[k][0] * r[k][0] + r[k][1] * r[k][1]).sqrt().max(1e-12);
                    assert!((fk[0] * fk[0] + fk[1] * fk[1]).sqrt() <= 1e-9 * size.max(1.0), "{alpha_degrees}°, mu {mu}, u {u:?}: point {k} off the law by {fk:?}");
                }
                solved += 1;
            }
        }
    }
    assert_eq!(solved, 60);
}

/// Where the sweeps converge (faces 25° apart), solving the pair as one gives their nodal
/// forces.
#[test]
fn the_pair_solve_finds_the_answer_of_the_sweeps() {
    for mu in [0.0, 0.3, 0.8] {
        for u in [[0.0, -1.0], [2.0, -1.0], [-0.3, -1.0]] {
            let case = Mirrored::new(25f64.to_radians(), mu, u, -0.5);
            let mut plain = vec![[0.0; 3]; 3];
            let outcome = case.solve(&mut plain, &[], 100_000);
            assert!(outcome.converged, "mu {mu}, u {u:?}: the sweeps do not converge ({outcome:?})");
            let mut paired = vec![[0.0; 3]; 3];
            assert!(case.solve(&mut paired, &[[0, 1]], 1000).converged);
            let (a, b) = (case.force_on_a(&plain), case.force_on_a(&paired));
            let size = a[0].hypot(a[1]).max(1e-12);
            assert!((a[0] - b[0]).hypot(a[1] - b[1]) <= 1e-6 * size, "mu {mu}, u {u:?}: {a:?} against {b:?}");
        }
    }
}

/// A contact problem read from `tests/data`: the format the probe that found it wrote.
struct Stored {
    w: Delassus,
    colours: Colours,
    local: Vec<Local>,
    nodal: NodalMap,
    r: Vec<[f64; 3]>,
    pairs: Vec<[u32; 2]>,
    tolerance: f64,
    floor: f64,
}

impl Stored {
    fn read(name: &str) -> Self {
        let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let f = |x: &serde_json::Value| x.as_f64().unwrap();
        let list = |x: &serde_json::Value| x.as_array().unwrap().clone();
        let v3 = |x: &serde_json::Value| {
            let a = list(x);
            [f(&a[0]), f(&a[1]), f(&a[2])]
        };
        let index = |x: &serde_json::Value| x.as_u64().unwrap() as u32;
        let local = list(&v["local"])
            .iter()
            .map(|l| {
                let a = list(l);
                Local { v_free: [f(&a[0]), f(&a[1]), f(&a[2])], shift: f(&a[3]), mu: f(&a[4]), rho: f(&a[5]) }
            })
            .collect();
        let rows = list(&v["rows"]).iter().map(|r| list(r).iter().map(|e| (index(&e[0]), index(&e[1]))).collect()).collect();
        let blocks = list(&v["blocks"]).iter().map(|b| std::array::from_fn(|k| f(&b[k]))).collect();
        let w = Delassus { rows, blocks, version: 0 };
        let terms = list(&v["terms"]).iter().map(|t| list(t).iter().map(|e| (index(&e[0]), f(&e[1]))).collect()).collect();
        let frames = list(&v["frames"]).iter().map(|fr| [v3(&fr[0]), v3(&fr[1]), v3(&fr[2])]).collect();
        let nodal = NodalMap { terms, frames, nodes: v["nodes"].as_u64().unwrap() as usize };
        let pairs = list(&v["pairs"]).iter().map(|p| [index(&p[0]), index(&p[1])]).collect();
        Self { colours: Colours::of(&w), w, local, nodal, r: list(&v["r"]).iter().map(v3).collect(), pairs, tolerance: f(&v["tolerance"]), floor: f(&v["floor"]) }
    }

    fn solve(&self, r: &mut [[f64; 3]], pairs: &[[u32; 2]], max_iterations: usize) -> Outcome {
        let pairs = &colour_pairs(&self.w, pairs, self.local.len());
        let mut p =
            Problem { w: &self.w, colours: &self.colours, local: &self.local, nodal: &self.nodal, r, tolerance: self.tolerance, floor: self.floor, max_iterations, acceleration: Acceleration::Anderson, fallback: Fallback::None, dim: 2, pairs };
        solve(&mut p, Sweep::GaussSeidel, None)
    }
}

/// Regression: a jammed cluster of `grains_many` (30 grains at ten times the wall speed, the first
/// problem whose sweeps ran out of their 5 000): the 21 points around the one the sweeps left
/// farthest from the answer, 7 mirrored pairs among them, the other points' reactions (solved)
/// folded into the free velocities. The accelerated sweeps take over 10 000 sweeps; with the
/// pairs solved as one, a handful, to the same nodal forces.
#[test]
fn a_jammed_cluster_of_mirrored_pairs_stalls_the_sweeps_and_converges_with_the_pairs_as_one() {
    let case = Stored::read("jammed_cluster_2d.json");
    assert_eq!((case.local.len(), case.pairs.len()), (21, 7));
    let distinct: std::collections::HashSet<u32> = case.pairs.iter().flatten().copied().collect();
    assert_eq!(distinct.len(), 14, "each point in one pair");
    let mut plain = case.r.clone();
    let stalled = case.solve(&mut plain, &[], 5000);
    let mut paired = case.r.clone();
    let solved = case.solve(&mut paired, &case.pairs, 5000);
    println!("jammed cluster: sweeps {} (converged {}), pairs as one {} (converged {})", stalled.iterations, stalled.converged, solved.iterations, solved.converged);
    assert!(!stalled.converged, "{stalled:?}");
    assert!(solved.converged && solved.iterations <= 30, "{solved:?}");
    // The sweeps do get there, to the same nodal forces.
    assert!(case.solve(&mut plain, &[], 50_000).converged);
    let forces = |r: &[[f64; 3]]| {
        let mut f = vec![[0.0; 3]; case.nodal.nodes];
        for (i, terms) in case.nodal.terms.iter().enumerate() {
            let frame = &case.nodal.frames[i];
            for &(node, coef) in terms {
                for k in 0..3 {
                    f[node as usize][k] += coef * (r[i][0] * frame[0][k] + r[i][1] * frame[1][k] + r[i][2] * frame[2][k]);
                }
            }
        }
        f
    };
    let (a, b) = (forces(&plain), forces(&paired));
    let norm = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1]).sqrt();
    let size = a.iter().map(norm).fold(0.0, f64::max);
    let off = a.iter().zip(&b).map(|(x, y)| norm(&[x[0] - y[0], x[1] - y[1], 0.0])).fold(0.0, f64::max);
    assert!(off <= 1e-6 * size, "nodal forces {off:.2e} apart (largest {size:.2e})");
}

/// Two blocks face to face with matching nodes make a mirrored pair at each node of the face
/// when both passes are taken, none with one.
#[test]
fn faces_with_matching_nodes_make_mirrored_pairs() {
    for (two_pass, expected) in [(true, 5), (false, 0)] {
        let lower = rectangle([0.0, 0.0], [1.0, 0.5], [4, 2], ElementKind::Quad4);
        let upper = rectangle([0.0, 0.5 + 1e-4], [1.0, 0.5], [4, 2], ElementKind::Quad4);
        let meshes = [lower, upper];
        let rank = Rank { length_scale: 0.25, boundary_nodes: 0 };
        let mut pairs = BodyPairs::new(vec![rank; 2], None, two_pass);
        pairs.list(0, 1, 0.3, Some(1));
        let model = ContactModel {
            settings: Settings { tolerance: 1e-8, max_iterations: 10, sweep: Sweep::GaussSeidel, acceleration: Default::default(), fallback: Default::default() },
            surfaces: meshes.iter().map(Surface::of).collect(),
            obstacles: Vec::new(),
            pairs,
        };
        let positions: Vec<Vec<[f64; 3]>> = meshes.iter().map(|m| m.nodes.clone()).collect();
        let mut config = Configuration::new(&model, positions);
        let points = detect(&model, &mut config, &|_, _| unreachable!("every body is placed"), 2, 0.0, 0.01, 0.01, &mut Default::default());
        let found = mirrored_pairs(&points);
        assert_eq!(found.len(), expected, "two passes {two_pass}: {} points", points.len());
        for [p, q] in found {
            let (p, q) = (&points[p as usize], &points[q as usize]);
            assert!(!p.second && q.second && p.master == Master::Body(q.slave_body) && q.master == Master::Body(p.slave_body));
        }
    }
}
