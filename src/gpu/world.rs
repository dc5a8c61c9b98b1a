//! Every deformable body on the device at once. The bodies' elements live in shared buffers, one
//! batch per (element kind, material model); a body is a "member" of its batch, with its range
//! of elements, stiffness non-zeros and dofs (`shaders/include/batch.wgsl`).
//!
//! One [`GpuWorld::evaluate`] serves every body a Newton iteration evaluates, whatever their
//! number: their displacements go up (one write per run of consecutive members), each batch
//! records one dispatch per kernel over its active members, and one submit is followed by one
//! mapping of one read-back buffer that holds what the CPU needs: the failure flags, the
//! residuals of the evaluated bodies, and the stiffness values only of the bodies whose tangent
//! was asked for (those that refactorise).

mod contact;
mod invert;
mod mirror;
mod newton;
mod scatter;
mod step;

pub use contact::{delassus_loops, ContactLayout, GroupContact};
pub use invert::{invert_loops, run_newton_invert, Inverse};
use mirror::{update_mirrors, Mirror};
pub use newton::NewtonCall;
pub use scatter::ScatterCount;
pub use step::{run_newton_summary, run_step_kernels, KeptIterate, KeptState, StepEnd, StepKernelsOut, StepStart, SummaryBuffers, SummaryOut};

use super::types::{Active, Coefficients, DofOut, MaterialParams, MemberRange, StepTally, MODE_FORCES, MODE_TANGENT, NEWTON_MAX_FREE, NO_FAILURE, NO_HISTORY};
use super::uzawa_sweep::UzawaSweeps;
use super::{ElementVariant, Gpu, GpuError};
use crate::assembly::{element_out_stride, DofMap, GatherMap, StiffnessPattern};
use crate::contact::uzawa::{Outcome, Problem};
use crate::element::{Formulation, ReferenceGeometry};
use crate::material::viscous::HISTORY;
use crate::material::{Model, Relaxation};
use crate::mesh::Mesh;
use crate::policy::PhaseTimes;
use crate::policy::{RoundPlacement, UzawaPlacement};
use crate::precision::{Precision, Real};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;
use wgpu::util::DeviceExt;
use wgpu::{BindGroup, Buffer, BufferUsages, ComputePipeline};

/// Invocations per workgroup of the kernels that take one item per invocation.
const WORKGROUP: usize = 64;

/// The bytes one thread copies at a time into the staging memory of a large upload.
const COPY_STRETCH: usize = 1 << 20;

/// Why the element kernel rejected a body's state: its lowest failing element of each kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementFailure {
    Inverted(usize),
    NonFinite(usize),
}

/// Bytes moved between host and device.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Traffic {
    pub up: u64,
    pub down: u64,
}

impl Traffic {
    pub fn total(self) -> u64 {
        self.up + self.down
    }
}

/// What the world needs of a body, once, when it is built.
pub struct WorldBody<'a> {
    pub mesh: &'a Mesh,
    pub geometry: &'a ReferenceGeometry,
    pub model: &'a Model,
    pub formulation: Formulation,
    pub pattern: &'a StiffnessPattern,
    pub gather: &'a GatherMap,
    /// Which of its dofs are free (the rows of `K̄⁻¹` for device Newton iterations).
    pub dofs: &'a DofMap,
    /// Whether its material has a Prony series (a history per quadrature point each step).
    pub viscous: bool,
}

/// One body's share of an evaluation: its displacement in, its results out.
pub struct Evaluation<'a> {
    pub body: usize,
    pub u: &'a [Real],
    /// Whether the tangent and the stiffness values `ξ K` are wanted (into `values`).
    pub tangent: bool,
    pub values: &'a mut [Real],
    /// Internal force and residual of every dof, when wanted.
    pub dof_out: Option<&'a mut [DofOut<Real>]>,
    /// Out: why the element kernel rejected the state, if it did.
    pub failure: Option<ElementFailure>,
}

/// A pipeline with its bind group and the buffers bound, and the kernel and entry point it runs
/// (the clock's name for its dispatches).
struct Pass {
    pipeline: ComputePipeline,
    bind_group: BindGroup,
    /// The buffers bound, by the names the kernel gives them.
    buffers: Vec<(&'static str, Buffer)>,
    variant: Option<ElementVariant>,
    entry: (&'static str, &'static str),
}

impl Pass {
    fn new(gpu: &Gpu, kernel: &'static str, entry: &'static str, variant: Option<ElementVariant>, buffers: &[(&'static str, &Buffer)]) -> Result<Self, GpuError> {
        Ok(Self::bound(gpu, gpu.pipeline_at(kernel, entry, variant)?, (kernel, entry), variant, buffers))
    }

    /// A pass of a pipeline made before, with `buffers` bound by name.
    fn bound(gpu: &Gpu, pipeline: ComputePipeline, entry: (&'static str, &'static str), variant: Option<ElementVariant>, buffers: &[(&'static str, &Buffer)]) -> Self {
        let bind_group = gpu.bind_named(&pipeline, (entry.0, entry.1, variant), buffers);
        Self { pipeline, bind_group, buffers: buffers.iter().map(|&(name, b)| (name, b.clone())).collect(), variant, entry }
    }

    /// The same pipeline and buffers with another job list (`jobs`): device Newton iterations
    /// run the batch's passes over lists of their own.
    fn with_jobs(&self, gpu: &Gpu, jobs: &Buffer) -> Self {
        let buffers: Vec<(&'static str, &Buffer)> = self.buffers.iter().map(|(name, b)| (*name, if *name == "jobs" { jobs } else { b })).collect();
        Self::bound(gpu, self.pipeline.clone(), self.entry, self.variant, &buffers)
    }

    /// One z-slice per active member, enough workgroups of `per_group` items for `max_items`.
    fn record(&self, gpu: &Gpu, encoder: &mut wgpu::CommandEncoder, per_group: usize, max_items: usize, active: usize) {
        let chunks = max_items.div_ceil(per_group);
        if chunks == 0 || active == 0 {
            return;
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        let (x, y) = super::dispatch_rows(chunks);
        self.dispatch_xyz(gpu, &mut pass, [x, y, active as u32]);
    }

    /// A dispatch whose workgroup counts the device wrote (`offset` into `arguments`).
    fn dispatch_indirect(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, arguments: &Buffer, offset: u64) {
        gpu.dispatch(pass, self.entry, |pass| {
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups_indirect(arguments, offset);
        });
    }

    /// `groups` workgroups in a pass being recorded.
    fn dispatch(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, groups: u32) {
        self.dispatch_xyz(gpu, pass, [groups, 1, 1]);
    }

    /// `x * y * z` workgroups in a pass being recorded.
    fn dispatch_xyz(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass, [x, y, z]: [u32; 3]) {
        gpu.dispatch(pass, self.entry, |pass| {
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups(x, y, z);
        });
    }
}

/// The bodies of one element kind and material model.
struct Batch {
    members: Vec<MemberRange>,
    /// Entries per element of the element results.
    stride: usize,
    /// Elements per workgroup of the tangent entry point (`ELEMENTS_PER_GROUP`).
    tangent_elements_per_group: usize,
    /// The displacements of every dof of the batch, as last uploaded.
    u_host: Vec<Real>,
    /// The step inputs (`DofStep`, 4 reals) of every dof, as the host last gave them.
    step_host: Vec<Real>,
    /// The residuals (`DofOut`, 2 reals) of every dof as the device holds them, where the host
    /// knows them (NaN elsewhere): those it read back, and those it computed from a device Newton
    /// call's forces as `assemble_residual` does. A residual the host evaluated on the device
    /// does not go up again.
    dof_out_host: Vec<Real>,
    /// Per member: its step inputs in `step_host` have not gone up yet. They go with its next
    /// evaluation (a grain in contact that the host iterates on the CPU sends none).
    step_pending: Vec<bool>,
    u: Buffer,
    reference: Vec<Real>,
    /// The distinct stiffness patterns of the members (column starts, then row indices; grains
    /// of one shape share theirs), and where each member's starts: `newton_invert` reads them.
    patterns: Vec<u32>,
    pattern_start: Vec<u32>,
    step: Buffer,
    failure: Buffer,
    active: Buffer,
    element_out: Buffer,
    values: Buffer,
    dof_out: Buffer,
    energy: Buffer,
    /// The viscoelastic members' step relaxation and point histories (`MemberRange.history`).
    history: Buffer,
    member_buffer: Buffer,
    /// Each member's free dofs (indices into its dofs, ascending), `(start, count)` in `free_dofs`.
    free_dofs: Vec<u32>,
    free_range: Vec<(u32, u32)>,
    /// Where each member's `K̄⁻¹` lies in the Newton buffers' `inverse` (`None`: too large), and
    /// their total entries.
    inverse_slot: Vec<Option<u32>>,
    inverse_entries: usize,
    /// Per member, what the stiffness values that `values` holds are to the host; `None` while
    /// the device computes others. A `K̄` made from them goes up by its diagonal only.
    handed: Vec<Option<Held>>,
    /// Made by the first device Newton call that needs them.
    newton: Option<newton::NewtonBuffers>,
    forces: Pass,
    tangent: Deferred,
    csr: Pass,
    residual: Pass,
    element_energy: Pass,
}

/// A pipeline compiling on another thread until it is first needed: the tangent kernel is the
/// largest, and a software adapter compiles it on the CPU while the first evaluations run.
enum Deferred {
    Compiling(std::thread::JoinHandle<Result<Pass, GpuError>>),
    Ready(Pass),
    Failed,
}

impl Deferred {
    fn spawn(compile: impl FnOnce() -> Result<Pass, GpuError> + Send + 'static) -> Self {
        Self::Compiling(std::thread::spawn(compile))
    }

    /// Waits for the pipeline if it is still compiling.
    fn ready(&mut self) -> Result<&Pass, GpuError> {
        if let Self::Compiling(_) = self {
            let Self::Compiling(handle) = std::mem::replace(self, Self::Failed) else { unreachable!() };
            *self = Self::Ready(handle.join().map_err(|_| GpuError::Kernel { kernel: "element_force_tangent".into(), message: "the pipeline's compilation panicked".into() })??);
        }
        match self {
            Self::Ready(pass) => Ok(pass),
            _ => Err(GpuError::Kernel { kernel: "element_force_tangent".into(), message: "the pipeline failed to compile".into() }),
        }
    }
}

/// The kernels [`GpuWorld::replay`] can run alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorldKernel {
    /// `element_force_tangent`, entry point `main`.
    ForceTangent,
    /// `element_force_tangent`, entry point `forces`.
    Forces,
    /// `assemble_residual` and `assemble_csr`.
    Assembly,
}

/// A copy from a batch's buffer into the read-back buffer.
struct Copy {
    batch: usize,
    what: Source,
    /// Byte range in the source buffer, and where it lands.
    source: std::ops::Range<u64>,
    target: u64,
}

/// A member's stiffness values `ξ K` on the device, as the host knows them (`Batch::handed`).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Held {
    /// Those the host read back: the fingerprint of their entries off the diagonal
    /// (`invert::off_diagonal_print`).
    Read(u64),
    /// The tangent at the iterate where a device Newton call handed the member back, which the
    /// host did not read: it assembles its own there ([`invert::Inverse::AtHandBack`]).
    HandBack,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Source {
    Failure,
    DofOut,
    Values,
    Energy,
    Displacement,
    NewtonState,
    /// A device Newton call's strain energy per member (`newton_finish`).
    MemberEnergy,
    /// A device Newton call's internal forces, packed per dof (`newton_finish`).
    NewtonForces,
    /// A device Newton call's end-of-step summary per member (`newton_summary`).
    Summary,
    /// The box of each member's nodes, in f32 (`newton_summary`).
    Boxes,
    /// The committed states of steps begun on the device.
    Committed,
    /// Their strain energies, per member.
    CommittedEnergy,
    /// Per member of a kept call, what `newton_tally` sums (`newton_summary`).
    TallyRows,
    /// The sums of a call's kept members (`newton_tally`).
    Tally,
    /// Where a device Newton call last refactorised each member (`NewtonBuffers::u_factored`).
    Factored,
}

/// The copies of one pass into the read-back buffer, each landing 8-byte aligned after the last.
#[derive(Default)]
struct ReadBack {
    copies: Vec<Copy>,
    /// Copies from buffers outside the batches (the contact of device Newton calls):
    /// `(buffer, source offset, bytes, target)`.
    others: Vec<(Buffer, u64, u64, u64)>,
    end: u64,
}

impl ReadBack {
    /// Queues a copy of the byte range `source` of a batch's buffer; returns where it lands.
    fn queue(&mut self, batch: usize, what: Source, source: std::ops::Range<u64>) -> u64 {
        let target = self.end;
        self.end += (source.end - source.start).div_ceil(8) * 8;
        self.copies.push(Copy { batch, what, source, target });
        target
    }

    /// Queues a copy of the first `bytes` of a buffer outside the batches; returns where it lands.
    fn queue_buffer(&mut self, buffer: &Buffer, bytes: u64) -> usize {
        let target = self.end;
        self.end += bytes.div_ceil(8) * 8;
        self.others.push((buffer.clone(), 0, bytes, target));
        target as usize
    }

    /// Queues the byte span of each listed member (sorted), one copy per run of consecutive
    /// members; returns where each member's span lands, in the order given.
    fn queue_runs(&mut self, batch: usize, what: Source, members: &[usize], span: &dyn Fn(usize) -> std::ops::Range<u64>) -> Vec<usize> {
        let mut landing = Vec::with_capacity(members.len());
        for run in runs(members) {
            let (first, last) = (span(run[0]), span(*run.last().expect("a run has members")));
            let target = if last.end > first.start { self.queue(batch, what, first.start..last.end) } else { self.end };
            landing.extend(run.iter().map(|&m| (target + span(m).start - first.start) as usize));
        }
        landing
    }
}

pub struct GpuWorld {
    gpu: Arc<Gpu>,
    batches: Vec<Batch>,
    /// Each body's batch and member.
    place: Vec<(usize, usize)>,
    coefficients: Buffer,
    readback: Buffer,
    traffic: Traffic,
    submits: u64,
    /// The Uzawa sweeps, made when contact first runs on the device.
    contact: Option<UzawaSweeps>,
    /// Where the Uzawa sweeps run (set by the backend).
    pub uzawa: UzawaPlacement,
    /// Which Newton rounds evaluate on the device (set by the backend).
    pub rounds: RoundPlacement,
    /// The read-back of device Newton calls and its size, grown on demand.
    newton_readback: Option<(Buffer, u64)>,
    /// Uploads that wait for the step's start recorded at the head of the next submission
    /// ([`GpuWorld::settle_prologue`]): `(staging, target, offset, size)`, copied after it.
    deferred: Option<Vec<(Buffer, Buffer, u64, u64)>>,
    /// Mirror values that go up with their indices ([`GpuWorld::stage_mirror_by_dof`]), written
    /// at the head of the next submission, and the kernel that writes them (compiled on first
    /// use).
    scattered: Vec<scatter::Scattered>,
    scatter_pipeline: Option<ComputePipeline>,
    /// Compiled by the first device Newton call.
    newton_pipelines: Option<newton::NewtonPipelines>,
    /// Compiled by the first device Newton call with groups in contact.
    contact_pipelines: Option<contact::ContactPipelines>,
    /// What the step's kept ends add up to (`newton_tally`), less those the host took back.
    step_tally: StepTally,
    /// The committed states the device keeps for the host: how many, and their strain energy.
    held: (usize, Real),
}

pub(super) fn buffer(gpu: &Gpu, label: &str, bytes: usize, usage: BufferUsages) -> Buffer {
    // wgpu binds no empty buffer; copies need multiples of 4 bytes.
    gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: (bytes.max(8).div_ceil(8) * 8) as u64, usage, mapped_at_creation: false })
}

fn buffer_init(gpu: &Gpu, label: &str, contents: &[u8], usage: BufferUsages) -> Buffer {
    let mut padded = contents.to_vec();
    padded.resize(contents.len().max(8).div_ceil(8) * 8, 0);
    gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: &padded, usage })
}

/// Device bytes of the largest buffer a body brings to a batch, and of its element results. In
/// f64 that counts the `K̄⁻¹` of a body small enough to iterate on the device: a batch is cut
/// where its inverses would pass the binding limit, so that every such body has a slot
/// (doc/benchmarks.md, "Bytes a grain moves per step").
fn largest_buffer(body: &WorldBody, real: usize) -> u64 {
    let stride = element_out_stride(body.pattern.element_dofs);
    let element_out = body.mesh.element_count() * stride * real;
    let gathers = (body.gather.csr.len() + body.gather.dof.len()) * 4;
    let free = body.dofs.free_count;
    let inverse = if real == 8 && free <= NEWTON_MAX_FREE { free * free * real } else { 0 };
    (element_out.max(gathers).max(body.pattern.nnz() * real).max(inverse)) as u64
}

impl GpuWorld {
    /// Uploads every body's mesh, geometry, material and gather maps, in batches of one element
    /// kind and material model (split where a batch would pass the device's buffer limits).
    pub fn new(gpu: Arc<Gpu>, bodies: &[WorldBody]) -> Result<Self, GpuError> {
        let limits = gpu.device.limits();
        let real = gpu.precision.size();
        let max_bytes = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_members = limits.max_compute_workgroups_per_dimension as usize;
        let mut groups: Vec<(ElementVariant, Vec<usize>, u64)> = Vec::new();
        for (b, body) in bodies.iter().enumerate() {
            let variant = ElementVariant { kind: body.mesh.kind, formulation: body.formulation, material: body.model.name() };
            let bytes = largest_buffer(body, real);
            if bytes > max_bytes {
                return Err(GpuError::Kernel { kernel: "element_force_tangent".into(), message: format!("a body of {} elements needs a buffer of {bytes} bytes; this device binds at most {max_bytes}", body.mesh.element_count()) });
            }
            match groups.iter_mut().rev().find(|(v, members, total)| *v == variant && members.len() < max_members && total + bytes <= max_bytes) {
                Some((_, members, total)) => {
                    members.push(b);
                    *total += bytes;
                }
                None => groups.push((variant, vec![b], bytes)),
            }
        }
        let mut place = vec![(0, 0); bodies.len()];
        let mut batches = Vec::with_capacity(groups.len());
        let coefficients = buffer(&gpu, "coefficients", 3 * real.max(8), BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let mut traffic = Traffic::default();
        let mut readback_bytes = 0usize;
        for (variant, members, _) in groups {
            for (m, &b) in members.iter().enumerate() {
                place[b] = (batches.len(), m);
            }
            let batch = Batch::new(&gpu, variant, members, bodies, &coefficients, max_bytes, &mut traffic)?;
            let (elements, dofs, nnz) = batch.totals();
            readback_bytes += (batch.members.len() * 8 + dofs * 2 * real + nnz * real + elements * real).div_ceil(8) * 8;
            batches.push(batch);
        }
        let readback = buffer(&gpu, "readback", readback_bytes, BufferUsages::MAP_READ | BufferUsages::COPY_DST);
        let mut world = Self {
            gpu,
            batches,
            place,
            coefficients,
            readback,
            traffic,
            submits: 0,
            contact: None,
            uzawa: UzawaPlacement::default(),
            rounds: RoundPlacement::default(),
            newton_readback: None,
            deferred: None,
            scattered: Vec::new(),
            scatter_pipeline: None,
            newton_pipelines: None,
            contact_pipelines: None,
            step_tally: StepTally::default(),
            held: (0, 0.0),
        };
        for batch in 0..world.batches.len() {
            if world.batches[batch].inverse_entries > 0 {
                world.make_newton_buffers(batch)?;
            }
        }
        Ok(world)
    }

    pub fn precision(&self) -> Precision {
        self.gpu.precision
    }

    /// Whether the device is a software adapter (lavapipe).
    pub fn software(&self) -> bool {
        self.gpu.adapter.software()
    }

    /// Bytes moved since the last call (the upload of the bodies' data counts in the first),
    /// the Uzawa sweeps' included.
    pub fn take_traffic(&mut self) -> Traffic {
        let mut moved = std::mem::take(&mut self.traffic);
        if let Some(sweeps) = &mut self.contact {
            let swept = sweeps.take_traffic();
            moved.up += swept.up;
            moved.down += swept.down;
        }
        moved
    }

    /// Queue submits so far: one per [`GpuWorld::evaluate`] and per [`GpuWorld::element_energies`],
    /// and one per chunk of Uzawa sweeps ([`GpuWorld::solve_contact`]).
    /// The batch a body's elements are in.
    pub fn batch_of(&self, body: usize) -> usize {
        self.place[body].0
    }

    pub fn submits(&self) -> u64 {
        self.submits + self.contact.as_ref().map_or(0, |c| c.submits)
    }

    /// The contact problems of a Newton round, solved by Gauss-Seidel sweeps on the device
    /// ([`UzawaSweeps::solve`]; `None` when they do not fit its buffers); the time counts as
    /// `contact`.
    pub fn solve_contact(&mut self, problems: &mut [Problem], stop: Option<&AtomicBool>, times: &mut PhaseTimes) -> Result<Option<Vec<Outcome>>, GpuError> {
        let started = Instant::now();
        if self.contact.is_none() {
            self.contact = Some(UzawaSweeps::new(self.gpu.clone())?);
        }
        let sweeps = self.contact.as_mut().expect("made above");
        let outcomes = sweeps.solve(problems, stop);
        times.contact += started.elapsed().as_secs_f64();
        outcomes
    }

    fn upload(&mut self, buffer: &Buffer, offset: u64, bytes: &[u8]) {
        self.upload_pieces(buffer, offset, &[bytes]);
    }

    /// Uploads `pieces` one after the other from `offset`, in one write: each piece is copied
    /// once, into the staging memory (a write costs a staging allocation, and building one
    /// vector of the pieces first costs another copy), in stretches of at most
    /// [`COPY_STRETCH`] bytes on every thread (after a step that refactorised 100 000 grains,
    /// 3.5 GB of inverses). While uploads are deferred ([`GpuWorld::settle_prologue`]) the
    /// staging memory is a buffer of its own, copied in the next submission's encoder after the
    /// step's start (a write would land before it).
    fn upload_pieces(&mut self, buffer: &Buffer, offset: u64, pieces: &[&[u8]]) {
        let total: usize = pieces.iter().map(|p| p.len()).sum();
        let Some(size) = wgpu::BufferSize::new(total as u64) else { return };
        self.traffic.up += total as u64;
        let mut starts = Vec::with_capacity(pieces.len() + 1);
        starts.push(0);
        for piece in pieces {
            starts.push(starts.last().expect("a start") + piece.len());
        }
        if let Some(deferred) = &mut self.deferred {
            let staging = self.gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some("deferred upload"), size: total as u64, usage: BufferUsages::COPY_SRC, mapped_at_creation: true });
            copy_pieces(staging.get_mapped_range_mut(..).expect("a staging buffer mapped at creation").slice(..), pieces, &starts);
            staging.unmap();
            deferred.push((staging, buffer.clone(), offset, total as u64));
            return;
        }
        let mut view = self.gpu.queue.write_buffer_with(buffer, offset, size).expect("a write inside the buffer");
        copy_pieces(view.slice(..), pieces, &starts);
    }

    /// Uploads reals from `offset` (in reals) in the device's precision: straight from them in
    /// f64 ([`GpuWorld::upload_pieces`]), through a vector of f32 otherwise.
    fn upload_reals(&mut self, buffer: &Buffer, offset: usize, reals: &[Real]) {
        let real = self.gpu.precision.size();
        match self.gpu.precision {
            Precision::F64 => self.upload_pieces(buffer, (offset * real) as u64, &[bytemuck::cast_slice(reals)]),
            Precision::F32 => self.upload(buffer, (offset * real) as u64, &to_device(Precision::F32, reals)),
        }
    }

    /// Uploads each member's bytes (`pieces`, in member order) to its dofs in a buffer of the
    /// batch's, `per_dof` bytes a dof: one write per run of consecutive members.
    fn upload_member_runs(&mut self, batch: usize, buffer: &Buffer, per_dof: u64, pieces: &[(usize, &[u8])]) {
        let members: Vec<usize> = pieces.iter().map(|&(m, _)| m).collect();
        let runs: Vec<(u64, usize)> = runs(&members).iter().map(|run| (dof_span(&self.batches[batch].members, run).start as u64 * per_dof, run.len())).collect();
        let mut k = 0;
        for (offset, len) in runs {
            let run: Vec<&[u8]> = pieces[k..k + len].iter().map(|&(_, bytes)| bytes).collect();
            self.upload_pieces(buffer, offset, &run);
            k += len;
        }
    }

    /// A viscoelastic body's relaxation for the step (`c` and each point's history `H`), up with
    /// the next submit.
    pub fn set_relaxation(&mut self, body: usize, relaxation: Relaxation) {
        let (b, m) = self.place[body];
        let start = self.batches[b].members[m].history;
        assert_ne!(start, NO_HISTORY, "body {body} was uploaded without a Prony series");
        let mut reals = Vec::with_capacity(1 + relaxation.history.len());
        reals.push(relaxation.c);
        reals.extend_from_slice(relaxation.history);
        let buffer = self.batches[b].history.clone();
        let bytes = to_device(self.gpu.precision, &reals);
        self.upload(&buffer, start as u64 * self.gpu.precision.size() as u64, &bytes);
    }

    /// Evaluates the listed bodies at their displacements in one pass: `element_force_tangent`
    /// (forces, or forces and tangent), `assemble_residual` and, for those that want the
    /// tangent, `assemble_csr`, then one read-back. Each evaluation's `failure` says whether its
    /// element kernel rejected the state (its outputs are then not written).
    pub fn evaluate(&mut self, list: &mut [Evaluation], coefficients: Coefficients<Real>, times: &mut PhaseTimes) -> Result<(), GpuError> {
        let t0 = Instant::now();
        let coefficient_buffer = self.coefficients.clone();
        self.upload(&coefficient_buffer, 0, &to_device(self.gpu.precision, &[coefficients.factor, coefficients.c1, coefficients.motion]));
        let mut encoder = None;
        let mut readback = ReadBack::default();
        let landing = self.record_evaluation(list, &mut encoder, &mut readback)?;
        let encoder = encoder.expect("made by the evaluation");
        let precision = self.gpu.precision;
        self.read_back(encoder, &readback, "element_force_tangent", times, t0, |bytes| unpack_evaluation(precision, list, &landing, bytes))?;
        self.note_handed_evaluations(list);
        Ok(())
    }

    /// The stiffness values and residuals an evaluation pass read back, as the device holds
    /// them (a residual it did not read back: unknown).
    fn note_handed_evaluations(&mut self, list: &[Evaluation]) {
        for e in list.iter().filter(|e| e.tangent && e.failure.is_none() && !e.values.is_empty()) {
            self.note_handed(e.body, e.values);
        }
        for e in list {
            let out = e.dof_out.as_deref().filter(|_| e.failure.is_none());
            self.note_residuals(e.body, out);
        }
    }

    /// Body `body`'s stiffness values `ξ K` as the device holds them and the host read them.
    fn note_handed(&mut self, body: usize, values: &[Real]) {
        let (b, m) = self.place[body];
        let b = &mut self.batches[b];
        b.handed[m] = Some(Held::Read(invert::off_diagonal_print(values, &b.patterns, b.pattern_start[m], b.free_range[m].1 as usize)));
    }

    /// Uploads the displacements and active lists of an evaluation pass and records its
    /// dispatches and read-back copies into `encoder` (made after the displacements went up, so
    /// that a step's start at its head comes after them); returns where each evaluation's
    /// failure flags, residuals and values land.
    fn record_evaluation(&mut self, list: &[Evaluation], encoder: &mut Option<wgpu::CommandEncoder>, readback: &mut ReadBack) -> Result<Vec<[usize; 3]>, GpuError> {
        let real = self.gpu.precision.size() as u64;
        let by_batch = self.stage_displacements(&list.iter().map(|e| (e.body, e.u)).collect::<Vec<_>>());
        if encoder.is_none() {
            *encoder = Some(self.encoder("evaluate"));
        }
        let encoder = encoder.as_mut().expect("made above");
        let mut landing = vec![[0usize; 3]; list.len()];
        for (batch, mine) in by_batch {
            // (list index, member) in member order.
            let mine: Vec<(usize, usize)> = mine.into_iter().map(|i| (i, self.place[list[i].body].1)).collect();
            if let Some(n) = self.batches[batch].newton.as_mut() {
                mine.iter().for_each(|&(_, m)| n.resident.touched(m));
            }
            let active: Vec<Active> = mine.iter().map(|&(i, m)| Active { member: m as u32, mode: if list[i].tangent { MODE_TANGENT } else { MODE_FORCES } }).collect();
            for &(i, m) in &mine {
                if list[i].tangent {
                    self.batches[batch].handed[m] = None;
                }
            }
            let members: Vec<usize> = mine.iter().map(|&(_, m)| m).collect();
            let b = &self.batches[batch];
            let (active_buffer, failure_buffer) = (b.active.clone(), b.failure.clone());
            self.upload(&active_buffer, 0, bytemuck::cast_slice(&active));
            // The flags of the evaluated members only (a pass over the few grains in contact
            // of a packing of thousands).
            for run in runs(&members) {
                self.upload(&failure_buffer, 8 * run[0] as u64, bytemuck::cast_slice(&vec![NO_FAILURE; 2 * run.len()]));
            }
            if active.iter().any(|a| a.mode == MODE_TANGENT) {
                self.batches[batch].tangent.ready()?;
            }
            let b = &self.batches[batch];
            let extent = |mode: u32, f: fn(&MemberRange) -> u32| active.iter().filter(|a| a.mode == mode || mode == 0).map(|a| f(&b.members[a.member as usize]) as usize).max().unwrap_or(0);
            b.forces.record(&self.gpu, encoder, WORKGROUP, extent(MODE_FORCES, |m| m.elements), active.len());
            if let Deferred::Ready(tangent) = &b.tangent {
                tangent.record(&self.gpu, encoder, b.tangent_elements_per_group, extent(MODE_TANGENT, |m| m.elements), active.len());
            }
            b.residual.record(&self.gpu, encoder, WORKGROUP, extent(0, |m| m.dofs), active.len());
            b.csr.record(&self.gpu, encoder, WORKGROUP, extent(MODE_TANGENT, |m| m.nonzeros), active.len());
            let flag_span = |m: usize| 8 * m as u64..8 * (m as u64 + 1);
            for (&(i, _), at) in mine.iter().zip(readback.queue_runs(batch, Source::Failure, &members, &flag_span)) {
                landing[i][0] = at;
            }
            let dof_span = |m: usize| b.members[m].dof_start as u64 * 2 * real..(b.members[m].dof_start + b.members[m].dofs) as u64 * 2 * real;
            let value_span = |m: usize| b.members[m].nonzero_start as u64 * real..(b.members[m].nonzero_start + b.members[m].nonzeros) as u64 * real;
            let wanted: [(Source, Vec<(usize, usize)>); 2] = [(Source::DofOut, mine.iter().copied().filter(|&(i, _)| list[i].dof_out.is_some()).collect()), (Source::Values, mine.iter().copied().filter(|&(i, _)| list[i].tangent).collect())];
            for (slot, (what, chosen)) in wanted.into_iter().enumerate() {
                let members: Vec<usize> = chosen.iter().map(|&(_, m)| m).collect();
                let span: &dyn Fn(usize) -> std::ops::Range<u64> = if what == Source::DofOut { &dof_span } else { &value_span };
                for ((i, _), at) in chosen.into_iter().zip(readback.queue_runs(batch, what, &members, span)) {
                    landing[i][slot + 1] = at;
                }
            }
        }
        Ok(landing)
    }

    /// The strain energy of every element of each listed body at its displacement
    /// (`element_energy`), in one pass.
    pub fn element_energies(&mut self, list: &[(usize, &[Real])], times: &mut PhaseTimes) -> Result<Vec<Vec<Real>>, GpuError> {
        let t0 = Instant::now();
        let precision = self.gpu.precision;
        let real = precision.size() as u64;
        let by_batch = self.stage_displacements(list);
        let mut readback = ReadBack::default();
        // Where each body's energies land in the read-back, and how many there are.
        let mut landing = vec![(0usize, 0usize); list.len()];
        let mut encoder = self.encoder("energies");
        for (batch, mine) in by_batch {
            let members: Vec<usize> = mine.iter().map(|&i| self.place[list[i].0].1).collect();
            let active: Vec<Active> = members.iter().map(|&m| Active { member: m as u32, mode: MODE_FORCES }).collect();
            let active_buffer = self.batches[batch].active.clone();
            self.upload(&active_buffer, 0, bytemuck::cast_slice(&active));
            let b = &self.batches[batch];
            let most = members.iter().map(|&m| b.members[m].elements as usize).max().unwrap_or(0);
            b.element_energy.record(&self.gpu, &mut encoder, WORKGROUP, most, active.len());
            let span = |m: usize| b.members[m].element_start as u64 * real..(b.members[m].element_start + b.members[m].elements) as u64 * real;
            for ((i, m), at) in mine.into_iter().zip(&members).zip(readback.queue_runs(batch, Source::Energy, &members, &span)) {
                landing[i] = (at, b.members[*m].elements as usize);
            }
        }
        let mut energies = vec![Vec::new(); list.len()];
        self.read_back(encoder, &readback, "element_energy", times, t0, |bytes| {
            for (energy, (at, count)) in energies.iter_mut().zip(landing) {
                *energy = from_device(precision, &bytes[at..at + count * real as usize]);
            }
        })?;
        Ok(energies)
    }

    /// Runs `kernel` again on the members and modes of the last pass, with no upload and no
    /// read-back: what `bifirst bench` times as the kernel alone.
    pub fn replay(&mut self, kernel: WorldKernel) -> Result<(), GpuError> {
        if kernel == WorldKernel::ForceTangent {
            for b in &mut self.batches {
                b.tangent.ready()?;
            }
        }
        let mut encoder = self.encoder("replay");
        for b in &mut self.batches {
            b.handed.fill(None);
            b.dof_out_host.fill(Real::NAN);
        }
        for b in &self.batches {
            let all = b.members.len();
            let most = |f: fn(&MemberRange) -> u32| b.members.iter().map(|m| f(m) as usize).max().unwrap_or(0);
            match kernel {
                WorldKernel::ForceTangent => {
                    if let Deferred::Ready(tangent) = &b.tangent {
                        tangent.record(&self.gpu, &mut encoder, b.tangent_elements_per_group, most(|m| m.elements), all);
                    }
                }
                WorldKernel::Forces => b.forces.record(&self.gpu, &mut encoder, WORKGROUP, most(|m| m.elements), all),
                WorldKernel::Assembly => {
                    b.residual.record(&self.gpu, &mut encoder, WORKGROUP, most(|m| m.dofs), all);
                    b.csr.record(&self.gpu, &mut encoder, WORKGROUP, most(|m| m.nonzeros), all);
                }
            }
        }
        self.submit(encoder)?;
        self.gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Kernel { kernel: "replay".into(), message: e.to_string() })?;
        Ok(())
    }

    /// Submits `encoder`'s commands, counted in [`GpuWorld::submits`]. A submission that fails
    /// may have lost a step's start: the device's committed states are not trusted after it.
    fn submit(&mut self, encoder: wgpu::CommandEncoder) -> Result<(), GpuError> {
        if !self.scattered.iter().all(|s| s.is_empty()) {
            // Queued after this submission's encoder was made: they go first, in one of their own.
            let mut first = self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("scatter_reals") });
            self.record_scattered(&mut first);
            self.gpu.submit(first)?;
            self.submits += 1;
        }
        let submitted = self.gpu.submit(encoder);
        self.prologue_submitted();
        if let Err(e) = submitted {
            self.forget_committed();
            return Err(e);
        }
        self.submits += 1;
        Ok(())
    }

    /// A command encoder with the step's start at its head when it is waiting
    /// ([`GpuWorld::begin_step`]), and the uploads deferred behind it: every submission of the
    /// world's batches starts from one.
    fn encoder(&mut self, label: &str) -> wgpu::CommandEncoder {
        let mut encoder = self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        self.record_prologue(&mut encoder);
        for (staging, target, offset, size) in self.deferred.take().unwrap_or_default() {
            encoder.copy_buffer_to_buffer(&staging, 0, &target, offset, size);
        }
        self.record_scattered(&mut encoder);
        encoder
    }

    /// A body's element results as the last pass left them (forces, then the packed tangent):
    /// for the parity tests and `bifirst bench`.
    pub fn element_results(&mut self, body: usize) -> Result<Vec<Real>, GpuError> {
        let (b, m) = self.place[body];
        let (range, stride) = (self.batches[b].members[m], self.batches[b].stride as u64);
        let source = self.batches[b].element_out.clone();
        self.read_reals(("element_force_tangent", &source), range.element_start as u64 * stride, range.elements as u64 * stride)
    }

    /// A body's stiffness values `ξ K` as the device holds them (the last tangent pass or a
    /// device Newton call's hand-back left them): for the parity tests.
    pub fn stiffness_values(&mut self, body: usize) -> Result<Vec<Real>, GpuError> {
        let (b, m) = self.place[body];
        let range = self.batches[b].members[m];
        let source = self.batches[b].values.clone();
        self.read_reals(("assemble_csr", &source), range.nonzero_start as u64, range.nonzeros as u64)
    }

    /// `count` reals of `source` from real `first`, read back in a submission of their own
    /// (`kernel` names the buffer's writer in an error).
    fn read_reals(&mut self, (kernel, source): (&str, &Buffer), first: u64, count: u64) -> Result<Vec<Real>, GpuError> {
        let real = self.gpu.precision.size() as u64;
        let (start, size) = (first * real, count * real);
        let staging = self.gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some(kernel), size: size.max(8), usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST, mapped_at_creation: false });
        let mut encoder = self.encoder(kernel);
        encoder.copy_buffer_to_buffer(source, start, &staging, 0, size);
        self.submit(encoder)?;
        self.traffic.down += size;
        Ok(from_device(self.gpu.precision, &self.gpu.read_range(kernel, &staging, size)?))
    }

    /// Records the read-back's copies, submits once, maps once and hands the
    /// mapped bytes to `unpack`. The device's work counts as `elements`, the host's packing and
    /// unpacking as `transfer`.
    fn read_back(&mut self, encoder: wgpu::CommandEncoder, readback: &ReadBack, kernel: &str, times: &mut PhaseTimes, started: Instant, unpack: impl FnOnce(&[u8])) -> Result<(), GpuError> {
        let target = self.readback.clone();
        self.read_back_into(&target, encoder, readback, kernel, times, started, unpack)
    }

    /// [`GpuWorld::read_back`] into another mappable buffer.
    #[allow(clippy::too_many_arguments)]
    fn read_back_into(&mut self, target: &Buffer, mut encoder: wgpu::CommandEncoder, readback: &ReadBack, kernel: &str, times: &mut PhaseTimes, started: Instant, unpack: impl FnOnce(&[u8])) -> Result<(), GpuError> {
        for c in &readback.copies {
            let b = &self.batches[c.batch];
            let source = match c.what {
                Source::Failure => &b.failure,
                Source::DofOut => &b.dof_out,
                Source::Values => &b.values,
                Source::Energy => &b.energy,
                Source::Displacement => &b.u,
                Source::NewtonState => &b.newton.as_ref().expect("a batch whose Newton states are read has them").state,
                Source::MemberEnergy => &b.newton.as_ref().expect("a batch whose Newton energies are read has them").member_energy,
                Source::NewtonForces => &b.newton.as_ref().expect("a batch whose Newton forces are read has them").packed_forces,
                Source::Summary => &b.newton.as_ref().expect("a batch whose summaries are read has them").summary,
                Source::Boxes => &b.newton.as_ref().expect("a batch whose summaries are read has them").boxes,
                Source::Committed => b.newton.as_ref().expect("a batch whose committed states are read has them").resident.committed(),
                Source::CommittedEnergy => b.newton.as_ref().expect("a batch whose committed states are read has them").resident.committed_energy(),
                Source::TallyRows => &b.newton.as_ref().expect("a batch whose summaries are read has them").rows,
                Source::Tally => &b.newton.as_ref().expect("a batch whose summaries are read has them").tally,
                Source::Factored => &b.newton.as_ref().expect("a batch whose refactorisations are read has them").u_factored,
            };
            encoder.copy_buffer_to_buffer(source, c.source.start, target, c.target, c.source.end - c.source.start);
        }
        for (source, offset, bytes, at) in &readback.others {
            encoder.copy_buffer_to_buffer(source, *offset, target, *at, *bytes);
        }
        let submitted = Instant::now();
        self.submit(encoder)?;
        let end = readback.end;
        let mut mapped = submitted;
        if end == 0 {
            self.gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Kernel { kernel: kernel.into(), message: e.to_string() })?;
            mapped = Instant::now();
            unpack(&[]);
        } else {
            self.gpu.read_range_with(kernel, target, end, |bytes| {
                mapped = Instant::now();
                unpack(bytes);
            })?;
        }
        self.traffic.down += end;
        times.transfer += (submitted - started).as_secs_f64() + mapped.elapsed().as_secs_f64();
        times.elements += (mapped - submitted).as_secs_f64();
        Ok(())
    }
}

/// Takes an evaluation pass's results from the read-back (`landing` from
/// `GpuWorld::record_evaluation`).
fn unpack_evaluation(precision: Precision, list: &mut [Evaluation], landing: &[[usize; 3]], bytes: &[u8]) {
    let real = precision.size();
    for (e, &[flags_at, dof_at, values_at]) in list.iter_mut().zip(landing) {
        e.failure = failure_of(bytemuck::pod_read_unaligned(&bytes[flags_at..flags_at + 8]));
        if e.failure.is_some() {
            continue;
        }
        if let Some(out) = e.dof_out.as_deref_mut() {
            copy_from_device(precision, &bytes[dof_at..dof_at + out.len() * 2 * real], bytemuck::cast_slice_mut(out));
        }
        if e.tangent && !e.values.is_empty() {
            copy_from_device(precision, &bytes[values_at..values_at + e.values.len() * real], e.values);
        }
    }
}

/// A member's failure flags (its lowest inverted element, its lowest non-finite one) as the
/// failure they report.
fn failure_of(flags: [u32; 2]) -> Option<ElementFailure> {
    if flags[0] != NO_FAILURE {
        Some(ElementFailure::Inverted(flags[0] as usize))
    } else if flags[1] != NO_FAILURE {
        Some(ElementFailure::NonFinite(flags[1] as usize))
    } else {
        None
    }
}

/// Copies `pieces` one after the other into `target` (`starts`: where each begins, then their
/// total), in stretches of at most [`COPY_STRETCH`] bytes on every thread.
fn copy_pieces(target: wgpu::WriteOnly<[u8]>, pieces: &[&[u8]], starts: &[usize]) {
    let (stretches, mut tail) = target.into_chunks::<COPY_STRETCH>();
    let stretches: Vec<wgpu::WriteOnly<[u8; COPY_STRETCH]>> = stretches.into_iter().collect();
    let whole = stretches.len() * COPY_STRETCH;
    stretches.into_par_iter().enumerate().for_each(|(k, stretch)| copy_joined(&mut stretch.into(), k * COPY_STRETCH, pieces, starts));
    copy_joined(&mut tail, whole, pieces, starts);
}

/// Fills `target` with the bytes from `from` on of the pieces laid end to end (`starts`: where
/// each begins, then their total).
fn copy_joined(target: &mut wgpu::WriteOnly<[u8]>, from: usize, pieces: &[&[u8]], starts: &[usize]) {
    let end = from + target.len();
    let mut k = starts.partition_point(|&s| s <= from) - 1;
    let mut at = from;
    while at < end {
        let (piece, start) = (pieces[k], starts[k]);
        let take = (start + piece.len()).min(end) - at;
        target.slice(at - from..at - from + take).copy_from_slice(&piece[at - start..at - start + take]);
        at += take;
        k += 1;
    }
}

/// The dofs of consecutive members of a batch (a run, or one member) in its dof arrays.
fn dof_span(members: &[MemberRange], run: &[usize]) -> std::ops::Range<usize> {
    let (first, last) = (&members[run[0]], &members[*run.last().expect("a run has members")]);
    first.dof_start as usize..(last.dof_start + last.dofs) as usize
}

/// Sorted member indices cut into runs of consecutive members.
fn runs(members: &[usize]) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = Vec::new();
    for &m in members {
        match out.last_mut() {
            Some(run) if run.last() == Some(&(m.wrapping_sub(1))) => run.push(m),
            _ => out.push(vec![m]),
        }
    }
    out
}

/// A batch's members laid end to end: their ranges, the distinct materials, the geometry and
/// connectivity (node numbers shifted to the batch's), the gather maps (entries shifted to the
/// batch's element results), the totals, and the free dofs with each member's range of them.
struct BatchLayout {
    ranges: Vec<MemberRange>,
    materials: Vec<MaterialParams<Real>>,
    geometry: Vec<Real>,
    connectivity: Vec<u32>,
    csr_start: Vec<u32>,
    csr: Vec<u32>,
    dof_start: Vec<u32>,
    dof: Vec<u32>,
    elements: usize,
    dofs: usize,
    nnz: usize,
    history: usize,
    free_dofs: Vec<u32>,
    free_range: Vec<(u32, u32)>,
}

impl BatchLayout {
    fn of(members: &[usize], bodies: &[WorldBody], stride: usize, dim: usize) -> Self {
        let mut ranges = Vec::with_capacity(members.len());
        let mut materials: Vec<MaterialParams<Real>> = Vec::new();
        let (mut geometry, mut connectivity) = (Vec::new(), Vec::new());
        let (mut csr_start, mut csr, mut dof_start, mut dof) = (vec![0u32], Vec::new(), vec![0u32], Vec::new());
        let (mut elements, mut dofs, mut nnz, mut history) = (0usize, 0usize, 0usize, 0usize);
        let (mut free_dofs, mut free_range) = (Vec::new(), Vec::with_capacity(members.len()));
        for &b in members {
            let body = &bodies[b];
            let free_start = free_dofs.len() as u32;
            free_dofs.extend(body.dofs.free_pairs().map(|(d, _)| d as u32));
            free_range.push((free_start, free_dofs.len() as u32 - free_start));
            let params = MaterialParams::of(body.model);
            let material = materials.iter().position(|m| *m == params).unwrap_or_else(|| {
                materials.push(params);
                materials.len() - 1
            });
            let element_start = elements;
            let node_start = (dofs / dim) as u32;
            for p in &body.geometry.points {
                geometry.extend(p.dn_dx.iter().flatten());
                geometry.push(p.dv);
            }
            connectivity.extend(body.mesh.connectivity.iter().map(|&n| n + node_start));
            let shift = (element_start * stride) as u32;
            let (gather_base, dof_base) = (csr.len() as u32, dof.len() as u32);
            csr.extend(body.gather.csr.iter().map(|&j| j + shift));
            csr_start.extend(body.gather.csr_start[1..].iter().map(|&s| s + gather_base));
            dof.extend(body.gather.dof.iter().map(|&j| j + shift));
            dof_start.extend(body.gather.dof_start[1..].iter().map(|&s| s + dof_base));
            let body_dofs = body.mesh.nodes.len() * dim;
            ranges.push(MemberRange {
                element_start: element_start as u32,
                elements: body.mesh.element_count() as u32,
                nonzero_start: nnz as u32,
                nonzeros: body.pattern.nnz() as u32,
                dof_start: dofs as u32,
                dofs: body_dofs as u32,
                material: material as u32,
                history: if body.viscous { history as u32 } else { NO_HISTORY },
            });
            if body.viscous {
                history += 1 + HISTORY * body.geometry.points.len();
            }
            elements += body.mesh.element_count();
            dofs += body_dofs;
            nnz += body.pattern.nnz();
        }
        Self { ranges, materials, geometry, connectivity, csr_start, csr, dof_start, dof, elements, dofs, nnz, history, free_dofs, free_range }
    }
}

impl Batch {
    fn new(gpu: &Arc<Gpu>, variant: ElementVariant, members: Vec<usize>, bodies: &[WorldBody], coefficients: &Buffer, max_bytes: u64, traffic: &mut Traffic) -> Result<Self, GpuError> {
        let kind = variant.kind;
        let dim = kind.dim();
        let stride = element_out_stride(kind.nodes() * dim);
        let precision = gpu.precision;
        let real = precision.size();
        let BatchLayout { ranges, materials, geometry, connectivity, csr_start, csr, dof_start, dof, elements, dofs, nnz, history, free_dofs, free_range } = BatchLayout::of(&members, bodies, stride, dim);
        if (elements * stride) as u64 >= u64::from(u32::MAX) {
            return Err(GpuError::Kernel { kernel: "element_force_tangent".into(), message: format!("{elements} elements of {} are too many for 32-bit indices", kind.name()) });
        }
        let storage = BufferUsages::STORAGE;
        let (read, write, copy_out) = (storage, storage | BufferUsages::COPY_DST, storage | BufferUsages::COPY_SRC);
        let mut uploaded = |label: &str, bytes: &[u8]| {
            traffic.up += bytes.len() as u64;
            buffer_init(gpu, label, bytes, read)
        };
        let material_buffer = uploaded("materials", &to_device(precision, bytemuck::cast_slice(&materials)));
        let geometry = uploaded("geometry", &to_device(precision, &geometry));
        let connectivity = uploaded("connectivity", bytemuck::cast_slice(&connectivity));
        let member_buffer = uploaded("members", bytemuck::cast_slice(&ranges));
        let csr_start = uploaded("csr gather start", bytemuck::cast_slice(&csr_start));
        let csr = uploaded("csr gather", bytemuck::cast_slice(&csr));
        let dof_start = uploaded("dof gather start", bytemuck::cast_slice(&dof_start));
        let dof = uploaded("dof gather", bytemuck::cast_slice(&dof));
        let u = buffer(gpu, "u", dofs * real, write | BufferUsages::COPY_SRC);
        // Every dof's reference coordinate, in member order: where `newton_summary` places nodes
        // (it goes up with the batch's Newton buffers, if a call needs them).
        let reference: Vec<Real> = members.iter().flat_map(|&i| bodies[i].mesh.nodes.iter().flat_map(move |x| x[..dim].iter().copied())).collect();
        assert_eq!(reference.len(), dofs, "a batch's dofs are its members' nodes");
        let step = buffer(gpu, "step", dofs * 4 * real, write);
        let failure = buffer(gpu, "failure", members.len() * 8, write | BufferUsages::COPY_SRC);
        let active = buffer(gpu, "active", members.len() * 8, write);
        let element_out = buffer(gpu, "element_out", elements * stride * real, copy_out);
        let values = buffer(gpu, "values", nnz * real, copy_out);
        let dof_out = buffer(gpu, "dof_out", dofs * 2 * real, copy_out | BufferUsages::COPY_DST);
        let energy = buffer(gpu, "energy", elements * real, copy_out);
        let history = buffer(gpu, "history", history * real, write);
        let v = Some(variant);
        let element_buffers =
            [("geometry", &geometry), ("connectivity", &connectivity), ("u", &u), ("element_out", &element_out), ("failure", &failure), ("members", &member_buffer), ("materials", &material_buffer), ("jobs", &active), ("history", &history)];
        let residual_bindings = [("element_out", &element_out), ("gather_start", &dof_start), ("gather", &dof), ("coefficients", coefficients), ("u", &u), ("step", &step), ("dof_out", &dof_out), ("members", &member_buffer), ("jobs", &active)];
        let energy_bindings = [("geometry", &geometry), ("connectivity", &connectivity), ("u", &u), ("energy", &energy), ("members", &member_buffer), ("materials", &material_buffer), ("jobs", &active)];
        // The pipelines compile in parallel: a software adapter compiles each on the CPU.
        let tangent = {
            let (gpu, buffers) = (gpu.clone(), element_buffers.map(|(name, b)| (name, b.clone())));
            Deferred::spawn(move || Pass::new(&gpu, "element_force_tangent", "main", v, &buffers.each_ref().map(|(name, b)| (*name, b))))
        };
        let (forces, csr_pass, residual, element_energy) = std::thread::scope(|scope| {
            let forces = scope.spawn(|| Pass::new(gpu, "element_force_tangent", "forces", v, &element_buffers));
            let csr = scope.spawn(|| {
                Pass::new(gpu, "assemble_csr", "main", None, &[("element_out", &element_out), ("gather_start", &csr_start), ("gather", &csr), ("coefficients", coefficients), ("values", &values), ("members", &member_buffer), ("jobs", &active)])
            });
            let residual = scope.spawn(|| Pass::new(gpu, "assemble_residual", "main", None, &residual_bindings));
            let energy = Pass::new(gpu, "element_energy", "main", v, &energy_bindings);
            let join = |h: std::thread::ScopedJoinHandle<'_, Result<Pass, GpuError>>| h.join().expect("a pipeline compiles without panicking");
            Ok::<_, GpuError>((join(forces)?, join(csr)?, join(residual)?, energy?))
        })?;
        let (patterns, pattern_start) = distinct_patterns(&members, bodies);
        let (inverse_slot, inverse_entries) = newton::inverse_slots(&free_range.iter().map(|&(_, n)| n as usize).collect::<Vec<_>>(), real, max_bytes);
        Ok(Self {
            members: ranges,
            stride,
            tangent_elements_per_group: super::shaders::tangent_workgroup(gpu.precision, gpu.device.limits().max_compute_workgroup_storage_size) as usize / crate::element::shape::quadrature(kind).len(),
            u_host: vec![0.0; dofs],
            step_host: vec![0.0; 4 * dofs],
            dof_out_host: vec![Real::NAN; 2 * dofs],
            step_pending: vec![false; members.len()],
            u,
            reference,
            patterns,
            pattern_start,
            step,
            failure,
            active,
            element_out,
            values,
            dof_out,
            energy,
            history,
            member_buffer,
            free_dofs,
            free_range,
            handed: vec![None; members.len()],
            inverse_slot,
            inverse_entries,
            newton: None,
            forces,
            tangent,
            csr: csr_pass,
            residual,
            element_energy,
        })
    }

    /// Elements, dofs and stiffness non-zeros of the batch.
    fn totals(&self) -> (usize, usize, usize) {
        self.members.iter().fold((0, 0, 0), |(e, d, n), m| (e + m.elements as usize, d + m.dofs as usize, n + m.nonzeros as usize))
    }
}

/// Reals as the device stores them.
pub fn to_device(precision: Precision, reals: &[Real]) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::cast_slice(reals).to_vec(),
        Precision::F32 => bytemuck::cast_slice(&reals.iter().map(|&x| x as f32).collect::<Vec<f32>>()).to_vec(),
    }
}

/// Reals read back from the device into `out` (of `bytes`' length in reals), without a vector
/// between: a read-back lands in every iterate's displacements and residuals.
pub fn copy_from_device(precision: Precision, bytes: &[u8], out: &mut [Real]) {
    match precision {
        Precision::F64 => bytemuck::cast_slice_mut::<Real, u8>(out).copy_from_slice(bytes),
        Precision::F32 => {
            for (x, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                *x = Real::from(f32::from_ne_bytes(b.try_into().expect("four bytes")));
            }
        }
    }
}

/// Reals read back from the device (copied: mapped bytes need not be aligned for f64).
pub fn from_device(precision: Precision, bytes: &[u8]) -> Vec<Real> {
    let mut out = vec![0.0; bytes.len() / precision.size()];
    copy_from_device(precision, bytes, &mut out);
    out
}

/// The members' stiffness patterns laid end to end once each (bodies that share one, the grains
/// of a shape, by address), and where each member's starts.
fn distinct_patterns(members: &[usize], bodies: &[WorldBody]) -> (Vec<u32>, Vec<u32>) {
    let mut seen: std::collections::HashMap<*const StiffnessPattern, u32> = std::collections::HashMap::new();
    let mut patterns = Vec::new();
    let starts = members
        .iter()
        .map(|&i| {
            let pattern = bodies[i].pattern;
            *seen.entry(std::ptr::from_ref(pattern)).or_insert_with(|| {
                let start = patterns.len() as u32;
                patterns.extend_from_slice(&pattern.col_ptr);
                patterns.extend_from_slice(&pattern.row_idx);
                start
            })
        })
        .collect();
    (patterns, starts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretches_of_a_joined_upload_take_the_pieces_bytes_across_their_ends() {
        // Pieces of odd lengths (one empty), copied in stretches of 7 bytes and a tail, as
        // `upload_pieces` copies them in stretches of `COPY_STRETCH`.
        let data: Vec<u8> = (0..=255).cycle().take(100).collect();
        let pieces: Vec<&[u8]> = vec![&data[0..13], &data[13..13], &data[13..14], &data[14..60], &data[60..100]];
        let mut starts = vec![0];
        for piece in &pieces {
            starts.push(starts.last().unwrap() + piece.len());
        }
        let mut target = vec![0u8; 100];
        for (k, stretch) in target.chunks_mut(7).enumerate() {
            copy_joined(&mut stretch.into(), 7 * k, &pieces, &starts);
        }
        assert_eq!(target, data);
    }
}
