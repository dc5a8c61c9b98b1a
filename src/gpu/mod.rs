//! The GPU side: adapters and devices (wgpu), the WGSL kernels of `shaders/`, the `#[repr(C)]`
//! types that cross to them, and a body's data on the device. Every kernel has a CPU twin of the
//! same name in [`crate::cpu`], which is the test oracle.

pub mod body;
pub mod context;
pub mod shaders;
pub mod types;
pub mod uzawa_step;

pub use body::GpuBody;
pub use context::{describe_adapters, hardware_adapter, open, open_adapter, AdapterReport, Gpu, GpuError};
pub use shaders::ElementVariant;
