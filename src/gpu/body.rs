//! One body's data on the device and the kernels that evaluate it: `element_force_tangent`,
//! `assemble_csr`, `assemble_residual`, `element_energy` and `reduce_sum`.
//!
//! The mesh, reference geometry, material and gather maps are uploaded once. Per Newton
//! iteration only the displacements go up, and the stiffness values (and the internal force and
//! residual) come down; the step's inputs of `assemble_residual` go up once per step.

use super::types::{Coefficients, DofOut, DofStep, MaterialParams};
use super::{ElementVariant, Gpu, GpuError};
use crate::assembly::{element_out_stride, GatherMap, StiffnessPattern};
use crate::element::ReferenceGeometry;
use crate::material::Model;
use crate::mesh::Mesh;
use crate::precision::{Precision, Real};
use crate::solver::PhaseTimes;
use std::sync::Arc;
use std::time::Instant;
use wgpu::util::DeviceExt;
use wgpu::{BindGroup, Buffer, BufferUsages, ComputePipeline};

const WORKGROUP: u32 = 64;
const REDUCE_WIDTH: u32 = 256;
const MAX_GROUPS_PER_ROW: u32 = 65_535;
/// `failure` entries: the lowest inverted element, the lowest non-finite one.
const NO_FAILURE: u32 = u32::MAX;

/// Why the element kernel rejected the state: the lowest failing element of each kind.
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

/// A kernel's pipeline with its bind group.
struct Pass {
    pipeline: ComputePipeline,
    bind_group: BindGroup,
    invocations: u32,
    workgroup: u32,
}

impl Pass {
    fn new(gpu: &Gpu, kernel: &str, variant: Option<ElementVariant>, buffers: &[&Buffer], invocations: usize, workgroup: u32) -> Result<Self, GpuError> {
        let pipeline = gpu.pipeline(kernel, variant)?;
        let entries: Vec<wgpu::BindGroupEntry> =
            buffers.iter().enumerate().map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() }).collect();
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(kernel), layout: &pipeline.get_bind_group_layout(0), entries: &entries });
        Ok(Self { pipeline, bind_group, invocations: invocations as u32, workgroup })
    }

    fn record(&self, encoder: &mut wgpu::CommandEncoder) {
        if self.invocations == 0 {
            return;
        }
        let groups = self.invocations.div_ceil(self.workgroup);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        // Rows of at most 65535 workgroups (the kernels index by id.x + id.y * row).
        pass.dispatch_workgroups(groups.min(MAX_GROUPS_PER_ROW), groups.div_ceil(MAX_GROUPS_PER_ROW), 1);
    }
}

pub struct GpuBody {
    gpu: Arc<Gpu>,
    elements: usize,
    nnz: usize,
    dofs: usize,
    u: Buffer,
    coefficients: Buffer,
    step: Buffer,
    failure: Buffer,
    element_out: Buffer,
    values: Buffer,
    dof_out: Buffer,
    energy: Buffer,
    /// The last level of the reduction: one value.
    total: Buffer,
    element_pass: Pass,
    csr_pass: Pass,
    residual_pass: Pass,
    energy_pass: Pass,
    reduce_passes: Vec<Pass>,
    /// Bytes moved since the last [`GpuBody::take_traffic`].
    traffic: Traffic,
}

/// A buffer of `count` items of `item` bytes (at least one item: wgpu binds no empty buffer).
fn buffer(gpu: &Gpu, label: &str, count: usize, item: usize, usage: BufferUsages) -> Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: (count.max(1) * item) as u64, usage, mapped_at_creation: false })
}

fn buffer_init(gpu: &Gpu, label: &str, contents: &[u8], usage: BufferUsages) -> Buffer {
    gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
}

impl GpuBody {
    pub fn new(gpu: Arc<Gpu>, mesh: &Mesh, geometry: &ReferenceGeometry, model: &Model, pattern: &StiffnessPattern, gather: &GatherMap) -> Result<Self, GpuError> {
        let kind = mesh.kind;
        let dim = kind.dim();
        let variant = Some(ElementVariant { kind, material: model.name() });
        let elements = mesh.element_count();
        let dofs = mesh.nodes.len() * dim;
        let nnz = pattern.nnz();
        let stride = element_out_stride(pattern.element_dofs);
        if (elements * stride) as u64 >= u64::from(u32::MAX) {
            return Err(GpuError::Kernel { kernel: "element_force_tangent".into(), message: format!("{elements} elements of {} are too many for 32-bit indices", kind.name()) });
        }
        let real = gpu.precision.size();
        let storage = BufferUsages::STORAGE;
        let (read, write, copy_out) = (storage, storage | BufferUsages::COPY_DST, storage | BufferUsages::COPY_SRC);
        let g = &*gpu;
        let params = MaterialParams::of(model);
        let material = buffer_init(g, "material", &to_device(g.precision, bytemuck::cast_slice(std::slice::from_ref(&params))), read);
        let mut points = Vec::with_capacity(geometry.points.len() * (3 * kind.nodes() + 1));
        for p in &geometry.points {
            points.extend(p.dn_dx.iter().flatten());
            points.push(p.dv);
        }
        let geometry_buffer = buffer_init(g, "geometry", &to_device(g.precision, &points), read);
        let connectivity = buffer_init(g, "connectivity", bytemuck::cast_slice(&mesh.connectivity), read);
        let csr_start = buffer_init(g, "csr gather start", bytemuck::cast_slice(&gather.csr_start), read);
        let csr = buffer_init(g, "csr gather", bytemuck::cast_slice(&nonempty(&gather.csr)), read);
        let dof_start = buffer_init(g, "dof gather start", bytemuck::cast_slice(&gather.dof_start), read);
        let dof = buffer_init(g, "dof gather", bytemuck::cast_slice(&nonempty(&gather.dof)), read);
        let u = buffer(g, "u", dofs, real, write);
        let coefficients = buffer(g, "coefficients", 2, real.max(8), BufferUsages::UNIFORM | BufferUsages::COPY_DST);
        let step = buffer(g, "step", dofs, 4 * real, write);
        let failure = buffer(g, "failure", 2, 4, write | BufferUsages::COPY_SRC);
        let element_out = buffer(g, "element_out", elements * stride, real, copy_out);
        let values = buffer(g, "values", nnz, real, copy_out);
        let dof_out = buffer(g, "dof_out", dofs, 2 * real, copy_out);
        let energy = buffer(g, "energy", elements, real, copy_out);
        let element_pass = Pass::new(g, "element_force_tangent", variant, &[&material, &geometry_buffer, &connectivity, &u, &element_out, &failure], elements, WORKGROUP)?;
        let csr_pass = Pass::new(g, "assemble_csr", None, &[&element_out, &csr_start, &csr, &coefficients, &values], nnz, WORKGROUP)?;
        let residual_pass = Pass::new(g, "assemble_residual", None, &[&element_out, &dof_start, &dof, &coefficients, &u, &step, &dof_out], dofs, WORKGROUP)?;
        let energy_pass = Pass::new(g, "element_energy", variant, &[&material, &geometry_buffer, &connectivity, &u, &energy], elements, WORKGROUP)?;
        // Reduction levels: n, ceil(n/256), ... down to one value.
        let mut reduce_passes = Vec::new();
        let mut level = energy.clone();
        let mut count = elements;
        loop {
            let next_count = count.div_ceil(REDUCE_WIDTH as usize);
            let next = buffer(g, "energy partial sums", next_count, real, copy_out);
            reduce_passes.push(Pass::new(g, "reduce_sum", None, &[&level, &next], next_count * REDUCE_WIDTH as usize, REDUCE_WIDTH)?);
            level = next;
            count = next_count;
            if count == 1 {
                break;
            }
        }
        let traffic = Traffic { up: [&material, &geometry_buffer, &connectivity, &csr_start, &csr, &dof_start, &dof].iter().map(|b| b.size()).sum(), down: 0 };
        Ok(Self {
            gpu,
            elements,
            nnz,
            dofs,
            u,
            coefficients,
            step,
            failure,
            element_out,
            values,
            dof_out,
            energy,
            total: level,
            element_pass,
            csr_pass,
            residual_pass,
            energy_pass,
            reduce_passes,
            traffic,
        })
    }

    pub fn precision(&self) -> Precision {
        self.gpu.precision
    }

    /// Bytes moved since the last call (the upload of the body's data counts in the first).
    pub fn take_traffic(&mut self) -> Traffic {
        std::mem::take(&mut self.traffic)
    }

    fn upload(&mut self, buffer: &Buffer, reals: &[Real]) {
        let bytes = to_device(self.gpu.precision, reals);
        self.traffic.up += bytes.len() as u64;
        self.gpu.queue.write_buffer(buffer, 0, &bytes);
    }

    /// The step's start values for `assemble_residual` (once per step).
    pub fn begin_step(&mut self, step: &[DofStep<Real>]) {
        let step_buffer = self.step.clone();
        self.upload(&step_buffer, bytemuck::cast_slice(step));
    }

    fn submit(&self, encoder: wgpu::CommandEncoder, kernel: &str) -> Result<(), GpuError> {
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Kernel { kernel: kernel.into(), message: e.to_string() })?;
        Ok(())
    }

    fn encoder(&self) -> wgpu::CommandEncoder {
        self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None })
    }

    /// Copies `size` bytes of `source` to a mappable buffer and reads them back as reals.
    fn download(&mut self, kernel: &str, source: &Buffer, size: u64) -> Result<Vec<Real>, GpuError> {
        let staging = self.gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some("readback"), size, usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST, mapped_at_creation: false });
        let mut encoder = self.encoder();
        encoder.copy_buffer_to_buffer(source, 0, &staging, 0, size);
        self.gpu.queue.submit([encoder.finish()]);
        let bytes = self.gpu.read(kernel, &staging)?;
        self.traffic.down += size;
        Ok(from_device(self.gpu.precision, &bytes))
    }

    /// Runs `element_force_tangent` at displacement `u` (every dof of the body); the results stay
    /// on the device.
    pub fn run_elements(&mut self, u: &[Real], times: &mut PhaseTimes) -> Result<Option<ElementFailure>, GpuError> {
        let t0 = Instant::now();
        let u_buffer = self.u.clone();
        self.upload(&u_buffer, u);
        let none = [NO_FAILURE; 2];
        self.gpu.queue.write_buffer(&self.failure, 0, bytemuck::cast_slice(&none));
        self.traffic.up += 8;
        let mut encoder = self.encoder();
        self.element_pass.record(&mut encoder);
        self.submit(encoder, "element_force_tangent")?;
        let t1 = Instant::now();
        times.elements += (t1 - t0).as_secs_f64();
        let staging = self.gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some("failure readback"), size: 8, usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST, mapped_at_creation: false });
        let mut encoder = self.encoder();
        encoder.copy_buffer_to_buffer(&self.failure, 0, &staging, 0, 8);
        self.gpu.queue.submit([encoder.finish()]);
        let flags: Vec<u32> = bytemuck::pod_collect_to_vec(&self.gpu.read("element_force_tangent", &staging)?);
        self.traffic.down += 8;
        times.transfer += t1.elapsed().as_secs_f64();
        Ok(if flags[0] != NO_FAILURE {
            Some(ElementFailure::Inverted(flags[0] as usize))
        } else if flags[1] != NO_FAILURE {
            Some(ElementFailure::NonFinite(flags[1] as usize))
        } else {
            None
        })
    }

    /// Element results (forces, then tangents) at `u`, as `element_force_tangent` writes them.
    pub fn element_results(&mut self, u: &[Real]) -> Result<(Vec<Real>, Option<ElementFailure>), GpuError> {
        let failure = self.run_elements(u, &mut PhaseTimes::default())?;
        let size = self.element_out.size();
        let element_out = self.element_out.clone();
        Ok((self.download("element_force_tangent", &element_out, size)?, failure))
    }

    /// One Newton evaluation at `u`: element kernel, then [`GpuBody::assemble`].
    pub fn evaluate(
        &mut self,
        u: &[Real],
        coefficients: Coefficients<Real>,
        values: &mut [Real],
        dof_out: Option<&mut [DofOut<Real>]>,
        times: &mut PhaseTimes,
    ) -> Result<Option<ElementFailure>, GpuError> {
        if let Some(failure) = self.run_elements(u, times)? {
            return Ok(Some(failure));
        }
        self.assemble(coefficients, values, dof_out, times)?;
        Ok(None)
    }

    /// `assemble_csr` into `values` from the element results on the device, and with `dof_out`
    /// also `assemble_residual` (after [`GpuBody::begin_step`], at the last uploaded `u`).
    pub fn assemble(&mut self, coefficients: Coefficients<Real>, values: &mut [Real], dof_out: Option<&mut [DofOut<Real>]>, times: &mut PhaseTimes) -> Result<(), GpuError> {
        let t0 = Instant::now();
        let coefficient_buffer = self.coefficients.clone();
        self.upload(&coefficient_buffer, &[coefficients.factor, coefficients.c1]);
        let mut encoder = self.encoder();
        self.csr_pass.record(&mut encoder);
        if dof_out.is_some() {
            self.residual_pass.record(&mut encoder);
        }
        self.submit(encoder, "assemble_csr")?;
        let t1 = Instant::now();
        times.assembly += (t1 - t0).as_secs_f64();
        if self.nnz > 0 {
            let (source, size) = (self.values.clone(), (self.nnz * self.gpu.precision.size()) as u64);
            values.copy_from_slice(&self.download("assemble_csr", &source, size)?);
        }
        if let Some(out) = dof_out {
            let (source, size) = (self.dof_out.clone(), (self.dofs * 2 * self.gpu.precision.size()) as u64);
            let reals = self.download("assemble_residual", &source, size)?;
            out.copy_from_slice(bytemuck::cast_slice(&reals));
        }
        times.transfer += t1.elapsed().as_secs_f64();
        Ok(())
    }

    /// The strain energy of each element at `u` (`element_energy`).
    pub fn element_energies(&mut self, u: &[Real]) -> Result<Vec<Real>, GpuError> {
        let u_buffer = self.u.clone();
        self.upload(&u_buffer, u);
        let mut encoder = self.encoder();
        self.energy_pass.record(&mut encoder);
        self.submit(encoder, "element_energy")?;
        let (source, size) = (self.energy.clone(), (self.elements * self.gpu.precision.size()) as u64);
        self.download("element_energy", &source, size)
    }

    /// The body's strain energy at `u`: `element_energy`, then `reduce_sum` passes on the device.
    pub fn strain_energy(&mut self, u: &[Real]) -> Result<Real, GpuError> {
        let u_buffer = self.u.clone();
        self.upload(&u_buffer, u);
        let mut encoder = self.encoder();
        self.energy_pass.record(&mut encoder);
        for pass in &self.reduce_passes {
            pass.record(&mut encoder);
        }
        self.submit(encoder, "reduce_sum")?;
        let (source, size) = (self.total.clone(), self.gpu.precision.size() as u64);
        Ok(self.download("reduce_sum", &source, size)?[0])
    }
}

/// A list with at least one entry (a zero-sized storage buffer cannot be bound).
fn nonempty(list: &[u32]) -> Vec<u32> {
    if list.is_empty() {
        vec![0]
    } else {
        list.to_vec()
    }
}

/// Reals as the device stores them.
pub fn to_device(precision: Precision, reals: &[Real]) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::cast_slice(reals).to_vec(),
        Precision::F32 => bytemuck::cast_slice(&reals.iter().map(|&x| x as f32).collect::<Vec<f32>>()).to_vec(),
    }
}

/// Reals read back from the device (copied: mapped bytes need not be aligned for f64).
pub fn from_device(precision: Precision, bytes: &[u8]) -> Vec<Real> {
    match precision {
        Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
        Precision::F32 => bytemuck::pod_collect_to_vec::<u8, f32>(bytes).into_iter().map(Real::from).collect(),
    }
}
