//! The bodies of a step in groups that Newton solves independently: the connected components of
//! the contact graph (two bodies are joined by a contact point between them; an obstacle joins
//! nothing). Each group iterates until its own bodies and contact points have converged and then
//! leaves the loop, so a grain in free flight or at rest costs one evaluation per step, not one
//! per Newton iteration of the busiest cluster. Groups run in parallel.

use super::body::{Body, StepFailure, StepParams};
use super::coupling::ContactStep;
use crate::contact::uzawa::Outcome;
use crate::contact::{ContactPoint, Settings, WarmStart};
use crate::gpu::types::ContactState;
use crate::gpu::uzawa_sweep::{JUDGE_CONVERGED, JUDGE_LIVE};
use crate::gpu::GpuWorld;
use crate::policy::{PhaseTimes, TIGHTEN_AFTER, UZAWA_STALLS};
use crate::precision::Real;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// What the Newton loop of one group did.
#[derive(Debug, Clone, Copy, Default)]
pub struct GroupReport {
    pub iterations: usize,
    pub uzawa_iterations: usize,
    /// Iterations of the semi-smooth Newton solves its stalled contact problems took.
    pub contact_newton_iterations: usize,
    /// Body evaluations: the group's size times its evaluations.
    pub bodies_iterated: usize,
    /// Newton increments its bodies took on the device ([`GpuWorld::newton`]).
    pub device_iterations: usize,
    pub factorizations: usize,
    pub residual_norm: Real,
    pub wall: PhaseTimes,
}

/// Connected components of the bodies joined by contact points, flat: group `g`'s bodies
/// (ascending) are `bodies[body_start[g]..body_start[g + 1]]`, its points (in detection order)
/// likewise. Flat, because a packing at rest is 10 000 groups of one body and no point, and a
/// pair of vectors per group cost more than the groups' Newton loops.
struct Plan {
    bodies: Vec<usize>,
    body_start: Vec<usize>,
    points: Vec<usize>,
    point_start: Vec<usize>,
}

impl Plan {
    fn len(&self) -> usize {
        self.body_start.len() - 1
    }
}

fn components(body_count: usize, points: &[ContactPoint]) -> Plan {
    let mut parent: Vec<usize> = (0..body_count).collect();
    fn root(parent: &mut [usize], mut b: usize) -> usize {
        while parent[b] != b {
            parent[b] = parent[parent[b]];
            b = parent[b];
        }
        b
    }
    for c in points {
        let first = c.terms()[0].body as usize;
        for t in &c.terms()[1..] {
            let (a, b) = (root(&mut parent, first), root(&mut parent, t.body as usize));
            parent[a.max(b)] = a.min(b);
        }
    }
    // Groups numbered in the order of their first body.
    let mut index = vec![usize::MAX; body_count];
    let mut groups = 0;
    let group_of: Vec<usize> = (0..body_count)
        .map(|b| {
            let r = root(&mut parent, b);
            if index[r] == usize::MAX {
                index[r] = groups;
                groups += 1;
            }
            index[r]
        })
        .collect();
    let point_group: Vec<usize> = points.iter().map(|c| group_of[c.terms()[0].body as usize]).collect();
    let (bodies, body_start) = counting_sort(&group_of, groups);
    let (points, point_start) = counting_sort(&point_group, groups);
    Plan { bodies, body_start, points, point_start }
}

/// The indices `0..keys.len()` ordered by key (stably), and where each key's run starts (with
/// the end appended).
fn counting_sort(keys: &[usize], count: usize) -> (Vec<usize>, Vec<usize>) {
    let mut start = vec![0; count + 1];
    for &k in keys {
        start[k + 1] += 1;
    }
    for g in 0..count {
        start[g + 1] += start[g];
    }
    let mut next = start.clone();
    let mut order = vec![0; keys.len()];
    for (i, &k) in keys.iter().enumerate() {
        order[next[k]] = i;
        next[k] += 1;
    }
    (order, start)
}

/// One group during a step: its bodies (borrowed from the simulation: a body is 1.3 KB, and
/// moving 10 000 resting grains in and out of groups cost more than their evaluation), its
/// contact problem (none without points: most groups of a packing) with body indices local to
/// the group.
pub(super) struct Group<'a, 'b> {
    pub(super) ids: &'a [usize],
    pub(super) bodies: &'a mut [&'b mut Body],
    point_ids: &'a [usize],
    pub(super) contact: Option<Box<ContactStep>>,
    pub(super) newton: NewtonState,
}

/// Solves a step's Newton problem group by group: on the CPU each group runs its own loop, the
/// groups in parallel; with a GPU `world` the groups iterate in lockstep, so that each Newton
/// iteration evaluates the bodies of every group still iterating in one device pass. The points
/// (global indices, with their solution) are returned in detection order, whether the step
/// converged or not. Forming the groups counts as `contact` time, the device passes in `times`.
#[allow(clippy::too_many_arguments)]
pub fn solve_groups(
    bodies: &mut [Body],
    points: Vec<ContactPoint>,
    p: &StepParams,
    settings: Option<&Settings>,
    warm: &WarmStart,
    velocity_scale: Real,
    world: Option<&mut GpuWorld>,
    interrupt: Option<&AtomicBool>,
    hold: Option<&[Hold]>,
    times: &mut PhaseTimes,
) -> (Vec<ContactPoint>, Vec<Result<GroupReport, StepFailure>>) {
    let started = std::time::Instant::now();
    let plan = components(bodies.len(), &points);
    // Each body's index in its group, and the bodies in the plan's order, handed out in one pass.
    let mut local = vec![0u32; bodies.len()];
    let mut slot = vec![0usize; bodies.len()];
    for g in 0..plan.len() {
        for (k, i) in (plan.body_start[g]..plan.body_start[g + 1]).enumerate() {
            (local[plan.bodies[i]], slot[plan.bodies[i]]) = (k as u32, i);
        }
    }
    let mut members: Vec<Option<&mut Body>> = (0..bodies.len()).map(|_| None).collect();
    for (b, body) in bodies.iter_mut().enumerate() {
        members[slot[b]] = Some(body);
    }
    let mut members: Vec<&mut Body> = members.into_iter().map(|b| b.expect("every body is in a group")).collect();
    let mut points: Vec<Option<ContactPoint>> = points.into_iter().map(Some).collect();
    let mut rest: &mut [&mut Body] = &mut members;
    let mut groups: Vec<Group> = Vec::with_capacity(plan.len());
    let mut group_points: Vec<Option<Vec<ContactPoint>>> = Vec::with_capacity(plan.len());
    for g in 0..plan.len() {
        let (group_bodies, tail) = std::mem::take(&mut rest).split_at_mut(plan.body_start[g + 1] - plan.body_start[g]);
        rest = tail;
        let point_ids = &plan.points[plan.point_start[g]..plan.point_start[g + 1]];
        group_points.push((!point_ids.is_empty()).then(|| {
            point_ids
                .iter()
                .map(|&i| {
                    let mut c = points[i].take().expect("a point is in one group");
                    for t in &mut c.terms[..c.term_count] {
                        t.body = local[t.body as usize];
                    }
                    c
                })
                .collect()
        }));
        groups.push(Group { ids: &plan.bodies[plan.body_start[g]..plan.body_start[g + 1]], bodies: group_bodies, point_ids, contact: None, newton: NewtonState::default() });
    }
    groups.par_iter_mut().zip(group_points).filter_map(|(g, points)| Some((g, points?))).for_each(|(g, points)| {
        g.contact = Some(Box::new(ContactStep::new(points, g.bodies, p, warm, velocity_scale)));
    });
    times.contact += started.elapsed().as_secs_f64();
    let context = Context { p, settings, velocity_scale, interrupt, hold };
    let reports = match world {
        None => groups.par_iter_mut().map(|g| g.newton_on_cpu(&context)).collect(),
        Some(world) => super::lockstep::newton_in_lockstep(&mut groups, world, &context, times),
    };
    for g in groups {
        let Some(contact) = g.contact else { continue };
        for (mut c, &i) in contact.points.into_iter().zip(g.point_ids) {
            for t in &mut c.terms[..c.term_count] {
                t.body = g.ids[t.body as usize] as u32;
            }
            points[i] = Some(c);
        }
    }
    (points.into_iter().map(|c| c.expect("every point came back")).collect(), reports)
}

/// What every group's Newton loop shares in a step.
pub(super) struct Context<'a> {
    pub(super) p: &'a StepParams,
    pub(super) settings: Option<&'a Settings>,
    pub(super) velocity_scale: Real,
    /// The run's interrupt flag, checked before every increment.
    pub(super) interrupt: Option<&'a AtomicBool>,
    /// Per body, what of its step's end a device Newton call may keep on the device; `None`:
    /// nothing, for any body.
    pub(super) hold: Option<&'a [Hold]>,
}

/// What of a body's step end may stay on the device ([`crate::gpu::NewtonCall::keep`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// Nothing: the body has contact points, or steps by rules of its own.
    No,
    /// All of it: nothing is near the body.
    All,
    /// All but its displacements, which the searches of the step read (something is near it,
    /// but it has no contact point).
    AllButPositions,
}

/// Where a group's Newton loop stands between two evaluations.
#[derive(Default)]
pub(super) struct NewtonState {
    pub(super) report: GroupReport,
    last_change: Option<Real>,
    /// `false` until the first increment: the Uzawa sweeps have not run yet.
    uzawa_ran: bool,
    uzawa_converged: bool,
    /// Newton iterations in a row whose Uzawa sweeps did not converge.
    pub(super) uzawa_stalls: usize,
    /// The last solve ran on the device and was cut short, still live (a software adapter's
    /// dispatches take fewer sweeps, `SOFTWARE_SOLVE_DISPATCHES`): the next increment's runs
    /// whole on the host's path, or the same cut would count as stalls until the step fails.
    pub(super) cut_short: bool,
}

impl NewtonState {
    /// What an increment's Uzawa solve (on the host or the device) leaves for the group's
    /// convergence test: its sweeps, whether it converged, the contact forces' last change.
    fn record_solve(&mut self, sweeps: usize, converged: bool, change: Real) {
        self.report.uzawa_iterations += sweeps;
        self.uzawa_ran = true;
        self.uzawa_converged = converged;
        self.uzawa_stalls = if converged { 0 } else { self.uzawa_stalls + 1 };
        self.last_change = Some(change);
        self.cut_short = false;
    }

    /// What a device call's increments leave ([`ContactState`]): its last solve, the stalls
    /// the device counted on from the group's, and whether that solve was cut short.
    pub(super) fn record_device_solve(&mut self, o: &ContactState<Real>) {
        self.record_solve(o.sweeps as usize, o.uzawa == JUDGE_CONVERGED, o.change);
        self.uzawa_stalls = o.stalls as usize;
        self.cut_short = o.uzawa == JUDGE_LIVE;
    }
}

/// A contact criterion a group's convergence test found unmet, worded only for a failure
/// message (as the bodies' own, [`Body::unmet`]).
enum ContactUnmet {
    Changing { change: Real, tolerance: Real },
    NotSolved,
    Uzawa,
    Complementarity { complementarity: Real, tolerance: Real },
}

impl std::fmt::Display for ContactUnmet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Changing { change, tolerance } => write!(f, "contact forces still changing by {change:.3e} > {tolerance:.3e}"),
            Self::NotSolved => write!(f, "contact forces not solved yet"),
            Self::Uzawa => write!(f, "Uzawa iterations not converged"),
            Self::Complementarity { complementarity, tolerance } => write!(f, "complementarity {complementarity:.3e} > {tolerance:.3e}"),
        }
    }
}

impl Group<'_, '_> {
    /// The Newton loop of one group on the CPU (paper eqs. 16-19, with contact as in
    /// `coupling.rs`), until its bodies meet the solver tolerances and its contact points the
    /// contact criteria.
    fn newton_on_cpu(&mut self, c: &Context) -> Result<GroupReport, StepFailure> {
        loop {
            for body in self.bodies.iter_mut() {
                body.evaluate(c.p, &mut self.newton.report.wall)?;
            }
            self.newton.report.bodies_iterated += self.bodies.len();
            if self.converged(c)? {
                return Ok(self.finish(c.p));
            }
            self.increment(c)?;
        }
    }

    /// After the bodies' evaluation: applies the contact forces and tests convergence; an error
    /// when the iterations are spent.
    pub(super) fn converged(&mut self, c: &Context) -> Result<bool, StepFailure> {
        let (p, bodies, state) = (c.p, &mut *self.bodies, &mut self.newton);
        if let Some(contact) = &mut self.contact {
            contact.apply_forces(bodies);
        }
        let mut converged = true;
        for body in bodies.iter_mut() {
            converged &= body.converged(p, c.velocity_scale * p.dt)?;
        }
        let mut contact_unmet = Vec::new();
        if let Some(contact) = &self.contact {
            let tolerance = c.settings.expect("contact points need contact settings").tolerance;
            // A step that starts from last step's solution may already satisfy everything.
            match state.last_change {
                Some(change) if change > tolerance => contact_unmet.push(ContactUnmet::Changing { change, tolerance }),
                None if !contact.all_warm() => contact_unmet.push(ContactUnmet::NotSolved),
                _ => {}
            }
            if state.uzawa_ran && !state.uzawa_converged {
                contact_unmet.push(ContactUnmet::Uzawa);
            }
            // Before any Uzawa sweep of this step (reactions carried over from the last step),
            // the law is checked point by point; after one, the sweeps' own convergence and the
            // change of the nodal forces say it (per point, nearly redundant points, as of two
            // passes over faces lying on each other, may keep an ill-determined split of their
            // reactions that the bodies never see).
            if !state.uzawa_ran {
                let complementarity = contact.complementarity(bodies, p);
                if complementarity > tolerance {
                    contact_unmet.push(ContactUnmet::Complementarity { complementarity, tolerance });
                }
            }
            converged &= contact_unmet.is_empty();
        }
        if converged {
            return Ok(true);
        }
        // Forces balanced and reactions settled, increments still above their bound after a few
        // iterations: what remains is the reactions' inexactness.
        if state.report.iterations >= TIGHTEN_AFTER && contact_unmet.is_empty() && bodies.iter().all(|b| b.balanced()) {
            if let Some(contact) = &mut self.contact {
                contact.tighten();
            }
        }
        if state.report.iterations == p.max_iterations || state.uzawa_stalls >= UZAWA_STALLS {
            let names: Vec<String> = bodies.iter().map(|b| format!("`{}`", b.def.name)).collect();
            let bodies_named = if names.len() == 1 { format!("body {}", names[0]) } else { format!("bodies {} (coupled by contact)", names.join(", ")) };
            let unmet: Vec<String> = bodies.iter().flat_map(|b| b.unmet()).chain(contact_unmet.iter().map(ContactUnmet::to_string)).collect();
            return Err(StepFailure::NotConverged { bodies: bodies_named, iterations: state.report.iterations, unmet: unmet.join("; ") });
        }
        Ok(false)
    }

    /// One Newton increment on the CPU: [`Group::begin_increment`], the contact problem's Uzawa
    /// iterations, [`Group::end_increment`].
    fn increment(&mut self, c: &Context) -> Result<(), StepFailure> {
        if self.begin_increment(c)? {
            let contact = self.contact.as_mut().expect("a group waiting on its contact problem has one");
            let outcome = contact.solve_on_cpu(c.settings.expect("contact settings"), c.interrupt, &mut self.newton.report.wall);
            self.end_increment(c, outcome)?;
        }
        Ok(())
    }

    /// The factorisations that are due, then either the increment of every body (no contact
    /// points) or the contact problem prepared: `true` when it waits to be solved.
    pub(super) fn begin_increment(&mut self, c: &Context) -> Result<bool, StepFailure> {
        let Some(refactorized) = self.refresh_for_increment(c)? else { return Ok(false) };
        self.prepare_contact(c, &refactorized);
        Ok(true)
    }

    /// [`Group::begin_increment`] up to the contact problem: the factorisations refreshed, and
    /// a group without contact incremented. Returns which bodies refactorised when the group
    /// has contact ([`Group::prepare_contact`] next, unless the device takes the increment).
    pub(super) fn refresh_for_increment(&mut self, c: &Context) -> Result<Option<Vec<bool>>, StepFailure> {
        if c.interrupt.is_some_and(|f| f.load(Ordering::SeqCst)) {
            return Err(StepFailure::Interrupted);
        }
        let (p, bodies, state) = (c.p, &mut *self.bodies, &mut self.newton);
        let mut refactorized = Vec::with_capacity(bodies.len());
        for body in bodies.iter_mut() {
            let fresh = body.refresh_factor(p, &mut state.report.wall)?;
            refactorized.push(fresh);
            state.report.factorizations += fresh as usize;
        }
        if self.contact.is_some() {
            return Ok(Some(refactorized));
        }
        for body in bodies.iter_mut() {
            body.newton_step(&mut state.report.wall);
        }
        state.report.iterations += 1;
        Ok(None)
    }

    /// The contact problem of the increment, with the bodies that just refactorised
    /// (`refactorized`).
    pub(super) fn prepare_contact(&mut self, c: &Context, refactorized: &[bool]) {
        let contact = self.contact.as_mut().expect("a group whose increment waits on contact");
        contact.prepare(self.bodies, c.p, c.settings.expect("contact settings"), refactorized, &mut self.newton.report.wall);
    }

    /// The increment after the contact problem is solved: the reactions applied, the bodies
    /// incremented.
    pub(super) fn end_increment(&mut self, c: &Context, outcome: Outcome) -> Result<(), StepFailure> {
        if c.interrupt.is_some_and(|f| f.load(Ordering::SeqCst)) {
            return Err(StepFailure::Interrupted);
        }
        let state = &mut self.newton;
        let change = self.contact.as_mut().expect("a group with an outcome has contact").apply(self.bodies, &mut state.report.wall);
        state.record_solve(outcome.iterations, outcome.converged, change);
        state.report.contact_newton_iterations += outcome.newton_iterations;
        state.report.wall.contact_newton += outcome.newton_seconds;
        state.report.iterations += 1;
        Ok(())
    }

    /// The report of a converged group, after the contact points take their solution.
    pub(super) fn finish(&mut self, p: &StepParams) -> GroupReport {
        // (a step end the device keeps has its residual in the device's sums: GpuWorld::step_tally)
        self.newton.report.residual_norm = self.bodies.iter().filter(|b| b.held_end().is_none()).map(|b| b.residual_norm()).fold(0.0, Real::max);
        if let Some(contact) = &mut self.contact {
            contact.finish(self.bodies, p);
        }
        self.newton.report
    }
}
