//! A sweep as a Slurm job array: one array task per variant (`bifirst sweep ... --index
//! $SLURM_ARRAY_TASK_ID`), every log into the sweep directory on the cluster's shared file
//! system, merged afterwards by `bifirst sweep-report`.

use super::{Sweep, SweepError};
use std::fmt::Write;
use std::path::PathBuf;

/// The sbatch options that may stand without a value (`--sbatch exclusive`); every other
/// option needs one (a bare `time` would write `#SBATCH --time`, which sbatch rejects at submit).
const SBATCH_FLAGS: [&str; 17] = ["exclusive", "requeue", "no-requeue", "hold", "overcommit", "oversubscribe", "contiguous", "spread-job", "use-min-nodes", "nice", "propagate", "get-user-env", "test-only", "wait", "parsable", "quiet", "verbose"];

/// `--sbatch KEY=VALUE` (or a bare flag, such as `exclusive`): one `#SBATCH --KEY=VALUE` line.
#[derive(Debug, Clone, PartialEq)]
pub struct SbatchOption {
    pub key: String,
    pub value: Option<String>,
}

impl std::str::FromStr for SbatchOption {
    type Err = SweepError;

    fn from_str(spec: &str) -> Result<Self, SweepError> {
        let (key, value) = match spec.split_once('=') {
            Some((k, v)) => (k.trim(), Some(v.trim().to_string())),
            None => (spec.trim(), None),
        };
        let key = key.trim_start_matches('-');
        // A line break would end the directive and start a shell command in the script.
        let bad_key = key.is_empty() || !key.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
        if bad_key || value.as_ref().is_some_and(|v| v.is_empty() || v.chars().any(char::is_control)) {
            return Err(SweepError::Sbatch(spec.to_string()));
        }
        if value.is_none() && !SBATCH_FLAGS.contains(&key) {
            return Err(SweepError::SbatchValue(key.to_string()));
        }
        Ok(Self { key: key.to_string(), value })
    }
}

/// A job array that runs a sweep, one variant per task.
pub struct SlurmJob<'a> {
    pub sweep: &'a Sweep,
    /// The sweep directory, absolute: the tasks run on other machines.
    pub out_dir: PathBuf,
    /// The `bifirst` binary the tasks call, absolute (the environment variable `BIFIRST`
    /// overrides it when the job runs).
    pub exe: PathBuf,
    /// Threads per task: Slurm's `--cpus-per-task` and bifirst's `--threads`.
    pub threads: usize,
    /// Run options every task passes on (`--backend`, `--adapter`, `--precision`).
    pub run_args: Vec<String>,
    /// Directives of the user's, replacing the default of the same key.
    pub sbatch: Vec<SbatchOption>,
}

impl SlurmJob<'_> {
    /// The command that merges the tasks' logs into a table and plots.
    pub fn merge_command(&self) -> String {
        format!("{} sweep-report {}", quote(&self.exe.to_string_lossy()), quote(&self.out_dir.to_string_lossy()))
    }

    /// The batch script: `#SBATCH` directives, then the one command every task runs.
    pub fn script(&self) -> String {
        let count = self.sweep.variants.len();
        let output = self.out_dir.join("slurm-%A_%a.out");
        let defaults = [("job-name", format!("bifirst-{}", self.sweep.name)), ("array", format!("0-{}", count.saturating_sub(1))), ("cpus-per-task", self.threads.to_string()), ("output", output.to_string_lossy().into_owned())];
        let mut s = String::from("#!/bin/bash\n");
        let _ = writeln!(s, "# A Slurm job array written by `bifirst sweep --slurm` (bifirst {}): one task per variant", env!("CARGO_PKG_VERSION"));
        let _ = writeln!(s, "# of the sweep of `{}`, {count} variants, logs in {}.", self.sweep.name, self.out_dir.display());
        let _ = writeln!(s, "#   submit:             sbatch THIS_FILE");
        let _ = writeln!(s, "#   one variant here:   SLURM_ARRAY_TASK_ID=I bash THIS_FILE");
        let _ = writeln!(s, "#   when all are done:  {}", self.merge_command());
        for (key, value) in defaults.iter().filter(|(key, _)| !self.sbatch.iter().any(|o| o.key == *key)) {
            let _ = writeln!(s, "#SBATCH --{key}={}", directive_value(value));
        }
        for o in &self.sbatch {
            match &o.value {
                Some(v) => writeln!(s, "#SBATCH --{}={}", o.key, directive_value(v)),
                None => writeln!(s, "#SBATCH --{}", o.key),
            }
            .expect("writes to a string");
        }
        s.push_str("set -euo pipefail\n# The variants, by array task index:\n");
        for v in &self.sweep.variants {
            let _ = writeln!(s, "#   {:>4}  {}  ->  {}.mcap", v.index, v.label.replace(char::is_control, " "), v.stem);
        }
        let _ = writeln!(s, ": \"${{SLURM_ARRAY_TASK_ID:?is set by Slurm for each array task (0 to {})}}\"", count.saturating_sub(1));
        let _ = writeln!(s, "BIFIRST=${{BIFIRST:-{}}}", quote(&self.exe.to_string_lossy()));
        let mut args = vec![format!("--threads {}", self.threads), "sweep".into(), quote(&self.sweep.scene.to_string_lossy())];
        args.extend(self.sweep.sets.iter().map(|set| format!("--set {}", quote(set))));
        args.extend(self.sweep.axes.iter().map(|a| format!("--over {}", quote(&format!("{}={}", a.key, a.values.join(","))))));
        if !self.run_args.is_empty() {
            args.push(self.run_args.iter().map(|a| quote(a)).collect::<Vec<_>>().join(" "));
        }
        args.push(format!("--out {}", quote(&self.out_dir.to_string_lossy())));
        args.push("--index \"$SLURM_ARRAY_TASK_ID\"".into());
        let _ = writeln!(s, "exec \"$BIFIRST\" {}", args.join(" \\\n  "));
        s
    }
}

/// A word for bash: as it is when it holds no special character, else in single quotes.
fn quote(word: &str) -> String {
    if !word.is_empty() && word.chars().all(|c| c.is_ascii_alphanumeric() || "/._-=,:+@%".contains(c)) {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', r"'\''"))
    }
}

/// An `#SBATCH` value, in double quotes when it holds white space (sbatch reads them).
fn directive_value(value: &str) -> String {
    if value.chars().any(char::is_whitespace) {
        format!("\"{}\"", value.replace('"', "\\\""))
    } else {
        value.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_are_quoted_for_bash_only_when_needed() {
        assert_eq!(quote("/a/b-c_1.toml"), "/a/b-c_1.toml");
        assert_eq!(quote("body.b.v=[1, 0]"), "'body.b.v=[1, 0]'");
        assert_eq!(quote("it's"), r"'it'\''s'");
        assert_eq!(quote(""), "''");
    }

    #[test]
    fn sbatch_options_cannot_break_out_of_their_line() {
        let o: SbatchOption = "--partition=short".parse().unwrap();
        assert_eq!((o.key.as_str(), o.value.as_deref()), ("partition", Some("short")));
        assert_eq!("exclusive".parse::<SbatchOption>().unwrap().value, None);
        for bad in ["time=1:00\nrm -rf /", "=3", "a b=1", "mem="] {
            assert!(bad.parse::<SbatchOption>().is_err(), "{bad:?}");
        }
    }
}
