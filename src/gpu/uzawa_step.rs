//! The `uzawa_step` kernel (`shaders/uzawa_step.wgsl`): one Uzawa predictor/corrector step per
//! contact point. CPU twin: [`crate::contact::law::uzawa_step`].

use super::{Gpu, GpuError};
use crate::contact::law::uzawa_step;
use crate::precision::{Precision, Real};
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

const KERNEL: &str = "uzawa_step";
const WORKGROUP: usize = 64;

/// A contact point as the kernel reads and writes it (`struct UzawaPoint` in the shader), in
/// the contact frame: `r` in/out, `status` out.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UzawaPoint<R> {
    pub r: [R; 3],
    pub v: [R; 3],
    pub mu: R,
    pub rho: R,
    pub status: R,
}

// SAFETY: `repr(C)` with fields all of type `R`: no padding, and any bit pattern of `R` (f32 or
// f64) is valid.
unsafe impl<R: Pod> Zeroable for UzawaPoint<R> {}
unsafe impl<R: Pod> Pod for UzawaPoint<R> {}

impl UzawaPoint<Real> {
    /// The CPU twin on this point: what the kernel must produce.
    pub fn stepped_on_cpu(&self) -> Self {
        let (r, status) = uzawa_step(self.r, self.v, self.mu, self.rho);
        Self { r, status: Real::from(status.code()), ..*self }
    }

    fn to_f32(self) -> UzawaPoint<f32> {
        let f = |x: [Real; 3]| x.map(|c| c as f32);
        UzawaPoint { r: f(self.r), v: f(self.v), mu: self.mu as f32, rho: self.rho as f32, status: self.status as f32 }
    }
}

impl UzawaPoint<f32> {
    fn to_f64(self) -> UzawaPoint<Real> {
        let f = |x: [f32; 3]| x.map(Real::from);
        UzawaPoint { r: f(self.r), v: f(self.v), mu: self.mu.into(), rho: self.rho.into(), status: self.status.into() }
    }
}

/// The pipeline of the kernel on one device.
pub struct UzawaStepKernel {
    pipeline: wgpu::ComputePipeline,
}

impl UzawaStepKernel {
    pub fn new(gpu: &Gpu) -> Result<Self, GpuError> {
        Ok(Self { pipeline: gpu.pipeline(KERNEL, None)? })
    }

    /// Steps every point on the device (in the device's precision) and writes the results back
    /// into `points`; returns the bytes moved each way.
    pub fn run(&self, gpu: &Gpu, points: &mut [UzawaPoint<Real>]) -> Result<usize, GpuError> {
        if points.is_empty() {
            return Ok(0);
        }
        let bytes: Vec<u8> = match gpu.precision {
            Precision::F64 => bytemuck::cast_slice(points).to_vec(),
            Precision::F32 => bytemuck::cast_slice(&points.iter().map(|p| p.to_f32()).collect::<Vec<_>>()).to_vec(),
        };
        let device = &gpu.device;
        let storage = device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(KERNEL), contents: &bytes, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC });
        let staging = device.create_buffer(&wgpu::BufferDescriptor { label: Some("uzawa_step readback"), size: bytes.len() as u64, usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST, mapped_at_creation: false });
        let bind_group = gpu.bind_named(&self.pipeline, (KERNEL, "main", None), &[("points", &storage)]);
        let (x, y) = super::dispatch_rows(points.len().div_ceil(WORKGROUP));
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(KERNEL) });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(KERNEL), timestamp_writes: None });
            gpu.dispatch(&mut pass, (KERNEL, "main"), |pass| {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.dispatch_workgroups(x, y, 1);
            });
        }
        encoder.copy_buffer_to_buffer(&storage, 0, &staging, 0, bytes.len() as u64);
        gpu.submit(encoder)?;
        let out = gpu.read(KERNEL, &staging)?;
        match gpu.precision {
            // Copied into typed vectors: the mapped bytes need not be aligned for f64.
            Precision::F64 => points.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, UzawaPoint<Real>>(&out)),
            Precision::F32 => {
                for (p, q) in points.iter_mut().zip(bytemuck::pod_collect_to_vec::<u8, UzawaPoint<f32>>(&out)) {
                    *p = q.to_f64();
                }
            }
        }
        Ok(bytes.len())
    }
}
