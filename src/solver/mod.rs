//! Time stepping: Jean's first-order theta method solved by Newton, body by body, with
//! automatic cut-back of failed steps; energies and per-body, probe and reaction quantities.

pub mod body;
pub mod coupling;
pub mod group;
pub mod linear;
mod lockstep;
pub mod ordering;
mod restart;
mod setup;
pub mod topology;

pub use crate::policy::{PhaseTimes, REFACTOR_CONTRACTION, TIGHTEN_AFTER, UZAWA_STALLS};
use body::StepEnergy;
pub use body::{Body, NodalLoad, StepFailure};
pub use restart::{RestoreError, SavedBody, SavedFactor, SavedReaction, SavedState};
pub use setup::{build_mesh, build_simulation};

use crate::contact::broad::KeptPairs;
use crate::contact::configuration::extent;
use crate::contact::detect::{thin_second_pass, Detection};
use crate::contact::overlap::{Overlap, OverlapSearch, Worst};
use crate::contact::{Configuration, ContactModel, ContactPoint, ContactStats, Master};
use crate::gpu::types::{StepMotion, StepSummary};
use crate::gpu::{GpuWorld, StepEnd, StepStart};
use crate::precision::{Precision, Real};
pub use body::StepParams;
use group::{solve_groups, GroupReport, Hold};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A node set with a prescribed motion (its reaction goes to `/reaction/<name>`).
#[derive(Debug, Clone)]
pub struct BoundarySet {
    pub name: String,
    pub body: usize,
}

/// A probe: the node nearest to the requested point, and the elements around it.
#[derive(Debug, Clone)]
pub struct Probe {
    pub name: String,
    pub body: usize,
    pub node: usize,
    pub elements: Vec<usize>,
}

/// What one (possibly cut-back) step did.
#[derive(Debug, Clone, Default)]
pub struct StepReport {
    pub step: usize,
    pub t: Real,
    pub dt: Real,
    pub newton_iterations: usize,
    /// Uzawa iterations, summed over the Newton iterations and sub-steps.
    pub uzawa_iterations: usize,
    /// Semi-smooth Newton iterations of the contact problems whose sweeps stalled.
    pub contact_newton_iterations: usize,
    pub residual_norm: Real,
    pub cutbacks: usize,
    /// Body evaluations, summed over the Newton iterations (a group of bodies coupled by
    /// contact counts each of its bodies per iteration) and sub-steps.
    pub bodies_iterated: usize,
    /// Newton increments taken on the device, summed over bodies and sub-steps.
    pub device_iterations: usize,
    /// Numeric factorisations, summed over bodies, iterations and sub-steps.
    pub factorizations: usize,
    /// Contact totals over the step (sub-steps added up; penetration the largest).
    pub contact: ContactStats,
    pub wall: PhaseTimes,
    /// Bytes moved between host and GPU (zero on the CPU backend).
    pub bytes_moved: u64,
    /// Of `bytes_moved`, those that went up, host to GPU.
    pub bytes_up: u64,
    /// Queue submits to the GPU (zero on the CPU backend): one per device pass, whatever the
    /// number of bodies.
    pub device_submits: u64,
    /// One line per cut-back: why the step failed and the new time step.
    pub events: Vec<String>,
    /// Sub-steps the step was taken in (1 without step control acting).
    pub substeps: usize,
    /// Attempts rejected because a node went deeper than `solver.max_overlap`, or because
    /// the attempt created more energy than `solver.max_step_energy_gain`.
    pub overlap_retries: usize,
    pub energy_retries: usize,
    /// Sub-steps kept with θ = ξ = 1 (raised after one at the scene's θ created energy).
    pub raised_theta: usize,
    /// Sub-steps kept beyond a bound at the smallest step the cut-backs allow.
    pub kept_beyond_bounds: usize,
}

impl StepReport {
    /// Adds the counts of one attempt's groups (of those that converged, also in an attempt that failed); the
    /// first failure fails the attempt. The attempt took as many Newton iterations as its
    /// slowest group.
    fn add_groups(&mut self, groups: Vec<Result<GroupReport, StepFailure>>) -> Result<(), StepFailure> {
        let (mut failure, mut iterations) = (None, 0);
        for g in groups {
            let g = match g {
                Ok(g) => g,
                Err(e) => {
                    failure.get_or_insert(e);
                    continue;
                }
            };
            iterations = iterations.max(g.iterations);
            self.uzawa_iterations += g.uzawa_iterations;
            self.contact_newton_iterations += g.contact_newton_iterations;
            self.bodies_iterated += g.bodies_iterated;
            self.device_iterations += g.device_iterations;
            self.factorizations += g.factorizations;
            self.residual_norm = self.residual_norm.max(g.residual_norm);
            self.wall += g.wall;
        }
        if let Some(e) = failure {
            return Err(e);
        }
        self.newton_iterations += iterations;
        Ok(())
    }
}

/// A step that could not be completed even after all cut-backs.
#[derive(Debug, Clone, thiserror::Error)]
#[error("step {step} at t = {t:.6e} failed after {cutbacks} cut-backs{} (dt = {dt:.3e}): {failure}", started_at(*.level))]
pub struct RunFailure {
    pub step: usize,
    pub t: Real,
    pub dt: Real,
    pub cutbacks: usize,
    /// The cut-back level the step started at, carried over from the steps before it.
    pub level: usize,
    pub failure: StepFailure,
    /// The partial report (cut-back events) of the failing step.
    pub report: StepReport,
}

/// Where a failed step started, when earlier steps had already shortened it.
fn started_at(level: usize) -> String {
    if level == 0 {
        String::new()
    } else {
        format!(" from dt / {}", 1u64 << level)
    }
}

/// Energies of the whole system at the current time.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, schemars::JsonSchema)]
pub struct Energies {
    pub kinetic: Real,
    pub strain: Real,
    pub potential: Real,
    pub external_work: Real,
    pub friction_dissipation: Real,
    /// Cumulative work of the viscoelastic overstress (the stress less the material model's,
    /// `solver::body::StepEnergy::viscous_work`): what the Prony branches dissipate, counted
    /// against the model's instantaneous strain energy (`strain`).
    pub viscous_dissipation: Real,
    /// The scheme's own dissipation: theta and xi weighting, and the normal (impact) part of
    /// the contact work.
    pub numerical_dissipation: Real,
    /// Work of the contact reactions on the separation the drift correction asks of penetrated
    /// points (energy put in; see `coupling::shift`).
    pub contact_correction: Real,
    pub total: Real,
    /// `|E(0) + W_ext + W_correction - E - D_friction - D_viscous - D_numerical| / scale` (see
    /// [`Simulation::energies`]).
    pub energy_balance_error: Real,
}

impl Energies {
    /// The scale energy gains are measured against: `max(|E(0)|, |E|, |W_ext|)`, `initial`
    /// being `E(0)`.
    pub fn scale(&self, initial: Real) -> Real {
        [initial, self.total, self.external_work].iter().map(|x| x.abs()).fold(Real::MIN_POSITIVE, Real::max)
    }
}

/// The boundary nodes of `bodies` displaced by their committed state that are inside another
/// body or behind an obstacle (at time `t`), searched afresh. The bodies' states must be the
/// host's ([`Simulation::sync_states`]).
pub(crate) fn state_overlaps(bodies: &[Body], model: &ContactModel, t: Real) -> Vec<Overlap> {
    assert!(bodies.iter().all(|b| b.held_state().is_none()), "the states are the host's");
    let mut config = configuration(bodies, model, |b| &b.committed.state.u);
    let mut kept = KeptPairs::default();
    let search = OverlapSearch::new(model, &config, t, &mut kept);
    let meshes: Vec<&crate::mesh::Mesh> = bodies.iter().map(|b| &b.def.mesh).collect();
    search.overlaps(model, &meshes, &mut config, &placer(bodies, |b| &b.committed.state.u))
}

/// The configuration of `bodies` at the displacements `u`: boundary boxes and largest facets,
/// no body placed yet. Written over `config`, whose position buffers are kept (a packing's
/// positions are megabytes: fresh pages each step cost as much as filling them).
///
/// `committed`, when given, is the configuration of the committed state, and `u` are the trial
/// displacements: a body that did not move in the step ([`Body::still`]) keeps its box and
/// largest facet from it. In a packing at rest that is nearly every body, and the pass over
/// every boundary node cost a third of the contact phase. A body whose displacements the device
/// keeps (`held`) takes the box of its nodes the device computed and the largest facet it had
/// in `committed` (a body without contact points, moving nearly as a rigid body in one step).
pub(crate) fn configure(bodies: &[Body], model: &ContactModel, u: impl Fn(&Body) -> &[Real] + Sync, held: impl Fn(&Body) -> Option<&StepSummary> + Sync, committed: Option<&Configuration>, config: &mut Configuration) {
    let committed = committed.filter(|c| c.boxes.len() == bodies.len());
    (config.boxes, config.largest) = bodies
        .par_iter()
        .zip(&model.surfaces)
        .enumerate()
        .map_init(Vec::new, |scratch, (i, (b, surface))| match (committed, held(b)) {
            (Some(c), Some(h)) => ((h.low, h.high), c.largest[i]),
            (None, Some(_)) => unreachable!("a body the device keeps has a committed configuration"),
            (Some(c), None) if b.still() => (c.boxes[i], c.largest[i]),
            _ => {
                let u = u(b);
                extent(surface, |k| displaced(surface.reference[k], u, surface.nodes[k] as usize, b.def.dim), scratch)
            }
        })
        .unzip();
    config.nodes.unplace(bodies.len());
}

/// [`configure`] into a new configuration.
pub(crate) fn configuration(bodies: &[Body], model: &ContactModel, u: impl Fn(&Body) -> &[Real] + Sync) -> Configuration {
    let mut config = Configuration::default();
    configure(bodies, model, u, |_| None, None, &mut config);
    config
}

/// Node `n`, at `x` in the reference configuration, moved by the displacements `u` (`dim` per
/// node), padded to 3 components.
fn displaced(x: [Real; 3], u: &[Real], n: usize, dim: usize) -> [Real; 3] {
    match dim {
        2 => {
            let u = &u[2 * n..2 * n + 2];
            [x[0] + u[0], x[1] + u[1], x[2]]
        }
        _ => {
            let u = &u[3 * n..3 * n + 3];
            [x[0] + u[0], x[1] + u[1], x[2] + u[2]]
        }
    }
}

/// Node `n` of body `b` at the displacements `u`.
fn position(b: &Body, u: &[Real], n: usize) -> [Real; 3] {
    displaced(b.def.mesh.nodes[n], u, n, b.def.dim)
}

/// Places a body's nodes at the displacements `u` ([`Configuration`]'s `Fill`).
fn placer<'a>(bodies: &'a [Body], u: impl Fn(&Body) -> &[Real] + Sync + 'a) -> impl Fn(usize, &mut Vec<[Real; 3]>) + Sync + 'a {
    move |b, x| {
        let body = &bodies[b];
        let u = u(body);
        x.clear();
        x.extend((0..body.def.mesh.nodes.len()).map(|n| position(body, u, n)));
    }
}

/// The committed states the device keeps of the listed bodies (each held), back into the host's.
fn take_committed_of(bodies: &mut [Body], world: Option<&mut GpuWorld>, held: &[usize], times: &mut PhaseTimes) -> Result<(), StepFailure> {
    if held.is_empty() {
        return Ok(());
    }
    let world = world.expect("a state kept on a device");
    let (states, _) = world.read_kept(held, &[], times).map_err(|e| bodies[held[0]].device_failure(&e))?;
    for (&b, kept) in held.iter().zip(states) {
        bodies[b].take_committed(&kept);
    }
    Ok(())
}

/// The host's own factorisations of `bodies` (`(id, body)`) where the device made their last ones
/// within a Newton call ([`Body::factor_on_device`]): their iterates there in one read
/// ([`GpuWorld::factored_at`]), then each body's own tangent there, in parallel; the device then
/// holds those versions. Returns each body's result (a device error is every body's).
fn factorize_where_the_device_did(world: &mut GpuWorld, bodies: &mut [(usize, &mut Body)], times: &mut PhaseTimes) -> Vec<Result<(), StepFailure>> {
    if bodies.is_empty() {
        return Vec::new();
    }
    let ids: Vec<usize> = bodies.iter().map(|(id, _)| *id).collect();
    let at = match world.factored_at(&ids, times) {
        Ok(at) => at,
        Err(e) => return bodies.iter().map(|(_, b)| Err(b.device_failure(&e))).collect(),
    };
    let made: Vec<(Result<(), StepFailure>, PhaseTimes)> = bodies
        .par_iter_mut()
        .zip(at)
        .map(|((_, body), u)| {
            let mut spent = PhaseTimes::default();
            (body.factorize_at(&u, &mut spent), spent)
        })
        .collect();
    bodies
        .iter()
        .zip(made)
        .map(|((id, body), (result, spent))| {
            *times += spent;
            if result.is_ok() {
                world.note_factorized(*id, body.factor_version());
            }
            result
        })
        .collect()
}

/// The step's ends the device keeps of the `needed` bodies, back into the host's (and their
/// committed states first, where the device keeps those too).
fn take_step_ends(bodies: &mut [Body], world: Option<&mut GpuWorld>, needed: &[bool], p: &StepParams, times: &mut PhaseTimes) -> Result<(), StepFailure> {
    let held: Vec<usize> = (0..bodies.len()).filter(|&b| needed[b] && !bodies[b].trial_positions_current()).collect();
    if held.is_empty() {
        return Ok(());
    }
    let world = world.expect("a step's end kept on a device");
    let failure = |e: crate::gpu::GpuError| bodies[held[0]].device_failure(&e);
    let starts: Vec<usize> = held.iter().copied().filter(|&b| bodies[b].held_state().is_some()).collect();
    let (states, ends) = world.read_kept(&starts, &held, times).map_err(failure)?;
    for (&b, kept) in starts.iter().zip(states) {
        bodies[b].take_committed_mid_step(p, &kept);
    }
    for (&b, kept) in held.iter().zip(ends) {
        bodies[b].take_iterate(p, &kept);
    }
    Ok(())
}

/// The elements of each kind of `bodies` (what their kernels cost: `backend::round_on_device`).
fn element_work<'a>(bodies: impl Iterator<Item = &'a Body>) -> Vec<(crate::mesh::ElementKind, usize)> {
    let mut work: Vec<(crate::mesh::ElementKind, usize)> = Vec::new();
    for body in bodies {
        let mesh = body.elements();
        match work.iter_mut().find(|(kind, _)| *kind == mesh.kind) {
            Some((_, n)) => *n += mesh.element_count(),
            None => work.push((mesh.kind, mesh.element_count())),
        }
    }
    work
}

/// The largest nodal speed of a body's velocities `v`.
fn max_speed(v: &[Real], dim: usize) -> Real {
    v.chunks(dim).map(|v| v.iter().map(|x| x * x).sum::<Real>()).fold(0.0, Real::max).sqrt()
}

/// A step retried with the second contact pass thinned is kept only if no node ends deeper than
/// this share of its element inside another body; otherwise it is cut back.
pub const THINNED_PENETRATION: Real = 0.01;

/// A step is retried for overlap only when it leaves the deepest overlap more than this many
/// times deeper than the step before it did.
pub const OVERLAP_GROWTH: Real = 1.25;

/// Sub-steps in a row without a retry after which the sub-step doubles back. Counted in
/// sub-steps: the issue-55 compression of 200 grains at ten times the wall speed (t ≤ 0.3)
/// took 1 657 sub-steps counting 4 scene steps (256 at dt / 64 after each sub-step rejected
/// at dt / 32), 641 with 16 sub-steps, and 409 with 4 but a node 1.2 % of its element deep
/// (doc/benchmarks.md).
pub const GROW_AFTER: usize = 16;

/// Relative round-off allowed between the time left and a whole step (see `step_dt`).
const GRID_ROUND_OFF: Real = 1e-9;

/// How an attempt at a step is solved and judged.
#[derive(Debug, Clone, Copy, Default)]
struct Attempt {
    /// Without the second-pass points that repeat first-pass ones ([`thin_second_pass`]).
    thin: bool,
    /// With θ = ξ = 1 (backward Euler, which dissipates), after the scene's θ created energy.
    raised: bool,
    /// At the smallest step the cut-backs allow: kept even beyond the overlap and energy
    /// bounds (counted in [`StepReport::kept_beyond_bounds`]).
    last: bool,
    /// The energy scale the step's gain is measured against.
    energy_scale: Real,
}

pub struct Simulation {
    /// What set-up found worth a warning (a nearly incompressible material on displacement
    /// elements).
    notices: Vec<String>,
    dim: usize,
    bodies: Vec<Body>,
    sets: Vec<BoundarySet>,
    probes: Vec<Probe>,
    gravity: [Real; 3],
    t: Real,
    step: usize,
    end: Real,
    dt: Real,
    xi: Real,
    theta: Real,
    residual_tolerance: Real,
    increment_tolerance: Real,
    max_iterations: usize,
    max_cutbacks: usize,
    /// Step control: the deepest overlap a kept step may leave, in element sizes, and the
    /// share of the energy scale a kept step may create ([`StepFailure::Overlap`],
    /// [`StepFailure::EnergyGain`]).
    max_overlap: Real,
    max_step_energy_gain: Real,
    /// Cut-back level the next sub-step is taken at (`dt / 2^level`), and the easy sub-steps
    /// taken at it since: after [`GROW_AFTER`] the level drops by one (the sub-step doubles
    /// back) where the sub-steps so far tile the longer one.
    level: usize,
    easy_steps: usize,
    /// The deepest overlap the last committed sub-step left, in element sizes.
    last_overlap: Real,
    /// Cumulative work of the reactions of prescribed sets and of moving obstacles.
    external_work: Real,
    friction_dissipation: Real,
    /// Cumulative work of the viscoelastic overstress ([`Energies::viscous_dissipation`]).
    viscous_dissipation: Real,
    numerical_dissipation: Real,
    contact_correction: Real,
    /// Total energy at t = 0 (set by [`Simulation::start`]).
    initial_energy: Real,
    contact: Option<ContactModel>,
    /// Contact points of the last step, with their solution.
    contact_points: Vec<ContactPoint>,
    /// Net force of each obstacle on the bodies over the last step (mean over the step).
    obstacle_reactions: Vec<[Real; 3]>,
    /// Every body's element and assembly kernels on a GPU; `None` runs their CPU twins.
    world: Option<GpuWorld>,
    /// When set (by a signal handler), the step in progress is abandoned at its next Newton
    /// iteration or cut-back ([`StepFailure::Interrupted`]), so that a stop takes effect within
    /// one iteration, not after a step that may never finish.
    interrupt: Option<Arc<AtomicBool>>,
    /// Time and step the run starts from: (0, 0), or a restored state's.
    first_step: (Real, usize),
    /// The warm start of a restored state, until its first step is done.
    restored_warm_start: Option<crate::contact::WarmStart>,
    /// The broad phase's body pairs, kept between steps (they do not change the points or
    /// overlaps found). The overlap search after a step takes the detection's: found for grown
    /// boxes, they hold the pairs of the boxes themselves until a box leaves them.
    kept_pairs: KeptPairs,
    /// The committed state's configuration and largest nodal speed, as the step that committed
    /// it left them (its overlap search built the configuration): the next detection starts
    /// from them instead of visiting every node again. `None` until a step is taken, and after
    /// [`Simulation::load_state`].
    committed: Option<(Configuration, Real)>,
    /// The buffers the next step's configuration is written over (the one before the committed).
    spare_configuration: Configuration,
    /// Bodies without contact points may keep their state on the device between steps (a GPU
    /// world with device Newton iterations): the host's copy of such a body's state is stale
    /// (but for its displacements, when something is near it) until
    /// [`Simulation::sync_states`], and its energies, momenta and box come from the device's
    /// summary. Off, every step's end state comes back.
    hold_states: bool,
}

impl Simulation {
    /// What set-up found worth a warning (a nearly incompressible material on displacement elements).
    pub fn notices(&self) -> &[String] {
        &self.notices
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn bodies(&self) -> &[Body] {
        &self.bodies
    }

    /// The prescribed boundary sets.
    pub fn sets(&self) -> &[BoundarySet] {
        &self.sets
    }

    pub fn probes(&self) -> &[Probe] {
        &self.probes
    }

    /// The time of the committed state.
    pub fn t(&self) -> Real {
        self.t
    }

    /// Steps committed, counted from the run's start (a restored state's step included).
    pub fn step(&self) -> usize {
        self.step
    }

    /// The scene's time step (a cut-back's sub-steps are shorter).
    pub fn dt(&self) -> Real {
        self.dt
    }

    pub fn friction_dissipation(&self) -> Real {
        self.friction_dissipation
    }

    pub fn numerical_dissipation(&self) -> Real {
        self.numerical_dissipation
    }

    /// Total energy at t = 0 (set by [`Simulation::start`]).
    pub fn initial_energy(&self) -> Real {
        self.initial_energy
    }

    pub fn contact(&self) -> &Option<ContactModel> {
        &self.contact
    }

    /// Contact points of the last step, with their solution.
    pub fn contact_points(&self) -> &[ContactPoint] {
        &self.contact_points
    }

    /// Net force of each obstacle on the bodies over the last step (mean over the step).
    pub fn obstacle_reactions(&self) -> &[[Real; 3]] {
        &self.obstacle_reactions
    }

    /// Every body's element and assembly kernels on a GPU; `None` runs their CPU twins.
    pub fn world(&self) -> &Option<GpuWorld> {
        &self.world
    }

    /// Time and step the run starts from: (0, 0), or a restored state's.
    pub fn first_step(&self) -> (Real, usize) {
        self.first_step
    }

    /// One body, to change by hand (a test of a body's response).
    pub fn body_mut(&mut self, index: usize) -> &mut Body {
        &mut self.bodies[index]
    }

    /// Runs the element and assembly kernels of every body on `world` (`None`: their CPU
    /// twins); with a world, bodies without contact points keep their states on the device
    /// ([`Simulation::hold_states`]).
    pub fn set_world(&mut self, world: Option<GpuWorld>) {
        self.hold_states = world.is_some();
        self.world = world;
    }

    /// Whether bodies without contact points keep their states on the device (on with a
    /// world, by [`Simulation::set_world`]).
    pub fn set_hold_states(&mut self, hold: bool) {
        self.hold_states = hold;
    }

    /// The flag a signal handler sets to abandon the step in progress.
    pub fn set_interrupt(&mut self, interrupt: Option<Arc<AtomicBool>>) {
        self.interrupt = interrupt;
    }

    /// Number of steps to reach `end` (the last one is shortened if `end` is not a multiple),
    /// counted from t = 0, or from a restored state with the steps before it.
    pub fn step_count(&self) -> usize {
        let (t0, step0) = self.first_step;
        step0 + (((self.end - t0) / self.dt) - GRID_ROUND_OFF).ceil().max(1.0) as usize
    }

    /// The next step's length: `dt`, or what is left to `end` when that is a shorter step. A step
    /// that lands within round-off of `end` is a whole `dt`, so that a run ends on the same time
    /// grid as a longer run of the scene, and continues on it bit for bit (`--restart`).
    fn step_dt(&self) -> Real {
        let left = self.end - self.t;
        if left >= self.dt * (1.0 - GRID_ROUND_OFF) {
            self.dt
        } else {
            left.max(self.dt * GRID_ROUND_OFF)
        }
    }

    pub fn finished(&self) -> bool {
        self.step >= self.step_count()
    }

    /// Advances one scene step in sub-steps of `dt / 2^level` ([`Simulation::advance_substeps`]).
    pub fn advance(&mut self) -> Result<StepReport, Box<RunFailure>> {
        let started = std::time::Instant::now();
        let dt = self.step_dt();
        let mut report = StepReport { step: self.step + 1, dt, ..Default::default() };
        let submits = self.world.as_ref().map_or(0, GpuWorld::submits);
        let level = self.level.min(self.max_cutbacks);
        let energy_scale = if self.max_step_energy_gain.is_finite() { self.energy_scale() } else { Real::INFINITY };
        let result = self.advance_substeps(dt, energy_scale, &mut report);
        report.wall.total = started.elapsed().as_secs_f64();
        if let Some(world) = &mut self.world {
            let traffic = world.take_traffic();
            (report.bytes_moved, report.bytes_up) = (traffic.total(), traffic.up);
            report.device_submits = world.submits() - submits;
        }
        match result {
            Ok(()) => {
                self.step += 1;
                self.restored_warm_start = None;
                report.t = self.t;
                Ok(report)
            }
            Err((failure, sub_dt)) => Err(Box::new(RunFailure { step: self.step + 1, t: self.t, dt: sub_dt, cutbacks: report.cutbacks, level, failure, report })),
        }
    }

    /// Takes the scene step `dt` in sub-steps of `dt / 2^level`, halving a failed or rejected
    /// attempt up to `max_cutbacks` levels (each half is itself retried the same way). A
    /// sub-step that needed a retry sets the level of the next to the deepest it used;
    /// [`GROW_AFTER`] sub-steps in a row without one double the sub-step where those taken so
    /// far tile the longer one. Counted in sub-steps, not scene steps: a jammed packing that
    /// rejected one sub-step for overlap at dt / 32 took 4 scene steps, 256 sub-steps, at
    /// dt / 64 before trying dt / 32 again.
    fn advance_substeps(&mut self, dt: Real, energy_scale: Real, report: &mut StepReport) -> Result<(), (StepFailure, Real)> {
        let mut level = self.level.min(self.max_cutbacks);
        // Sub-steps of the current level taken so far.
        let mut taken: u64 = 0;
        while taken < 1u64 << level {
            let retries = report.cutbacks + report.overlap_retries + report.energy_retries;
            let mut deepest = level;
            self.advance_by(dt / (1u64 << level) as Real, level, energy_scale, report, &mut deepest)?;
            taken += 1;
            if report.cutbacks + report.overlap_retries + report.energy_retries > retries {
                taken <<= deepest - level;
                (level, self.easy_steps) = (deepest, 0);
            } else {
                self.easy_steps += 1;
                if self.easy_steps >= GROW_AFTER && level > 0 && taken.is_multiple_of(2) {
                    (level, taken, self.easy_steps) = (level - 1, taken / 2, 0);
                }
            }
            self.level = level;
        }
        Ok(())
    }

    /// The energy scale a step's gain is measured against, now ([`Energies::scale`]).
    pub fn energy_scale(&self) -> Real {
        self.energies().scale(self.initial_energy)
    }

    fn advance_by(&mut self, dt: Real, depth: usize, energy_scale: Real, report: &mut StepReport, deepest: &mut usize) -> Result<(), (StepFailure, Real)> {
        if self.interrupted() {
            return Err((StepFailure::Interrupted, dt));
        }
        *deepest = (*deepest).max(depth);
        let attempt = Attempt { last: depth >= self.max_cutbacks, energy_scale, ..Default::default() };
        let mut result = self.try_step(dt, report, attempt);
        if let Err(failure @ StepFailure::NotConverged { .. }) = &result {
            if self.contact.as_ref().is_some_and(|c| c.pairs.any_second()) {
                report.events.push(format!("t = {:.6e}: {failure}; retrying with the second contact pass thinned", self.t));
                result = self.try_step(dt, report, Attempt { thin: true, ..attempt });
            }
        }
        if let Err(failure @ StepFailure::EnergyGain { contact, .. }) = &result {
            report.energy_retries += 1;
            // Only an impact step is taken with backward Euler: raising θ on a step of free
            // elastodynamics would damp the vibration; a shorter step is the cure there.
            if *contact && (self.theta < 1.0 || self.xi < 1.0) {
                report.events.push(format!("t = {:.6e}: {failure}; retrying with theta = xi = 1", self.t));
                result = self.try_step(dt, report, Attempt { raised: true, ..attempt });
                if matches!(result, Err(StepFailure::EnergyGain { .. })) {
                    report.energy_retries += 1;
                }
            }
        }
        if matches!(result, Err(StepFailure::Overlap { .. })) {
            report.overlap_retries += 1;
        }
        match result {
            Ok(()) => Ok(()),
            Err(StepFailure::Interrupted) => Err((StepFailure::Interrupted, dt)),
            Err(failure) if depth < self.max_cutbacks => {
                report.cutbacks += 1;
                report.events.push(format!("t = {:.6e}: {failure}; retrying with dt = {:.3e}", self.t, dt / 2.0));
                self.advance_by(dt / 2.0, depth + 1, energy_scale, report, deepest)?;
                self.advance_by(dt / 2.0, depth + 1, energy_scale, report, deepest)
            }
            Err(failure) => Err((failure, dt)),
        }
    }

    /// Whether the interrupt flag is set.
    pub fn interrupted(&self) -> bool {
        self.interrupt.as_ref().is_some_and(|f| f.load(Ordering::SeqCst))
    }

    /// One attempt at a step of length `dt`, solved and judged as `attempt` says. A converged
    /// attempt that breaks the overlap or energy bound (not at the last level) is rejected
    /// before anything is committed.
    fn try_step(&mut self, dt: Real, report: &mut StepReport, attempt: Attempt) -> Result<(), StepFailure> {
        let Attempt { thin, raised, last, energy_scale } = attempt;
        let p = StepParams { dt, xi: if raised { 1.0 } else { self.xi }, theta: if raised { 1.0 } else { self.theta }, residual_tolerance: self.residual_tolerance, increment_tolerance: self.increment_tolerance, max_iterations: self.max_iterations };
        let started = std::time::Instant::now();
        let (mut points, velocity_scale) = self.detect(dt, &mut report.wall)?;
        if let (true, Some(model), Some((config, _))) = (thin, &self.contact, &self.committed) {
            // The slaves of second-pass points, which the detection placed.
            thin_second_pass(model, &config.nodes.positions, &mut points);
        }
        let warm = self.warm_start();
        report.wall.contact += started.elapsed().as_secs_f64();
        let settings = self.contact.as_ref().map(|c| c.settings.clone());
        let gravity = self.gravity;
        let t = self.t;
        self.bodies.par_iter_mut().for_each(|body| body.begin_step(&p, &gravity, t));
        self.begin_device_step(&p)?;
        let stop = self.interrupt.as_deref();
        let hold = self.hold(&points);
        let (points, groups) = solve_groups(&mut self.bodies, points, &p, settings.as_ref(), &warm, velocity_scale, self.world.as_mut(), stop, hold.as_deref(), &mut report.wall);
        report.add_groups(groups)?;
        // The step's overlaps, measured once on its end state (the state `commit` keeps).
        let started = std::time::Instant::now();
        let mut config = std::mem::take(&mut self.spare_configuration);
        let overlap = match &self.contact {
            Some(model) => {
                let committed = self.committed.as_ref().map(|c| &c.0);
                configure(&self.bodies, model, |b| &b.work.trial.u, Body::held_end, committed, &mut config);
                let search = OverlapSearch::new(model, &config, self.t + dt, &mut self.kept_pairs);
                take_step_ends(&mut self.bodies, self.world.as_mut(), &search.needed, &p, &mut report.wall)?;
                let meshes: Vec<&crate::mesh::Mesh> = self.bodies.iter().map(|b| &b.def.mesh).collect();
                Worst::of(&search.overlaps(model, &meshes, &mut config, &placer(&self.bodies, |b| &b.work.trial.u)))
            }
            None => Worst::default(),
        };
        report.wall.contact += started.elapsed().as_secs_f64();
        if thin && overlap.ratio > THINNED_PENETRATION && !last {
            // Thinning trades convergence for a little penetration; beyond this, a shorter step
            // with both passes is the better trade. At the smallest step there is none: the step
            // is kept like any other beyond the overlap bound, and counted.
            return Err(StepFailure::ThinnedPenetration { ratio: overlap.ratio });
        }
        // Only an overlap the step deepened is retried: one that stays (a master's corner
        // between two slave nodes of a single pass) does not shrink with the step.
        let over_overlap = overlap.ratio > self.max_overlap && overlap.ratio > OVERLAP_GROWTH * self.last_overlap;
        if over_overlap && !last {
            return Err(StepFailure::Overlap { ratio: overlap.ratio, bound: self.max_overlap });
        }
        let stats = ContactStats::of(&points, dt);
        let accumulators = (self.external_work, self.friction_dissipation, self.numerical_dissipation, self.contact_correction, self.viscous_dissipation);
        let speed = self.book_step(&p, &points, stats.friction_dissipation_step, &mut report.wall)?;
        // Created energy: what the scheme dissipated, when negative. The drift correction's
        // input is booked apart and bounded by design (`coupling::shift`); the run's total
        // counts it ([`Simulation::energy_created`]).
        let created = accumulators.2 - self.numerical_dissipation;
        // The work done on the bodies in this step counts in the scale: a body pulled from rest
        // has no energy at the start of its first step.
        let energy_scale = energy_scale.max(self.external_work.abs());
        let over_gain = created > self.max_step_energy_gain * energy_scale;
        if over_gain && !last {
            (self.external_work, self.friction_dissipation, self.numerical_dissipation, self.contact_correction, self.viscous_dissipation) = accumulators;
            let contact = points.iter().any(|c| c.r[0] > 0.0);
            return Err(StepFailure::EnergyGain { gain: created / energy_scale, bound: self.max_step_energy_gain, contact });
        }
        if over_overlap || over_gain {
            report.kept_beyond_bounds += 1;
            let why = if over_overlap { format!("a node {:.3e} elements deep", overlap.ratio) } else { format!("{:.3e} of the energy scale created", created / energy_scale) };
            report.events.push(format!("t = {:.6e}: kept at the smallest step (dt = {dt:.3e}, solver.max_cutbacks reached) with {why}", self.t));
        }
        report.substeps += 1;
        report.raised_theta += raised as usize;
        report.contact.add_substep(&stats);
        self.contact_points = points;
        for body in &mut self.bodies {
            body.commit();
        }
        if let Some(world) = &mut self.world {
            let ends: Vec<StepEnd> = self.bodies.iter().enumerate().map(|(b, body)| body.step_end(b)).collect();
            world.commit_step(&ends, StepMotion::of(p.dt, p.theta, self.dim));
        }
        if let Some((old, _)) = self.committed.replace((config, speed)) {
            self.spare_configuration = old;
        }
        self.t += dt;
        self.last_overlap = overlap.ratio;
        report.contact.max_overlap = report.contact.max_overlap.max(overlap.depth);
        report.contact.max_overlap_ratio = report.contact.max_overlap_ratio.max(overlap.ratio);
        Ok(())
    }

    /// Begins the step of every body on the device, if there is one. A body whose committed
    /// state the device keeps begins there, in contact or not: its inputs and, at the step's end,
    /// its committed state need not go up (a body the host iterates takes the same inputs, which
    /// it computed from the same state).
    fn begin_device_step(&mut self, p: &StepParams) -> Result<(), StepFailure> {
        let Some(world) = &mut self.world else { return Ok(()) };
        let starts: Vec<StepStart> = self.bodies.iter().enumerate().map(|(b, body)| body.step_start(b)).collect();
        world.begin_step(&starts, StepMotion::of(p.dt, p.theta, self.dim)).map_err(|e| self.bodies[0].device_failure(&e))?;
        for (b, relaxation) in self.bodies.iter().enumerate().filter_map(|(b, body)| Some((b, body.relaxation()?))) {
            world.set_relaxation(b, relaxation);
        }
        Ok(())
    }

    /// Per body, what of its step's end may stay on the device ([`Simulation::hold_states`]):
    /// all of it for a body without contact points whose nodes the detection did not place
    /// (nothing is near it), all but its displacements for one the detection placed (the
    /// searches read them). `None` when no body may keep anything there.
    fn hold(&self, points: &[ContactPoint]) -> Option<Vec<Hold>> {
        self.world.as_ref().filter(|w| self.hold_states && w.precision() == Precision::F64)?;
        let mut hold: Vec<Hold> = self.bodies.iter().map(|b| if b.may_step_on_device() { Hold::All } else { Hold::No }).collect();
        if let (Some(_), Some((config, _))) = (&self.contact, &self.committed) {
            for (h, &placed) in hold.iter_mut().zip(&config.nodes.placed) {
                if placed && *h == Hold::All {
                    *h = Hold::AllButPositions;
                }
            }
        }
        for t in points.iter().flat_map(|c| c.terms()) {
            hold[t.body as usize] = Hold::No;
        }
        Some(hold)
    }

    /// The boundary nodes of the committed state that are inside another body or behind an
    /// obstacle (none without contact). The states must be the host's ([`Simulation::sync_states`]).
    pub fn overlaps(&self) -> Vec<Overlap> {
        self.contact.as_ref().map_or_else(Vec::new, |model| state_overlaps(&self.bodies, model, self.t))
    }

    /// Contact points for a step of length `dt` from the committed state, and the step's
    /// velocity scale (fastest body or obstacle, or what gravity adds in one step).
    ///
    /// The velocity scale is what matters in a step: the fastest body or obstacle, or what
    /// gravity adds in one step, but not below round-off of the smallest element per step.
    fn detect(&mut self, dt: Real, times: &mut PhaseTimes) -> Result<(Vec<ContactPoint>, Real), StepFailure> {
        let dim = self.dim;
        if self.committed.is_none() {
            let config = self.contact.as_ref().map(|model| configuration(&self.bodies, model, |b| &b.committed.state.u)).unwrap_or_default();
            let speed = self.bodies.par_iter().map(|b| max_speed(&b.committed.state.v, dim)).reduce(|| 0.0, Real::max);
            self.committed = Some((config, speed));
        }
        let (config, body_speed) = self.committed.as_mut().expect("configured above");
        let body_speed = *body_speed;
        let obstacle_speed = self.contact.iter().flat_map(|c| &c.obstacles).flat_map(|o| [o.motion.velocity(self.t), o.motion.velocity(self.t + dt)]).map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()).fold(0.0, Real::max);
        let h = self.bodies.iter().map(|b| b.length_scale()).fold(Real::INFINITY, Real::min);
        let gravity = self.gravity.iter().map(|g| g * g).sum::<Real>().sqrt();
        let velocity_scale = body_speed.max(obstacle_speed).max(gravity * dt).max(1e-9 * h / dt);
        let Some(model) = &self.contact else { return Ok((Vec::new(), velocity_scale)) };
        // The search reaches as far as anything can travel in two steps, plus a little.
        let margin = 2.0 * dt * (2.0 * body_speed + obstacle_speed) + 0.01 * h;
        let detection = Detection::new(model, config, self.t, dt, margin, &mut self.kept_pairs);
        // The searches place bodies at the host's displacements; a body with contact points is
        // the host's from here on.
        let unplaceable: Vec<usize> = (0..self.bodies.len()).filter(|&b| detection.needed[b] && !self.bodies[b].positions_current()).collect();
        take_committed_of(&mut self.bodies, self.world.as_mut(), &unplaceable, times)?;
        let points = detection.points(model, config, &placer(&self.bodies, |b| &b.committed.state.u), dim, margin);
        let mut touching: Vec<usize> = points.iter().flat_map(|c| c.terms()).map(|t| t.body as usize).filter(|&b| self.bodies[b].held_state().is_some()).collect();
        touching.sort_unstable();
        touching.dedup();
        take_committed_of(&mut self.bodies, self.world.as_mut(), &touching, times)?;
        Ok((points, velocity_scale))
    }

    /// Brings back every committed state the device keeps: the host's copies are current after
    /// this (logged states, VTU frames, probes, restarts, the end of a run).
    pub fn sync_states(&mut self) -> Result<(), StepFailure> {
        let held: Vec<usize> = (0..self.bodies.len()).filter(|&b| self.bodies[b].held_state().is_some()).collect();
        take_committed_of(&mut self.bodies, self.world.as_mut(), &held, &mut PhaseTimes::default())
    }

    /// Makes the host's factorisations where the device made the bodies' last ones within a
    /// Newton call ([`Body::factor_on_device`]), their displacements there in one read: a saved
    /// state holds the host's (a restart factorises them again).
    pub fn sync_factors(&mut self) -> Result<(), StepFailure> {
        let Some(world) = self.world.as_mut() else { return Ok(()) };
        let mut pending: Vec<(usize, &mut Body)> = self.bodies.iter_mut().enumerate().filter(|(_, b)| b.factor_on_device()).collect();
        factorize_where_the_device_did(world, &mut pending, &mut PhaseTimes::default()).into_iter().collect()
    }

    /// Energy bookkeeping of a converged step (before commit): external work, friction (as
    /// [`ContactStats`] counts it) and numerical dissipation, and the obstacles' reactions.
    /// Returns the largest nodal speed at the step's end.
    fn book_step(&mut self, p: &StepParams, points: &[ContactPoint], friction: Real, times: &mut PhaseTimes) -> Result<Real, StepFailure> {
        // Per body its strain energy at the step's end; none for a step end the device keeps (its
        // terms are in the device's sums). f32 kernels leave the energies, like the residual, to
        // the f64 CPU twins.
        let strains: Vec<Option<Real>> = match self.world.as_mut().filter(|w| w.precision() == Precision::F64) {
            None => self.bodies.par_iter().map(|b| Some(b.trial_strain_energy())).collect(),
            Some(world) => {
                // A body that has not moved keeps its state's energy, as on the CPU; one whose
                // device Newton call left its energy at the trial displacement takes that.
                let mut strains: Vec<Option<Real>> = self.bodies.par_iter().map(|b| b.unmoved_strain_energy().or_else(|| b.evaluated_strain_energy())).collect();
                let held: Vec<bool> = self.bodies.iter().map(|b| b.held_end().is_some()).collect();
                let list: Vec<(usize, &[Real])> = self.bodies.iter().enumerate().filter(|(b, _)| strains[*b].is_none() && !held[*b]).map(|(b, body)| (b, &body.work.trial.u[..])).collect();
                // A few bodies (grains that took their step on the host) cost the CPU twins less
                // than a device pass, as a later Newton round does.
                if !list.is_empty() {
                    let energies: Vec<Real> = if crate::backend::round_on_device(world, false, &element_work(list.iter().map(|&(b, _)| &self.bodies[b]))) {
                        world.element_energies(&list, times).map_err(|e| self.bodies[0].device_failure(&e))?.iter().map(|e| e.iter().sum()).collect()
                    } else {
                        list.par_iter().map(|&(b, _)| self.bodies[b].trial_strain_energy()).collect()
                    };
                    for ((b, _), e) in list.iter().zip(energies) {
                        strains[*b] = Some(e);
                    }
                }
                strains.into_iter().zip(held).map(|(s, held)| (!held).then(|| s.expect("every body's energy"))).collect()
            }
        };
        let dim = self.dim;
        let finished: Vec<_> = self
            .bodies
            .par_iter_mut()
            .zip(strains)
            .map(|(body, strain)| match strain {
                Some(strain) => (body.finish_step(p, strain), max_speed(&body.work.trial.v, dim)),
                None => (StepEnergy::default(), 0.0),
            })
            .collect();
        let mut speed = finished.iter().map(|f| f.1).fold(0.0, Real::max);
        for (e, _) in finished {
            self.external_work += e.support_work + e.load_work;
            self.numerical_dissipation += e.theta_dissipation + e.force_dissipation;
            self.viscous_dissipation += e.viscous_dissipation;
        }
        // The step ends the device keeps: neither loads, nor supports, nor Prony series (a body
        // the device steps has none), their theta and force terms summed there.
        if let Some(world) = &self.world {
            let kept = world.step_tally();
            self.numerical_dissipation += (p.theta - 0.5) * kept.theta_term + kept.force_dissipation;
            speed = speed.max(kept.max_speed2.sqrt());
        }
        let mut reactions = vec![[0.0; 3]; self.contact.as_ref().map_or(0, |c| c.obstacles.len())];
        let (mut relative_work, mut correction) = (0.0, 0.0);
        for c in points {
            let f = c.force();
            let mut du = c.obstacle_displacement.map(|x| -x);
            for t in c.terms() {
                let b = &self.bodies[t.body as usize];
                for i in 0..dim {
                    let d = t.node as usize * dim + i;
                    du[i] += t.coef * (b.work.trial.u[d] - b.committed.state.u[d]);
                }
            }
            relative_work += f[0] * du[0] + f[1] * du[1] + f[2] * du[2];
            // A point that started penetrated and separates does so because of the drift
            // correction (this step's, or the velocity the last one left): the reaction's work
            // on that separation is the correction's.
            let separation: Real = (0..3).map(|i| c.frame[0][i] * du[i]).sum();
            if c.gap < 0.0 && separation > 0.0 {
                correction += c.r[0] * separation;
            }
            if let Master::Obstacle { obstacle, .. } = c.master {
                let d = c.obstacle_displacement;
                self.external_work += f[0] * d[0] + f[1] * d[1] + f[2] * d[2];
                for i in 0..3 {
                    reactions[obstacle as usize][i] += f[i];
                }
            }
        }
        self.friction_dissipation += friction;
        self.contact_correction += correction;
        self.numerical_dissipation += correction - relative_work - friction;
        self.obstacle_reactions = reactions;
        Ok(speed)
    }

    /// Energy the run has created so far, relative to the energy scale: the total energy less
    /// what it started with, the external work and the friction dissipation (the drift
    /// correction's input and the scheme's negative dissipation). Zero or negative when the
    /// scheme only dissipated.
    pub fn energy_created(&self) -> Real {
        let e = self.energies();
        (e.total - self.initial_energy - e.external_work + e.friction_dissipation + e.viscous_dissipation) / e.scale(self.initial_energy)
    }

    /// Records the initial energy, the reference of the energy balance.
    pub fn start(&mut self) {
        self.initial_energy = self.energies().total;
    }

    /// Energies now. The balance error is scaled by the largest of `|E(0)|`, `|E|`, `|W_ext|`
    /// and the dissipations, so that it stays meaningful when `E(0)` is zero.
    pub fn energies(&self) -> Energies {
        let mut e = Energies {
            external_work: self.external_work,
            friction_dissipation: self.friction_dissipation,
            viscous_dissipation: self.viscous_dissipation,
            numerical_dissipation: self.numerical_dissipation,
            contact_correction: self.contact_correction,
            ..Default::default()
        };
        // Each body's in parallel, summed in the bodies' order (the same sums on any pool).
        // Without gravity the potential is zero: no pass over every node's position.
        let weightless = self.gravity == [0.0; 3];
        let potential = |b: &Body| if weightless { 0.0 } else { b.potential_energy(&self.gravity) };
        // A body whose committed state the device keeps has its strain energy in the device's sum.
        let bodies: Vec<[Real; 3]> = self.bodies.par_iter().map(|b| [b.kinetic_energy(), b.strain_energy().unwrap_or(0.0), potential(b)]).collect();
        for [kinetic, strain, potential] in bodies {
            e.kinetic += kinetic;
            e.strain += strain;
            e.potential += potential;
        }
        e.strain += self.world.as_ref().map_or(0.0, GpuWorld::held_strain);
        e.total = e.kinetic + e.strain + e.potential;
        let e0 = self.initial_energy;
        let scale = [e0, e.total, e.external_work, e.contact_correction, e.friction_dissipation, e.viscous_dissipation, e.numerical_dissipation, e.kinetic, e.strain].iter().map(|x| x.abs()).fold(Real::MIN_POSITIVE, Real::max);
        e.energy_balance_error = (e0 + e.external_work + e.contact_correction - e.total - e.friction_dissipation - e.viscous_dissipation - e.numerical_dissipation).abs() / scale;
        e
    }

    /// Net reaction force of each boundary set (components beyond `dim` are zero).
    pub fn reactions(&self) -> Vec<[Real; 3]> {
        let mut r = vec![[0.0; 3]; self.sets.len()];
        for b in &self.bodies {
            for (p, f) in b.def.prescribed.iter().zip(&b.work.reactions) {
                r[p.set][p.dof % b.def.dim] += f;
            }
        }
        r
    }
}

/// Mass, centre of mass, momenta and kinetic energy of a body.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct BodyMetrics {
    pub mass: Real,
    pub center_of_mass: [Real; 3],
    pub linear_momentum: [Real; 3],
    /// About the origin; in 2D only the z component is non-zero.
    pub angular_momentum: [Real; 3],
    pub kinetic: Real,
}

impl Body {
    pub fn metrics(&self) -> BodyMetrics {
        let dim = self.def.dim;
        if let Some(h) = self.held_state() {
            let mass: Real = (0..self.def.mesh.nodes.len()).map(|n| self.def.mass[n * dim]).sum();
            return BodyMetrics { mass, center_of_mass: h.mass_moment.map(|c| c / mass), linear_momentum: h.momentum, angular_momentum: h.angular_momentum, kinetic: h.kinetic };
        }
        let (mut mass, mut mx, mut p, mut l) = (0.0, [0.0; 3], [0.0; 3], [0.0; 3]);
        for n in 0..self.def.mesh.nodes.len() {
            let m = self.def.mass[n * dim];
            let x = self.position(n);
            let mut v = [0.0; 3];
            v[..dim].copy_from_slice(&self.committed.state.v[n * dim..(n + 1) * dim]);
            mass += m;
            for i in 0..3 {
                mx[i] += m * x[i];
                p[i] += m * v[i];
            }
            l[0] += m * (x[1] * v[2] - x[2] * v[1]);
            l[1] += m * (x[2] * v[0] - x[0] * v[2]);
            l[2] += m * (x[0] * v[1] - x[1] * v[0]);
        }
        BodyMetrics { mass, center_of_mass: mx.map(|c| c / mass), linear_momentum: p, angular_momentum: l, kinetic: self.kinetic_energy() }
    }
}

/// `scenes/grains_many.toml` with these `--set`s, built, for the unit tests.
#[cfg(test)]
pub(crate) fn grains_many(settings: &[&str]) -> Simulation {
    let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/grains_many.toml"));
    let text = std::fs::read_to_string(path).expect("scene");
    let settings: Vec<String> = settings.iter().map(|s| s.to_string()).collect();
    let loaded = crate::scene::parse_scene(path, text, &settings).expect("scene parses");
    setup::build_simulation(&loaded).expect("simulation")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::geometry::{bounds, edge_range};

    /// Each grain's box and largest facet from its own nodes, although grains of one shape share
    /// their boundary search (a copied boundary once took the first grain's reference nodes for
    /// all of them), and placing fills exactly the bodies asked for.
    #[test]
    fn a_configuration_is_each_bodys_own_and_places_what_is_asked() {
        let mut sim = grains_many(&["packing.count=12"]);
        for (b, body) in sim.bodies.iter_mut().enumerate() {
            body.committed.state.u.iter_mut().enumerate().for_each(|(d, u)| *u = 1e-3 * ((b * 31 + d) as Real).sin());
        }
        let model = sim.contact.as_ref().expect("contact");
        let mut config = configuration(&sim.bodies, model, |b| &b.committed.state.u);
        for (b, body) in sim.bodies.iter().enumerate() {
            let x: Vec<[Real; 3]> = (0..body.def.mesh.nodes.len()).map(|n| position(body, &body.committed.state.u, n)).collect();
            let surface = &model.surfaces[b];
            assert_eq!(config.boxes[b], bounds(surface.nodes.iter().map(|&n| x[n as usize])), "body {b}'s box");
            let largest = (0..surface.facet_count()).map(|f| edge_range(&surface.facet_points(&x, f).0[..surface.facet_nodes]).1).fold(0.0, Real::max);
            assert_eq!(config.largest[b], largest, "body {b}'s largest facet");
        }
        assert!(config.nodes.placed.iter().all(|&p| !p), "nothing placed before it is asked for");
        config.nodes.place(|b| b % 5 == 0, &placer(&sim.bodies, |b| &b.committed.state.u));
        for (b, body) in sim.bodies.iter().enumerate() {
            assert_eq!(config.nodes.placed[b], b % 5 == 0);
            if b % 5 == 0 {
                let expected: Vec<[Real; 3]> = (0..body.def.mesh.nodes.len()).map(|n| position(body, &body.committed.state.u, n)).collect();
                assert_eq!(config.nodes.positions[b], expected);
            }
        }
    }

    /// The boxes a committed configuration keeps for the bodies that did not move are those of
    /// the committed state: a packing whose wall has started to push some grains, the others at
    /// rest, checked against a fresh configuration after every step.
    #[test]
    fn still_bodies_keep_the_boxes_of_their_committed_state() {
        let mut sim = grains_many(&["packing.count=16", "packing.wall_velocity=20.0", "time.end=0.05", "output.scene_every=0"]);
        sim.start();
        let (mut still, mut moved) = (0, 0);
        while !sim.finished() {
            sim.advance().expect("step");
            still += sim.bodies.iter().filter(|b| b.still()).count();
            moved += sim.bodies.iter().filter(|b| !b.still()).count();
            let model = sim.contact.as_ref().expect("contact");
            let fresh = configuration(&sim.bodies, model, |b| &b.committed.state.u);
            let (kept, _) = sim.committed.as_ref().expect("a committed configuration");
            assert_eq!(kept.boxes, fresh.boxes, "t = {}", sim.t);
            assert_eq!(kept.largest, fresh.largest, "t = {}", sim.t);
        }
        assert!(still > 0 && moved > 0, "both kinds of body: {still} still, {moved} moved");
    }
}
