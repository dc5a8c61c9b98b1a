//! The one place that decides where the kernels run: on a GPU (which adapter, which precision)
//! or on the CPU. The rest of the engine asks [`Backend::apply`] to place each body's kernels
//! and does not care where they went.

use crate::gpu::{self, Gpu, GpuError};
use crate::precision::{Precision, PRECISION_NAME};
use crate::solver::Simulation;
use std::sync::Arc;

/// What the user asked for (`bifirst run --backend`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BackendChoice {
    /// A hardware GPU if present, else a software adapter, else the CPU.
    Auto,
    /// A GPU adapter, or an error.
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

/// The backend request of a run: choice, adapter name (a case-insensitive substring) and
/// precision (default: f64 when the adapter has it).
#[derive(Debug, Clone, Default)]
pub struct BackendRequest {
    pub choice: BackendChoice,
    pub adapter: Option<String>,
    pub precision: Option<Precision>,
}

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("the CPU backend runs in f64 only; --precision f32 needs a GPU backend")]
    CpuPrecision,
    #[error("--adapter needs a GPU backend (auto or gpu)")]
    CpuAdapter,
}

/// Where the kernels run.
#[derive(Clone)]
pub enum Backend {
    Cpu,
    Gpu(Arc<Gpu>),
}

/// The backend a request resolved to, with why `auto` did not take a GPU.
pub struct Resolved {
    pub backend: Backend,
    pub fallback: Option<String>,
}

impl Backend {
    /// Resolves a request. `auto` falls back to the CPU (saying why) only when no adapter exists;
    /// a named adapter that is missing, or `gpu` without an adapter, is an error.
    pub fn resolve(request: &BackendRequest) -> Result<Resolved, BackendError> {
        match request.choice {
            BackendChoice::Cpu if request.precision == Some(Precision::F32) => Err(BackendError::CpuPrecision),
            BackendChoice::Cpu if request.adapter.is_some() => Err(BackendError::CpuAdapter),
            BackendChoice::Cpu => Ok(Resolved { backend: Backend::Cpu, fallback: None }),
            BackendChoice::Gpu => Ok(Resolved { backend: Backend::Gpu(Arc::new(gpu::open(request.adapter.as_deref(), request.precision)?)), fallback: None }),
            BackendChoice::Auto => match gpu::open(request.adapter.as_deref(), request.precision) {
                Ok(gpu) => Ok(Resolved { backend: Backend::Gpu(Arc::new(gpu)), fallback: None }),
                Err(GpuError::NoAdapter { wanted: None, .. }) => Ok(Resolved { backend: Backend::Cpu, fallback: Some("no GPU adapter".into()) }),
                Err(e) => Err(e.into()),
            },
        }
    }

    /// `cpu` or `gpu`, as logged in `/run`.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu(_) => "gpu",
        }
    }

    /// Precision of the kernels.
    pub fn precision(&self) -> &'static str {
        match self {
            Backend::Cpu => PRECISION_NAME,
            Backend::Gpu(gpu) => gpu.precision.name(),
        }
    }

    /// The adapter, as `bifirst info` lists it.
    pub fn adapter(&self) -> Option<String> {
        match self {
            Backend::Cpu => None,
            Backend::Gpu(gpu) => Some(gpu.adapter.line()),
        }
    }

    /// One line for the terminal and the log.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!("cpu ({PRECISION_NAME})"),
            Backend::Gpu(gpu) => format!("gpu on {} in {}", gpu.adapter.line(), gpu.precision.name()),
        }
    }

    /// Places every body's element and assembly kernels (the CPU twins are the default).
    pub fn apply(&self, sim: &mut Simulation) -> Result<(), GpuError> {
        if let Backend::Gpu(gpu) = self {
            for body in &mut sim.bodies {
                body.use_gpu(gpu.clone())?;
            }
        }
        Ok(())
    }
}
