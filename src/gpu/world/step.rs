//! Steps begun and committed on the device. A body that takes its steps there (device Newton
//! iterations, neither surface loads nor prescribed dofs nor Prony series) keeps its committed
//! state `(u, v, f_int)` in a device buffer: `step_commit` derives it from the step's last iterate
//! when the host keeps the step, and `step_begin` computes the next step's inputs from it, so that
//! its steps send nothing per dof up. The host's copy of the state is its own (it takes the
//! displacements and forces that come back); the device's is the one its steps start from.
//!
//! A member's device state is used only while the host knows it is the committed one: it is set
//! up from the host's state after a step that ended with a device Newton call, and from then on
//! derived by `step_commit` while each kept step ends so. A step that ends otherwise (on the host,
//! or a body the host moved since) drops it, and the next step's inputs go up from the host
//! again.

use super::{buffer, Batch, GpuWorld, Pass, WORKGROUP};
use crate::gpu::types::{summary_len, Active, Coefficients, DofOut, DofState, DofStep, MemberRange, NewtonState, StepMotion, StepTally, MODE_FORCES, NO_MEMBER, TALLY_LEN, TALLY_ROW};
use crate::gpu::{Gpu, GpuError};
use crate::policy::PhaseTimes;
use crate::precision::{same_bits, Precision, Real};
use wgpu::{Buffer, BufferUsages, ComputePipeline};

/// A committed state the device kept, handed back ([`GpuWorld::read_kept`]): one `DofState`
/// per dof, and its strain energy.
pub struct KeptState {
    pub states: Vec<DofState<Real>>,
    pub strain: Real,
}

/// A step's end the device kept, handed back ([`GpuWorld::read_kept`]): the iterate, its
/// internal forces and strain energy.
pub struct KeptIterate {
    pub u: Vec<Real>,
    pub f_int: Vec<Real>,
    pub strain: Real,
}

/// A read-back of the same span of each listed body: the bodies, the batch buffer, and the
/// span of a member (its batch and index).
type SpanRequest<'a> = (&'a [usize], super::Source, &'a dyn Fn(&Batch, usize) -> std::ops::Range<u64>);

/// What the host hands the world at the start of one body's step.
pub struct StepStart<'a> {
    pub body: usize,
    /// The step's inputs as the host computed them (they go up unless the device computes its own).
    pub inputs: &'a [DofStep<Real>],
    /// The committed displacements: the start displacements of the step's Newton calls.
    pub u: &'a [Real],
    /// Whether the device may begin the body's steps: no surface loads, no prescribed dofs, no
    /// Prony series ([`crate::solver::Body`] decides).
    pub on_device: bool,
}

/// The committed state of one body after the host kept a step.
pub struct StepEnd<'a> {
    pub body: usize,
    pub u: &'a [Real],
    pub v: &'a [Real],
    pub f_int: &'a [Real],
    /// The committed strain energy (the host's, unless `held`).
    pub strain: Real,
    pub on_device: bool,
    /// The step ended with a kept device Newton call ([`crate::gpu::NewtonCall::keep`]): the
    /// host's `u`, `v` and `f_int` are not the step's, the device's iterate is.
    pub held: bool,
}

/// The pipelines of `step_begin` and `step_commit`.
pub(super) struct StepPipelines {
    begin: ComputePipeline,
    commit: ComputePipeline,
}

impl StepPipelines {
    pub(super) fn new(gpu: &Gpu) -> Result<Self, GpuError> {
        Ok(Self { begin: gpu.pipeline_at("step_begin", "main", None)?, commit: gpu.pipeline_at("step_commit", "main", None)? })
    }

    /// `step_begin` and `step_commit` bound to `b`, by the names the kernels give their
    /// resources.
    fn passes(&self, gpu: &Gpu, b: &StepBindings) -> [Pass; 2] {
        let common = [("committed", b.committed), ("u", b.u), ("members", b.members)];
        let common = [&common[..], &[("dof_out", b.dof_out)]].concat();
        let adoption = [("adopted", b.adoption.velocities), ("adopt_at", b.adoption.at), ("epoch", b.adoption.epoch)];
        let begin = [&common[..], &adoption, &[("motion", b.motions[0]), ("jobs", b.jobs[0]), ("step", b.step), ("u_start", b.u_start), ("u_base", b.u_base)]].concat();
        let commit = [&common[..], &[("motion", b.motions[1]), ("jobs", b.jobs[1]), ("member_energy", b.member_energy), ("committed_energy", b.committed_energy)]].concat();
        [Pass::bound(gpu, self.begin.clone(), ("step_begin", "main"), None, &begin), Pass::bound(gpu, self.commit.clone(), ("step_commit", "main"), None, &commit)]
    }
}

/// The buffers the step kernels bind: the motions and job lists of the begin (`[0]`) and of the
/// commit (`[1]`), the per-dof and per-member buffers they share, the strain energies the
/// commit takes, and what the begin's adopting members take.
struct StepBindings<'a> {
    motions: [&'a Buffer; 2],
    jobs: [&'a Buffer; 2],
    committed: &'a Buffer,
    member_energy: &'a Buffer,
    committed_energy: &'a Buffer,
    step: &'a Buffer,
    u: &'a Buffer,
    u_start: &'a Buffer,
    u_base: &'a Buffer,
    dof_out: &'a Buffer,
    members: &'a Buffer,
    adoption: AdoptionBuffers<'a>,
}

/// `step_begin`'s `adopted` (a velocity per dof), `adopt_at` (a pass number per member) and
/// `epoch` (its own number).
struct AdoptionBuffers<'a> {
    velocities: &'a Buffer,
    at: &'a Buffer,
    epoch: &'a Buffer,
}

/// A batch's committed states on the device and what the host knows of them, per member.
pub(super) struct Resident {
    committed: Buffer,
    /// The committed states' strain energies, one per member.
    committed_energy: Buffer,
    /// `step_begin`'s `adopted`, `adopt_at` and `epoch`.
    adoption: [Buffer; 3],
    /// The number of the last `step_begin` pass queued, and the members (in order) whose
    /// `adopt_at` on the device is the next one's (older marks name passes that ran).
    epoch: u32,
    marked: Vec<usize>,
    motions: [Buffer; 2],
    jobs: [Buffer; 2],
    /// `step_begin` (`[0]`) and `step_commit` (`[1]`), as `motions` and `jobs`.
    passes: [Pass; 2],
    /// The device's committed state is the host's committed state (bit for bit, but for the
    /// velocity, which `step_commit` computes as the host does).
    valid: Vec<bool>,
    /// The device's `u` and `dof_out` are those a device Newton call left and the host took.
    current: Vec<bool>,
    /// The device's `u` is its own predictor (`step_begin`), which the host's mirror does not
    /// hold: the step's first Newton call starts from it instead of uploading the host's.
    pub(super) predicted: Vec<bool>,
    /// The members whose kept step `step_commit` commits before the next `step_begin`, and
    /// that step's motion.
    pending: Option<(Vec<usize>, StepMotion<Real>)>,
    /// The members the next submission's head begins (`[0]`) and commits (`[1]`), and whether
    /// each member is in either.
    lists: [Vec<usize>; 2],
    involved: Vec<bool>,
    /// The motions as last uploaded, and the lists as the device holds them, per pass.
    uploaded_motions: [Option<StepMotion<Real>>; 2],
    slots: [Slots; 2],
}

/// A pass's list as the device holds it: a member per slot, [`NO_MEMBER`] in the slots of the
/// members that left it. A list that changes by a few members sends those slots only: when the
/// lowest grains of a falling packing land, they leave the steps' passes, and the whole list
/// went up again (8 bytes a grain of 20 000, two or three times a step).
#[derive(Debug, Default)]
struct Slots {
    members: Vec<u32>,
}

impl Slots {
    /// Takes the members of `list` (distinct, below `count`), keeping those still listed in
    /// their slots and the others in the empty slots, or after the last; starts afresh when
    /// most slots would be empty. Returns the runs of slots that changed, `(first, entries)`.
    fn take(&mut self, list: &[usize], count: usize) -> Vec<(usize, Vec<Active>)> {
        let mut wanted = vec![false; count];
        for &m in list {
            wanted[m] = true;
        }
        let mut changed = vec![false; self.members.len()];
        for (slot, member) in self.members.iter_mut().enumerate() {
            if *member != NO_MEMBER && !std::mem::replace(&mut wanted[*member as usize], false) {
                (*member, changed[slot]) = (NO_MEMBER, true);
            }
        }
        // `wanted` now holds the members that have no slot yet.
        let mut empty = (0..self.members.len()).filter(|&s| self.members[s] == NO_MEMBER).collect::<Vec<_>>().into_iter();
        for &m in list.iter().filter(|&&m| wanted[m]) {
            let slot = empty.next().unwrap_or_else(|| {
                self.members.push(NO_MEMBER);
                changed.push(false);
                self.members.len() - 1
            });
            (self.members[slot], changed[slot]) = (m as u32, true);
        }
        while self.members.last() == Some(&NO_MEMBER) {
            self.members.pop();
        }
        changed.truncate(self.members.len());
        if self.members.len() > 2 * list.len() + 64 {
            self.members = list.iter().map(|&m| m as u32).collect();
            changed = vec![true; self.members.len()];
        }
        let slots: Vec<usize> = (0..changed.len()).filter(|&s| changed[s]).collect();
        super::runs(&slots).into_iter().map(|run| (run[0], run.iter().map(|&s| Active { member: self.members[s], mode: MODE_FORCES }).collect())).collect()
    }
}

impl Resident {
    /// `member_energy`: the strain energies where device Newton calls ended (`newton_finish`).
    pub(super) fn new(gpu: &Gpu, pipelines: &StepPipelines, b: &Batch, (u_start, u_base): (&Buffer, &Buffer), member_energy: &Buffer) -> Self {
        let real = gpu.precision.size();
        let (dofs, members) = (b.u_host.len(), b.members.len());
        let committed = buffer(gpu, "committed state", dofs * 3 * real, BufferUsages::STORAGE | BufferUsages::COPY_DST | BufferUsages::COPY_SRC);
        let committed_energy = buffer(gpu, "committed energy", members * real, BufferUsages::STORAGE | BufferUsages::COPY_DST | BufferUsages::COPY_SRC);
        let at = |label: &str, bytes: usize, usage: BufferUsages| buffer(gpu, label, bytes, usage | BufferUsages::COPY_DST);
        let adoption = [at("adopted velocities", dofs * real, BufferUsages::STORAGE), at("adopt at", members * 4, BufferUsages::STORAGE), at("adoption epoch", 16, BufferUsages::UNIFORM)];
        let motion = || buffer(gpu, "step motion", 4 * real, BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let jobs = || buffer(gpu, "step jobs", members * 8, BufferUsages::STORAGE | BufferUsages::COPY_DST);
        let (motions, jobs) = ([motion(), motion()], [jobs(), jobs()]);
        let bindings = StepBindings {
            motions: [&motions[0], &motions[1]],
            jobs: [&jobs[0], &jobs[1]],
            committed: &committed,
            member_energy,
            committed_energy: &committed_energy,
            step: &b.step,
            u: &b.u,
            u_start,
            u_base,
            dof_out: &b.dof_out,
            members: &b.member_buffer,
            adoption: AdoptionBuffers { velocities: &adoption[0], at: &adoption[1], epoch: &adoption[2] },
        };
        let passes = pipelines.passes(gpu, &bindings);
        Self {
            committed,
            committed_energy,
            adoption,
            epoch: 0,
            marked: Vec::new(),
            motions,
            jobs,
            passes,
            valid: vec![false; members],
            current: vec![false; members],
            predicted: vec![false; members],
            pending: None,
            lists: [Vec::new(), Vec::new()],
            involved: vec![false; members],
            uploaded_motions: [None, None],
            slots: [Slots::default(), Slots::default()],
        }
    }

    /// The committed states (one `DofState` per dof).
    pub(super) fn committed(&self) -> &Buffer {
        &self.committed
    }

    /// The committed states' strain energies (one per member).
    pub(super) fn committed_energy(&self) -> &Buffer {
        &self.committed_energy
    }

    /// The motion of the step `step_begin` begins (the step the Newton calls solve).
    pub(super) fn begin_motion(&self) -> &Buffer {
        &self.motions[0]
    }

    /// Whether the member's step began on the device (`step_begin`, which also computed its
    /// trial velocity's base there): from a step's start to its commit, the device's committed
    /// state is the host's for those members only.
    pub(super) fn began_on_device(&self, m: usize) -> bool {
        self.valid[m]
    }

    /// A member's `u` or `dof_out` changed on the device by other means than a Newton call the
    /// host took (an upload, an evaluation).
    pub(super) fn touched(&mut self, m: usize) {
        self.current[m] = false;
        self.predicted[m] = false;
    }

    /// A device Newton call left the member's iterate and forces, and the host took them.
    pub(super) fn took(&mut self, m: usize) {
        self.current[m] = true;
        self.predicted[m] = false;
    }

    /// Sets the members of `adopting` (in order) to adopt in the next `step_begin`, and sets
    /// back any other set to adopt there by an earlier call; returns the `adopt_at` entries that
    /// changed, `(member, pass)`.
    fn mark_adoptions(&mut self, adopting: &[usize]) -> Vec<(usize, u32)> {
        let next = self.epoch + 1;
        let set = adopting.iter().filter(|m| self.marked.binary_search(m).is_err()).map(|&m| (m, next));
        let unset = self.marked.iter().filter(|m| adopting.binary_search(m).is_err()).map(|&m| (m, 0));
        let mut marks: Vec<(usize, u32)> = set.chain(unset).collect();
        marks.sort_unstable();
        self.marked = adopting.to_vec();
        marks
    }
}

impl GpuWorld {
    /// The step inputs of the listed bodies as the host computed them, up with their next
    /// evaluation (where they changed): a step whose inputs the device does not compute.
    pub fn set_step_inputs(&mut self, steps: &[(usize, &[DofStep<Real>])]) {
        for batch in 0..self.batches.len() {
            let mut mine: Vec<(usize, &[Real])> = steps.iter().filter(|(body, _)| self.place[*body].0 == batch).map(|&(body, step)| (self.place[body].1, bytemuck::cast_slice(step))).collect();
            mine.sort_unstable_by_key(|&(m, _)| m);
            self.stage_step_inputs(batch, &mine);
        }
    }

    /// Starts a step. The bodies whose committed state the device holds take their inputs from
    /// it: `step_commit` of the step kept before and `step_begin` are recorded first in the
    /// step's first submission (or alone, before an upload that would overwrite what they read or
    /// write). The others' inputs go up (one write per run of consecutive members whose values
    /// changed: a grain at rest starts every step from the same ones).
    pub fn begin_step(&mut self, starts: &[StepStart], motion: StepMotion<Real>) -> Result<(), GpuError> {
        self.flush_prologue()?;
        self.step_tally = StepTally::default();
        for batch in 0..self.batches.len() {
            let mut mine: Vec<&StepStart> = starts.iter().filter(|s| self.place[s.body].0 == batch).collect();
            mine.sort_unstable_by_key(|s| self.place[s.body].1);
            let on_device = |s: &StepStart| s.on_device && self.batches[batch].newton.as_ref().is_some_and(|n| n.resident.valid[self.place[s.body].1]);
            let (device, host): (Vec<&StepStart>, Vec<&StepStart>) = mine.into_iter().partition(|s| on_device(s));
            let host: Vec<(usize, &[Real])> = host.iter().map(|s| (self.place[s.body].1, bytemuck::cast_slice(s.inputs))).collect();
            self.stage_step_inputs(batch, &host);
            let members: Vec<usize> = device.iter().map(|s| self.place[s.body].1).collect();
            let b = &mut self.batches[batch];
            let Some(n) = b.newton.as_mut() else { continue };
            let r = &mut n.resident;
            r.current.fill(false);
            r.predicted.fill(false);
            for (s, &m) in device.iter().zip(&members) {
                let dofs = super::dof_span(&b.members, &[m]);
                b.step_host[4 * dofs.start..4 * dofs.end].fill(Real::NAN);
                b.step_pending[m] = false;
                b.u_host[dofs.clone()].fill(Real::NAN);
                n.start_host[dofs].copy_from_slice(s.u);
                r.predicted[m] = true;
            }
            // A member that steps with the host's inputs drops its device state (its step's
            // uploads would come before a commit waiting for it): it is set up again from the
            // host's when a step of its ends on the device.
            let commit = r.pending.take().map(|(list, motion)| (list.into_iter().filter(|m| r.predicted[*m]).collect::<Vec<_>>(), motion)).filter(|(list, _)| !list.is_empty());
            for (valid, predicted) in r.valid.iter_mut().zip(&r.predicted) {
                *valid &= *predicted;
            }
            if members.is_empty() && commit.is_none() {
                continue;
            }
            for (k, (list, motion)) in [(1, commit), (0, (!members.is_empty()).then_some((members, motion)))].into_iter().filter_map(|(k, w)| Some((k, w?))) {
                self.queue_step_pass(batch, k, list, motion);
            }
        }
        Ok(())
    }

    /// Queues `step_begin` (`k` = 0) or `step_commit` (1) over the listed members of a batch for
    /// the head of the next submission: its motion and list go up.
    fn queue_step_pass(&mut self, batch: usize, k: usize, list: Vec<usize>, motion: StepMotion<Real>) {
        let r = &mut self.batches[batch].newton.as_mut().expect("a batch with committed states").resident;
        let (motion_buffer, jobs) = (r.motions[k].clone(), r.jobs[k].clone());
        // What changed goes up: a packing in flight begins the same grains with the same motion
        // step after step.
        let motion_changed = r.uploaded_motions[k].is_none_or(|m| !same_bits(&[m], &[motion]));
        r.uploaded_motions[k] = Some(motion);
        let changed = r.slots[k].take(&list, r.valid.len());
        // Committed states are kept in f64 only (device Newton iterations are).
        if motion_changed {
            self.upload(&motion_buffer, 0, bytemuck::bytes_of(&motion));
        }
        for (first, entries) in changed {
            self.upload(&jobs, (first * std::mem::size_of::<Active>()) as u64, bytemuck::cast_slice(&entries));
        }
        if k == 0 {
            // A new number for each begin, so that a member adopts in the one it was meant for
            // (a retried step begins again from the state it adopted).
            let r = &mut self.batches[batch].newton.as_mut().expect("a batch with committed states").resident;
            r.epoch += 1;
            r.marked.clear();
            let (epoch, buffer) = (r.epoch, r.adoption[2].clone());
            self.upload(&buffer, 0, bytemuck::cast_slice(&[epoch, 0, 0, 0]));
        }
        let r = &mut self.batches[batch].newton.as_mut().expect("a batch with committed states").resident;
        for &m in &list {
            r.involved[m] = true;
        }
        r.lists[k] = list;
    }

    /// The committed states of the listed bodies `committed` (each kept on the device: a step of
    /// its ended there, [`StepEnd::held`]), one `DofState` per dof, with their strain energies,
    /// after the commit that is waiting (recorded at the head of the same submission); and the
    /// last device Newton iterates, internal forces and strain energies of the bodies `iterates`
    /// (kept calls that converged: [`crate::gpu::NewtonCall::keep`]), as their calls left them.
    /// One submission. Both are the host's from here on: the device's sums
    /// ([`GpuWorld::step_tally`], [`GpuWorld::held_strain`]) no longer count them.
    pub fn read_kept(&mut self, committed: &[usize], iterates: &[usize], times: &mut PhaseTimes) -> Result<(Vec<KeptState>, Vec<KeptIterate>), GpuError> {
        if !committed.is_empty() {
            for batch in 0..self.batches.len() {
                if let Some((list, motion)) = self.batches[batch].newton.as_mut().and_then(|n| n.resident.pending.take()) {
                    self.queue_step_pass(batch, 1, list, motion);
                }
            }
        }
        let (state, real) = (std::mem::size_of::<DofState<Real>>(), self.gpu.precision.size());
        let per_dof = |size: usize| {
            move |b: &Batch, m: usize| {
                let dofs = super::dof_span(&b.members, &[m]);
                (dofs.start * size) as u64..(dofs.end * size) as u64
            }
        };
        let per_member = |size: usize| move |_: &Batch, m: usize| (m * size) as u64..((m + 1) * size) as u64;
        let (states, reals, energy, row) = (per_dof(state), per_dof(real), per_member(real), per_member(TALLY_ROW * real));
        let requests: [SpanRequest; 5] = [
            (committed, super::Source::Committed, &states),
            (committed, super::Source::CommittedEnergy, &energy),
            (iterates, super::Source::Displacement, &reals),
            (iterates, super::Source::NewtonForces, &reals),
            (iterates, super::Source::TallyRows, &row),
        ];
        let [states, energies, u, f, rows]: [Vec<Vec<u8>>; 5] = self.read_member_spans(&requests, times)?.try_into().expect("five requests");
        let energies: Vec<Real> = energies.iter().map(|b| bytemuck::pod_read_unaligned(b)).collect();
        for e in &energies {
            self.held.0 = self.held.0.saturating_sub(1);
            self.held.1 = if self.held.0 == 0 { 0.0 } else { self.held.1 - e };
        }
        let rows: Vec<Vec<Real>> = rows.iter().map(|b| bytemuck::pod_collect_to_vec(b)).collect();
        for row in &rows {
            self.step_tally.remove(row);
        }
        let kept = states.iter().zip(energies).map(|(b, e)| KeptState { states: bytemuck::pod_collect_to_vec(b), strain: e }).collect();
        let iterates = u.iter().zip(&f).zip(&rows).map(|((u, f), row)| KeptIterate { u: bytemuck::pod_collect_to_vec(u), f_int: bytemuck::pod_collect_to_vec(f), strain: row[1] }).collect();
        Ok((kept, iterates))
    }

    /// What the step's ends that the device keeps add up to ([`GpuWorld::read_kept`] takes
    /// out those it hands back): booked by the host at the step's end.
    pub fn step_tally(&self) -> StepTally {
        self.step_tally
    }

    /// The strain energy of the committed states the device keeps for the host, summed on the
    /// device (`newton_tally` at the step's end, less those [`GpuWorld::read_kept`] handed back).
    pub fn held_strain(&self) -> Real {
        self.held.1
    }

    /// Per request, each listed body's span (`span` of its batch and member) of a batch buffer,
    /// all in one submission (none without a span).
    fn read_member_spans(&mut self, requests: &[SpanRequest], times: &mut PhaseTimes) -> Result<Vec<Vec<Vec<u8>>>, GpuError> {
        let mut readback = super::ReadBack::default();
        let mut landing: Vec<Vec<(u64, u64)>> = requests.iter().map(|(bodies, _, _)| vec![(0, 0); bodies.len()]).collect();
        for ((bodies, what, span), landing) in requests.iter().zip(&mut landing) {
            // Per batch, one copy per run of consecutive members (every grain of a packing at
            // the end of a run: one copy, not one per grain).
            for (batch, b) in self.batches.iter().enumerate() {
                let mut mine: Vec<(usize, usize)> = bodies.iter().enumerate().filter(|&(_, &body)| self.place[body].0 == batch).map(|(k, &body)| (k, self.place[body].1)).collect();
                mine.sort_unstable_by_key(|&(_, m)| m);
                let members: Vec<usize> = mine.iter().map(|&(_, m)| m).collect();
                let member_span = |m: usize| span(b, m);
                for (&(k, m), at) in mine.iter().zip(readback.queue_runs(batch, *what, &members, &member_span)) {
                    let range = span(b, m);
                    landing[k] = (at as u64, range.end - range.start);
                }
            }
        }
        if readback.copies.is_empty() {
            return Ok(landing.iter().map(|_| Vec::new()).collect());
        }
        let target = self.newton_target_of(readback.end);
        let encoder = self.encoder("read kept");
        let mut out = Vec::new();
        self.read_back_into(&target, encoder, &readback, "step_commit", times, std::time::Instant::now(), |bytes| {
            out = landing.iter().map(|l| l.iter().map(|&(at, n)| bytes[at as usize..(at + n) as usize].to_vec()).collect()).collect();
        })?;
        Ok(out)
    }

    /// Records the step's start where it is waiting (`step_commit`, then `step_begin`, per
    /// batch) at the head of `encoder`.
    pub(super) fn record_prologue(&mut self, encoder: &mut wgpu::CommandEncoder) {
        for b in &mut self.batches {
            let Some(n) = b.newton.as_mut() else { continue };
            let r = &mut n.resident;
            for k in [1, 0] {
                let list = std::mem::take(&mut r.lists[k]);
                let most = list.iter().map(|&m| b.members[m].dofs as usize).max().unwrap_or(0);
                // Over the slots, the empty ones included (they return at once).
                let slots = if list.is_empty() { 0 } else { r.slots[k].members.len() };
                r.passes[k].record(&self.gpu, encoder, WORKGROUP, most, slots);
            }
        }
    }

    /// The step's start went with a submission: its members may take uploads again.
    pub(super) fn prologue_submitted(&mut self) {
        for n in self.batches.iter_mut().filter_map(|b| b.newton.as_mut()) {
            if n.resident.lists.iter().all(Vec::is_empty) {
                n.resident.involved.fill(false);
            }
        }
    }

    /// Defers the uploads from here to the next submission's encoder, behind the step's start,
    /// if it is waiting and an upload is about to change what it reads or writes of `members`
    /// of `batch` (a write lands before the commands of the submission it goes with): so the
    /// start costs no submission of its own.
    pub(super) fn settle_prologue(&mut self, batch: usize, members: &[usize]) {
        let Some(r) = self.batches[batch].newton.as_ref().map(|n| &n.resident) else { return };
        if !members.iter().any(|&m| r.involved[m]) {
            return;
        }
        // Once the step's start is recorded, nothing may touch its members until it is submitted.
        assert!(r.lists.iter().any(|l| !l.is_empty()), "an upload to a member of a step's start recorded but not submitted");
        self.deferred.get_or_insert_with(Vec::new);
    }

    /// Submits the step's start alone if any of it is waiting.
    fn flush_prologue(&mut self) -> Result<(), GpuError> {
        if self.batches.iter().filter_map(|b| b.newton.as_ref()).any(|n| n.resident.lists.iter().any(|l| !l.is_empty())) {
            let encoder = self.encoder("step");
            self.submit(encoder)?;
        }
        Ok(())
    }

    /// After the host kept a step (`motion` its theta rule): each listed body's committed state
    /// on the device follows the host's. One whose step ended with a device Newton call the host
    /// took, at the displacements the host kept, commits on the device before the next step
    /// begins (or, the first time, takes the host's state: its velocity alone where the device's
    /// iterate and forces are the host's, set up by the next `step_begin`, else all of it); the
    /// others' device state is dropped.
    pub fn commit_step(&mut self, ends: &[StepEnd], motion: StepMotion<Real>) {
        if self.gpu.precision != Precision::F64 {
            return;
        }
        // The step's kept ends are the committed states the device keeps for the host now.
        let held = ends.iter().filter(|e| e.held).count();
        debug_assert_eq!(held, self.step_tally.members, "the tally counts every kept end");
        self.held = (held, if held == 0 { 0.0 } else { self.step_tally.strain });
        for batch in 0..self.batches.len() {
            let mut mine: Vec<&StepEnd> = ends.iter().filter(|e| self.place[e.body].0 == batch).collect();
            mine.sort_unstable_by_key(|e| self.place[e.body].1);
            let b = &mut self.batches[batch];
            let Some(n) = b.newton.as_mut() else { continue };
            let r = &mut n.resident;
            let (mut commits, mut adopts, mut uploads) = (Vec::new(), Vec::new(), Vec::new());
            for e in mine {
                let m = self.place[e.body].1;
                let dofs = super::dof_span(&b.members, &[m]);
                let current = e.on_device && r.current[m] && (e.held || same_bits(&b.u_host[dofs.clone()], e.u));
                assert!(!e.held || (current && r.valid[m]), "a body whose step end the device keeps commits there");
                // Where the device's forces are the host's too, it holds all of the host's
                // committed state but the velocity.
                let forces_held = || b.dof_out_host[2 * dofs.start..2 * dofs.end].chunks(2).zip(e.f_int).all(|(out, f)| out[0].to_bits() == f.to_bits());
                match (current, r.valid[m]) {
                    (true, true) => commits.push(m),
                    (true, false) if forces_held() => adopts.push((m, e)),
                    (true, false) => uploads.push((m, e)),
                    (false, _) => r.valid[m] = false,
                }
                r.current[m] = false;
            }
            r.pending = (!commits.is_empty()).then_some((commits, motion));
            let adopting: Vec<usize> = adopts.iter().map(|&(m, _)| m).collect();
            let members: Vec<usize> = uploads.iter().map(|&(m, _)| m).collect();
            for &m in adopting.iter().chain(&members) {
                r.valid[m] = true;
            }
            let (committed, energy, [velocities, at, _]) = (r.committed.clone(), r.committed_energy.clone(), r.adoption.clone());
            let marks = r.mark_adoptions(&adopting);
            self.settle_prologue(batch, &[&adopting[..], &members[..]].concat());
            let pieces: Vec<(usize, &[u8])> = adopts.iter().map(|&(m, e)| (m, bytemuck::cast_slice(e.v))).collect();
            self.upload_member_runs(batch, &velocities, 8, &pieces);
            self.upload_per_member(&at, &marks);
            let states: Vec<(usize, Vec<DofState<Real>>)> = uploads.iter().map(|&(m, e)| (m, (0..e.u.len()).map(|d| DofState { u: e.u[d], v: e.v[d], f_int: e.f_int[d] }).collect())).collect();
            let pieces: Vec<(usize, &[u8])> = states.iter().map(|(m, s)| (*m, bytemuck::cast_slice(s))).collect();
            self.upload_member_runs(batch, &committed, 3 * 8, &pieces);
            // The strain energies of both go up.
            uploads.extend(adopts);
            uploads.sort_unstable_by_key(|&(m, _)| m);
            let strains: Vec<(usize, Real)> = uploads.iter().map(|&(m, e)| (m, e.strain)).collect();
            self.upload_per_member(&energy, &strains);
        }
    }

    /// Writes one value per listed member (`(member, value)`, in member order) at the member's
    /// index of `buffer`: one write per run of consecutive members.
    fn upload_per_member<T: bytemuck::Pod>(&mut self, buffer: &Buffer, entries: &[(usize, T)]) {
        let members: Vec<usize> = entries.iter().map(|&(m, _)| m).collect();
        let mut k = 0;
        for run in super::runs(&members) {
            let values: Vec<T> = entries[k..k + run.len()].iter().map(|&(_, value)| value).collect();
            self.upload(buffer, (run[0] * std::mem::size_of::<T>()) as u64, bytemuck::cast_slice(&values));
            k += run.len();
        }
    }

    /// Drops every committed state the device holds (the host's changed: a restored state).
    pub fn forget_committed(&mut self) {
        self.held = (0, 0.0);
        for n in self.batches.iter_mut().filter_map(|b| b.newton.as_mut()) {
            let r = &mut n.resident;
            r.valid.fill(false);
            r.pending = None;
            r.lists = [Vec::new(), Vec::new()];
            r.involved.fill(false);
            r.predicted.fill(false);
        }
    }
}

/// What the step kernels leave: the committed states, the step inputs, the trial and the start
/// displacements, the committed strain energies, the trial velocities' bases.
pub type StepKernelsOut = (Vec<DofState<Real>>, Vec<DofStep<Real>>, Vec<Real>, Vec<Real>, Vec<Real>, Vec<Real>);

/// `step_commit` over the members `commit` lists, then `step_begin` over those `begin` lists
/// as pass number `epoch` (with `adopted` and `adopt_at` for the members that adopt there),
/// alone on an f64 device from the given buffers (`energies`: the committed and the members'
/// strain energies), in one submission as a step's start records them; what they leave, for
/// the parity tests with the CPU twins.
#[allow(clippy::too_many_arguments)]
pub fn run_step_kernels(
    gpu: &Gpu,
    members: &[MemberRange],
    (commit, commit_motion): (&[usize], StepMotion<Real>),
    (begin, begin_motion, epoch): (&[usize], StepMotion<Real>, u32),
    committed: &[DofState<Real>],
    step: &[DofStep<Real>],
    (u, dof_out): (&[Real], &[DofOut<Real>]),
    (committed_energy, member_energy): (&[Real], &[Real]),
    (adopted, adopt_at): (&[Real], &[u32]),
) -> Result<StepKernelsOut, GpuError> {
    assert_eq!(gpu.precision, Precision::F64, "the device keeps committed states in f64 only");
    let pipelines = StepPipelines::new(gpu)?;
    let rw = BufferUsages::STORAGE | BufferUsages::COPY_SRC | BufferUsages::COPY_DST;
    let init = |label: &str, bytes: &[u8], usage: BufferUsages| super::buffer_init(gpu, label, bytes, usage);
    let (committed_b, step_b, u_b, u_start_b) = (init("committed", bytemuck::cast_slice(committed), rw), init("step", bytemuck::cast_slice(step), rw), init("u", bytemuck::cast_slice(u), rw), buffer(gpu, "u start", u.len() * 8, rw));
    let u_base_b = buffer(gpu, "u base", u.len() * 8, rw);
    let (dof_out_b, members_b) = (init("dof out", bytemuck::cast_slice(dof_out), BufferUsages::STORAGE), init("members", bytemuck::cast_slice(members), BufferUsages::STORAGE));
    let (committed_energy_b, member_energy_b) = (init("committed energy", bytemuck::cast_slice(committed_energy), rw), init("member energy", bytemuck::cast_slice(member_energy), BufferUsages::STORAGE));
    let uniform = BufferUsages::UNIFORM;
    let motion = |m: StepMotion<Real>| init("motion", bytemuck::cast_slice(&[m]), uniform);
    let jobs = |list: &[usize]| init("jobs", bytemuck::cast_slice(&list.iter().map(|&m| Active { member: m as u32, mode: MODE_FORCES }).collect::<Vec<_>>()), BufferUsages::STORAGE);
    let (commit_motion, begin_motion, commit_jobs, begin_jobs) = (motion(commit_motion), motion(begin_motion), jobs(commit), jobs(begin));
    let (adopted_b, adopt_at_b) = (init("adopted", bytemuck::cast_slice(adopted), BufferUsages::STORAGE), init("adopt at", bytemuck::cast_slice(adopt_at), BufferUsages::STORAGE));
    let epoch_b = init("epoch", bytemuck::cast_slice(&[epoch, 0, 0, 0]), uniform);
    let bindings = StepBindings {
        motions: [&begin_motion, &commit_motion],
        jobs: [&begin_jobs, &commit_jobs],
        committed: &committed_b,
        member_energy: &member_energy_b,
        committed_energy: &committed_energy_b,
        step: &step_b,
        u: &u_b,
        u_start: &u_start_b,
        u_base: &u_base_b,
        dof_out: &dof_out_b,
        members: &members_b,
        adoption: AdoptionBuffers { velocities: &adopted_b, at: &adopt_at_b, epoch: &epoch_b },
    };
    let [begin_pass, commit_pass] = pipelines.passes(gpu, &bindings);
    let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("step kernels") });
    let most = |list: &[usize]| list.iter().filter(|&&m| m != NO_MEMBER as usize).map(|&m| members[m].dofs as usize).max().unwrap_or(0);
    commit_pass.record(gpu, &mut encoder, WORKGROUP, most(commit), commit.len());
    begin_pass.record(gpu, &mut encoder, WORKGROUP, most(begin), begin.len());
    let sizes = [std::mem::size_of_val(committed), std::mem::size_of_val(step), u.len() * 8, u.len() * 8, committed_energy.len() * 8, u.len() * 8];
    let bytes = read_buffers(gpu, encoder, &[&committed_b, &step_b, &u_b, &u_start_b, &committed_energy_b, &u_base_b], &sizes)?;
    let reals = |k: usize| bytemuck::pod_collect_to_vec(&bytes[k]);
    Ok((bytemuck::pod_collect_to_vec(&bytes[0]), bytemuck::pod_collect_to_vec(&bytes[1]), reals(2), reals(3), reals(4), reals(5)))
}

/// Copies the first `sizes[k]` bytes of each buffer into mappable ones after the commands of
/// `encoder`, submits, and reads them.
fn read_buffers(gpu: &Gpu, mut encoder: wgpu::CommandEncoder, buffers: &[&Buffer], sizes: &[usize]) -> Result<Vec<Vec<u8>>, GpuError> {
    let staged: Vec<Buffer> = buffers
        .iter()
        .zip(sizes)
        .map(|(b, &bytes)| {
            let staging = buffer_of(gpu, bytes);
            encoder.copy_buffer_to_buffer(b, 0, &staging, 0, bytes as u64);
            staging
        })
        .collect();
    gpu.submit(encoder)?;
    staged.iter().zip(sizes).map(|(b, &size)| gpu.read_range("step kernels", b, size as u64)).collect()
}

/// What `newton_summary` reads besides the members and the call's list: the step's motion and
/// coefficients, the committed states and their strain energies, the step inputs, every dof's
/// reference coordinate, the iterate and its forces, and the members' Newton states and strain
/// energies.
pub type SummaryBuffers<'a> = (StepMotion<Real>, Coefficients<Real>, (&'a [DofState<Real>], &'a [Real]), &'a [DofStep<Real>], &'a [Real], &'a [Real], &'a [DofOut<Real>], &'a [NewtonState<Real>], &'a [Real]);

/// What `newton_summary` and `newton_tally` leave: the summaries, the boxes, the tally rows,
/// and the tally.
pub type SummaryOut = (Vec<Real>, Vec<f32>, Vec<Real>, Vec<Real>);

/// `newton_summary` over the first `kept` members `call` lists, then `newton_tally`, alone on
/// an f64 device from the given buffers; the summaries, boxes and rows the first writes
/// (`summary_len(dim)` reals, `2 dim` f32 and `TALLY_ROW` reals per member, zero for the
/// others) and the tally, for the parity tests with the CPU twins.
pub fn run_newton_summary(gpu: &Gpu, members: &[MemberRange], (call, kept): (&[usize], usize), (motion, coefficients, (committed, committed_energy), step, reference, u, dof_out, state, member_energy): SummaryBuffers) -> Result<SummaryOut, GpuError> {
    assert_eq!(gpu.precision, Precision::F64, "the device keeps committed states in f64 only");
    let (summary_pipeline, tally_pipeline) = (gpu.pipeline_at("newton_summary", "main", None)?, gpu.pipeline_at("newton_tally", "main", None)?);
    let read = BufferUsages::STORAGE;
    let init = |label: &str, bytes: &[u8], usage: BufferUsages| super::buffer_init(gpu, label, bytes, usage);
    let zeros = |label: &str, reals: usize| init(label, bytemuck::cast_slice(&vec![0.0 as Real; reals]), read | BufferUsages::COPY_SRC);
    let sizes = [members.len() * summary_len(motion.dim as usize) * 8, members.len() * 2 * motion.dim as usize * 4, members.len() * TALLY_ROW * 8, TALLY_LEN * 8];
    let (summary, boxes, rows, tally) = (zeros("summary", sizes[0] / 8), zeros("boxes", sizes[1] / 8 + 1), zeros("rows", sizes[2] / 8), zeros("tally", TALLY_LEN));
    let mut dispatch = [0u32; super::newton::DISPATCH_WORDS];
    dispatch[super::newton::CALL_COUNT] = call.len() as u32;
    dispatch[super::newton::KEPT_COUNT] = kept as u32;
    let jobs: Vec<Active> = call.iter().map(|&m| Active { member: m as u32, mode: MODE_FORCES }).collect();
    let buffers = [
        ("motion", init("motion", bytemuck::bytes_of(&motion), BufferUsages::UNIFORM)),
        ("coefficients", init("coefficients", bytemuck::cast_slice(&[coefficients.factor, coefficients.c1, coefficients.motion]), BufferUsages::UNIFORM)),
        ("committed", init("committed", bytemuck::cast_slice(committed), read)),
        ("committed_energy", init("committed energy", bytemuck::cast_slice(committed_energy), read)),
        ("step", init("step", bytemuck::cast_slice(step), read)),
        ("reference", init("reference", bytemuck::cast_slice(reference), read)),
        ("u", init("u", bytemuck::cast_slice(u), read)),
        ("dof_out", init("dof out", bytemuck::cast_slice(dof_out), read)),
        ("members", init("members", bytemuck::cast_slice(members), read)),
        ("jobs", init("jobs", bytemuck::cast_slice(&jobs), read)),
        ("dispatch", init("dispatch", bytemuck::cast_slice(&dispatch), read)),
        ("state", init("state", bytemuck::cast_slice(state), read)),
        ("member_energy", init("member energy", bytemuck::cast_slice(member_energy), read)),
    ];
    let mut bindings: Vec<(&str, &Buffer)> = buffers.iter().map(|(name, b)| (*name, b)).collect();
    bindings.extend([("summary", &summary), ("boxes", &boxes), ("rows", &rows)]);
    let summarise = Pass::bound(gpu, summary_pipeline, ("newton_summary", "main"), None, &bindings);
    let find = |name: &str| &buffers.iter().find(|(n, _)| *n == name).expect("bound above").1;
    let add_up = Pass::bound(gpu, tally_pipeline, ("newton_tally", "main"), None, &[("call", find("jobs")), ("dispatch", find("dispatch")), ("state", find("state")), ("rows", &rows), ("tally", &tally)]);
    let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("newton summary") });
    {
        let mut compute = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("newton summary"), timestamp_writes: None });
        summarise.dispatch(gpu, &mut compute, call.len().div_ceil(WORKGROUP).max(1) as u32);
        add_up.dispatch(gpu, &mut compute, 1);
    }
    let bytes = read_buffers(gpu, encoder, &[&summary, &boxes, &rows, &tally], &sizes)?;
    Ok((bytemuck::pod_collect_to_vec(&bytes[0]), bytemuck::pod_collect_to_vec(&bytes[1]), bytemuck::pod_collect_to_vec(&bytes[2]), bytemuck::pod_collect_to_vec(&bytes[3])))
}

/// A mappable buffer of `bytes` for a read-back.
fn buffer_of(gpu: &Gpu, bytes: usize) -> Buffer {
    buffer(gpu, "step read-back", bytes, BufferUsages::MAP_READ | BufferUsages::COPY_DST)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn held(s: &Slots) -> Vec<u32> {
        let mut members: Vec<u32> = s.members.iter().copied().filter(|&m| m != NO_MEMBER).collect();
        members.sort_unstable();
        members
    }

    #[test]
    fn a_step_list_that_loses_and_gains_members_sends_the_slots_that_changed() {
        let mut s = Slots::default();
        let all: Vec<usize> = (0..100).collect();
        let first = s.take(&all, 100);
        assert_eq!((first.len(), first[0].0, first[0].1.len()), (1, 0, 100));
        assert!(s.take(&all, 100).is_empty(), "the same list sends nothing");
        // Two grains land: their slots empty, nothing else moves.
        let fewer: Vec<usize> = all.iter().copied().filter(|&m| m != 10 && m != 11).collect();
        assert_eq!(s.take(&fewer, 100), vec![(10, vec![Active { member: NO_MEMBER, mode: MODE_FORCES }; 2])]);
        assert_eq!(s.members.len(), 100);
        // One takes off again: the first empty slot.
        let back: Vec<usize> = fewer.iter().copied().chain([11]).collect();
        assert_eq!(s.take(&back, 100), vec![(10, vec![Active { member: 11, mode: MODE_FORCES }])]);
        assert_eq!(held(&s), (0..100u32).filter(|&m| m != 10).collect::<Vec<_>>());
        // The last ones leave: the list ends at its last member.
        assert!(!s.take(&(0..90).collect::<Vec<_>>(), 100).is_empty());
        assert_eq!(s.members.len(), 90);
        // Most leave: their slots empty, the list as long as its last member's slot.
        let no = Active { member: NO_MEMBER, mode: MODE_FORCES };
        assert_eq!(s.take(&[5, 7], 100), vec![(0, vec![no; 5]), (6, vec![no])]);
        assert_eq!(s.members, vec![NO_MEMBER, NO_MEMBER, NO_MEMBER, NO_MEMBER, NO_MEMBER, 5, NO_MEMBER, 7]);
        // Most of a long list empty: a fresh list, all of it sent.
        let mut long = Slots::default();
        long.take(&(0..1000).collect::<Vec<_>>(), 1000);
        assert_eq!(long.take(&[5, 900], 1000), vec![(0, vec![Active { member: 5, mode: MODE_FORCES }, Active { member: 900, mode: MODE_FORCES }])]);
        assert_eq!(long.members, vec![5, 900]);
    }
}
