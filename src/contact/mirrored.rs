//! Mirrored two-pass pairs, solved as one.
//!
//! Where two faces lie on each other with matching vertices, the two passes make a pair of points
//! on the same two nodes: a vertex of one grain on the end of the other's facet, at the other's
//! vertex, and that vertex on the end of the first one's facet. Their normals differ by the small
//! angle `α` between the faces, so their rows of `W` nearly coincide: the split of the reaction
//! between them is a mode that Gauss-Seidel contracts by about `1 - α²` a sweep, and with
//! friction the answer is one point pressing while the other opens (sliding along one face
//! leaves the other). Jammed packings stalled on these pairs for thousands of sweeps.
//!
//! A pair is solved exactly against the others' reactions: in 2D its local problem (two points,
//! four reactions) has four regimes a point (open, sticking, sliding either way), each a linear
//! system; of the sixteen, the one whose reactions satisfy the law at both points is the answer,
//! checked by the law's own fixed point (the Uzawa step leaves them where they are). This is a
//! block of the Gauss-Seidel sweep, the law unchanged.

use super::geometry::{norm, sub};
use super::law::uzawa_step;
use super::uzawa::{add_block_times, others_sum, Blocks, Delassus, Local};
use super::{ContactPoint, Master};
use crate::precision::Real;
use std::collections::HashMap;

/// A node is the one a point's master facet is mostly at when its weight there is at least this.
const AT_NODE: Real = 0.5;

/// The mirrored pairs among `points`, `[first pass, second pass]`: a first-pass point whose
/// master facet is mostly at a node which, as the slave of a second-pass point on the first
/// point's body, has a facet mostly at the first point's node, the two normals opposed.
pub fn mirrored_pairs(points: &[ContactPoint]) -> Vec<[u32; 2]> {
    let at = |c: &ContactPoint| {
        let masters = &c.terms()[1..];
        let k = (0..masters.len()).max_by(|&a, &b| masters[b].coef.total_cmp(&masters[a].coef))?;
        (-masters[k].coef >= AT_NODE).then_some(masters[k].node)
    };
    let seconds: HashMap<(u32, u32, u32), usize> = points
        .iter()
        .enumerate()
        .filter_map(|(i, c)| match c.master {
            Master::Body(m) if c.second && !c.corner => Some(((c.slave_body, c.slave_node, m), i)),
            _ => None,
        })
        .collect();
    let mut pairs = Vec::new();
    for (i, c) in points.iter().enumerate() {
        let Master::Body(m) = c.master else { continue };
        if c.second || c.corner {
            continue;
        }
        let Some(node) = at(c) else { continue };
        let Some(&j) = seconds.get(&(m, node, c.slave_body)) else { continue };
        let q = &points[j];
        if at(q) == Some(c.slave_node) && super::geometry::dot(c.frame[0], q.frame[0]) < 0.0 {
            pairs.push([i as u32, j as u32]);
        }
    }
    pairs
}

/// What a point does in one of the local problem's regimes.
#[derive(Debug, Clone, Copy)]
enum Regime {
    Open,
    Sticking,
    /// Sliding with its tangential reaction `sign μ r_n`.
    Sliding(Real),
}

const REGIMES: [Regime; 4] = [Regime::Open, Regime::Sticking, Regime::Sliding(1.0), Regime::Sliding(-1.0)];

/// A candidate is the answer when an Uzawa step moves each of its reactions by at most this
/// share of `max(|r|, floor)`.
const FIXED: Real = 1e-9;

/// Solves the 2D local problem of pair `[p, q]` against the other points' reactions in `r`, and
/// writes its reactions there. Returns false (and leaves `r`) when no regime's reactions satisfy
/// the law, as when a singular system leaves the split undetermined.
pub fn solve_mirrored_pair(w: &Delassus, local: &[Local], pair: [u32; 2], r: &mut [[Real; 3]], floor: Real) -> bool {
    match pair_reactions(&w.rows, &w.blocks[..], local, pair, r, floor) {
        Some([rp, rq]) => {
            (r[pair[0] as usize], r[pair[1] as usize]) = (rp, rq);
            true
        }
        None => false,
    }
}

/// [`solve_mirrored_pair`]'s reactions of the pair over `blocks` (W's rows `rows`), `None` where
/// it finds none, without writing them: pairs that no row of W couples are solved side by side.
pub(super) fn pair_reactions<B: Blocks + ?Sized>(rows: &[Vec<(u32, u32)>], blocks: &B, local: &[Local], [p, q]: [u32; 2], r: &[[Real; 3]], floor: Real) -> Option<[[Real; 3]; 2]> {
    let (p, q) = (p as usize, q as usize);
    // v_k = c_k + Σ_l A_kl r_l over the pair, in the first two components.
    let mut c = [[0.0; 2]; 2];
    let mut a = [[[0.0; 9]; 2]; 2];
    for (k, &i) in [p, q].iter().enumerate() {
        let l = &local[i];
        let (base, own) = others_sum(&rows[i], blocks, [p, q], r, [l.v_free[0] + l.shift, l.v_free[1], l.v_free[2]]);
        for (block, b) in a[k].iter_mut().zip(own) {
            if let Some(b) = b {
                *block = blocks.whole(b);
            }
        }
        c[k] = [base[0], base[1]];
    }
    let velocity = |x: &[Real; 4], k: usize| -> [Real; 3] {
        let mut v = [c[k][0], c[k][1], 0.0];
        for (l, block) in a[k].iter().enumerate() {
            add_block_times(&mut v, block, &[x[2 * l], x[2 * l + 1], 0.0]);
        }
        v
    };
    let residual = |x: &[Real; 4]| {
        [p, q]
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let ri = [x[2 * k], x[2 * k + 1], 0.0];
                let stepped = uzawa_step(ri, velocity(x, k), local[i].mu, local[i].rho).0;
                norm(sub(stepped, ri)) / norm(ri).max(floor).max(Real::MIN_POSITIVE)
            })
            .fold(0.0, Real::max)
    };
    let mu = [local[p].mu, local[q].mu];
    // The regimes the reactions are in first: between sweeps they seldom change.
    let current = [regime_of(r[p], mu[0]), regime_of(r[q], mu[1])];
    let others = REGIMES.iter().flat_map(|&first| REGIMES.iter().map(move |&second| [first, second]));
    for regimes in std::iter::once(current).chain(others) {
        let Some(x) = regime_reactions(regimes, &c, &a, mu) else { continue };
        if residual(&x) <= FIXED {
            return Some([[x[0], x[1], 0.0], [x[2], x[3], 0.0]]);
        }
    }
    None
}

/// The pairs in colours: no row of `w` couples two pairs of a colour (each point's row read
/// for its pair's neighbours), greedily, in the pairs' order; `n` points in all.
pub fn colour_pairs(w: &Delassus, pairs: &[[u32; 2]], n: usize) -> Vec<Vec<[u32; 2]>> {
    let mut owner = vec![u32::MAX; n];
    for (k, pair) in pairs.iter().enumerate() {
        pair.iter().for_each(|&i| owner[i as usize] = k as u32);
    }
    let mut colour_of = vec![usize::MAX; pairs.len()];
    let mut colours: Vec<Vec<[u32; 2]>> = Vec::new();
    let mut taken = Vec::new();
    for (k, pair) in pairs.iter().enumerate() {
        taken.clear();
        taken.resize(colours.len(), false);
        for &i in pair {
            for &(j, _) in &w.rows[i as usize] {
                match owner[j as usize] {
                    other if other == u32::MAX || other as usize == k => {}
                    other if colour_of[other as usize] != usize::MAX => taken[colour_of[other as usize]] = true,
                    _ => {}
                }
            }
        }
        let c = taken.iter().position(|&t| !t).unwrap_or(colours.len());
        if c == colours.len() {
            colours.push(Vec::new());
        }
        colours[c].push(*pair);
        colour_of[k] = c;
    }
    colours
}

/// The regime reaction `r` is in.
fn regime_of(r: [Real; 3], mu: Real) -> Regime {
    if r[0] <= 0.0 {
        Regime::Open
    } else if r[1].abs() < mu * r[0] * (1.0 - 1e-12) {
        Regime::Sticking
    } else {
        Regime::Sliding(r[1].signum())
    }
}

/// The pair's reactions `[r_p, r_q]` (normal, tangential each) in regimes `regimes`: two
/// equations a point (open: `r = 0`; sticking: `v = 0`; sliding: `v_n = 0`, `r_t = ± μ r_n`),
/// solved by elimination with partial pivoting; `None` when the system is singular.
fn regime_reactions(regimes: [Regime; 2], c: &[[Real; 2]; 2], a: &[[[Real; 9]; 2]; 2], mu: [Real; 2]) -> Option<[Real; 4]> {
    let mut m = [[0.0; 5]; 4];
    for k in 0..2 {
        // Row `comp` of point k's velocity: its coefficients on the four reactions, and `-c`.
        let velocity_row = |comp: usize| {
            let mut row = [0.0; 5];
            for l in 0..2 {
                row[2 * l] = a[k][l][3 * comp];
                row[2 * l + 1] = a[k][l][3 * comp + 1];
            }
            row[4] = -c[k][comp];
            row
        };
        let (n, t) = (2 * k, 2 * k + 1);
        let mut unit = |row: usize, col: usize| {
            m[row] = [0.0; 5];
            m[row][col] = 1.0;
        };
        match regimes[k] {
            Regime::Open => {
                unit(n, n);
                unit(t, t);
            }
            Regime::Sticking => {
                m[n] = velocity_row(0);
                m[t] = velocity_row(1);
            }
            Regime::Sliding(sign) => {
                m[n] = velocity_row(0);
                m[t] = [0.0; 5];
                m[t][t] = 1.0;
                m[t][n] = -sign * mu[k];
            }
        }
    }
    // Rows scaled to unit size: the velocity rows are in W's units, the others in ones.
    for row in m.iter_mut() {
        let size = row[..4].iter().fold(0.0, |s: Real, x| s.max(x.abs()));
        if size == 0.0 {
            return None;
        }
        row.iter_mut().for_each(|x| *x /= size);
    }
    for col in 0..4 {
        let pivot = (col..4).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if m[pivot][col].abs() <= 1e-13 {
            return None;
        }
        m.swap(col, pivot);
        for row in col + 1..4 {
            let f = m[row][col] / m[col][col];
            for k in col..5 {
                m[row][k] -= f * m[col][k];
            }
        }
    }
    let mut x = [0.0; 4];
    for col in (0..4).rev() {
        let s: Real = (col + 1..4).map(|k| m[col][k] * x[k]).sum();
        x[col] = (m[col][4] - s) / m[col][col];
    }
    Some(x)
}
