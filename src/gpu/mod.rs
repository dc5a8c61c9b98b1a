//! The GPU side: adapters and devices (wgpu), the WGSL kernels of `shaders/`, the `#[repr(C)]`
//! types that cross to them, and the bodies' data on the device (`world`: every body in shared
//! buffers, one device pass per Newton evaluation) and the contact problems' Uzawa sweeps
//! (`uzawa_sweep`). Every kernel has a CPU twin of the same name
//! in [`crate::cpu`], which is the test oracle.

pub mod context;
pub mod peak;
pub mod shaders;
pub mod types;
pub mod uzawa_step;
pub mod uzawa_sweep;
pub mod world;

pub use world::{ElementFailure, Evaluation, GpuWorld, Traffic, WorldBody, WorldKernel};
pub use context::{describe_adapters, hardware_adapter, open, AdapterReport, Gpu, GpuError};
pub use shaders::ElementVariant;
