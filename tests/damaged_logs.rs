//! Logs as inputs: every command that reads a log takes damaged, edited, foreign or cut logs
//! with a clear error (exit 1 or 2), never an abort; a restart continues only the run that
//! saved its state, never over its own input, on the uninterrupted run's time grid.

#[path = "common/run.rs"]
mod common_run;

use common_run::{scene_path, temp_path};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// An edit of a log's JSON record.
type Edit = Box<dyn Fn(&mut Value)>;

fn bifirst(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bifirst")).args(args).current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap()
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = temp_path(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A finished `sliding_block` log of `steps` steps of dt = 1e-3.
fn sliding_log(dir: &Path, steps: usize) -> PathBuf {
    let log = dir.join("L.mcap");
    let end = format!("time.end={}", steps as f64 * 1e-3);
    let o = bifirst(&["run", scene_path("sliding_block").to_str().unwrap(), "--quiet", "--backend", "cpu", "--set", &end, "--out", log.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    log
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// The exit status, or the signal as a negative number.
fn exit_of(o: &Output) -> i32 {
    use std::os::unix::process::ExitStatusExt;
    o.status.code().unwrap_or_else(|| -o.status.signal().unwrap_or(0))
}

/// Caught: 6 of 60 single-bit flips made `state` and `run --restart` abort (exit 134) on an
/// allocation of exabytes that a damaged chunk header asked of the MCAP reader. Every reader now
/// walks the file with its lengths checked: bit flips and cuts at seeded offsets, through every
/// command that reads a log, end with exit 0, 1 or 2 and no panic.
#[test]
fn damaged_logs_are_errors_never_aborts() {
    let dir = fresh_dir("damaged");
    let sweep = dir.join("sweep");
    let o = bifirst(&["sweep", p(&scene_path("sliding_block")), "--backend", "cpu", "--set", "time.end=0.02", "--over", "contact.friction=0.3", "--out", p(&sweep)]);
    assert!(o.status.success(), "{}", text(&o));
    let log = std::fs::read_dir(&sweep).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|x| x == "mcap")).unwrap();
    let good = std::fs::read(&log).unwrap();
    let mut rng = SmallRng::seed_from_u64(0x3210_2026);
    let (plots, out) = (dir.join("plots"), dir.join("continued.mcap"));
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for _ in 0..48 {
        let (at, bit) = (rng.random_range(0..good.len()), rng.random_range(0..8));
        let mut bytes = good.clone();
        bytes[at] ^= 1 << bit;
        cases.push((format!("bit {bit} flipped at {at}"), bytes));
    }
    for _ in 0..12 {
        let at = rng.random_range(0..good.len());
        cases.push((format!("cut at {at}"), good[..at].to_vec()));
    }
    let mut errors = 0;
    for (case, bytes) in &cases {
        std::fs::write(&log, bytes).unwrap();
        let commands: [Vec<&str>; 5] =
            [vec!["summary", p(&log)], vec!["plot", p(&log), "--out", p(&plots)], vec!["state", p(&log)], vec!["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.022", "--out", p(&out)], vec!["sweep-report", p(&sweep)]];
        for args in commands {
            let _ = std::fs::remove_file(&out);
            let o = bifirst(&args);
            let code = exit_of(&o);
            assert!((0..=2).contains(&code) && !text(&o).contains("panicked"), "{case}: `bifirst {}` exit {code}: {}", args.join(" "), text(&o));
            errors += usize::from(code != 0);
        }
    }
    assert!(errors > 0, "some damage is found");
}

/// Caught: a restart onto the same number of dofs with another geometry ran on (kinetic energy
/// doubled at the restart); a changed material would continue with forces of another material.
#[test]
fn a_restart_onto_another_mesh_or_material_is_refused() {
    let dir = fresh_dir("restart_changed");
    let log = sliding_log(&dir, 20);
    let out = dir.join("continued.mcap");
    for (set, what) in [("body.block.mesh.size=[0.4,0.1]", "meshes"), ("material.steel_like.G=2.0e7", "materials")] {
        let o = bifirst(&["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.03", "--set", set, "--out", p(&out)]);
        assert_eq!(exit_of(&o), 2, "{set}: {}", text(&o));
        assert!(text(&o).contains(&format!("the bodies' {what}")), "{set}: {}", text(&o));
        let o = bifirst(&["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.03", "--set", set, "--out", p(&out)]);
        assert_eq!(text(&o).matches("a restart continues the same bodies").count(), 1, "said once: {}", text(&o));
    }
    let o = bifirst(&["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.03", "--set", "contact.friction=0.1", "--out", p(&out)]);
    assert!(o.status.success(), "what is not in the state may change: {}", text(&o));
}

/// Caught: `--out` equal to the restart's input emptied the log being continued.
#[test]
fn a_restart_never_writes_over_its_own_input() {
    let dir = fresh_dir("restart_over_input");
    let log = sliding_log(&dir, 10);
    let before = std::fs::read(&log).unwrap();
    let other_spelling = dir.join("..").join(dir.file_name().unwrap()).join("L.mcap");
    for out in [log.clone(), other_spelling] {
        let o = bifirst(&["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.02", "--out", p(&out)]);
        assert_eq!(exit_of(&o), 2, "{}", text(&o));
        assert!(text(&o).contains("is the log the run continues from"), "{}", text(&o));
        assert_eq!(std::fs::read(&log).unwrap(), before, "the input is untouched");
    }
}

/// The last `/state` of a log.
fn last_state(log: &Path) -> Value {
    bifirst::output::read_run(log).unwrap().messages("/state").last().unwrap().clone()
}

/// Caught: a finished run ended at t = 0.1 exactly (its last step shortened by round-off) while
/// the uninterrupted run was at 0.10000000000000007, so a continued run went on another time
/// grid. A step within round-off of the end is now a whole step.
#[test]
fn a_finished_run_continued_is_the_uninterrupted_run_bit_for_bit() {
    let dir = fresh_dir("continued_grid");
    let log = sliding_log(&dir, 100);
    let continued = dir.join("continued.mcap");
    let o = bifirst(&["run", "--restart", p(&log), "--quiet", "--set", "time.end=0.12", "--out", p(&continued)]);
    assert!(o.status.success(), "{}", text(&o));
    let whole = dir.join("whole.mcap");
    let o = bifirst(&["run", p(&scene_path("sliding_block")), "--quiet", "--backend", "cpu", "--set", "time.end=0.12", "--out", p(&whole)]);
    assert!(o.status.success(), "{}", text(&o));
    let (a, b) = (last_state(&continued), last_state(&whole));
    assert_eq!(a["step"], 120);
    assert_eq!(a, b, "the same state, bit for bit");
}

/// Caught: `summary` divided a restarted log's totals by the global step index (`180
/// (1.80/step)` for 60 steps), and the restart's start line counted the steps before it.
#[test]
fn a_restarted_log_counts_its_own_steps() {
    let dir = fresh_dir("restart_steps");
    let log = sliding_log(&dir, 30);
    let continued = dir.join("continued.mcap");
    let o = bifirst(&["run", "--restart", p(&log), "--set", "time.end=0.05", "--out", p(&continued)]);
    assert!(o.status.success(), "{}", text(&o));
    let record = bifirst::output::read_run(&continued).unwrap();
    let start = record.messages("/log").iter().filter_map(|m| m["message"].as_str()).find(|m| m.starts_with("bifirst ")).unwrap().to_string();
    assert!(start.contains(" 20 steps of dt"), "{start}");
    assert_eq!(record.messages("/summary")[0]["last_step"], 50);
    let o = bifirst(&["summary", p(&continued), "--json"]);
    let rows: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(rows[0]["steps"], 20, "{rows}");
    // A cut log (no `/summary`) counts from `/run.first_step` too.
    let messages: Vec<(&str, Value)> = ["/run", "/energy", "/solver"].iter().flat_map(|t| record.messages(t).iter().map(move |m| (*t, m.clone()))).collect();
    let cut = dir.join("cut.mcap");
    write_log(&cut, &messages, false);
    let o = bifirst(&["summary", p(&cut), "--json"]);
    let rows: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((rows[0]["status"].as_str(), rows[0]["steps"].as_u64()), (Some("incomplete"), Some(20)), "{rows}");
}

/// A sweep of two variants into `dir`.
fn two_variant_sweep(dir: &Path) {
    let o = bifirst(&["sweep", p(&scene_path("sliding_block")), "--backend", "cpu", "--set", "time.end=0.01", "--over", "contact.friction=0.2,0.4", "--out", p(dir)]);
    assert!(o.status.success(), "{}", text(&o));
}

/// Caught: `sweep-report` believed `sweep.json`: swapped labels showed one variant's log under
/// the other's values, a copied stem counted one log twice, and a stem with `../` was looked up
/// outside the directory, all at exit 0.
#[test]
fn sweep_report_holds_the_record_and_the_logs_against_the_grid() {
    let dir = fresh_dir("report_trust");
    let sweep = dir.join("s");
    two_variant_sweep(&sweep);
    assert!(bifirst(&["sweep-report", p(&sweep)]).status.success());
    let manifest = sweep.join("sweep.json");
    let good = std::fs::read_to_string(&manifest).unwrap();
    let record: Value = serde_json::from_str(&good).unwrap();
    let edits: [(&str, Edit); 3] = [
        (
            "swapped labels",
            Box::new(|r: &mut Value| {
                let (a, b) = (r["variants"][0]["label"].clone(), r["variants"][1]["label"].clone());
                (r["variants"][0]["label"], r["variants"][1]["label"]) = (b, a);
            }),
        ),
        ("copied stem", Box::new(|r: &mut Value| r["variants"][1]["stem"] = r["variants"][0]["stem"].clone())),
        ("stem outside", Box::new(|r: &mut Value| r["variants"][0]["stem"] = "../../../../etc/passwd".into())),
    ];
    for (what, edit) in edits {
        let mut edited = record.clone();
        edit(&mut edited);
        std::fs::write(&manifest, serde_json::to_string(&edited).unwrap()).unwrap();
        let o = bifirst(&["sweep-report", p(&sweep)]);
        assert_eq!(exit_of(&o), 2, "{what}: {}", text(&o));
        assert!(text(&o).contains("it was edited"), "{what}: {}", text(&o));
    }
    // The record intact, the logs swapped: each log's own scene tells.
    std::fs::write(&manifest, &good).unwrap();
    let stems: Vec<PathBuf> = record["variants"].as_array().unwrap().iter().map(|v| sweep.join(format!("{}.mcap", v["stem"].as_str().unwrap()))).collect();
    let aside = sweep.join("aside");
    std::fs::rename(&stems[0], &aside).unwrap();
    std::fs::rename(&stems[1], &stems[0]).unwrap();
    std::fs::rename(&aside, &stems[1]).unwrap();
    let o = bifirst(&["sweep-report", p(&sweep), "--json"]);
    assert_ne!(exit_of(&o), 0, "{}", text(&o));
    let report: Value = serde_json::from_slice(&o.stdout).unwrap();
    for v in report["variants"].as_array().unwrap() {
        assert_eq!(v["status"], "mismatched", "{v}");
        assert!(v["message"].as_str().unwrap().contains("another variant's log"), "{v}");
    }
}

/// Writes `messages` as a log that bifirst's readers read; without its summary section and
/// footer unless `finished` (a log cut short).
fn write_log(path: &Path, messages: &[(&str, Value)], finished: bool) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new().profile("").create(file).unwrap();
    let mut channel = BTreeMap::new();
    for (sequence, (topic, message)) in messages.iter().enumerate() {
        if !channel.contains_key(topic) {
            let schema = w.add_schema(topic, "jsonschema", b"{}").unwrap();
            channel.insert(*topic, w.add_channel(schema, topic, "json", &BTreeMap::new()).unwrap());
        }
        let header = mcap::records::MessageHeader { channel_id: channel[topic], sequence: sequence as u32, log_time: 0, publish_time: 0 };
        w.write_to_known_channel(&header, &serde_json::to_vec(message).unwrap()).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    if !finished {
        let bytes = std::fs::read(path).unwrap();
        let footer_at = bytes.len() - 8 - 29;
        let summary_start = u64::from_le_bytes(bytes[footer_at + 9..footer_at + 17].try_into().unwrap()) as usize;
        std::fs::write(path, &bytes[..summary_start]).unwrap();
    }
}

/// A finished log of `/run` and the given `/state` messages.
fn log_with_states(path: &Path, run: &Value, states: &[Value]) {
    let messages: Vec<(&str, Value)> = std::iter::once(("/run", run.clone())).chain(states.iter().map(|s| ("/state", s.clone()))).collect();
    write_log(path, &messages, true);
}

/// Caught: a `/state` with `v[0] = 1e308` wrote `null` energies and `state` printed `kinetic
/// inf` at exit 0; a state at t = -5 ran 5 210 steps.
#[test]
fn a_state_out_of_range_is_refused() {
    let dir = fresh_dir("state_values");
    let log = sliding_log(&dir, 10);
    let record = bifirst::output::read_run(&log).unwrap();
    let (run, state) = (record.messages("/run")[0].clone(), record.messages("/state").last().unwrap().clone());
    let edits: [(&str, Edit, &str); 3] = [
        ("huge velocity", Box::new(|s: &mut Value| s["bodies"][0]["v"][0] = 1e308.into()), "kinetic energy is inf"),
        ("negative time", Box::new(|s: &mut Value| s["t"] = (-5.0).into()), "time t is -5"),
        ("huge displacement", Box::new(|s: &mut Value| s["bodies"][0]["u"][3] = 1e308.into()), "energy is"),
    ];
    let edited = dir.join("edited.mcap");
    for (what, edit, said) in edits {
        let mut s = state.clone();
        edit(&mut s);
        log_with_states(&edited, &run, &[s]);
        for args in [vec!["state", p(&edited)], vec!["run", "--restart", p(&edited), "--quiet", "--set", "time.end=0.02", "--out", p(&dir.join("c.mcap"))]] {
            let o = bifirst(&args);
            assert_eq!(exit_of(&o), 2, "{what}, {}: {}", args[0], text(&o));
            assert!(text(&o).contains(said), "{what}, {}: {}", args[0], text(&o));
        }
    }
    // The same log with the state as saved restarts: the edits were what was refused.
    log_with_states(&edited, &run, &[state]);
    assert!(bifirst(&["state", p(&edited)]).status.success());
}

/// Caught: with `--over contact.friction=0,0.5` the expected stopping distance was infinite,
/// the NaN error was dropped and that variant put on the front; `--target nan`, `--target -1`
/// and `--repeat 0` were accepted.
#[test]
fn accuracy_refuses_answers_and_arguments_it_cannot_measure_against() {
    let dir = fresh_dir("accuracy_nan");
    let scene = scene_path("sliding_block");
    let o = bifirst(&["accuracy", p(&scene), "--over", "contact.friction=0,0.5", "--out", p(&dir)]);
    assert_eq!(exit_of(&o), 2, "{}", text(&o));
    assert!(text(&o).contains("variant friction=0") && text(&o).contains("expected stopping distance is inf"), "{}", text(&o));
    for args in [["--target", "nan"], ["--target", "-1"], ["--repeat", "0"]] {
        let o = bifirst(&["accuracy", p(&scene), args[0], args[1], "--out", p(&dir)]);
        assert_eq!(exit_of(&o), 2, "{args:?}: {}", text(&o));
    }
}

/// Caught: an empty file, random bytes, a PNG or a TOML given as a log were asked whether they
/// were bifirst logs; a killed run's log without a state blamed an old bifirst; an unknown probe
/// in `plot --trace` asked whether the log was bifirst's; `--sbatch time` wrote `#SBATCH --time`.
#[test]
fn messages_say_what_is_wrong_once() {
    let dir = fresh_dir("messages");
    let mut rng = SmallRng::seed_from_u64(9);
    let png = std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("doc")).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|x| x == "png"));
    let mut foreign: Vec<(&str, Vec<u8>)> = vec![("empty", Vec::new()), ("random", (0..4096).map(|_| rng.random()).collect()), ("toml", std::fs::read(scene_path("sliding_block")).unwrap())];
    if let Some(png) = png {
        foreign.push(("png", std::fs::read(png).unwrap()));
    }
    let file = dir.join("foreign.mcap");
    for (what, bytes) in foreign {
        std::fs::write(&file, bytes).unwrap();
        for command in ["summary", "state", "plot"] {
            let o = bifirst(&[command, p(&file)]);
            assert!(matches!(exit_of(&o), 1 | 2), "{what}, {command}: {}", text(&o));
            assert!(text(&o).contains("is not an MCAP file"), "{what}, {command}: {}", text(&o));
        }
    }
    let log = sliding_log(&dir, 10);
    let o = bifirst(&["plot", p(&log), "--trace", "Z,Q,W", "--out", p(&dir.join("plots"))]);
    assert_eq!(exit_of(&o), 2, "{}", text(&o));
    assert!(text(&o).contains("logs no probe `Z`"), "{}", text(&o));
    let o = bifirst(&["sweep", p(&scene_path("sliding_block")), "--over", "contact.friction=0.2", "--slurm", p(&dir.join("job.sh")), "--sbatch", "time"]);
    assert_eq!(exit_of(&o), 2, "{}", text(&o));
    assert!(text(&o).contains("needs a value"), "{}", text(&o));
    assert!(bifirst(&["sweep", p(&scene_path("sliding_block")), "--over", "contact.friction=0.2", "--out", p(&dir.join("s")), "--slurm", p(&dir.join("job.sh")), "--sbatch", "exclusive"]).status.success());
    // A log cut before its first state: the run was cut short, not written by an old bifirst.
    let record = bifirst::output::read_run(&log).unwrap();
    let cut = dir.join("no_state.mcap");
    write_log(&cut, &[("/run", record.messages("/run")[0].clone())], false);
    let o = bifirst(&["run", "--restart", p(&cut)]);
    assert_eq!(exit_of(&o), 2, "{}", text(&o));
    assert!(text(&o).contains("the run was cut short before it logged one"), "{}", text(&o));
}

/// Caught: a killed run's last chunk kept the length placeholder 2^64 - 1, so the Python `mcap`
/// reader's default path (`make_reader(f).iter_messages()`) yielded nothing and raised. Chunks
/// are now written whole, each followed by a provisional footer.
#[test]
fn a_killed_runs_log_reads_in_the_python_readers_default_path() {
    let has_reader = Command::new("python3").args(["-c", "import mcap.reader"]).output().is_ok_and(|o| o.status.success());
    if !has_reader {
        eprintln!("skipped: python3 with the `mcap` package is not installed");
        return;
    }
    let dir = fresh_dir("killed_python");
    let killed = dir.join("killed.mcap");
    let mut child = Command::new(env!("CARGO_BIN_EXE_bifirst")).current_dir(env!("CARGO_MANIFEST_DIR")).args(["run", "scenes/bar_impact.toml", "--backend", "cpu", "--quiet", "--set", "time.end=100.0", "--out", p(&killed)]).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_secs(4));
    child.kill().unwrap();
    child.wait().unwrap();
    let script = "import sys\nfrom mcap.reader import make_reader\nwith open(sys.argv[1], 'rb') as f:\n    print(sum(1 for _ in make_reader(f).iter_messages()))";
    let o = Command::new("python3").args(["-c", script, p(&killed)]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let python: usize = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    let record = bifirst::output::read_run(&killed).unwrap();
    assert!(!record.has_summary, "the run was killed");
    let ours: usize = record.topics.values().map(Vec::len).sum();
    assert!(python > 100 && python == ours, "the Python reader reads {python} messages, bifirst {ours}");
}
