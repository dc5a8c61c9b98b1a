//! The `uzawa_sweep` and `uzawa_judge` kernels (`shaders/uzawa_sweep.wgsl`,
//! `shaders/uzawa_judge.wgsl`): the Gauss-Seidel Uzawa iterations of a Newton round on the
//! device, for every group's contact problem ([`Problem`]) at once, judged there. CPU twins:
//! [`crate::contact::uzawa::uzawa_sweep`] and [`crate::cpu::uzawa_judge`];
//! [`crate::contact::uzawa::solve`] is the whole iteration this one repeats.
//!
//! Two ways, both with the iterates, stopping rule ([`crate::contact::uzawa::Judge`]) and
//! iteration counts of the CPU's plain sweeps, a problem that stops keeping the reactions of
//! that sweep, and the host reading back only where each problem stands and the reactions:
//! - *Whole* (`uzawa_solve`), when every colour of the round fits a workgroup's share
//!   ([`SOLVE_WIDEST`]; grains): one workgroup per problem runs its sweeps and judgements, so a
//!   Newton round's Uzawa iterations are one dispatch and one submit (more only past
//!   [`SOLVE_SWEEPS`] sweeps).
//! - *Colour by colour* (`uzawa_sweep`, `uzawa_judge`), for larger colours: the problems are
//!   independent (their points share no body), so colour `c` of the round is colour `c` of
//!   every problem, and a sweep is one dispatch per colour across the device, then one of the
//!   judge. Sweeps go to the device in chunks, one submit each.

use super::world::{buffer, Traffic};
use super::{Gpu, GpuError};
use crate::contact::uzawa::{Colours, Delassus, NodalMap, Outcome, Problem, LOCAL_STEPS, SETTLE};
use crate::precision::{Precision, Real};
use bytemuck::{Pod, Zeroable};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use wgpu::{BindGroup, Buffer, BufferUsages};

const KERNEL: &str = "uzawa_sweep";
const JUDGE: &str = "uzawa_judge";
const SOLVE: &str = "uzawa_solve";
const UNPACK: &str = "planar_unpack";
const WORKGROUP: u32 = 64;
/// Sweeps in the first chunk of a solve; each further chunk doubles, up to [`LAST_CHUNK`]: a
/// warm-started problem often converges in a few sweeps, a hard one needs hundreds.
const FIRST_CHUNK: usize = 4;
const LAST_CHUNK: usize = 64;
/// Dispatches of a whole solve in the last submission; the first has one, each further one
/// doubles: a solve that a software adapter's loop guard cuts into a few hundred sweeps a
/// dispatch took a submission per dispatch, 27-36 in a step of a pressed packing.
pub const LAST_DISPATCHES: usize = 16;

/// The largest colour (points) that a round's problems may have to be solved whole, one
/// workgroup per problem (`uzawa_solve`): beyond it, a colour's points are better spread over
/// the device by `uzawa_sweep`.
pub const SOLVE_WIDEST: usize = 4 * JUDGE_WORKGROUP;

/// Sweeps one dispatch of `uzawa_solve` may take before the host looks (an interrupt waits for
/// at most this many).
pub const SOLVE_SWEEPS: usize = 512;

/// Loop iterations one invocation may run on a software adapter. llvmpipe (lavapipe) ends every
/// loop of an invocation, silently, once their iterations together pass 65 535 (gallivm's
/// `LP_MAX_TGSI_LOOP_ITERATIONS`, a guard against endless loops): a whole solve of a dense
/// problem (one body's points, a colour each) stopped after a few dozen sweeps with the problem
/// live, or judged converged on reactions the cut loops had left wrong.
pub const SOFTWARE_LOOP_BUDGET: usize = 60_000;

/// Dispatches of `uzawa_solve` a device Newton increment records on a software adapter, whose
/// dispatches take fewer sweeps ([`SOFTWARE_LOOP_BUDGET`]) and cost even when every problem has
/// stopped: enough that a grain cluster's solve mostly runs to its end (doc/benchmarks.md,
/// "Figures behind constants"); one cut short hands its group back. A hardware GPU takes every
/// sweep in one dispatch.
pub const SOFTWARE_SOLVE_DISPATCHES: usize = 4;

/// An upper bound on the loop iterations of one `uzawa_solve` invocation per sweep of a
/// problem: its share of each colour's visits (the row of W and the local steps of each), the
/// colour and sweep loops, and its share of the nodal sums and their reduction.
pub fn solve_loops_per_sweep(w: &Delassus, colours: &Colours, nodal: &NodalMap) -> usize {
    let share = |n: usize| n.div_ceil(JUDGE_WORKGROUP);
    let widest_row = w.rows.iter().map(Vec::len).max().unwrap_or(0);
    let visit = widest_row + 1 + LOCAL_STEPS + 1;
    let colour_loops: usize = (0..colours.count()).map(|c| 2 + share(colours.colour(c).len()) * visit).sum();
    let mut per_node = vec![0usize; nodal.nodes];
    for term in nodal.terms.iter().flatten() {
        per_node[term.0 as usize] += 1;
    }
    let node_loops = share(nodal.nodes) * (per_node.iter().max().copied().unwrap_or(0) + 2);
    2 + colour_loops + node_loops + 2 + JUDGE_WORKGROUP.ilog2() as usize
}

/// Whether problems whose widest colour has `widest` points and whose sweep runs at most
/// `loops_per_sweep()` loop iterations ([`solve_loops_per_sweep`], counted only where it
/// matters) are solved whole, one workgroup for all their sweeps: colours within
/// [`SOLVE_WIDEST`], and on a software adapter a sweep within its loop guard
/// ([`SOFTWARE_LOOP_BUDGET`]); else colour by colour.
pub fn solved_whole(widest: usize, loops_per_sweep: impl FnOnce() -> usize, software: bool) -> bool {
    widest <= SOLVE_WIDEST && (!software || loops_per_sweep() <= SOFTWARE_LOOP_BUDGET)
}

/// A contact point's data for the kernel (`struct UzawaLocal` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UzawaLocal<R> {
    pub v_free: [R; 3],
    pub shift: R,
    pub mu: R,
    pub rho: R,
    pub floor: R,
    pub settle: R,
}

// SAFETY: `repr(C)` with fields all of type `R`: no padding, and any bit pattern of `R` (f32 or
// f64) is valid.
unsafe impl<R: Pod> Zeroable for UzawaLocal<R> {}
unsafe impl<R: Pod> Pod for UzawaLocal<R> {}

/// The points of one colour (`struct ColourRange` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct ColourRange {
    pub start: u32,
    pub count: u32,
}

/// A contact problem of a device solve, for `uzawa_judge` (`struct UzawaProblem` in the
/// shader): its points, its nodes (where its reactions land, [`crate::contact::uzawa::NodalMap`])
/// and its stopping rule.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UzawaProblem<R> {
    pub point_start: u32,
    pub point_end: u32,
    pub node_start: u32,
    pub node_end: u32,
    pub max_iterations: u32,
    /// For `uzawa_solve`: its colours' starts in the colour-start array, and how many.
    pub colour_first: u32,
    pub colours: u32,
    pub pad: u32,
    pub tolerance: R,
    pub floor: R,
}

/// Where a problem's device iterations stand (`struct UzawaJudgeState` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UzawaJudgeState<R> {
    /// [`JUDGE_LIVE`], [`JUDGE_CONVERGED`] or [`JUDGE_SPENT`].
    pub status: u32,
    /// Sweeps judged.
    pub iterations: u32,
    pub pad: [u32; 2],
    /// The last sweep's largest change of a nodal force; negative before the first sweep.
    pub previous: R,
    /// That change over its scale ([`Outcome::change`]).
    pub change: R,
}

// SAFETY: `repr(C)`, the `u32` fields fill whole 16 and 32 bytes before the reals, so that
// neither f32 nor f64 leaves padding, and any bit pattern is valid.
unsafe impl<R: Pod> Zeroable for UzawaProblem<R> {}
unsafe impl<R: Pod> Pod for UzawaProblem<R> {}
unsafe impl<R: Pod> Zeroable for UzawaJudgeState<R> {}
unsafe impl<R: Pod> Pod for UzawaJudgeState<R> {}

impl UzawaJudgeState<Real> {
    /// Before the first sweep: live, unless the problem may take no sweep or has no point.
    pub fn start(problem: &UzawaProblem<Real>) -> Self {
        let live = problem.max_iterations > 0 && problem.point_end > problem.point_start;
        Self { status: if live { JUDGE_LIVE } else { JUDGE_SPENT }, previous: -1.0, ..Default::default() }
    }

    /// The outcome the CPU's iterations would report.
    pub fn outcome(&self) -> Outcome {
        Outcome { iterations: self.iterations as usize, converged: self.status == JUDGE_CONVERGED, change: self.change, ..Outcome::default() }
    }
}

/// `UzawaJudgeState.status`: still sweeping, converged, `max_iterations` spent.
pub const JUDGE_LIVE: u32 = 0;
pub const JUDGE_CONVERGED: u32 = 1;
pub const JUDGE_SPENT: u32 = 2;

/// Invocations of a `uzawa_judge` or `uzawa_solve` workgroup (one problem).
pub const JUDGE_WORKGROUP: usize = 64;

/// The number of problems, and the sweeps a dispatch of `uzawa_solve` may take (`struct
/// SolveCount` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct SolveCount {
    pub problems: u32,
    pub sweeps: u32,
    pub pad: [u32; 2],
}

/// The number of blocks `planar_unpack` writes (`struct UnpackCount` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct UnpackCount {
    pub blocks: u32,
    pub pad: [u32; 3],
}

/// Where the reactions of a solve's problems land, for `uzawa_judge`: per node (numbered over
/// all problems, each problem's in a run), the points that act on it in ascending order, each
/// with its coefficient, and every point's frame.
#[derive(Debug, Clone, Default)]
pub struct NodeGather {
    /// Node `n`'s points are `points[start[n]..start[n + 1]]`.
    pub start: Vec<u32>,
    pub points: Vec<u32>,
    pub coefs: Vec<Real>,
    /// Per point, its frame `[n, t1, t2]` row by row.
    pub frames: Vec<Real>,
    /// Problem `k`'s nodes are `node_offsets[k]..node_offsets[k + 1]`.
    pub node_offsets: Vec<u32>,
}

impl NodeGather {
    /// The gather of `problems`, their points numbered one after the other.
    pub fn of(problems: &[Problem]) -> Self {
        let mut g = NodeGather { start: vec![0], node_offsets: vec![0], ..Default::default() };
        let mut point0 = 0u32;
        for p in problems {
            let nodal = p.nodal;
            let mut count = vec![0u32; nodal.nodes + 1];
            for terms in &nodal.terms {
                for &(node, _) in terms {
                    count[node as usize + 1] += 1;
                }
            }
            for n in 0..nodal.nodes {
                count[n + 1] += count[n];
            }
            let base = g.points.len() as u32;
            g.start.extend(count[1..].iter().map(|&c| base + c));
            g.points.resize(base as usize + count[nodal.nodes] as usize, 0);
            g.coefs.resize(g.points.len(), 0.0);
            // Point by point, so that each node lists its points in ascending order.
            for (i, terms) in nodal.terms.iter().enumerate() {
                for &(node, coef) in terms {
                    let slot = (base + count[node as usize]) as usize;
                    count[node as usize] += 1;
                    g.points[slot] = point0 + i as u32;
                    g.coefs[slot] = coef;
                }
            }
            g.frames.extend(nodal.frames.iter().flatten().flatten());
            g.node_offsets.push(g.node_offsets.last().expect("starts at 0") + nodal.nodes as u32);
            point0 += p.local.len() as u32;
        }
        g
    }
}

/// The round's problems in one set of arrays: W (its blocks and rows), the colour order and
/// where the reactions land, which change only when a problem's Delassus operator does.
#[derive(Default)]
struct Layout {
    /// Each problem's W version and points: the layout serves a round with the same key.
    key: Vec<(u64, usize)>,
    blocks: Vec<Real>,
    /// The blocks' planar upper-left 2 x 2 where every block's third row and column are
    /// zeros (+0.0; a 2D round: [`planar_of`]): what goes up, 4 reals a block, which
    /// `planar_unpack` writes out whole on the device. W's blocks were a third of the bytes a
    /// pressed packing moved a step on lavapipe.
    planar: Option<Vec<Real>>,
    /// The same of the points' frames (in 2D `[n, t1, 0]`, rows `(x, y, 0)`).
    planar_frames: Option<Vec<Real>>,
    row_start: Vec<u32>,
    row_entries: Vec<[u32; 2]>,
    order: Vec<u32>,
    ranges: Vec<ColourRange>,
    /// Each problem's first point, and the end.
    offsets: Vec<usize>,
    nodes: NodeGather,
    /// For `uzawa_solve`: each problem's points colour by colour, where its colours start
    /// (`colours + 1` entries per problem, the first at `colour_first[k]`), and the largest
    /// colour of any problem.
    solve_order: Vec<u32>,
    colour_start: Vec<u32>,
    colour_first: Vec<u32>,
    widest: usize,
}

/// The planar upper-left 2 x 2 of each 3 x 3 block of `whole` (row-major), where every third
/// row and column holds +0.0 only, bit for bit: what `planar_unpack` writes out again as they
/// were.
fn planar_of(whole: &[Real]) -> Option<Vec<Real>> {
    let flat = whole.chunks_exact(9).all(|w| [2, 5, 6, 7, 8].iter().all(|&e| w[e].to_bits() == 0));
    flat.then(|| whole.chunks_exact(9).flat_map(|w| [w[0], w[1], w[3], w[4]]).collect())
}

fn key_of(problems: &[Problem]) -> Vec<(u64, usize)> {
    problems.iter().map(|p| (p.w.version, p.local.len())).collect()
}

impl Layout {
    fn of(problems: &[Problem]) -> Self {
        let mut m = Layout { key: key_of(problems), row_start: vec![0], offsets: vec![0], nodes: NodeGather::of(problems), ..Default::default() };
        for p in problems {
            let (point0, block0) = (*m.offsets.last().expect("starts at 0") as u32, (m.blocks.len() / 9) as u32);
            m.blocks.extend(p.w.blocks.iter().flatten());
            for row in &p.w.rows {
                m.row_entries.extend(row.iter().map(|&(j, b)| [point0 + j, block0 + b]));
                m.row_start.push(m.row_entries.len() as u32);
            }
            m.offsets.push(point0 as usize + p.local.len());
        }
        m.planar = planar_of(&m.blocks);
        m.planar_frames = planar_of(&m.nodes.frames);
        let colours = problems.iter().map(|p| p.colours.count()).max().unwrap_or(0);
        for c in 0..colours {
            let start = m.order.len() as u32;
            for (p, &offset) in problems.iter().zip(&m.offsets) {
                if c < p.colours.count() {
                    m.order.extend(p.colours.colour(c).iter().map(|&i| offset as u32 + i));
                }
            }
            m.ranges.push(ColourRange { start, count: m.order.len() as u32 - start });
        }
        for (p, &offset) in problems.iter().zip(&m.offsets) {
            m.colour_first.push(m.colour_start.len() as u32);
            for c in 0..p.colours.count() {
                m.colour_start.push(m.solve_order.len() as u32);
                m.solve_order.extend(p.colours.colour(c).iter().map(|&i| offset as u32 + i));
                m.widest = m.widest.max(p.colours.colour(c).len());
            }
            m.colour_start.push(m.solve_order.len() as u32);
        }
        m
    }

    fn points(&self) -> usize {
        *self.offsets.last().expect("starts at 0")
    }

    fn range(&self, k: usize) -> std::ops::Range<usize> {
        self.offsets[k]..self.offsets[k + 1]
    }

    /// What `uzawa_judge` needs of each problem.
    fn judged(&self, problems: &[Problem]) -> Vec<UzawaProblem<Real>> {
        let offsets = &self.nodes.node_offsets;
        problems
            .iter()
            .enumerate()
            .map(|(k, p)| UzawaProblem {
                point_start: self.offsets[k] as u32,
                point_end: self.offsets[k + 1] as u32,
                node_start: offsets[k],
                node_end: offsets[k + 1],
                max_iterations: p.max_iterations.min(u32::MAX as usize) as u32,
                colour_first: self.colour_first[k],
                colours: p.colours.count() as u32,
                pad: 0,
                tolerance: p.tolerance,
                floor: p.floor,
            })
            .collect()
    }
}

/// Device buffers, grown as rounds need more.
pub(crate) struct Buffers {
    /// Capacities: points, blocks, row entries, colours, problems, nodes, node entries,
    /// colour starts.
    points: usize,
    blocks: usize,
    entries: usize,
    colours: usize,
    problems: usize,
    nodes: usize,
    node_entries: usize,
    colour_entries: usize,
    pub(crate) block: Buffer,
    /// The blocks and the frames as they go up planar, for `planar_unpack`.
    unpacked: [Unpacked; 2],
    pub(crate) row_start: Buffer,
    pub(crate) row_entries: Buffer,
    pub(crate) locals: Buffer,
    order: Buffer,
    live: Buffer,
    pub(crate) r: Buffer,
    ranges: Buffer,
    pub(crate) judged: Buffer,
    pub(crate) states: Buffer,
    pub(crate) node_start: Buffer,
    pub(crate) node_points: Buffer,
    pub(crate) node_coefs: Buffer,
    pub(crate) frames: Buffer,
    solve_order: Buffer,
    colour_start: Buffer,
    count: Buffer,
    /// The reactions, then the problems' states.
    staging: Buffer,
    /// One per colour: the same buffers with that colour's range.
    bind_groups: Vec<BindGroup>,
    judge_group: BindGroup,
    solve_group: BindGroup,
}

/// A buffer of 3 x 3 blocks that may go up planar: the planar staging, the count, and
/// `planar_unpack`'s bind group that writes them out into the buffer.
struct Unpacked {
    planar: Buffer,
    count: Buffer,
    group: BindGroup,
}

/// Which of [`Buffers::unpacked`].
const BLOCKS: usize = 0;
const FRAMES: usize = 1;

/// The pipelines and buffers of the device's Uzawa sweeps.
pub struct UzawaSweeps {
    gpu: Arc<Gpu>,
    pipeline: wgpu::ComputePipeline,
    judge: wgpu::ComputePipeline,
    solve: wgpu::ComputePipeline,
    unpack: wgpu::ComputePipeline,
    /// How many planar blocks and frames went up and are not yet written out whole (0: none):
    /// the first pass recorded after staging writes them ([`UzawaSweeps::record_unpack`]).
    unpack_pending: [AtomicU32; 2],
    buffers: Option<Buffers>,
    /// What the device holds of the last round.
    layout: Layout,
    /// Whether the blocks the device holds are its own, built from its `K̄⁻¹`
    /// (`newton_contact`'s `delassus`), not the host's: a solve of the host's W sends them.
    blocks_built: bool,
    /// Stride of the colour ranges in their uniform buffer (the device's offset alignment).
    range_stride: u64,
    /// Sweeps a dispatch of the staged whole solve takes (`count.sweeps`).
    whole_sweeps: usize,
    pub submits: u64,
    /// Bytes moved so far.
    pub traffic: Traffic,
}

fn storage(gpu: &Gpu, label: &str, bytes: usize, extra: BufferUsages) -> Buffer {
    buffer(gpu, label, bytes, BufferUsages::STORAGE | BufferUsages::COPY_DST | extra)
}

impl UzawaSweeps {
    pub fn new(gpu: Arc<Gpu>) -> Result<Self, GpuError> {
        let pipeline = gpu.pipeline(KERNEL, None)?;
        let judge = gpu.pipeline(JUDGE, None)?;
        let solve = gpu.pipeline(SOLVE, None)?;
        let unpack = gpu.pipeline(UNPACK, None)?;
        let range_stride = (gpu.device.limits().min_uniform_buffer_offset_alignment as u64).max(std::mem::size_of::<ColourRange>() as u64);
        Ok(Self { gpu, pipeline, judge, solve, unpack, unpack_pending: Default::default(), buffers: None, layout: Layout::default(), blocks_built: false, range_stride, whole_sweeps: 0, submits: 0, traffic: Traffic::default() })
    }

    /// The most items of `bytes` each that one buffer of the device can bind.
    fn most(&self, bytes: usize) -> usize {
        let limits = self.gpu.device.limits();
        (limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) / bytes as u64) as usize
    }

    /// Makes sure the buffers hold the round (growing them by half again what it needs, within
    /// the device's limits) and that there is a bind group per colour; whether they are new
    /// (and hold nothing yet), or `None` when the round is too large for the device's buffers.
    fn reserve(&mut self, m: &Layout, problems: usize) -> Option<bool> {
        let real = self.gpu.precision.size();
        let local_bytes = std::mem::size_of::<UzawaLocal<f64>>() / 8 * real;
        let problem_bytes = std::mem::size_of::<UzawaProblem<f64>>();
        let (points, blocks, entries, colours) = (m.points(), m.blocks.len() / 9, m.row_entries.len(), m.ranges.len());
        let (nodes, node_entries, colour_entries) = (m.nodes.start.len() - 1, m.nodes.points.len(), m.colour_start.len());
        let limits = [self.most(local_bytes).min(self.most(9 * real)), self.most(9 * real), self.most(8), self.most(problem_bytes), self.most(4), self.most(real)];
        let uniform_limit = (self.gpu.device.limits().max_buffer_size / self.range_stride) as usize;
        if points > limits[0] || blocks > limits[1] || entries > limits[2] || colours > uniform_limit || problems > limits[3] || nodes >= limits[4] || node_entries > limits[5] || colour_entries > limits[4] {
            return None;
        }
        let fits = |b: &Buffers| b.points >= points && b.blocks >= blocks && b.entries >= entries && b.colours >= colours && b.problems >= problems && b.nodes >= nodes && b.node_entries >= node_entries && b.colour_entries >= colour_entries;
        if self.buffers.as_ref().is_some_and(fits) {
            return Some(false);
        }
        let grow = |n: usize, old: Option<usize>, limit: usize| old.unwrap_or(0).max(n + n / 2).clamp(1, limit.max(1));
        let old = self.buffers.as_ref();
        let points = grow(points, old.map(|b| b.points), limits[0]);
        let blocks = grow(blocks, old.map(|b| b.blocks), limits[1]);
        let entries = grow(entries, old.map(|b| b.entries), limits[2]);
        let colours = grow(colours, old.map(|b| b.colours), uniform_limit);
        let problems = grow(problems, old.map(|b| b.problems), limits[3]);
        let nodes = grow(nodes, old.map(|b| b.nodes), limits[4] - 1);
        let node_entries = grow(node_entries, old.map(|b| b.node_entries), limits[5]);
        let colour_entries = grow(colour_entries, old.map(|b| b.colour_entries), limits[4]);
        let gpu = &self.gpu;
        let none = BufferUsages::empty();
        let state_bytes = problems * std::mem::size_of::<UzawaJudgeState<Real>>();
        let block = storage(gpu, "uzawa blocks", blocks * 9 * real, none);
        let row_start = storage(gpu, "uzawa row starts", (points + 1) * 4, none);
        let row_entries = storage(gpu, "uzawa row entries", entries * 8, none);
        let locals = storage(gpu, "uzawa points", points * local_bytes, none);
        let order = storage(gpu, "uzawa colour order", points * 4, none);
        let live = storage(gpu, "uzawa live", points * 4, none);
        let r = storage(gpu, "uzawa reactions", points * 3 * real, BufferUsages::COPY_SRC);
        let dr = storage(gpu, "uzawa reaction changes", points * 3 * real, none);
        let ranges = buffer(gpu, "uzawa colours", colours * self.range_stride as usize, BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let judged = storage(gpu, "uzawa problems", problems * problem_bytes, none);
        let states = storage(gpu, "uzawa judge states", state_bytes, BufferUsages::COPY_SRC);
        let node_start = storage(gpu, "uzawa node starts", (nodes + 1) * 4, none);
        let node_points = storage(gpu, "uzawa node points", node_entries * 4, none);
        let node_coefs = storage(gpu, "uzawa node coefficients", node_entries * real, none);
        let frames = storage(gpu, "uzawa frames", points * 9 * real, none);
        let unpacked = [(&block, blocks), (&frames, points)].map(|(whole, count)| {
            let planar = storage(gpu, "uzawa planar blocks", count * 4 * real, none);
            let count = buffer(gpu, "uzawa unpack count", std::mem::size_of::<UnpackCount>(), BufferUsages::UNIFORM | BufferUsages::COPY_DST);
            let group = gpu.bind_named(&self.unpack, (UNPACK, "main", None), &[("planar", &planar), ("blocks", whole), ("count", &count)]);
            Unpacked { planar, count, group }
        });
        let solve_order = storage(gpu, "uzawa problem colours", points * 4, none);
        let colour_start = storage(gpu, "uzawa colour starts", colour_entries * 4, none);
        let count = buffer(gpu, "uzawa problem count", std::mem::size_of::<SolveCount>(), BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let staging = buffer(gpu, "uzawa read-back", points * 3 * real + state_bytes, BufferUsages::MAP_READ | BufferUsages::COPY_DST);
        // Each kernel's resources by the names it gives them (`Gpu::bind_named`); a sweep's bind
        // group per colour, with that colour's range of `ranges`.
        let bind_groups = (0..colours)
            .map(|c| {
                let range = wgpu::BufferBinding { buffer: &ranges, offset: c as u64 * self.range_stride, size: wgpu::BufferSize::new(std::mem::size_of::<ColourRange>() as u64) };
                let whole = [("blocks", &block), ("row_start", &row_start), ("row_entries", &row_entries), ("locals", &locals), ("order", &order), ("live", &live), ("r", &r), ("dr", &dr)];
                let mut entries: Vec<(&str, wgpu::BindingResource)> = whole.iter().map(|&(name, b)| (name, b.as_entire_binding())).collect();
                entries.push(("colour", wgpu::BindingResource::Buffer(range)));
                gpu.bind_resources(&self.pipeline, (KERNEL, "main", None), &entries)
            })
            .collect();
        let nodal = [("problems", &judged), ("states", &states), ("node_start", &node_start), ("node_points", &node_points), ("node_coefs", &node_coefs), ("frames", &frames), ("count", &count)];
        let judge_group = gpu.bind_named(&self.judge, (JUDGE, "main", None), &[&nodal[..], &[("live", &live), ("r", &r), ("dr", &dr)]].concat());
        let solve = [("blocks", &block), ("row_start", &row_start), ("row_entries", &row_entries), ("locals", &locals), ("order", &solve_order), ("colour_start", &colour_start), ("r", &r), ("dr", &dr)];
        let solve_group = gpu.bind_named(&self.solve, (SOLVE, "main", None), &[&nodal[..], &solve[..]].concat());
        self.buffers = Some(Buffers {
            points,
            blocks,
            entries,
            colours,
            problems,
            nodes,
            node_entries,
            colour_entries,
            block,
            unpacked,
            row_start,
            row_entries,
            locals,
            order,
            live,
            r,
            ranges,
            judged,
            states,
            node_start,
            node_points,
            node_coefs,
            frames,
            solve_order,
            colour_start,
            count,
            staging,
            bind_groups,
            judge_group,
            solve_group,
        });
        Some(true)
    }

    fn upload(&mut self, buffer: &Buffer, offset: u64, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.traffic.up += bytes.len() as u64;
            self.gpu.queue.write_buffer(buffer, offset, bytes);
        }
    }

    /// Solves every problem with Gauss-Seidel sweeps on the device until each converges by the
    /// CPU's rule, reaches its `max_iterations`, or `stop` is set; each problem's `r` gets the
    /// reactions of its last sweep. The outcomes are in the problems' order; `None` (nothing
    /// done) when the round is too large for the device's buffers. f64 kernels only (the
    /// engine's sweeps run in f64).
    pub fn solve(&mut self, problems: &mut [Problem], stop: Option<&AtomicBool>) -> Result<Option<Vec<Outcome>>, GpuError> {
        let mut outcomes = vec![Outcome::default(); problems.len()];
        if problems.iter().all(|p| p.local.is_empty()) {
            return Ok(Some(outcomes));
        }
        let Some(whole) = self.stage(problems, SOLVE_SWEEPS, false) else {
            return Ok(None);
        };
        let b = self.buffers.take().expect("staged");
        let layout = std::mem::take(&mut self.layout);
        let result = self.iterate(&b, &layout, whole, problems, &mut outcomes, stop);
        self.buffers = Some(b);
        self.layout = layout;
        result.map(|()| Some(outcomes))
    }

    /// Uploads the problems: W, the colour orders and the node gather when they changed, the
    /// points, the problems with their states before the first sweep, and the reactions; a
    /// whole solve may take `sweeps` sweeps per dispatch; W's blocks stay where the device
    /// builds them (`built_on_device`: `newton_contact`'s `delassus`, before the sweeps). Whether
    /// they are solved whole ([`SOLVE_WIDEST`]), or `None` (nothing uploaded) when they do not
    /// fit the device's buffers. f64 kernels only.
    pub(crate) fn stage(&mut self, problems: &[Problem], sweeps: usize, built_on_device: bool) -> Option<bool> {
        assert_eq!(self.gpu.precision, Precision::F64, "the device's Uzawa sweeps need f64 kernels");
        let resident = self.layout.key == key_of(problems);
        let layout = if resident { std::mem::take(&mut self.layout) } else { Layout::of(problems) };
        let Some(reallocated) = self.reserve(&layout, problems.len()) else {
            self.layout = if resident { layout } else { Layout::default() };
            return None;
        };
        let b = self.buffers.take().expect("reserved");
        if !built_on_device && (!resident || reallocated || self.blocks_built) {
            self.upload_blocks(&b, BLOCKS, (&b.block, &layout.blocks), layout.planar.as_deref());
        }
        if built_on_device {
            self.unpack_pending[BLOCKS].store(0, Ordering::Relaxed);
        }
        self.blocks_built = built_on_device;
        if !resident || reallocated {
            self.upload(&b.row_start, 0, bytemuck::cast_slice(&layout.row_start));
            self.upload(&b.row_entries, 0, bytemuck::cast_slice(&layout.row_entries));
            self.upload(&b.order, 0, bytemuck::cast_slice(&layout.order));
            for (c, range) in layout.ranges.iter().enumerate() {
                self.upload(&b.ranges, c as u64 * self.range_stride, bytemuck::bytes_of(range));
            }
            let nodes = &layout.nodes;
            self.upload(&b.node_start, 0, bytemuck::cast_slice(&nodes.start));
            self.upload(&b.node_points, 0, bytemuck::cast_slice(&nodes.points));
            self.upload(&b.node_coefs, 0, bytemuck::cast_slice(&nodes.coefs));
            self.upload_blocks(&b, FRAMES, (&b.frames, &nodes.frames), layout.planar_frames.as_deref());
            self.upload(&b.solve_order, 0, bytemuck::cast_slice(&layout.solve_order));
            self.upload(&b.colour_start, 0, bytemuck::cast_slice(&layout.colour_start));
        }
        let locals: Vec<UzawaLocal<Real>> = problems
            .iter()
            .flat_map(|p| {
                let settle = SETTLE * p.tolerance;
                p.local.iter().map(move |l| UzawaLocal { v_free: l.v_free, shift: l.shift, mu: l.mu, rho: l.rho, floor: p.floor, settle })
            })
            .collect();
        let judged = layout.judged(problems);
        let states: Vec<UzawaJudgeState<Real>> = judged.iter().map(UzawaJudgeState::start).collect();
        let start: Vec<Real> = problems.iter().flat_map(|p| p.r.iter().flatten().copied()).collect();
        self.upload(&b.locals, 0, bytemuck::cast_slice(&locals));
        self.upload(&b.judged, 0, bytemuck::cast_slice(&judged));
        self.upload(&b.states, 0, bytemuck::cast_slice(&states));
        // On a software adapter a dispatch takes only the sweeps its loop guard lets through,
        // and a problem of which one sweep is too many goes colour by colour.
        let software = self.gpu.adapter.software();
        let budget = software.then_some(SOFTWARE_LOOP_BUDGET);
        let loops = problems.iter().map(|p| solve_loops_per_sweep(p.w, p.colours, p.nodal)).max().unwrap_or(0).max(1);
        let whole = solved_whole(layout.widest, || loops, software);
        let most = problems.iter().map(|p| p.max_iterations).max().unwrap_or(0);
        let sweeps = budget.map_or(sweeps, |b| sweeps.min(b / loops));
        let sweeps = if whole { most.min(sweeps).min(u32::MAX as usize) as u32 } else { 0 };
        self.whole_sweeps = sweeps as usize;
        self.upload(&b.count, 0, bytemuck::bytes_of(&SolveCount { problems: problems.len() as u32, sweeps, pad: [0; 2] }));
        if !whole {
            let live: Vec<u32> = judged.iter().zip(&states).flat_map(|(p, s)| std::iter::repeat_n((s.status == JUDGE_LIVE) as u32, (p.point_end - p.point_start) as usize)).collect();
            self.upload(&b.live, 0, bytemuck::cast_slice(&live));
        }
        self.upload(&b.r, 0, bytemuck::cast_slice(&start));
        self.buffers = Some(b);
        self.layout = layout;
        Some(whole)
    }

    /// The node gather of the last staged problems.
    pub(crate) fn staged_nodes(&self) -> &NodeGather {
        &self.layout.nodes
    }

    /// The staged problems' buffers (after [`UzawaSweeps::stage`]).
    pub(crate) fn buffers(&self) -> &Buffers {
        self.buffers.as_ref().expect("staged")
    }

    /// Dispatches of the staged whole solve that let a problem of `max_iterations` run all its
    /// sweeps: more than one where a dispatch takes fewer (a software adapter's loop guard), at
    /// most [`SOFTWARE_SOLVE_DISPATCHES`] there.
    pub(crate) fn whole_dispatches(&self, max_iterations: usize) -> usize {
        let needed = max_iterations.div_ceil(self.whole_sweeps.max(1)).max(1);
        if self.gpu.adapter.software() {
            needed.min(SOFTWARE_SOLVE_DISPATCHES)
        } else {
            needed
        }
    }

    /// Uploads 3 x 3 blocks (`whole`, into `buffer`) planar where they can ([`planar_of`]), for
    /// `planar_unpack` to write out ([`UzawaSweeps::record_unpack`]), else whole.
    fn upload_blocks(&mut self, b: &Buffers, which: usize, (buffer, whole): (&Buffer, &[Real]), planar: Option<&[Real]>) {
        match planar {
            Some(planar) => {
                let blocks = (planar.len() / 4) as u32;
                self.upload(&b.unpacked[which].planar, 0, bytemuck::cast_slice(planar));
                self.upload(&b.unpacked[which].count, 0, bytemuck::bytes_of(&UnpackCount { blocks, pad: [0; 3] }));
                self.unpack_pending[which].store(blocks, Ordering::Relaxed);
            }
            None => {
                self.upload(buffer, 0, bytemuck::cast_slice(whole));
                self.unpack_pending[which].store(0, Ordering::Relaxed);
            }
        }
    }

    /// Records `planar_unpack` for the staged blocks and frames that went up planar and are not
    /// written out yet: in the first pass after staging, before its sweeps.
    pub(crate) fn record_unpack(&self, pass: &mut wgpu::ComputePass) {
        self.record_unpack_in(pass, self.buffers());
    }

    fn record_unpack_in(&self, pass: &mut wgpu::ComputePass, b: &Buffers) {
        for (pending, unpacked) in self.unpack_pending.iter().zip(&b.unpacked) {
            let blocks = pending.swap(0, Ordering::Relaxed);
            if blocks > 0 {
                let (x, y) = super::dispatch_rows((blocks as usize).div_ceil(WORKGROUP as usize));
                self.gpu.dispatch(pass, (UNPACK, "main"), |pass| {
                    pass.set_pipeline(&self.unpack);
                    pass.set_bind_group(0, &unpacked.group, &[]);
                    pass.dispatch_workgroups(x, y, 1);
                });
            }
        }
    }

    /// Records one dispatch of `uzawa_solve` over `problems` staged problems.
    pub(crate) fn record_solve(&self, pass: &mut wgpu::ComputePass, problems: usize) {
        let (x, y) = super::dispatch_rows(problems);
        self.gpu.dispatch(pass, (SOLVE, "main"), |pass| {
            pass.set_pipeline(&self.solve);
            pass.set_bind_group(0, &self.buffers().solve_group, &[]);
            pass.dispatch_workgroups(x, y, 1);
        });
    }

    /// Bytes moved since the last call.
    pub(crate) fn take_traffic(&mut self) -> Traffic {
        std::mem::take(&mut self.traffic)
    }

    /// Submits until no problem is live: each 1, 2, 4, … dispatches of `uzawa_solve` if
    /// `whole` (a problem that has stopped returns at once), else a chunk of sweeps colour by
    /// colour, each followed by the device's judgement; after each the host reads back where
    /// each problem stands and the reactions.
    #[allow(clippy::too_many_arguments)]
    fn iterate(&mut self, b: &Buffers, m: &Layout, whole: bool, problems: &mut [Problem], outcomes: &mut [Outcome], stop: Option<&AtomicBool>) -> Result<(), GpuError> {
        let n = m.points();
        let r_bytes = (n * 3 * std::mem::size_of::<Real>()) as u64;
        let state_bytes = (problems.len() * std::mem::size_of::<UzawaJudgeState<Real>>()) as u64;
        let (mut swept, mut chunk, mut dispatches) = (0usize, FIRST_CHUNK, 1usize);
        let most = problems.iter().map(|p| p.max_iterations).max().unwrap_or(0);
        let (judge_x, judge_y) = super::dispatch_rows(problems.len());
        let mut live = true;
        while live && swept < most && !stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            let mut encoder = self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(KERNEL) });
            let recorded = dispatches.min((most - swept).div_ceil(self.whole_sweeps.max(1)));
            let sweeps = if whole { recorded * self.whole_sweeps } else { chunk.min(most - swept) };
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(KERNEL), timestamp_writes: None });
                self.record_unpack_in(&mut pass, b);
                let gpu = &self.gpu;
                if whole {
                    for _ in 0..recorded {
                        gpu.dispatch(&mut pass, (SOLVE, "main"), |pass| {
                            pass.set_pipeline(&self.solve);
                            pass.set_bind_group(0, &b.solve_group, &[]);
                            pass.dispatch_workgroups(judge_x, judge_y, 1);
                        });
                    }
                } else {
                    // Colour by colour: each sweep's dispatches, then its judgement.
                    for _ in 0..sweeps {
                        for (range, group) in m.ranges.iter().zip(&b.bind_groups) {
                            let (x, y) = super::dispatch_rows(range.count.div_ceil(WORKGROUP) as usize);
                            gpu.dispatch(&mut pass, (KERNEL, "main"), |pass| {
                                pass.set_pipeline(&self.pipeline);
                                pass.set_bind_group(0, group, &[]);
                                pass.dispatch_workgroups(x, y, 1);
                            });
                        }
                        gpu.dispatch(&mut pass, (JUDGE, "main"), |pass| {
                            pass.set_pipeline(&self.judge);
                            pass.set_bind_group(0, &b.judge_group, &[]);
                            pass.dispatch_workgroups(judge_x, judge_y, 1);
                        });
                    }
                }
            }
            encoder.copy_buffer_to_buffer(&b.r, 0, &b.staging, 0, r_bytes);
            encoder.copy_buffer_to_buffer(&b.states, 0, &b.staging, r_bytes, state_bytes);
            self.gpu.submit(encoder)?;
            self.submits += 1;
            let bytes = self.gpu.read_range(KERNEL, &b.staging, r_bytes + state_bytes)?;
            self.traffic.down += bytes.len() as u64;
            let reactions: Vec<Real> = bytemuck::pod_collect_to_vec(&bytes[..r_bytes as usize]);
            let states: Vec<UzawaJudgeState<Real>> = bytemuck::pod_collect_to_vec(&bytes[r_bytes as usize..]);
            live = false;
            for (k, (p, state)) in problems.iter_mut().zip(&states).enumerate() {
                // A problem that stopped keeps the reactions of its last sweep; a live one
                // where the device stands, should the next chunk not come.
                let range = m.range(k);
                p.r.copy_from_slice(bytemuck::cast_slice(&reactions[3 * range.start..3 * range.end]));
                outcomes[k] = state.outcome();
                live |= state.status == JUDGE_LIVE;
            }
            swept += sweeps;
            chunk = (2 * chunk).min(LAST_CHUNK);
            dispatches = (2 * dispatches).min(LAST_DISPATCHES);
        }
        Ok(())
    }
}
