//! What a run did ([`RunSummary`], printed at its end and logged on `/summary`) and how a step's
//! created energy is told ([`energy_gain`]): here, below `run`, so that the log's readers and
//! schemas need nothing of the run itself.

use crate::policy::PhaseTimes;
use crate::precision::Real;
use crate::solver::Energies;
use std::path::PathBuf;

/// What a run did, printed at its end and logged on `/summary`.
#[derive(Debug, Clone, serde::Serialize, schemars::JsonSchema)]
#[schemars(title = "bifirst.Summary")]
pub struct RunSummary {
    pub scene: String,
    /// `finished`, `failed` or `interrupted`.
    #[schemars(extend("enum" = ["finished", "energy_created", "failed", "interrupted"]))]
    pub status: String,
    /// Why the run stopped early.
    pub message: Option<String>,
    pub backend: String,
    pub precision: String,
    /// The GPU adapter, when the kernels ran on one.
    pub adapter: Option<String>,
    /// Steps this run took (a restarted run counts from its state).
    pub steps: usize,
    /// The index of the last step, counted from t = 0 across restarts.
    pub last_step: usize,
    pub t_end: Real,
    pub cutbacks: usize,
    pub newton_iterations: usize,
    pub uzawa_iterations: usize,
    /// Semi-smooth Newton iterations of stalled contact problems over the run.
    pub contact_newton_iterations: usize,
    /// Body evaluations over the run (see [`StepReport::bodies_iterated`]).
    pub bodies_iterated: usize,
    /// Newton increments taken on the device over the run, summed over bodies.
    pub device_iterations: usize,
    /// Numeric factorisations over the run.
    pub factorizations: usize,
    /// Largest penetration over the run (0 without contact).
    pub max_penetration: Real,
    /// Deepest node inside another body or behind an obstacle over the run, and the largest
    /// such depth relative to the local element size (`/contact.max_overlap*`).
    pub max_overlap: Real,
    pub max_overlap_ratio: Real,
    /// Steps whose numerical dissipation was negative beyond [`ENERGY_GAIN_TOLERANCE`] (energy
    /// created by the scheme), and the largest such gain relative to the energy scale.
    pub energy_gain_steps: usize,
    pub max_energy_gain: Real,
    /// Step control over the run (see `/solver`): attempts rejected for overlap and for
    /// energy, and sub-steps kept beyond a bound at the smallest step allowed.
    pub overlap_retries: usize,
    pub energy_retries: usize,
    pub kept_beyond_bounds: usize,
    /// Energy the run created, relative to the energy scale ([`Simulation::energy_created`]):
    /// above `solver.max_energy_gain` the status is `energy_created` and the exit status 3.
    pub energy_created: Real,
    pub wall_s: f64,
    /// Wall time of the steps by phase, summed over the run.
    pub wall_by_phase: PhaseTimes,
    /// Bytes moved between host and GPU over the run.
    pub bytes_moved: u64,
    /// GPU queue submits over the run (one per device pass over all bodies).
    pub device_submits: u64,
    /// The device's time by kernel over the run, with `--kernel-times` (else null).
    pub kernel_times: Option<crate::gpu::clock::KernelTimes>,
    /// Energies at the end, with the dissipation and the energy balance error.
    pub energy: crate::solver::Energies,
    pub output: PathBuf,
}

/// A step whose numerical dissipation is negative by more than this share of the energy scale
/// created energy: the scheme is meant to dissipate (theta, xi, impacts), never to add.
pub const ENERGY_GAIN_TOLERANCE: Real = 1e-4;
/// The energy a step created relative to the energy scale (`max(|E(0)|, |E|, |W_ext|)`), when
/// beyond [`ENERGY_GAIN_TOLERANCE`]: `initial` is `E(0)`, `e` the energies after the step and
/// `dissipated` the numerical dissipation before it. The run counts its steps with it, and the
/// summary of a log without `/summary` its logged intervals.
pub fn energy_gain(initial: Real, e: &Energies, dissipated: Real) -> Option<Real> {
    let gain = (dissipated - e.numerical_dissipation) / e.scale(initial);
    (gain > ENERGY_GAIN_TOLERANCE).then_some(gain)
}
