//! The contact of groups that take their Newton iterations on the device
//! ([`GpuWorld::newton`] with [`GroupContact`]s): the layout `shaders/newton_contact.wgsl` reads
//! (built on the host once per call, from the problems as `uzawa_solve` holds them), and its
//! buffers and bind groups.

use super::{buffer_init, Batch};
use crate::contact::uzawa::{Delassus, NodalMap, Problem};
use crate::gpu::types::{ContactCall, ContactGroup, ContactState, NEWTON_WORKGROUP};
use crate::gpu::uzawa_sweep::{Buffers as UzawaBuffers, NodeGather};
use crate::gpu::Gpu;
use crate::precision::Real;
use wgpu::{BindGroup, Buffer, BufferUsages, ComputePipeline};

/// One group in contact whose Newton iterations go to the device with its bodies' calls, beside
/// its contact problem as the host prepared it for the step (W, colours, points, their step
/// lengths, the Uzawa tolerance), whose reactions the call leaves at those of the last
/// increment.
pub struct GroupContact<'a> {
    /// Its bodies' indices in the call list, in the group's body order (the local body
    /// numbers of `slot_nodes`).
    pub calls: Vec<usize>,
    /// Per node slot of the problem's nodal map: (body in the group, node).
    pub slot_nodes: &'a [(u32, u32)],
    /// Per point, the obstacle's velocity at the end of the step (global).
    pub obstacle: Vec<[Real; 3]>,
    /// Per body (group order), `u_t + dt (1 - θ) v_t`: the trial velocity is
    /// `(u - u_base) / θdt`.
    pub u_base: Vec<Vec<Real>>,
    /// `contact.tolerance`.
    pub tolerance: Real,
    /// The floor of its reactions per unit step length (`ContactStep::velocity_scale`), and
    /// whether its step lengths are those of Jacobi sweeps.
    pub velocity_scale: Real,
    pub jacobi: bool,
    /// Whether a member whose residual contracts too slowly refactorises within the call (the
    /// device's `K̄⁻¹` from its tangent there, and W again) rather than handing the group back:
    /// where the device can invert every member's `K̄` ([`crate::gpu::GpuWorld::inverts`]).
    pub refactor: bool,
    /// In: its Uzawa stalls so far in the step (`stalls`, the rest zero); out: where its
    /// contact stood after the last increment.
    pub outcome: ContactState<Real>,
    /// Out: its points' step lengths, from the W the device built (`newton_contact`'s
    /// `delassus`).
    pub step_lengths: Vec<Real>,
}

/// What `newton_contact` reads of a call's groups, besides the batch's buffers and the Uzawa
/// solve's (the problems, the node gather and the frames): the host copy, and the CPU twins'
/// input.
#[derive(Debug, Clone, Default)]
pub struct ContactLayout {
    pub groups: Vec<ContactGroup<Real>>,
    /// Batch member indices, each group's in a run (its leader first).
    pub group_members: Vec<u32>,
    /// Point `i`'s terms: `(node slot, coefficient)` for `e` in `term_start[i]..term_start[i + 1]`.
    pub term_start: Vec<u32>,
    pub term_slots: Vec<u32>,
    pub term_coefs: Vec<Real>,
    /// Per point, the obstacle's end velocity, 3 reals.
    pub obstacle: Vec<Real>,
    /// Per node slot, the batch dof of its first component, and the batch member of its body.
    pub node_dof: Vec<u32>,
    pub node_member: Vec<u32>,
    pub call: ContactCall<Real>,
    /// Each group's contact state before the call: its stalls so far.
    pub states: Vec<ContactState<Real>>,
}

impl ContactLayout {
    /// The layout of `contacts` whose problems `staged` the Uzawa solve holds with the node
    /// gather `nodes`; `member_of(call)` is a call's batch member and `dof_start(member)` its
    /// first dof.
    #[allow(clippy::too_many_arguments)]
    pub fn of(contacts: &[GroupContact], staged: &[Problem], nodes: &NodeGather, member_of: &dyn Fn(usize) -> u32, dof_start: &dyn Fn(u32) -> u32, dim: usize, theta_dt: Real) -> Self {
        let mut l = ContactLayout { term_start: vec![0], ..Default::default() };
        for (k, g) in contacts.iter().enumerate() {
            l.groups.push(ContactGroup { member_start: l.group_members.len() as u32, member_count: g.calls.len() as u32, jacobi: g.jacobi as u32, refactor: g.refactor as u32, tolerance: g.tolerance, velocity_scale: g.velocity_scale });
            l.group_members.extend(g.calls.iter().map(|&c| member_of(c)));
            l.states.push(ContactState { stalls: g.outcome.stalls, ..ContactState::default() });
            let slot0 = nodes.node_offsets[k];
            for terms in &staged[k].nodal.terms {
                l.term_slots.extend(terms.iter().map(|&(slot, _)| slot0 + slot));
                l.term_coefs.extend(terms.iter().map(|&(_, coef)| coef));
                l.term_start.push(l.term_slots.len() as u32);
            }
            l.obstacle.extend(g.obstacle.iter().flatten());
            debug_assert_eq!(g.slot_nodes.len(), (nodes.node_offsets[k + 1] - slot0) as usize);
            l.node_dof.extend(g.slot_nodes.iter().map(|&(body, node)| dof_start(member_of(g.calls[body as usize])) + node * dim as u32));
            l.node_member.extend(g.slot_nodes.iter().map(|&(body, _)| member_of(g.calls[body as usize])));
        }
        l.call = ContactCall { problems: contacts.len() as u32, dim: dim as u32, pad: [0; 2], theta_dt };
        l
    }
}

/// The most loop iterations an invocation of `newton_contact`'s `delassus` runs for a problem
/// of W's rows `w`, its points' terms `nodal` and the body of each node slot `slot_nodes`
/// (`dim` the scene's): the lane whose rows take the most. A software adapter ends an
/// invocation's loops past its guard without an error
/// ([`crate::gpu::uzawa_sweep::SOFTWARE_LOOP_BUDGET`]).
pub fn delassus_loops(w: &Delassus, nodal: &NodalMap, slot_nodes: &[(u32, u32)], dim: usize) -> usize {
    let pair = dim * (1 + dim * (1 + dim * (1 + dim)));
    let body = |slot: u32| slot_nodes[slot as usize].0;
    // An entry: its pairs of terms (those on one body multiply K̄⁻¹'s entries), then its 3 x 3
    // writes.
    let entry = |i: usize, j: usize| 1 + nodal.terms[i].iter().map(|&(s, _)| 1 + nodal.terms[j].iter().map(|&(t, _)| 1 + if body(s) == body(t) { pair } else { 0 }).sum::<usize>()).sum::<usize>() + 3 * (1 + 3);
    // A row: its entries, then its floor.
    let row = |i: usize| 1 + w.rows[i].iter().map(|&(j, _)| entry(i, j as usize)).sum::<usize>() + 1;
    let most = (0..NEWTON_WORKGROUP).map(|lane| (lane..w.rows.len()).step_by(NEWTON_WORKGROUP).map(row).sum::<usize>()).max().unwrap_or(0);
    most + NEWTON_WORKGROUP.ilog2() as usize
}

/// The pipelines of `newton_contact`'s entry points, compiled by the first call with contact.
pub(super) struct ContactPipelines {
    prepare: ComputePipeline,
    forces: ComputePipeline,
    judge: ComputePipeline,
    first_forces: ComputePipeline,
    first_judge: ComputePipeline,
    delassus: ComputePipeline,
    rebuild: ComputePipeline,
}

impl ContactPipelines {
    pub(super) fn new(gpu: &Gpu) -> Result<Self, crate::gpu::GpuError> {
        let at = |entry: &str| gpu.pipeline_at("newton_contact", entry, None);
        Ok(Self { prepare: at("prepare")?, forces: at("forces")?, judge: at("judge")?, first_forces: at("first_forces")?, first_judge: at("first_judge")?, delassus: at("delassus")?, rebuild: at("rebuild")? })
    }
}

/// A call's `newton_contact` bind groups, and the contact states it reads back.
pub(super) struct ContactPasses {
    prepare: BindGroup,
    forces: BindGroup,
    judge: BindGroup,
    first_forces: BindGroup,
    first_judge: BindGroup,
    delassus: BindGroup,
    rebuild: BindGroup,
    pub(super) states: Buffer,
    /// The points' step lengths `delassus` gives (for the host: `GroupContact::step_lengths`).
    pub(super) step_lengths: Buffer,
    problems: u32,
    /// The dofs `forces` and `first_forces` write in the contact forces: `dim` from each node
    /// slot's first (`ContactLayout::node_dof`).
    pub(super) written: (Vec<u32>, usize),
}

impl ContactPasses {
    /// Uploads the layout (buffers made for the call: a few kilobytes per group) and binds it
    /// with the batch's Newton buffers and the staged Uzawa problems.
    pub(super) fn new(gpu: &Gpu, pipelines: &ContactPipelines, l: &ContactLayout, b: &Batch, newton: &super::newton::NewtonBuffers, uzawa: &UzawaBuffers, up: &mut u64) -> Self {
        let storage = BufferUsages::STORAGE;
        let mut made = |label: &str, bytes: &[u8], usage: BufferUsages| {
            *up += bytes.len() as u64;
            buffer_init(gpu, label, bytes, usage)
        };
        let groups = made("contact groups", bytemuck::cast_slice(&l.groups), storage);
        let group_members = made("contact group members", bytemuck::cast_slice(&l.group_members), storage);
        let term_start = made("contact term starts", bytemuck::cast_slice(&l.term_start), storage);
        let term_slots = made("contact term slots", bytemuck::cast_slice(&l.term_slots), storage);
        let term_coefs = made("contact term coefficients", bytemuck::cast_slice(&l.term_coefs), storage);
        let obstacle = made("contact obstacle velocities", bytemuck::cast_slice(&l.obstacle), storage);
        let node_dof = made("contact node dofs", bytemuck::cast_slice(&l.node_dof), storage);
        let node_member = made("contact node members", bytemuck::cast_slice(&l.node_member), storage);
        let states = made("contact states", bytemuck::cast_slice(&l.states), storage | BufferUsages::COPY_SRC);
        let call = made("contact call", bytemuck::bytes_of(&l.call), BufferUsages::UNIFORM);
        let points = l.term_start.len() - 1;
        let step_lengths = super::buffer(gpu, "contact step lengths", (points.max(1) * std::mem::size_of::<Real>()).next_multiple_of(8), storage | BufferUsages::COPY_SRC);
        let n = newton;
        // Every resource of `newton_contact` by the name the kernel gives it; each entry point's
        // bind group takes those it uses (naga's reflection, `Gpu::bind_named`).
        let all = [
            ("inverse", &n.inverse),
            ("free_dofs", &n.free),
            ("newton", &n.newton),
            ("state", &n.state),
            ("dof_out", &b.dof_out),
            ("u", &b.u),
            ("members", &b.member_buffer),
            ("x0", &n.x0),
            ("u_base", &n.u_base),
            ("contact", &n.contact),
            ("groups", &groups),
            ("group_members", &group_members),
            ("locals", &uzawa.locals),
            ("uzawa_states", &uzawa.states),
            ("problems", &uzawa.judged),
            ("term_start", &term_start),
            ("term_slots", &term_slots),
            ("term_coefs", &term_coefs),
            ("obstacle", &obstacle),
            ("frames", &uzawa.frames),
            ("node_dof", &node_dof),
            ("node_start", &uzawa.node_start),
            ("node_points", &uzawa.node_points),
            ("node_coefs", &uzawa.node_coefs),
            ("r", &uzawa.r),
            ("contact_states", &states),
            ("call", &call),
            ("blocks", &uzawa.block),
            ("row_start", &uzawa.row_start),
            ("row_entries", &uzawa.row_entries),
            ("node_member", &node_member),
            ("step_lengths", &step_lengths),
            ("free_of", &n.free_of),
        ];
        let bind = |pipeline: &ComputePipeline, entry: &str| gpu.bind_named(pipeline, ("newton_contact", entry, None), &all);
        let (prepare, forces, judge) = (bind(&pipelines.prepare, "prepare"), bind(&pipelines.forces, "forces"), bind(&pipelines.judge, "judge"));
        let (first_forces, first_judge) = (bind(&pipelines.first_forces, "first_forces"), bind(&pipelines.first_judge, "first_judge"));
        let (delassus, rebuild) = (bind(&pipelines.delassus, "delassus"), bind(&pipelines.rebuild, "rebuild"));
        Self { prepare, forces, judge, first_forces, first_judge, delassus, rebuild, states, step_lengths, problems: l.groups.len() as u32, written: (l.node_dof.clone(), l.call.dim as usize) }
    }

    fn dispatch(gpu: &Gpu, pass: &mut wgpu::ComputePass, entry: &'static str, pipeline: &ComputePipeline, group: &BindGroup, workgroups: usize) {
        let (x, y) = crate::gpu::dispatch_rows(workgroups);
        gpu.dispatch(pass, ("newton_contact", entry), |pass| {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(x, y, 1);
        });
    }

    /// `prepare`, one workgroup per group.
    pub(super) fn record_prepare(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "prepare", &p.prepare, &self.prepare, self.problems as usize);
    }

    /// `forces`, one workgroup per group.
    pub(super) fn record_forces(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "forces", &p.forces, &self.forces, self.problems as usize);
    }

    /// `delassus`, one workgroup per group: W from the members' `K̄⁻¹`, after the call's
    /// inversions and before anything reads W.
    pub(super) fn record_delassus(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "delassus", &p.delassus, &self.delassus, self.problems as usize);
    }

    /// `rebuild`, one workgroup per group: W again where a member refactorised within the call,
    /// after its `K̄⁻¹` and before the next iteration reads W.
    pub(super) fn record_rebuild(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "rebuild", &p.rebuild, &self.rebuild, self.problems as usize);
    }

    /// `first_forces`, one workgroup per group.
    pub(super) fn record_first_forces(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "first_forces", &p.first_forces, &self.first_forces, self.problems as usize);
    }

    /// `first_judge`, one workgroup per group.
    pub(super) fn record_first_judge(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "first_judge", &p.first_judge, &self.first_judge, self.problems as usize);
    }

    /// `judge`, one invocation per group.
    pub(super) fn record_judge(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, p: &ContactPipelines) {
        Self::dispatch(gpu, pass, "judge", &p.judge, &self.judge, (self.problems as usize).div_ceil(crate::gpu::types::NEWTON_WORKGROUP));
    }
}
