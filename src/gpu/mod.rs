//! The GPU side: adapters and devices (wgpu), the WGSL kernels of `shaders/`, and the Rust types
//! that cross to them. Every kernel has a CPU twin of the same name that is the test oracle.

pub mod context;
pub mod shaders;
pub mod uzawa_step;

pub use context::{describe_adapters, open, AdapterReport, Gpu, GpuError};
