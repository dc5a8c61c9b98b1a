//! Running a scene end to end: set-up, time steps, the MCAP run log (with the Foxglove view),
//! VTU frames, and a summary. However the run ends (finished, a step failure, a non-finite
//! state, a panic, an interrupt), the log is closed with everything up to the last finished step.

use crate::backend::{Backend, BackendError, BackendRequest};
use crate::element::CellFields;
use crate::output::foxglove::{self, Level, View};
use crate::output::messages::{AngularMomentum, BatchedBodies, BodiesMessage, BodyMessage, ContactMessage, EnergyMessage, ProbeMessage, ReactionMessage, RunMessage, SolverMessage};
use crate::output::plot::{contour_png, PlotError};
pub use crate::output::run_summary::{energy_gain, RunSummary, ENERGY_GAIN_TOLERANCE};
use crate::output::{encode, schemas, OutputError, RunLog, VtuSeries};
use crate::precision::Real;
use crate::scene::{LoadedScene, OutputSpec, SceneError};
use crate::solver::{build_simulation, Energies, PhaseTimes, RunFailure, SavedState, Simulation, StepFailure, StepReport};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    // Transparent: `{0}` with a source would print the message twice in `anyhow`'s `{:#}`.
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Backend(#[from] BackendError),
    #[error(transparent)]
    Plot(#[from] PlotError),
    #[error("cannot restart from that state: {0}")]
    Restore(#[from] crate::solver::RestoreError),
    /// The run stopped early; the log holds everything up to the last finished step.
    #[error("the run stopped: {reason}. The log `{}` holds everything up to t = {:.6e}.", .summary.output.display(), .summary.t_end)]
    Stopped { reason: Stop, summary: Box<RunSummary> },
}

/// Why a run stopped before its end time.
#[derive(Debug, thiserror::Error)]
pub enum Stop {
    #[error("{0}")]
    Failed(Box<RunFailure>),
    #[error("the state is not finite after step {step} (t = {t:.6e})")]
    NotFinite { step: usize, t: Real },
    #[error("panic: {0}")]
    Panicked(String),
    #[error("interrupted")]
    Interrupted,
    /// The states the device kept could not be read back for the outputs.
    #[error("the device's state could not be read back: {0}")]
    Device(String),
}

impl Stop {
    /// The `/solver` status and the `/run` summary status of a run that stopped this way.
    pub fn status(&self) -> &'static str {
        match self {
            Stop::Interrupted => "interrupted",
            _ => "failed",
        }
    }
}

/// What a run writes besides its MCAP log, and how it can be stopped.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Directory for VTU frames; overrides the scene's `output.vtu`.
    pub vtu: Option<PathBuf>,
    /// When set (by a signal handler), the run stops within a Newton iteration, at the last
    /// finished step.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Where the kernels run (default: the CPU).
    pub backend: BackendRequest,
    /// A PNG of the von Mises contours at the end of the run (2D scenes).
    pub contour: Option<PathBuf>,
    /// Continue from this state (a `/state` message of an earlier run) instead of t = 0.
    pub restart: Option<SavedState>,
}

/// Told about each step as it finishes (progress display).
pub trait Monitor {
    /// Where the kernels run, once the backend is chosen.
    fn backend(&mut self, _description: &str) {}
    fn started(&mut self, _total_steps: usize) {}
    fn step(&mut self, _report: &StepReport, _total_steps: usize) {}
    /// The state at the start and after every finished step (the known-answer measures of
    /// `bifirst accuracy` read it).
    fn state(&mut self, _sim: &Simulation) {}
    /// Whether [`Monitor::state`] reads the bodies' states (they are then brought back from a
    /// device that keeps them every step).
    fn reads_states(&self) -> bool {
        false
    }
    fn warning(&mut self, _message: &str) {}
}

/// A monitor that ignores everything.
pub struct Silent;
impl Monitor for Silent {}

/// Commit the build came from, when it was built from a git checkout (see `src/build.rs`).
pub const GIT_REVISION: Option<&str> = option_env!("BIFIRST_GIT_REVISION");

/// Per body of `sim`: logged on `/bodies` rather than a channel of its own (`output.bodies`).
fn batched_bodies(loaded: &LoadedScene, sim: &Simulation) -> Vec<bool> {
    let grains: std::collections::HashSet<String> = loaded.scene.packing.iter().flat_map(|p| (0..p.count).map(|i| crate::scene::grain_name(i, p.count))).collect();
    let grain: Vec<bool> = sim.bodies().iter().map(|b| grains.contains(b.name())).collect();
    loaded.scene.output.bodies.batched(&grain)
}

struct Logger {
    log: RunLog,
    dim: usize,
    view: Option<View>,
    scene_every: usize,
    vtu: Option<VtuSeries>,
    vtu_every: usize,
    /// Last step whose state channels / frames are in the outputs.
    state_step: Option<usize>,
    frame_step: Option<usize>,
    /// `/state` every this many steps (0: only the last finished step), and the step last saved.
    saved_every: usize,
    saved_step: Option<usize>,
    /// Per body: on `/bodies` rather than a `/body/<name>` channel of its own.
    batched: Vec<bool>,
    /// `/contacts` every this many steps (0: never), and the step last written.
    contacts_every: usize,
    contacts_step: Option<usize>,
}

impl Logger {
    fn new(path: &Path, loaded: &LoadedScene, sim: &Simulation, options: &RunOptions, backend: &Backend) -> Result<Self, OutputError> {
        let mut log = RunLog::create(path)?;
        let dim = sim.dim();
        let output = &loaded.scene.output;
        let total = sim.step_count();
        let scene_every = OutputSpec::frame_interval(output.scene_every, total);
        let vtu_dir = options.vtu.clone().or_else(|| output.vtu.clone());
        let vtu = vtu_dir.map(|dir| VtuSeries::create(&dir, sim)).transpose()?;
        log.add_channel("/run", "bifirst.Run", &schemas::run())?;
        log.add_channel("/energy", "bifirst.Energy", &schemas::energy())?;
        log.add_channel("/solver", "bifirst.Solver", &schemas::solver())?;
        log.add_channel("/summary", "bifirst.Summary", &schemas::summary())?;
        log.add_channel("/log", "foxglove.Log", &serde_json::from_str(foxglove::LOG_SCHEMA).expect("bundled schema is JSON"))?;
        if scene_every > 0 {
            log.add_channel("/scene", "foxglove.SceneUpdate", &serde_json::from_str(foxglove::SCENE_UPDATE_SCHEMA).expect("bundled schema is JSON"))?;
        }
        let batched = batched_bodies(loaded, sim);
        // One schema for thousands of bodies (it is derived, not a constant).
        let body_schema = schemas::body(dim);
        for (b, _) in sim.bodies().iter().zip(&batched).filter(|(_, batched)| !**batched) {
            log.add_channel(&format!("/body/{}", b.name()), "bifirst.Body", &body_schema)?;
        }
        if batched.contains(&true) {
            log.add_channel("/bodies", "bifirst.Bodies", &schemas::bodies(dim))?;
        }
        for p in sim.probes() {
            log.add_channel(&format!("/probe/{}", p.name), "bifirst.Probe", &schemas::probe(dim))?;
        }
        let reaction_schema = schemas::reaction(dim);
        for s in sim.sets() {
            log.add_channel(&format!("/reaction/{}", s.name), "bifirst.Reaction", &reaction_schema)?;
        }
        if let Some(c) = &sim.contact() {
            log.add_channel("/contact", "bifirst.Contact", &schemas::contact())?;
            for o in &c.obstacles {
                log.add_channel(&format!("/reaction/{}", o.name), "bifirst.Reaction", &reaction_schema)?;
            }
        }
        let run = RunMessage {
            version: env!("CARGO_PKG_VERSION").to_string(),
            git_revision: GIT_REVISION.map(String::from),
            scene_name: loaded.name.clone(),
            scene: loaded.resolved_toml.clone(),
            scene_file: loaded.path.display().to_string(),
            backend: backend.name().to_string(),
            precision: backend.precision().to_string(),
            adapter: backend.adapter(),
            first_step: sim.first_step().1,
            batched_bodies: batched.contains(&true).then(|| {
                let (names, mass) = sim.bodies().iter().zip(&batched).filter(|(_, batched)| **batched).map(|(b, _)| (b.name().to_string(), b.metrics().mass)).unzip();
                BatchedBodies { names, mass }
            }),
            body_names: sim.bodies().iter().map(|b| b.name().to_string()).collect(),
            obstacle_names: sim.contact().as_ref().map_or(Vec::new(), |c| c.obstacles.iter().map(|o| o.name.clone()).collect()),
        };
        log.write("/run", sim.t(), &run)?;
        log.attach("scene.toml", "application/toml", loaded.resolved_toml.as_bytes())?;
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let meta: BTreeMap<String, String> = [
            ("version", env!("CARGO_PKG_VERSION").to_string()),
            ("git_revision", GIT_REVISION.unwrap_or("unknown").to_string()),
            ("scene_name", loaded.name.clone()),
            ("scene_file", loaded.path.display().to_string()),
            ("scene", loaded.resolved_toml.clone()),
            ("backend", backend.name().to_string()),
            ("adapter", backend.adapter().unwrap_or_else(|| "none (CPU backend)".to_string())),
            ("precision", backend.precision().to_string()),
            ("cores", cores.to_string()),
            ("threads", rayon::current_num_threads().to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        log.metadata("bifirst.run", meta)?;
        let view = (scene_every > 0).then(|| View::new(sim));
        let vtu_every = OutputSpec::frame_interval(output.vtu_every, total);
        log.add_channel("/state", "bifirst.SavedState", &schemas::saved_state())?;
        let contacts_every = if sim.contact().is_some() { output.contacts_every.unwrap_or(scene_every) } else { 0 };
        if contacts_every > 0 {
            log.add_channel("/contacts", "bifirst.Contacts", &schemas::contacts())?;
        }
        Ok(Self { log, dim, view, scene_every, vtu, vtu_every, state_step: None, frame_step: None, saved_every: output.state_every, saved_step: None, batched, contacts_every, contacts_step: None })
    }

    /// State channels: energy (`energies`, the simulation's at this time), bodies, probes,
    /// reactions at the current time.
    fn state(&mut self, sim: &Simulation, energies: Energies) -> Result<(), OutputError> {
        if self.state_step == Some(sim.step()) {
            return Ok(());
        }
        self.state_step = Some(sim.step());
        let (t, dim) = (sim.t(), self.dim);
        self.log.write("/energy", t, &EnergyMessage { t, energies })?;
        let angular = |l: [Real; 3]| if dim == 2 { AngularMomentum::Plane(l[2]) } else { AngularMomentum::Space(l) };
        let metrics: Vec<_> = sim.bodies().par_iter().map(|b| b.metrics()).collect();
        let own: Vec<(usize, Vec<u8>)> = (0..metrics.len())
            .into_par_iter()
            .filter(|&b| !self.batched[b])
            .map(|b| {
                let m = &metrics[b];
                (b, encode(&BodyMessage { t, mass: m.mass, center_of_mass: m.center_of_mass[..dim].to_vec(), linear_momentum: m.linear_momentum[..dim].to_vec(), angular_momentum: angular(m.angular_momentum), kinetic: m.kinetic }))
            })
            .collect();
        for (b, data) in own {
            self.log.write_encoded(&format!("/body/{}", sim.bodies()[b].name()), t, &data)?;
        }
        if self.batched.contains(&true) {
            let batch: Vec<_> = metrics.iter().zip(&self.batched).filter(|(_, batched)| **batched).map(|(m, _)| m).collect();
            let message = BodiesMessage {
                t,
                center_of_mass: batch.iter().map(|m| m.center_of_mass[..dim].to_vec()).collect(),
                linear_momentum: batch.iter().map(|m| m.linear_momentum[..dim].to_vec()).collect(),
                angular_momentum: batch.iter().map(|m| angular(m.angular_momentum)).collect(),
                kinetic: batch.iter().map(|m| m.kinetic).collect(),
            };
            self.log.write("/bodies", t, &message)?;
        }
        for p in sim.probes() {
            let b = &sim.bodies()[p.body];
            let n = p.node;
            let msg = ProbeMessage { t, position: b.position(n)[..dim].to_vec(), displacement: b.state().u[n * dim..(n + 1) * dim].to_vec(), velocity: b.state().v[n * dim..(n + 1) * dim].to_vec(), von_mises: b.von_mises(&p.elements) };
            self.log.write(&format!("/probe/{}", p.name), t, &msg)?;
        }
        for (s, r) in sim.sets().iter().zip(sim.reactions()) {
            self.log.write(&format!("/reaction/{}", s.name), t, &ReactionMessage { t, force: r[..dim].to_vec() })?;
        }
        if let Some(c) = &sim.contact() {
            for (o, r) in c.obstacles.iter().zip(sim.obstacle_reactions()) {
                self.log.write(&format!("/reaction/{}", o.name), t, &ReactionMessage { t, force: r[..dim].to_vec() })?;
            }
        }
        Ok(())
    }

    /// Whether this step's outputs read the bodies' states (`last`: the run's last step): probes,
    /// frames, `/contacts` and `/state` when due. A device that keeps the states then sends
    /// them back first ([`Simulation::sync_states`]).
    fn reads_states(&self, sim: &Simulation, logged: bool, last: bool) -> bool {
        let due = |every: usize| every > 0 && (last || sim.step().is_multiple_of(every));
        let frames = (self.view.is_some() && due(self.scene_every)) || (self.vtu.is_some() && due(self.vtu_every));
        let saved = last || (self.saved_every > 0 && sim.step().is_multiple_of(self.saved_every));
        (logged && !sim.probes().is_empty()) || frames || due(self.contacts_every) || saved
    }

    /// `/state`, the full state a run can continue from: at the scene's cadence, and (`last`)
    /// at the last finished step of the run, however it ends.
    fn saved(&mut self, sim: &Simulation, last: bool) -> Result<(), OutputError> {
        if !self.saves(sim, last) {
            return Ok(());
        }
        self.saved_step = Some(sim.step());
        self.log.write("/state", sim.t(), &sim.saved_state())
    }

    /// Whether [`Logger::saved`] writes the state now.
    fn saves(&self, sim: &Simulation, last: bool) -> bool {
        // With a cadence, the initial state too (a restarted run's is in the log it came from).
        let due = self.saved_every > 0 && sim.step().is_multiple_of(self.saved_every) && (sim.step() > sim.first_step().1 || sim.step() == 0);
        self.saved_step != Some(sim.step()) && (last || due)
    }

    /// The 3D view and the VTU frame when their cadence says so, or when `last`.
    fn frames(&mut self, sim: &Simulation, last: bool) -> Result<(), OutputError> {
        if self.frame_step == Some(sim.step()) {
            return Ok(());
        }
        let due = |every: usize| every > 0 && (last || sim.step().is_multiple_of(every));
        let scene = self.view.is_some() && due(self.scene_every);
        let vtu = self.vtu.is_some() && due(self.vtu_every);
        if !scene && !vtu {
            return Ok(());
        }
        self.frame_step = Some(sim.step());
        let fields: Vec<Vec<CellFields>> = sim.bodies().par_iter().map(|b| b.cell_fields()).collect();
        if let (true, Some(view)) = (scene, &mut self.view) {
            let update = view.scene_update(sim, &fields);
            self.log.write_encoded("/scene", sim.t(), &update)?;
        }
        if let (true, Some(series)) = (vtu, &mut self.vtu) {
            series.write_frame(sim, &fields)?;
        }
        Ok(())
    }

    /// The contact network (`/contacts`) when its cadence says so, or when `last`.
    fn contacts(&mut self, sim: &Simulation, last: bool) -> Result<(), OutputError> {
        let due = self.contacts_every > 0 && (last || sim.step().is_multiple_of(self.contacts_every));
        if !due || self.contacts_step == Some(sim.step()) {
            return Ok(());
        }
        self.contacts_step = Some(sim.step());
        self.log.write("/contacts", sim.t(), &crate::output::contacts::network(sim))
    }

    /// The `/contact` channel of a step (only in scenes with contact).
    fn contact(&mut self, sim: &Simulation, r: &StepReport) -> Result<(), OutputError> {
        if sim.contact().is_none() {
            return Ok(());
        }
        self.log.write("/contact", sim.t(), &ContactMessage { t: sim.t(), stats: r.contact })
    }

    fn solver(&mut self, r: &StepReport, t: Real, status: &str, message: Option<String>) -> Result<(), OutputError> {
        let msg = SolverMessage {
            t,
            step: r.step,
            dt: r.dt,
            newton_iterations: r.newton_iterations,
            uzawa_iterations: r.uzawa_iterations,
            contact_newton_iterations: r.contact_newton_iterations,
            bodies_iterated: r.bodies_iterated,
            device_iterations: r.device_iterations,
            factorizations: r.factorizations,
            residual_norm: r.residual_norm,
            cutbacks: r.cutbacks,
            substeps: r.substeps,
            overlap_retries: r.overlap_retries,
            energy_retries: r.energy_retries,
            raised_theta: r.raised_theta,
            kept_beyond_bounds: r.kept_beyond_bounds,
            wall_s: r.wall,
            bytes_moved: r.bytes_moved,
            bytes_up: r.bytes_up,
            device_submits: r.device_submits,
            status: status.to_string(),
            message,
        };
        self.log.write("/solver", t, &msg)
    }

    /// The run's totals on `/summary`, its last message.
    fn summary(&mut self, summary: &RunSummary, t: Real) -> Result<(), OutputError> {
        self.log.write("/summary", t, summary)
    }

    /// A step's events (cut-backs) to the monitor and, as warnings, to `/log`.
    fn events(&mut self, monitor: &mut dyn Monitor, t: Real, events: &[String]) -> Result<(), OutputError> {
        for ev in events {
            monitor.warning(ev);
            self.line(t, Level::Warning, ev)?;
        }
        Ok(())
    }

    fn line(&mut self, t: Real, level: Level, message: &str) -> Result<(), OutputError> {
        self.log.write("/log", t, &foxglove::log(t, level, message))
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| payload.downcast_ref::<String>().cloned()).unwrap_or_else(|| "a panic without a message".into())
}

/// Totals kept while stepping, for the summary.
#[derive(Default)]
struct Totals {
    cutbacks: usize,
    newton: usize,
    uzawa: usize,
    contact_newton: usize,
    bodies_iterated: usize,
    device_iterations: usize,
    factorizations: usize,
    max_penetration: Real,
    max_overlap: Real,
    max_overlap_ratio: Real,
    energy_gain_steps: usize,
    max_energy_gain: Real,
    overlap_retries: usize,
    energy_retries: usize,
    kept_beyond_bounds: usize,
    wall: PhaseTimes,
    bytes_moved: u64,
    device_submits: u64,
}

impl Totals {
    /// Adds a finished step's counts.
    fn add(&mut self, report: &StepReport) {
        self.cutbacks += report.cutbacks;
        self.overlap_retries += report.overlap_retries;
        self.energy_retries += report.energy_retries;
        self.kept_beyond_bounds += report.kept_beyond_bounds;
        self.newton += report.newton_iterations;
        self.uzawa += report.uzawa_iterations;
        self.contact_newton += report.contact_newton_iterations;
        self.bodies_iterated += report.bodies_iterated;
        self.device_iterations += report.device_iterations;
        self.factorizations += report.factorizations;
        self.max_penetration = self.max_penetration.max(report.contact.max_penetration);
        self.max_overlap = self.max_overlap.max(report.contact.max_overlap);
        self.max_overlap_ratio = self.max_overlap_ratio.max(report.contact.max_overlap_ratio);
        self.wall += report.wall;
        self.bytes_moved += report.bytes_moved;
        self.device_submits += report.device_submits;
    }
}

/// The status of a run that finished having created more energy than `solver.max_energy_gain`.
pub const ENERGY_CREATED: &str = "energy_created";

/// Energy-gain warnings written to `/log` before they are only counted.
const ENERGY_GAIN_LINES: usize = 10;

/// Runs a loaded scene to its end time, logging to `out`.
pub fn run_scene(loaded: &LoadedScene, out: &Path, options: &RunOptions, monitor: &mut dyn Monitor) -> Result<RunSummary, RunError> {
    let started = std::time::Instant::now();
    let (mut sim, resolved, notices) = set_up(loaded, options, monitor)?;
    let backend = &resolved.backend;
    let mut logger = Logger::new(out, loaded, &sim, options, backend)?;
    log_start(&mut logger, loaded, &sim, &resolved, &notices, options)?;
    let total = sim.step_count();
    monitor.started(total);
    monitor.state(&sim);
    logger.state(&sim, sim.energies())?;
    logger.frames(&sim, false)?;
    logger.contacts(&sim, false)?;
    logger.saved(&sim, false)?;
    let mut totals = Totals::default();
    let stop = step_until_stopped(loaded, &mut sim, &mut logger, monitor, &mut totals)?;
    let contour = |sim: &Simulation| match &options.contour {
        Some(path) => contour_png(sim, &sim.bodies().iter().map(|b| b.cell_fields()).collect::<Vec<_>>(), &format!("{}: von Mises stress at t = {:.4}", loaded.name, sim.t()), path),
        None => Ok(()),
    };
    let summary = |sim: &Simulation, stop: Option<&Stop>| run_summary(loaded, backend, sim, &totals, stop, started, out);
    match stop {
        None => {
            contour(&sim)?;
            let summary = summary(&sim, None);
            let end = format!(
                "finished: {} steps to t = {:.6e}, {} Newton iterations, {} cut-backs, {:.2} s wall; energy balance error {:.1e}",
                summary.steps, summary.t_end, summary.newton_iterations, summary.cutbacks, summary.wall_s, summary.energy.energy_balance_error
            );
            logger.line(sim.t(), Level::Info, &end)?;
            logger.summary(&summary, sim.t())?;
            logger.log.finish()?;
            Ok(summary)
        }
        Some((stop, report)) => {
            // The last finished step goes into every output, then the reason for stopping (the
            // states only if the device that kept them gives them back).
            let synced = sim.sync_states().is_ok();
            logger.state(&sim, sim.energies())?;
            if synced {
                logger.frames(&sim, true)?;
                logger.contacts(&sim, true)?;
                if !logger.saves(&sim, true) || sim.sync_factors().is_ok() {
                    logger.saved(&sim, true)?;
                }
            }
            let level = if matches!(stop, Stop::Interrupted) { Level::Warning } else { Level::Error };
            let message = stop.to_string();
            logger.line(sim.t(), level, &format!("the run stopped at t = {:.6e}: {message}", sim.t()))?;
            logger.solver(&report, report.t, stop.status(), Some(message))?;
            if let Some(Err(e)) = synced.then(|| contour(&sim)) {
                monitor.warning(&e.to_string());
            }
            let summary = summary(&sim, Some(&stop));
            logger.summary(&summary, sim.t())?;
            logger.log.finish()?;
            Err(RunError::Stopped { reason: stop, summary: Box::new(summary) })
        }
    }
}

/// The simulation of a run, on its backend, at its start (t = 0 or the restored state); the
/// backend's choice and the notices the user is warned of.
fn set_up(loaded: &LoadedScene, options: &RunOptions, monitor: &mut dyn Monitor) -> Result<(Simulation, crate::backend::Resolved, Vec<String>), RunError> {
    let mut sim = build_simulation(loaded)?;
    let resolved = Backend::resolve(&options.backend)?;
    let uzawa_notice = resolved.backend.uzawa_notice(sim.contact().as_ref().map(|c| c.settings.sweep));
    let notices: Vec<String> = resolved.notice.iter().chain(&uzawa_notice).chain(sim.notices()).cloned().collect();
    for notice in &notices {
        monitor.warning(notice);
    }
    monitor.backend(&resolved.backend.describe());
    let bodies: Vec<_> = sim.bodies().iter().map(|b| b.world_body()).collect();
    // The outputs bring the states back where they read them (`Logger::reads_states`).
    sim.set_world(resolved.backend.device_world(&bodies).map_err(BackendError::from)?);
    if let (Some(path), 3) = (&options.contour, sim.dim()) {
        return Err(PlotError::Draw { path: path.clone(), message: "contour plots are drawn for 2D scenes; use --vtu and ParaView for 3D".into() }.into());
    }
    match &options.restart {
        Some(state) => sim.restore(state)?,
        None => sim.start(),
    }
    sim.set_interrupt(options.interrupt.clone());
    Ok((sim, resolved, notices))
}

/// The log's first lines: what runs where, the notices, why `auto` chose, where a restart
/// continues from.
fn log_start(logger: &mut Logger, loaded: &LoadedScene, sim: &Simulation, resolved: &crate::backend::Resolved, notices: &[String], options: &RunOptions) -> Result<(), RunError> {
    let free_dofs: usize = sim.bodies().iter().map(|b| b.dofs().free_count).sum();
    let start = format!(
        "bifirst {}: scene `{}` ({}), {}, {free_dofs} free dofs, {} of dt = {:e}, backend {}, {}",
        env!("CARGO_PKG_VERSION"),
        loaded.name,
        loaded.path.display(),
        crate::output::counted(sim.bodies().len(), "body", "bodies"),
        crate::output::counted(sim.step_count() - sim.first_step().1, "step", "steps"),
        sim.dt(),
        resolved.backend.describe(),
        crate::output::counted(rayon::current_num_threads(), "thread", "threads")
    );
    // A restarted run's log begins at its state's time.
    logger.line(sim.t(), Level::Info, &start)?;
    for notice in notices {
        logger.line(sim.t(), Level::Warning, notice)?;
    }
    if let Some(reason) = &resolved.reason {
        logger.line(sim.t(), Level::Info, reason)?;
    }
    if let Some(state) = &options.restart {
        logger.line(sim.t(), Level::Info, &format!("continued from a saved state at t = {:.6e} (step {})", state.t, state.step))?;
    }
    Ok(())
}

/// The steps of a run, each logged, until it ends (`None`) or stops (why, and the report of the
/// step it stopped in).
fn step_until_stopped(loaded: &LoadedScene, sim: &mut Simulation, logger: &mut Logger, monitor: &mut dyn Monitor, totals: &mut Totals) -> Result<Option<(Stop, StepReport)>, RunError> {
    let every = loaded.scene.output.every;
    let total = sim.step_count();
    loop {
        if sim.finished() {
            return Ok(None);
        }
        if sim.interrupted() {
            return Ok(Some((Stop::Interrupted, StepReport { step: sim.step(), t: sim.t(), ..Default::default() })));
        }
        let dissipated = sim.numerical_dissipation();
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| sim.advance()));
        let report = match result {
            Ok(Ok(report)) => report,
            Ok(Err(failure)) if matches!(failure.failure, StepFailure::Interrupted) => {
                // The abandoned step leaves the state at the last finished one.
                totals.cutbacks += failure.cutbacks;
                logger.events(monitor, failure.t, &failure.report.events)?;
                return Ok(Some((Stop::Interrupted, StepReport { step: sim.step(), t: sim.t(), ..Default::default() })));
            }
            Ok(Err(failure)) => {
                totals.cutbacks += failure.cutbacks;
                logger.events(monitor, failure.t, &failure.report.events)?;
                let mut report = failure.report.clone();
                report.t = failure.t;
                return Ok(Some((Stop::Failed(failure), report)));
            }
            Err(payload) => return Ok(Some((Stop::Panicked(panic_message(payload.as_ref())), StepReport { step: sim.step() + 1, t: sim.t(), ..Default::default() }))),
        };
        logger.events(monitor, sim.t(), &report.events)?;
        totals.add(&report);
        let energies = sim.energies();
        if !energies.total.is_finite() {
            return Ok(Some((Stop::NotFinite { step: sim.step(), t: sim.t() }, report)));
        }
        if let Some(gain) = energy_gain(sim.initial_energy(), &energies, dissipated) {
            totals.energy_gain_steps += 1;
            totals.max_energy_gain = totals.max_energy_gain.max(gain);
            if totals.energy_gain_steps <= ENERGY_GAIN_LINES {
                let more = if totals.energy_gain_steps == ENERGY_GAIN_LINES { " (further such steps are counted in the summary only)" } else { "" };
                let message = format!("step {} at t = {:.6e} created energy: numerical dissipation {:.3e} of the energy scale (a time step too large for the impact speeds?){more}", report.step, sim.t(), -gain);
                monitor.warning(&message);
                logger.line(sim.t(), Level::Warning, &message)?;
            }
        }
        let logged = report.step % every == 0 || sim.finished();
        if logger.reads_states(sim, logged, sim.finished()) || monitor.reads_states() {
            if let Err(e) = sim.sync_states() {
                return Ok(Some((Stop::Device(e.to_string()), report)));
            }
        }
        if logger.saves(sim, sim.finished()) {
            if let Err(e) = sim.sync_factors() {
                return Ok(Some((Stop::Device(e.to_string()), report)));
            }
        }
        if logged {
            logger.solver(&report, sim.t(), "converged", None)?;
            logger.contact(sim, &report)?;
            logger.state(sim, energies)?;
        }
        logger.frames(sim, sim.finished())?;
        logger.contacts(sim, sim.finished())?;
        logger.saved(sim, sim.finished())?;
        monitor.state(sim);
        monitor.step(&report, total);
    }
}

/// The summary of a run as it ends: finished, or `stop`; a run that finished having created
/// more than `solver.max_energy_gain` of the energy scale has status [`ENERGY_CREATED`].
fn run_summary(loaded: &LoadedScene, backend: &Backend, sim: &Simulation, totals: &Totals, stop: Option<&Stop>, started: std::time::Instant, out: &Path) -> RunSummary {
    let max_energy_gain = loaded.scene.solver.max_energy_gain;
    let created = sim.energy_created();
    let (status, message) = match stop {
        Some(stop) => (stop.status().to_string(), Some(stop.to_string())),
        None if created > max_energy_gain => {
            (ENERGY_CREATED.to_string(), Some(format!("the run created {created:.3e} of the energy scale, more than solver.max_energy_gain = {max_energy_gain:.3e} (a time step too large for the impact speed? `bifirst stability` maps it)")))
        }
        None => ("finished".to_string(), None),
    };
    RunSummary {
        scene: loaded.name.clone(),
        status,
        message,
        backend: backend.name().to_string(),
        precision: backend.precision().to_string(),
        adapter: backend.adapter(),
        steps: sim.step() - sim.first_step().1,
        last_step: sim.step(),
        t_end: sim.t(),
        cutbacks: totals.cutbacks,
        newton_iterations: totals.newton,
        uzawa_iterations: totals.uzawa,
        contact_newton_iterations: totals.contact_newton,
        bodies_iterated: totals.bodies_iterated,
        device_iterations: totals.device_iterations,
        factorizations: totals.factorizations,
        max_penetration: totals.max_penetration,
        max_overlap: totals.max_overlap,
        max_overlap_ratio: totals.max_overlap_ratio,
        energy_gain_steps: totals.energy_gain_steps,
        max_energy_gain: totals.max_energy_gain,
        overlap_retries: totals.overlap_retries,
        energy_retries: totals.energy_retries,
        kept_beyond_bounds: totals.kept_beyond_bounds,
        energy_created: created,
        wall_s: started.elapsed().as_secs_f64(),
        wall_by_phase: totals.wall,
        bytes_moved: totals.bytes_moved,
        device_submits: totals.device_submits,
        kernel_times: backend.kernel_times(),
        energy: sim.energies(),
        output: out.to_path_buf(),
    }
}

/// Why a run cannot continue from a log.
#[derive(Debug, thiserror::Error)]
pub enum RestartError {
    #[error(transparent)]
    Read(#[from] crate::output::ReadError),
    #[error("`{path}` holds no `/state` to continue from: {why}")]
    NoState { path: PathBuf, why: &'static str },
    #[error("`{path}` holds no state at or before t = {at} (the first is at t = {first})")]
    NoStateAt { path: PathBuf, at: Real, first: Real },
    #[error("`{0}` does not record its scene and scene file (`/run`)")]
    NoScene(PathBuf),
    #[error("`{path}`: a `/state` message does not read back: {message}")]
    BadState { path: PathBuf, message: String },
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("the logged state does not fit its scene: {0}")]
    Restore(#[from] crate::solver::RestoreError),
}

/// The simulation of the run logged in `log` at its last state (or the last at or before `at`):
/// to draw or export a state long after the run (`bifirst state`).
pub fn simulation_at(log: &Path, at: Option<Real>) -> Result<(LoadedScene, Simulation), RestartError> {
    let (loaded, state) = restart_from(log, at, &[])?;
    let mut sim = build_simulation(&loaded)?;
    sim.load_state(&state)?;
    Ok((loaded, sim))
}

/// The scene of the run logged in `log` (its resolved scene, then `sets`) and the state to
/// continue from: the last, or the last at or before `at`.
pub fn restart_from(log: &Path, at: Option<Real>, sets: &[String]) -> Result<(LoadedScene, SavedState), RestartError> {
    // `/run` is the log's first message, so a log cut short by a crash still names its scene.
    let record = crate::output::read_run_topics(log, |topic| topic == "/run" || topic == "/state")?;
    let states = record.messages("/state");
    let chosen = match at {
        None => states.last(),
        Some(at) => states.iter().rev().find(|s| s["t"].as_f64().is_some_and(|t| t <= at + 1e-9 * at.abs().max(1.0))),
    };
    let chosen = match (chosen, states.first()) {
        (Some(s), _) => s,
        (None, None) => {
            let why = if record.has_summary { "it was written by a bifirst older than `run --restart`, or not by bifirst" } else { "the run was cut short before it logged one (`output.state_every = N` logs one every N steps)" };
            return Err(RestartError::NoState { path: log.into(), why });
        }
        (None, Some(first)) => return Err(RestartError::NoStateAt { path: log.into(), at: at.unwrap_or_default(), first: first["t"].as_f64().unwrap_or(f64::NAN) }),
    };
    let state: SavedState = serde_json::from_value(chosen.clone()).map_err(|e| RestartError::BadState { path: log.into(), message: e.to_string() })?;
    let run = record.messages("/run").first().ok_or_else(|| RestartError::NoScene(log.into()))?;
    let (Some(scene), Some(file)) = (run["scene"].as_str(), run["scene_file"].as_str()) else { return Err(RestartError::NoScene(log.into())) };
    // Mesh files are named relative to the original scene file.
    let loaded = crate::scene::parse_scene(Path::new(file), scene.to_string(), sets)?;
    Ok((loaded, state))
}
