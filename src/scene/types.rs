//! The scene format. Unknown keys are rejected everywhere.

pub use crate::contact::uzawa::{Acceleration, Fallback, Sweep};
pub use crate::material::Values;
use crate::material::{Model, Parameters};
use crate::mesh::ElementKind;
use crate::precision::Real;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Defaults to the file stem.
    pub name: Option<String>,
    /// Gravity acceleration, 2 or 3 components; zero when absent.
    pub gravity: Option<Vec<Real>>,
    pub time: TimeSpec,
    #[serde(default)]
    pub solver: SolverSpec,
    pub material: BTreeMap<String, MaterialSpec>,
    #[serde(default)]
    pub body: BTreeMap<String, BodySpec>,
    /// A generated random packing of grains in a rigid box (adds bodies and obstacles).
    pub packing: Option<PackingSpec>,
    #[serde(default)]
    pub boundary: BTreeMap<String, BoundarySpec>,
    #[serde(default)]
    pub load: BTreeMap<String, LoadSpec>,
    #[serde(default)]
    pub probe: BTreeMap<String, ProbeSpec>,
    #[serde(default)]
    pub contact: ContactSpec,
    #[serde(default)]
    pub obstacle: BTreeMap<String, ObstacleSpec>,
    #[serde(default)]
    pub output: OutputSpec,
    #[serde(default)]
    pub limits: LimitsSpec,
}

/// `[limits]`: the most a scene may ask for before `check` and `run` reject it, so that a typo
/// (`divisions = [20000, 2000, 2000]`, `dt = 1e-20`) is an error, not hours of work or an
/// allocation that kills the machine. A run that really needs more raises them, e.g.
/// `--set limits.max_elements=100000000`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsSpec {
    /// Elements over all generated meshes.
    pub max_elements: u64,
    /// Time steps to `time.end`.
    pub max_steps: u64,
}

impl Default for LimitsSpec {
    fn default() -> Self {
        Self { max_elements: 5_000_000, max_steps: 100_000_000 }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSpec {
    pub end: Real,
    pub dt: Real,
    /// Weight of the end-of-step forces, eq. (13).
    #[serde(default = "half")]
    pub xi: Real,
    /// Weight of the end-of-step velocity, eq. (15).
    #[serde(default = "half")]
    pub theta: Real,
}

fn half() -> Real {
    0.5
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverSpec {
    /// Newton stops when the residual norm is below this fraction of the step's force scale...
    pub residual_tolerance: Real,
    /// ...and the last increment is below this fraction of the step's displacement change.
    pub increment_tolerance: Real,
    pub max_iterations: usize,
    /// How many times a failed step may be halved (recursively) before the run stops.
    pub max_cutbacks: usize,
    /// Keep a body's factorisation across Newton iterations and steps while it reduces the
    /// residual at least tenfold per iteration; `false` refactorises every iteration.
    pub reuse_factorization: bool,
    /// Fill-reducing ordering of each body's factorisation.
    pub ordering: OrderingChoice,
    /// Step control: a step that leaves a node deeper than this share of its element inside
    /// another body (or behind an obstacle) is retried smaller (`inf`: never).
    pub max_overlap: Real,
    /// Step control: a step that creates more than this share of the energy scale is retried
    /// with θ = ξ = 1, then smaller (`inf`: never).
    pub max_step_energy_gain: Real,
    /// A run that ends having created more than this share of the energy scale (total energy
    /// above what it started with, plus external work, less friction) exits non-zero
    /// (`inf`: never).
    pub max_energy_gain: Real,
}

/// `solver.ordering`: `auto` tries nested dissection on bodies of 3000 free dofs or more and
/// keeps whichever ordering gives the smaller factor; the others force one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OrderingChoice {
    #[default]
    Auto,
    Amd,
    NestedDissection,
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self { residual_tolerance: 1e-9, increment_tolerance: 1e-9, max_iterations: 25, max_cutbacks: 6, reuse_factorization: true, ordering: OrderingChoice::Auto, max_overlap: 0.01, max_step_energy_gain: 1e-4, max_energy_gain: 0.01 }
    }
}

/// A material model's name (`model = "..."`): one of the registry's ([`Model::ENTRIES`]).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(transparent)]
pub struct ModelName(pub String);

/// Checked against the registry as it is read, so that a misspelt model is named with the
/// models there are.
impl<'de> Deserialize<'de> for ModelName {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Name;
        impl<'de> serde::de::Visitor<'de> for Name {
            type Value = ModelName;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "one of {}", model_names())
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ModelName, E> {
                match Model::entry(v) {
                    Some(e) => Ok(ModelName(e.name.to_string())),
                    None => Err(E::custom(format!("unknown model `{v}`, expected one of {}", model_names()))),
                }
            }
        }
        deserializer.deserialize_str(Name)
    }
}

fn model_names() -> String {
    Model::ENTRIES.iter().map(|e| format!("`{}`", e.name)).collect::<Vec<_>>().join(", ")
}

/// A material: its model, density and the model's parameters (each model takes exactly its
/// own, `material::Law::PARAMETERS`; the checks name any other).
#[derive(Debug, Clone, Serialize)]
pub struct MaterialSpec {
    pub model: ModelName,
    pub density: Real,
    /// The model's parameters by name (`G`, `K`, Ogden's `mu` list, ...).
    #[serde(flatten)]
    pub parameters: Parameters,
    /// A Prony series on the isochoric stress, on any model (`material::viscous`): the model's
    /// parameters are then its instantaneous response.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub viscoelastic: Option<Vec<PronySpec>>,
}

impl MaterialSpec {
    /// The number the scene gave parameter `name`, if it gave one.
    pub fn number(&self, name: &str) -> Option<Real> {
        self.parameters.get(name).and_then(Values::one)
    }
}

/// By hand: every key but `model`, `density` and `viscoelastic` is a parameter of the model,
/// read where it stands so that an error names its key and line (a derived `flatten` loses both).
impl<'de> Deserialize<'de> for MaterialSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Spec;
        impl<'de> serde::de::Visitor<'de> for Spec {
            type Value = MaterialSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a material table: `model`, `density` and the model's parameters")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<MaterialSpec, A::Error> {
                let (mut model, mut density, mut viscoelastic, mut parameters) = (None, None, None, Parameters::new());
                while let Some(key) = map.next_key::<String>()? {
                    match key.as_str() {
                        "model" => model = Some(map.next_value()?),
                        "density" => density = Some(map.next_value()?),
                        "viscoelastic" => viscoelastic = Some(map.next_value()?),
                        _ => {
                            let value = map.next_value()?;
                            parameters.insert(key, value);
                        }
                    }
                }
                let model = model.ok_or_else(|| serde::de::Error::missing_field("model"))?;
                let density = density.ok_or_else(|| serde::de::Error::missing_field("density"))?;
                Ok(MaterialSpec { model, density, parameters, viscoelastic })
            }
        }
        deserializer.deserialize_map(Spec)
    }
}

/// One term of a Prony series: relative modulus `g` (the share of the isochoric stress that
/// relaxes with this term) and relaxation time `tau`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PronySpec {
    pub g: Real,
    pub tau: Real,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub material: String,
    pub mesh: MeshSpec,
    /// Translational velocity at t = 0.
    pub initial_velocity: Option<Vec<Real>>,
    /// Rotation about the centre of mass at t = 0: a number (2D) or a vector (3D).
    pub angular_velocity: Option<AngularVelocity>,
    /// How the elements take the volume change; `auto` (the default) is F-bar (simplices as
    /// patches) when the material's K/G exceeds `element::FBAR_ABOVE_K_OVER_G`.
    pub formulation: Option<FormulationChoice>,
}

/// A body's element formulation as the scene names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FormulationChoice {
    #[default]
    Auto,
    Displacement,
    Fbar,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(untagged)]
pub enum AngularVelocity {
    Planar(Real),
    Spatial(Vec<Real>),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Generator {
    Rectangle,
    Disk,
    Annulus,
    Polygon,
    Box,
    Ball,
}

/// Either a generator with its parameters or a Gmsh `.msh` 4.1 file (relative to the scene).
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    pub generator: Option<Generator>,
    pub file: Option<PathBuf>,
    pub element: Option<ElementKind>,
    /// Rectangle and box: lower corner.
    pub origin: Option<Vec<Real>>,
    /// Rectangle and box: edge lengths.
    pub size: Option<Vec<Real>>,
    /// Rectangle and box: cells per direction; disk and ball: one number, cells per radius.
    pub divisions: Option<Vec<usize>>,
    /// Disk and ball: centre and radius.
    pub center: Option<Vec<Real>>,
    pub radius: Option<Real>,
    /// Annulus: inner and outer radius.
    pub radii: Option<Vec<Real>>,
    /// Annulus: the sector's opening in degrees, from the x axis counter-clockwise (default 360).
    pub angle: Option<Real>,
    /// Polygon: the vertices of a convex outline, `[[x, y], ...]`.
    pub points: Option<Vec<Vec<Real>>>,
    /// Mesh file: only the elements of this physical group (one file, several bodies).
    pub group: Option<String>,
    /// 3D generators: a rotation vector (axis times angle, radians) turning the generated mesh
    /// about its centre (the mean of its nodes).
    pub rotation: Option<Vec<Real>>,
}

/// The share of polygons (2D) or boxes (3D) of a packing that does not give it.
pub const DEFAULT_SHARE: Real = 0.5;

/// A random packing of `count` grains in a rigid box whose left wall moves right: disks and
/// convex polygons (Tri3) in 2D, balls and boxes (Tet4 or Hex8) in 3D. Generated at load time
/// into bodies `grain_0001`... and the obstacles `left`, `right`, `bottom`, `top` (and `back`,
/// `front` in 3D); the same seed gives the same packing.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PackingSpec {
    pub count: usize,
    pub seed: u64,
    /// The grains' material (a name from `[material]`).
    pub material: String,
    /// Range of the grains' radii (circumradius of a polygon), `[min, max]`.
    pub radius: Vec<Real>,
    /// 2 (disks and polygons) or 3 (balls and boxes).
    pub dimension: usize,
    /// Share of the grains that are polygons (3 to 6 vertices), in 2D; the rest are disks
    /// (default [`DEFAULT_SHARE`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub polygons: Option<Real>,
    /// Share of the grains that are boxes (random edge ratios, random orientation), in 3D; the
    /// rest are balls (default [`DEFAULT_SHARE`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub polyhedra: Option<Real>,
    /// The 3D grains' element: `tet4` (default) or `hex8`. 2D grains are Tri3.
    pub element: Option<ElementKind>,
    /// Cells per radius of each grain's mesh.
    pub divisions: usize,
    /// Grains per row of the initial lattice (and per layer, in 3D); 0: about as many rows as
    /// columns (and layers).
    pub columns: usize,
    /// Clearance between neighbouring grains' lattice cells, relative to the largest diameter.
    pub gap: Real,
    /// Speed of the left wall towards +x.
    pub wall_velocity: Real,
    /// When the left wall stops (a compression, then a hold); it never stops when absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wall_until: Option<Real>,
    /// Friction of the top and bottom walls (the side walls are frictionless).
    pub wall_friction: Real,
}

impl Default for PackingSpec {
    fn default() -> Self {
        Self { count: 100, seed: 1, material: String::new(), radius: vec![0.4, 0.5], dimension: 2, polygons: None, polyhedra: None, element: None, divisions: 2, columns: 0, gap: 0.05, wall_velocity: 0.0, wall_until: None, wall_friction: 0.0 }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

/// A node set whose components are fixed (zero velocity) or driven at a constant velocity.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    pub body: String,
    /// A named node set of the body's mesh.
    pub nodes: String,
    /// Prescribed components; all when absent.
    pub components: Option<Vec<Axis>>,
    /// Prescribed velocity (all components, as many as the dimension); zero when absent.
    pub velocity: Option<Vec<Real>>,
    /// The nodes move at `velocity` until this time, then hold where they are (a stretch held:
    /// relaxation tests); the whole run when absent.
    pub until: Option<Real>,
}

/// A dead surface load on the boundary facets of a node set (the facets whose nodes all belong
/// to it), as nodal forces: a traction (force per unit reference area; per unit length and
/// thickness in 2D) or a pressure (along the inward reference normal).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    pub body: String,
    /// A named node set of the body's mesh.
    pub nodes: String,
    pub traction: Option<Vec<Real>>,
    pub pressure: Option<Real>,
    /// The load grows linearly from zero at t = 0 to full at t = `ramp`, then holds; 0 (the
    /// default): full from the start.
    #[serde(default)]
    pub ramp: Real,
}

/// A probe follows the mesh node nearest to `point` (reference configuration).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    pub body: String,
    pub point: Vec<Real>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputSpec {
    /// MCAP file, relative to the working directory; `<name>.mcap` when absent.
    pub mcap: Option<PathBuf>,
    /// Write the per-step channels every this many steps.
    pub every: usize,
    /// Write the Foxglove 3D view (`/scene`) every this many steps; 0: never. When absent,
    /// about 100 frames per run.
    pub scene_every: Option<usize>,
    /// Directory for ParaView files (VTU frames and `.pvd` series); `--vtu` overrides it.
    pub vtu: Option<PathBuf>,
    /// Write a VTU frame every this many steps. When absent, about 100 frames per run.
    pub vtu_every: Option<usize>,
    /// Write the full state (`/state`, what `run --restart` continues from) every this many
    /// steps; 0: only at the last finished step, which is always written.
    pub state_every: usize,
    /// Write the contact network (`/contacts`) every this many steps, and at the start and the
    /// last step; 0: never. When absent, the `/scene` cadence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contacts_every: Option<usize>,
    /// Where the bodies' momenta are logged: a `/body/<name>` channel each, or one `/bodies`
    /// message per step for all of them.
    pub bodies: BodyLog,
}

impl Default for OutputSpec {
    fn default() -> Self {
        Self { mcap: None, every: 1, scene_every: None, vtu: None, vtu_every: None, state_every: 0, contacts_every: None, bodies: BodyLog::Auto }
    }
}

/// `output.bodies`: how the bodies' channels are laid out in the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BodyLog {
    /// A packing's grains on `/bodies`, the scene's own bodies on `/body/<name>` (all on
    /// `/bodies` when the scene declares more than [`BodyLog::AUTO_CHANNELS`]).
    Auto,
    /// A `/body/<name>` channel for every body.
    Channels,
    /// Every body on `/bodies`.
    Batched,
}

impl BodyLog {
    /// The most bodies `auto` gives channels of their own.
    pub const AUTO_CHANNELS: usize = 1000;
    /// The most bodies `channels` accepts: an MCAP file holds at most 65 536 channels, and the
    /// run's other channels need some.
    pub const MAX_CHANNELS: usize = 60_000;

    /// Which bodies go on `/bodies`, given whether each one is a packing's grain.
    pub fn batched(self, grain: &[bool]) -> Vec<bool> {
        match self {
            BodyLog::Channels => vec![false; grain.len()],
            BodyLog::Batched => vec![true; grain.len()],
            BodyLog::Auto => {
                let declared = grain.iter().filter(|g| !**g).count();
                grain.iter().map(|&g| g || declared > Self::AUTO_CHANNELS).collect()
            }
        }
    }
}

impl OutputSpec {
    /// Steps between frames for a cadence that may be absent (about 100 frames per run).
    pub fn frame_interval(cadence: Option<usize>, total_steps: usize) -> usize {
        cadence.unwrap_or(total_steps.div_ceil(100).max(1))
    }
}

/// Contact between bodies and the settings of the contact solver (`[contact]`).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ContactSpec {
    /// Friction coefficient of every pair and obstacle that does not set its own.
    pub friction: Real,
    /// Treat each body pair from both sides, so that neither body's nodes can pass through the
    /// other's facets; otherwise the body with the finer mesh is the slave.
    pub two_pass: bool,
    /// Every pair of bodies may touch; when false only the pairs listed in `pair`.
    pub all_pairs: bool,
    /// Relative tolerance on the reactions: Uzawa change and complementarity residual.
    pub tolerance: Real,
    /// Uzawa iterations allowed per Newton iteration.
    pub max_iterations: usize,
    /// Order of the Uzawa updates: `gauss_seidel` (robust) or `jacobi` (parallel, as on the GPU).
    pub sweep: Sweep,
    /// Between Gauss-Seidel sweeps: `anderson` (mixing of the last sweeps, safeguarded) or
    /// `none` (plain sweeps, as on the device).
    pub acceleration: Acceleration,
    /// When the Gauss-Seidel sweeps stall: `none` (sweeps to `max_iterations`) or `newton` (a
    /// semi-smooth Newton solve of the whole problem).
    pub fallback: Fallback,
    /// Body pairs with their own friction coefficient or slave (or, with `all_pairs = false`,
    /// the only pairs in contact).
    pub pair: BTreeMap<String, PairSpec>,
    /// Bodies that overlap at t = 0 (a node inside another body or behind an obstacle) are an
    /// error; with this, they are pushed apart by rigid translations before the first step.
    pub resolve_initial_overlap: bool,
}

impl Default for ContactSpec {
    fn default() -> Self {
        Self { friction: 0.0, two_pass: false, all_pairs: true, tolerance: 1e-8, max_iterations: 5000, sweep: Sweep::GaussSeidel, acceleration: Acceleration::Anderson, fallback: Fallback::None, pair: BTreeMap::new(), resolve_initial_overlap: false }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PairSpec {
    /// The two bodies.
    pub bodies: Vec<String>,
    pub friction: Option<Real>,
    /// The body whose nodes are checked against the other's facets in a single pass (default:
    /// the finer mesh, then the one with more boundary nodes, then the first in the scene).
    pub slave: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleShape {
    /// Half-plane (2D) or half-space (3D): `point`, `normal` towards the bodies.
    Plane,
    /// Axis-aligned box `min`..`max`: solid, or a container with `inside = true`.
    Box,
    /// Convex polygon (2D) through `points`, bodies outside.
    Polygon,
    /// Open polyline (2D) through `points`, bodies on its left.
    Polyline,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    Step,
    Linear,
}

/// A rigid obstacle. Its reaction on the bodies goes to `/reaction/<name>`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    pub shape: ObstacleShape,
    pub point: Option<Vec<Real>>,
    pub normal: Option<Vec<Real>>,
    pub min: Option<Vec<Real>>,
    pub max: Option<Vec<Real>>,
    /// Box only: the bodies are inside (a container) rather than outside (a solid).
    pub inside: Option<bool>,
    pub points: Option<Vec<Vec<Real>>>,
    /// Friction coefficient against this obstacle; `contact.friction` when absent.
    pub friction: Option<Real>,
    /// Constant velocity.
    pub velocity: Option<Vec<Real>>,
    /// Velocity history, rows `[t, vx, vy(, vz)]` with increasing `t`.
    pub motion: Option<Vec<Vec<Real>>>,
    /// How `motion` is read between rows; `linear` when absent.
    pub interpolation: Option<Interpolation>,
    /// The bodies it touches; all when absent.
    pub bodies: Option<Vec<String>>,
}
