//! The contact problem of one Newton iteration, `v = v_free + W r` with the law of eq. (10) at
//! every point, solved by Uzawa iterations. Two sweeps: Gauss-Seidel (each point takes its
//! predictor/corrector steps with the latest reactions of the others, as in Jean's NSCD; robust
//! when a stiff body couples its contact points strongly) and Jacobi (every point steps from the
//! same iterate: parallel, but slow when the coupling is strong).
//!
//! Gauss-Seidel visits the points colour by colour ([`Colours`]): no two points of a colour share
//! a body, so their steps do not see each other and a colour can run in parallel, on the CPU's
//! threads or as one dispatch of the `uzawa_sweep` kernel, with the iterates of a sequential
//! sweep in that order.
//!
//! `W` (the Delassus operator `H K̄⁻¹ Hᵀ / (θ dt)` in contact frames) is stored by blocks: one
//! `3 x 3` block for each pair of points that share a body.

use super::anderson::Anderson;
use super::geometry::norm;
use super::law::uzawa_step;
use super::mirrored::pair_reactions;
use super::semismooth::semismooth_solve;
use crate::precision::Real;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Block-sparse Delassus operator.
#[derive(Debug, Clone, Default)]
pub struct Delassus {
    /// Per point (row), `(column point, block index)`.
    pub rows: Vec<Vec<(u32, u32)>>,
    /// `3 x 3` blocks, row-major, in contact frames.
    pub blocks: Vec<[Real; 9]>,
    /// A number no other operator of the process has had, taken by [`Delassus::stamp`] once its
    /// blocks are written: while it stays, the device keeps its copy of W.
    pub version: u64,
}

static VERSIONS: AtomicU64 = AtomicU64::new(1);

impl Delassus {
    /// Marks the blocks as new (a fresh [`Delassus::version`]).
    pub fn stamp(&mut self) {
        self.version = VERSIONS.fetch_add(1, Ordering::Relaxed);
    }

    /// `W r` for point `i`.
    pub fn row_times(&self, i: usize, r: &[[Real; 3]]) -> [Real; 3] {
        let mut out = [0.0; 3];
        for &(j, b) in &self.rows[i] {
            add_block_times(&mut out, &self.blocks[b as usize], &r[j as usize]);
        }
        out
    }

    /// The Uzawa step of point `i`. Jacobi: `1 / Σ_j ‖W_ij‖_∞`, whose inverse bounds the
    /// response of the point to a unit reaction anywhere in its row, which keeps the parallel
    /// sweep stable. Gauss-Seidel: `1 / ‖W_ii‖_∞`, the point's own response.
    pub fn rho(&self, i: usize, dim: usize, sweep: Sweep) -> Real {
        let norm = |w: &[Real; 9]| (0..dim).map(|a| (0..dim).map(|c| w[3 * a + c].abs()).sum::<Real>()).fold(0.0, Real::max);
        let sum: Real = match sweep {
            Sweep::Jacobi => self.rows[i].iter().map(|&(_, b)| norm(&self.blocks[b as usize])).sum(),
            Sweep::GaussSeidel => self.rows[i].iter().filter(|&&(j, _)| j as usize == i).map(|&(_, b)| norm(&self.blocks[b as usize])).sum(),
        };
        if sum > 0.0 {
            1.0 / sum
        } else {
            0.0
        }
    }
}

/// The blocks of W as the CPU's sweeps read them: whole, or their planar part ([`Planar`]).
pub trait Blocks: Sync {
    /// `out += W_b r`.
    fn add_times(&self, out: &mut [Real; 3], b: u32, r: &[Real; 3]);
    /// Block `b`, `3 x 3`.
    fn whole(&self, b: u32) -> [Real; 9];
}

impl Blocks for [[Real; 9]] {
    fn add_times(&self, out: &mut [Real; 3], b: u32, r: &[Real; 3]) {
        add_block_times(out, &self[b as usize], r);
    }

    fn whole(&self, b: u32) -> [Real; 9] {
        self[b as usize]
    }
}

/// The upper-left `2 x 2` of each block of W: in 2D the third row and column are zeros, and a
/// reaction's third component is zero, so the products are those of the whole blocks (but for
/// the sign of a zero) from less than half the bytes. A jammed packing's sweeps spend most of
/// their time reading blocks (a 30-grain compression: two thirds of its samples in the row
/// products).
pub struct Planar(Vec<[Real; 4]>);

impl Planar {
    pub fn of(w: &Delassus) -> Self {
        Self(w.blocks.iter().map(|b| [b[0], b[1], b[3], b[4]]).collect())
    }
}

impl Blocks for Planar {
    fn add_times(&self, out: &mut [Real; 3], b: u32, r: &[Real; 3]) {
        let w = &self.0[b as usize];
        out[0] += w[0] * r[0] + w[1] * r[1];
        out[1] += w[2] * r[0] + w[3] * r[1];
    }

    fn whole(&self, b: u32) -> [Real; 9] {
        let w = &self.0[b as usize];
        [w[0], w[1], 0.0, w[2], w[3], 0.0, 0.0, 0.0, 0.0]
    }
}

/// `start + Σ_j W_ij r_j` over row `row` without the columns `skip` (a point's own, or a
/// mirrored pair's two), and the blocks of those. Not inlined: inlined into the pair solve, the
/// sum went through the stack at every block (a third of a jammed packing's samples).
#[inline(never)]
pub(super) fn others_sum<B: Blocks + ?Sized>(row: &[(u32, u32)], blocks: &B, skip: [usize; 2], r: &[[Real; 3]], start: [Real; 3]) -> ([Real; 3], [Option<u32>; 2]) {
    let mut out = start;
    let mut own = [None, None];
    for &(j, b) in row {
        let j = j as usize;
        if j == skip[0] {
            own[0] = Some(b);
        } else if j == skip[1] {
            own[1] = Some(b);
        } else {
            blocks.add_times(&mut out, b, &r[j]);
        }
    }
    (out, own)
}

/// `out += w r` for a row-major `3 x 3` block.
pub(super) fn add_block_times(out: &mut [Real; 3], w: &[Real; 9], r: &[Real; 3]) {
    for a in 0..3 {
        out[a] += w[3 * a] * r[0] + w[3 * a + 1] * r[1] + w[3 * a + 2] * r[2];
    }
}

/// The order of the Uzawa updates within a sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sweep {
    GaussSeidel,
    Jacobi,
}

/// What is done between Gauss-Seidel sweeps to speed them up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Acceleration {
    /// Anderson mixing of the last sweeps, safeguarded ([`super::anderson`]), and in 2D the
    /// mirrored two-pass pairs solved as one ([`super::mirrored`]).
    #[default]
    Anderson,
    /// Plain sweeps, as the device's.
    None,
}

/// A mixed iterate whose sweep changes the nodal forces by more than this many times the
/// smallest change of the solve so far is rejected ([`super::anderson::Anderson::reject`]).
const REJECT_GROWTH: Real = 2.0;

/// Rejections after which a solve goes on with plain sweeps.
const MAX_REJECTIONS: usize = 30;

/// Local Uzawa steps per point and Gauss-Seidel visit: enough to settle the point against the
/// others' current reactions (`LOCAL_STEPS` of the `uzawa_sweep` kernel).
pub const LOCAL_STEPS: usize = 25;

/// A point's local steps stop once a step moves its reaction by less than this share of the
/// Uzawa tolerance (relative to `max(|r|, floor)`).
pub const SETTLE: Real = 1e-3;

/// Points of a colour below which a colour is swept on one thread (the threads' start-up would
/// cost more than the steps).
const PARALLEL_COLOUR: usize = 256;

/// The points of a contact problem in colours: no two points of a colour share a body (their
/// block of `W` is zero), so their Gauss-Seidel steps are independent.
#[derive(Debug, Clone, Default)]
pub struct Colours {
    /// The points, colour by colour, each colour in point order.
    pub order: Vec<u32>,
    /// Colour `c` is `order[starts[c]..starts[c + 1]]`.
    pub starts: Vec<u32>,
}

impl Colours {
    /// Greedy colouring in point order: each point takes the lowest colour that no point of its
    /// row of `W` has taken.
    pub fn of(w: &Delassus) -> Self {
        let n = w.rows.len();
        let mut colour = vec![u32::MAX; n];
        // `seen[c] == i + 1`: colour c is taken by a neighbour of point i.
        let mut seen: Vec<usize> = Vec::new();
        let mut count = 0u32;
        for i in 0..n {
            for &(j, _) in &w.rows[i] {
                let c = colour[j as usize];
                if c != u32::MAX {
                    seen[c as usize] = i + 1;
                }
            }
            let c = (0..count).find(|&c| seen[c as usize] != i + 1).unwrap_or(count);
            if c == count {
                count += 1;
                seen.push(0);
            }
            colour[i] = c;
        }
        let mut starts = vec![0u32; count as usize + 1];
        for &c in &colour {
            starts[c as usize + 1] += 1;
        }
        for c in 0..count as usize {
            starts[c + 1] += starts[c];
        }
        let mut next = starts.clone();
        let mut order = vec![0u32; n];
        for (i, &c) in colour.iter().enumerate() {
            order[next[c as usize] as usize] = i as u32;
            next[c as usize] += 1;
        }
        Self { order, starts }
    }

    pub fn count(&self) -> usize {
        self.starts.len().saturating_sub(1)
    }

    /// The points of colour `c`.
    pub fn colour(&self, c: usize) -> &[u32] {
        &self.order[self.starts[c] as usize..self.starts[c + 1] as usize]
    }
}

/// The Gauss-Seidel visit of point `i`: up to [`LOCAL_STEPS`] predictor/corrector steps against
/// the others' reactions in `r`, until a step moves the reaction by at most
/// `settle max(|r_i|, floor)`. The body of the `uzawa_sweep` kernel.
pub fn gauss_seidel_point(w: &Delassus, l: &Local, i: usize, r: &[[Real; 3]], settle: Real, floor: Real) -> [Real; 3] {
    visit_point(&w.rows, &w.blocks[..], l, i, r, settle, floor)
}

/// [`gauss_seidel_point`] over `blocks`.
#[allow(clippy::too_many_arguments)]
fn visit_point<B: Blocks + ?Sized>(rows: &[Vec<(u32, u32)>], blocks: &B, l: &Local, i: usize, r: &[[Real; 3]], settle: Real, floor: Real) -> [Real; 3] {
    let (wr, [own, _]) = others_sum(&rows[i], blocks, [i, i], r, [0.0; 3]);
    let base = [l.v_free[0] + wr[0] + l.shift, l.v_free[1] + wr[1], l.v_free[2] + wr[2]];
    let mut ri = r[i];
    for _ in 0..LOCAL_STEPS {
        let mut v = base;
        if let Some(b) = own {
            blocks.add_times(&mut v, b, &ri);
        }
        let stepped = uzawa_step(ri, v, l.mu, l.rho).0;
        let moved = norm([stepped[0] - ri[0], stepped[1] - ri[1], stepped[2] - ri[2]]);
        ri = stepped;
        if moved <= settle * norm(ri).max(floor) {
            break;
        }
    }
    ri
}

/// One colour of a Gauss-Seidel sweep (the CPU twin of the `uzawa_sweep` kernel, one dispatch):
/// every point of `points` visited against the same `r`, which is then updated; the changes go
/// into `dr`. A large colour is visited on the thread pool.
#[allow(clippy::too_many_arguments)]
pub fn uzawa_sweep(w: &Delassus, local: &[Local], points: &[u32], r: &mut [[Real; 3]], dr: &mut [[Real; 3]], settle: Real, floor: Real) {
    sweep_colour(&w.rows, &w.blocks[..], local, points, r, dr, settle, floor);
}

/// [`uzawa_sweep`] over `blocks`.
#[allow(clippy::too_many_arguments)]
fn sweep_colour<B: Blocks + ?Sized>(rows: &[Vec<(u32, u32)>], blocks: &B, local: &[Local], points: &[u32], r: &mut [[Real; 3]], dr: &mut [[Real; 3]], settle: Real, floor: Real) {
    let mut update = |i: usize, next: [Real; 3], r: &mut [[Real; 3]]| {
        dr[i] = [next[0] - r[i][0], next[1] - r[i][1], next[2] - r[i][2]];
        r[i] = next;
    };
    if points.len() < PARALLEL_COLOUR {
        // In place: no point of the colour reads another's reaction.
        for &i in points {
            let next = visit_point(rows, blocks, &local[i as usize], i as usize, r, settle, floor);
            update(i as usize, next, r);
        }
        return;
    }
    let stepped: Vec<[Real; 3]> = points.par_iter().with_min_len(PARALLEL_COLOUR / 4).map(|&i| visit_point(rows, blocks, &local[i as usize], i as usize, r, settle, floor)).collect();
    for (&i, next) in points.iter().zip(stepped) {
        update(i as usize, next, r);
    }
}

/// Each mirrored pair solved as one against the others' reactions, colour by colour, the pairs
/// of a colour side by side (a pair without a regime that satisfies the law is visited point by
/// point, as the sweeps do); `dr` takes its points' changes.
#[allow(clippy::too_many_arguments)]
fn solve_pairs<B: Blocks + ?Sized>(rows: &[Vec<(u32, u32)>], blocks: &B, local: &[Local], colours: &[Vec<[u32; 2]>], r: &mut [[Real; 3]], dr: &mut [[Real; 3]], settle: Real, floor: Real) {
    for pairs in colours {
        // No pair of a colour reads another's reactions: solved side by side, then written.
        let solved: Vec<Option<[[Real; 3]; 2]>> = if pairs.len() < PARALLEL_COLOUR / 2 {
            pairs.iter().map(|&pair| pair_reactions(rows, blocks, local, pair, r, floor)).collect()
        } else {
            pairs.par_iter().with_min_len(PARALLEL_COLOUR / 8).map(|&pair| pair_reactions(rows, blocks, local, pair, r, floor)).collect()
        };
        for (&pair, solved) in pairs.iter().zip(solved) {
            let before = pair.map(|i| r[i as usize]);
            match solved {
                Some([rp, rq]) => (r[pair[0] as usize], r[pair[1] as usize]) = (rp, rq),
                // No regime fits (a split the law leaves undetermined): the points one by one.
                None => {
                    for i in pair.map(|i| i as usize) {
                        r[i] = visit_point(rows, blocks, &local[i], i, r, settle, floor);
                    }
                }
            }
            for (k, i) in pair.map(|i| i as usize).into_iter().enumerate() {
                dr[i] = [r[i][0] - before[k][0], r[i][1] - before[k][1], r[i][2] - before[k][2]];
            }
        }
    }
}

/// Per-point data of the local problem.
#[derive(Debug, Clone, Copy)]
pub struct Local {
    pub v_free: [Real; 3],
    pub shift: Real,
    pub mu: Real,
    pub rho: Real,
}

/// How the iterations ended.
#[derive(Debug, Clone, Copy, Default)]
pub struct Outcome {
    /// Sweeps.
    pub iterations: usize,
    pub converged: bool,
    /// Last largest change of a nodal force over `max(largest nodal force, floor)`.
    pub change: Real,
    /// Iterations of the semi-smooth Newton solve the sweeps stalled into, and its wall time.
    pub newton_iterations: usize,
    pub newton_seconds: f64,
}

/// What a solve does when its Gauss-Seidel sweeps stall (`contact.fallback`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fallback {
    /// A semi-smooth Newton solve of the whole problem ([`super::semismooth`]), from the
    /// sweeps' iterate, up to [`NEWTON_ATTEMPTS`] times; the sweeps go on from its last
    /// iterate when it does not converge.
    Newton,
    /// Sweeps to the end of the budget: the jammed packings measured stall mostly on degenerate
    /// problems, where the Newton solve does not pay (doc/benchmarks.md, "Jammed packings").
    #[default]
    None,
}

/// Semi-smooth Newton solves a stalled solve may try (the first that ends on a plateau is the
/// last).
pub const NEWTON_ATTEMPTS: usize = 4;

/// Sweeps between two looks at whether the Gauss-Seidel sweeps stall, and the sweeps before the
/// first: with Anderson mixing most solves end within 65 sweeps, some after a stretch that only
/// looks stalled, which an earlier look hands to the Newton solve for nothing (doc/benchmarks.md,
/// "Jammed packings").
const STALL_WINDOW: usize = 16;
const FIRST_LOOK: usize = 256;

/// A solve has stalled when its sweeps, contracting as over the last [`STALL_WINDOW`], would
/// need more than this many more to converge.
const STALL_SWEEPS: Real = 256.0;

/// Whether sweeps whose largest nodal-force change went from `earlier` to `change` over the last
/// `window` sweeps would need more than [`STALL_SWEEPS`] more to reach `target`.
fn stalled(earlier: Real, change: Real, window: usize, target: Real) -> bool {
    if change <= target {
        return false;
    }
    let q = (change / earlier).powf(1.0 / window as Real);
    q >= 1.0 || (target / change).ln() / q.ln() > STALL_SWEEPS
}

/// Where each point's reaction lands: the nodes of its terms (numbered `0..nodes`), with their
/// coefficients, and the point's frame. The iterations are judged on the nodal forces `Hᵀ r`:
/// with nearly redundant points (two passes over faces lying on each other) the split of a
/// reaction between them is ill-determined and settles very slowly, while the forces on the
/// nodes, which are all the bodies see, have long converged.
#[derive(Debug, Clone, Default)]
pub struct NodalMap {
    pub terms: Vec<Vec<(u32, Real)>>,
    pub frames: Vec<[[Real; 3]; 3]>,
    pub nodes: usize,
}

impl NodalMap {
    /// Largest change of a nodal force for the reaction changes `dr`, and the largest nodal
    /// force of `r` (its scale); `scratch` holds one vector per node and is left zeroed.
    pub fn change(&self, dr: &[[Real; 3]], r: &[[Real; 3]], scratch: &mut Vec<[[Real; 3]; 2]>) -> (Real, Real) {
        scratch.resize(self.nodes, [[0.0; 3]; 2]);
        for (i, terms) in self.terms.iter().enumerate() {
            let f = &self.frames[i];
            let global = |x: &[Real; 3]| [0, 1, 2].map(|k| x[0] * f[0][k] + x[1] * f[1][k] + x[2] * f[2][k]);
            let (d, a) = (global(&dr[i]), global(&r[i]));
            for &(node, coef) in terms {
                let slot = &mut scratch[node as usize];
                for k in 0..3 {
                    slot[0][k] += coef * d[k];
                    slot[1][k] += coef * a[k];
                }
            }
        }
        let (mut change, mut size): (Real, Real) = (0.0, 0.0);
        for slot in scratch.iter_mut() {
            change = change.max(norm(slot[0]));
            size = size.max(norm(slot[1]));
            *slot = [[0.0; 3]; 2];
        }
        (change, size)
    }
}

/// The stopping rule of the Uzawa iterations, judged after every sweep on the largest change
/// of a nodal force (see [`NodalMap`]).
///
/// The sweep contracts linearly with a factor `q` that can be close to 1 when the points are
/// strongly coupled (a stiff body), so a small change is not a small error: the error is
/// estimated as `change q / (1 - q)`, with `q` the ratio of the last two changes.
#[derive(Debug, Clone, Copy)]
pub struct Judge {
    tolerance: Real,
    floor: Real,
    previous: Real,
}

impl Judge {
    pub fn new(tolerance: Real, floor: Real) -> Self {
        Self { tolerance, floor, previous: Real::INFINITY }
    }

    /// The outcome after sweep `iteration`, whose largest nodal-force change is `change` and
    /// largest nodal force `size`.
    pub fn after(&mut self, iteration: usize, change: Real, size: Real) -> Outcome {
        let (tolerance, scale) = (self.tolerance, size.max(self.floor).max(Real::MIN_POSITIVE));
        let q = change / self.previous;
        self.previous = change;
        let error = if q < 1.0 { change * q / (1.0 - q) } else { Real::INFINITY };
        // Far below the tolerance the ratio is round-off; a change that small is converged.
        let converged = change <= 1e-3 * tolerance * scale || (change <= tolerance * scale && error <= tolerance * scale);
        Outcome { iterations: iteration, converged, change: change / scale, ..Outcome::default() }
    }
}

/// One contact problem of a Newton iteration with its stopping rule: what [`solve`] and the
/// device's sweeps (`gpu::uzawa_sweep`) take.
pub struct Problem<'a> {
    pub w: &'a Delassus,
    /// The order of the Gauss-Seidel sweeps.
    pub colours: &'a Colours,
    pub local: &'a [Local],
    pub nodal: &'a NodalMap,
    /// In: the reactions to start from; out: those of the sweep that ended the iterations.
    pub r: &'a mut [[Real; 3]],
    pub tolerance: Real,
    pub floor: Real,
    pub max_iterations: usize,
    /// Between Gauss-Seidel sweeps (Jacobi sweeps are never accelerated; the device's sweeps
    /// are plain).
    pub acceleration: Acceleration,
    /// When the Gauss-Seidel sweeps stall (the device's sweeps have none).
    pub fallback: Fallback,
    /// The scene's dimension (the components of a reaction in use).
    pub dim: usize,
    /// Mirrored two-pass pairs: with Anderson acceleration, in 2D, each is solved as one in
    /// place of its points' visits, after the colours of every Gauss-Seidel sweep
    /// ([`super::mirrored`]); plain sweeps, as the device's, visit them point by point. In
    /// colours: no row of `w` couples two pairs of one ([`super::mirrored::colour_pairs`]).
    pub pairs: &'a [Vec<[u32; 2]>],
}

/// Uzawa iterations from the reactions in `p.r` until the estimated distance to the fixed
/// point, in nodal forces, is below `tolerance * max(largest nodal force, floor)` ([`Judge`]),
/// or `max_iterations`, or until `stop` is set (an interrupt: then not converged). Gauss-Seidel
/// sweeps visit the points by `colours`, with Anderson mixing between them and the mirrored
/// pairs solved as one (2D) if `p.acceleration` says so; with `p.fallback` Newton, sweeps that
/// stall hand their iterate to [`semismooth_solve`]. The reactions returned are those of a sweep, or of a Newton solve that
/// converged.
pub fn solve(p: &mut Problem, sweep: Sweep, stop: Option<&AtomicBool>) -> Outcome {
    let Problem { w, colours, local, nodal, ref mut r, tolerance, floor, max_iterations, acceleration, fallback, dim, pairs } = *p;
    let n = local.len();
    let mut next = vec![[0.0; 3]; n];
    let mut dr = vec![[0.0; 3]; n];
    // Accelerated 2D sweeps visit the paired points with their pair, after the colours; plain
    // sweeps (the device's) one by one.
    let accelerate = sweep == Sweep::GaussSeidel && acceleration == Acceleration::Anderson;
    let unpaired = (accelerate && dim == 2 && !pairs.is_empty()).then(|| {
        let mut paired = vec![false; n];
        pairs.iter().flatten().flatten().for_each(|&i| paired[i as usize] = true);
        (0..colours.count()).map(|c| colours.colour(c).iter().copied().filter(|&i| !paired[i as usize]).collect::<Vec<u32>>()).collect::<Vec<_>>()
    });
    // The CPU's own 2D sweeps read the planar blocks (the device's twin, the whole ones).
    let planar = (accelerate && dim == 2).then(|| Planar::of(w));
    let mut scratch = Vec::new();
    let mut outcome = Outcome::default();
    let mut judge = Judge::new(tolerance, floor);
    let mut anderson = Anderson::new();
    let mut start = Vec::new();
    let (mut mixed, mut best_change, mut rejections) = (false, Real::INFINITY, 0);
    let newton = fallback == Fallback::Newton && sweep == Sweep::GaussSeidel && n > 1;
    let mut attempts = if newton { 0 } else { NEWTON_ATTEMPTS };
    let (mut window_start, mut newton_iterations, mut newton_seconds) = (Real::INFINITY, 0, 0.0);
    for it in 1..=max_iterations {
        if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            break;
        }
        match sweep {
            Sweep::Jacobi => {
                for i in 0..n {
                    let l = &local[i];
                    let wr = w.row_times(i, r);
                    let v = [l.v_free[0] + wr[0] + l.shift, l.v_free[1] + wr[1], l.v_free[2] + wr[2]];
                    next[i] = uzawa_step(r[i], v, l.mu, l.rho).0;
                }
                for i in 0..n {
                    dr[i] = [next[i][0] - r[i][0], next[i][1] - r[i][1], next[i][2] - r[i][2]];
                }
                r.copy_from_slice(&next);
            }
            Sweep::GaussSeidel => {
                if accelerate {
                    start.clear();
                    start.extend_from_slice(r);
                }
                for c in 0..colours.count() {
                    let points = unpaired.as_ref().map_or(colours.colour(c), |u| &u[c][..]);
                    match &planar {
                        Some(planar) => sweep_colour(&w.rows, planar, local, points, r, &mut dr, SETTLE * tolerance, floor),
                        None => uzawa_sweep(w, local, points, r, &mut dr, SETTLE * tolerance, floor),
                    }
                }
                // Pairs are solved as one only where the planar blocks are read (2D, accelerated).
                if let (Some(_), Some(planar)) = (&unpaired, &planar) {
                    solve_pairs(&w.rows, planar, local, pairs, r, &mut dr, SETTLE * tolerance, floor);
                }
            }
        }
        let (change, size) = nodal.change(&dr, r, &mut scratch);
        // A mixed iterate that made things worse: back to the sweep before it.
        if mixed && change > REJECT_GROWTH * best_change {
            anderson.reject(r);
            outcome.iterations = it;
            rejections += 1;
            mixed = false;
            continue;
        }
        if mixed {
            anderson.accept();
        }
        best_change = best_change.min(change);
        outcome = judge.after(it, change, size);
        if outcome.converged {
            break;
        }
        if attempts < NEWTON_ATTEMPTS && it % STALL_WINDOW == 0 && it >= FIRST_LOOK - STALL_WINDOW {
            let scale = size.max(floor).max(Real::MIN_POSITIVE);
            if stalled(window_start, best_change, STALL_WINDOW, tolerance * scale) {
                // From the sweeps' iterate; the sweeps go on from the Newton solve's last
                // iterate if it did not converge (a lower |F|, and the sweeps settle the points
                // whose regimes it could not).
                attempts += 1;
                let started = std::time::Instant::now();
                let solved = semismooth_solve(w, local, nodal, r, dim, tolerance, floor, stop);
                newton_iterations += solved.iterations;
                newton_seconds += started.elapsed().as_secs_f64();
                if solved.converged {
                    outcome = Outcome { iterations: it, converged: true, change: solved.residual, ..outcome };
                    break;
                }
                if solved.plateau {
                    // Most likely a problem without a solution: no further Newton solve.
                    attempts = NEWTON_ATTEMPTS;
                }
                if solved.iterations > 0 {
                    // A new start: no history to mix, no contraction to extrapolate.
                    anderson = Anderson::new();
                    judge = Judge::new(tolerance, floor);
                    (mixed, best_change, window_start) = (false, Real::INFINITY, Real::INFINITY);
                    continue;
                }
            }
            window_start = best_change;
        }
        if accelerate && rejections < MAX_REJECTIONS && it < max_iterations {
            mixed = anderson.mix(&start, r, |i| local[i].mu);
        }
    }
    Outcome { newton_iterations, newton_seconds, ..outcome }
}
