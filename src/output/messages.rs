//! The run log's own channels as Rust types: what the run writes, and, derived from the same
//! types by schemars, the JSON schema each channel declares ([`super::schemas`]). One source of
//! truth; `tests/mcap_contract.rs` checks the two against doc/mcap.md and each other.

use crate::contact::ContactStats;
use crate::precision::Real;
use crate::solver::{Energies, PhaseTimes};
use schemars::JsonSchema;
use serde::Serialize;

/// `/run`: once, at t = 0.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Run")]
pub struct RunMessage {
    pub version: String,
    /// The commit the binary was built from, when known.
    pub git_revision: Option<String>,
    pub scene_name: String,
    /// The resolved scene after `--set`, with defaults, as TOML.
    pub scene: String,
    /// The scene file it was read from (mesh files are named relative to it).
    pub scene_file: String,
    /// `cpu` or `gpu`, after `--backend auto` has chosen.
    pub backend: String,
    /// `f64` or `f32`: the kernels' precision.
    pub precision: String,
    /// The GPU adapter, or null on the CPU.
    pub adapter: Option<String>,
    /// The step the run starts from: 0, or a restarted run's state's step.
    pub first_step: usize,
    /// The bodies logged together on `/bodies` (`output.bodies`), or null when every body has
    /// its own `/body/<name>` channel.
    pub batched_bodies: Option<BatchedBodies>,
    /// Every body, in the scene's order: what `/contacts` indexes.
    pub body_names: Vec<String>,
    /// Every obstacle, in the scene's order: what `/contacts` indexes.
    pub obstacle_names: Vec<String>,
}

/// The bodies of `/bodies`, in the order of its arrays: written once, in `/run`.
#[derive(Debug, Serialize, JsonSchema)]
pub struct BatchedBodies {
    pub names: Vec<String>,
    pub mass: Vec<Real>,
}

/// `/energy`: the initial state and each logged step.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Energy")]
pub struct EnergyMessage {
    pub t: Real,
    #[serde(flatten)]
    pub energies: Energies,
}

/// `/solver`: each logged step.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Solver")]
pub struct SolverMessage {
    pub t: Real,
    /// 1-based.
    pub step: usize,
    /// The scene's time step.
    pub dt: Real,
    /// Of the slowest group of contact-coupled bodies, summed over cut-back sub-steps.
    pub newton_iterations: usize,
    /// Uzawa sweeps, summed over Newton iterations and groups.
    pub uzawa_iterations: usize,
    /// Semi-smooth Newton iterations of the contact problems whose sweeps stalled, summed over
    /// Newton iterations and groups.
    pub contact_newton_iterations: usize,
    /// Body evaluations in the step, summed over Newton iterations (bodies that converged
    /// leave the loop).
    pub bodies_iterated: usize,
    /// Newton increments taken on the device, summed over bodies (0 on the CPU).
    pub device_iterations: usize,
    pub factorizations: usize,
    pub residual_norm: Real,
    pub cutbacks: usize,
    /// Step control: sub-steps the step was taken in, attempts rejected for a node deeper than
    /// `solver.max_overlap` or for creating more energy than `solver.max_step_energy_gain`,
    /// sub-steps kept with θ = ξ = 1 after one that created energy, and sub-steps kept beyond
    /// a bound at the smallest step allowed.
    pub substeps: usize,
    pub overlap_retries: usize,
    pub energy_retries: usize,
    pub raised_theta: usize,
    pub kept_beyond_bounds: usize,
    pub wall_s: PhaseTimes,
    /// Bytes between host and GPU in the step (0 on the CPU).
    pub bytes_moved: u64,
    /// Of `bytes_moved`, those from host to GPU.
    pub bytes_up: u64,
    /// GPU queue submits in the step, one per device pass over all bodies (0 on the CPU).
    pub device_submits: u64,
    #[schemars(extend("enum" = ["converged", "failed", "interrupted"]))]
    pub status: String,
    /// Why the run stopped, or null.
    pub message: Option<String>,
}

/// The angular momentum about the origin: the scalar z component in 2D, a vector in 3D.
#[derive(Debug, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum AngularMomentum {
    Plane(Real),
    Space([Real; 3]),
}

/// `/body/<name>`: the initial state and each logged step.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Body")]
pub struct BodyMessage {
    pub t: Real,
    pub mass: Real,
    pub center_of_mass: Vec<Real>,
    pub linear_momentum: Vec<Real>,
    pub angular_momentum: AngularMomentum,
    pub kinetic: Real,
}

/// `/bodies`: the bodies without a channel of their own (a packing's grains), one array entry
/// per body in the order of `/run.batched_bodies.names`: the initial state and each logged step.
/// One message for any number of bodies (an MCAP file holds at most 65 536 channels).
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Bodies")]
pub struct BodiesMessage {
    pub t: Real,
    pub center_of_mass: Vec<Vec<Real>>,
    pub linear_momentum: Vec<Vec<Real>>,
    pub angular_momentum: Vec<AngularMomentum>,
    pub kinetic: Vec<Real>,
}

/// `/probe/<name>`: the probe's node at the initial state and each logged step.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Probe")]
pub struct ProbeMessage {
    pub t: Real,
    pub position: Vec<Real>,
    pub displacement: Vec<Real>,
    pub velocity: Vec<Real>,
    pub von_mises: Real,
}

/// `/reaction/<set or obstacle>`: the net reaction on the bodies.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Reaction")]
pub struct ReactionMessage {
    pub t: Real,
    pub force: Vec<Real>,
}

/// `/contact`: each logged step of a scene with contact.
#[derive(Debug, Serialize, JsonSchema)]
#[schemars(title = "bifirst.Contact")]
pub struct ContactMessage {
    pub t: Real,
    #[serde(flatten)]
    pub stats: ContactStats,
}

/// `/contacts`: the contact network of a logged step (`output.contacts_every`), as arrays, for
/// the granular measures (`bifirst grains`). A contact is a pair of bodies, or a body and an
/// obstacle, pressed together: the contact points of a pair (its slave nodes, of both passes)
/// summed. Vectors are flat, `dim` numbers each.
#[derive(Debug, Default, Serialize, serde::Deserialize, JsonSchema)]
#[schemars(title = "bifirst.Contacts")]
pub struct ContactsMessage {
    pub t: Real,
    /// Each body's centre of mass, in the order of `/run.body_names`.
    pub body_center: Vec<Real>,
    /// Each body's current volume (area in 2D), from its deformed boundary.
    pub body_volume: Vec<Real>,
    /// The plane obstacles where they are at `t`: index into `/run.obstacle_names`, a point of
    /// the plane and its normal (towards the side the bodies are on).
    pub wall: Vec<u32>,
    pub wall_point: Vec<Real>,
    pub wall_normal: Vec<Real>,
    /// The contact's body (the lower index of a pair of bodies).
    pub body: Vec<u32>,
    /// The other side: a body's index, or `-1 - k` for obstacle `k`.
    pub other: Vec<i64>,
    /// Where the contact is: its points' positions weighted by their normal forces.
    pub point: Vec<Real>,
    /// Unit normal, from the other side towards `body`.
    pub normal: Vec<Real>,
    /// The force on `body` (the other side takes its opposite).
    pub force: Vec<Real>,
    /// `force · normal`: zero or positive (pressing).
    pub normal_force: Vec<Real>,
    /// The norm of the force's part across `normal`.
    pub tangential_force: Vec<Real>,
    /// Every point of the contact slides (on the Coulomb cone's surface).
    pub sliding: Vec<bool>,
    /// Contact points (slave nodes) the contact sums.
    pub points: Vec<u32>,
}
