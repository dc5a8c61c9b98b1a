//! What the solver and both kernel backends agree on: the Newton and contact policy constants
//! the WGSL kernels are built with and their CPU twins read, where the device's work goes, and
//! the phase timers. It imports nothing of the engine, so that `gpu/` and `cpu/` sit below
//! `solver/` and `backend.rs` (doc/ARCHITECTURE.md, "Layers").

/// A reused factorisation is kept while each Newton iteration reduces the residual at least
/// tenfold: at the default tolerances (1e-9) a slower contraction would need more iterations
/// than `solver.max_iterations` allows, and refactorising costs less than a few extra ones.
pub const REFACTOR_CONTRACTION: f64 = 0.1;

/// Newton iterations in a row with stalled Uzawa sweeps after which a step is given up (to be
/// retried thinned or cut back) rather than iterated to `max_iterations`: each costs up to
/// `contact.max_iterations` sweeps, and a stall that lasts this long did not clear in any run.
pub const UZAWA_STALLS: usize = 3;

/// Newton iterations after which a group whose only unmet criterion is the increment solves its
/// contact problems tighter (`solver::coupling::ContactStep::tighten`).
pub const TIGHTEN_AFTER: usize = 4;

/// How far `solver::coupling::ContactStep::tighten` takes the inner tolerance down, at most
/// (relative to the contact tolerance).
pub const TIGHTEST_INNER: f64 = 1e-4;

/// Where the Uzawa sweeps run when the bodies are on a GPU (`bifirst run --uzawa`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UzawaPlacement {
    /// On the device when a Newton round's contact set is large enough to gain
    /// ([`crate::backend::uzawa_on_device`]).
    #[default]
    Auto,
    /// On the device whenever it can run them (Gauss-Seidel sweeps in f64).
    Gpu,
    Cpu,
}

impl UzawaPlacement {
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Gpu => "gpu",
            Self::Cpu => "cpu",
        }
    }
}

impl std::str::FromStr for UzawaPlacement {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            _ => Err(format!("unknown Uzawa placement `{s}` (auto, gpu or cpu)")),
        }
    }
}

/// Which Newton rounds evaluate their bodies on the device when the bodies are on a GPU
/// (`bifirst run --rounds`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RoundPlacement {
    /// The first round of every step, and a later round when its element work is worth a
    /// device pass ([`crate::backend::round_on_device`]); the other rounds on the CPU twins.
    #[default]
    Auto,
    /// Every round.
    Gpu,
}

impl RoundPlacement {
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Gpu => "gpu",
        }
    }
}

impl std::str::FromStr for RoundPlacement {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            _ => Err(format!("unknown round placement `{s}` (auto or gpu)")),
        }
    }
}

/// Wall-clock seconds spent per phase.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, schemars::JsonSchema)]
pub struct PhaseTimes {
    /// Element kernels (on a GPU: the device passes, all kernels, from submission to the mapped
    /// read-back).
    pub elements: f64,
    /// Assembly kernels on the CPU (on a GPU they count in `elements`).
    pub assembly: f64,
    /// On a GPU, packing the uploads and unpacking the read-back (zero on the CPU backend).
    pub transfer: f64,
    pub factorization: f64,
    pub solve: f64,
    pub contact: f64,
    /// Of `contact`: the semi-smooth Newton solves of contact problems whose sweeps stalled.
    pub contact_newton: f64,
    pub total: f64,
}

impl std::ops::AddAssign for PhaseTimes {
    fn add_assign(&mut self, o: Self) {
        self.elements += o.elements;
        self.assembly += o.assembly;
        self.transfer += o.transfer;
        self.factorization += o.factorization;
        self.solve += o.solve;
        self.contact += o.contact;
        self.contact_newton += o.contact_newton;
        self.total += o.total;
    }
}
