// Shared by the test files through `#[path]`: random contact problems like those of a grain
// packing, for the Uzawa sweeps. Each point touches one body (an obstacle contact) or two (a
// contact between grains); every pair of points on one body has a block of W.
#![allow(dead_code)]
use bifirst::contact::uzawa::{Colours, Delassus, Local, NodalMap, Sweep};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::collections::HashMap;

pub struct ContactProblem {
    pub w: Delassus,
    pub colours: Colours,
    pub local: Vec<Local>,
    pub nodal: NodalMap,
    /// Warm-start reactions.
    pub r: Vec<[f64; 3]>,
}

/// `points` points on `bodies` bodies; W is symmetric with dominant diagonal blocks, so that
/// Gauss-Seidel converges; free velocities mostly close the gaps, with every friction regime.
pub fn random_problem(seed: u64, bodies: usize, points: usize) -> ContactProblem {
    let mut rng = SmallRng::seed_from_u64(seed);
    let touching: Vec<Vec<usize>> = (0..points)
        .map(|_| {
            let a = rng.random_range(0..bodies);
            let b = rng.random_range(0..bodies);
            if b != a && rng.random_bool(0.6) { vec![a, b] } else { vec![a] }
        })
        .collect();
    let mut lists: Vec<Vec<usize>> = vec![Vec::new(); bodies];
    for (i, t) in touching.iter().enumerate() {
        for &b in t {
            lists[b].push(i);
        }
    }
    let mut w = Delassus { rows: vec![Vec::new(); points], blocks: Vec::new() };
    let mut index: HashMap<(usize, usize), u32> = HashMap::new();
    let mut block = |w: &mut Delassus, l: usize, k: usize| -> usize {
        let next = w.blocks.len() as u32;
        let id = *index.entry((l, k)).or_insert_with(|| {
            w.rows[l].push((k as u32, next));
            w.blocks.push([0.0; 9]);
            next
        });
        id as usize
    };
    for list in &lists {
        for (x, &l) in list.iter().enumerate() {
            let own = block(&mut w, l, l);
            for a in 0..3 {
                w.blocks[own][4 * a] += rng.random_range(0.5..1.5);
            }
            for &k in &list[x + 1..] {
                let m: [f64; 9] = std::array::from_fn(|_| rng.random_range(-0.03..0.03));
                let lk = block(&mut w, l, k);
                let kl = block(&mut w, k, l);
                for a in 0..3 {
                    for c in 0..3 {
                        w.blocks[lk][3 * a + c] += m[3 * a + c];
                        w.blocks[kl][3 * c + a] += m[3 * a + c];
                    }
                }
            }
        }
    }
    let colours = Colours::of(&w);
    let mut local = Vec::with_capacity(points);
    for i in 0..points {
        let mu = [0.0, 0.3, 0.6][rng.random_range(0..3)];
        let v_free = [rng.random_range(-1.0..0.4), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
        local.push(Local { v_free, shift: rng.random_range(-0.01..0.01), mu, rho: w.rho(i, 3, Sweep::GaussSeidel) });
    }
    let r = (0..points).map(|_| if rng.random_bool(0.5) { [rng.random_range(0.0..0.5), rng.random_range(-0.1..0.1), 0.0] } else { [0.0; 3] }).collect();
    // Each point's own node, and a node of its second body with the opposite sign.
    let terms = touching.iter().enumerate().map(|(i, t)| if t.len() == 2 { vec![(i as u32, 1.0), ((points + i) as u32, -1.0)] } else { vec![(i as u32, 1.0)] }).collect();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let nodal = NodalMap { terms, frames: vec![identity; points], nodes: 2 * points };
    ContactProblem { w, colours, local, nodal, r }
}
