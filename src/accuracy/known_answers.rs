//! The known-answer scenes and their error measures against the closed forms, in one place.
//! Each measure reads its parameters from the resolved scene (so `--set` changes the expected
//! answer too) and watches the run's states through [`KnownAnswer::observe`].

use super::AccuracyError;
use crate::contact::{Master, Status};
use crate::scene::{LoadedScene, MaterialSpec};
use crate::solver::{build_mesh, Simulation};

/// The scenes with a known answer, by measure name (the scene's `name` picks its measure).
pub const KNOWN_ANSWERS: [(&str, &str); 7] = [
    ("bar_impact", "contact duration against 2 L / c and rebound velocity against V (1D wave theory)"),
    ("sliding_block", "stopping distance against v0^2 / (2 mu g) and friction dissipation against m v0^2 / 2"),
    ("hertz_cylinder", "contact half-width and peak pressure against Hertz's line contact"),
    ("thick_cylinder", "radial displacement of the inner and outer surfaces of a pressurised tube against Lamé's plane-strain solution"),
    ("free_vibration_2d", "largest drift of the total energy, relative to the initial energy; the first probe's period against the Euler-Bernoulli cantilever (plane-strain modulus)"),
    ("free_vibration_3d", "largest drift of the total energy; the first probe's period against the Euler-Bernoulli cantilever"),
    ("free_flight_3d", "largest drift of the linear and angular momentum, relative to their initial values"),
];

/// One quantity of a known answer: what the run gave, the closed form's value, and the relative
/// error (for a conserved quantity, its relative drift, and `expected` = 0).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ErrorTerm {
    pub quantity: &'static str,
    pub computed: f64,
    pub expected: f64,
    pub error: f64,
}

impl ErrorTerm {
    fn relative(quantity: &'static str, computed: f64, expected: f64) -> Self {
        Self { quantity, computed, expected, error: ((computed - expected) / expected).abs() }
    }
    fn drift(quantity: &'static str, drift: f64) -> Self {
        Self { quantity, computed: drift, expected: 0.0, error: drift }
    }
}

/// A scene's error measure.
pub trait KnownAnswer {
    /// Sees the state at the start and after every finished step.
    fn observe(&mut self, sim: &Simulation);
    /// The errors of the run observed so far.
    fn errors(&self) -> Vec<ErrorTerm>;
}

/// The measure `name` (one of [`KNOWN_ANSWERS`]) for the loaded scene.
pub fn known_answer(name: &str, loaded: &LoadedScene) -> Result<Box<dyn KnownAnswer>, AccuracyError> {
    let scene = &loaded.scene;
    let missing = |what: &str| AccuracyError::Parameter { measure: name.to_string(), what: what.to_string() };
    let (body_name, body) = scene.body.iter().next().ok_or_else(|| missing("a body"))?;
    let material = scene.material.get(&body.material).ok_or_else(|| missing("the body's material"))?;
    let velocity = |axis: usize| body.initial_velocity.as_ref().and_then(|v| v.get(axis).copied()).ok_or_else(|| missing(&format!("body.{body_name}.initial_velocity")));
    let moduli = |m: &MaterialSpec| Ok::<_, AccuracyError>((m.number("G").ok_or_else(|| missing("material G"))?, m.number("K").ok_or_else(|| missing("material K"))?));
    // A closed form that is infinite, zero or NaN here (no friction, no speed) has no relative
    // error to offer: refused before anything runs.
    let expected = |quantity: &'static str, value: f64, hint: &'static str| {
        if value.is_finite() && value > 0.0 {
            Ok(value)
        } else {
            Err(AccuracyError::Expected { measure: name.to_string(), quantity, value, hint })
        }
    };
    Ok(match name {
        "bar_impact" => {
            let (g, k) = moduli(material)?;
            let length = body.mesh.size.as_ref().and_then(|s| s.first().copied()).ok_or_else(|| missing("the bar's mesh size"))?;
            let wave_speed = ((k + 4.0 * g / 3.0) / material.density).sqrt();
            let duration = expected("contact duration", 2.0 * length / wave_speed, "the bar's length, moduli and density")?;
            let speed = expected("rebound speed", velocity(0)?.abs(), "the bar's initial velocity")?;
            Box::new(BarImpact { duration, speed, touching: None, rebound: f64::NAN })
        }
        "sliding_block" => {
            let floor = scene.obstacle.values().next().ok_or_else(|| missing("a floor obstacle"))?;
            let friction = floor.friction.unwrap_or(scene.contact.friction);
            let gravity = scene.gravity.as_ref().and_then(|g| g.get(1).copied()).ok_or_else(|| missing("gravity"))?.abs();
            let speed = velocity(0)?.abs();
            expected("stopping distance", speed * speed / (2.0 * friction * gravity), "a block stops only with friction, gravity and an initial speed above zero")?;
            Box::new(SlidingBlock { speed, friction, gravity, start: None, end: None })
        }
        "hertz_cylinder" => {
            let (g, k) = moduli(material)?;
            if !scene.obstacle.contains_key("floor") {
                return Err(missing("an obstacle named `floor`"));
            }
            let contact_modulus = expected("contact modulus", plane_strain_contact_modulus(g, k), "the material's G and K")?;
            Box::new(Hertz { contact_modulus, end: None })
        }
        "free_vibration_2d" | "free_vibration_3d" => {
            let (g, k) = moduli(material)?;
            // A generated beam's `size`, or the extent of a mesh file's nodes.
            let size = match &body.mesh.size {
                Some(s) => s.clone(),
                None => {
                    let mesh = build_mesh(loaded, &format!("body.{body_name}.mesh"), &body.mesh).map_err(|_| missing("the beam's mesh size (or a mesh file that reads)"))?;
                    (0..mesh.dim()).map(|i| mesh.nodes.iter().map(|x| x[i]).fold(f64::MIN, f64::max) - mesh.nodes.iter().map(|x| x[i]).fold(f64::MAX, f64::min)).collect()
                }
            };
            if size.len() < 2 {
                return Err(missing("the beam's mesh size"));
            }
            let v0 = body.initial_velocity.as_ref().ok_or_else(|| missing(&format!("body.{body_name}.initial_velocity")))?;
            let axis = (1..v0.len()).max_by(|&i, &j| v0[i].abs().total_cmp(&v0[j].abs())).ok_or_else(|| missing("a transverse initial velocity"))?;
            if scene.probe.is_empty() {
                return Err(missing("a probe at the beam's tip"));
            }
            let (e, nu) = (9.0 * k * g / (3.0 * k + g), (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g)));
            let modulus = if name == "free_vibration_2d" { e / (1.0 - nu * nu) } else { e };
            let (length, depth) = (size[0], size[axis]);
            // Euler-Bernoulli: ω = 1.8751² / L² √(E I / (ρ A)), I / A = depth² / 12.
            let omega = 1.875_104_068_711_961_f64.powi(2) / (length * length) * depth * (modulus / (12.0 * material.density)).sqrt();
            let period = expected("bending period", 2.0 * std::f64::consts::PI / omega, "the beam's size, moduli and density")?;
            Box::new(Vibration { drift: EnergyDrift { initial: None, drift: 0.0 }, axis, period, last: None, crossings: vec![0.0] })
        }
        "thick_cylinder" => {
            let (g, k) = moduli(material)?;
            let radii = body.mesh.radii.as_ref().filter(|r| r.len() == 2).ok_or_else(|| missing("an annulus mesh (`radii`)"))?;
            let pressure = scene.load.values().find(|l| l.body == *body_name).and_then(|l| l.pressure).ok_or_else(|| missing("a pressure load on the tube"))?;
            let center = body.mesh.center.clone().unwrap_or_else(|| vec![0.0, 0.0]);
            let (a, b) = (radii[0], radii[1]);
            let (e, nu) = (9.0 * k * g / (3.0 * k + g), (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g)));
            // Lamé, plane strain: u_r(r) = (1 + ν) p a² / (E (b² - a²)) ((1 - 2ν) r + b² / r).
            let radial = |r: f64| (1.0 + nu) * pressure * a * a / (e * (b * b - a * a)) * ((1.0 - 2.0 * nu) * r + b * b / r);
            let inner = expected("inner radial displacement", radial(a).abs(), "the pressure, radii and moduli")?.copysign(pressure);
            Box::new(Tube { center: [center[0], center[1]], radii: [a, b], expected: [inner, radial(b)], computed: [f64::NAN; 2] })
        }
        "free_flight_3d" => Box::new(MomentumDrift { initial: None, linear: 0.0, angular: 0.0 }),
        _ => return Err(AccuracyError::UnknownMeasure(name.to_string())),
    })
}

/// Plane-strain contact modulus E / (1 - nu^2) of the small-strain limit of (G, K).
fn plane_strain_contact_modulus(g: f64, k: f64) -> f64 {
    let e = 9.0 * k * g / (3.0 * k + g);
    let nu = (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g));
    e / (1.0 - nu * nu)
}

/// A bar against a rigid wall: in contact for 2 L / c, then leaving at the speed it came.
struct BarImpact {
    duration: f64,
    speed: f64,
    /// First and last time with a contact point in contact, and the step.
    touching: Option<(f64, f64, f64)>,
    rebound: f64,
}

impl KnownAnswer for BarImpact {
    fn observe(&mut self, sim: &Simulation) {
        if sim.contact_points().iter().any(|p| !matches!(p.status, Status::Separated)) {
            let first = self.touching.map_or(sim.t(), |(first, _, _)| first);
            self.touching = Some((first, sim.t(), sim.dt()));
        }
        let m = sim.bodies()[0].metrics();
        self.rebound = m.linear_momentum[0] / m.mass;
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        // A step in contact counts whole: the contact spans from the start of the first such
        // step to the end of the last.
        let duration = self.touching.map_or(0.0, |(first, last, dt)| last - first + dt);
        vec![ErrorTerm::relative("contact duration", duration, self.duration), ErrorTerm::relative("rebound velocity", self.rebound, self.speed)]
    }
}

/// A block braked by Coulomb friction: it stops after v0^2 / (2 mu g), friction having taken all
/// of its kinetic energy.
struct SlidingBlock {
    speed: f64,
    friction: f64,
    gravity: f64,
    /// Centre of mass and mass at the start; centre of mass and friction dissipation at the end.
    start: Option<(f64, f64)>,
    end: Option<(f64, f64)>,
}

impl KnownAnswer for SlidingBlock {
    fn observe(&mut self, sim: &Simulation) {
        let m = sim.bodies()[0].metrics();
        self.start.get_or_insert((m.center_of_mass[0], m.mass));
        self.end = Some((m.center_of_mass[0], sim.friction_dissipation()));
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        let ((x0, mass), (x1, dissipated)) = (self.start.unwrap_or((f64::NAN, f64::NAN)), self.end.unwrap_or((f64::NAN, f64::NAN)));
        vec![ErrorTerm::relative("stopping distance", x1 - x0, self.speed * self.speed / (2.0 * self.friction * self.gravity)), ErrorTerm::relative("friction dissipation", dissipated, 0.5 * mass * self.speed * self.speed)]
    }
}

/// A cylinder pressed on the floor: the contact strip's half-width and peak pressure against
/// Hertz's, for the load the floor carries at the end.
struct Hertz {
    contact_modulus: f64,
    /// (x, normal force) of the floor's contact points at the last state.
    end: Option<Vec<(f64, f64)>>,
}

impl KnownAnswer for Hertz {
    fn observe(&mut self, sim: &Simulation) {
        let floor = sim.contact().as_ref().and_then(|c| c.obstacles.iter().position(|o| o.name == "floor")).map(|i| i as u32);
        let mut points: Vec<(f64, f64)> =
            sim.contact_points().iter().filter(|c| matches!(c.master, Master::Obstacle { obstacle, .. } if Some(obstacle) == floor)).map(|c| (sim.bodies()[c.slave_body as usize].position(c.slave_node as usize)[0], c.r[0])).collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.end = Some(points);
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        let points = self.end.as_deref().unwrap_or_default();
        let load: f64 = points.iter().map(|p| p.1).sum();
        let a = (4.0 * load / (std::f64::consts::PI * self.contact_modulus)).sqrt();
        let p0 = 2.0 * load / (std::f64::consts::PI * a);
        if points.len() < 3 || load <= 0.0 {
            return vec![ErrorTerm::relative("half-width", 0.0, a), ErrorTerm::relative("peak pressure", 0.0, p0)];
        }
        let center = points.iter().map(|p| p.0 * p.1).sum::<f64>() / load;
        // For p(x) = p0 sqrt(1 - x^2/a^2), the second moment of the load is a^2 / 4 of it.
        let half_width = 2.0 * (points.iter().map(|p| (p.0 - center).powi(2) * p.1).sum::<f64>() / load).sqrt();
        let peak = (1..points.len() - 1).max_by(|&i, &j| points[i].1.total_cmp(&points[j].1)).expect("three points or more");
        let peak_pressure = points[peak].1 / (0.5 * (points[peak + 1].0 - points[peak - 1].0));
        vec![ErrorTerm::relative("half-width", half_width, a), ErrorTerm::relative("peak pressure", peak_pressure, p0)]
    }
}

/// A free vibration: the total energy stays where it started.
struct EnergyDrift {
    initial: Option<f64>,
    drift: f64,
}

impl KnownAnswer for EnergyDrift {
    fn observe(&mut self, sim: &Simulation) {
        let e = sim.energies().total;
        let e0 = *self.initial.get_or_insert(e);
        self.drift = self.drift.max(((e - e0) / e0).abs());
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        vec![ErrorTerm::drift("energy drift", self.drift)]
    }
}

/// A cantilever vibrating freely: the energy drift, and the first bending period from the tip
/// probe's zero crossings (the tip starts at zero displacement, so t = 0 is one).
struct Vibration {
    drift: EnergyDrift,
    /// The component of the tip's displacement that vibrates.
    axis: usize,
    /// Euler-Bernoulli's first period.
    period: f64,
    /// The last sample with a non-zero displacement, `(t, u)`.
    last: Option<(f64, f64)>,
    crossings: Vec<f64>,
}

impl KnownAnswer for Vibration {
    fn observe(&mut self, sim: &Simulation) {
        self.drift.observe(sim);
        let Some(probe) = sim.probes().first() else { return };
        let u = sim.bodies()[probe.body].state().u[probe.node * sim.dim() + self.axis];
        if u == 0.0 {
            return;
        }
        if let Some((t0, u0)) = self.last.filter(|(_, u0)| u0.signum() != u.signum()) {
            self.crossings.push(t0 + (sim.t() - t0) * u0 / (u0 - u));
        }
        self.last = Some((sim.t(), u));
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        let n = self.crossings.len();
        // Successive crossings are half a period apart.
        let measured = if n >= 2 { 2.0 * (self.crossings[n - 1] - self.crossings[0]) / (n - 1) as f64 } else { f64::NAN };
        vec![ErrorTerm::drift("energy drift", self.drift.drift), ErrorTerm::relative("first bending period", measured, self.period)]
    }
}

/// A pressurised tube: the radial displacement of the nodes on the x axis at the inner and
/// outer radius, at the last state (the load held, the vibrations damped).
struct Tube {
    center: [f64; 2],
    radii: [f64; 2],
    expected: [f64; 2],
    computed: [f64; 2],
}

impl KnownAnswer for Tube {
    fn observe(&mut self, sim: &Simulation) {
        let body = &sim.bodies()[0];
        for (k, r) in self.radii.iter().enumerate() {
            let at = [self.center[0] + r, self.center[1]];
            let distance = |x: &[f64; 3]| (x[0] - at[0]).powi(2) + (x[1] - at[1]).powi(2);
            let node = (0..body.mesh().nodes.len()).min_by(|&i, &j| distance(&body.mesh().nodes[i]).total_cmp(&distance(&body.mesh().nodes[j]))).expect("a mesh has nodes");
            self.computed[k] = body.state().u[node * body.dim()];
        }
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        vec![ErrorTerm::relative("inner radial displacement", self.computed[0], self.expected[0]), ErrorTerm::relative("outer radial displacement", self.computed[1], self.expected[1])]
    }
}

/// A free flight: linear and angular momentum stay where they started.
struct MomentumDrift {
    initial: Option<([f64; 3], [f64; 3])>,
    linear: f64,
    angular: f64,
}

impl KnownAnswer for MomentumDrift {
    fn observe(&mut self, sim: &Simulation) {
        let (mut p, mut l) = ([0.0; 3], [0.0; 3]);
        for b in sim.bodies() {
            let m = b.metrics();
            (0..3).for_each(|i| {
                p[i] += m.linear_momentum[i];
                l[i] += m.angular_momentum[i];
            });
        }
        let (p0, l0) = *self.initial.get_or_insert((p, l));
        let change = |a: [f64; 3], b: [f64; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt() / (0..3).map(|i| b[i] * b[i]).sum::<f64>().sqrt();
        self.linear = self.linear.max(change(p, p0));
        self.angular = self.angular.max(change(l, l0));
    }
    fn errors(&self) -> Vec<ErrorTerm> {
        vec![ErrorTerm::drift("linear momentum drift", self.linear), ErrorTerm::drift("angular momentum drift", self.angular)]
    }
}
