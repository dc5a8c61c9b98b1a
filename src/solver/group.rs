//! The bodies of a step in groups that Newton solves independently: the connected components of
//! the contact graph (two bodies are joined by a contact point between them; an obstacle joins
//! nothing). Each group iterates until its own bodies and contact points have converged and then
//! leaves the loop, so a grain in free flight or at rest costs one evaluation per step, not one
//! per Newton iteration of the busiest cluster. Groups run in parallel.

use super::body::{Body, StepFailure, StepParams};
use super::coupling::ContactStep;
use super::PhaseTimes;
use crate::contact::{ContactPoint, Master, Settings};
use crate::precision::Real;
use rayon::prelude::*;
use std::collections::HashMap;

/// What the Newton loop of one group did.
#[derive(Debug, Clone, Copy, Default)]
pub struct GroupReport {
    pub iterations: usize,
    pub uzawa_iterations: usize,
    /// Body evaluations: the group's size times its evaluations.
    pub bodies_iterated: usize,
    pub factorizations: usize,
    pub residual_norm: Real,
    pub wall: PhaseTimes,
}

/// Connected components of the bodies joined by contact points, each as its bodies (ascending)
/// and its points (in detection order).
fn components(body_count: usize, points: &[ContactPoint]) -> Vec<(Vec<usize>, Vec<usize>)> {
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
    let mut index = vec![usize::MAX; body_count];
    let mut groups: Vec<(Vec<usize>, Vec<usize>)> = Vec::new();
    for b in 0..body_count {
        let r = root(&mut parent, b);
        if index[r] == usize::MAX {
            index[r] = groups.len();
            groups.push((Vec::new(), Vec::new()));
        }
        groups[index[r]].0.push(b);
    }
    for (i, c) in points.iter().enumerate() {
        let r = root(&mut parent, c.terms()[0].body as usize);
        groups[index[r]].1.push(i);
    }
    groups
}

/// One group during a step: its bodies (moved out of the simulation), its contact points with
/// body indices local to the group.
struct Group {
    ids: Vec<usize>,
    bodies: Vec<Body>,
    point_ids: Vec<usize>,
    contact: ContactStep,
}

/// Solves a step's Newton problem group by group, in parallel. The bodies go back into
/// `bodies` and the points (global indices, with their solution) are returned in detection
/// order, whether the step converged or not. Forming the groups counts as `contact` time.
pub fn solve_groups(
    bodies: &mut Vec<Body>,
    points: Vec<ContactPoint>,
    p: &StepParams,
    settings: Option<&Settings>,
    warm: &HashMap<(u32, u32, Master), ([Real; 3], Real)>,
    velocity_scale: Real,
    times: &mut PhaseTimes,
) -> (Vec<ContactPoint>, Vec<Result<GroupReport, StepFailure>>) {
    let started = std::time::Instant::now();
    let plan = components(bodies.len(), &points);
    let mut local = vec![0u32; bodies.len()];
    for (ids, _) in &plan {
        for (k, &b) in ids.iter().enumerate() {
            local[b] = k as u32;
        }
    }
    let mut slots: Vec<Option<Body>> = std::mem::take(bodies).into_iter().map(Some).collect();
    let mut points: Vec<Option<ContactPoint>> = points.into_iter().map(Some).collect();
    let mut groups: Vec<Group> = plan
        .into_iter()
        .map(|(ids, point_ids)| {
            let group_bodies: Vec<Body> = ids.iter().map(|&b| slots[b].take().expect("a body is in one group")).collect();
            let group_points: Vec<ContactPoint> = point_ids
                .iter()
                .map(|&i| {
                    let mut c = points[i].take().expect("a point is in one group");
                    for t in &mut c.terms[..c.term_count] {
                        t.body = local[t.body as usize];
                    }
                    c
                })
                .collect();
            let contact = ContactStep::new(group_points, &group_bodies, p, warm, velocity_scale);
            Group { ids, bodies: group_bodies, point_ids, contact }
        })
        .collect();
    times.contact += started.elapsed().as_secs_f64();
    let reports: Vec<Result<GroupReport, StepFailure>> = groups.par_iter_mut().map(|g| newton(&mut g.bodies, &mut g.contact, p, settings, velocity_scale)).collect();
    for g in groups {
        for (c, i) in g.contact.points.into_iter().zip(g.point_ids) {
            let mut c = c;
            for t in &mut c.terms[..c.term_count] {
                t.body = g.ids[t.body as usize] as u32;
            }
            points[i] = Some(c);
        }
        for (b, body) in g.ids.into_iter().zip(g.bodies) {
            slots[b] = Some(body);
        }
    }
    *bodies = slots.into_iter().map(|b| b.expect("every body came back")).collect();
    (points.into_iter().map(|c| c.expect("every point came back")).collect(), reports)
}

/// The Newton loop of one group (paper eqs. 16-19, with contact as in `coupling.rs`), until its
/// bodies meet the solver tolerances and its contact points the contact criteria.
fn newton(bodies: &mut [Body], contact: &mut ContactStep, p: &StepParams, settings: Option<&Settings>, velocity_scale: Real) -> Result<GroupReport, StepFailure> {
    let mut report = GroupReport::default();
    let mut last_change: Option<Real> = None;
    let mut uzawa_converged = true;
    loop {
        for body in bodies.iter_mut() {
            body.evaluate(p, &mut report.wall)?;
        }
        report.bodies_iterated += bodies.len();
        contact.apply_forces(bodies);
        let mut converged = true;
        for body in bodies.iter_mut() {
            converged &= body.converged(p, velocity_scale * p.dt)?;
        }
        let mut contact_unmet = Vec::new();
        if !contact.is_empty() {
            let tolerance = settings.expect("contact points need contact settings").tolerance;
            // A step that starts from last step's solution may already satisfy everything.
            match last_change {
                Some(c) if c > tolerance => contact_unmet.push(format!("contact forces still changing by {c:.3e} > {tolerance:.3e}")),
                None if !contact.all_warm() => contact_unmet.push("contact forces not solved yet".to_string()),
                _ => {}
            }
            if !uzawa_converged {
                contact_unmet.push("Uzawa iterations not converged".to_string());
            }
            let complementarity = contact.complementarity(bodies, p);
            if complementarity > tolerance {
                contact_unmet.push(format!("complementarity {complementarity:.3e} > {tolerance:.3e}"));
            }
            converged &= contact_unmet.is_empty();
        }
        if converged {
            break;
        }
        if report.iterations == p.max_iterations {
            let names: Vec<String> = bodies.iter().map(|b| format!("`{}`", b.name)).collect();
            let bodies_named = if names.len() == 1 { format!("body {}", names[0]) } else { format!("bodies {} (coupled by contact)", names.join(", ")) };
            let unmet: Vec<String> = bodies.iter().flat_map(|b| b.unmet().iter().cloned()).chain(contact_unmet).collect();
            return Err(StepFailure::NotConverged { bodies: bodies_named, iterations: report.iterations, unmet: unmet.join("; ") });
        }
        let mut refactorized = false;
        for body in bodies.iter_mut() {
            let fresh = body.refresh_factor(p, &mut report.wall)?;
            refactorized |= fresh;
            report.factorizations += fresh as usize;
        }
        if contact.is_empty() {
            for body in bodies.iter_mut() {
                body.newton_step(&mut report.wall);
            }
        } else {
            let (outcome, change) = contact.newton_increment(bodies, p, settings.expect("contact settings"), refactorized, &mut report.wall);
            report.uzawa_iterations += outcome.iterations;
            uzawa_converged = outcome.converged;
            last_change = Some(change);
        }
        report.iterations += 1;
    }
    report.residual_norm = bodies.iter().map(Body::residual_norm).fold(0.0, Real::max);
    contact.finish(bodies, p);
    Ok(report)
}
