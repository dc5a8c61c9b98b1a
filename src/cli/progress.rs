//! What a run shows while it runs (a progress bar on a terminal, plain lines otherwise) and after
//! (the summary), and the interrupt flags that SIGINT, SIGTERM and SIGHUP set.

use anyhow::Result;
use bifirst::run::{Monitor, RunSummary};
use bifirst::solver::StepReport;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

/// A progress bar on a terminal; otherwise plain lines about every 10% (at most every 2 s, at
/// least every 30 s).
pub(crate) struct Progress {
    pub(crate) quiet: bool,
    pub(crate) bar: Option<ProgressBar>,
    pub(crate) last_line: Instant,
    pub(crate) last_fraction: f64,
}

impl Monitor for Progress {
    fn backend(&mut self, description: &str) {
        if !self.quiet {
            eprintln!("backend: {description}");
        }
    }
    fn started(&mut self, total: usize) {
        if !self.quiet && std::io::stderr().is_terminal() {
            let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            bar.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} steps  t = {msg}  [{elapsed_precise} < {eta}]").expect("valid template"));
            self.bar = Some(bar);
        }
    }
    fn step(&mut self, r: &StepReport, total: usize) {
        if self.quiet {
            return;
        }
        let fraction = r.step as f64 / total as f64;
        match &self.bar {
            Some(bar) => {
                bar.set_position(r.step as u64);
                bar.set_message(format!("{:.4e}", r.t));
            }
            None => {
                let since = self.last_line.elapsed().as_secs_f64();
                if fraction - self.last_fraction >= 0.1 - 1e-12 && since >= 2.0 || since >= 30.0 || r.step == total {
                    eprintln!("step {}/{}  t = {:.4e}  newton {}  cut-backs {}", r.step, total, r.t, r.newton_iterations, r.cutbacks);
                    self.last_line = Instant::now();
                    self.last_fraction = fraction;
                }
            }
        }
    }
    fn warning(&mut self, message: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.println(format!("warning: {message}")),
            None => eprintln!("warning: {message}"),
        }
    }
}

pub(crate) fn print_summary(s: &RunSummary) {
    eprintln!(
        "{}: {} steps to t = {:.6e}, {} Newton iterations, {} cut-backs, {:.2} s wall; dissipated by friction {:.4e}, viscosity {:.4e}, numerically {:.4e}, energy balance error {:.1e}; log written to {}",
        s.scene,
        s.steps,
        s.t_end,
        s.newton_iterations,
        s.cutbacks,
        s.wall_s,
        s.energy.friction_dissipation,
        s.energy.viscous_dissipation,
        s.energy.numerical_dissipation,
        s.energy.energy_balance_error,
        s.output.display()
    );
    if s.energy_gain_steps > 0 {
        eprintln!("warning: {} steps created energy (largest {:.3e} of the energy scale); see /log", s.energy_gain_steps, s.max_energy_gain);
    }
    if let Some(times) = &s.kernel_times {
        let total: f64 = times.kernels.iter().map(|k| k.seconds).sum();
        eprintln!("device time by kernel ({total:.4} s in all):");
        for k in &times.kernels {
            eprintln!("  {:<34} {:>10.4} s {:>5.1} % {:>9} dispatches", k.kernel, k.seconds, 100.0 * k.seconds / total.max(f64::MIN_POSITIVE), k.dispatches);
        }
        if times.untimed_dispatches > 0 {
            eprintln!("  and {} dispatches untimed (submissions longer than the clock's timestamps)", times.untimed_dispatches);
        }
    }
    if s.max_overlap_ratio > 0.01 {
        eprintln!("warning: a node ended {:.3e} inside another body or an obstacle ({:.1} % of its element); see /contact.max_overlap", s.max_overlap, 100.0 * s.max_overlap_ratio);
    }
}

/// Interrupts (SIGINT, SIGTERM, SIGHUP: a closed terminal or SSH session) set the first flag,
/// which abandons the step in progress at its next Newton iteration, cut-back or Uzawa sweep
/// and stops the run with its log closed properly; a second interrupt
/// exits at once. The second flag tells a hang-up apart (exit 129 instead of 130).
pub(crate) fn interrupt_flags() -> Result<(Arc<AtomicBool>, Arc<AtomicBool>)> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let (flag, hangup) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
    for (signal, code) in [(SIGINT, 130), (SIGTERM, 130), (SIGHUP, 129)] {
        signal_hook::flag::register_conditional_shutdown(signal, code, Arc::clone(&flag))?;
        signal_hook::flag::register(signal, Arc::clone(&flag))?;
    }
    signal_hook::flag::register(SIGHUP, Arc::clone(&hangup))?;
    Ok((flag, hangup))
}
