//! The device's time per kernel (`--kernel-times`): a timestamp before and after every dispatch,
//! resolved after each submission and summed by kernel. It tells where a device pass spends
//! its time, which the host's clocks around a submission cannot (they see the whole pass, waits
//! included). Timing serialises the dispatches a little and adds a read-back per submission, so
//! a timed run's wall time is not the untimed run's.

use super::{Gpu, GpuError};
use std::collections::BTreeMap;
use std::sync::Mutex;
use wgpu::{Buffer, BufferUsages, ComputePass, QuerySet};

/// The timestamps a submission can hold: two per dispatch (wgpu's `QUERY_SET_MAX_QUERIES`).
const QUERIES: u32 = 4096;
/// The features the clock needs, requested whenever the adapter has them.
pub const FEATURES: wgpu::Features = wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS).union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES);

/// A kernel's device time over a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct KernelTime {
    /// The kernel, and its entry point when it is not `main` (`element_force_tangent/forces`).
    pub kernel: String,
    /// Seconds between the timestamps before and after its dispatches, summed.
    pub seconds: f64,
    pub dispatches: u64,
}

/// The device's time by kernel over a run.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct KernelTimes {
    /// The longest first.
    pub kernels: Vec<KernelTime>,
    /// Dispatches of submissions too long for the clock's timestamps, not counted above.
    pub untimed_dispatches: u64,
}

/// Timestamps around dispatches, one submission at a time.
pub struct KernelClock {
    queries: QuerySet,
    resolved: Buffer,
    read: Buffer,
    /// Nanoseconds per timestamp tick.
    period: f64,
    state: Mutex<ClockState>,
}

/// A kernel of `shaders/` and one of its entry points.
type Entry = (&'static str, &'static str);

#[derive(Default)]
struct ClockState {
    /// The kernel and entry point of each dispatch timed in the submission being recorded.
    pending: Vec<Entry>,
    /// Dispatches of the submissions that had no timestamp left.
    untimed: u64,
    totals: BTreeMap<Entry, (f64, u64)>,
}

impl KernelClock {
    /// A clock on `device`, which must have been opened with [`FEATURES`].
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let queries = device.create_query_set(&wgpu::QuerySetDescriptor { label: Some("kernel clock"), ty: wgpu::QueryType::Timestamp, count: QUERIES });
        let bytes = QUERIES as u64 * 8;
        let buffer = |label, usage| device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: bytes, usage, mapped_at_creation: false });
        Self {
            queries,
            resolved: buffer("kernel clock resolved", BufferUsages::QUERY_RESOLVE | BufferUsages::COPY_SRC),
            read: buffer("kernel clock read", BufferUsages::MAP_READ | BufferUsages::COPY_DST),
            period: queue.get_timestamp_period() as f64,
            state: Mutex::new(ClockState::default()),
        }
    }

    /// Records `dispatch` into `pass` between two timestamps, when the submission has two left.
    pub fn time(&self, pass: &mut ComputePass, entry: Entry, dispatch: impl FnOnce(&mut ComputePass)) {
        let mut state = self.state.lock().expect("clock state");
        let at = 2 * state.pending.len() as u32;
        if at + 2 > QUERIES {
            state.untimed += 1;
            drop(state);
            dispatch(pass);
            return;
        }
        state.pending.push(entry);
        drop(state);
        pass.write_timestamp(&self.queries, at);
        dispatch(pass);
        pass.write_timestamp(&self.queries, at + 1);
    }

    /// Records, at the end of a submission's commands, the copy of its timestamps to where the
    /// host reads them.
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        let state = self.state.lock().expect("clock state");
        let used = 2 * state.pending.len() as u32;
        if used > 0 {
            encoder.resolve_query_set(&self.queries, 0..used, &self.resolved, 0);
            encoder.copy_buffer_to_buffer(&self.resolved, 0, &self.read, 0, used as u64 * 8);
        }
    }

    /// After the submission whose commands [`KernelClock::resolve`] ended has been submitted:
    /// waits for it (on `gpu`, the clock's device) and adds its dispatches' times to their
    /// kernels'.
    pub fn collect(&self, gpu: &Gpu) -> Result<(), GpuError> {
        let mut state = self.state.lock().expect("clock state");
        let pending = std::mem::take(&mut state.pending);
        if pending.is_empty() {
            return Ok(());
        }
        let ticks: Vec<u64> = gpu.read_range_with("kernel clock", &self.read, pending.len() as u64 * 16, bytemuck::pod_collect_to_vec)?;
        for (&entry, pair) in pending.iter().zip(ticks.chunks_exact(2)) {
            let total = state.totals.entry(entry).or_default();
            total.0 += pair[1].saturating_sub(pair[0]) as f64 * self.period * 1e-9;
            total.1 += 1;
        }
        Ok(())
    }

    /// Every kernel's time so far, the longest first.
    pub fn times(&self) -> KernelTimes {
        let state = self.state.lock().expect("clock state");
        let mut kernels: Vec<KernelTime> = state.totals.iter().map(|(&(kernel, entry), &(seconds, dispatches))| KernelTime { kernel: if entry == "main" { kernel.to_string() } else { format!("{kernel}/{entry}") }, seconds, dispatches }).collect();
        kernels.sort_by(|a, b| b.seconds.total_cmp(&a.seconds));
        KernelTimes { kernels, untimed_dispatches: state.untimed }
    }
}
