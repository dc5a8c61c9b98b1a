//! The GPU side: adapters and devices (wgpu), the WGSL kernels of `shaders/`, the `#[repr(C)]`
//! types that cross to them, and the bodies' data on the device (`world`: every body in shared
//! buffers, one device pass per Newton evaluation) and the contact problems' Uzawa sweeps
//! (`uzawa_sweep`). Every kernel has a CPU twin of the same name
//! in [`crate::cpu`], which is the test oracle.

pub mod clock;
pub mod context;
pub mod peak;
pub mod shaders;
pub mod types;
pub mod uzawa_step;
pub mod uzawa_sweep;
pub mod world;

pub use context::{describe_adapters, hardware_adapter, open, AdapterReport, Gpu, GpuError};
pub use shaders::ElementVariant;
pub use world::{ContactLayout, ElementFailure, Evaluation, GpuWorld, GroupContact, Inverse, KeptIterate, KeptState, NewtonCall, StepEnd, StepStart, Traffic, WorldBody, WorldKernel};

/// Workgroups per row of a dispatch: a grid of more workgroups than one dimension allows is laid
/// out in rows of this many (`MAX_ROW` of `batch.wgsl`; the kernels index by row).
const MAX_ROW: usize = 65_535;

/// The `(x, y)` workgroup counts that cover `groups` workgroups in rows of at most [`MAX_ROW`].
pub fn dispatch_rows(groups: usize) -> (u32, u32) {
    (groups.min(MAX_ROW) as u32, groups.div_ceil(MAX_ROW) as u32)
}
