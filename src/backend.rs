//! The one place that decides where the kernels run: on a GPU (which adapter, which precision)
//! or on the CPU. The rest of the engine asks [`Backend::apply`] to place each body's kernels
//! and does not care where they went.

use crate::contact::uzawa::{Acceleration, Sweep};
use crate::contact::Settings;
use crate::gpu::{self, Gpu, GpuError, GpuWorld, WorldBody};
use crate::mesh::ElementKind;
pub use crate::policy::{RoundPlacement, UzawaPlacement};
use crate::precision::{Precision, PRECISION_NAME};
use std::sync::Arc;

/// What the user asked for (`bifirst run --backend`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BackendChoice {
    /// The fastest, which is the CPU on every scene measured so far, with or without a hardware
    /// GPU ([`AUTO_REASON_GPU`]); an adapter named with `--adapter` is taken.
    Auto,
    /// A GPU adapter (a hardware one first, else a software one, with a notice), or an error.
    Gpu,
    #[default]
    Cpu,
}

impl std::str::FromStr for BackendChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            _ => Err(format!("unknown backend `{s}` (auto, gpu or cpu)")),
        }
    }
}

/// The backend request of a run: choice, adapter name (a case-insensitive substring),
/// precision (default: f64 when the adapter has it), where the Uzawa sweeps run and which
/// Newton rounds go to the device.
#[derive(Debug, Clone, Default)]
pub struct BackendRequest {
    pub choice: BackendChoice,
    pub adapter: Option<String>,
    pub precision: Option<Precision>,
    pub uzawa: UzawaPlacement,
    pub rounds: RoundPlacement,
    /// Time every dispatch on the device (`--kernel-times`), reported by kernel.
    pub kernel_times: bool,
}

impl BackendRequest {
    /// The command-line options that make this request (`--backend`, `--adapter`,
    /// `--precision`), for a command run elsewhere (a Slurm array task).
    pub fn args(&self) -> Vec<String> {
        let choice = match self.choice {
            BackendChoice::Auto => "auto",
            BackendChoice::Gpu => "gpu",
            BackendChoice::Cpu => "cpu",
        };
        let mut args = vec!["--backend".to_string(), choice.to_string()];
        if let Some(adapter) = &self.adapter {
            args.extend(["--adapter".to_string(), adapter.clone()]);
        }
        if let Some(precision) = self.precision {
            args.extend(["--precision".to_string(), precision.name().to_string()]);
        }
        if self.uzawa != UzawaPlacement::Auto {
            args.extend(["--uzawa".to_string(), self.uzawa.name().to_string()]);
        }
        if self.rounds != RoundPlacement::Auto {
            args.extend(["--rounds".to_string(), self.rounds.name().to_string()]);
        }
        if self.kernel_times {
            args.push("--kernel-times".to_string());
        }
        args
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("the CPU backend runs in f64 only; --precision f32 needs a GPU backend")]
    CpuPrecision,
    #[error("--adapter needs a GPU backend (auto or gpu)")]
    CpuAdapter,
    #[error("--kernel-times needs a GPU backend")]
    CpuKernelTimes,
    #[error("--uzawa gpu needs a GPU backend")]
    CpuUzawa,
    #[error("--rounds gpu needs a GPU backend")]
    CpuRounds,
}

/// Where the kernels run.
#[derive(Clone)]
pub enum Backend {
    Cpu,
    Gpu(Arc<Gpu>, UzawaPlacement, RoundPlacement),
}

/// Why `auto` runs on the CPU on a machine with a hardware GPU: the GPU backend was measured
/// slower than the CPU backend of the same build and machine on every scene and size, on an
/// NVIDIA H100 and an H200 (doc/benchmarks.md, "GPU pipeline" and "The GPU at scale"), because
/// the factorisations, solves and contact stay on the host and the device is refilled every
/// call; so no size is named where the GPU wins.
pub const AUTO_REASON_GPU: &str = "was measured slower than the CPU backend on every scene (doc/benchmarks.md); `--backend gpu` runs on it";

/// `--uzawa auto` on a hardware adapter: the fewest contact points of a Newton round, and the
/// fewest per colour on average, for the device's sweeps. Estimated, not yet measured on
/// hardware: a device pass costs ~0.3 ms of submit and fence wait on an H100, a point-sweep
/// 1.3 to 5 µs on the CPU (doc/benchmarks.md, "Contact on the device").
pub const AUTO_UZAWA_POINTS: usize = 1000;
pub const AUTO_UZAWA_POINTS_PER_COLOUR: usize = 64;

/// The backend a request resolved to, with what the user should be told about the choice.
pub struct Resolved {
    pub backend: Backend,
    /// Why the choice may surprise: a software adapter for `gpu` (printed as a warning).
    pub notice: Option<String>,
    /// Why `auto` chose what it chose (logged as information).
    pub reason: Option<String>,
}

impl Backend {
    /// Resolves a request. A named adapter that is missing, or `gpu` without any adapter, is an
    /// error.
    pub fn resolve(request: &BackendRequest) -> Result<Resolved, BackendError> {
        let on_gpu = |mut gpu: Gpu| -> Result<Resolved, BackendError> {
            if request.kernel_times {
                gpu.start_clock()?;
            }
            let notice = gpu.adapter.software().then(|| format!("no hardware GPU: the GPU kernels run on the software adapter {} (slow; use --backend cpu for speed)", gpu.adapter.name));
            Ok(Resolved { backend: Backend::Gpu(Arc::new(gpu), request.uzawa, request.rounds), notice, reason: None })
        };
        let cpu = |reason: String| Ok(Resolved { backend: Backend::Cpu, notice: None, reason: Some(format!("backend auto: {reason}; running on the CPU")) });
        match request.choice {
            BackendChoice::Cpu if request.precision == Some(Precision::F32) => Err(BackendError::CpuPrecision),
            BackendChoice::Cpu if request.adapter.is_some() => Err(BackendError::CpuAdapter),
            BackendChoice::Cpu if request.uzawa == UzawaPlacement::Gpu => Err(BackendError::CpuUzawa),
            BackendChoice::Cpu if request.rounds == RoundPlacement::Gpu => Err(BackendError::CpuRounds),
            BackendChoice::Cpu if request.kernel_times => Err(BackendError::CpuKernelTimes),
            BackendChoice::Cpu => Ok(Resolved { backend: Backend::Cpu, notice: None, reason: None }),
            BackendChoice::Gpu => on_gpu(gpu::open(request.adapter.as_deref(), request.precision)?),
            // An adapter named by the user is taken whatever it is.
            BackendChoice::Auto if request.adapter.is_some() => on_gpu(gpu::open(request.adapter.as_deref(), request.precision)?),
            BackendChoice::Auto => match gpu::hardware_adapter() {
                None => cpu("no hardware GPU".into()),
                Some(report) => cpu(format!("the GPU {} {AUTO_REASON_GPU}", report.name)),
            },
        }
    }

    /// `cpu` or `gpu`, as logged in `/run`.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu(..) => "gpu",
        }
    }

    /// Precision of the kernels.
    pub fn precision(&self) -> &'static str {
        match self {
            Backend::Cpu => PRECISION_NAME,
            Backend::Gpu(gpu, ..) => gpu.precision.name(),
        }
    }

    /// The adapter, as `bifirst info` lists it.
    pub fn adapter(&self) -> Option<String> {
        match self {
            Backend::Cpu => None,
            Backend::Gpu(gpu, ..) => Some(gpu.adapter.line()),
        }
    }

    /// The device's time by kernel so far, when `--kernel-times` asked for it.
    pub fn kernel_times(&self) -> Option<crate::gpu::clock::KernelTimes> {
        match self {
            Backend::Cpu => None,
            Backend::Gpu(gpu, ..) => gpu.kernel_times(),
        }
    }

    /// One line for the terminal and the log.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!("cpu ({PRECISION_NAME})"),
            Backend::Gpu(gpu, uzawa, rounds) => format!("gpu on {} in {}, Uzawa sweeps {}, Newton rounds {}", gpu.adapter.line(), gpu.precision.name(), uzawa.name(), rounds.name()),
        }
    }

    /// Why `--uzawa gpu` cannot put a scene's sweeps on the device (they stay on the CPU).
    pub fn uzawa_notice(&self, sweep: Option<Sweep>) -> Option<String> {
        let Backend::Gpu(gpu, UzawaPlacement::Gpu, _) = self else { return None };
        let why = if gpu.precision != Precision::F64 {
            "in f32 they could not reach the contact tolerance"
        } else if sweep == Some(Sweep::Jacobi) {
            "the scene asks for Jacobi sweeps (contact.sweep)"
        } else {
            return None;
        };
        Some(format!("--uzawa gpu: the device's Uzawa sweeps are Gauss-Seidel in f64 and {why}; they run on the CPU"))
    }

    /// Where the bodies' element and assembly kernels run: on a GPU, every body in one device
    /// world; `None` runs the CPU twins.
    pub fn device_world(&self, bodies: &[WorldBody]) -> Result<Option<GpuWorld>, GpuError> {
        let Backend::Gpu(gpu, uzawa, rounds) = self else { return Ok(None) };
        let mut world = GpuWorld::new(gpu.clone(), bodies)?;
        world.uzawa = *uzawa;
        world.rounds = *rounds;
        Ok(Some(world))
    }
}

/// Whether a Newton round's contact problems, `points` points in at most `colours` colours, the
/// widest of `widest` points, take their Uzawa sweeps on the device of `world`. Only
/// Gauss-Seidel sweeps in f64 can: the device has no Jacobi kernel, and in f32 the iterations
/// cannot reach the contact tolerance. `auto` never takes a software adapter (lavapipe was
/// measured slower than the CPU's sweeps), and takes a hardware one when the round has at least
/// [`AUTO_UZAWA_POINTS`] points and either is solved whole, one workgroup per problem
/// (`widest` within [`crate::gpu::uzawa_sweep::SOLVE_WIDEST`]: one dispatch for all its sweeps),
/// or a colour holds on average at least [`AUTO_UZAWA_POINTS_PER_COLOUR`] points (a dispatch per
/// colour and sweep), and
/// only for plain sweeps: the device's sweeps are not accelerated, and the CPU's Anderson-mixed
/// sweeps need 5 to 10 times fewer (doc/benchmarks.md, "Contact solver"). `gpu` runs plain
/// sweeps on the device whatever `contact.acceleration` says.
pub fn uzawa_on_device(world: &GpuWorld, settings: &Settings, points: usize, colours: usize, widest: usize) -> bool {
    if settings.sweep != Sweep::GaussSeidel || world.precision() != Precision::F64 {
        return false;
    }
    match world.uzawa {
        UzawaPlacement::Gpu => true,
        UzawaPlacement::Cpu => false,
        UzawaPlacement::Auto => {
            let dispatches_pay = widest <= crate::gpu::uzawa_sweep::SOLVE_WIDEST || points >= AUTO_UZAWA_POINTS_PER_COLOUR * colours;
            settings.acceleration == Acceleration::None && !world.software() && points >= AUTO_UZAWA_POINTS && dispatches_pay
        }
    }
}

/// What a device pass costs in submit and fence wait, in seconds: ~0.3 ms on an NVIDIA H100
/// (doc/benchmarks.md, "GPU pipeline"), about 13 of them per grain step before rounds were
/// placed.
pub const DEVICE_PASS_SECONDS: f64 = 3e-4;

/// The cores of the machine whose rates [`cpu_seconds_per_element`] are (the H100's host).
const REFERENCE_CORES: f64 = 16.0;

/// CPU seconds per element and core of a force and tangent evaluation, by element kind: the
/// CPU column of `bifirst bench --elements 1000000` on that machine (16 cores: Tri3 23.9 M/s,
/// Quad4 6.58 M/s, Tet4 14.1 M/s, Hex8 860 k/s) times 16.
fn cpu_seconds_per_element(kind: ElementKind) -> f64 {
    REFERENCE_CORES
        / match kind {
            ElementKind::Tri3 => 23.9e6,
            ElementKind::Quad4 => 6.58e6,
            ElementKind::Tet4 => 14.1e6,
            ElementKind::Hex8 => 860e3,
        }
}

/// Whether a Newton round evaluates its bodies, `elements` of each kind, on the device of
/// `world`. With `--rounds auto`, the first round of a step does (every body of the scene, in
/// the large dispatches a GPU is for), and a later round when the CPU twins would take longer
/// on the run's threads than a device pass costs ([`DEVICE_PASS_SECONDS`]): after the first
/// round only the groups still iterating remain, mostly a few grains in contact, which the CPU
/// evaluates in microseconds while a pass waits for the device. A software adapter decides as
/// the H100's machine would (its rates and its cores, not the software's nor this machine's):
/// it is how CI sees the GPU path, on two cores, where a round of the hundred grains that land
/// in a falling packing went to the device and sent their states across the bus each round
/// (a submit and 20-30 bytes a grain of the packing each, on lavapipe), which that machine
/// evaluates on its CPU. Estimated from the H100's measurements, not yet measured as a rule.
pub fn round_on_device(world: &GpuWorld, first: bool, elements: &[(ElementKind, usize)]) -> bool {
    match world.rounds {
        RoundPlacement::Gpu => true,
        RoundPlacement::Auto if first => true,
        RoundPlacement::Auto => {
            let threads = if world.software() { REFERENCE_CORES } else { rayon::current_num_threads() as f64 };
            elements.iter().map(|&(kind, n)| n as f64 * cpu_seconds_per_element(kind)).sum::<f64>() / threads >= DEVICE_PASS_SECONDS
        }
    }
}
