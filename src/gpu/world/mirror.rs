//! The host's copies of a batch's per-dof device inputs ("mirrors"): what the device holds, so
//! that only what changed goes up, one write per run of consecutive members. Displacements, step
//! inputs, residuals, and a device Newton call's start displacements and contact forces (those
//! dof by dof: `scatter.rs`).

use super::{dof_span, runs, Batch, GpuWorld};
use crate::gpu::types::DofOut;
use crate::precision::{same_bits, Real};
use rayon::prelude::*;
use wgpu::Buffer;

/// The per-dof inputs a batch keeps a host copy of, uploaded by runs of members: its
/// displacements, step inputs and residuals, and its device Newton calls' start displacements
/// and contact forces (those dof by dof, [`GpuWorld::stage_mirror_by_dof`]).
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Mirror {
    Displacement,
    Step,
    Residual,
    NewtonStart,
    NewtonContact,
}

impl GpuWorld {
    /// Takes the listed members' values (`(member, values)`, in member order) into a mirror,
    /// member by member on every thread, and uploads those that changed since they last went
    /// up, one write per run of consecutive members. Returns the members that went up.
    pub(super) fn stage_mirror(&mut self, batch: usize, mirror: Mirror, mine: &[(usize, &[Real])]) -> Vec<usize> {
        let members = self.take_into_mirror(batch, mirror, mine);
        self.upload_mirror(batch, mirror, &members);
        members
    }

    /// Takes the listed members' values (`(member, values)`, in member order) into a mirror's
    /// host copy, member by member on every thread; returns those that changed.
    fn take_into_mirror(&mut self, batch: usize, mirror: Mirror, mine: &[(usize, &[Real])]) -> Vec<usize> {
        let b = &mut self.batches[batch];
        let starts: Vec<usize> = mine.iter().map(|&(m, _)| b.members[m].dof_start as usize).collect();
        let (host, _, per_dof) = b.mirror(mirror);
        let changed = update_mirrors(host, starts.iter().zip(mine).map(|(&start, &(_, values))| (per_dof * start, values)).collect());
        mine.iter().zip(changed).filter(|(_, c)| *c).map(|(&(m, _), _)| m).collect()
    }

    /// Uploads the listed members' values of a mirror as its host copy holds them, one write per
    /// run of consecutive members (after the step's start, if it waits for any of them).
    pub(super) fn upload_mirror(&mut self, batch: usize, mirror: Mirror, members: &[usize]) {
        if !matches!(mirror, Mirror::NewtonContact) {
            self.settle_prologue(batch, members);
        }
        let (host, buffer, per_dof) = self.batches[batch].mirror(mirror);
        let host = std::mem::take(host);
        for run in runs(members) {
            let dofs = dof_span(&self.batches[batch].members, &run);
            if !self.scattered.is_empty() {
                self.drop_scattered(batch, mirror, per_dof * dofs.start..per_dof * dofs.end);
            }
            self.upload_reals(&buffer, per_dof * dofs.start, &host[per_dof * dofs.start..per_dof * dofs.end]);
        }
        *self.batches[batch].mirror(mirror).0 = host;
    }

    /// Takes the listed members' step inputs (`(member, inputs)`, in member order) into the
    /// batch's mirror; those that changed go up with the member's next evaluation
    /// ([`GpuWorld::stage_displacements_but`]).
    pub(super) fn stage_step_inputs(&mut self, batch: usize, mine: &[(usize, &[Real])]) {
        for m in self.take_into_mirror(batch, Mirror::Step, mine) {
            self.batches[batch].step_pending[m] = true;
        }
    }

    /// Uploads the step inputs of the listed members that have not gone up yet, one write per
    /// run of consecutive members.
    fn flush_step_inputs(&mut self, batch: usize, members: &[usize]) {
        let b = &mut self.batches[batch];
        let pending: Vec<usize> = members.iter().copied().filter(|&m| std::mem::take(&mut b.step_pending[m])).collect();
        self.upload_mirror(batch, Mirror::Step, &pending);
    }

    /// Copies the displacements of the listed bodies (`(body, u)`) into their batches' mirrors
    /// and uploads them, with the step inputs still waiting to go up; returns, per batch with any
    /// of them, the list indices in member order.
    pub(super) fn stage_displacements(&mut self, list: &[(usize, &[Real])]) -> Vec<(usize, Vec<usize>)> {
        self.stage_displacements_but(list, &|_| false)
    }

    /// [`GpuWorld::stage_displacements`], but for the list indices `kept` names, whose device
    /// displacements stay as they are (a step's predictor, which the device computed).
    pub(super) fn stage_displacements_but(&mut self, list: &[(usize, &[Real])], kept: &dyn Fn(usize) -> bool) -> Vec<(usize, Vec<usize>)> {
        let mut order: Vec<usize> = (0..list.len()).collect();
        order.sort_by_key(|&i| self.place[list[i].0]);
        let mut by_batch: Vec<(usize, Vec<usize>)> = Vec::new();
        for i in order {
            let batch = self.place[list[i].0].0;
            match by_batch.last_mut() {
                Some((b, mine)) if *b == batch => mine.push(i),
                _ => by_batch.push((batch, vec![i])),
            }
        }
        for (batch, mine) in &by_batch {
            let all: Vec<usize> = mine.iter().map(|&i| self.place[list[i].0].1).collect();
            self.flush_step_inputs(*batch, &all);
            let members: Vec<(usize, &[Real])> = mine.iter().filter(|&&i| !kept(i)).map(|&i| (self.place[list[i].0].1, list[i].1)).collect();
            let sent = self.stage_mirror(*batch, Mirror::Displacement, &members);
            if let Some(n) = self.batches[*batch].newton.as_mut() {
                for m in sent {
                    n.resident.touched(m);
                }
            }
        }
        by_batch
    }

    /// Body `body`'s residuals as the device holds them: `out`, or unknown.
    pub(super) fn note_residuals(&mut self, body: usize, out: Option<&[DofOut<Real>]>) {
        let (b, m) = self.place[body];
        self.batches[b].note_residuals(m, out);
    }
}

impl Batch {
    /// Member `m`'s residuals as the device holds them (`dof_out_host`): `out`, or unknown.
    pub(super) fn note_residuals(&mut self, m: usize, out: Option<&[DofOut<Real>]>) {
        let dofs = dof_span(&self.members, &[m]);
        let host = &mut self.dof_out_host[2 * dofs.start..2 * dofs.end];
        match out {
            Some(out) => host.copy_from_slice(bytemuck::cast_slice(out)),
            None => host.fill(Real::NAN),
        }
    }

    /// A mirror's host copy, its device buffer, and its reals per dof.
    pub(super) fn mirror(&mut self, mirror: Mirror) -> (&mut Vec<Real>, Buffer, usize) {
        match mirror {
            Mirror::Displacement => (&mut self.u_host, self.u.clone(), 1),
            Mirror::Step => (&mut self.step_host, self.step.clone(), 4),
            Mirror::Residual => (&mut self.dof_out_host, self.dof_out.clone(), 2),
            Mirror::NewtonStart | Mirror::NewtonContact => {
                let n = self.newton.as_mut().expect("a batch whose Newton mirrors are staged has them");
                match mirror {
                    Mirror::NewtonStart => (&mut n.start_host, n.u_start.clone(), 1),
                    _ => (&mut n.contact_host, n.contact.clone(), 1),
                }
            }
        }
    }
}

/// [`update_mirror`] of the spans `(start, values)` of one mirror (sorted by start, disjoint), on
/// every thread: whether each changed.
pub(super) fn update_mirrors(mirror: &mut [Real], spans: Vec<(usize, &[Real])>) -> Vec<bool> {
    split_spans(mirror, &spans).into_par_iter().map(|(_, mine, values)| update_mirror(mine, values)).collect()
}

/// The spans `(start, values)` of one mirror (sorted by start, disjoint), each with its part of
/// the mirror: `(start, part, values)`, to be compared on every thread.
pub(super) fn split_spans<'m, 'v>(mirror: &'m mut [Real], spans: &[(usize, &'v [Real])]) -> Vec<(usize, &'m mut [Real], &'v [Real])> {
    let mut rest = mirror;
    let mut consumed = 0;
    let mut parts = Vec::with_capacity(spans.len());
    for &(start, values) in spans {
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(start - consumed);
        let (mine, after) = tail.split_at_mut(values.len());
        parts.push((start, mine, values));
        rest = after;
        consumed = start + values.len();
    }
    parts
}

/// Copies `values` into a host mirror if they differ from it, bit for bit; whether they did (and
/// must go up).
fn update_mirror(mirror: &mut [Real], values: &[Real]) -> bool {
    let changed = !same_bits(mirror, values);
    if changed {
        mirror.copy_from_slice(values);
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirrors_take_the_spans_that_changed_and_say_which() {
        let mut mirror = vec![0.0; 10];
        let (same, new) = ([0.0, 0.0], [1.0, 2.0, 3.0]);
        // A span unchanged, one changed after a gap, one changed at the end.
        let changed = update_mirrors(&mut mirror, vec![(0, &same[..]), (4, &new[..]), (8, &new[1..])]);
        assert_eq!(changed, [false, true, true]);
        assert_eq!(mirror, [0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.0, 2.0, 3.0]);
        // -0.0 is not the mirror's 0.0, bit for bit.
        assert_eq!(update_mirrors(&mut mirror, vec![(2, &[-0.0][..])]), [true]);
    }
}
