//! The `#[repr(C)]` structs that cross to the kernels, generic over the real type (f32 or f64);
//! tests check them against naga's layouts. The CPU twins use their `Real` instances.

use bytemuck::{Pod, Zeroable};

/// `struct MaterialParams` of `shaders/include/tensor.wgsl`: G, K, a1..a6
/// (zero where a model has no such parameter, see `Model::parameters`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MaterialParams<R> {
    pub g: R,
    pub k: R,
    pub a1: R,
    pub a2: R,
    pub a3: R,
    pub a4: R,
    pub a5: R,
    pub a6: R,
}

/// `struct Coefficients` of `shaders/include/batch.wgsl` (the assembly and Newton kernels):
/// `factor` (ξ) multiplies the tangent and the new internal force, `c1 = 1/(θ dt²)` the inertia,
/// `motion` (how far the scene's fastest motion goes in the step; zero outside Newton calls) is
/// the floor of the Newton increment's bound.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Coefficients<R> {
    pub factor: R,
    pub c1: R,
    pub motion: R,
}

/// `struct DofStep` of `shaders/include/batch.wgsl`: what a dof needs from the start of the step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DofStep<R> {
    pub mass: R,
    /// `u_t + dt v_t`.
    pub u_pred: R,
    pub f_int_t: R,
    pub f_ext: R,
}

impl DofStep<f64> {
    /// The contact-free residual of the dof at displacement `u` with internal force `f`, as
    /// `assemble_residual` computes it: `c1 m (u - u_pred) - (1-ξ)(f_ext - f_int,t) - ξ (f_ext - f)`.
    pub fn residual(&self, coefficients: Coefficients<f64>, u: f64, f: f64) -> f64 {
        let xi = coefficients.factor;
        let inertia = coefficients.c1 * self.mass * (u - self.u_pred);
        inertia - (1.0 - xi) * (self.f_ext - self.f_int_t) - xi * (self.f_ext - f)
    }
}

/// `struct DofOut` of `shaders/include/batch.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DofOut<R> {
    pub f_int: R,
    pub g: R,
}

/// `struct DofState` of `shaders/include/batch.wgsl`: a dof's committed state, kept on the device
/// for a body that steps there (`step_begin`, `step_commit`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DofState<R> {
    pub u: R,
    pub v: R,
    pub f_int: R,
}

/// `struct StepMotion` of `shaders/include/batch.wgsl`: the theta rule of one step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepMotion<R> {
    pub dt: R,
    /// `dt (1 - θ)`, computed once as the host's `Body::trial_velocity` computes it.
    pub dt_explicit: R,
    /// `θ dt`.
    pub theta_dt: R,
    /// The scene's dimension, 2 or 3 (a real, as the uniform's other fields).
    pub dim: R,
}

impl StepMotion<f64> {
    pub fn of(dt: f64, theta: f64, dim: usize) -> Self {
        Self { dt, dt_explicit: dt * (1.0 - theta), theta_dt: theta * dt, dim: dim as f64 }
    }
}

/// The reals `newton_summary` writes per member in a scene of dimension `dim` that the host
/// reads every step (what `/bodies` logs and the energy balance needs of each body): its Newton
/// state's status and iterations (`status + 4 iterations`), the kinetic energy, `Σ m x`,
/// `Σ m v` (`dim` each) and the angular momentum (1 component in 2D, 3 in 3D). The box of the
/// nodes goes apart, in f32 (`2 dim` of them), and the rest of the step's bookkeeping into the
/// member's [`TALLY_ROW`], which `newton_tally` adds up on the device.
pub const fn summary_len(dim: usize) -> usize {
    2 + 2 * dim + if dim == 2 { 1 } else { 3 }
}

/// The reals of a member's tally row (`newton_summary`), which the host reads only for a
/// member whose step's end it takes back: the residual where its iterations ended, its strain
/// energy there, `Σ m (v - v_t)²` (times `θ - 1/2`, the theta rule's dissipation), the force
/// terms' dissipation `Σ Δu ((1 - ξ) f_int,t + ξ f_int) - (E_end - E_start)`, and the largest
/// squared nodal speed.
pub const TALLY_ROW: usize = 5;

/// The reals `newton_tally` writes per batch: over the kept members of a call that converged,
/// their count, then the sums of their theta terms, force dissipations and strain energies, the
/// largest squared nodal speed and the largest residual ([`StepTally`]).
pub const TALLY_LEN: usize = 6;

/// What the host books of the members whose step's ends the device keeps, summed on the device
/// (`newton_tally`) instead of read member by member.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepTally {
    pub members: usize,
    /// `Σ m (v - v_t)²`: times `θ - 1/2`, the theta rule's dissipation.
    pub theta_term: f64,
    /// `Σ Δu ((1 - ξ) f_int,t + ξ f_int) - ΔE`: the force terms' dissipation.
    pub force_dissipation: f64,
    /// The strain energy at the step's end.
    pub strain: f64,
    pub max_speed2: f64,
    pub max_residual: f64,
}

impl StepTally {
    /// From `newton_tally`'s reals ([`TALLY_LEN`]).
    pub fn of(reals: &[f64]) -> Self {
        Self { members: reals[0] as usize, theta_term: reals[1], force_dissipation: reals[2], strain: reals[3], max_speed2: reals[4], max_residual: reals[5] }
    }

    /// Both tallies' members. The largest values stay the larger (a member taken out keeps
    /// counting there: they bound what the step reports, they are not booked).
    pub fn add(&mut self, other: &Self) {
        self.members += other.members;
        self.theta_term += other.theta_term;
        self.force_dissipation += other.force_dissipation;
        self.strain += other.strain;
        self.max_speed2 = self.max_speed2.max(other.max_speed2);
        self.max_residual = self.max_residual.max(other.max_residual);
    }

    /// Takes out one member whose tally row (`row`, [`TALLY_ROW`]) was counted.
    pub fn remove(&mut self, row: &[f64]) {
        self.members -= 1;
        self.theta_term -= row[2];
        self.force_dissipation -= row[3];
        self.strain -= row[1];
        if self.members == 0 {
            *self = Self::default();
        }
    }
}

/// Where entry `(i, j)` of a symmetric matrix lies in its lower triangle stored row by row
/// (`packed` of `newton.wgsl`): how a member's `K̄⁻¹` is laid out in its slot.
pub fn packed(i: usize, j: usize) -> usize {
    let a = i.max(j);
    a * (a + 1) / 2 + i.min(j)
}

/// The entries of an `n x n` symmetric matrix's lower triangle ([`packed`]).
pub const fn packed_len(n: usize) -> usize {
    n * (n + 1) / 2
}

/// The lower triangle of an `n x n` symmetric matrix, row by row ([`packed`]), entry `(i, j)`,
/// `i >= j`, from `entry(i, j)`.
pub fn pack_lower(n: usize, entry: impl Fn(usize, usize) -> f64) -> Vec<f64> {
    (0..n).flat_map(|i| (0..=i).map(move |j| (i, j))).map(|(i, j)| entry(i, j)).collect()
}

/// A body's step end as the device reduced it (`newton_summary`), for a body whose
/// displacements and forces stay on the device: what the host reads of it every step. The rest
/// of its step's bookkeeping is summed over such bodies on the device ([`StepTally`]).
/// Components beyond the scene's dimension are zero.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepSummary {
    pub kinetic: f64,
    /// `Σ m x`: the centre of mass times the mass, and the gravity potential.
    pub mass_moment: [f64; 3],
    pub momentum: [f64; 3],
    pub angular_momentum: [f64; 3],
    /// A box that holds the body's nodes (f32, rounded outward).
    pub low: [f64; 3],
    pub high: [f64; 3],
}

impl StepSummary {
    /// The Newton status and iterations a summary carries (the rest of the state stays on the
    /// device), and the summary itself. `boxes`: its box (`2 dim` f32, low then high).
    pub fn of(dim: usize, summary: &[f64], boxes: &[f32]) -> (NewtonState<f64>, Self) {
        let word = summary[0] as u32;
        let state = NewtonState { status: word % 4, iterations: word / 4, ..NewtonState::default() };
        let mut s = Self { kinetic: summary[1], ..Self::default() };
        s.mass_moment[..dim].copy_from_slice(&summary[2..2 + dim]);
        s.momentum[..dim].copy_from_slice(&summary[2 + dim..2 + 2 * dim]);
        if dim == 2 {
            s.angular_momentum[2] = summary[2 + 2 * dim];
        } else {
            s.angular_momentum.copy_from_slice(&summary[2 + 2 * dim..2 + 2 * dim + 3]);
        }
        for i in 0..dim {
            s.low[i] = f64::from(boxes[i]);
            s.high[i] = f64::from(boxes[dim + i]);
        }
        (state, s)
    }
}

// SAFETY: each is `repr(C)` with all fields of one type `R`: no padding, and every bit pattern of
// f32 or f64 is valid.
macro_rules! pod {
    ($($t:ident),*) => {$(
        unsafe impl<R: Pod> Zeroable for $t<R> {}
        unsafe impl<R: Pod> Pod for $t<R> {}
    )*};
}
pod!(MaterialParams, Coefficients, DofStep, DofOut, DofState, StepMotion);

impl MaterialParams<f64> {
    pub fn of(model: &crate::material::Model) -> Self {
        let [g, k, a1, a2, a3, a4, a5, a6] = model.parameters();
        Self { g, k, a1, a2, a3, a4, a5, a6 }
    }
}

/// `struct MemberRange` of `shaders/include/batch.wgsl`: where one body of a batch lies in the
/// batch's elements, stiffness non-zeros and dofs, and which of the batch's materials it has.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct MemberRange {
    pub element_start: u32,
    pub elements: u32,
    pub nonzero_start: u32,
    pub nonzeros: u32,
    pub dof_start: u32,
    pub dofs: u32,
    pub material: u32,
    /// Where the member's viscoelastic history starts in the batch's `history` buffer (the
    /// step's `c`, then `H` of each point), or [`NO_HISTORY`].
    pub history: u32,
}

/// `MemberRange.history` of a member without a Prony series.
pub const NO_HISTORY: u32 = u32::MAX;

/// `struct Active` of `shaders/include/batch.wgsl`: a member a dispatch works on, and what it
/// asks of it ([`MODE_FORCES`] or [`MODE_TANGENT`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Active {
    pub member: u32,
    pub mode: u32,
}

/// `FORCES` of `batch.wgsl`: internal force and residual.
pub const MODE_FORCES: u32 = 1;
/// `TANGENT` of `batch.wgsl`: also the tangent and the stiffness values.
pub const MODE_TANGENT: u32 = 2;

/// `NO_MEMBER` of `batch.wgsl`: `Active::member` of a slot of a step pass's list that no member
/// holds (`step_begin` and `step_commit` skip it).
pub const NO_MEMBER: u32 = u32::MAX;

/// `struct NewtonMember` of `shaders/include/newton.wgsl`: what a member's device Newton
/// iterations need ([`crate::cpu::newton_judge`] reads the fields as the shader does).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NewtonMember<R> {
    pub inverse_start: u32,
    pub free_start: u32,
    pub free_count: u32,
    /// The most Newton iterations of the member's step (`solver.max_iterations`): the device
    /// stops it when its count reaches it (`NewtonState::iterations`, which counts on from the
    /// iterations the step took before the call). The same from step to step, so that a
    /// member's row stays put.
    pub budget: u32,
    pub residual_tolerance: R,
    pub floor: R,
    pub floor_per_travel: R,
    pub increment_tolerance: R,
    pub increment_floor: R,
    pub round_off: R,
}

/// `struct NewtonState` of `shaders/include/newton.wgsl`: where a member's device Newton
/// iterations stand.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NewtonState<R> {
    pub status: u32,
    pub iterations: u32,
    pub moved: u32,
    /// Whether the last evaluation's residual met its tolerance (`Body::balanced`).
    pub balanced: u32,
    /// Times the device made the member's `K̄⁻¹` anew within the call ([`NEWTON_REFACTOR`]); its
    /// displacement at the last of them is in the batch's `u_factored`.
    pub refactors: u32,
    pub pad: u32,
    pub residual: R,
    pub previous_residual: R,
    pub increment: R,
}

/// `struct Inversion` of `shaders/newton_invert.wgsl`: a member whose `K̄⁻¹` the device makes
/// from its `K̄` values (at `values_start` of the call's values) and its pattern (at
/// `pattern_start` of the batch's patterns: column starts, then row indices).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Inversion {
    pub member: u32,
    pub values_start: u32,
    pub pattern_start: u32,
    /// 1: `effective` holds the diagonal only, one value per free dof; the entries off it are
    /// the member's stiffness values (`ξ K`) the device holds.
    pub diagonal_only: u32,
}

/// A member's `failure` entry (its lowest inverted element, its lowest non-finite one) when
/// the element kernel found nothing wrong.
pub const NO_FAILURE: u32 = u32::MAX;

/// `NewtonState.status`: still iterating, converged, handed to the host, element failure,
/// refactorising within the call (a member of a group in contact, between `newton_contact`'s
/// `judge` and its `rebuild`).
pub const NEWTON_ITERATING: u32 = 0;
pub const NEWTON_CONVERGED: u32 = 1;
pub const NEWTON_HOST: u32 = 2;
pub const NEWTON_FAILED: u32 = 3;
pub const NEWTON_REFACTOR: u32 = 4;
/// `MAX_FREE` of `newton.wgsl`: the most free dofs a body iterating on the device may have.
pub const NEWTON_MAX_FREE: usize = 1024;

/// A prescribed dof's free index (`newton_contact`'s `free_of`: `NOT_FREE`).
pub const NOT_FREE: u32 = u32::MAX;
/// `NEWTON_WORKGROUP` of `newton.wgsl`: the invocations of a member's reductions.
pub const NEWTON_WORKGROUP: usize = 64;

/// `struct ContactGroup` of `shaders/newton_contact.wgsl`: a group in contact that iterates on
/// the device, with its members at `member_start..member_start + member_count` of the call's
/// member list (the first its leader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactGroup<R> {
    pub member_start: u32,
    pub member_count: u32,
    /// 1: its points' step lengths are those of Jacobi sweeps ([`crate::contact::uzawa::Delassus::rho`]).
    pub jacobi: u32,
    /// 1: a member whose residual contracts too slowly refactorises within the call
    /// ([`NEWTON_REFACTOR`]) instead of handing the group back.
    pub refactor: u32,
    /// `contact.tolerance`, the bound on the contact forces' change.
    pub tolerance: R,
    /// The floor of its reactions per unit step length (`ContactStep::velocity_scale`).
    pub velocity_scale: R,
}

/// `struct ContactState` of `shaders/newton_contact.wgsl`: where a device group's contact stands.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactState<R> {
    /// Uzawa sweeps in the call, and the status of the last solve
    /// ([`crate::gpu::uzawa_sweep::JUDGE_CONVERGED`] or `JUDGE_SPENT`).
    pub sweeps: u32,
    pub uzawa: u32,
    /// Times the device solved the group's problem tighter
    /// (`solver::coupling::ContactStep::tighten`).
    pub tightened: u32,
    /// Increments in a row whose solve did not converge (its sweeps spent), counted on from the
    /// host's ([`crate::policy::UZAWA_STALLS`] of them hand the group back).
    pub stalls: u32,
    /// The change of the contact forces over the last increment, relative
    /// ([`crate::solver::coupling::ContactStep::apply`]).
    pub change: R,
}

/// `struct ContactCall` of `shaders/newton_contact.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactCall<R> {
    pub problems: u32,
    pub dim: u32,
    pub pad: [u32; 2],
    pub theta_dt: R,
}

// SAFETY: four u32 (16 bytes, a multiple of either real's alignment) then fields of one type
// `R`: no padding, and every bit pattern is valid.
unsafe impl<R: Pod> Zeroable for ContactGroup<R> {}
unsafe impl<R: Pod> Pod for ContactGroup<R> {}
unsafe impl<R: Pod> Zeroable for ContactState<R> {}
unsafe impl<R: Pod> Pod for ContactState<R> {}
unsafe impl<R: Pod> Zeroable for ContactCall<R> {}
unsafe impl<R: Pod> Pod for ContactCall<R> {}
unsafe impl<R: Pod> Zeroable for NewtonMember<R> {}
unsafe impl<R: Pod> Pod for NewtonMember<R> {}
unsafe impl<R: Pod> Zeroable for NewtonState<R> {}
unsafe impl<R: Pod> Pod for NewtonState<R> {}

/// Fused multiply-adds per chain of `peak_fma` (the kernel and its CPU twin).
pub const PEAK_FMA_STEPS: usize = 256;
