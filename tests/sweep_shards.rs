//! Sweeps split over machines: shards (`--shard K/N`), one variant per job-array task
//! (`--index I` through the `--slurm` script, run here without Slurm) and the report that merges
//! a directory's logs (`sweep-report DIR`).

#[path = "common/run.rs"]
mod common;

use common::{read_log, temp_path};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

/// A 6-variant grid of a short sliding-block run (10 to 40 steps each).
const GRID: [&str; 8] = ["scenes/sliding_block.toml", "--over", "contact.friction=0.2,0.4", "--over", "time.dt=0.01,0.005,0.0025", "--set", "time.end=0.1", "--backend"];

fn bifirst(args: &[&str]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_bifirst"));
    cmd.args(args).current_dir(env!("CARGO_MANIFEST_DIR"));
    cmd
}

fn sweep(extra: &[&str], out: &Path) -> Command {
    let mut cmd = bifirst(&[&["sweep"], &GRID[..], &["cpu"], extra].concat());
    cmd.arg("--out").arg(out);
    cmd
}

fn text(o: &Output) -> String {
    format!("exit {:?}\nstdout:\n{}\nstderr:\n{}", o.status.code(), String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = temp_path(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The `.mcap` file names in `dir`, sorted.
fn logs(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).filter(|n| n.ends_with(".mcap")).collect();
    names.sort();
    names
}

/// What a run computed, without its timings: energies, contact, bodies, reactions and counts.
fn results(path: &Path) -> Vec<String> {
    let log = read_log(path);
    let mut out = Vec::new();
    for (topic, messages) in log.topics.iter().filter(|(t, _)| ["/energy", "/contact", "/body/", "/reaction/"].iter().any(|p| t.starts_with(p))) {
        out.extend(messages.iter().map(|m| format!("{topic} {m}")));
    }
    assert!(out.len() > 40, "{}: the log holds the run", path.display());
    let s = &log.topics["/summary"][0];
    for key in ["status", "steps", "t_end", "newton_iterations", "uzawa_iterations", "cutbacks"] {
        out.push(format!("{key} {}", s[key]));
    }
    out
}

#[test]
fn three_shards_write_the_six_logs_of_the_whole_sweep() {
    let (whole, sharded) = (fresh_dir("sweep_whole"), fresh_dir("sweep_sharded"));
    let o = sweep(&["--jobs", "2"], &whole).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(logs(&whole).len(), 6, "{}", text(&o));

    // The shards start together, as on three machines sharing the directory.
    let shards: Vec<_> = (0..3).map(|k| sweep(&["--shard", &format!("{k}/3"), "--jobs", "1"], &sharded).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap()).collect();
    for (k, child) in shards.into_iter().enumerate() {
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "shard {k}/3: {}", text(&o));
    }
    assert_eq!(logs(&sharded), logs(&whole), "the shards write the whole sweep's file names");
    for name in logs(&whole) {
        assert_eq!(results(&sharded.join(&name)), results(&whole.join(&name)), "{name}: the same results");
    }
    assert_eq!(std::fs::read_to_string(sharded.join("sweep.json")).unwrap(), std::fs::read_to_string(whole.join("sweep.json")).unwrap(), "one grid record");

    let o = bifirst(&["sweep-report"]).arg(&sharded).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && stdout.contains("6 of 6 variants finished"), "{}", text(&o));
    assert!(stdout.lines().next().unwrap().contains("friction=0.4, dt=0.0025"), "columns are labelled by variant:\n{stdout}");
    assert!(sharded.join("plots/energies.png").is_file(), "the report plots the runs overlaid");

    // A shard is refused a directory that holds another grid.
    let o = bifirst(&["sweep", "scenes/sliding_block.toml", "--over", "contact.friction=0.1,0.3", "--set", "time.end=0.1", "--shard", "0/2", "--out"]).arg(&sharded).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("describes another sweep (--over contact.friction=0.2,0.4 time.dt=0.01,0.005,0.0025, not contact.friction=0.1,0.3)"), "{}", text(&o));
}

#[test]
fn the_slurm_script_runs_every_variant_without_slurm() {
    let dir = fresh_dir("sweep_slurm");
    std::fs::create_dir_all(&dir).unwrap();
    let script = dir.join("job.sh");
    let mut write = sweep(&["--slurm", script.to_str().unwrap(), "--sbatch", "partition=short", "--sbatch", "time=00:10:00", "--sbatch", "array=0-5%2"], &dir.join("out"));
    let o = write.arg("--threads").arg("2").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("submit:      sbatch"), "{}", text(&o));
    let body = std::fs::read_to_string(&script).unwrap();
    for line in ["#SBATCH --array=0-5%2\n", "#SBATCH --cpus-per-task=2\n", "#SBATCH --partition=short\n", "#SBATCH --time=00:10:00\n", "#SBATCH --job-name=bifirst-sliding_block\n"] {
        assert!(body.contains(line), "the script has `{}`:\n{body}", line.trim());
    }
    assert!(!body.contains("--array=0-5\n"), "the user's array directive replaces the default:\n{body}");
    let syntax = Command::new("bash").arg("-n").arg(&script).output().unwrap();
    assert!(syntax.status.success(), "bash -n: {}", text(&syntax));

    let listed = sweep(&["--list"], &dir.join("out")).output().unwrap();
    let expected: Vec<String> = String::from_utf8_lossy(&listed.stdout).lines().map(|l| Path::new(l.split('\t').nth(2).unwrap()).file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(expected.len(), 6, "{}", text(&listed));

    // The report of the array before any task ran names every variant as missing.
    let o = bifirst(&["sweep-report"]).arg(dir.join("out")).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("0 of 6 variants finished"), "{}", text(&o));

    for index in 0..6 {
        // From another directory, as a task on a compute node starts.
        let o = Command::new("bash").arg(&script).env("SLURM_ARRAY_TASK_ID", index.to_string()).current_dir(std::env::temp_dir()).output().unwrap();
        assert!(o.status.success(), "task {index}: {}", text(&o));
    }
    let mut expected = expected;
    expected.sort();
    assert_eq!(logs(&dir.join("out")), expected, "every variant, under the names of the sweep");

    let o = Command::new("bash").arg(&script).env_remove("SLURM_ARRAY_TASK_ID").output().unwrap();
    assert!(!o.status.success() && text(&o).contains("SLURM_ARRAY_TASK_ID"), "without a task id the script says what it needs: {}", text(&o));
}

#[test]
fn a_report_names_the_variant_that_is_missing() {
    let dir = fresh_dir("sweep_missing");
    let o = sweep(&["--jobs", "2"], &dir).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    std::fs::remove_file(dir.join("sliding_block_friction-0.4_dt-0.005.mcap")).unwrap();
    let o = bifirst(&["sweep-report"]).arg(&dir).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "a missing variant fails the report: {}", text(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("5 of 6 variants finished"), "{stdout}");
    assert!(stdout.contains("variant 4, friction=0.4, dt=0.005: missing"), "{stdout}");

    let o = bifirst(&["sweep-report", "--json"]).arg(&dir).output().unwrap();
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", text(&o)));
    let statuses: Vec<&str> = json["variants"].as_array().unwrap().iter().map(|v| v["status"].as_str().unwrap()).collect();
    assert_eq!(statuses, ["finished", "finished", "finished", "finished", "missing", "finished"]);

    // Without the grid record, the report takes the logs it finds.
    std::fs::remove_file(dir.join("sweep.json")).unwrap();
    let o = bifirst(&["sweep-report"]).arg(&dir).output().unwrap();
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("5 of 5 variants finished"), "{}", text(&o));

    let o = sweep(&["--index", "6"], &dir).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("`--index 6`: the sweep has 6 variants (0 to 5)"), "{}", text(&o));
}
