//! The `uzawa_sweep` kernel (`shaders/uzawa_sweep.wgsl`): the Gauss-Seidel Uzawa iterations of
//! a Newton round on the device, for every group's contact problem ([`Problem`]) at once. CPU
//! twin: [`crate::contact::uzawa::uzawa_sweep`]; [`crate::contact::uzawa::solve`] is the whole
//! iteration this one repeats.
//!
//! The problems are independent (their points share no body), so colour `c` of the round is
//! colour `c` of every problem, and a sweep is one dispatch per colour. Sweeps go to the device
//! in chunks, one submit each; after every sweep the reactions are copied to the read-back
//! buffer, so that the host judges each problem after each sweep with the CPU's rule
//! ([`Judge`]) and takes the reactions of the sweep where it converged: the same iterates and
//! iteration counts as on the CPU, with one submit per chunk instead of one per sweep.

use super::world::{buffer, from_device, to_device, Traffic};
use super::{Gpu, GpuError};
use crate::contact::uzawa::{Judge, Outcome, Problem, SETTLE};
use crate::precision::Real;
use bytemuck::{Pod, Zeroable};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use wgpu::{BindGroup, Buffer, BufferUsages};

const KERNEL: &str = "uzawa_sweep";
const WORKGROUP: u32 = 64;
/// Sweeps in the first chunk of a solve; each further chunk doubles, up to [`LAST_CHUNK`]: a
/// warm-started problem often converges in a few sweeps, a hard one needs hundreds.
const FIRST_CHUNK: usize = 4;
const LAST_CHUNK: usize = 64;

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

/// The round's problems in one set of arrays: W (its blocks and rows) and the colour order,
/// which change only when a problem's Delassus operator does.
#[derive(Default)]
struct Layout {
    /// Each problem's W version and points: the layout serves a round with the same key.
    key: Vec<(u64, usize)>,
    blocks: Vec<Real>,
    row_start: Vec<u32>,
    row_entries: Vec<[u32; 2]>,
    order: Vec<u32>,
    ranges: Vec<ColourRange>,
    /// Each problem's first point, and the end.
    offsets: Vec<usize>,
}

fn key_of(problems: &[Problem]) -> Vec<(u64, usize)> {
    problems.iter().map(|p| (p.w.version, p.local.len())).collect()
}

impl Layout {
    fn of(problems: &[Problem]) -> Self {
        let mut m = Layout { key: key_of(problems), row_start: vec![0], offsets: vec![0], ..Default::default() };
        for p in problems {
            let (point0, block0) = (*m.offsets.last().expect("starts at 0") as u32, (m.blocks.len() / 9) as u32);
            m.blocks.extend(p.w.blocks.iter().flatten());
            for row in &p.w.rows {
                m.row_entries.extend(row.iter().map(|&(j, b)| [point0 + j, block0 + b]));
                m.row_start.push(m.row_entries.len() as u32);
            }
            m.offsets.push(point0 as usize + p.local.len());
        }
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
        m
    }

    fn points(&self) -> usize {
        *self.offsets.last().expect("starts at 0")
    }

    fn range(&self, k: usize) -> std::ops::Range<usize> {
        self.offsets[k]..self.offsets[k + 1]
    }
}

/// Device buffers, grown as rounds need more.
struct Buffers {
    /// Capacities: points, blocks, row entries, colours, sweeps the read-back holds.
    points: usize,
    blocks: usize,
    entries: usize,
    colours: usize,
    snapshots: usize,
    block: Buffer,
    row_start: Buffer,
    row_entries: Buffer,
    locals: Buffer,
    order: Buffer,
    live: Buffer,
    r: Buffer,
    ranges: Buffer,
    staging: Buffer,
    /// One per colour: the same buffers with that colour's range.
    bind_groups: Vec<BindGroup>,
}

/// The pipeline and buffers of the device's Uzawa sweeps.
pub struct UzawaSweeps {
    gpu: Arc<Gpu>,
    pipeline: wgpu::ComputePipeline,
    buffers: Option<Buffers>,
    /// What the device holds of the last round.
    layout: Layout,
    /// Stride of the colour ranges in their uniform buffer (the device's offset alignment).
    range_stride: u64,
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
        let range_stride = (gpu.device.limits().min_uniform_buffer_offset_alignment as u64).max(std::mem::size_of::<ColourRange>() as u64);
        Ok(Self { gpu, pipeline, buffers: None, layout: Layout::default(), range_stride, submits: 0, traffic: Traffic::default() })
    }

    /// The most items of `bytes` each that one buffer of the device can bind.
    fn most(&self, bytes: usize) -> usize {
        let limits = self.gpu.device.limits();
        (limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) / bytes as u64) as usize
    }

    /// Makes sure the buffers hold the round (growing them by half again what it needs, within
    /// the device's limits) and that there is a bind group per colour; whether they are new
    /// (and hold nothing yet), or `None` when the round is too large for the device's buffers.
    fn reserve(&mut self, m: &Layout) -> Option<bool> {
        let real = self.gpu.precision.size();
        let local_bytes = std::mem::size_of::<UzawaLocal<f64>>() / 8 * real;
        let (points, blocks, entries, colours) = (m.points(), m.blocks.len() / 9, m.row_entries.len(), m.ranges.len());
        let limits = [self.most(local_bytes).min(self.most(3 * real)), self.most(9 * real), self.most(8)];
        let uniform_limit = (self.gpu.device.limits().max_buffer_size / self.range_stride) as usize;
        if points > limits[0] || blocks > limits[1] || entries > limits[2] || colours > uniform_limit {
            return None;
        }
        if self.buffers.as_ref().is_some_and(|b| b.points >= points && b.blocks >= blocks && b.entries >= entries && b.colours >= colours) {
            return Some(false);
        }
        let grow = |n: usize, old: Option<usize>, limit: usize| old.unwrap_or(0).max(n + n / 2).clamp(1, limit.max(1));
        let old = self.buffers.as_ref();
        let points = grow(points, old.map(|b| b.points), limits[0]);
        let blocks = grow(blocks, old.map(|b| b.blocks), limits[1]);
        let entries = grow(entries, old.map(|b| b.entries), limits[2]);
        let colours = grow(colours, old.map(|b| b.colours), uniform_limit);
        let point_bytes = (points * 3 * real) as u64;
        let snapshots = ((self.gpu.device.limits().max_buffer_size / point_bytes) as usize).clamp(1, LAST_CHUNK);
        let gpu = &self.gpu;
        let none = BufferUsages::empty();
        let block = storage(gpu, "uzawa blocks", blocks * 9 * real, none);
        let row_start = storage(gpu, "uzawa row starts", (points + 1) * 4, none);
        let row_entries = storage(gpu, "uzawa row entries", entries * 8, none);
        let locals = storage(gpu, "uzawa points", points * local_bytes, none);
        let order = storage(gpu, "uzawa colour order", points * 4, none);
        let live = storage(gpu, "uzawa live", points * 4, none);
        let r = storage(gpu, "uzawa reactions", points * 3 * real, BufferUsages::COPY_SRC);
        let ranges = buffer(gpu, "uzawa colours", colours * self.range_stride as usize, BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let staging = buffer(gpu, "uzawa read-back", snapshots * point_bytes as usize, BufferUsages::MAP_READ | BufferUsages::COPY_DST);
        let layout = self.pipeline.get_bind_group_layout(0);
        let bind_groups = (0..colours)
            .map(|c| {
                let whole = [&block, &row_start, &row_entries, &locals, &order, &live, &r];
                let mut entries: Vec<wgpu::BindGroupEntry> = whole.iter().enumerate().map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() }).collect();
                let range = wgpu::BufferBinding { buffer: &ranges, offset: c as u64 * self.range_stride, size: wgpu::BufferSize::new(std::mem::size_of::<ColourRange>() as u64) };
                entries.push(wgpu::BindGroupEntry { binding: 7, resource: wgpu::BindingResource::Buffer(range) });
                gpu.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(KERNEL), layout: &layout, entries: &entries })
            })
            .collect();
        self.buffers = Some(Buffers { points, blocks, entries, colours, snapshots, block, row_start, row_entries, locals, order, live, r, ranges, staging, bind_groups });
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
    /// done) when the round is too large for the device's buffers.
    pub fn solve(&mut self, problems: &mut [Problem], stop: Option<&AtomicBool>) -> Result<Option<Vec<Outcome>>, GpuError> {
        let precision = self.gpu.precision;
        let mut outcomes = vec![Outcome::default(); problems.len()];
        if problems.iter().all(|p| p.local.is_empty()) {
            return Ok(Some(outcomes));
        }
        let resident = self.layout.key == key_of(problems);
        let layout = if resident { std::mem::take(&mut self.layout) } else { Layout::of(problems) };
        let Some(reallocated) = self.reserve(&layout) else {
            return Ok(None);
        };
        let b = self.buffers.take().expect("reserved");
        if !resident || reallocated {
            self.upload(&b.block, 0, &to_device(precision, &layout.blocks));
            self.upload(&b.row_start, 0, bytemuck::cast_slice(&layout.row_start));
            self.upload(&b.row_entries, 0, bytemuck::cast_slice(&layout.row_entries));
            self.upload(&b.order, 0, bytemuck::cast_slice(&layout.order));
            for (c, range) in layout.ranges.iter().enumerate() {
                self.upload(&b.ranges, c as u64 * self.range_stride, bytemuck::bytes_of(range));
            }
        }
        let locals: Vec<UzawaLocal<Real>> = problems
            .iter()
            .flat_map(|p| {
                let settle = SETTLE * p.tolerance;
                p.local.iter().map(move |l| UzawaLocal { v_free: l.v_free, shift: l.shift, mu: l.mu, rho: l.rho, floor: p.floor, settle })
            })
            .collect();
        let start: Vec<Real> = problems.iter().flat_map(|p| p.r.iter().flatten().copied()).collect();
        self.upload(&b.locals, 0, &to_device(precision, bytemuck::cast_slice(&locals)));
        self.upload(&b.live, 0, bytemuck::cast_slice(&vec![1u32; layout.points()]));
        self.upload(&b.r, 0, &to_device(precision, &start));
        let result = self.iterate(&b, &layout, start, problems, &mut outcomes, stop);
        self.buffers = Some(b);
        self.layout = layout;
        result.map(|()| Some(outcomes))
    }

    /// The chunks of sweeps and the host's judgement after each sweep, from the reactions
    /// `previous`.
    fn iterate(&mut self, b: &Buffers, m: &Layout, mut previous: Vec<Real>, problems: &mut [Problem], outcomes: &mut [Outcome], stop: Option<&AtomicBool>) -> Result<(), GpuError> {
        let precision = self.gpu.precision;
        let n = m.points();
        let point_bytes = (n * 3 * precision.size()) as u64;
        let mut judges: Vec<Judge> = problems.iter().map(|p| Judge::new(p.tolerance, p.floor)).collect();
        let mut live: Vec<bool> = problems.iter().map(|p| p.max_iterations > 0 && !p.r.is_empty()).collect();
        let (mut swept, mut chunk) = (0usize, FIRST_CHUNK);
        let (mut scratch, mut dr) = (Vec::new(), Vec::new());
        let most = problems.iter().map(|p| p.max_iterations).max().unwrap_or(0);
        while live.iter().any(|&l| l) && !stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            let sweeps = chunk.min(most - swept).min(b.snapshots);
            let mut encoder = self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(KERNEL) });
            for s in 0..sweeps {
                {
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(KERNEL), timestamp_writes: None });
                    pass.set_pipeline(&self.pipeline);
                    for (range, group) in m.ranges.iter().zip(&b.bind_groups) {
                        let (x, y) = super::dispatch_rows(range.count.div_ceil(WORKGROUP) as usize);
                        pass.set_bind_group(0, group, &[]);
                        pass.dispatch_workgroups(x, y, 1);
                    }
                }
                encoder.copy_buffer_to_buffer(&b.r, 0, &b.staging, s as u64 * point_bytes, point_bytes);
            }
            self.gpu.queue.submit([encoder.finish()]);
            self.submits += 1;
            let bytes = self.gpu.read_range(KERNEL, &b.staging, sweeps as u64 * point_bytes)?;
            self.traffic.down += bytes.len() as u64;
            let snapshots = from_device(precision, &bytes);
            let mut finished = false;
            for (s, now) in snapshots.chunks(3 * n).enumerate() {
                let iteration = swept + s + 1;
                for (k, p) in problems.iter_mut().enumerate() {
                    if !live[k] {
                        continue;
                    }
                    let range = m.range(k);
                    dr.clear();
                    dr.extend(range.clone().map(|i| [0, 1, 2].map(|a| now[3 * i + a] - previous[3 * i + a])));
                    let r: &[[Real; 3]] = bytemuck::cast_slice(&now[3 * range.start..3 * range.end]);
                    let (change, size) = p.nodal.change(&dr, r, &mut scratch);
                    outcomes[k] = judges[k].after(iteration, change, size);
                    if outcomes[k].converged || iteration == p.max_iterations {
                        p.r.copy_from_slice(r);
                        live[k] = false;
                        finished = true;
                    }
                }
                previous.copy_from_slice(now);
            }
            swept += sweeps;
            chunk = (2 * chunk).min(LAST_CHUNK);
            for (k, p) in problems.iter_mut().enumerate() {
                if live[k] {
                    // Where the device stands, should the next chunk not come.
                    let range = m.range(k);
                    p.r.copy_from_slice(bytemuck::cast_slice(&previous[3 * range.start..3 * range.end]));
                }
            }
            if finished && live.iter().any(|&l| l) {
                let flags: Vec<u32> = (0..problems.len()).flat_map(|k| std::iter::repeat_n(live[k] as u32, m.range(k).len())).collect();
                self.upload(&b.live, 0, bytemuck::cast_slice(&flags));
            }
        }
        Ok(())
    }
}
