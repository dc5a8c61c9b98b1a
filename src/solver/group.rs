//! The bodies of a step in groups that Newton solves independently: the connected components of
//! the contact graph (two bodies are joined by a contact point between them; an obstacle joins
//! nothing). Each group iterates until its own bodies and contact points have converged and then
//! leaves the loop, so a grain in free flight or at rest costs one evaluation per step, not one
//! per Newton iteration of the busiest cluster. Groups run in parallel.

use super::body::{coefficients, Body, StepFailure, StepParams};
use super::coupling::ContactStep;
use crate::policy::{PhaseTimes, TIGHTEN_AFTER, UZAWA_STALLS};
use crate::contact::uzawa::{Outcome, Problem};
use crate::contact::{ContactPoint, Settings, WarmStart};
use crate::gpu::types::ContactState;
use crate::gpu::uzawa_sweep::{JUDGE_CONVERGED, JUDGE_LIVE};
use crate::gpu::{ElementFailure, Evaluation, GpuWorld, GroupContact, NewtonCall};
use crate::mesh::ElementKind;
use crate::precision::{Precision, Real};
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
struct Group<'a, 'b> {
    ids: &'a [usize],
    bodies: &'a mut [&'b mut Body],
    point_ids: &'a [usize],
    contact: Option<Box<ContactStep>>,
    newton: NewtonState,
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
    let context = Context { p, settings, velocity_scale, interrupt };
    let reports = match world {
        None => groups.par_iter_mut().map(|g| g.newton_on_cpu(&context)).collect(),
        Some(world) => newton_in_lockstep(&mut groups, world, &context, times),
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
struct Context<'a> {
    p: &'a StepParams,
    settings: Option<&'a Settings>,
    velocity_scale: Real,
    /// The run's interrupt flag, checked before every increment.
    interrupt: Option<&'a AtomicBool>,
}

/// Where a group's Newton loop stands between two evaluations.
#[derive(Default)]
struct NewtonState {
    report: GroupReport,
    last_change: Option<Real>,
    /// `false` until the first increment: the Uzawa sweeps have not run yet.
    uzawa_ran: bool,
    uzawa_converged: bool,
    /// Newton iterations in a row whose Uzawa sweeps did not converge.
    uzawa_stalls: usize,
    /// The last solve ran on the device and was cut short, still live (a software adapter's
    /// dispatches take fewer sweeps, `SOFTWARE_SOLVE_DISPATCHES`): the next increment's runs
    /// whole on the host's path, or the same cut would count as stalls until the step fails.
    cut_short: bool,
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
    fn record_device_solve(&mut self, o: &ContactState<Real>) {
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
    fn converged(&mut self, c: &Context) -> Result<bool, StepFailure> {
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
            let names: Vec<String> = bodies.iter().map(|b| format!("`{}`", b.name)).collect();
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
    fn begin_increment(&mut self, c: &Context) -> Result<bool, StepFailure> {
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
        let Some(contact) = &mut self.contact else {
            for body in bodies.iter_mut() {
                body.newton_step(&mut state.report.wall);
            }
            state.report.iterations += 1;
            return Ok(false);
        };
        contact.prepare(bodies, p, c.settings.expect("contact settings"), &refactorized, &mut state.report.wall);
        Ok(true)
    }

    /// The increment after the contact problem is solved: the reactions applied, the bodies
    /// incremented.
    fn end_increment(&mut self, c: &Context, outcome: Outcome) -> Result<(), StepFailure> {
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
    fn finish(&mut self, p: &StepParams) -> GroupReport {
        self.newton.report.residual_norm = self.bodies.iter().map(|b| b.residual_norm()).fold(0.0, Real::max);
        if let Some(contact) = &mut self.contact {
            contact.finish(self.bodies, p);
        }
        self.newton.report
    }
}

/// The Newton loops of all groups in lockstep with a GPU world. Each round: one device pass
/// evaluates the bodies of every group still iterating (forces and residuals); the groups test
/// convergence in parallel; one device pass computes the tangents of the bodies that
/// refactorise; the groups take their increments in parallel. The number of device passes per
/// Newton iteration does not depend on the number of bodies. A round whose element work is not
/// worth a device pass ([`crate::backend::round_on_device`]: after the first, mostly a few
/// grains in contact) evaluates on the CPU twins instead, so that the passes of a step do not
/// grow with its Newton iterations.
fn newton_in_lockstep(groups: &mut [Group], world: &mut GpuWorld, c: &Context, times: &mut PhaseTimes) -> Vec<Result<GroupReport, StepFailure>> {
    let mut outcome: Vec<Option<Result<GroupReport, StepFailure>>> = (0..groups.len()).map(|_| None).collect();
    // In f32 the residual is computed in f64 on the CPU; the device gives the tangents.
    let device_residual = world.precision() == Precision::F64;
    let mut first = true;
    let none = vec![false; groups.len()];
    // The groups whose Newton iterations go to the device with this round's pass (in the first
    // round, unevaluated), and the batch of those in contact.
    let mut contact_batch = None;
    let mut iterating = if device_residual { evaluate_on_device_first(groups, world, c, &mut contact_batch) } else { none.clone() };
    build_for_device(groups, &iterating, c);
    loop {
        let live: Vec<bool> = outcome.iter().map(Option::is_none).collect();
        if !live.iter().any(|&l| l) {
            break;
        }
        let wanted = |_: &Body| true;
        let evaluating: Vec<bool> = live.iter().zip(&iterating).map(|(&l, &i)| l && !i).collect();
        let others_on_device = device_residual && on_device(groups, &evaluating, &wanted, world, first);
        let mut evaluated = if others_on_device || iterating.contains(&true) {
            device_pass(groups, if others_on_device { &evaluating } else { &none }, (&iterating, first), world, c, false, &wanted, times)
        } else {
            groups.iter().map(|_| Ok(())).collect()
        };
        if !others_on_device {
            let on_cpu: Vec<Result<(), StepFailure>> = groups
                .par_iter_mut()
                .zip(&evaluating)
                .map(|(g, &e)| {
                    if !e {
                        return Ok(());
                    }
                    for body in g.bodies.iter_mut() {
                        body.evaluate_residual_on_cpu(c.p, &mut g.newton.report.wall)?;
                    }
                    Ok(())
                })
                .collect();
            for (result, cpu) in evaluated.iter_mut().zip(on_cpu) {
                if result.is_ok() {
                    *result = cpu;
                }
            }
        }
        let checked: Vec<Option<Result<bool, StepFailure>>> = groups
            .par_iter_mut()
            .zip(evaluated)
            .zip(&live)
            .map(|((g, evaluated), &l)| {
                l.then(|| {
                    evaluated?;
                    g.newton.report.bodies_iterated += g.bodies.len();
                    g.converged(c)
                })
            })
            .collect();
        let mut continuing = vec![false; groups.len()];
        for (k, check) in checked.into_iter().enumerate() {
            match check {
                None => {}
                Some(Ok(true)) => outcome[k] = Some(Ok(groups[k].finish(c.p))),
                Some(Ok(false)) => continuing[k] = true,
                Some(Err(e)) => outcome[k] = Some(Err(e)),
            }
        }
        iterating = if device_residual { iterate_on_device(groups, &mut continuing, world, c, &mut contact_batch, false) } else { none.clone() };
        build_for_device(groups, &iterating, c);
        let p = c.p;
        let needs_tangent = |b: &Body| b.needs_tangent(p);
        // Else each body's `refresh_factor` assembles its tangent on the CPU.
        let tangents = if on_device(groups, &continuing, &needs_tangent, world, first) {
            device_pass(groups, &continuing, (&none, false), world, c, true, &needs_tangent, times)
        } else {
            groups.iter().map(|_| Ok(())).collect()
        };
        let begun: Vec<Option<Result<bool, StepFailure>>> =
            groups.par_iter_mut().zip(tangents).zip(&continuing).map(|((g, tangents), &go)| go.then(|| tangents.and_then(|()| g.begin_increment(c)))).collect();
        let mut waiting = vec![false; groups.len()];
        for (k, result) in begun.into_iter().enumerate() {
            match result {
                Some(Err(e)) => outcome[k] = Some(Err(e)),
                Some(Ok(true)) => waiting[k] = true,
                _ => {}
            }
        }
        // A group whose bodies just refactorised (W rebuilt for them) takes this increment on
        // the device with the next round's pass rather than on the host, where it may.
        if device_residual {
            let deferred = iterate_on_device(groups, &mut waiting, world, c, &mut contact_batch, true);
            for (i, d) in iterating.iter_mut().zip(deferred) {
                *i |= d;
            }
        }
        let solved = solve_contact(groups, &waiting, world, c, times);
        let ended: Vec<Option<Result<(), StepFailure>>> =
            groups.par_iter_mut().zip(solved).zip(&waiting).map(|((g, solved), &wait)| wait.then(|| solved.and_then(|o| g.end_increment(c, o)))).collect();
        for (k, result) in ended.into_iter().enumerate() {
            if let Some(Err(e)) = result {
                outcome[k] = Some(Err(e));
            }
        }
        first = false;
    }
    outcome.into_iter().map(|o| o.expect("every group has an outcome")).collect()
}

/// The groups whose first evaluation of a step goes to the device with their Newton iterations
/// ([`GpuWorld::newton`] evaluates and judges them before the first increment), with element
/// work worth device passes: bodies that keep their factorisation, whose `K̄⁻¹` the device
/// holds; either one body without contact points whose trial displacement is not that of its
/// last evaluation (a grain at rest takes that one again), or a group in contact as
/// [`iterate_on_device`] takes them (problems solved whole on the device, the step's
/// `contact_batch`), whose W [`build_for_device`] builds first. A falling grain then costs one
/// submission a step, not an evaluation pass, its read-back and the Newton call's upload of
/// the same residuals; a cluster of grains in contact, one submission less.
fn evaluate_on_device_first(groups: &[Group], world: &GpuWorld, c: &Context, contact_batch: &mut Option<usize>) -> Vec<bool> {
    let p = c.p;
    let software = world.software();
    let fits = |b: &Body, id: usize| world.newton_capable(id) && b.iterates_on_device(p) && world.newton_inverse_current(id, b.factor_version());
    let alone = |g: &Group| g.bodies.len() == 1 && fits(g.bodies[0], g.ids[0]) && !g.bodies[0].evaluation_holds(p);
    let mut chosen: Vec<bool> = groups.par_iter().map(|g| p.max_iterations > 0 && g.contact.is_none() && alone(g)).collect();
    let solvable = |_: usize, g: &Group| p.max_iterations > 0 && g.contact.as_ref().is_some_and(|k| k.solved_whole(software)) && g.bodies.iter().zip(g.ids).all(|(b, &id)| fits(b, id));
    let (in_contact, batch) = contact_groups_on_device(groups, &solvable, world, c, *contact_batch);
    for (chosen, &yes) in chosen.iter_mut().zip(&in_contact) {
        *chosen |= yes;
    }
    if !chosen.contains(&true) || !crate::backend::round_on_device(world, false, &element_work(groups, &chosen, &|_| true)) {
        return vec![false; groups.len()];
    }
    *contact_batch = batch;
    chosen
}

/// The groups in contact that `candidate` admits whose bodies lie in one batch, the step's
/// `contact_batch` (or the first such group's while the step has none), and whose problems'
/// sweeps go to the device ([`sweeps_on_device`]); none when they do not. Returns them and the
/// batch the step then has.
fn contact_groups_on_device(groups: &[Group], candidate: &dyn Fn(usize, &Group) -> bool, world: &GpuWorld, c: &Context, contact_batch: Option<usize>) -> (Vec<bool>, Option<usize>) {
    let mut in_contact = vec![false; groups.len()];
    let mut batch_taken = contact_batch;
    for (k, g) in groups.iter().enumerate() {
        if g.contact.is_some() && candidate(k, g) {
            let batch = world.batch_of(g.ids[0]);
            in_contact[k] = g.ids.iter().all(|&id| world.batch_of(id) == batch) && *batch_taken.get_or_insert(batch) == batch;
        }
    }
    if !in_contact.contains(&true) || !c.settings.is_some_and(|settings| sweeps_on_device(groups, &in_contact, world, settings)) {
        return (vec![false; groups.len()], contact_batch);
    }
    (in_contact, batch_taken)
}

/// The `continuing` groups whose next Newton iterations go to the device
/// ([`GpuWorld::newton`], with the next round's pass): bodies that keep their factorisation and
/// have a slot for `K̄⁻¹` there, and element work worth device passes
/// ([`crate::backend::round_on_device`]); either one body without contact points, or a group in
/// contact (also one whose last solve spent its sweeps: the device counts the stalls on, as
/// [`Group::converged`] does) with problems solved whole on the device
/// ([`crate::backend::uzawa_on_device`], colours of at most [`SOLVE_WIDEST`] points) and its
/// bodies in the step's `contact_batch` (that of the first such group); such a group's W is
/// built by [`build_for_device`] when no increment of the step built it yet. `refreshed`: the
/// groups' factorisations were just refreshed for their next increment. They leave `continuing`
/// for this round.
fn iterate_on_device(groups: &[Group], continuing: &mut [bool], world: &GpuWorld, c: &Context, contact_batch: &mut Option<usize>, refreshed: bool) -> Vec<bool> {
    let p = c.p;
    let fit = |b: &Body| if refreshed { b.factor_fit(p) } else { b.iterates_on_device(p) };
    let capable = |g: &Group| g.newton.report.iterations < p.max_iterations && g.bodies.iter().zip(g.ids).all(|(b, &id)| world.newton_capable(id) && fit(b));
    let software = world.software();
    let solvable = |k: usize, g: &Group| continuing[k] && capable(g) && !g.newton.cut_short && g.contact.as_ref().is_some_and(|k| k.solved_whole(software));
    let (in_contact, batch) = contact_groups_on_device(groups, &solvable, world, c, *contact_batch);
    let chosen: Vec<bool> = groups.iter().enumerate().map(|(k, g)| in_contact[k] || (continuing[k] && g.contact.is_none() && g.bodies.len() == 1 && capable(g))).collect();
    if !chosen.contains(&true) || !crate::backend::round_on_device(world, false, &element_work(groups, &chosen, &|_| true)) {
        return vec![false; groups.len()];
    }
    for (go, &chosen) in continuing.iter_mut().zip(&chosen) {
        *go &= !chosen;
    }
    *contact_batch = batch;
    chosen
}

/// The Delassus operators of the `iterating` groups in contact that no increment of the step
/// built yet (their first increment goes to the device), in parallel.
fn build_for_device(groups: &mut [Group], iterating: &[bool], c: &Context) {
    groups.par_iter_mut().zip(iterating).filter(|(g, &yes)| yes && g.contact.as_ref().is_some_and(|k| !k.delassus_built(g.bodies.len()))).for_each(|(g, _)| {
        let contact = g.contact.as_mut().expect("filtered");
        contact.build_delassus_for(g.bodies, c.p, c.settings.expect("contact points need contact settings"), &mut g.newton.report.wall);
    });
}

/// Whether the round's pass over the bodies of the `live` groups that `wanted` selects goes to
/// the device ([`crate::backend::round_on_device`]).
fn on_device(groups: &[Group], live: &[bool], wanted: &dyn Fn(&Body) -> bool, world: &GpuWorld, first: bool) -> bool {
    let work = if first { Vec::new() } else { element_work(groups, live, wanted) };
    crate::backend::round_on_device(world, first, &work)
}

/// The elements of each kind of the bodies of the `live` groups that `wanted` selects.
fn element_work(groups: &[Group], live: &[bool], wanted: &dyn Fn(&Body) -> bool) -> Vec<(ElementKind, usize)> {
    let mut work: Vec<(ElementKind, usize)> = Vec::new();
    for body in groups.iter().zip(live).filter(|(_, &l)| l).flat_map(|(g, _)| g.bodies.iter()).filter(|b| wanted(b)) {
        let mesh = body.elements();
        match work.iter_mut().find(|(kind, _)| *kind == mesh.kind) {
            Some((_, n)) => *n += mesh.element_count(),
            None => work.push((mesh.kind, mesh.element_count())),
        }
    }
    work
}

/// Whether the Uzawa sweeps of the `chosen` groups' contact problems go to the device
/// ([`crate::backend::uzawa_on_device`], from their points, colours and widest colour); never
/// without a point.
fn sweeps_on_device(groups: &[Group], chosen: &[bool], world: &GpuWorld, settings: &Settings) -> bool {
    let problems = || groups.iter().zip(chosen).filter(|(_, &yes)| yes).filter_map(|(g, _)| g.contact.as_ref());
    let points: usize = problems().map(|k| k.points.len()).sum();
    let colours = problems().map(|k| k.colours.count()).max().unwrap_or(0);
    let widest = problems().map(|k| k.widest_colour()).max().unwrap_or(0);
    points > 0 && crate::backend::uzawa_on_device(world, settings, points, colours, widest)
}

/// The Uzawa iterations of the `waiting` groups' contact problems: on the device, all in one
/// solve, where [`crate::backend::uzawa_on_device`] says so (and they fit the device's
/// buffers), else each group's on the CPU, in parallel. A device error fails every waiting
/// group.
fn solve_contact(groups: &mut [Group], waiting: &[bool], world: &mut GpuWorld, c: &Context, times: &mut PhaseTimes) -> Vec<Result<Outcome, StepFailure>> {
    let Some(settings) = c.settings else { return groups.iter().map(|_| Ok(Outcome::default())).collect() };
    if sweeps_on_device(groups, waiting, world, settings) {
        let owners: Vec<usize> = (0..groups.len()).filter(|&k| waiting[k]).collect();
        let mut problems: Vec<_> = groups.iter_mut().zip(waiting).filter(|(_, &w)| w).map(|(g, _)| g.contact.as_mut().expect("a waiting group has contact").problem(settings)).collect();
        let solved = world.solve_contact(&mut problems, c.interrupt, times);
        drop(problems);
        let mut results: Vec<Result<Outcome, StepFailure>> = groups.iter().map(|_| Ok(Outcome::default())).collect();
        match solved {
            Ok(Some(outcomes)) => {
                for (k, o) in owners.into_iter().zip(outcomes) {
                    results[k] = Ok(o);
                }
                return results;
            }
            Err(e) => {
                for k in owners {
                    let names: Vec<&str> = groups[k].bodies.iter().map(|b| b.name.as_str()).collect();
                    results[k] = Err(StepFailure::Device { body: names.join("`, `"), error: e.to_string() });
                }
                return results;
            }
            // Too large for the device's buffers: the CPU's sweeps.
            Ok(None) => {}
        }
    }
    groups
        .par_iter_mut()
        .zip(waiting)
        .map(|(g, &w)| match (&mut g.contact, w) {
            (Some(contact), true) => Ok(contact.solve_on_cpu(settings, c.interrupt, &mut g.newton.report.wall)),
            _ => Ok(Outcome::default()),
        })
        .collect()
}

/// A group's share of a device pass: its calls and contact when it iterates on the device, else
/// its evaluations.
type PassShare<'a> = (Vec<NewtonCall<'a>>, Option<(Problem<'a>, GroupContact<'a>)>, Vec<Evaluation<'a>>);

/// One device pass over the bodies of the `live` groups that `wanted` selects: the tangent and
/// stiffness values if `tangent`, else forces and residuals; and in the same submission the
/// Newton iterations of the `iterating` groups ([`GpuWorld::newton`]), which the device
/// evaluates first if they come `unevaluated`. Returns each group's result (a body's element
/// failure or a device error fails its group); no pass when nothing is wanted.
#[allow(clippy::too_many_arguments)]
fn device_pass(
    groups: &mut [Group],
    live: &[bool],
    (iterating, unevaluated): (&[bool], bool),
    world: &mut GpuWorld,
    c: &Context,
    tangent: bool,
    wanted: &(dyn Fn(&Body) -> bool + Sync),
    times: &mut PhaseTimes,
) -> Vec<Result<(), StepFailure>> {
    let p = c.p;
    let mut results: Vec<Result<(), StepFailure>> = groups.iter().map(|_| Ok(())).collect();
    // A body in contact without a factorisation for the step will most likely iterate, and
    // factorise at this iterate first: its tangent comes with its forces, not in a pass of its
    // own after the convergence test.
    let with_tangent = |body: &Body, in_contact: bool| tangent || (in_contact && body.lacks_factor(p));
    // A forces pass leaves out the bodies whose inputs are those of their last evaluation (a
    // grain at rest): their results are still there, as on the CPU; not a body that wants its
    // tangent too (a grain at rest just touched).
    let chosen: Vec<Vec<bool>> = groups
        .par_iter_mut()
        .zip(live)
        .map(|(g, &l)| {
            let in_contact = g.contact.is_some();
            g.bodies
                .iter_mut()
                .map(|b| {
                    let chosen = l && wanted(b);
                    let unchanged = chosen && !with_tangent(b, in_contact) && b.evaluation_holds(p);
                    if unchanged {
                        b.reuse_evaluation(p);
                    }
                    chosen && !unchanged
                })
                .collect()
        })
        .collect();
    if !chosen.iter().flatten().any(|&x| x) && !iterating.contains(&true) {
        return results;
    }
    // `K̄⁻¹` of each factorisation the device lacks (after a step that refactorised many
    // grains: all of them), in parallel.
    let shared: &GpuWorld = world;
    let mut inverses: Vec<Vec<Option<Vec<Real>>>> = groups
        .par_iter_mut()
        .zip(iterating)
        .map(|(g, &yes)| {
            if !yes {
                return Vec::new();
            }
            let wall = &mut g.newton.report.wall;
            g.bodies.iter_mut().zip(g.ids).map(|(b, &id)| (!shared.newton_inverse_current(id, b.factor_version())).then(|| b.effective_inverse(wall))).collect()
        })
        .collect();
    let motion_scale = c.velocity_scale * p.dt;
    let dim = groups.first().and_then(|g| g.bodies.first()).map_or(2, |b| b.dim);
    let group_count = groups.len();
    // Each group's share, made in parallel: its calls and contact (iterating on the device), or
    // its evaluations; then laid end to end.
    let shares: Vec<PassShare> = groups
        .par_iter_mut()
        .zip(&chosen)
        .zip(inverses.par_iter_mut())
        .zip(iterating)
        .map(|(((g, chosen), inverses), &on_device)| {
            if !on_device {
                let in_contact = g.contact.is_some();
                let evaluations = g.bodies.iter_mut().zip(g.ids).zip(chosen).filter(|(_, &yes)| yes).map(|((body, &id), _)| body.device_evaluation(id, with_tangent(body, in_contact), !tangent)).collect();
                return (Vec::new(), None, evaluations);
            }
            let budget = p.max_iterations - g.newton.report.iterations;
            let Group { ids, bodies, contact, newton, .. } = g;
            let u_base: Vec<Vec<Real>> = if contact.is_some() { bodies.iter().map(|b| b.trial_velocity_base(p)).collect() } else { Vec::new() };
            let calls: Vec<NewtonCall> = bodies.iter_mut().zip(ids.iter()).zip(std::mem::take(inverses)).map(|((body, &id), inverse)| body.newton_call(id, p, motion_scale, budget, inverse, !unevaluated)).collect();
            let contact = contact.as_mut().map(|contact| {
                let settings = c.settings.expect("contact points need contact settings");
                let obstacle = contact.obstacle_velocities();
                let (problem, slot_nodes) = contact.problem_and_slots(settings);
                let group = GroupContact {
                    calls: Vec::new(),
                    slot_nodes,
                    obstacle,
                    u_base,
                    iterations_before: newton.report.iterations as u32,
                    tolerance: settings.tolerance,
                    outcome: ContactState { stalls: newton.uzawa_stalls as u32, ..ContactState::default() },
                };
                (problem, group)
            });
            (calls, contact, Vec::new())
        })
        .collect();
    let mut list: Vec<Evaluation> = Vec::new();
    let mut calls: Vec<NewtonCall> = Vec::new();
    let mut problems: Vec<Problem> = Vec::new();
    let mut contacts: Vec<GroupContact> = Vec::new();
    // Per group iterating on the device: its calls, and its contact's index in `contacts`.
    let mut call_ranges: Vec<(std::ops::Range<usize>, Option<usize>)> = vec![(0..0, None); group_count];
    // Where each group's evaluations start in the list, so that the groups take their results
    // in parallel.
    let mut evaluations_start = Vec::with_capacity(group_count);
    for (k, (group_calls, contact, evaluations)) in shares.into_iter().enumerate() {
        evaluations_start.push(list.len());
        list.extend(evaluations);
        if !iterating[k] {
            continue;
        }
        let start = calls.len();
        calls.extend(group_calls);
        let index = contact.map(|(problem, mut group)| {
            group.calls = (start..calls.len()).collect();
            problems.push(problem);
            contacts.push(group);
            contacts.len() - 1
        });
        call_ranges[k] = (start..calls.len(), index);
    }
    let passed = if calls.is_empty() {
        world.evaluate(&mut list, coefficients(p), times)
    } else {
        world.newton(&mut calls, &mut problems, &mut contacts, &mut list, coefficients(p), (dim, p.theta * p.dt), c.interrupt, times)
    };
    let failures: Vec<Option<ElementFailure>> = list.iter().map(|e| e.failure).collect();
    let ends: Vec<_> = calls.iter_mut().map(|call| (call.outcome, call.strain_energy, call.failure, call.tangent.take())).collect();
    let contact_outcomes: Vec<ContactState<Real>> = contacts.iter().map(|g| g.outcome).collect();
    drop(list);
    drop(calls);
    drop(contacts);
    drop(problems);
    let passed = &passed;
    groups.par_iter_mut().zip(&chosen).zip(results.par_iter_mut()).enumerate().for_each(|(k, ((g, chosen), result))| {
        if iterating[k] {
            let (range, index) = call_ranges[k].clone();
            if let Err(e) = passed {
                *result = Err(g.bodies[0].device_failure(e));
                return;
            }
            // The members took their increments in lockstep. Each increment is followed by an
            // evaluation; the last one counts in the convergence test that follows, which takes
            // it again (the first evaluation, when the device made it, is the last one of a call
            // without increments).
            let iterations = ends[range.start].0.iterations as usize;
            let state = &mut g.newton;
            state.report.iterations += iterations;
            state.report.device_iterations += iterations;
            state.report.bodies_iterated += if unevaluated { iterations } else { iterations.saturating_sub(1) } * g.bodies.len();
            for (body, (end, strain, failure, tangent)) in g.bodies.iter_mut().zip(&ends[range]) {
                if let (Ok(()), Err(e)) = (&*result, body.finish_device_newton(p, end, *strain, *failure, tangent.as_deref())) {
                    *result = Err(e);
                }
            }
            if let (Some(j), true) = (index, iterations > 0) {
                let o = contact_outcomes[j];
                state.record_device_solve(&o);
                let contact = g.contact.as_mut().expect("a group with a contact outcome has contact");
                for _ in 0..o.tightened {
                    contact.tighten();
                }
            }
            return;
        }
        let mut failures = failures[evaluations_start[k]..].iter();
        let in_contact = g.contact.is_some();
        for (body, &yes) in g.bodies.iter_mut().zip(chosen) {
            if !yes {
                continue;
            }
            let failure = *failures.next().expect("one result per evaluation");
            let finished = match passed {
                Err(e) => Err(body.device_failure(e)),
                Ok(()) => body.finish_device_evaluation(p, failure, with_tangent(body, in_contact), !tangent),
            };
            if let (Ok(()), Err(e)) = (&*result, finished) {
                *result = Err(e);
            }
        }
    });
    results
}
