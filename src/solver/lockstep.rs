//! The Newton rounds of a step's groups with a GPU world, in lockstep: which groups' bodies the
//! device evaluates in a round and which iterate there ([`GpuWorld::newton`]), the device pass
//! that does both in one submission, and the contact solves of the groups left to the host.
//! The CPU's own loop is [`Group::newton_on_cpu`]; what the device does is `gpu::world`'s.

use super::body::{coefficients, Body, StepFailure};
use super::group::{Context, Group, GroupReport, Hold};
use crate::contact::uzawa::{Outcome, Problem, Sweep};
use crate::contact::Settings;
use crate::gpu::types::ContactState;
use crate::gpu::types::{Coefficients, NewtonState, StepSummary};
use crate::gpu::{ElementFailure, Evaluation, GpuError, GpuWorld, GroupContact, Inverse, NewtonCall};
use crate::mesh::ElementKind;
use crate::policy::PhaseTimes;
use crate::precision::{Precision, Real};
use rayon::prelude::*;

/// The Newton loops of all groups in lockstep with a GPU world. Each round: one device pass
/// evaluates the bodies of every group still iterating (forces and residuals); the groups test
/// convergence in parallel; one device pass computes the tangents of the bodies that
/// refactorise; the groups take their increments in parallel. The number of device passes per
/// Newton iteration does not depend on the number of bodies. A round whose element work is not
/// worth a device pass ([`crate::backend::round_on_device`]: after the first, mostly a few
/// grains in contact) evaluates on the CPU twins instead, so that the passes of a step do not
/// grow with its Newton iterations.
pub(super) fn newton_in_lockstep(groups: &mut [Group], world: &mut GpuWorld, c: &Context, times: &mut PhaseTimes) -> Vec<Result<GroupReport, StepFailure>> {
    let mut outcome: Vec<Option<Result<GroupReport, StepFailure>>> = (0..groups.len()).map(|_| None).collect();
    // In f32 the residual is computed in f64 on the CPU; the device gives the tangents.
    let device_residual = world.precision() == Precision::F64;
    let mut first = true;
    let none = vec![false; groups.len()];
    // The groups whose Newton iterations go to the device with this round's pass (in the first
    // round, unevaluated), and the batch of those in contact.
    let mut contact_batch = None;
    let mut iterating = if device_residual { evaluate_on_device_first(groups, world, c, &mut contact_batch) } else { none.clone() };
    loop {
        let live: Vec<bool> = outcome.iter().map(Option::is_none).collect();
        if !live.iter().any(|&l| l) {
            break;
        }
        let wanted = |_: &Body| true;
        let evaluating: Vec<bool> = live.iter().zip(&iterating).map(|(&l, &i)| l && !i).collect();
        // The step's first pass is every body's, in the large dispatches a GPU is for, unless
        // the bodies iterating on the device make it: then the others (mostly a few grains in
        // contact, which the host iterates) go by their work as in a later round, and need not
        // send their states across and their forces back.
        let others_on_device = device_residual && on_device(groups, &evaluating, &wanted, world, first && !iterating.contains(&true));
        let mut evaluated = if others_on_device || iterating.contains(&true) {
            device_pass(groups, if others_on_device { &evaluating } else { &none }, PassKind { tangent: false, iterating: &iterating, unevaluated: first }, world, c, &wanted, times)
        } else {
            groups.iter().map(|_| Ok(())).collect()
        };
        if !others_on_device {
            for (result, cpu) in evaluated.iter_mut().zip(evaluate_on_cpu(groups, &evaluating, c)) {
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
        let p = c.p;
        let needs_tangent = |b: &Body| b.needs_tangent(p);
        // Else each body's `refresh_factor` assembles its tangent on the CPU.
        let tangents = if on_device(groups, &continuing, &needs_tangent, world, first) {
            device_pass(groups, &continuing, PassKind { tangent: true, iterating: &none, unevaluated: false }, world, c, &needs_tangent, times)
        } else {
            groups.iter().map(|_| Ok(())).collect()
        };
        // A group without contact takes its increment in `refresh_for_increment`.
        let stepping: Vec<bool> = groups.iter().zip(&continuing).map(|(g, &go)| go && g.contact.is_none()).collect();
        fail_groups(factors_from_device(groups, &stepping, world, c, times), &mut continuing, &mut outcome);
        let begun: Vec<Option<Result<Option<Vec<bool>>, StepFailure>>> = groups.par_iter_mut().zip(tangents).zip(&continuing).map(|((g, tangents), &go)| go.then(|| tangents.and_then(|()| g.refresh_for_increment(c)))).collect();
        let mut waiting = vec![false; groups.len()];
        let mut refactorized = vec![Vec::new(); groups.len()];
        for (k, result) in begun.into_iter().enumerate() {
            match result {
                Some(Err(e)) => outcome[k] = Some(Err(e)),
                Some(Ok(Some(fresh))) => (waiting[k], refactorized[k]) = (true, fresh),
                _ => {}
            }
        }
        // A group whose bodies just refactorised takes this increment on the device with the
        // next round's pass rather than on the host, where it may: the device builds its W.
        if device_residual {
            let deferred = iterate_on_device(groups, &mut waiting, world, c, &mut contact_batch, true);
            for (i, d) in iterating.iter_mut().zip(deferred) {
                *i |= d;
            }
        }
        fail_groups(factors_from_device(groups, &waiting, world, c, times), &mut waiting, &mut outcome);
        groups.par_iter_mut().zip(&waiting).zip(&refactorized).filter(|((_, &wait), _)| wait).for_each(|((g, _), fresh)| g.prepare_contact(c, fresh));
        let solved = solve_contact(groups, &waiting, world, c, times);
        let ended: Vec<Option<Result<(), StepFailure>>> = groups.par_iter_mut().zip(solved).zip(&waiting).map(|((g, solved), &wait)| wait.then(|| solved.and_then(|o| g.end_increment(c, o)))).collect();
        for (k, result) in ended.into_iter().enumerate() {
            if let Some(Err(e)) = result {
                outcome[k] = Some(Err(e));
            }
        }
        first = false;
    }
    outcome.into_iter().map(|o| o.expect("every group has an outcome")).collect()
}

/// The host's own factorisations of the `chosen` groups' bodies whose last one the device made
/// within a Newton call ([`Body::factor_on_device`]) and that the host is about to solve with
/// (no refactorisation due), where the device made them ([`super::factorize_where_the_device_did`]).
/// A body whose call converged on the device needs none until then. Returns each group's result.
fn factors_from_device(groups: &mut [Group], chosen: &[bool], world: &mut GpuWorld, c: &Context, times: &mut PhaseTimes) -> Vec<Result<(), StepFailure>> {
    let mut results: Vec<Result<(), StepFailure>> = groups.iter().map(|_| Ok(())).collect();
    let (mut owners, mut wanted): (Vec<usize>, Vec<(usize, &mut Body)>) = (Vec::new(), Vec::new());
    for (k, g) in groups.iter_mut().enumerate().filter(|(k, _)| chosen[*k]) {
        for (&id, body) in g.ids.iter().zip(g.bodies.iter_mut()) {
            if body.factor_on_device() && !body.needs_factorization(c.p) {
                owners.push(k);
                wanted.push((id, &mut **body));
            }
        }
    }
    for (k, made) in owners.into_iter().zip(super::factorize_where_the_device_did(world, &mut wanted, times)) {
        if let (Ok(()), Err(e)) = (&results[k], made) {
            results[k] = Err(e);
        }
    }
    results
}

/// The groups whose `results` are errors end with them, and leave `live`.
fn fail_groups(results: Vec<Result<(), StepFailure>>, live: &mut [bool], outcome: &mut [Option<Result<GroupReport, StepFailure>>]) {
    for (k, result) in results.into_iter().enumerate() {
        if let Err(e) = result {
            (live[k], outcome[k]) = (false, Some(Err(e)));
        }
    }
}

/// The forces and residuals of the `evaluating` groups' bodies on the CPU twins, in parallel.
fn evaluate_on_cpu(groups: &mut [Group], evaluating: &[bool], c: &Context) -> Vec<Result<(), StepFailure>> {
    groups
        .par_iter_mut()
        .zip(evaluating)
        .map(|(g, &e)| {
            if !e {
                return Ok(());
            }
            for body in g.bodies.iter_mut() {
                body.evaluate_residual_on_cpu(c.p, &mut g.newton.report.wall)?;
            }
            Ok(())
        })
        .collect()
}

/// The groups whose first evaluation of a step goes to the device with their Newton iterations
/// ([`GpuWorld::newton`] evaluates and judges them before the first increment), with element
/// work worth device passes: bodies that keep their factorisation, whose `K̄⁻¹` the device
/// holds; either one body without contact points whose trial displacement is not that of its
/// last evaluation (a grain at rest takes that one again), or a group in contact as
/// [`iterate_on_device`] takes them (problems solved whole on the device, the step's
/// `contact_batch`), whose W the device builds. A falling grain then costs one
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
/// bodies in the step's `contact_batch` (that of the first such group); the device builds such
/// a group's W, the host none for it. `refreshed`: the
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

/// Whether the round's pass over the bodies of the `live` groups that `wanted` selects goes to
/// the device ([`crate::backend::round_on_device`]).
fn on_device(groups: &[Group], live: &[bool], wanted: &dyn Fn(&Body) -> bool, world: &GpuWorld, first: bool) -> bool {
    let work = if first { Vec::new() } else { element_work(groups, live, wanted) };
    crate::backend::round_on_device(world, first, &work)
}

/// The elements of each kind of the bodies of the `live` groups that `wanted` selects.
fn element_work(groups: &[Group], live: &[bool], wanted: &dyn Fn(&Body) -> bool) -> Vec<(ElementKind, usize)> {
    super::element_work(groups.iter().zip(live).filter(|(_, &l)| l).flat_map(|(g, _)| g.bodies.iter().map(|b| &**b)).filter(|b| wanted(b)))
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
                    let names: Vec<&str> = groups[k].bodies.iter().map(|b| b.def.name.as_str()).collect();
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

/// What a device pass does for its groups: the tangent too (`tangent`), and for the
/// `iterating` groups Newton iterations, which the device evaluates first if they come
/// `unevaluated`.
#[derive(Clone, Copy)]
struct PassKind<'a> {
    tangent: bool,
    iterating: &'a [bool],
    unevaluated: bool,
}

impl PassKind<'_> {
    /// Whether a body's evaluation computes its tangent: in a tangent pass, and for a body in
    /// contact without a factorisation for the step, which will most likely iterate and factorise
    /// at this iterate first (its tangent comes with its forces, not in a pass of its own after
    /// the convergence test).
    fn with_tangent(&self, body: &Body, in_contact: bool, c: &Context) -> bool {
        self.tangent || (in_contact && body.lacks_factor(c.p))
    }
}

/// The calls, problems, contacts and evaluations of a pass laid end to end, and where each
/// group's lie in them.
#[derive(Default)]
struct PassLayout<'a> {
    list: Vec<Evaluation<'a>>,
    calls: Vec<NewtonCall<'a>>,
    problems: Vec<Problem<'a>>,
    contacts: Vec<GroupContact<'a>>,
    /// Per group iterating on the device: its calls, and its contact's index in `contacts`.
    call_ranges: Vec<(std::ops::Range<usize>, Option<usize>)>,
    /// Where each group's evaluations start in the list, so that the groups take their results
    /// in parallel.
    evaluations_start: Vec<usize>,
}

/// A call's state, strain energy, element failure, whether the device holds the tangent where
/// it handed the body back, and its summary if the device kept its end (with whether its
/// displacements came back).
type CallEnd = (NewtonState<Real>, Option<Real>, Option<ElementFailure>, bool, Option<(StepSummary, bool)>);

/// What a pass leaves a group that iterated on the device: per call its state, strain energy,
/// element failure and whether the device holds its tangent; per contact its outcome and its
/// points' step lengths (from the W the device built).
struct IterationEnds {
    calls: Vec<CallEnd>,
    contacts: Vec<(ContactState<Real>, Vec<Real>)>,
}

/// One device pass over the bodies of the `live` groups that `wanted` selects: the tangent and
/// stiffness values if `kind.tangent`, else forces and residuals; and in the same submission the
/// Newton iterations of the `kind.iterating` groups ([`GpuWorld::newton`]). Returns each group's
/// result (a body's element failure or a device error fails its group); no pass when nothing is
/// wanted.
fn device_pass(groups: &mut [Group], live: &[bool], kind: PassKind, world: &mut GpuWorld, c: &Context, wanted: &(dyn Fn(&Body) -> bool + Sync), times: &mut PhaseTimes) -> Vec<Result<(), StepFailure>> {
    let p = c.p;
    let mut results: Vec<Result<(), StepFailure>> = groups.iter().map(|_| Ok(())).collect();
    let chosen = evaluations_of_pass(groups, live, kind, c, wanted);
    if !chosen.iter().flatten().any(|&x| x) && !kind.iterating.contains(&true) {
        return results;
    }
    let mut inverses = missing_inverses(groups, kind.iterating, world);
    let held: &GpuWorld = world;
    let dim = groups.first().and_then(|g| g.bodies.first()).map_or(2, |b| b.def.dim);
    // Each group's share, made in parallel, then laid end to end.
    let shares: Vec<PassShare> = groups
        .par_iter_mut()
        .zip(&chosen)
        .zip(inverses.par_iter_mut())
        .zip(kind.iterating)
        .map(|(((g, chosen), inverses), &on_device)| if on_device { iterations_share(g, std::mem::take(inverses), kind, c, held) } else { (Vec::new(), None, evaluations_share(g, chosen, kind, c)) })
        .collect();
    let mut layout = lay_out(shares, kind.iterating);
    let PassLayout { list, calls, problems, contacts, .. } = &mut layout;
    let asked: Vec<bool> = calls.iter().map(|call| call.keep).collect();
    // The factorisation each body held before the call, to number those the device made in it.
    let factors: Vec<(usize, u64)> = calls.iter().map(|call| (call.body, call.factor)).collect();
    let passed =
        if calls.is_empty() { world.evaluate(list, coefficients(p), times) } else { world.newton(calls, problems, contacts, list, Coefficients { motion: c.velocity_scale * p.dt, ..coefficients(p) }, (dim, p.theta * p.dt), c.interrupt, times) };
    let failures: Vec<Option<ElementFailure>> = list.iter().map(|e| e.failure).collect();
    let ends = IterationEnds {
        calls: calls.iter_mut().map(|call| (call.outcome, call.strain_energy, call.failure, call.tangent_held, call.summary.map(|s| (s, call.positions)))).collect(),
        contacts: contacts.iter_mut().map(|g| (g.outcome, std::mem::take(&mut g.step_lengths))).collect(),
    };
    // The calls that were to keep their step's end on the device and did not converge there.
    let unkept: Vec<usize> = calls.iter().zip(&asked).filter(|(call, &asked)| asked && call.summary.is_none()).map(|(call, _)| call.body).collect();
    let PassLayout { call_ranges, evaluations_start, .. } = layout;
    let passed = match passed {
        Ok(()) => take_back_unconverged(groups, &unkept, world, c, times),
        Err(e) => Err(e),
    };
    let passed = &passed;
    groups.par_iter_mut().zip(&chosen).zip(results.par_iter_mut()).enumerate().for_each(|(k, ((g, chosen), result))| {
        *result = match passed {
            Err(e) if kind.iterating[k] => Err(g.bodies[0].device_failure(e)),
            Ok(()) if kind.iterating[k] => finish_iterations(g, call_ranges[k].clone(), &ends, kind, c),
            _ => finish_evaluations(g, chosen, &failures[evaluations_start[k]..], passed, kind, c),
        };
    });
    for (k, g) in groups.iter().enumerate().filter(|&(k, _)| kind.iterating[k]) {
        for ((body, &id), &(_, before)) in g.bodies.iter().zip(g.ids).zip(&factors[call_ranges[k].0.clone()]) {
            if body.factor_version() != before {
                world.note_factorized(id, body.factor_version());
            }
        }
    }
    results
}

/// The bodies of `unkept` (calls that were to keep their step's end on the device and did not
/// converge there) whose committed state the device holds: their calls' iterates came back,
/// with residuals from stale step inputs; their committed states come back now and the
/// residuals follow from them ([`Body::take_committed_mid_step`]).
fn take_back_unconverged(groups: &mut [Group], unkept: &[usize], world: &mut GpuWorld, c: &Context, times: &mut PhaseTimes) -> Result<(), GpuError> {
    if unkept.is_empty() {
        return Ok(());
    }
    // Where each of them lies: (group, index in it). A kept call is a group of one body.
    let place: Vec<(usize, usize)> = groups.iter().enumerate().filter(|(_, g)| g.ids.len() == 1 && unkept.contains(&g.ids[0])).map(|(k, _)| (k, 0)).collect();
    let held: Vec<(usize, (usize, usize))> = place.into_iter().map(|(k, j)| (groups[k].ids[j], (k, j))).filter(|&(_, (k, j))| groups[k].bodies[j].held_state().is_some()).collect();
    if held.is_empty() {
        return Ok(());
    }
    let ids: Vec<usize> = held.iter().map(|&(id, _)| id).collect();
    let (states, _) = world.read_kept(&ids, &[], times)?;
    for ((_, (k, j)), kept) in held.iter().zip(states) {
        groups[*k].bodies[*j].take_committed_mid_step(c.p, &kept);
    }
    Ok(())
}

/// Per group, the bodies of a pass's evaluations: those of the `live` groups that `wanted`
/// selects, less those whose inputs are those of their last evaluation (a grain at rest), whose
/// results are still there, as on the CPU; not a body that wants its tangent too (a grain at
/// rest just touched).
fn evaluations_of_pass(groups: &mut [Group], live: &[bool], kind: PassKind, c: &Context, wanted: &(dyn Fn(&Body) -> bool + Sync)) -> Vec<Vec<bool>> {
    let p = c.p;
    groups
        .par_iter_mut()
        .zip(live)
        .map(|(g, &l)| {
            let in_contact = g.contact.is_some();
            g.bodies
                .iter_mut()
                .map(|b| {
                    let chosen = l && wanted(b);
                    let unchanged = chosen && !kind.with_tangent(b, in_contact, c) && b.evaluation_holds(p);
                    if unchanged {
                        b.reuse_evaluation(p);
                    }
                    chosen && !unchanged
                })
                .collect()
        })
        .collect()
}

/// `K̄⁻¹` of each factorisation of the `iterating` groups' bodies that the device lacks (after a
/// step that refactorised many grains: all of them), in parallel: `K̄` for the device to invert
/// where the body holds the values it factorised ([`Body::device_inverse`]).
fn missing_inverses(groups: &mut [Group], iterating: &[bool], world: &GpuWorld) -> Vec<Vec<Option<Inverse>>> {
    groups
        .par_iter_mut()
        .zip(iterating)
        .map(|(g, &yes)| {
            if !yes {
                return Vec::new();
            }
            let wall = &mut g.newton.report.wall;
            g.bodies.iter_mut().zip(g.ids).map(|(b, &id)| (!world.newton_inverse_current(id, b.factor_version())).then(|| b.device_inverse(world.inverts(b.dofs().free_count), wall))).collect()
        })
        .collect()
}

/// The evaluations of a group that does not iterate on the device, for its `chosen` bodies.
fn evaluations_share<'a>(g: &'a mut Group, chosen: &[bool], kind: PassKind, c: &Context) -> Vec<Evaluation<'a>> {
    let in_contact = g.contact.is_some();
    g.bodies.iter_mut().zip(g.ids).zip(chosen).filter(|(_, &yes)| yes).map(|((body, &id), _)| body.device_evaluation(id, kind.with_tangent(body, in_contact, c), !kind.tangent)).collect()
}

/// The calls of a group that iterates on the device, with its contact problem if it has one;
/// a member of such a group refactorises within the call where the device can invert `K̄` of
/// every member (`world`).
fn iterations_share<'a>(g: &'a mut Group, inverses: Vec<Option<Inverse>>, kind: PassKind, c: &Context, world: &GpuWorld) -> PassShare<'a> {
    let p = c.p;
    let taken = g.newton.report.iterations;
    let Group { ids, bodies, contact, newton, .. } = g;
    let u_base: Vec<Vec<Real>> = if contact.is_some() { bodies.iter().map(|b| b.trial_velocity_base(p)).collect() } else { Vec::new() };
    // A free body that nothing is near may leave its step's end on the device.
    let alone = contact.is_none() && bodies.len() == 1;
    let hold = |id: usize| if alone { c.hold.map_or(Hold::No, |hold| hold[id]) } else { Hold::No };
    let refactor = bodies.iter().all(|b| world.inverts(b.dofs().free_count));
    let calls: Vec<NewtonCall> = bodies
        .iter_mut()
        .zip(ids.iter())
        .zip(inverses)
        .map(|((body, &id), inverse)| {
            let hold = if body.may_step_on_device() { hold(id) } else { Hold::No };
            let mut call = body.newton_call(id, p, taken, inverse, !kind.unevaluated);
            (call.keep, call.positions) = (hold != Hold::No, hold == Hold::AllButPositions);
            call
        })
        .collect();
    let contact = contact.as_mut().map(|contact| {
        let settings = c.settings.expect("contact points need contact settings");
        let (obstacle, velocity_scale) = (contact.obstacle_velocities(), contact.velocity_scale());
        let (problem, slot_nodes) = contact.problem_and_slots(settings);
        let group = GroupContact {
            calls: Vec::new(),
            slot_nodes,
            obstacle,
            u_base,
            tolerance: settings.tolerance,
            velocity_scale,
            jacobi: settings.sweep == Sweep::Jacobi,
            refactor,
            outcome: ContactState { stalls: newton.uzawa_stalls as u32, ..ContactState::default() },
            step_lengths: Vec::new(),
        };
        (problem, group)
    });
    (calls, contact, Vec::new())
}

/// The groups' shares laid end to end.
fn lay_out<'a>(shares: Vec<PassShare<'a>>, iterating: &[bool]) -> PassLayout<'a> {
    let mut layout = PassLayout { call_ranges: vec![(0..0, None); shares.len()], evaluations_start: Vec::with_capacity(shares.len()), ..PassLayout::default() };
    for (k, (group_calls, contact, evaluations)) in shares.into_iter().enumerate() {
        layout.evaluations_start.push(layout.list.len());
        layout.list.extend(evaluations);
        if !iterating[k] {
            continue;
        }
        let start = layout.calls.len();
        layout.calls.extend(group_calls);
        let index = contact.map(|(problem, mut group)| {
            group.calls = (start..layout.calls.len()).collect();
            layout.problems.push(problem);
            layout.contacts.push(group);
            layout.contacts.len() - 1
        });
        layout.call_ranges[k] = (start..layout.calls.len(), index);
    }
    layout
}

/// A group that iterated on the device takes its calls' ends (`range` of them, and its
/// contact's outcome). The members took their increments in lockstep. Each increment is
/// followed by an evaluation; the last one counts in the convergence test that follows, which
/// takes it again (the first evaluation, when the device made it, is the last one of a call
/// without increments).
fn finish_iterations(g: &mut Group, (range, index): (std::ops::Range<usize>, Option<usize>), ends: &IterationEnds, kind: PassKind, c: &Context) -> Result<(), StepFailure> {
    let iterations = ends.calls[range.start].0.iterations as usize;
    let state = &mut g.newton;
    state.report.iterations += iterations;
    state.report.device_iterations += iterations;
    state.report.bodies_iterated += if kind.unevaluated { iterations } else { iterations.saturating_sub(1) } * g.bodies.len();
    let mut result = Ok(());
    for (body, (end, strain, failure, tangent_held, summary)) in g.bodies.iter_mut().zip(&ends.calls[range]) {
        if end.refactors > 0 {
            body.note_device_factorization(coefficients(c.p));
            state.report.factorizations += end.refactors as usize;
        }
        if let (Ok(()), Err(e)) = (&result, body.finish_device_newton(c.p, end, *strain, *failure, *tangent_held, *summary)) {
            result = Err(e);
        }
    }
    if let Some(j) = index {
        let (o, step_lengths) = &ends.contacts[j];
        let contact = g.contact.as_mut().expect("a group with a contact outcome has contact");
        contact.take_device_delassus(step_lengths);
        if iterations > 0 {
            g.newton.record_device_solve(o);
            for _ in 0..o.tightened {
                contact.tighten();
            }
        }
    }
    result
}

/// A group whose `chosen` bodies the pass evaluated takes their results (`failures`, from its
/// first evaluation on), or the pass's error.
fn finish_evaluations(g: &mut Group, chosen: &[bool], failures: &[Option<ElementFailure>], passed: &Result<(), GpuError>, kind: PassKind, c: &Context) -> Result<(), StepFailure> {
    let mut failures = failures.iter();
    let in_contact = g.contact.is_some();
    let mut result = Ok(());
    for (body, &yes) in g.bodies.iter_mut().zip(chosen) {
        if !yes {
            continue;
        }
        let failure = *failures.next().expect("one result per evaluation");
        let finished = match passed {
            Err(e) => Err(body.device_failure(e)),
            Ok(()) => body.finish_device_evaluation(c.p, failure, kind.with_tangent(body, in_contact, c), !kind.tangent),
        };
        if let (Ok(()), Err(e)) = (&result, finished) {
            result = Err(e);
        }
    }
    result
}
