//! Frictional contact by the bi-potential method (paper section 3): detection of contact
//! points between bodies and against rigid obstacles, the local law of eq. (10), and the Uzawa
//! iterations on the contact problem of one Newton iteration.
//!
//! A contact point couples a slave node with a master (a facet of another body, or an
//! obstacle). Its frame `[n, t1, t2]`, the facet weights and the gap are fixed at the start of
//! the step, so the relative velocity at the end of the step is linear in the displacements.

pub mod anderson;
pub mod broad;
pub mod configuration;
pub mod detect;
pub mod geometry;
pub mod grid;
pub mod law;
pub mod mirrored;
pub mod obstacle;
pub mod overlap;
pub mod pairs;
pub mod semismooth;
pub mod surface;
pub mod uzawa;

pub use configuration::Configuration;
pub use law::{project_on_cone, uzawa_step, ContactLaw, Coulomb, Law, Status};
pub use obstacle::{Motion, Obstacle};
pub use surface::Surface;
pub use uzawa::Sweep;

use crate::precision::Real;
use geometry::Vec3;
use pairs::BodyPairs;

/// The other side of a contact point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub enum Master {
    /// A facet of a deformable body.
    Body(u32),
    /// A face of a rigid obstacle.
    Obstacle { obstacle: u32, face: u32 },
}

/// One node of a contact point's relative velocity `v = Σ coef v_node - v_obstacle`.
#[derive(Debug, Clone, Copy, Default)]
pub struct Term {
    pub body: u32,
    pub node: u32,
    pub coef: Real,
}

/// A contact point and, after the step, its solution.
#[derive(Debug, Clone)]
pub struct ContactPoint {
    pub slave_body: u32,
    pub slave_node: u32,
    pub master: Master,
    /// The slave node (coef 1) and the master facet's nodes (coef `-weight`).
    pub terms: [Term; 5],
    pub term_count: usize,
    /// The point belongs to the second pass of a two-pass pair.
    pub second: bool,
    /// The point holds its node on a second facet of its master, in a concave corner
    /// ([`detect`]'s `concave`): its key differs from the first's.
    pub corner: bool,
    /// `[n, t1, t2]`, `n` pointing from the master towards the slave.
    pub frame: [Vec3; 3],
    /// Signed gap at the start of the step (negative: penetration).
    pub gap: Real,
    pub friction: Real,
    /// The gap at the end of the step if the end normal velocity were zero:
    /// `g + (1 - θ) dt v_n,t` (linearised; set when the step starts).
    pub predicted_gap: Real,
    /// Obstacle velocity at the start and the end of the step, and its displacement over it.
    pub obstacle_velocity: [Vec3; 2],
    pub obstacle_displacement: Vec3,
    /// Added to the end-of-step normal velocity (`solver::coupling::shift`): an open point may
    /// close its gap but not more; a penetrated one must separate by part of its penetration
    /// (drift correction).
    pub shift: Real,
    /// Uzawa step length, from the local response.
    pub rho: Real,
    /// Mean reaction over the step in the contact frame (`[r_n, r_t1, r_t2]`), force on the slave.
    pub r: Vec3,
    /// Relative velocity at the end of the step in the contact frame (unshifted).
    pub v: Vec3,
    pub status: Status,
    /// Linearised gap at the end of the step.
    pub end_gap: Real,
}

impl ContactPoint {
    pub fn terms(&self) -> &[Term] {
        &self.terms[..self.term_count]
    }

    /// Reaction on the slave in global coordinates.
    pub fn force(&self) -> Vec3 {
        self.to_global(&self.r)
    }

    /// A vector given in the contact frame, in global coordinates.
    pub fn to_global(&self, x: &Vec3) -> Vec3 {
        let f = &self.frame;
        [0, 1, 2].map(|i| x[0] * f[0][i] + x[1] * f[1][i] + x[2] * f[2][i])
    }

    /// Identity across steps, to warm-start the Uzawa iterations (a slave node sliding from one
    /// facet of a master body to the next keeps its key).
    pub fn key(&self) -> PointKey {
        (self.slave_body, self.slave_node, self.master, self.corner)
    }
}

/// A contact point's identity across steps: slave body and node, master, and whether it is the
/// node's second point on that master ([`ContactPoint::corner`]).
pub type PointKey = (u32, u32, Master, bool);

/// The reactions and rho a step's Uzawa sweeps start from, by point identity.
pub type WarmStart = std::collections::HashMap<PointKey, ([Real; 3], Real)>;

/// Contact settings of a scene (`[contact]`).
#[derive(Debug, Clone)]
pub struct Settings {
    /// Relative tolerance on the reactions (Uzawa change and complementarity residual).
    pub tolerance: Real,
    /// Uzawa iterations allowed per Newton iteration.
    pub max_iterations: usize,
    pub sweep: uzawa::Sweep,
    pub acceleration: uzawa::Acceleration,
    pub fallback: uzawa::Fallback,
}

/// Everything the engine knows about contact in a scene, built once.
#[derive(Debug, Clone)]
pub struct ContactModel {
    pub settings: Settings,
    pub surfaces: Vec<Surface>,
    pub obstacles: Vec<Obstacle>,
    /// The body pairs that can touch: friction and roles of each pass.
    pub pairs: BodyPairs,
}

/// Contact totals of one step (the `/contact` channel).
#[derive(Debug, Clone, Copy, Default, serde::Serialize, schemars::JsonSchema)]
pub struct ContactStats {
    pub active: usize,
    pub sticking: usize,
    pub sliding: usize,
    /// Deepest linearised end gap of the contact points (what the contact law saw).
    pub max_penetration: Real,
    /// Deepest node inside another body or behind an obstacle at the end of the step, measured
    /// on the configuration itself ([`overlap::overlaps`]).
    pub max_overlap: Real,
    /// The largest such depth relative to the local element size.
    pub max_overlap_ratio: Real,
    pub normal_impulse: Real,
    pub friction_dissipation_step: Real,
}

impl ContactStats {
    pub fn of(points: &[ContactPoint], dt: Real) -> Self {
        let mut s = ContactStats::default();
        for p in points {
            s.max_penetration = s.max_penetration.max(-p.end_gap);
            match p.status {
                Status::Separated => continue,
                Status::Sticking => s.sticking += 1,
                Status::Sliding => s.sliding += 1,
            }
            s.active += 1;
            s.normal_impulse += dt * p.r[0];
            s.friction_dissipation_step -= dt * (p.r[1] * p.v[1] + p.r[2] * p.v[2]);
        }
        s
    }

    /// Adds a sub-step's statistics to a step's: the largest counts and depths, the sums of
    /// impulses and dissipation (the overlaps are measured apart).
    pub fn add_substep(&mut self, sub: &ContactStats) {
        self.active = self.active.max(sub.active);
        self.sticking = self.sticking.max(sub.sticking);
        self.sliding = self.sliding.max(sub.sliding);
        self.max_penetration = self.max_penetration.max(sub.max_penetration);
        self.normal_impulse += sub.normal_impulse;
        self.friction_dissipation_step += sub.friction_dissipation_step;
    }
}
