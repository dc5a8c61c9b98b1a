//! Contact inside the Newton iterations of a theta step (method.md section 3).
//!
//! Contact enters only through the reactions on the right-hand side, so each body keeps its own
//! factorisation. Each Newton iteration: the contact-free increment `x0 = K̄⁻¹(-g)` gives the
//! free velocities at the contact points; back-substitutions with the same factorisation give the
//! Delassus blocks `W = H K̄⁻¹ Hᵀ / (θ dt)`; Uzawa iterations solve `v = v_free + W r` with the
//! local law; a last solve applies the reactions, `Δu = K̄⁻¹(-g + Hᵀ r)`.

use super::body::{Body, StepParams};
use crate::contact::mirrored::{colour_pairs, mirrored_pairs};
use crate::contact::uzawa::{self, Colours, Delassus, Local, NodalMap, Outcome, Problem};
use crate::contact::{uzawa_step, ContactPoint, Settings, Status, WarmStart};
use crate::gpu::uzawa_sweep::{self, solve_loops_per_sweep};
use crate::gpu::world::delassus_loops;
use crate::policy::{PhaseTimes, TIGHTEST_INNER};
use crate::precision::Real;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::AtomicBool;

/// The non-zero entries `(free dof, value)` of a row of `H`.
type SparseRow = Vec<(u32, Real)>;

/// The Uzawa iterations of a Newton iteration go this much below the contact tolerance, so that
/// their own error does not keep the reactions from settling between Newton iterations; with
/// accelerated sweeps a tenth is enough (doc/benchmarks.md, "Figures behind constants").
const INNER_TOLERANCE: Real = 0.1;

/// Columns solved together: bounds the dense right-hand-side block to `64 x free dofs`.
const COLUMN_BATCH: usize = 64;

/// The contact points of a step with what the Newton iterations need of them.
pub struct ContactStep {
    pub points: Vec<ContactPoint>,
    /// The mirrored two-pass pairs among `points`, solved as one ([`crate::contact::mirrored`]),
    /// in colours of W's pattern, which is the step's.
    pairs: Vec<Vec<[u32; 2]>>,
    pub delassus: Delassus,
    /// The order of the Gauss-Seidel sweeps (from the pattern of `delassus`).
    pub colours: Colours,
    /// Per body: the points with a node on it, and for each of them the block index of every
    /// pair (row-major over that list).
    per_body: Vec<(Vec<u32>, Vec<u32>)>,
    /// Per body and listed point, the non-zero entries `(free dof, value)` of `H` in each of
    /// the point's directions.
    h: Vec<Vec<[SparseRow; 3]>>,
    pub r: Vec<[Real; 3]>,
    pub local: Vec<Local>,
    nodal: NodalMap,
    /// Per node slot of `nodal`: (body, node).
    slot_nodes: Vec<(u32, u32)>,
    dim: usize,
    /// A velocity that matters in this step (the fastest body or obstacle, or what gravity adds
    /// in one step): reactions are compared with `max ρ` times it, so that round-off in a
    /// vanishing reaction is not mistaken for a change.
    velocity_scale: Real,
    floor: Real,
    /// The Uzawa tolerance of each Newton iteration, relative to the contact tolerance.
    inner: Real,
    /// Per body, its terms of the Delassus blocks `(block, entry, value)`, with its current
    /// factorisation (none before the first build): while no body refactorises, `W` does not
    /// change within a step.
    shares: Vec<Vec<(u32, u8, Real)>>,
    /// Per body, the contact-free increment `K̄⁻¹(-g)` of the increment being solved.
    free_increment: Vec<Vec<Real>>,
    /// Per body, the columns `K̄⁻¹ Hᵀ` that `delassus` was built from, kept where they are small
    /// ([`KEPT_COLUMNS`]): with them the increment is `K̄⁻¹(-g) + K̄⁻¹ Hᵀ r` without a
    /// second solve.
    responses: Vec<Option<Response>>,
}

/// A body's kept columns `K̄⁻¹ Hᵀ`: column `j` (free dofs, contiguous) belongs to the listed
/// point and direction `of[j]`.
struct Response {
    of: Vec<(usize, usize)>,
    columns: Vec<Real>,
}

/// A body keeps its Delassus columns while they hold at most this many reals (8 MB): a grain's
/// take a few thousand; a large body with many points solves its increment instead.
const KEPT_COLUMNS: usize = 1 << 20;

impl ContactStep {
    /// Sets up a step's contact points: their gap shift and the block pattern of `W`.
    pub fn new(mut points: Vec<ContactPoint>, bodies: &[&mut Body], p: &StepParams, warm: &WarmStart, velocity_scale: Real) -> Self {
        let dim = bodies[0].def.dim;
        let (dt, theta) = (p.dt, p.theta);
        for c in &mut points {
            let vn_start = local_velocity(c, dim, |b, d| bodies[b].committed.state.v[d], 0)[0];
            c.predicted_gap = c.gap + (1.0 - theta) * dt * vn_start;
            // The first term is the slave node (its body index is local to the group).
            c.shift = shift(c.gap, c.predicted_gap, bodies[c.terms[0].body as usize].length_scale(), theta * dt);
        }
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); bodies.len()];
        for (i, c) in points.iter().enumerate() {
            for t in c.terms() {
                let list = &mut lists[t.body as usize];
                if list.last() != Some(&(i as u32)) {
                    list.push(i as u32);
                }
            }
        }
        let mut delassus = Delassus { rows: vec![Vec::new(); points.len()], ..Default::default() };
        let mut index: HashMap<(u32, u32), u32> = HashMap::new();
        let mut per_body = Vec::with_capacity(bodies.len());
        let mut h = Vec::with_capacity(bodies.len());
        for (b, list) in lists.into_iter().enumerate() {
            let mut blocks = Vec::with_capacity(list.len() * list.len());
            for &l in &list {
                for &k in &list {
                    let next = index.len() as u32;
                    let id = *index.entry((l, k)).or_insert_with(|| {
                        delassus.rows[l as usize].push((k, next));
                        next
                    });
                    blocks.push(id);
                }
            }
            let body = &bodies[b];
            let entries = list
                .iter()
                .map(|&k| {
                    let c = &points[k as usize];
                    [0, 1, 2].map(|a| {
                        let mut e = Vec::new();
                        if a < dim {
                            for t in c.terms().iter().filter(|t| t.body as usize == b) {
                                for comp in 0..dim {
                                    if let Some(f) = body.def.dofs.free[t.node as usize * dim + comp] {
                                        e.push((f, t.coef * c.frame[a][comp]));
                                    }
                                }
                            }
                        }
                        e
                    })
                })
                .collect();
            per_body.push((list, blocks));
            h.push(entries);
        }
        delassus.blocks = vec![[0.0; 9]; index.len()];
        // A version of its own before any block is built: a device that builds W itself keys
        // the problem's layout on it.
        delassus.stamp();
        let colours = Colours::of(&delassus);
        // Reactions and step lengths carry over from the last step for the points found again.
        let previous: Vec<([Real; 3], Real)> = points.iter().map(|c| warm.get(&c.key()).copied().unwrap_or(([0.0; 3], 0.0))).collect();
        let r = previous.iter().map(|p| p.0).collect();
        let local: Vec<Local> = points.iter().zip(&previous).map(|(c, p)| Local { v_free: [0.0; 3], shift: c.shift, mu: c.friction, rho: p.1 }).collect();
        let floor = velocity_scale * local.iter().map(|l| l.rho).fold(0.0, Real::max);
        let mut slots: HashMap<(u32, u32), u32> = HashMap::new();
        let mut slot_nodes = Vec::new();
        let mut nodal = NodalMap { terms: Vec::with_capacity(points.len()), frames: points.iter().map(|c| c.frame).collect(), nodes: 0 };
        for c in &points {
            let terms = c.terms().iter().map(|t| {
                let next = slots.len() as u32;
                let slot = *slots.entry((t.body, t.node)).or_insert_with(|| {
                    slot_nodes.push((t.body, t.node));
                    next
                });
                (slot, t.coef)
            });
            nodal.terms.push(terms.collect());
        }
        nodal.nodes = slots.len();
        let responses = bodies.iter().map(|_| None).collect();
        // Solved as one in 2D only ([`Problem::pairs`]).
        let pairs = if dim == 2 { colour_pairs(&delassus, &mirrored_pairs(&points), points.len()) } else { Vec::new() };
        Self { points, pairs, delassus, colours, per_body, h, r, local, nodal, slot_nodes, dim, velocity_scale, floor, inner: INNER_TOLERANCE, shares: Vec::new(), free_increment: Vec::new(), responses }
    }

    /// Takes the step lengths of the points from the W a device built for its increments
    /// (`newton_contact`'s `delassus`), with the floor they give; the host's blocks, if any, are
    /// then stale (the bodies may have refactorised since): its next increment builds them all.
    pub fn take_device_delassus(&mut self, step_lengths: &[Real]) {
        debug_assert_eq!(step_lengths.len(), self.local.len(), "a step length per point");
        for (l, &rho) in self.local.iter_mut().zip(step_lengths) {
            l.rho = rho;
        }
        self.floor = self.velocity_scale * self.local.iter().map(|l| l.rho).fold(0.0, Real::max);
        self.shares.clear();
        self.responses.iter_mut().for_each(|r| *r = None);
    }

    /// A velocity that matters in this step (the fastest body or obstacle, or what gravity adds
    /// in one step): the floor of the reactions per unit step length.
    pub fn velocity_scale(&self) -> Real {
        self.velocity_scale
    }

    /// The most points of one colour of the Gauss-Seidel sweeps.
    pub fn widest_colour(&self) -> usize {
        (0..self.colours.count()).map(|k| self.colours.colour(k).len()).max().unwrap_or(0)
    }

    /// Whether a device solves this problem whole, one workgroup for all its sweeps
    /// ([`uzawa_sweep::solved_whole`], the rule its staging follows), and on a software adapter
    /// builds its W within the adapter's loop guard ([`delassus_loops`]): a group's increments
    /// go to the device only then.
    pub fn solved_whole(&self, software: bool) -> bool {
        let built = || !software || delassus_loops(&self.delassus, &self.nodal, &self.slot_nodes, self.dim) <= uzawa_sweep::SOFTWARE_LOOP_BUDGET;
        uzawa_sweep::solved_whole(self.widest_colour(), || solve_loops_per_sweep(&self.delassus, &self.colours, &self.nodal), software) && built()
    }

    /// Each point's obstacle velocity at the end of the step, for a device that takes the
    /// increments (it computes the free velocities).
    pub fn obstacle_velocities(&self) -> Vec<[Real; 3]> {
        self.points.iter().map(|c| c.obstacle_velocity[1]).collect()
    }

    /// Whether every point has a step length (carried over from the last step), so that the
    /// complementarity residual can be judged before any Uzawa iteration of this step.
    pub fn all_warm(&self) -> bool {
        self.local.iter().all(|l| l.rho > 0.0)
    }

    /// Writes the nodal forces of the reactions `r` into each body's `contact_force`.
    pub fn apply_forces(&self, bodies: &mut [&mut Body]) {
        let dim = self.dim;
        for b in bodies.iter_mut() {
            b.work.contact_force.iter_mut().for_each(|f| *f = 0.0);
        }
        for (c, r) in self.points.iter().zip(&self.r) {
            let f = c.to_global(r);
            for t in c.terms() {
                let body = &mut bodies[t.body as usize];
                for i in 0..dim {
                    body.work.contact_force[t.node as usize * dim + i] += t.coef * f[i];
                }
            }
        }
    }

    /// The Uzawa residuals `r - proj(r - ρ ṽ)` at the trial displacements as nodal forces, the
    /// largest relative to `max(largest nodal force, ρ v_scale)`: zero when the reactions satisfy
    /// the law with the current velocities.
    pub fn complementarity(&self, bodies: &[&mut Body], p: &StepParams) -> Real {
        let residual: Vec<[Real; 3]> = self
            .points
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let (l, r) = (&self.local[i], self.r[i]);
                if l.rho == 0.0 {
                    return [0.0; 3];
                }
                let mut v = end_velocity(c, bodies, p);
                v[0] += l.shift;
                let (next, _) = uzawa_step(r, v, l.mu, l.rho);
                [next[0] - r[0], next[1] - r[1], next[2] - r[2]]
            })
            .collect();
        // Judged on the nodal forces, as the Uzawa iterations are (see `NodalMap`).
        let (worst, size) = self.nodal.change(&residual, &self.r, &mut Vec::new());
        worst / size.max(self.floor).max(Real::MIN_POSITIVE)
    }

    /// The linearised contact problem of a Newton increment: the free velocities (the trial
    /// velocity plus the contact-free increment) and, when some body is `refactorized` (a new
    /// factorisation since the last increment) or they are not built yet for this step, the
    /// Delassus blocks.
    pub fn prepare(&mut self, bodies: &mut [&mut Body], p: &StepParams, settings: &Settings, refactorized: &[bool], times: &mut PhaseTimes) {
        let dim = self.dim;
        let theta_dt = p.theta * p.dt;
        let started = std::time::Instant::now();
        let solve_before = times.solve;
        // The bodies' contact-free increments on the thread pool, their wall time counted as solves.
        let solving = std::time::Instant::now();
        let x0: Vec<Vec<Real>> = bodies
            .par_iter_mut()
            .map(|body| {
                let mut rhs = vec![0.0; body.def.dofs.free_count];
                for (d, f) in body.def.dofs.free_pairs() {
                    rhs[f] = -body.work.g[d];
                }
                if !rhs.is_empty() {
                    body.solve_effective(&mut rhs, &mut PhaseTimes::default());
                }
                rhs
            })
            .collect();
        times.solve += solving.elapsed().as_secs_f64();
        for (i, c) in self.points.iter().enumerate() {
            let v = local_velocity(
                c,
                dim,
                |b, d| {
                    let body = &bodies[b];
                    let dv = body.def.dofs.free[d].map_or(0.0, |f| x0[b][f as usize] / theta_dt);
                    body.trial_velocity(p, d) + dv
                },
                1,
            );
            self.local[i].v_free = v;
        }
        self.free_increment = x0;
        let first = self.shares.len() != bodies.len();
        if first || refactorized.iter().any(|&r| r) {
            self.build_delassus(bodies, |b| first || refactorized[b], theta_dt, settings, times);
        }
        // The back-substitutions are counted as solves, the rest as contact.
        times.contact += started.elapsed().as_secs_f64() - (times.solve - solve_before);
    }

    /// The Uzawa iterations of the prepared problem on the CPU.
    pub fn solve_on_cpu(&mut self, settings: &Settings, stop: Option<&AtomicBool>, times: &mut PhaseTimes) -> Outcome {
        let started = std::time::Instant::now();
        let outcome = uzawa::solve(&mut self.problem(settings), settings.sweep, stop);
        times.contact += started.elapsed().as_secs_f64();
        outcome
    }

    /// Solves the next Newton iterations' Uzawa problems ten times tighter (down to
    /// [`TIGHTEST_INNER`]): for a group whose residual and contact forces have converged but
    /// whose increments stay above their bound, the reactions' own inexactness, applied through
    /// `K̄⁻¹ Hᵀ`, is what is left of the increment (a compression of 100 grains at 10 times the
    /// wall speed stalled at 1.1 times the bound at dt / 64; regression test
    /// `a_fast_compression_passes_the_step_whose_increments_stalled_on_the_reactions`).
    pub fn tighten(&mut self) {
        self.inner = (0.1 * self.inner).max(TIGHTEST_INNER);
    }

    /// The prepared problem, as [`uzawa::solve`] and the device's sweeps take it.
    pub fn problem(&mut self, settings: &Settings) -> Problem<'_> {
        self.problem_and_slots(settings).0
    }

    /// [`ContactStep::problem`], and each node slot of its nodal map as (body, node), for a
    /// device that takes the increments (it applies the reactions to the bodies' dofs).
    pub fn problem_and_slots(&mut self, settings: &Settings) -> (Problem<'_>, &[(u32, u32)]) {
        let problem = Problem {
            w: &self.delassus,
            colours: &self.colours,
            local: &self.local,
            nodal: &self.nodal,
            r: &mut self.r,
            tolerance: self.inner * settings.tolerance,
            floor: self.floor,
            max_iterations: settings.max_iterations,
            acceleration: settings.acceleration,
            fallback: settings.fallback,
            dim: self.dim,
            pairs: &self.pairs,
        };
        (problem, &self.slot_nodes)
    }

    /// Applies the solved reactions: each body's contact forces and Newton increment
    /// `Δu = K̄⁻¹(-g + Hᵀ r)`. Returns the relative change of the contact forces.
    pub fn apply(&mut self, bodies: &mut [&mut Body], times: &mut PhaseTimes) -> Real {
        let started = std::time::Instant::now();
        let solve_before = times.solve;
        // The change is judged on the nodal forces H^T r: with redundant constraints (two passes
        // over matching nodes) r itself is not unique, but H^T r is.
        let before: Vec<Vec<Real>> = bodies.iter().map(|b| b.work.contact_force.clone()).collect();
        self.apply_forces(bodies);
        let (mut change, mut size): (Real, Real) = (0.0, 0.0);
        for (body, old) in bodies.iter().zip(&before) {
            for (a, b) in body.work.contact_force.iter().zip(old) {
                change = change.max((a - b).abs());
                size = size.max(a.abs());
            }
        }
        for (b, body) in bodies.iter_mut().enumerate() {
            match &self.responses[b] {
                Some(response) => {
                    let n = body.def.dofs.free_count;
                    let list = &self.per_body[b].0;
                    let mut du = std::mem::take(&mut self.free_increment[b]);
                    for (j, &(k, a)) in response.of.iter().enumerate() {
                        let r = self.r[list[k] as usize][a];
                        if r != 0.0 {
                            du.iter_mut().zip(&response.columns[j * n..(j + 1) * n]).for_each(|(x, c)| *x += r * c);
                        }
                    }
                    body.apply_increment(&du);
                }
                None => body.newton_step(times),
            }
        }
        times.contact += started.elapsed().as_secs_f64() - (times.solve - solve_before);
        change / size.max(self.floor).max(Real::MIN_POSITIVE)
    }

    /// The Delassus blocks `W = H K̄⁻¹ Hᵀ / (θ dt)` by back-substitution with each body's
    /// factorisation, a batch of columns at a time, and each point's Uzawa step length. Only the
    /// `changed` bodies' columns are solved again: the others' share of the blocks is kept (in a
    /// group of tens of grains, one refactorising grain used to solve the columns of all).
    fn build_delassus(&mut self, bodies: &mut [&mut Body], changed: impl Fn(usize) -> bool + Sync, theta_dt: Real, settings: &Settings, times: &mut PhaseTimes) {
        let dim = self.dim;
        self.shares.resize_with(bodies.len(), Vec::new);
        let (points, per_body, h) = (&self.points, &self.per_body, &self.h);
        // Body by body on the thread pool (a jammed packing is one group of hundreds of grains);
        // the back-substitutions' share of the wall time counted as solves.
        let started = std::time::Instant::now();
        let seconds: Vec<(f64, f64)> = bodies
            .par_iter_mut()
            .zip(self.shares.par_iter_mut())
            .zip(self.responses.par_iter_mut())
            .enumerate()
            .filter(|(b, _)| changed(*b))
            .map(|(b, ((body, share), response))| {
                let (t0, mut own) = (std::time::Instant::now(), PhaseTimes::default());
                *response = body_share(body, (&per_body[b], &h[b], points), dim, theta_dt, share, &mut own);
                (own.solve, t0.elapsed().as_secs_f64())
            })
            .collect();
        let (solving, busy) = seconds.iter().fold((0.0, 0.0), |(s, t), &(a, b)| (s + a, t + b));
        times.solve += started.elapsed().as_secs_f64() * if busy > 0.0 { solving / busy } else { 0.0 };
        // Summed body after body, as one pass over every body would.
        self.delassus.blocks.iter_mut().for_each(|b| *b = [0.0; 9]);
        for share in &self.shares {
            for &(block, entry, value) in share {
                self.delassus.blocks[block as usize][entry as usize] += value;
            }
        }
        for i in 0..self.points.len() {
            self.local[i].rho = self.delassus.rho(i, dim, settings.sweep);
        }
        self.floor = self.velocity_scale * self.local.iter().map(|l| l.rho).fold(0.0, Real::max);
        self.delassus.stamp();
    }

    /// Records the end-of-step velocity, status and linearised end gap of every point.
    pub fn finish(&mut self, bodies: &[&mut Body], p: &StepParams) {
        for (i, c) in self.points.iter_mut().enumerate() {
            c.r = self.r[i];
            c.rho = self.local[i].rho;
            c.v = end_velocity(c, bodies, p);
            c.status = status_of(&c.r, c.friction);
            c.end_gap = c.predicted_gap + p.theta * p.dt * c.v[0];
        }
    }
}

/// A body's listed points and their blocks (`ContactStep::per_body`), its rows of `H`, and the
/// step's points.
type BodyRows<'a> = (&'a (Vec<u32>, Vec<u32>), &'a [[SparseRow; 3]], &'a [ContactPoint]);

/// Body `body`'s share of the Delassus blocks into `share` (`(block, entry, value)`), from its
/// listed points and their blocks, its rows of `H` and the step's points: `K̄⁻¹ Hᵀ` column batch
/// by column batch, then `H` times it. Returns the columns when the body keeps them.
fn body_share(body: &mut Body, ((list, blocks), h, points): BodyRows, dim: usize, theta_dt: Real, share: &mut Vec<(u32, u8, Real)>, times: &mut PhaseTimes) -> Option<Response> {
    let n = body.def.dofs.free_count;
    share.clear();
    if list.is_empty() || n == 0 {
        return None;
    }
    // A frictionless point needs only its normal column: its tangential reaction stays zero.
    let directions = |k: usize| if points[list[k] as usize].friction == 0.0 { 1 } else { dim };
    let columns: Vec<(usize, usize)> = (0..list.len()).flat_map(|k| (0..directions(k)).map(move |a| (k, a))).collect();
    let keep = n * columns.len() <= KEPT_COLUMNS;
    let mut kept = Vec::with_capacity(if keep { n * columns.len() } else { 0 });
    for batch in columns.chunks(COLUMN_BATCH) {
        let mut x = vec![0.0; n * batch.len()];
        for (j, &(k, a)) in batch.iter().enumerate() {
            for &(f, val) in &h[k][a] {
                x[j * n + f as usize] += val;
            }
        }
        body.solve_effective(&mut x, times);
        for (j, &(k, a)) in batch.iter().enumerate() {
            let col = &x[j * n..(j + 1) * n];
            for l in 0..list.len() {
                let block = blocks[l * list.len() + k];
                for c in 0..dim {
                    let s: Real = h[l][c].iter().map(|&(f, val)| val * col[f as usize]).sum();
                    share.push((block, (3 * c + a) as u8, s / theta_dt));
                }
            }
        }
        if keep {
            kept.extend_from_slice(&x);
        }
    }
    keep.then_some(Response { of: columns, columns: kept })
}

/// Share of a penetration that the drift correction removes in one step.
pub const DRIFT_FRACTION: Real = 0.5;
/// Most a drift correction removes in one step, in element sizes of the slave body.
pub const DRIFT_CAP: Real = 0.05;

/// Added to the end-of-step normal velocity of a point with gap `gap` at the start of the step
/// and `predicted` = `gap + (1 - θ) dt v_n,t` (the end gap if the end normal velocity were
/// zero). The end gap must be at least `min(predicted, 0)`: an open point may close its gap but
/// not more, and a point the theta rule carries past the surface goes no further. A point that
/// starts penetrated (`gap < 0`) must in addition separate by `min(DRIFT_FRACTION |gap|,
/// DRIFT_CAP h)` (drift correction, method.md §2), so that a penetration decays geometrically,
/// half of it per step, instead of staying for good. The reaction's work on the separation of a
/// point that started penetrated is the energy the correction adds, booked as
/// `contact_correction`: per point and step at most `r_n DRIFT_CAP h / θ` (this step's removal
/// and the `(1 - θ)` share of the velocity the last one left).
pub fn shift(gap: Real, predicted: Real, h: Real, theta_dt: Real) -> Real {
    let removal = (DRIFT_FRACTION * (-gap).max(0.0)).min(DRIFT_CAP * h);
    let target = (predicted.min(0.0) + removal).min(0.0);
    (predicted - target) / theta_dt
}

/// Classifies a reaction: zero, strictly inside the cone, or on its surface.
pub fn status_of(r: &[Real; 3], mu: Real) -> Status {
    let rt = (r[1] * r[1] + r[2] * r[2]).sqrt();
    if r[0] <= 0.0 {
        Status::Separated
    } else if mu > 0.0 && rt < mu * r[0] * (1.0 - 1e-9) {
        Status::Sticking
    } else {
        Status::Sliding
    }
}

/// Relative velocity in the contact frame, from a dof-velocity function `vel(body, dof)`;
/// `which` picks the obstacle velocity at the start (0) or the end (1) of the step.
fn local_velocity(c: &ContactPoint, dim: usize, vel: impl Fn(usize, usize) -> Real, which: usize) -> [Real; 3] {
    let mut g = c.obstacle_velocity[which].map(|x| -x);
    for t in c.terms() {
        for i in 0..dim {
            g[i] += t.coef * vel(t.body as usize, t.node as usize * dim + i);
        }
    }
    c.frame.map(|e| e[0] * g[0] + e[1] * g[1] + e[2] * g[2])
}

/// Relative velocity at the end of the step implied by the trial displacements.
fn end_velocity(c: &ContactPoint, bodies: &[&mut Body], p: &StepParams) -> [Real; 3] {
    local_velocity(c, bodies[0].def.dim, |b, d| bodies[b].trial_velocity(p, d), 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::grains_many;

    /// Sixteen grains pressed by the wall to their last step: the simulation, that step's points
    /// (every body one group, so that the points' body indices hold), the bodies they touch,
    /// and the step's parameters. Each body has begun the step and factorised.
    fn pressed_points() -> (crate::solver::Simulation, Vec<ContactPoint>, Vec<usize>, StepParams) {
        let mut sim = grains_many(&["packing.count=16", "packing.wall_velocity=20.0", "time.end=0.05", "output.scene_every=0"]);
        sim.start();
        while !sim.finished() {
            sim.advance().expect("step");
        }
        let points: Vec<ContactPoint> = sim.contact_points.clone();
        let touched: std::collections::BTreeSet<u32> = points.iter().flat_map(|c| c.terms().iter().map(|t| t.body)).collect();
        assert!(points.len() > 4 && touched.len() > 2, "the case has points on several grains: {} points, {} grains", points.len(), touched.len());
        let p = StepParams { dt: 0.005, xi: 1.0, theta: 1.0, residual_tolerance: 1e-8, increment_tolerance: 1e-8, max_iterations: 20 };
        let mut times = PhaseTimes::default();
        for body in sim.bodies.iter_mut() {
            body.begin_step(&p, &[0.0; 3], 0.0);
            body.evaluate(&p, &mut times).expect("evaluation");
            body.refresh_factor(&p, &mut times).expect("factorisation");
        }
        (sim, points, touched.into_iter().map(|b| b as usize).collect(), p)
    }

    /// The pressed packing's last step: W built, then `change` (a refactorisation and what
    /// follows it; it returns which bodies the next increment counts as refactorised), then
    /// the next increment's W; beside a build from scratch of the same points.
    fn rebuilt_and_fresh(change: impl FnOnce(&mut ContactStep, &mut [&mut Body], &[usize], StepParams) -> Vec<bool>) -> (ContactStep, ContactStep) {
        let (mut sim, points, touched, p) = pressed_points();
        let contact_settings = sim.contact.as_ref().expect("contact").settings.clone();
        let mut times = PhaseTimes::default();
        let mut bodies: Vec<&mut Body> = sim.bodies.iter_mut().collect();
        let mut kept = ContactStep::new(points.clone(), &bodies, &p, &HashMap::new(), 1.0);
        let none = vec![false; bodies.len()];
        kept.prepare(&mut bodies, &p, &contact_settings, &none, &mut times);
        let refactorized = change(&mut kept, &mut bodies, &touched, p);
        kept.prepare(&mut bodies, &p, &contact_settings, &refactorized, &mut times);
        let mut fresh = ContactStep::new(points, &bodies, &p, &HashMap::new(), 1.0);
        fresh.prepare(&mut bodies, &p, &contact_settings, &none, &mut times);
        (kept, fresh)
    }

    /// Sixteen grains pressed as one group build their W on a software adapter within its loop
    /// guard (under a fifth of it), and a problem of the same rows with sixty times the points
    /// per lane would not: such a group stays on the host there.
    #[test]
    fn a_pressed_group_builds_its_w_within_a_software_adapters_loop_guard() {
        let (mut sim, points, _, p) = pressed_points();
        let bodies: Vec<&mut Body> = sim.bodies.iter_mut().collect();
        let step = ContactStep::new(points, &bodies, &p, &HashMap::new(), 1.0);
        let loops = delassus_loops(&step.delassus, &step.nodal, &step.slot_nodes, 2);
        assert!(loops * 5 < uzawa_sweep::SOFTWARE_LOOP_BUDGET, "{loops} loop iterations");
        let rows = step.delassus.rows.len();
        let many = Delassus { rows: (0..60 * 64).map(|i| step.delassus.rows[i % rows].clone()).collect(), ..Default::default() };
        let terms = NodalMap { terms: (0..60 * 64).map(|i| step.nodal.terms[i % rows].clone()).collect(), frames: Vec::new(), nodes: step.nodal.nodes };
        assert!(delassus_loops(&many, &terms, &step.slot_nodes, 2) > uzawa_sweep::SOFTWARE_LOOP_BUDGET);
        assert!(step.solved_whole(true) && step.solved_whole(false));
    }

    /// One touched body refactorises at another step length.
    fn refactorise_one(bodies: &mut [&mut Body], touched: &[usize], p: StepParams) -> Vec<bool> {
        bodies[touched[1]].refresh_factor(&StepParams { dt: 0.004, ..p }, &mut PhaseTimes::default()).expect("factorisation");
        (0..bodies.len()).map(|b| b == touched[1]).collect()
    }

    /// When one body of a group refactorises, the Delassus blocks solved again for that body
    /// alone are those of a build from scratch, to the bit.
    #[test]
    fn delassus_solved_again_for_one_body_is_that_of_a_fresh_build() {
        let (kept, fresh) = rebuilt_and_fresh(|_, bodies, touched, p| refactorise_one(bodies, touched, p));
        assert_eq!(kept.delassus.blocks, fresh.delassus.blocks);
    }

    /// After a device built W for the group's increments (and took a body's refactorisation,
    /// which the host's blocks do not know of), the step lengths and floor are the device's,
    /// and the host's next increment builds every body's share: its W is that of a build from
    /// scratch, to the bit.
    #[test]
    fn a_host_increment_after_the_devices_w_builds_every_share_again() {
        let (kept, fresh) = rebuilt_and_fresh(|kept, bodies, touched, p| {
            refactorise_one(bodies, touched, p);
            let device: Vec<Real> = (0..kept.points.len()).map(|i| 1.0 + i as Real).collect();
            kept.take_device_delassus(&device);
            assert!(kept.local.iter().zip(&device).all(|(l, &rho)| l.rho == rho));
            assert_eq!(kept.floor, kept.velocity_scale() * device.len() as Real);
            // The device's call took the refactorisation: no body is marked.
            vec![false; bodies.len()]
        });
        assert_eq!(kept.delassus.blocks, fresh.delassus.blocks);
        assert!(kept.local.iter().zip(&fresh.local).all(|(a, b)| a.rho == b.rho) && kept.floor == fresh.floor);
    }
}
