//! Finding an adapter and opening a device: a hardware GPU when there is one, else a software
//! adapter (lavapipe on Vulkan, llvmpipe on GL); f64 when the adapter has `SHADER_F64`.

use super::shaders::ElementVariant;
use crate::precision::Precision;
use std::sync::Arc;
use wgpu::{Adapter, Backends, DeviceType};

#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter{}; available: {}", .wanted.as_ref().map(|w| format!(" named like `{w}`")).unwrap_or_default(), if .available.is_empty() { "none (install mesa-vulkan-drivers for the lavapipe software adapter)".to_string() } else { .available.join(", ") })]
    NoAdapter { wanted: Option<String>, available: Vec<String> },
    #[error("adapter `{adapter}` has no f64 support in shaders (SHADER_F64); use --precision f32")]
    NoF64 { adapter: String },
    #[error("cannot open a device on `{adapter}`: {message}")]
    Device { adapter: String, message: String },
    #[error("adapter `{adapter}` cannot time kernels (no timestamp queries inside compute passes); leave out --kernel-times")]
    NoClock { adapter: String },
    #[error("kernel `{kernel}`: {message}")]
    Kernel { kernel: String, message: String },
}

/// What `bifirst info` prints about an adapter.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AdapterReport {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    pub f64: bool,
}

impl AdapterReport {
    fn of(adapter: &Adapter) -> Self {
        let info = adapter.get_info();
        Self {
            name: info.name,
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
            f64: adapter.features().contains(wgpu::Features::SHADER_F64),
        }
    }

    /// Whether this is a software rasteriser on the CPU (lavapipe, llvmpipe), not a GPU.
    pub fn software(&self) -> bool {
        self.device_type == format!("{:?}", DeviceType::Cpu)
    }

    /// One line for listings and logs.
    pub fn line(&self) -> String {
        format!("{} ({}, {}, f64 {})", self.name, self.backend, self.device_type, if self.f64 { "yes" } else { "no" })
    }
}

/// What naga's reflection of a kernel's module says of its resources: every one, by name with
/// its binding, and per entry point the names of those it uses.
struct Reflection {
    declared: Vec<(String, u32)>,
    used: std::collections::HashMap<String, Vec<String>>,
}

/// An open device with the precision its pipelines use.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: AdapterReport,
    pub precision: Precision,
    /// Timestamps around every dispatch, when the run asked for kernel times.
    clock: Option<super::clock::KernelClock>,
    /// Whether the device was opened with what the clock needs.
    clock_features: bool,
    /// Per kernel and variant, its resources by name with their bindings, and those each entry
    /// point uses ([`Gpu::bind_named`]), read once.
    bindings: std::sync::Mutex<std::collections::HashMap<String, Arc<Reflection>>>,
}

fn adapters_of(backends: Backends) -> Vec<Adapter> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor { backends, ..wgpu::InstanceDescriptor::new_without_display_handle() });
    pollster::block_on(instance.enumerate_adapters(backends))
}

/// The Vulkan adapters, or the GL ones when there is no Vulkan adapter: GL comes after Vulkan in
/// the ranking anyway, and probing it talks to the display server (and complains without one).
fn adapters() -> Vec<Adapter> {
    let vulkan = adapters_of(Backends::VULKAN);
    if vulkan.is_empty() {
        adapters_of(Backends::GL)
    } else {
        vulkan
    }
}

/// Every adapter this machine offers, Vulkan and GL, best first (the order `auto` picks in).
pub fn describe_adapters() -> Vec<AdapterReport> {
    ranked(adapters_of(Backends::VULKAN | Backends::GL)).iter().map(AdapterReport::of).collect()
}

/// Hardware before software, Vulkan before GL, f64 before none.
fn ranked(mut list: Vec<Adapter>) -> Vec<Adapter> {
    list.sort_by_key(|a| {
        let info = a.get_info();
        let kind = match info.device_type {
            DeviceType::DiscreteGpu => 0,
            DeviceType::IntegratedGpu => 1,
            DeviceType::VirtualGpu | DeviceType::Other => 2,
            DeviceType::Cpu => 3,
        };
        (kind, info.backend != wgpu::Backend::Vulkan, !a.features().contains(wgpu::Features::SHADER_F64))
    });
    list
}

/// Opens the best adapter, or the first whose name contains `name` (case-insensitive), in
/// `precision` (default: f64 when the adapter has it, else f32).
pub fn open(name: Option<&str>, precision: Option<Precision>) -> Result<Gpu, GpuError> {
    let list = ranked(adapters());
    let available: Vec<String> = list.iter().map(|a| AdapterReport::of(a).line()).collect();
    let wanted = name.map(str::to_lowercase);
    let adapter = list.into_iter().find(|a| wanted.as_ref().is_none_or(|w| a.get_info().name.to_lowercase().contains(w))).ok_or_else(|| GpuError::NoAdapter { wanted: name.map(String::from), available })?;
    open_adapter(adapter, precision)
}

/// The best hardware GPU, if the machine has one (software adapters are never taken), as
/// `bifirst info` describes it.
pub fn hardware_adapter() -> Option<AdapterReport> {
    ranked(adapters()).iter().map(AdapterReport::of).find(|report| !report.software())
}

/// Opens a device on `adapter` in `precision` (default: f64 when the adapter has it, else f32).
fn open_adapter(adapter: Adapter, precision: Option<Precision>) -> Result<Gpu, GpuError> {
    let report = AdapterReport::of(&adapter);
    let precision = match precision {
        Some(Precision::F64) if !report.f64 => return Err(GpuError::NoF64 { adapter: report.name }),
        Some(p) => p,
        None if report.f64 => Precision::F64,
        None => Precision::F32,
    };
    let clock_features = adapter.features().contains(super::clock::FEATURES);
    let mut required_features = if precision == Precision::F64 { wgpu::Features::SHADER_F64 } else { wgpu::Features::empty() };
    if clock_features {
        required_features |= super::clock::FEATURES;
    }
    let descriptor = wgpu::DeviceDescriptor { label: Some("bifirst"), required_features, required_limits: adapter.limits(), ..Default::default() };
    let (device, queue) = pollster::block_on(adapter.request_device(&descriptor)).map_err(|e| GpuError::Device { adapter: report.name.clone(), message: e.to_string() })?;
    Ok(Gpu { device, queue, adapter: report, precision, clock: None, clock_features, bindings: Default::default() })
}

/// The checks wgpu would add to our kernels, all left out: every loop counts up to a bound and
/// every integer division is by a non-zero constant (tests/shader_promises.rs), and the
/// kernels index their arrays within bounds (their parity tests against the CPU twins). On an
/// NVIDIA H100 the checks cost more than the work (doc/benchmarks.md, "Shader runtime checks"):
/// with them the Hex8 force+tangent kernel ran 2.3x slower in f64 and 11x in f32, most of it
/// the loop counters wgpu adds, which probably keep the driver from unrolling the loops.
const SHADER_CHECKS: wgpu::ShaderRuntimeChecks = wgpu::ShaderRuntimeChecks::unchecked();

impl Gpu {
    /// Starts timing every dispatch ([`super::clock::KernelClock`]).
    pub fn start_clock(&mut self) -> Result<(), GpuError> {
        if !self.clock_features {
            return Err(GpuError::NoClock { adapter: self.adapter.name.clone() });
        }
        self.clock = Some(super::clock::KernelClock::new(&self.device, &self.queue));
        Ok(())
    }

    /// Records `dispatch`, of `kernel`'s entry point `entry`, into `pass`, between timestamps
    /// when the clock runs.
    pub fn dispatch(&self, pass: &mut wgpu::ComputePass, (kernel, entry): (&'static str, &'static str), dispatch: impl FnOnce(&mut wgpu::ComputePass)) {
        match &self.clock {
            Some(clock) => clock.time(pass, (kernel, entry), dispatch),
            None => dispatch(pass),
        }
    }

    /// Submits `encoder`'s commands; when the clock runs, with its timestamps, which it takes
    /// once the submission has finished.
    pub fn submit(&self, mut encoder: wgpu::CommandEncoder) -> Result<(), GpuError> {
        match &self.clock {
            Some(clock) => {
                clock.resolve(&mut encoder);
                self.queue.submit([encoder.finish()]);
                clock.collect(self)
            }
            None => {
                self.queue.submit([encoder.finish()]);
                Ok(())
            }
        }
    }

    /// The device's time by kernel so far, when the clock runs.
    pub fn kernel_times(&self) -> Option<super::clock::KernelTimes> {
        self.clock.as_ref().map(super::clock::KernelClock::times)
    }

    /// A bind group of `pipeline`'s group 0 (`kernel`'s `entry` point for `variant`) with each
    /// `(name, buffer)` bound whole at the binding the kernel declares for that name: naga's
    /// reflection of the composed module, not numbers kept by hand. Names the entry point does
    /// not use are left out, so one list can serve every entry point of a module.
    ///
    /// # Panics
    /// When a name is not one of the module's resources, or the entry point uses a resource
    /// the list lacks: the kernel and the code that binds it disagree.
    pub fn bind_named(&self, pipeline: &wgpu::ComputePipeline, kernel: (&str, &str, Option<ElementVariant>), bound: &[(&str, &wgpu::Buffer)]) -> wgpu::BindGroup {
        self.bind_resources(pipeline, kernel, &bound.iter().map(|&(name, b)| (name, b.as_entire_binding())).collect::<Vec<_>>())
    }

    /// [`Gpu::bind_named`] with any binding resources (a range of a buffer, for one).
    pub fn bind_resources(&self, pipeline: &wgpu::ComputePipeline, (kernel, entry, variant): (&str, &str, Option<ElementVariant>), bound: &[(&str, wgpu::BindingResource)]) -> wgpu::BindGroup {
        let reflection = self.reflection(kernel, variant);
        let used = reflection.used.get(entry).unwrap_or_else(|| panic!("`{kernel}` has no entry point `{entry}`"));
        let mut entries = Vec::with_capacity(used.len());
        for (name, resource) in bound {
            let (_, binding) = reflection.declared.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("`{kernel}` declares no resource `{name}`"));
            if used.iter().any(|u| u == name) {
                entries.push(wgpu::BindGroupEntry { binding: *binding, resource: resource.clone() });
            }
        }
        for name in used {
            assert!(bound.iter().any(|(n, _)| n == name), "`{kernel}`'s `{entry}` uses `{name}`, which is not bound");
        }
        self.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(kernel), layout: &pipeline.get_bind_group_layout(0), entries: &entries })
    }

    /// The reflection of a kernel's module for `variant` (made once).
    fn reflection(&self, kernel: &str, variant: Option<ElementVariant>) -> Arc<Reflection> {
        let key = format!("{kernel}/{variant:?}");
        if let Some(found) = self.bindings.lock().expect("not poisoned").get(&key) {
            return found.clone();
        }
        let (module, info) = self.reflect(kernel, variant);
        let named = |(_, g): (naga::Handle<naga::GlobalVariable>, &naga::GlobalVariable)| Some((g.name.clone()?, g.binding.as_ref()?.binding));
        let declared: Vec<(String, u32)> = module.global_variables.iter().filter_map(named).collect();
        let used = module
            .entry_points
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let uses = info.get_entry_point(i);
                (e.name.clone(), module.global_variables.iter().filter(|(handle, _)| !uses[*handle].is_empty()).filter_map(named).map(|(name, _)| name).collect())
            })
            .collect();
        let found = Arc::new(Reflection { declared, used });
        self.bindings.lock().expect("not poisoned").insert(key, found.clone());
        found
    }

    /// The composed module of a kernel at this device's precision, parsed and analysed by naga.
    fn reflect(&self, kernel: &str, variant: Option<ElementVariant>) -> (naga::Module, naga::valid::ModuleInfo) {
        let source = super::shaders::source(kernel, self.precision, variant, self.device.limits().max_compute_workgroup_storage_size).unwrap_or_else(|e| panic!("`{kernel}` composes: {e}"));
        let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("`{kernel}` parses: {e}"));
        let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all()).validate(&module).unwrap_or_else(|e| panic!("`{kernel}` validates: {e}"));
        (module, info)
    }

    /// A compute pipeline for a shader of `shaders/` at this device's precision; shader errors
    /// come back as [`GpuError::Kernel`] instead of wgpu's default panic.
    pub fn pipeline(&self, kernel: &str, variant: Option<ElementVariant>) -> Result<wgpu::ComputePipeline, GpuError> {
        self.pipeline_at(kernel, "main", variant)
    }

    /// [`Gpu::pipeline`] for another entry point of the kernel's module.
    pub fn pipeline_at(&self, kernel: &str, entry: &str, variant: Option<ElementVariant>) -> Result<wgpu::ComputePipeline, GpuError> {
        let source = super::shaders::source(kernel, self.precision, variant, self.device.limits().max_compute_workgroup_storage_size).map_err(|message| GpuError::Kernel { kernel: kernel.into(), message })?;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let descriptor = wgpu::ShaderModuleDescriptor { label: Some(kernel), source: wgpu::ShaderSource::Wgsl(source.into()) };
        // SAFETY: `SHADER_CHECKS` holds for every kernel of `shaders/` (tests/shader_promises.rs
        // checks each module); the storage buffers stay bounded by the device's robust buffer
        // access, which wgpu turns on wherever there is one.
        let module = unsafe { self.device.create_shader_module_trusted(descriptor, SHADER_CHECKS) };
        let pipeline = self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor { label: Some(kernel), layout: None, module: &module, entry_point: Some(entry), compilation_options: Default::default(), cache: None });
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Kernel { kernel: kernel.into(), message: e.to_string() }),
            None => Ok(pipeline),
        }
    }

    /// Waits for submitted work and maps `buffer` for reading.
    pub fn read(&self, kernel: &str, buffer: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
        self.read_range(kernel, buffer, buffer.size())
    }

    /// Maps the first `bytes` of a buffer (after what was submitted) and copies them out.
    pub fn read_range(&self, kernel: &str, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        self.read_range_with(kernel, buffer, bytes, <[u8]>::to_vec)
    }

    /// Maps the first `bytes` of a buffer (after what was submitted) and hands them to `read`
    /// while mapped: a large read-back is taken where it lies instead of copied out first.
    pub fn read_range_with<R>(&self, kernel: &str, buffer: &wgpu::Buffer, bytes: u64, read: impl FnOnce(&[u8]) -> R) -> Result<R, GpuError> {
        let err = |message: String| GpuError::Kernel { kernel: kernel.into(), message };
        let (sender, receiver) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, ..bytes, move |result| {
            let _ = sender.send(result);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| err(e.to_string()))?;
        receiver.recv().map_err(|e| err(e.to_string()))?.map_err(|e| err(e.to_string()))?;
        let out = read(&buffer.get_mapped_range(..bytes).map_err(|e| err(e.to_string()))?);
        buffer.unmap();
        Ok(out)
    }
}
