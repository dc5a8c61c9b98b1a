//! The adapter's peaks, measured by `bifirst bench` itself so that its kernel numbers can be
//! judged on any card: copy bandwidth (`peak_copy`) and fused multiply-add throughput
//! (`peak_fma`). CPU twins: [`crate::cpu::peak_copy`], [`crate::cpu::peak_fma`].

use super::types::PEAK_FMA_STEPS;
use super::world::{from_device, to_device};
use super::{Gpu, GpuError};
use crate::precision::Real;
use std::time::Instant;
use wgpu::util::DeviceExt;
use wgpu::{BufferUsages, ComputePipeline};

const WORKGROUP: usize = 256;

/// Measured peaks of a device in its precision.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Peaks {
    /// Bytes read plus bytes written per second by `peak_copy`.
    pub bytes_per_second: f64,
    /// Floating-point operations per second of `peak_fma` (a fused multiply-add counts 2).
    pub flops_per_second: f64,
    /// The sizes measured (values) and their seconds per call.
    pub copy_values: usize,
    pub copy_seconds: f64,
    pub fma_values: usize,
    pub fma_seconds: f64,
}

/// A kernel of one or two storage buffers, run on `values` and timed.
struct Probe {
    pipeline: ComputePipeline,
    kernel: &'static str,
}

impl Probe {
    /// Runs the kernel `calls` times from `values` into a second buffer, then reads the result;
    /// returns it with the seconds per call.
    fn run(&self, gpu: &Gpu, values: &[Real], vec4s: bool, calls: u32) -> Result<(Vec<Real>, f64), GpuError> {
        let bytes = to_device(gpu.precision, values);
        let usage = BufferUsages::STORAGE | BufferUsages::COPY_SRC;
        let first = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("peak"), contents: &bytes, usage });
        let second = gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some("peak result"), size: bytes.len() as u64, usage, mapped_at_creation: false });
        let bind_group = gpu.bind_named(&self.pipeline, (self.kernel, "main", None), &[("source", &first), ("destination", &second)]);
        let items = if vec4s { values.len() / 4 } else { values.len() };
        let groups = items.div_ceil(WORKGROUP);
        let dispatch = |encoder: &mut wgpu::CommandEncoder| {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("peak"), timestamp_writes: None });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            let (x, y) = super::dispatch_rows(groups);
            pass.dispatch_workgroups(x, y, 1);
        };
        let wait = || gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Kernel { kernel: "peak".into(), message: e.to_string() });
        // One call to warm up, then `calls` in one submit: the launch cost is spread over them.
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        dispatch(&mut encoder);
        gpu.queue.submit([encoder.finish()]);
        wait()?;
        let started = Instant::now();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        for _ in 0..calls {
            dispatch(&mut encoder);
        }
        gpu.queue.submit([encoder.finish()]);
        wait()?;
        let seconds = started.elapsed().as_secs_f64() / f64::from(calls);
        let result = &second;
        let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some("peak readback"), size: bytes.len() as u64, usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST, mapped_at_creation: false });
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(result, 0, &staging, 0, bytes.len() as u64);
        gpu.queue.submit([encoder.finish()]);
        Ok((from_device(gpu.precision, &gpu.read("peak", &staging)?), seconds))
    }
}

/// `peak_copy` on `values` (a multiple of 4 long): the copy and the seconds per call.
pub fn peak_copy(gpu: &Gpu, values: &[Real], calls: u32) -> Result<(Vec<Real>, f64), GpuError> {
    Probe { pipeline: gpu.pipeline("peak_copy", None)?, kernel: "peak_copy" }.run(gpu, values, true, calls)
}

/// `peak_fma` on `values`: the results and the seconds per call.
pub fn peak_fma(gpu: &Gpu, values: &[Real], calls: u32) -> Result<(Vec<Real>, f64), GpuError> {
    Probe { pipeline: gpu.pipeline("peak_fma", None)?, kernel: "peak_fma" }.run(gpu, values, false, calls)
}

/// Floating-point operations of `peak_fma` per value.
pub const FMA_FLOPS_PER_VALUE: f64 = (8 * 2 * PEAK_FMA_STEPS) as f64;

/// A probe on some values: its results and seconds per call.
type ProbeRun<'a> = dyn Fn(&[Real]) -> Result<(Vec<Real>, f64), GpuError> + 'a;

/// Repetitions of the last size of [`measure`], of which the fastest counts.
const REPETITIONS: usize = 4;

/// The device's peaks: the sizes grow fourfold until a call takes `min_seconds` (or the
/// device's largest buffer is reached), so that launch costs do not count; that size is then
/// run [`REPETITIONS`] times more and the fastest taken, because an H100's `peak_fma` ranged
/// from 8.6 to 32.7 TFLOP/s (f64) between runs, in no order that the kernels' differences explain
/// (probably its clocks coming up).
pub fn measure(gpu: &Gpu, min_seconds: f64) -> Result<Peaks, GpuError> {
    let limits = gpu.device.limits();
    let largest = (limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) / 2).min(1 << 30) as usize / gpu.precision.size();
    let grow = |mut n: usize, run: &ProbeRun| loop {
        let values = vec![1.0; n];
        let (_, seconds) = run(&values)?;
        if seconds >= min_seconds || 4 * n > largest {
            let mut fastest = seconds;
            for _ in 0..REPETITIONS {
                fastest = fastest.min(run(&values)?.1);
            }
            return Ok::<_, GpuError>((n, fastest));
        }
        n *= 4;
    };
    let (copy_values, copy_seconds) = grow(1 << 16, &|v| peak_copy(gpu, v, 8))?;
    let (fma_values, fma_seconds) = grow(1 << 12, &|v| peak_fma(gpu, v, 8))?;
    Ok(Peaks { bytes_per_second: 2.0 * (copy_values * gpu.precision.size()) as f64 / copy_seconds, flops_per_second: FMA_FLOPS_PER_VALUE * fma_values as f64 / fma_seconds, copy_values, copy_seconds, fma_values, fma_seconds })
}
