//! A step's Newton iterations on the device, for the bodies that keep their factorisation and
//! have no contact point (most of a packing's groups after the first round: a grain in free
//! flight, or one that rests alone). When a small body's factorisation is refreshed, the host
//! sends `K̄` (the values faer factorised) and the device makes `K̄⁻¹` of its free dofs
//! (`newton_invert`, `invert.rs`), once per factorisation; the device
//! then takes the increments (`newton_update`), the forces (`element_force_tangent`'s
//! `forces`, `assemble_residual`), the convergence test (`newton_judge`) and drops the members
//! that are done from the next iteration's list and dispatch counts (`newton_compact`), several
//! iterations per submission. The host reads back the members' states, displacements and
//! internal forces (it computes the residuals from them), and their strain energies, once per
//! submission. In the first round of a step the
//! members come unevaluated, and the device evaluates and judges them first, in the same
//! submission.

use super::contact::{ContactLayout, ContactPasses, ContactPipelines, GroupContact};
use super::invert::{diagonal_of, off_diagonal_print, Inverse, NewInverses};
use super::{buffer, to_device, Batch, Evaluation, GpuWorld, Pass, ReadBack, Source, WORKGROUP};
use crate::contact::uzawa::Problem;
use crate::gpu::types::{
    packed_len, summary_len, Active, Coefficients, ContactState, DofOut, DofStep, NewtonMember, NewtonState, StepSummary, StepTally, MODE_FORCES, MODE_TANGENT, NEWTON_CONVERGED, NEWTON_FAILED, NEWTON_HOST, NEWTON_ITERATING, NEWTON_MAX_FREE,
    NO_FAILURE, TALLY_LEN, TALLY_ROW,
};
use crate::gpu::uzawa_sweep::UzawaSweeps;
use crate::gpu::{ElementFailure, Gpu, GpuError};
use crate::policy::PhaseTimes;
use crate::precision::{same_bits, Precision, Real};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;
use wgpu::{Buffer, BufferUsages, ComputePipeline};

/// Device iterations recorded in the first submission of a call: a body that converges on the
/// device mostly does so in one to three, a group in contact in four to eleven, and an iteration
/// recorded for members that have stopped costs only empty dispatches (doc/benchmarks.md,
/// "Figures behind constants"). The second records what is left of the largest budget, so that
/// a call takes at most two submissions however many iterations it needs.
const ITERATIONS_PER_SUBMIT: u32 = 12;

/// The indirect dispatches (x, y, z) of update, forces, residual and judge, then the length of
/// the call's list and how many of its first members are kept (`DISPATCHES`, `CALL_COUNT` and
/// `KEPT_COUNT` of `newton.wgsl`).
pub(super) const DISPATCH_WORDS: usize = 14;
const DISPATCHES: usize = 4;
pub(super) const CALL_COUNT: usize = 12;
pub(super) const KEPT_COUNT: usize = 13;

/// A batch's share of a [`GpuWorld::newton`] call: the batch, its `(call, member)` pairs in
/// member order, and the workgroups of the energy pass over them.
type BatchCalls = (usize, Vec<(usize, usize)>, [u32; 3]);

/// What the submissions of a [`GpuWorld::newton`] call record: its batches' calls, the passes of
/// its groups in contact (their batch), the solve dispatches per increment, the number of
/// groups in contact and whether any may refactorise within the call.
struct CallPlan<'a> {
    work: &'a [BatchCalls],
    contact: Option<&'a (usize, ContactPasses)>,
    solves: usize,
    contacts: usize,
    refactor: bool,
}

/// Where a call's results land in a read-back: its state, then (absent for a kept call) its
/// failure flags, displacements and internal forces, its strain energy, and (a kept call's) its
/// summary.
#[derive(Clone, Copy, Default)]
struct Landing {
    /// A call that is not kept: where its Newton state and strain energy land.
    state_and_energy: Option<(usize, usize)>,
    iterate: Option<[usize; 3]>,
    /// A kept call: its summary, which holds its state and energy too, and its box.
    summary: Option<(usize, usize)>,
    /// A kept call's displacements, when it sends them ([`NewtonCall::positions`]).
    positions: Option<usize>,
}

/// Takes every call's state, displacements, residuals and strain energy from a submission's
/// read-back (`landing` from `GpuWorld::queue_states`), in parallel (100 000 grains a call). A
/// kept call takes its state, energy and summary only.
fn unpack_calls(precision: Precision, calls: &mut [NewtonCall], (landing, coefficients, dim): (&[Landing], Coefficients<Real>, usize), bytes: &[u8]) {
    let real = precision.size();
    calls.par_iter_mut().zip(landing).for_each(|(call, at)| {
        match (at.state_and_energy, at.summary) {
            (Some((state, energy)), _) => {
                call.outcome = bytemuck::pod_read_unaligned(&bytes[state..state + std::mem::size_of::<NewtonState<Real>>()]);
                call.strain_energy = Some(super::from_device(precision, &bytes[energy..energy + real])[0]);
            }
            (None, Some((s, b))) => {
                let boxes: &[f32] = bytemuck::cast_slice(&bytes[b..b + 8 * dim]);
                let (state, summary) = StepSummary::of(dim, &super::from_device(precision, &bytes[s..s + summary_len(dim) * real]), boxes);
                call.outcome = state;
                // (a kept call that did not converge takes its strain energy with its iterate)
                call.strain_energy = None;
                call.summary = (state.status == NEWTON_CONVERGED).then_some(summary);
            }
            (None, None) => unreachable!("a call reads its state or its summary"),
        }
        call.outcome.iterations -= call.taken;
        if let Some(iterate) = at.iterate {
            unpack_iterate(precision, call, iterate, coefficients, bytes);
        }
        if let Some(u_at) = at.positions {
            let n = call.u.len();
            super::copy_from_device(precision, &bytes[u_at..u_at + n * real], call.u);
        }
    });
}

/// Takes a call's failure flags, displacements and internal forces (`[flags, u, forces]`: where
/// they land), and computes its residuals from the forces as `assemble_residual` does, with
/// the step inputs the host holds.
fn unpack_iterate(precision: Precision, call: &mut NewtonCall, [flags_at, u_at, out_at]: [usize; 3], coefficients: Coefficients<Real>, bytes: &[u8]) {
    let real = precision.size();
    let flags: [u32; 2] = bytemuck::pod_read_unaligned(&bytes[flags_at..flags_at + 8]);
    call.failure = (call.outcome.status == NEWTON_FAILED).then(|| super::failure_of(flags)).flatten();
    let n = call.u.len();
    super::copy_from_device(precision, &bytes[u_at..u_at + n * real], call.u);
    let forces = super::from_device(precision, &bytes[out_at..out_at + n * real]);
    for (d, (out, f)) in call.dof_out.iter_mut().zip(forces).enumerate() {
        *out = DofOut { f_int: f, g: call.inputs[d].residual(coefficients, call.u[d], f) };
    }
}

/// Takes the reactions of the groups in contact and their states from a submission's read-back
/// (where each lands: `(reactions, states)`).
fn unpack_contact(precision: Precision, problems: &mut [Problem], contacts: &mut [GroupContact], (r_at, states_at, rho_at): (usize, usize, usize), bytes: &[u8]) {
    let real = precision.size();
    let mut at = r_at;
    for p in problems.iter_mut() {
        let end = at + p.r.len() * 3 * real;
        super::copy_from_device(precision, &bytes[at..end], bytemuck::cast_slice_mut(p.r));
        at = end;
    }
    let mut at = rho_at;
    for (p, g) in problems.iter().zip(contacts.iter_mut()) {
        let end = at + p.local.len() * real;
        g.step_lengths = super::from_device(precision, &bytes[at..end]);
        at = end;
    }
    let size = std::mem::size_of::<ContactState<Real>>();
    for (k, g) in contacts.iter_mut().enumerate() {
        g.outcome = bytemuck::pod_read_unaligned(&bytes[states_at + k * size..states_at + (k + 1) * size]);
    }
}

/// Per dof of batch `b`, its free index in its member's `K̄⁻¹`, or [`crate::gpu::types::NOT_FREE`].
fn free_index_of_dofs(b: &Batch) -> Vec<u32> {
    let mut free_of = vec![crate::gpu::types::NOT_FREE; b.u_host.len()];
    for (r, &(start, count)) in b.members.iter().zip(&b.free_range) {
        for (f, &d) in b.free_dofs[start as usize..][..count as usize].iter().enumerate() {
            free_of[(r.dof_start + d) as usize] = f as u32;
        }
    }
    free_of
}

/// What the read-back of a call's groups in contact holds: their points and groups.
type ContactTarget = (usize, usize);

/// One body's share of [`GpuWorld::newton`].
pub struct NewtonCall<'a> {
    pub body: usize,
    /// Newton iterations the body's step took before this call: the device counts on from
    /// them (`NewtonMember::budget` is the step's), and `outcome` counts this call's only.
    pub taken: u32,
    /// The version of the body's factorisation, and its `K̄⁻¹` of the free dofs when the device
    /// does not hold that version's yet ([`GpuWorld::newton_inverse_current`]).
    pub factor: u64,
    pub inverse: Option<Inverse>,
    /// The body's tolerances and the step's budget (`inverse_start`, `free_start` and
    /// `free_count` are the world's to set).
    pub member: NewtonMember<Real>,
    /// The residual norm of the evaluation at `u`; `None`: `u` is not evaluated yet (the first
    /// round of a step), and the device evaluates and judges it before the first increment, as
    /// the host would have, without a round trip between.
    pub residual: Option<Real>,
    /// In: the iterate and, when it was evaluated, its results; out: the device's last ones.
    pub u: &'a mut [Real],
    pub dof_out: &'a mut [DofOut<Real>],
    /// The displacements at the start of the step.
    pub u_start: &'a [Real],
    /// The step's inputs as the host holds them: the residual returned is computed from the
    /// device's forces with them.
    pub inputs: &'a [DofStep<Real>],
    /// The contact forces per dof (`None`: zero, a body without contact points).
    pub contact_force: Option<&'a [Real]>,
    /// The host leaves the body's step end on the device if it converges there: only its
    /// summary comes back ([`NewtonCall::summary`]), not its displacements and forces (those of
    /// a call that ends otherwise come back after it). Only for a call whose step the device
    /// began ([`GpuWorld::begin_step`]).
    pub keep: bool,
    /// A kept call sends back its displacements too (into `u`): the host's searches read them.
    pub positions: bool,
    /// Out, for a kept call that converged: its step end, reduced on the device.
    pub summary: Option<StepSummary>,
    /// Out: where the iterations ended.
    pub outcome: NewtonState<Real>,
    /// Out: the strain energy at the `u` returned (`element_energy` after the iterations, in
    /// the same submission: the step's energy balance then needs no pass of its own).
    pub strain_energy: Option<Real>,
    pub failure: Option<ElementFailure>,
    /// Out, for a member of a group in contact that the device hands back to the host
    /// ([`NEWTON_HOST`]): the device holds its stiffness values `ξ K` at the `u` returned
    /// (computed after the iterations, not read back), so that the `K̄` the host makes there
    /// goes up by its diagonal ([`Inverse::AtHandBack`]).
    pub tangent_held: bool,
}

/// The tangents of the members of groups in contact that a call hands back to the host
/// (mostly a factorisation that contracts too slowly, which the host renews at that iterate):
/// `newton_compact`'s `host` entry lists them, and the tangent kernel and `assemble_csr` run
/// over that list after the iterations. Their stiffness values stay on the device
/// ([`NewtonCall::tangent_held`]): the host assembles its own to factorise (a grain's tangent
/// costs the CPU less than its factorisation, and reading them cost half the bytes of a
/// pressed packing's steps), and `K̄` goes back up by its diagonal.
struct HostTangents {
    /// The members of the call's groups in contact (mode TANGENT); those handed back go into
    /// a list the passes are bound to.
    call: Buffer,
    /// The indirect dispatches of the tangent and `assemble_csr`, then the list's length
    /// (the layout of [`DISPATCH_WORDS`]).
    dispatch: Buffer,
    compact: Pass,
    tangent: Pass,
    csr: Pass,
    /// The same list and passes for the members that refactorise within the call
    /// (`newton_compact`'s `refactor`), then their `K̄⁻¹` (`newton_invert`'s `refactor`, the
    /// third dispatch).
    compact_refactor: Pass,
    invert_refactor: Pass,
}

impl HostTangents {
    fn new(gpu: &Gpu, pipelines: &NewtonPipelines, b: &Batch, tangent: &Pass, (n, coefficients): (&NewtonBuffers, &Buffer)) -> Self {
        let write = BufferUsages::STORAGE | BufferUsages::COPY_DST;
        let members = b.members.len();
        let call = buffer(gpu, "host tangents call", members * 8, write);
        let jobs = buffer(gpu, "host tangents jobs", members * 8, write);
        let dispatch = buffer(gpu, "host tangents dispatch", DISPATCH_WORDS * 4, write | BufferUsages::INDIRECT);
        let (tangent, csr) = (tangent.with_jobs(gpu, &jobs), b.csr.with_jobs(gpu, &jobs));
        let listing = [("call", &call), ("state", &n.state), ("jobs", &jobs), ("dispatch", &dispatch)];
        let compact = Pass::bound(gpu, pipelines.compact_host.clone(), ("newton_compact", "host"), None, &listing);
        let compact_refactor = Pass::bound(gpu, pipelines.compact_refactor.clone(), ("newton_compact", "refactor"), None, &listing);
        let invert_refactor = Pass::bound(
            gpu,
            pipelines.invert_refactor.clone(),
            ("newton_invert", "refactor"),
            None,
            &[
                ("inverse", &n.inverse),
                ("newton", &n.newton),
                ("patterns", &n.patterns),
                ("values", &b.values),
                ("members", &b.member_buffer),
                ("jobs", &jobs),
                ("pattern_of", &n.pattern_of),
                ("free_dofs", &n.free),
                ("step", &b.step),
                ("coefficients", coefficients),
                ("u", &b.u),
                ("u_factored", &n.u_factored),
                ("state", &n.state),
            ],
        );
        Self { call, dispatch, compact, tangent, csr, compact_refactor, invert_refactor }
    }

    /// Records the refactorisations within an iteration, after the groups' verdicts: the list
    /// of members in REFACTOR, their tangents and stiffness values at the iterate, their `K̄⁻¹`.
    fn record_refactor(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass) {
        self.compact_refactor.dispatch(gpu, pass, 1);
        self.tangent.dispatch_indirect(gpu, pass, &self.dispatch, 0);
        self.csr.dispatch_indirect(gpu, pass, &self.dispatch, 12);
        self.invert_refactor.dispatch_indirect(gpu, pass, &self.dispatch, 24);
    }
}

/// A batch's buffers and pipelines for device Newton iterations, made with the world where its
/// members can iterate on the device ([`GpuWorld::make_newton_buffers`]; a batch of large
/// bodies pays nothing).
pub(super) struct NewtonBuffers {
    pub(super) inverse: Buffer,
    /// The batch's distinct stiffness patterns (`Batch::patterns`), for `newton_invert`, and
    /// where each member's starts (`Batch::pattern_start`), for its `refactor`.
    pub(super) patterns: Buffer,
    pattern_of: Buffer,
    /// Per dof, the displacement at which the device last refactorised its member within a
    /// call ([`GpuWorld::factored_at`]).
    pub(super) u_factored: Buffer,
    /// The inversions a call staged, recorded at the head of its first submission.
    invert: Option<(Pass, u32)>,
    pub(super) free: Buffer,
    /// Per dof, its free index in its member's `K̄⁻¹` ([`crate::gpu::types::NOT_FREE`] if prescribed):
    /// where `newton_contact`'s `delassus` reads a node's response.
    pub(super) free_of: Buffer,
    pub(super) newton: Buffer,
    pub(super) state: Buffer,
    /// Per dof: the contact forces (zero but for groups in contact), and for those groups the
    /// contact-free increment and `u_t + dt (1 - θ) v_t` (`newton_contact.wgsl`).
    pub(super) contact: Buffer,
    pub(super) x0: Buffer,
    pub(super) u_base: Buffer,
    pub(super) u_start: Buffer,
    call: Buffer,
    /// The members still iterating, which every kernel of an iteration runs over: a list of
    /// its own, so that an evaluation pass of other bodies (over the batch's `active`) can share
    /// the submission.
    jobs: Buffer,
    dispatch: Buffer,
    forces: Pass,
    residual: Pass,
    /// `element_energy` over the call's list, then `newton_finish`: each member's sum of them
    /// into `member_energy`, its internal forces packed into `packed_forces`.
    energy: Pass,
    finish: Pass,
    pub(super) member_energy: Buffer,
    pub(super) packed_forces: Buffer,
    /// `newton_summary` over the call's list, after `newton_finish`: per member what the host
    /// books at the end of its step, so that a member the host leaves on the device sends back
    /// these few reals instead of its displacements and forces.
    summarise: Pass,
    pub(super) summary: Buffer,
    /// Each member's box in f32 (`newton_summary`).
    pub(super) boxes: Buffer,
    /// Each kept member's row of what `newton_tally` sums (`newton_summary`), and the sums.
    pub(super) rows: Buffer,
    pub(super) tally: Buffer,
    add_up: Pass,
    update: Pass,
    judge: Pass,
    compact: Pass,
    /// Made by the first call with groups in contact.
    host_tangents: Option<HostTangents>,
    /// Each member's state at the start of an unevaluated call and its flags without a failure,
    /// which the device copies into `state` and the batch's `failure` for the call's runs of
    /// members (`start_runs`: first member, count) at its first submission.
    initial_state: Buffer,
    no_failure: Buffer,
    start_runs: Vec<(usize, usize)>,
    /// The call's list as last uploaded, and how many of its first are kept.
    call_host: Vec<Active>,
    call_kept: usize,
    /// Host copies: each member's parameters and start displacements as last uploaded, and the
    /// factorisation whose inverse its slot holds.
    newton_host: Vec<NewtonMember<Real>>,
    pub(super) start_host: Vec<Real>,
    pub(super) contact_host: Vec<Real>,
    inverse_version: Vec<Option<u64>>,
    /// The members' committed states, for steps begun and committed on the device.
    pub(super) resident: super::step::Resident,
}

/// Where each member's `K̄⁻¹` (its lower triangle, `gpu::types::packed`) lies in a batch's
/// `inverse` buffer: members of at most
/// `NEWTON_MAX_FREE` free dofs, in member order, while the buffer stays within the device's
/// binding limit; `None` for the others (they iterate on the host).
pub(super) fn inverse_slots(free_counts: &[usize], real: usize, max_bytes: u64) -> (Vec<Option<u32>>, usize) {
    let mut total = 0usize;
    let slots = free_counts
        .iter()
        .map(|&n| {
            let size = packed_len(n);
            let fits = n > 0 && n <= NEWTON_MAX_FREE && ((total + size) * real) as u64 <= max_bytes && total + size <= u32::MAX as usize;
            fits.then(|| {
                total += size;
                (total - size) as u32
            })
        })
        .collect();
    (slots, total)
}

/// A call's list: the `kept` members first, then the `others`, each part's members in the slots
/// they held in its part of the `previous` list (its first `previous_kept` the kept part) where
/// they can: a member that left gives its slot to its part's last, one that joined goes last.
/// A list that changes by a few members (a grain that lands leaves the kept part) then changes
/// in a few slots.
fn arrange((previous, previous_kept): (&[Active], usize), kept: &[usize], others: &[usize]) -> Vec<Active> {
    let count = previous.iter().map(|a| a.member as usize + 1).chain(kept.iter().chain(others).map(|&m| m + 1)).max().unwrap_or(0);
    let mut list = Vec::with_capacity(kept.len() + others.len());
    for (was, wanted) in [(&previous[..previous_kept], kept), (&previous[previous_kept..], others)] {
        let mut listed = vec![false; count];
        for &m in wanted {
            listed[m] = true;
        }
        let mut part: Vec<u32> = was.iter().map(|a| a.member).collect();
        let mut k = 0;
        while k < part.len() {
            if listed[part[k] as usize] {
                listed[part[k] as usize] = false;
                k += 1;
            } else {
                part.swap_remove(k);
            }
        }
        part.extend(wanted.iter().filter(|&&m| listed[m]).map(|&m| m as u32));
        list.extend(part.into_iter().map(|member| Active { member, mode: MODE_FORCES }));
    }
    list
}

/// The pipelines of `newton_update`, `newton_judge` and `newton_compact`, compiled once per
/// world (they do not depend on the batch's element or material).
pub(super) struct NewtonPipelines {
    update: ComputePipeline,
    invert: ComputePipeline,
    judge: ComputePipeline,
    compact: ComputePipeline,
    compact_host: ComputePipeline,
    compact_refactor: ComputePipeline,
    invert_refactor: ComputePipeline,
    finish: ComputePipeline,
    summary: ComputePipeline,
    tally: ComputePipeline,
    step: super::step::StepPipelines,
}

impl NewtonPipelines {
    fn new(gpu: &Gpu) -> Result<Self, GpuError> {
        Ok(Self {
            update: gpu.pipeline_at("newton_update", "main", None)?,
            invert: gpu.pipeline_at("newton_invert", "main", None)?,
            judge: gpu.pipeline_at("newton_judge", "main", None)?,
            compact: gpu.pipeline_at("newton_compact", "main", None)?,
            compact_host: gpu.pipeline_at("newton_compact", "host", None)?,
            compact_refactor: gpu.pipeline_at("newton_compact", "refactor", None)?,
            invert_refactor: gpu.pipeline_at("newton_invert", "refactor", None)?,
            finish: gpu.pipeline_at("newton_finish", "main", None)?,
            summary: gpu.pipeline_at("newton_summary", "main", None)?,
            tally: gpu.pipeline_at("newton_tally", "main", None)?,
            step: super::step::StepPipelines::new(gpu)?,
        })
    }
}

impl NewtonBuffers {
    fn new(gpu: &Arc<Gpu>, pipelines: &NewtonPipelines, b: &Batch, coefficients: &Buffer) -> Result<Self, GpuError> {
        let real = gpu.precision.size();
        let dofs = b.u_host.len();
        let members = b.members.len();
        let storage = BufferUsages::STORAGE;
        let write = storage | BufferUsages::COPY_DST;
        let inverse = buffer(gpu, "inverse", b.inverse_entries * real, write);
        let free = super::buffer_init(gpu, "free dofs", bytemuck::cast_slice(&b.free_dofs), storage);
        let free_of = super::buffer_init(gpu, "free index of dof", bytemuck::cast_slice(&free_index_of_dofs(b)), storage);
        let newton = buffer(gpu, "newton members", members * std::mem::size_of::<NewtonMember<Real>>(), write);
        let state = buffer(gpu, "newton state", members * std::mem::size_of::<NewtonState<Real>>(), write | BufferUsages::COPY_SRC);
        let u_start = buffer(gpu, "u start", dofs * real, write);
        let contact = buffer(gpu, "contact forces", dofs * real, write);
        let x0 = buffer(gpu, "contact-free increments", dofs * real, write);
        let u_base = buffer(gpu, "u base", dofs * real, write);
        let call = buffer(gpu, "newton call", members * 8, write | BufferUsages::COPY_SRC);
        let jobs = buffer(gpu, "newton jobs", members * 8, write);
        let dispatch = buffer(gpu, "newton dispatch", DISPATCH_WORDS * 4, write | BufferUsages::INDIRECT);
        let (forces, residual) = (b.forces.with_jobs(gpu, &jobs), b.residual.with_jobs(gpu, &jobs));
        let energy = b.element_energy.with_jobs(gpu, &call);
        let common = [("free_dofs", &free), ("newton", &newton), ("state", &state), ("dof_out", &b.dof_out), ("u", &b.u), ("members", &b.member_buffer), ("jobs", &jobs), ("contact", &contact)];
        let update = Pass::bound(gpu, pipelines.update.clone(), ("newton_update", "main"), None, &[&common[..], &[("inverse", &inverse)]].concat());
        let judge = Pass::bound(gpu, pipelines.judge.clone(), ("newton_judge", "main"), None, &[&common[..], &[("u_start", &u_start), ("step", &b.step), ("coefficients", coefficients), ("failure", &b.failure)]].concat());
        let compact = Pass::bound(gpu, pipelines.compact.clone(), ("newton_compact", "main"), None, &[("call", &call), ("state", &state), ("jobs", &jobs), ("dispatch", &dispatch)]);
        let member_energy = buffer(gpu, "member energy", members * real, storage | BufferUsages::COPY_SRC);
        let resident = super::step::Resident::new(gpu, &pipelines.step, b, (&u_start, &u_base), &member_energy);
        let packed_forces = buffer(gpu, "newton forces", dofs * real, storage | BufferUsages::COPY_SRC);
        let finish = Pass::bound(
            gpu,
            pipelines.finish.clone(),
            ("newton_finish", "main"),
            None,
            &[("energy", &b.energy), ("dof_out", &b.dof_out), ("members", &b.member_buffer), ("jobs", &call), ("dispatch", &dispatch), ("member_energy", &member_energy), ("forces", &packed_forces)],
        );
        let (summary, boxes) = (buffer(gpu, "summary", members * summary_len(3) * real, storage | BufferUsages::COPY_SRC), buffer(gpu, "boxes", members * 6 * 4, storage | BufferUsages::COPY_SRC));
        let (rows, tally) = (buffer(gpu, "tally rows", members * TALLY_ROW * real, storage | BufferUsages::COPY_SRC), buffer(gpu, "tally", TALLY_LEN * real, storage | BufferUsages::COPY_SRC));
        let (reference, patterns) = (super::buffer_init(gpu, "reference", &super::to_device(gpu.precision, &b.reference), storage), super::buffer_init(gpu, "patterns", bytemuck::cast_slice(&b.patterns), storage));
        let pattern_of = super::buffer_init(gpu, "pattern of member", bytemuck::cast_slice(&b.pattern_start), storage);
        let u_factored = buffer(gpu, "u factored", dofs * real, storage | BufferUsages::COPY_SRC);
        let summarise = Pass::bound(
            gpu,
            pipelines.summary.clone(),
            ("newton_summary", "main"),
            None,
            &[
                ("motion", resident.begin_motion()),
                ("coefficients", coefficients),
                ("committed", resident.committed()),
                ("step", &b.step),
                ("reference", &reference),
                ("u", &b.u),
                ("dof_out", &b.dof_out),
                ("members", &b.member_buffer),
                ("jobs", &call),
                ("dispatch", &dispatch),
                ("summary", &summary),
                ("state", &state),
                ("member_energy", &member_energy),
                ("boxes", &boxes),
                ("committed_energy", resident.committed_energy()),
                ("rows", &rows),
            ],
        );
        let add_up = Pass::bound(gpu, pipelines.tally.clone(), ("newton_tally", "main"), None, &[("call", &call), ("dispatch", &dispatch), ("state", &state), ("rows", &rows), ("tally", &tally)]);
        let initial = NewtonState::<Real> { status: NEWTON_ITERATING, residual: Real::MAX, previous_residual: Real::MAX, ..NewtonState::default() };
        let initial_state = super::buffer_init(gpu, "initial newton state", bytemuck::cast_slice(&vec![initial; members]), BufferUsages::COPY_SRC);
        let no_failure = super::buffer_init(gpu, "no failure", bytemuck::cast_slice(&vec![NO_FAILURE; 2 * members]), BufferUsages::COPY_SRC);
        Ok(Self {
            initial_state,
            no_failure,
            start_runs: Vec::new(),
            call_host: Vec::new(),
            call_kept: 0,
            summarise,
            summary,
            boxes,
            rows,
            tally,
            add_up,
            patterns,
            pattern_of,
            u_factored,
            invert: None,
            inverse,
            free,
            free_of,
            newton,
            state,
            contact,
            x0,
            u_base,
            u_start,
            call,
            jobs,
            dispatch,
            forces,
            residual,
            energy,
            finish,
            member_energy,
            packed_forces,
            update,
            judge,
            compact,
            host_tangents: None,
            newton_host: vec![NewtonMember { residual_tolerance: Real::NAN, ..NewtonMember::default() }; members],
            // (wgpu zero-fills a new buffer: a run's first call sends no start displacements
            // and contact forces that are still zero)
            start_host: vec![0.0; dofs],
            contact_host: vec![0.0; dofs],
            inverse_version: vec![None; members],
            resident,
        })
    }
}

impl GpuWorld {
    /// Whether a body can take Newton iterations on the device: f64 kernels (f32 residuals
    /// could not meet the tolerances) and a slot for its `K̄⁻¹`.
    pub fn newton_capable(&self, body: usize) -> bool {
        let (b, m) = self.place[body];
        self.gpu.precision == Precision::F64 && self.batches[b].inverse_slot[m].is_some()
    }

    /// Whether the device holds `K̄⁻¹` of this version of a body's factorisation.
    pub fn newton_inverse_current(&self, body: usize, factor: u64) -> bool {
        let (b, m) = self.place[body];
        self.batches[b].newton.as_ref().is_some_and(|n| n.inverse_version[m] == Some(factor))
    }

    /// Newton iterations of the listed bodies on the device, each from its evaluated iterate
    /// until it converges, needs the host (its factorisation contracts too slowly, its budget is
    /// spent, a residual is not finite) or an element fails: eight iterations in the first
    /// submission, the rest of the budgets in a second if any body needs it. The bodies must be
    /// [`GpuWorld::newton_capable`]; `interrupt` is checked between submissions.
    ///
    /// The evaluation pass of other bodies (`list`, as [`GpuWorld::evaluate`] takes it) shares
    /// the first submission: a Newton round that evaluates the groups in contact and iterates
    /// the free bodies costs one submit. Calls without a residual ([`NewtonCall::residual`],
    /// all or none of them) are evaluated and judged first in that submission.
    ///
    /// Groups in contact (`contacts`, each with its problem in `problems`, their bodies' calls
    /// among `calls`, all in one batch, their problems solved whole by `uzawa_solve`) iterate
    /// in the same submissions: per increment `newton_contact`'s `prepare`, `uzawa_solve` and
    /// `forces` before the bodies' kernels, its `judge` after theirs. Their problems' reactions
    /// and outcomes come back with the states. `dim` and `theta_dt` are the scene's.
    #[allow(clippy::too_many_arguments)]
    pub fn newton(
        &mut self,
        calls: &mut [NewtonCall],
        problems: &mut [Problem],
        contacts: &mut [GroupContact],
        list: &mut [Evaluation],
        coefficients: Coefficients<Real>,
        (dim, theta_dt): (usize, Real),
        interrupt: Option<&AtomicBool>,
        times: &mut PhaseTimes,
    ) -> Result<(), GpuError> {
        let started = Instant::now();
        let precision = self.gpu.precision;
        assert_eq!(precision, Precision::F64, "device Newton iterations need f64 kernels");
        let coefficient_buffer = self.coefficients.clone();
        self.upload(&coefficient_buffer, 0, &to_device(precision, &[coefficients.factor, coefficients.c1, coefficients.motion]));
        let work = self.stage_calls(calls)?;
        let contact = if contacts.is_empty() { None } else { Some(self.stage_contact(calls, problems, contacts, dim, theta_dt)?) };
        // An increment's solve runs every sweep its problem may take, as the host's does, where
        // a software adapter's dispatches allow: a solve cut short hands its group back
        // (`judge`: its problem still live).
        let solves = match &self.contact {
            Some(sweeps) if contact.is_some() => sweeps.whole_dispatches(problems.iter().map(|p| p.max_iterations).max().unwrap_or(0)),
            _ => 0,
        };
        // The members of the groups in contact, `(call, member)`, whose tangents the device
        // computes when it hands them back.
        let in_contact = match &contact {
            Some((batch, _)) => self.stage_host_tangents(*batch, calls, contacts)?,
            None => Vec::new(),
        };
        let points = problems.iter().map(|p| p.local.len()).sum::<usize>();
        let target = self.newton_target(&work, list, contact.as_ref().map(|_| (points, contacts.len())));
        let plan = CallPlan { work: &work, contact: contact.as_ref(), solves, contacts: contacts.len(), refactor: contacts.iter().any(|g| g.refactor) };
        let mut t0 = started;
        let mut iterations = calls.iter().map(|c| c.member.budget.saturating_sub(c.taken)).max().unwrap_or(0).min(ITERATIONS_PER_SUBMIT);
        let evaluate_first = calls.first().is_some_and(|c| c.residual.is_none());
        assert!(calls.iter().all(|c| c.residual.is_none() == evaluate_first), "a call's members are all evaluated, or none");
        let mut first = true;
        // The last submission's tallies: they count every kept member that has converged.
        let mut tally = StepTally::default();
        loop {
            let mut encoder = None;
            let mut readback = ReadBack::default();
            let evaluated = if first { Some(self.record_evaluation(list, &mut encoder, &mut readback)?) } else { None };
            let mut encoder = encoder.unwrap_or_else(|| self.encoder("newton"));
            if first {
                self.record_call_start(&mut encoder, &work);
                self.record_inversions(&mut encoder, &work);
                self.record_delassus(&mut encoder, &plan);
            }
            self.record_iterations(&mut encoder, &plan, first && evaluate_first, iterations);
            let (landing, tallies) = self.queue_states(&mut readback, &work, calls, dim);
            let contact_landing = contact.as_ref().map(|(_, passes)| {
                let r = readback.queue_buffer(&self.contact.as_ref().expect("staged").buffers().r, (points * 3 * precision.size()) as u64);
                let states = readback.queue_buffer(&passes.states, (contacts.len() * std::mem::size_of::<ContactState<Real>>()) as u64);
                // The step lengths of the last W (`delassus`, or `rebuild` after a refactorisation
                // within the call).
                (r, states, readback.queue_buffer(&passes.step_lengths, (points * precision.size()) as u64))
            });
            let mut iterating = false;
            self.read_back_into(&target, encoder, &readback, "newton_update", times, t0, |bytes| {
                if let Some(landing) = &evaluated {
                    super::unpack_evaluation(precision, list, landing, bytes);
                }
                unpack_calls(precision, calls, (&landing, coefficients, dim), bytes);
                tally = StepTally::default();
                for &at in &tallies {
                    tally.add(&StepTally::of(&super::from_device(precision, &bytes[at..at + TALLY_LEN * precision.size()])));
                }
                iterating = calls.iter().any(|call| call.outcome.status == NEWTON_ITERATING);
                if let Some(at) = contact_landing {
                    unpack_contact(precision, problems, contacts, at, bytes);
                }
            })?;
            if evaluated.is_some() {
                self.note_handed_evaluations(list);
            }
            if let Some((batch, _)) = &contact {
                self.note_held_tangents(*batch, calls, &in_contact);
            }
            first = false;
            if !iterating || interrupt.is_some_and(|f| f.load(Ordering::SeqCst)) {
                break;
            }
            iterations = calls.iter().filter(|c| c.outcome.status == NEWTON_ITERATING).map(|c| c.member.budget - c.taken - c.outcome.iterations).max().unwrap_or(1);
            t0 = Instant::now();
        }
        self.take_unconverged(&work, calls, coefficients, times)?;
        self.step_tally.add(&tally);
        self.after_newton(&work, calls, contact.as_ref());
        Ok(())
    }

    /// Marks the members of groups in contact (`(call, member)` of `batch`) that the device
    /// handed back: it holds their tangents at the `u` returned ([`NewtonCall::tangent_held`]).
    /// A member that refactorised within the call holds the device's tangent of that iterate,
    /// which the host did not read, and a `K̄⁻¹` of no version of the host's until the host
    /// factorises there too ([`GpuWorld::note_factorized`]).
    fn note_held_tangents(&mut self, batch: usize, calls: &mut [NewtonCall], in_contact: &[(usize, usize)]) {
        let b = &mut self.batches[batch];
        for &(i, m) in in_contact {
            if calls[i].outcome.status == NEWTON_HOST {
                calls[i].tangent_held = true;
                b.handed[m] = Some(super::Held::HandBack);
            } else if calls[i].outcome.refactors > 0 {
                b.handed[m] = None;
            }
            if calls[i].outcome.refactors > 0 {
                b.newton.as_mut().expect("staged").inverse_version[m] = None;
            }
        }
    }

    /// The device's `K̄⁻¹` of a body is that of this version of its factorisations: one the
    /// device made within a Newton call ([`NewtonState::refactors`]), which the host numbers, or
    /// the host's own of it ([`GpuWorld::factored_at`]).
    pub fn note_factorized(&mut self, body: usize, factor: u64) {
        let (b, m) = self.place[body];
        if let Some(n) = self.batches[b].newton.as_mut() {
            n.inverse_version[m] = Some(factor);
        }
    }

    /// Makes a batch's Newton buffers unless it has them: with the world for a batch whose
    /// members can iterate on the device (so that their upload is the first step's, not that
    /// of the step in which a call first needs them), else when a call first needs them.
    pub(super) fn make_newton_buffers(&mut self, batch: usize) -> Result<(), GpuError> {
        if self.batches[batch].newton.is_some() {
            return Ok(());
        }
        if self.newton_pipelines.is_none() {
            self.newton_pipelines = Some(NewtonPipelines::new(&self.gpu)?);
        }
        let pipelines = self.newton_pipelines.as_ref().expect("made above");
        let made = NewtonBuffers::new(&self.gpu, pipelines, &self.batches[batch], &self.coefficients)?;
        // The templates of a call's start, the reference coordinates, each dof's free index and
        // each member's pattern start, once.
        let b = &self.batches[batch];
        self.traffic.up += (b.members.len() * (std::mem::size_of::<NewtonState<Real>>() + 12) + b.reference.len() * self.gpu.precision.size() + 4 * b.u_host.len()) as u64;
        self.batches[batch].newton = Some(made);
        Ok(())
    }

    /// Makes each batch's Newton buffers when a call first needs them and stages the calls,
    /// batch by batch.
    fn stage_calls(&mut self, calls: &mut [NewtonCall]) -> Result<Vec<BatchCalls>, GpuError> {
        // An unevaluated call of a body whose step the device began starts from the device's
        // predictor.
        let predicted = |c: &NewtonCall| {
            let (b, m) = self.place[c.body];
            c.residual.is_none() && self.batches[b].newton.as_ref().is_some_and(|n| n.resident.predicted[m])
        };
        let kept: Vec<bool> = calls.iter().map(predicted).collect();
        // Only a step the device began can end there: the summary reads its committed state.
        for (call, &predicted) in calls.iter_mut().zip(&kept) {
            call.keep &= predicted;
        }
        let by_batch = self.stage_displacements_but(&calls.iter().map(|c| (c.body, &*c.u)).collect::<Vec<_>>(), &|i| kept[i]);
        let mut work: Vec<BatchCalls> = Vec::with_capacity(by_batch.len());
        for (batch, mine) in by_batch {
            self.make_newton_buffers(batch)?;
            let mine: Vec<(usize, usize)> = mine.into_iter().map(|i| (i, self.place[calls[i].body].1)).collect();
            let energy = self.stage_newton(batch, &mine, calls);
            work.push((batch, mine, energy));
        }
        Ok(work)
    }

    /// The read-back buffer of a call, grown when its submissions need more: per member its
    /// failure flags and state, per dof its displacement and internal force, its strain energy
    /// (every span a multiple of 8 bytes), after an evaluation pass's read-back when one shares
    /// it; with groups in contact (`(points, groups)`) their reactions, states and step lengths.
    fn newton_target(&mut self, work: &[BatchCalls], list: &[Evaluation], contact: Option<ContactTarget>) -> Buffer {
        let real = self.gpu.precision.size();
        let total = |f: fn(&crate::gpu::types::MemberRange) -> u32| -> usize { work.iter().map(|(b, mine, _)| mine.iter().map(|&(_, m)| f(&self.batches[*b].members[m]) as usize).sum::<usize>()).sum() };
        let total_dofs = total(|r| r.dofs);
        let total_members: usize = work.iter().map(|(_, mine, _)| mine.len()).sum();
        // (their reactions, states and step lengths)
        let contact_bytes = contact.map_or(0, |(points, groups)| (points * 4 * real + groups * std::mem::size_of::<ContactState<Real>>() + 24) as u64);
        let per_member = 16 + std::mem::size_of::<NewtonState<Real>>() + summary_len(3) * real + 6 * 4;
        // (a kept call's displacements fit in the room of another's displacements and forces)
        let tallies = work.len() * TALLY_LEN * real;
        let bytes = (total_members * per_member + total_dofs * 2 * real + tallies) as u64 + if list.is_empty() { 0 } else { self.readback.size() } + contact_bytes;
        self.newton_target_of(bytes)
    }

    /// The read-back buffer of device Newton calls, grown to at least `bytes`.
    pub(super) fn newton_target_of(&mut self, bytes: u64) -> Buffer {
        if self.newton_readback.as_ref().is_none_or(|(_, size)| *size < bytes) {
            self.newton_readback = Some((buffer(&self.gpu, "newton readback", bytes as usize, BufferUsages::MAP_READ | BufferUsages::COPY_DST), bytes));
        }
        self.newton_readback.as_ref().expect("made above").0.clone()
    }

    /// Records a call's start on the device, before its first submission's passes: the list of
    /// members the iterations run over, a copy of the call's; the initial states and cleared
    /// failure flags of unevaluated members, copies of the templates.
    fn record_call_start(&self, encoder: &mut wgpu::CommandEncoder, work: &[BatchCalls]) {
        let state = std::mem::size_of::<NewtonState<Real>>() as u64;
        for (batch, mine, _) in work {
            let (b, n) = (&self.batches[*batch], self.batches[*batch].newton.as_ref().expect("staged"));
            encoder.copy_buffer_to_buffer(&n.call, 0, &n.jobs, 0, 8 * mine.len() as u64);
            for &(first, count) in &n.start_runs {
                encoder.copy_buffer_to_buffer(&n.initial_state, first as u64 * state, &n.state, first as u64 * state, count as u64 * state);
                encoder.copy_buffer_to_buffer(&n.no_failure, 8 * first as u64, &b.failure, 8 * first as u64, 8 * count as u64);
            }
        }
    }

    /// Records the inversions the call staged (`newton_invert`), before its iterations read
    /// the inverses.
    fn record_inversions(&mut self, encoder: &mut wgpu::CommandEncoder, work: &[BatchCalls]) {
        let staged: Vec<(Pass, u32)> = work.iter().filter_map(|(batch, _, _)| self.batches[*batch].newton.as_mut().and_then(|n| n.invert.take())).collect();
        if staged.is_empty() {
            return;
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("newton invert"), timestamp_writes: None });
        for (invert, count) in &staged {
            invert.dispatch(&self.gpu, &mut pass, *count);
        }
    }

    /// Records the Delassus blocks of the call's groups in contact (`newton_contact`'s
    /// `delassus`), from the inverses the call's inversions made, after the frames went up.
    fn record_delassus(&self, encoder: &mut wgpu::CommandEncoder, plan: &CallPlan) {
        let (Some((_, passes)), Some(pipelines)) = (plan.contact, self.contact_pipelines.as_ref()) else { return };
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("newton delassus"), timestamp_writes: None });
        self.contact.as_ref().expect("staged").record_unpack(&mut pass);
        passes.record_delassus(&self.gpu, &mut pass, pipelines);
    }

    /// Records one submission's compute pass: the members' first evaluation and its test when
    /// they come unevaluated (`evaluate_first`), `iterations` Newton iterations, the tangents of
    /// the members in contact handed back, and the members' energies.
    fn record_iterations(&self, encoder: &mut wgpu::CommandEncoder, plan: &CallPlan, evaluate_first: bool, iterations: u32) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("newton"), timestamp_writes: None });
        let pipelines = self.contact_pipelines.as_ref();
        let contact_of = |batch: usize| plan.contact.filter(|(at, _)| *at == batch).map(|(_, passes)| passes);
        // The frames, where they went up planar, before anything reads them (none left after
        // the call's first submission: `record_delassus`).
        if plan.contact.is_some() {
            self.contact.as_ref().expect("staged").record_unpack(&mut pass);
        }
        // The members' first evaluation and its convergence test: `newton_judge` from a state
        // without a residual before (`Real::MAX`) and without an increment tests it as
        // `Body::converged` tests a step's first evaluation. Groups in contact:
        // `newton_contact`'s `first_forces` (the contact forces of the reactions the step starts
        // from) before the test and `first_judge` (the group's verdict, the law at the
        // reactions) after it.
        if evaluate_first {
            for (batch, _, _) in plan.work {
                let n = self.batches[*batch].newton.as_ref().expect("staged");
                let mine = contact_of(*batch);
                n.forces.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 12);
                n.residual.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 24);
                if let (Some(c), Some(p)) = (mine, pipelines) {
                    c.record_first_forces(&self.gpu, &mut pass, p);
                }
                n.judge.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 36);
                if let (Some(c), Some(p)) = (mine, pipelines) {
                    c.record_first_judge(&self.gpu, &mut pass, p);
                }
                n.compact.dispatch(&self.gpu, &mut pass, 1);
            }
        }
        for _ in 0..iterations {
            for (batch, _, _) in plan.work {
                let n = self.batches[*batch].newton.as_ref().expect("staged");
                let mine = contact_of(*batch);
                if let (Some(c), Some(p)) = (mine, pipelines) {
                    c.record_prepare(&self.gpu, &mut pass, p);
                    for _ in 0..plan.solves {
                        self.contact.as_ref().expect("staged").record_solve(&mut pass, plan.contacts);
                    }
                    c.record_forces(&self.gpu, &mut pass, p);
                }
                n.update.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 0);
                n.forces.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 12);
                n.residual.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 24);
                n.judge.dispatch_indirect(&self.gpu, &mut pass, &n.dispatch, 36);
                if let (Some(c), Some(p)) = (mine, pipelines) {
                    c.record_judge(&self.gpu, &mut pass, p);
                    // The members the verdicts send to REFACTOR: K̄⁻¹ at this iterate and their
                    // groups' W again, before the next iteration's list.
                    if plan.refactor {
                        n.host_tangents.as_ref().expect("staged").record_refactor(&self.gpu, &mut pass);
                        c.record_rebuild(&self.gpu, &mut pass, p);
                    }
                }
                n.compact.dispatch(&self.gpu, &mut pass, 1);
            }
        }
        if let Some((batch, _)) = plan.contact {
            let h = self.batches[*batch].newton.as_ref().and_then(|n| n.host_tangents.as_ref()).expect("staged");
            h.compact.dispatch(&self.gpu, &mut pass, 1);
            h.tangent.dispatch_indirect(&self.gpu, &mut pass, &h.dispatch, 0);
            h.csr.dispatch_indirect(&self.gpu, &mut pass, &h.dispatch, 12);
        }
        for (batch, mine, energy) in plan.work {
            let n = self.batches[*batch].newton.as_ref().expect("staged");
            n.energy.dispatch_xyz(&self.gpu, &mut pass, *energy);
            n.finish.dispatch(&self.gpu, &mut pass, mine.len().div_ceil(WORKGROUP) as u32);
            n.summarise.dispatch(&self.gpu, &mut pass, mine.len().div_ceil(WORKGROUP) as u32);
            n.add_up.dispatch(&self.gpu, &mut pass, 1);
        }
    }

    /// Queues each call's state and strain energy, and its failure flags, displacements and
    /// internal forces, or (a kept call, `dim` the scene's) its summary, and per batch with kept
    /// calls their tally; returns per call where they land, and where the tallies land.
    fn queue_states(&self, readback: &mut ReadBack, work: &[BatchCalls], calls: &[NewtonCall], dim: usize) -> (Vec<Landing>, Vec<usize>) {
        let real = self.gpu.precision.size();
        let mut landing = vec![Landing::default(); calls.len()];
        let mut tallies = Vec::new();
        for (batch, mine, _) in work {
            let (kept, others): (Vec<_>, Vec<_>) = mine.iter().partition(|&&(i, _)| calls[i].keep);
            for (&(i, _), at) in others.iter().zip(self.queue_state_and_energy(readback, *batch, &others)) {
                landing[i].state_and_energy = Some(at);
            }
            let iterates = self.queue_iterates(readback, *batch, &others);
            let summary_span = |m: usize| (m * summary_len(dim) * real) as u64..((m + 1) * summary_len(dim) * real) as u64;
            let kept_members: Vec<usize> = kept.iter().map(|&(_, m)| m).collect();
            if !kept.is_empty() {
                tallies.push(readback.queue(*batch, Source::Tally, 0..(TALLY_LEN * real) as u64) as usize);
            }
            let summaries = readback.queue_runs(*batch, Source::Summary, &kept_members, &summary_span);
            let box_span = |m: usize| (m * 8 * dim) as u64..((m + 1) * 8 * dim) as u64;
            let boxes = readback.queue_runs(*batch, Source::Boxes, &kept_members, &box_span);
            for (&(i, _), at) in others.iter().zip(iterates) {
                landing[i].iterate = Some(at);
            }
            for ((&(i, _), at), b) in kept.iter().zip(summaries).zip(boxes) {
                landing[i].summary = Some((at, b));
            }
            let placed: Vec<(usize, usize)> = kept.iter().copied().filter(|&(i, _)| calls[i].positions).collect();
            let b = &self.batches[*batch];
            let per_dof = |m: usize| {
                let dofs = super::dof_span(&b.members, &[m]);
                (dofs.start * real) as u64..(dofs.end * real) as u64
            };
            for (&(i, _), at) in placed.iter().zip(readback.queue_runs(*batch, Source::Displacement, &placed.iter().map(|&(_, m)| m).collect::<Vec<_>>(), &per_dof)) {
                landing[i].positions = Some(at);
            }
        }
        (landing, tallies)
    }

    /// Queues the Newton states and strain energies of the listed calls `(call, member)` of a
    /// batch (in member order); returns where each call's land.
    fn queue_state_and_energy(&self, readback: &mut ReadBack, batch: usize, mine: &[(usize, usize)]) -> Vec<(usize, usize)> {
        let real = self.gpu.precision.size();
        let members: Vec<usize> = mine.iter().map(|&(_, m)| m).collect();
        let state_size = std::mem::size_of::<NewtonState<Real>>() as u64;
        let state_span = |m: usize| m as u64 * state_size..(m as u64 + 1) * state_size;
        let states = readback.queue_runs(batch, Source::NewtonState, &members, &state_span);
        let energy_span = |m: usize| (m * real) as u64..((m + 1) * real) as u64;
        let energies = readback.queue_runs(batch, Source::MemberEnergy, &members, &energy_span);
        states.into_iter().zip(energies).collect()
    }

    /// Queues the failure flags, displacements and internal forces of the listed calls `(call,
    /// member)` of a batch (in member order); returns where each call's land.
    fn queue_iterates(&self, readback: &mut ReadBack, batch: usize, mine: &[(usize, usize)]) -> Vec<[usize; 3]> {
        let real = self.gpu.precision.size();
        let b = &self.batches[batch];
        let members: Vec<usize> = mine.iter().map(|&(_, m)| m).collect();
        let flag_span = |m: usize| 8 * m as u64..8 * (m as u64 + 1);
        let flags = readback.queue_runs(batch, Source::Failure, &members, &flag_span);
        let per_dof = |m: usize| {
            let dofs = super::dof_span(&b.members, &[m]);
            (dofs.start * real) as u64..(dofs.end * real) as u64
        };
        let us = readback.queue_runs(batch, Source::Displacement, &members, &per_dof);
        let outs = readback.queue_runs(batch, Source::NewtonForces, &members, &per_dof);
        (0..mine.len()).map(|k| [flags[k], us[k], outs[k]]).collect()
    }

    /// The displacements and forces of the kept calls that did not converge on the device (the
    /// host goes on with them), in one submission after the call's; each such call is no
    /// longer kept.
    fn take_unconverged(&mut self, work: &[BatchCalls], calls: &mut [NewtonCall], coefficients: Coefficients<Real>, times: &mut PhaseTimes) -> Result<(), GpuError> {
        let wanted = |c: &NewtonCall| c.keep && c.outcome.status != NEWTON_CONVERGED;
        if !calls.iter().any(wanted) {
            return Ok(());
        }
        let mut readback = ReadBack::default();
        let mut landing: Vec<(usize, [usize; 3], (usize, usize))> = Vec::new();
        for (batch, mine, _) in work {
            let theirs: Vec<(usize, usize)> = mine.iter().copied().filter(|&(i, _)| wanted(&calls[i])).collect();
            let states = self.queue_state_and_energy(&mut readback, *batch, &theirs);
            let at = self.queue_iterates(&mut readback, *batch, &theirs);
            landing.extend(theirs.iter().zip(at).zip(states).map(|((&(i, _), at), state)| (i, at, state)));
        }
        let target = self.newton_target_of(readback.end);
        let encoder = self.encoder("newton iterates");
        let precision = self.gpu.precision;
        self.read_back_into(&target, encoder, &readback, "newton_update", times, Instant::now(), |bytes| {
            for &(i, at, (state, energy)) in &landing {
                calls[i].keep = false;
                // The whole state: the host goes on from the device's last increment.
                calls[i].outcome = bytemuck::pod_read_unaligned(&bytes[state..state + std::mem::size_of::<NewtonState<Real>>()]);
                calls[i].outcome.iterations -= calls[i].taken;
                calls[i].strain_energy = Some(super::from_device(precision, &bytes[energy..energy + precision.size()])[0]);
                unpack_iterate(precision, &mut calls[i], at, coefficients, bytes);
            }
        })
    }

    /// The displacements at which the device last refactorised each of `bodies` within a
    /// Newton call ([`NewtonState::refactors`]), in one submission: where the host makes the
    /// same factorisation when it needs its own (its next increment, a saved state), not after
    /// every call.
    pub fn factored_at(&mut self, bodies: &[usize], times: &mut PhaseTimes) -> Result<Vec<Vec<Real>>, GpuError> {
        let real = self.gpu.precision.size();
        let mut readback = ReadBack::default();
        let at: Vec<(usize, usize)> = bodies
            .iter()
            .map(|&body| {
                let (b, m) = self.place[body];
                let dofs = super::dof_span(&self.batches[b].members, &[m]);
                (readback.queue(b, Source::Factored, (dofs.start * real) as u64..(dofs.end * real) as u64) as usize, dofs.len())
            })
            .collect();
        let target = self.newton_target_of(readback.end);
        let encoder = self.encoder("factored at");
        let precision = self.gpu.precision;
        let mut out = Vec::with_capacity(bodies.len());
        self.read_back_into(&target, encoder, &readback, "newton_invert", times, Instant::now(), |bytes| {
            out = at.iter().map(|&(at, n)| super::from_device(precision, &bytes[at..at + n * real])).collect();
        })?;
        Ok(out)
    }

    /// After a call: the device's displacements are the host's now, and the mirror follows, so
    /// that the next pass does not send them back. The contact forces the device computed for
    /// the groups in contact (`contact`: their batch and passes) are not the host's: those at
    /// their nodes in contact go up again next time, the rest are as they went up.
    fn after_newton(&mut self, work: &[BatchCalls], calls: &[NewtonCall], contact: Option<&(usize, ContactPasses)>) {
        for (batch, mine, _) in work {
            let b = &mut self.batches[*batch];
            let known = |c: &NewtonCall| !c.keep || c.positions;
            let spans = mine.iter().filter(|&&(i, _)| known(&calls[i])).map(|&(i, m)| (b.members[m].dof_start as usize, &*calls[i].u)).collect();
            super::update_mirrors(&mut b.u_host, spans);
            // A kept call's iterate is the device's alone, unless its displacements came back.
            for &(_, m) in mine.iter().filter(|&&(i, _)| !known(&calls[i])) {
                let dofs = super::dof_span(&b.members, &[m]);
                b.u_host[dofs].fill(Real::NAN);
            }
            // The residuals at an iterate that came back are the host's from the device's forces,
            // as `assemble_residual` computed them there; a kept call's are the device's alone.
            for &(i, m) in mine {
                let came_back = calls[i].failure.is_none() && !calls[i].keep;
                b.note_residuals(m, came_back.then_some(&*calls[i].dof_out));
                let resident = &mut b.newton.as_mut().expect("staged").resident;
                match calls[i].failure {
                    None => resident.took(m),
                    Some(_) => resident.touched(m),
                }
            }
        }
        if let Some((batch, passes)) = contact {
            let (written, dim) = &passes.written;
            let host = &mut self.batches[*batch].newton.as_mut().expect("staged").contact_host;
            for &d in written {
                host[d as usize..d as usize + dim].fill(Real::NAN);
            }
        }
    }

    /// Stages the groups in contact of a Newton call: their problems into the Uzawa solve's
    /// buffers, each member's `u_t + dt (1 - θ) v_t`, the layout `newton_contact` reads. Returns
    /// their batch and the bound passes.
    fn stage_contact(&mut self, calls: &[NewtonCall], problems: &[Problem], contacts: &[GroupContact], dim: usize, theta_dt: Real) -> Result<(usize, ContactPasses), GpuError> {
        let batch = self.place[calls[contacts[0].calls[0]].body].0;
        assert!(contacts.iter().flat_map(|g| &g.calls).all(|&c| self.place[calls[c].body].0 == batch), "a call's groups in contact lie in one batch");
        if self.contact.is_none() {
            self.contact = Some(UzawaSweeps::new(self.gpu.clone())?);
        }
        if self.contact_pipelines.is_none() {
            self.contact_pipelines = Some(ContactPipelines::new(&self.gpu)?);
        }
        let sweeps = self.contact.as_mut().expect("made above");
        let most = problems.iter().map(|p| p.max_iterations).max().unwrap_or(0);
        let whole = sweeps.stage(problems, most, true).ok_or_else(|| GpuError::Kernel { kernel: "uzawa_solve".into(), message: "the contact problems do not fit the device's buffers".into() })?;
        assert!(whole, "groups in contact iterate on the device only with problems solved whole");
        let precision = self.gpu.precision;
        let real = precision.size() as u64;
        let b = &self.batches[batch];
        let layout = ContactLayout::of(contacts, problems, sweeps.staged_nodes(), &|c| self.place[calls[c].body].1 as u32, &|m| b.members[m as usize].dof_start, dim, theta_dt);
        let mut up = 0;
        let n = b.newton.as_ref().expect("made before staging");
        let passes = ContactPasses::new(&self.gpu, self.contact_pipelines.as_ref().expect("made above"), &layout, b, n, sweeps.buffers(), &mut up);
        // Each member's `u_base`, one write per run of consecutive members (every grain of a
        // packing in contact: one write, not one per grain). Device Newton iterations run in
        // f64 only: the host's reals are the device's bytes.
        debug_assert_eq!(precision, Precision::F64);
        // A member whose step began on the device has the step's there already.
        let resident = &n.resident;
        let mut bases: Vec<(usize, &[u8])> = contacts.iter().flat_map(|g| g.calls.iter().zip(&g.u_base).map(|(&c, base)| (self.place[calls[c].body].1, bytemuck::cast_slice(base)))).filter(|&(m, _)| !resident.began_on_device(m)).collect();
        bases.sort_unstable_by_key(|&(m, _)| m);
        let u_base = n.u_base.clone();
        self.upload_member_runs(batch, &u_base, real, &bases);
        self.traffic.up += up;
        Ok((batch, passes))
    }

    /// Stages the tangents of the members of a call's groups in contact (all in `batch`) that
    /// the device hands back ([`HostTangents`]): their list, in mode TANGENT, and the
    /// dispatches' extent. Returns those members, `(call, member)` in member order.
    fn stage_host_tangents(&mut self, batch: usize, calls: &[NewtonCall], contacts: &[GroupContact]) -> Result<Vec<(usize, usize)>, GpuError> {
        self.batches[batch].tangent.ready()?;
        let b = &self.batches[batch];
        let n = b.newton.as_ref().expect("made before staging");
        if n.host_tangents.is_none() {
            let super::Deferred::Ready(tangent) = &b.tangent else { unreachable!("made ready above") };
            let made = HostTangents::new(&self.gpu, self.newton_pipelines.as_ref().expect("made with the batch's buffers"), b, tangent, (n, &self.coefficients));
            self.batches[batch].newton.as_mut().expect("made before staging").host_tangents = Some(made);
        }
        let mut mine: Vec<(usize, usize)> = contacts.iter().flat_map(|g| &g.calls).map(|&c| (c, self.place[calls[c].body].1)).collect();
        mine.sort_unstable_by_key(|&(_, m)| m);
        let b = &self.batches[batch];
        let list: Vec<Active> = mine.iter().map(|&(_, m)| Active { member: m as u32, mode: MODE_TANGENT }).collect();
        let most = |f: fn(&crate::gpu::types::MemberRange) -> u32| mine.iter().map(|&(_, m)| f(&b.members[m]) as usize).max().unwrap_or(0);
        let (tx, ty) = crate::gpu::dispatch_rows(most(|r| r.elements).div_ceil(b.tangent_elements_per_group));
        let (cx, cy) = crate::gpu::dispatch_rows(most(|r| r.nonzeros).div_ceil(WORKGROUP));
        let dispatch: [u32; DISPATCH_WORDS] = [tx, ty, 0, cx, cy, 0, 1, 1, 0, 1, 1, 0, list.len() as u32, 0];
        let h = b.newton.as_ref().and_then(|n| n.host_tangents.as_ref()).expect("made above");
        let (call, arguments) = (h.call.clone(), h.dispatch.clone());
        self.upload(&call, 0, bytemuck::cast_slice(&list));
        self.upload(&arguments, 0, bytemuck::cast_slice(&dispatch));
        Ok(mine)
    }

    /// Uploads what the listed calls (`(call, member)`, member order) of one batch need: stale
    /// inverses, parameters, initial states, start displacements, evaluated residuals, the
    /// call's list and the first iteration's dispatch arguments; clears their failure flags.
    /// Returns the workgroups of `element_energy` over the call's list.
    fn stage_newton(&mut self, batch: usize, mine: &[(usize, usize)], calls: &mut [NewtonCall]) -> [u32; 3] {
        let precision = self.gpu.precision;
        let real = precision.size() as u64;
        let mut uploads: Vec<(Buffer, u64, Vec<u8>)> = Vec::new();
        let b = &mut self.batches[batch];
        let n = b.newton.as_mut().expect("made before staging");
        let mut states = Vec::with_capacity(mine.len());
        let mut changed = Vec::new();
        let mut new = NewInverses::default();
        // (none left from a call that did not run)
        n.invert = None;
        for &(i, m) in mine {
            let call = &mut calls[i];
            let slot = b.inverse_slot[m].expect("a capable body has an inverse slot");
            let (free_start, free_count) = b.free_range[m];
            if let Some(inverse) = call.inverse.take() {
                // `K̄ = ξ K + c1 M` differs from the stiffness values the device holds on the
                // diagonal only: where those are the ones the host read back, the rest stays.
                let diagonal = match (&inverse, b.handed[m]) {
                    (Inverse::Effective(values), Some(super::Held::Read(print))) if off_diagonal_print(values, &b.patterns, b.pattern_start[m], free_count as usize) == print => {
                        Some(diagonal_of(values, &b.patterns, b.pattern_start[m], free_count as usize))
                    }
                    (Inverse::AtHandBack(values), Some(super::Held::HandBack)) => Some(diagonal_of(values, &b.patterns, b.pattern_start[m], free_count as usize)),
                    _ => None,
                };
                new.add(inverse, [packed_len(free_count as usize), b.members[m].nonzeros as usize], slot as u64 * real, (m, b.pattern_start[m]), diagonal);
                n.inverse_version[m] = Some(call.factor);
            }
            let member = NewtonMember { inverse_start: slot, free_start, free_count, ..call.member };
            // The device reads a member's parameters only: those it holds need not go up again
            // (a grain in flight keeps its tolerances from step to step).
            if !same_bits(&[member], &n.newton_host[m..=m]) {
                n.newton_host[m] = member;
                changed.push(m);
            }
            let residual = call.residual.unwrap_or(Real::MAX);
            // (an unevaluated call starts its step: the device's template counts none)
            debug_assert!(call.residual.is_some() || call.taken == 0);
            states.push(NewtonState { status: NEWTON_ITERATING, iterations: call.taken, residual, previous_residual: residual, ..NewtonState::default() });
        }
        let members: Vec<usize> = mine.iter().map(|&(_, m)| m).collect();
        let member_size = std::mem::size_of::<NewtonMember<Real>>() as u64;
        let state_size = std::mem::size_of::<NewtonState<Real>>() as u64;
        let mut k = 0;
        for run in super::runs(&changed) {
            let first = run[0] as u64;
            uploads.push((n.newton.clone(), first * member_size, bytemuck::cast_slice(&n.newton_host[run[0]..=*run.last().expect("a run has members")]).to_vec()));
        }
        // Unevaluated calls start from the same state, which the device copies from its own
        // template with the failure flags' (`record_call_start`); evaluated ones from the host's
        // residuals.
        n.start_runs.clear();
        let unevaluated = mine.iter().all(|&(i, _)| calls[i].residual.is_none());
        for run in super::runs(&members) {
            let first = run[0] as u64;
            if unevaluated {
                n.start_runs.push((run[0], run.len()));
            } else {
                uploads.push((n.state.clone(), first * state_size, bytemuck::cast_slice(&states[k..k + run.len()]).to_vec()));
                uploads.push((b.failure.clone(), 8 * first, bytemuck::cast_slice(&vec![NO_FAILURE; 2 * run.len()]).to_vec()));
            }
            k += run.len();
        }
        // The slots of the list that changed go up (a packing in flight calls the same grains
        // step after step); the device copies it into the iterations' list. The kept calls come
        // first: `newton_summary` and `newton_tally` take those.
        let (kept, others): (Vec<_>, Vec<_>) = mine.iter().partition(|&&(i, _)| calls[i].keep);
        let (kept, others): (Vec<usize>, Vec<usize>) = (kept.iter().map(|&&(_, m)| m).collect(), others.iter().map(|&&(_, m)| m).collect());
        let list = arrange((&n.call_host, n.call_kept), &kept, &others);
        let changed: Vec<usize> = (0..list.len()).filter(|&k| n.call_host.get(k) != Some(&list[k])).collect();
        for run in super::runs(&changed) {
            uploads.push((n.call.clone(), 8 * run[0] as u64, bytemuck::cast_slice(&list[run[0]..=run[run.len() - 1]]).to_vec()));
        }
        (n.call_host, n.call_kept) = (list, kept.len());
        let list = &n.call_host;
        let count = list.len() as u32;
        let most = |f: fn(&crate::gpu::types::MemberRange) -> u32| members.iter().map(|&m| f(&b.members[m]) as usize).max().unwrap_or(0);
        let (fx, fy) = crate::gpu::dispatch_rows(most(|r| r.elements).div_ceil(WORKGROUP));
        let (rx, ry) = crate::gpu::dispatch_rows(most(|r| r.dofs).div_ceil(WORKGROUP));
        let dispatch: [u32; DISPATCH_WORDS] = [1, 1, count, fx, fy, count, rx, ry, count, 1, 1, count, count, kept.len() as u32];
        debug_assert_eq!((DISPATCHES * 3, DISPATCHES * 3 + 2), (CALL_COUNT, DISPATCH_WORDS));
        uploads.push((n.dispatch.clone(), 0, bytemuck::cast_slice(&dispatch).to_vec()));
        let inverse = n.inverse.clone();
        if !new.inversions.is_empty() {
            let pipeline = self.newton_pipelines.as_ref().expect("made with the batch's buffers").invert.clone();
            let (pass, values, jobs) = new.invert_pass(&self.gpu, pipeline, n, (&b.values, &b.member_buffer));
            n.invert = Some((pass, new.inversions.len() as u32));
            uploads.push((values, 0, bytemuck::cast_slice(&new.effective).to_vec()));
            uploads.push((jobs, 0, bytemuck::cast_slice(&new.inversions).to_vec()));
        }
        for (buffer, offset, bytes) in uploads {
            self.upload(&buffer, offset, &bytes);
        }
        // The start displacements and contact forces (zero for a call without them); those
        // that changed go up.
        let zeros = vec![0.0; mine.iter().filter(|&&(i, _)| calls[i].contact_force.is_none()).map(|&(i, _)| calls[i].u.len()).max().unwrap_or(0)];
        let starts: Vec<(usize, &[Real])> = mine.iter().map(|&(i, m)| (m, calls[i].u_start)).collect();
        let contacts: Vec<(usize, &[Real])> = mine.iter().map(|&(i, m)| (m, calls[i].contact_force.unwrap_or_else(|| &zeros[..calls[i].u.len()]))).collect();
        self.stage_mirror(batch, super::Mirror::NewtonStart, &starts);
        self.stage_mirror_by_dof(batch, super::Mirror::NewtonContact, &contacts);
        // Device Newton iterations run in f64 only (asserted by `newton`): the host's reals are
        // the device's bytes.
        debug_assert_eq!(precision, Precision::F64);
        for (offset, _, run) in new.runs {
            self.upload_pieces(&inverse, offset, &run.iter().map(|x| bytemuck::cast_slice(x)).collect::<Vec<&[u8]>>());
        }
        // Members evaluated on the host side of the call: their results; the others' the
        // device computes first. Those the device holds already (its own evaluation, read back or
        // taken from its last call's forces) stay.
        let evaluated: Vec<(usize, &[Real])> = mine.iter().filter(|&&(i, _)| calls[i].residual.is_some()).map(|&(i, m)| (m, bytemuck::cast_slice::<DofOut<Real>, Real>(calls[i].dof_out))).collect();
        self.stage_mirror(batch, super::Mirror::Residual, &evaluated);
        [fx, fy, count]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn members(list: &[Active]) -> Vec<u32> {
        list.iter().map(|a| a.member).collect()
    }

    #[test]
    fn a_call_list_that_loses_and_gains_members_changes_in_their_slots_only() {
        // Issue 59: the call's list went up whole when a grain left it (a grain that lands),
        // 8 bytes a grain of the batch. Kept members first, each part keeping its slots.
        let previous = arrange((&[], 0), &[0, 1, 2, 3, 4, 5], &[6]);
        assert_eq!(members(&previous), [0, 1, 2, 3, 4, 5, 6]);
        // Member 1 lands (no longer kept, not called), 7 joins the others.
        let next = arrange((&previous, 6), &[0, 2, 3, 4, 5], &[6, 7]);
        assert_eq!(members(&next), [0, 5, 2, 3, 4, 6, 7], "the kept part's last takes the slot that was left");
        let changed = (0..next.len()).filter(|&k| previous.get(k) != Some(&next[k])).count();
        assert_eq!(changed, 3, "slot 1, and the two of the others, which moved up by one and grew");
        // The same members again: nothing changes.
        assert_eq!(arrange((&next, 5), &[0, 2, 3, 4, 5], &[6, 7]), next);
        // A kept member becomes one of the others.
        let moved = arrange((&next, 5), &[0, 2, 3, 4], &[5, 6, 7]);
        assert_eq!(members(&moved), [0, 4, 2, 3, 6, 7, 5]);
        assert!(moved.iter().all(|a| a.mode == MODE_FORCES));
    }
}
