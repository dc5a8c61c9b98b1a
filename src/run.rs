//! Running a scene end to end: set-up, time steps, the MCAP run log, and a summary.

use crate::output::{schemas, OutputError, RunLog};
use crate::precision::{Real, PRECISION_NAME};
use crate::scene::{LoadedScene, SceneError};
use crate::solver::{build_simulation, RunFailure, Simulation, StepReport};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Name of the CPU backend as logged in `/run`.
pub const BACKEND: &str = "cpu";

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Scene(#[from] SceneError),
    #[error("{0}")]
    Output(#[from] OutputError),
    /// The run stopped early; the log holds everything up to the failure.
    #[error("the run stopped: {failure}. The log `{}` holds everything up to t = {:.6e}.", .summary.output.display(), .summary.t_end)]
    Failed { failure: Box<RunFailure>, summary: RunSummary },
}

/// What a run did, printed at its end.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    pub scene: String,
    pub steps: usize,
    pub t_end: Real,
    pub cutbacks: usize,
    pub newton_iterations: usize,
    pub wall_s: f64,
    /// Energies at the end, with the dissipation and the energy balance error.
    pub energy: crate::solver::Energies,
    pub output: PathBuf,
}

/// Told about each step as it finishes (progress display).
pub trait Monitor {
    fn started(&mut self, _total_steps: usize) {}
    fn step(&mut self, _report: &StepReport, _total_steps: usize) {}
    fn warning(&mut self, _message: &str) {}
}

/// A monitor that ignores everything.
pub struct Silent;
impl Monitor for Silent {}

fn vec_of(v: &[Real; 3], dim: usize) -> Value {
    json!(v[..dim])
}

struct Logger {
    log: RunLog,
    dim: usize,
}

impl Logger {
    fn new(path: &Path, loaded: &LoadedScene, sim: &Simulation) -> Result<Self, OutputError> {
        let mut log = RunLog::create(path)?;
        let dim = sim.dim;
        log.add_channel("/run", "bifirst.Run", &schemas::run())?;
        log.add_channel("/energy", "bifirst.Energy", &schemas::energy())?;
        log.add_channel("/solver", "bifirst.Solver", &schemas::solver())?;
        for b in &sim.bodies {
            log.add_channel(&format!("/body/{}", b.name), "bifirst.Body", &schemas::body(dim))?;
        }
        for p in &sim.probes {
            log.add_channel(&format!("/probe/{}", p.name), "bifirst.Probe", &schemas::probe(dim))?;
        }
        for s in &sim.sets {
            log.add_channel(&format!("/reaction/{}", s.name), "bifirst.Reaction", &schemas::reaction(dim))?;
        }
        if let Some(c) = &sim.contact {
            log.add_channel("/contact", "bifirst.Contact", &schemas::contact())?;
            for o in &c.obstacles {
                log.add_channel(&format!("/reaction/{}", o.name), "bifirst.Reaction", &schemas::reaction(dim))?;
            }
        }
        let run = json!({
            "version": env!("CARGO_PKG_VERSION"),
            "scene_name": loaded.name,
            "scene": loaded.resolved_toml,
            "backend": BACKEND,
            "precision": PRECISION_NAME,
            "adapter": Value::Null,
        });
        log.write("/run", 0.0, &run)?;
        log.attach("scene.toml", "application/toml", loaded.resolved_toml.as_bytes())?;
        let meta: BTreeMap<String, String> = [
            ("version", env!("CARGO_PKG_VERSION").to_string()),
            ("scene_name", loaded.name.clone()),
            ("scene_file", loaded.path.display().to_string()),
            ("scene", loaded.resolved_toml.clone()),
            ("backend", BACKEND.to_string()),
            ("precision", PRECISION_NAME.to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        log.metadata("bifirst.run", meta)?;
        Ok(Self { log, dim })
    }

    /// State channels: energy, bodies, probes, reactions at the current time.
    fn state(&mut self, sim: &Simulation) -> Result<(), OutputError> {
        let (t, dim) = (sim.t, self.dim);
        let e = sim.energies();
        let mut energy = serde_json::to_value(e).expect("serializes");
        energy["t"] = json!(t);
        self.log.write("/energy", t, &energy)?;
        for b in &sim.bodies {
            let m = b.metrics();
            let angular = if dim == 2 { json!(m.angular_momentum[2]) } else { json!(m.angular_momentum) };
            let msg = json!({
                "t": t, "mass": m.mass, "center_of_mass": vec_of(&m.center_of_mass, dim),
                "linear_momentum": vec_of(&m.linear_momentum, dim), "angular_momentum": angular, "kinetic": m.kinetic,
            });
            self.log.write(&format!("/body/{}", b.name), t, &msg)?;
        }
        for p in &sim.probes {
            let b = &sim.bodies[p.body];
            let n = p.node;
            let u = &b.state.u[n * dim..(n + 1) * dim];
            let v = &b.state.v[n * dim..(n + 1) * dim];
            let msg = json!({
                "t": t, "position": vec_of(&b.position(n), dim), "displacement": u, "velocity": v,
                "von_mises": b.von_mises(&p.elements),
            });
            self.log.write(&format!("/probe/{}", p.name), t, &msg)?;
        }
        for (s, r) in sim.sets.iter().zip(sim.reactions()) {
            self.log.write(&format!("/reaction/{}", s.name), t, &json!({"t": t, "force": vec_of(&r, dim)}))?;
        }
        if let Some(c) = &sim.contact {
            for (o, r) in c.obstacles.iter().zip(&sim.obstacle_reactions) {
                self.log.write(&format!("/reaction/{}", o.name), t, &json!({"t": t, "force": vec_of(r, dim)}))?;
            }
        }
        Ok(())
    }

    /// The `/contact` channel of a step (only in scenes with contact).
    fn contact(&mut self, sim: &Simulation, r: &StepReport) -> Result<(), OutputError> {
        if sim.contact.is_none() {
            return Ok(());
        }
        let mut msg = serde_json::to_value(r.contact).expect("serializes");
        msg["t"] = json!(sim.t);
        self.log.write("/contact", sim.t, &msg)
    }

    fn solver(&mut self, r: &StepReport, t: Real, failure: Option<String>) -> Result<(), OutputError> {
        let msg = json!({
            "t": t, "step": r.step, "dt": r.dt, "newton_iterations": r.newton_iterations, "uzawa_iterations": r.uzawa_iterations,
            "residual_norm": r.residual_norm, "cutbacks": r.cutbacks, "wall_s": r.wall,
            "status": if failure.is_some() { "failed" } else { "converged" }, "message": failure,
        });
        self.log.write("/solver", t, &msg)
    }
}

/// Runs a loaded scene to its end time, logging to `out`.
pub fn run_scene(loaded: &LoadedScene, out: &Path, monitor: &mut dyn Monitor) -> Result<RunSummary, RunError> {
    let started = std::time::Instant::now();
    let mut sim = build_simulation(loaded)?;
    sim.start();
    let mut logger = Logger::new(out, loaded, &sim)?;
    let every = loaded.scene.output.every;
    let total = sim.step_count();
    monitor.started(total);
    logger.state(&sim)?;
    let (mut cutbacks, mut newton) = (0, 0);
    let summary = |sim: &Simulation, cutbacks, newton| {
        let e = sim.energies();
        RunSummary {
            scene: loaded.name.clone(),
            steps: sim.step,
            t_end: sim.t,
            cutbacks,
            newton_iterations: newton,
            wall_s: started.elapsed().as_secs_f64(),
            energy: e,
            output: out.to_path_buf(),
        }
    };
    while !sim.finished() {
        match sim.advance() {
            Ok(report) => {
                for ev in &report.events {
                    monitor.warning(ev);
                }
                cutbacks += report.cutbacks;
                newton += report.newton_iterations;
                if report.step % every == 0 || sim.finished() {
                    logger.solver(&report, sim.t, None)?;
                    logger.contact(&sim, &report)?;
                    logger.state(&sim)?;
                }
                monitor.step(&report, total);
            }
            Err(failure) => {
                for ev in &failure.report.events {
                    monitor.warning(ev);
                }
                let mut report = failure.report.clone();
                report.t = failure.t;
                logger.solver(&report, failure.t, Some(failure.to_string()))?;
                logger.log.finish()?;
                let summary = summary(&sim, cutbacks + failure.cutbacks, newton);
                return Err(RunError::Failed { failure: Box::new(failure), summary });
            }
        }
    }
    logger.log.finish()?;
    Ok(summary(&sim, cutbacks, newton))
}
