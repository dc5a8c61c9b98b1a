//! The contact network of a step (`/contacts`): each pair of bodies, or body and obstacle,
//! pressed together, its points summed; each body's centre and current volume; the plane
//! obstacles where they are.

use super::messages::ContactsMessage;
use crate::contact::detect::facet_normal;
use crate::contact::law::Status;
use crate::contact::obstacle::Shape;
use crate::contact::{ContactPoint, Master};
use crate::precision::Real;
use crate::solver::Simulation;
use rayon::prelude::*;
use std::collections::HashMap;

/// What a contact's points add up to.
#[derive(Default)]
struct Sum {
    force: [Real; 3],
    /// `Σ r_n x` and `Σ r_n`: the point.
    weighted_point: [Real; 3],
    weight: Real,
    /// `Σ r_n n`: the normal.
    normal: [Real; 3],
    sliding: bool,
    points: u32,
}

/// The key of a contact and the sign that turns its point's force and normal to its `body`:
/// a pair of bodies is keyed by its lower index (both passes of a pair are one contact).
fn key(c: &ContactPoint) -> ((u32, i64), Real) {
    match c.master {
        Master::Body(m) if m < c.slave_body => ((m, c.slave_body as i64), -1.0),
        Master::Body(m) => ((c.slave_body, m as i64), 1.0),
        Master::Obstacle { obstacle, .. } => ((c.slave_body, -1 - obstacle as i64), 1.0),
    }
}

/// The `/contacts` message of the simulation's last step.
pub fn network(sim: &Simulation) -> ContactsMessage {
    let dim = sim.dim();
    let mut sums: HashMap<(u32, i64), Sum> = HashMap::new();
    for c in sim.contact_points().iter().filter(|c| c.r[0] > 0.0) {
        let (key, sign) = key(c);
        let [n, t1, t2] = c.frame;
        let force: [Real; 3] = std::array::from_fn(|i| sign * (c.r[0] * n[i] + c.r[1] * t1[i] + c.r[2] * t2[i]));
        let x = sim.bodies()[c.slave_body as usize].position(c.slave_node as usize);
        let sum = sums.entry(key).or_insert_with(|| Sum { sliding: true, ..Sum::default() });
        for i in 0..3 {
            sum.force[i] += force[i];
            sum.weighted_point[i] += c.r[0] * x[i];
            sum.normal[i] += sign * c.r[0] * n[i];
        }
        sum.weight += c.r[0];
        sum.sliding &= c.status == Status::Sliding;
        sum.points += 1;
    }
    let mut contacts: Vec<((u32, i64), Sum)> = sums.into_iter().collect();
    contacts.sort_by_key(|(k, _)| *k);
    let mut m = ContactsMessage { t: sim.t(), ..Default::default() };
    for ((body, other), s) in contacts {
        let length = s.normal.iter().map(|x| x * x).sum::<Real>().sqrt();
        let normal = s.normal.map(|x| x / length);
        let normal_force: Real = (0..3).map(|i| s.force[i] * normal[i]).sum();
        let tangential = (0..3).map(|i| (s.force[i] - normal_force * normal[i]).powi(2)).sum::<Real>().sqrt();
        m.body.push(body);
        m.other.push(other);
        m.point.extend(s.weighted_point[..dim].iter().map(|x| x / s.weight));
        m.normal.extend_from_slice(&normal[..dim]);
        m.force.extend_from_slice(&s.force[..dim]);
        m.normal_force.push(normal_force);
        m.tangential_force.push(tangential);
        m.sliding.push(s.sliding);
        m.points.push(s.points);
    }
    let centers_volumes: Vec<([Real; 3], Real)> = sim.bodies().par_iter().enumerate().map(|(b, body)| (body.metrics().center_of_mass, volume(sim, b))).collect();
    for (c, v) in centers_volumes {
        m.body_center.extend_from_slice(&c[..dim]);
        m.body_volume.push(v);
    }
    if let Some(model) = &sim.contact() {
        for (k, o) in model.obstacles.iter().enumerate() {
            if let Shape::Plane { point, normal } = o.shape {
                let shift = o.motion.displacement(sim.t());
                m.wall.push(k as u32);
                m.wall_point.extend((0..dim).map(|i| point[i] + shift[i]));
                m.wall_normal.extend_from_slice(&normal[..dim]);
            }
        }
    }
    m
}

/// A body's current volume (area in 2D) from its deformed boundary: `(1/d) Σ x_f · N_f` over
/// its boundary facets, `N_f` a facet's outward area vector, `x_f` its centroid.
fn volume(sim: &Simulation, b: usize) -> Real {
    let Some(model) = &sim.contact() else { return 0.0 };
    let body = &sim.bodies()[b];
    let surface = &model.surfaces[b];
    let x: Vec<[Real; 3]> = (0..body.mesh().nodes.len()).map(|n| body.position(n)).collect();
    let sum: Real = (0..surface.facet_count())
        .map(|f| {
            let (p, count) = surface.facet_points(&x, f);
            let normal = facet_normal(&p[..count]);
            let centroid: [Real; 3] = std::array::from_fn(|i| p[..count].iter().map(|q| q[i]).sum::<Real>() / count as Real);
            (0..3).map(|i| centroid[i] * normal[i]).sum::<Real>()
        })
        .sum();
    sum / sim.dim() as Real
}
