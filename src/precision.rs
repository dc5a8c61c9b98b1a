//! The one place that chooses the engine's floating-point precision.
//!
//! The CPU engine runs in f64; the GPU backend (later) picks f32 or f64 per adapter, but
//! everything on the CPU side, the factorisation included, uses [`Real`].

/// The floating-point type of the CPU engine.
pub type Real = f64;

/// Name of [`Real`] as written to logs (`/run.precision`).
pub const PRECISION_NAME: &str = "f64";
