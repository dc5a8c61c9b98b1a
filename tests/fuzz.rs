//! Fuzzing the command line with mutated scenes: whatever a scene or a `--set` says, `check`
//! and `run` end with exit 0 (fine), 1 (the run failed) or 2 (bad input), never with a panic,
//! an abort or a hang. Seeded, so a failure names the case that reproduces it.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};
use toml::{Table, Value};

/// CI's draw; `BIFIRST_FUZZ_SEED` and `BIFIRST_FUZZ_CASES` explore others.
const SEED: u64 = 0xb1f1_2026;
const CASES: usize = 400;

fn setting(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}
/// One case in `RUN_EVERY` whose scene passes `check` is also run for two time steps.
const RUN_EVERY: usize = 2;
/// Longer than any check or two-step run of a shipped scene takes in the test profile.
const HANG: Duration = Duration::from_secs(30);
/// How long an interrupted run may take to stop.
const STOP: Duration = Duration::from_secs(10);

/// Values that broke parsers and solvers elsewhere: extremes, wrong types, wrong shapes.
fn nasty_value(rng: &mut SmallRng) -> Value {
    let choices: [fn() -> Value; 16] = [
        || Value::Float(0.0),
        || Value::Float(-1.0),
        || Value::Float(1e308),
        || Value::Float(-1e308),
        || Value::Float(1e-308),
        || Value::Float(f64::NAN),
        || Value::Float(f64::INFINITY),
        || Value::Integer(i64::MAX),
        || Value::Integer(i64::MIN),
        || Value::Integer(0),
        || Value::String(String::new()),
        || Value::String("no such thing".into()),
        || Value::Boolean(true),
        || Value::Array(Vec::new()),
        || Value::Array(vec![Value::Float(1e300); 3]),
        || Value::Table(Table::new()),
    ];
    let v = choices[rng.random_range(0..choices.len())]();
    // Sometimes a plausible number a few orders of magnitude off instead.
    if rng.random_bool(0.25) {
        Value::Float(10f64.powi(rng.random_range(-30..30)) * if rng.random_bool(0.2) { -1.0 } else { 1.0 })
    } else {
        v
    }
}

/// Text for the right-hand side of `--set KEY=VALUE`, well-formed or not.
fn nasty_text(rng: &mut SmallRng) -> String {
    const RAW: [&str; 10] = ["[", "1e999", "\"", "=", "[1, \"a\"]", "{ x = 1 }", "-0", "[[]]", "0x10", "nan"];
    if rng.random_bool(0.5) {
        RAW[rng.random_range(0..RAW.len())].to_string()
    } else {
        nasty_value(rng).to_string()
    }
}

/// Dotted paths of every leaf (array elements included) of a TOML table.
fn leaves(table: &Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in table {
        let path = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
        match v {
            Value::Table(t) => leaves(t, &path, out),
            Value::Array(a) => {
                out.push(path.clone());
                for (i, item) in a.iter().enumerate() {
                    match item {
                        Value::Table(t) => leaves(t, &format!("{path}.{i}"), out),
                        _ => out.push(format!("{path}.{i}")),
                    }
                }
            }
            _ => out.push(path),
        }
    }
}

/// The value at a dotted path, to replace or remove.
fn at<'a>(table: &'a mut Table, path: &str) -> Option<(&'a mut Value, String)> {
    let mut parts: Vec<&str> = path.split('.').collect();
    let last = parts.pop()?.to_string();
    let mut node = table.get_mut(*parts.first()?)?;
    for p in &parts[1..] {
        node = match node {
            Value::Table(t) => t.get_mut(*p)?,
            Value::Array(a) => a.get_mut(p.parse::<usize>().ok()?)?,
            _ => return None,
        };
    }
    Some((node, last))
}

/// One fuzz case: a scene text and its `--set` pairs.
struct Case {
    index: usize,
    base: String,
    scene: String,
    sets: Vec<String>,
    /// `time.end` for a two-step run, when the mutated scene still has a usable `dt`.
    short_end: Option<f64>,
}

fn mutate(index: usize, base: &str, text: &str, rng: &mut SmallRng) -> Case {
    let table: Table = text.parse().expect("shipped scenes parse");
    let mut paths = Vec::new();
    leaves(&table, "", &mut paths);
    let pick = |rng: &mut SmallRng| paths[rng.random_range(0..paths.len())].clone();
    let (mut scene, mut sets) = (text.to_string(), Vec::new());
    match rng.random_range(0..6) {
        // Replace one value, or several.
        0 | 1 => {
            let mut t = table.clone();
            for _ in 0..rng.random_range(1..4) {
                let path = pick(rng);
                let value = nasty_value(rng);
                match at(&mut t, &path) {
                    Some((Value::Table(parent), key)) => _ = parent.insert(key, value),
                    Some((Value::Array(parent), key)) => {
                        if let Some(slot) = key.parse::<usize>().ok().and_then(|i| parent.get_mut(i)) {
                            *slot = value;
                        }
                    }
                    _ => {}
                }
            }
            scene = toml::to_string(&t).expect("a table serializes");
        }
        // Remove a key, or add an unknown one next to it.
        2 => {
            let mut t = table.clone();
            let path = pick(rng);
            if let Some((Value::Table(parent), key)) = at(&mut t, &path) {
                if rng.random_bool(0.5) {
                    parent.remove(&key);
                } else {
                    parent.insert(format!("{key}_typo"), nasty_value(rng));
                }
            }
            scene = toml::to_string(&t).expect("a table serializes");
        }
        // Damage the text: cut it, drop or repeat a line, insert stray bytes.
        3 => {
            let mut lines: Vec<String> = text.lines().map(String::from).collect();
            let i = rng.random_range(0..lines.len());
            match rng.random_range(0..4) {
                0 => _ = lines.remove(i),
                1 => lines.insert(i, lines[i].clone()),
                2 => lines.insert(i, ["[[", "]", "= 1", "\u{0}", "[body.x.mesh]", "é = \"\\u{d800}\""][rng.random_range(0..6)].to_string()),
                _ => {
                    let mut cut = rng.random_range(0..text.len());
                    while !text.is_char_boundary(cut) {
                        cut -= 1;
                    }
                    lines = text[..cut].lines().map(String::from).collect();
                }
            }
            scene = lines.join("\n");
        }
        // `--set` pairs on a good scene: existing keys, array elements, unknown keys.
        _ => {
            for _ in 0..rng.random_range(1..4) {
                let key = if rng.random_bool(0.85) { pick(rng) } else { format!("{}.unknown", pick(rng)) };
                sets.push(format!("{key}={}", nasty_text(rng)));
            }
        }
    }
    let dt = scene.parse::<Table>().ok().and_then(|t| t.get("time")?.get("dt")?.as_float());
    let short_end = dt.filter(|dt| dt.is_finite() && *dt > 0.0).map(|dt| 2.0 * dt);
    Case { index, base: base.to_string(), scene, sets, short_end }
}

/// A command run in `dir`, so that outputs a mutated scene names land there.
fn bifirst(dir: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_bifirst"));
    command.current_dir(dir);
    command
}

/// Waits for the child at most `limit`; `None` when it is still running.
fn wait_for(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            return Some(status);
        }
        if start.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Runs one command to its end and returns its exit code and stderr. A command still running
/// after `HANG` gets SIGINT and must then stop within `STOP` (a run that is merely slow stops
/// with exit 130); one that does not is killed and reported as a hang.
fn outcome(mut command: Command, what: &str) -> (i32, String) {
    let err = std::env::temp_dir().join(format!("bifirst_fuzz_{}.stderr", what.replace(['/', ' '], "_")));
    let mut child = command.stdout(Stdio::null()).stderr(std::fs::File::create(&err).unwrap()).spawn().expect("bifirst starts");
    let status = wait_for(&mut child, HANG).or_else(|| {
        let _ = Command::new("kill").args(["-INT", &child.id().to_string()]).status();
        wait_for(&mut child, STOP)
    });
    let status = status.unwrap_or_else(|| {
        let _ = child.kill();
        panic!("{what}: still running {:?} after SIGINT", STOP)
    });
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    let _ = std::fs::remove_file(&err);
    let code = status.code().unwrap_or_else(|| panic!("{what}: killed by a signal ({status}); stderr: {stderr}"));
    (code, stderr)
}

/// What a case gave: `check`'s exit code, the run's when there was one, and any problem.
struct Outcome {
    check: i32,
    run: Option<i32>,
    problem: Option<String>,
}

fn check_case(case: &Case, dir: &Path) -> Outcome {
    let path = dir.join(format!("case_{:03}_{}", case.index, case.base));
    std::fs::write(&path, &case.scene).unwrap();
    let sets: Vec<String> = case.sets.iter().flat_map(|s| ["--set".to_string(), s.clone()]).collect();
    let what = format!("case {} (BIFIRST_FUZZ_SEED={}, {} mutated into {}, sets {:?})", case.index, setting("BIFIRST_FUZZ_SEED", SEED), case.base, path.display(), case.sets);
    let mut check = bifirst(dir);
    check.arg("check").arg(&path).args(&sets);
    let (code, stderr) = outcome(check, &format!("check {}", case.index));
    let mut problems = Vec::new();
    if !(0..=2).contains(&code) || stderr.contains("panicked") {
        problems.push(format!("{what}: check exited {code}: {stderr}"));
    }
    let mut run_code = None;
    if let (0, Some(end), 0) = (code, case.short_end, case.index % RUN_EVERY) {
        let out = dir.join(format!("case_{:03}.mcap", case.index));
        let mut run = bifirst(dir);
        run.arg("run").arg(&path).args(&sets).args(["--set", &format!("time.end={end:e}"), "--quiet", "--backend", "cpu", "--out"]).arg(&out);
        let (run_exit, stderr) = outcome(run, &format!("run {}", case.index));
        if !([0, 1, 2, 130].contains(&run_exit)) || stderr.contains("panicked") {
            problems.push(format!("{what}: run exited {run_exit}: {stderr}"));
        }
        run_code = Some(run_exit);
        let _ = std::fs::remove_file(&out);
    }
    // A failing case keeps its scene, to reproduce it.
    if problems.is_empty() {
        let _ = std::fs::remove_file(&path);
    }
    Outcome { check: code, run: run_code, problem: (!problems.is_empty()).then(|| problems.join("\n")) }
}

#[test]
fn mutated_scenes_and_sets_end_with_exit_0_1_or_2_never_a_panic_or_a_hang() {
    let scenes_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut bases: Vec<PathBuf> = std::fs::read_dir(&scenes_dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "toml")).collect();
    bases.sort();
    let texts: Vec<(String, String)> = bases.iter().map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read_to_string(p).unwrap())).collect();
    let mut rng = SmallRng::seed_from_u64(setting("BIFIRST_FUZZ_SEED", SEED));
    let count = setting("BIFIRST_FUZZ_CASES", CASES as u64) as usize;
    let cases: Vec<Case> = (0..count)
        .map(|i| {
            let (name, text) = &texts[rng.random_range(0..texts.len())];
            mutate(i, name, text, &mut rng)
        })
        .collect();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz");
    std::fs::create_dir_all(&dir).unwrap();
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get()).min(4);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let outcomes: Vec<Outcome> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                s.spawn(|| {
                    let mut found = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                        let Some(case) = cases.get(i) else { break found };
                        found.push(check_case(case, &dir));
                    }
                })
            })
            .collect();
        handles.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    let tally = |codes: Vec<i32>| (0..=2).map(|c| codes.iter().filter(|&&x| x == c).count()).collect::<Vec<_>>();
    println!("check exits 0/1/2: {:?}", tally(outcomes.iter().map(|o| o.check).collect()));
    println!("run exits 0/1/2: {:?}", tally(outcomes.iter().filter_map(|o| o.run).collect()));
    let failures: Vec<&String> = outcomes.iter().filter_map(|o| o.problem.as_ref()).collect();
    assert!(failures.is_empty(), "{} of {count} cases failed:\n{}", failures.len(), failures.iter().map(|f| f.as_str()).collect::<Vec<_>>().join("\n"));
}

/// The material blocks of the rubber models whose coefficients the targeted cases vary.
const RUBBERS: [&str; 4] = [
    "model = \"mooney_rivlin\"\nC10 = 400.0\nC01 = 100.0\nK = 2000.0",
    "model = \"yeoh\"\nC10 = 400.0\nC20 = -10.0\nC30 = 1.0\nK = 2000.0",
    "model = \"ogden\"\nmu = [630.0, 1.2, -10.0]\nalpha = [1.3, 5.0, -2.0]\nK = 2000.0",
    "model = \"arruda_boyce\"\nmu = 900.0\nlambda_m = 2.5\nK = 2000.0",
];

/// A number for a targeted key: the nasty values, and the edges the issues found.
fn edge_number(rng: &mut SmallRng) -> String {
    const EDGES: [&str; 10] = ["1e-90", "1e-60", "1e-50", "1e-30", "1e-300", "0.999999", "1e300", "-1e300", "nan", "-0.0"];
    if rng.random_bool(0.5) {
        EDGES[rng.random_range(0..EDGES.len())].to_string()
    } else {
        nasty_text(rng)
    }
}

/// A case aimed at the keys whose edges broke runs (issue 57): packing radii, Prony terms and
/// rubber coefficients.
fn targeted(index: usize, texts: &[(String, String)], rng: &mut SmallRng) -> Case {
    let text = |name: &str| texts.iter().find(|(n, _)| n == name).expect("a shipped scene").1.clone();
    let (base, scene, sets) = match rng.random_range(0..3) {
        0 => {
            let base = ["grains_many.toml", "grains_3d.toml"][rng.random_range(0..2)];
            let radius = format!("packing.radius=[{}, {}]", edge_number(rng), edge_number(rng));
            (base, text(base), vec!["packing.count=8".to_string(), radius])
        }
        1 => {
            let terms: Vec<String> = (0..rng.random_range(1..3)).map(|_| format!("{{ g = {}, tau = {} }}", edge_number(rng), edge_number(rng))).collect();
            ("relaxation.toml", text("relaxation.toml"), vec![format!("material.rubber.viscoelastic=[{}]", terms.join(", "))])
        }
        _ => {
            let rubber = RUBBERS[rng.random_range(0..RUBBERS.len())];
            let scene = text("relaxation.toml").replace("model = \"mooney_rivlin\"\nC10 = 400.0\nC01 = 100.0\nK = 2000.0", rubber);
            let keys: Vec<&str> = rubber.lines().skip(1).map(|l| l.split(" = ").next().unwrap()).collect();
            let key = keys[rng.random_range(0..keys.len())];
            let value = if rng.random_bool(0.3) && key != "K" { format!("[{}]", edge_number(rng)) } else { edge_number(rng) };
            ("relaxation.toml", scene, vec![format!("material.rubber.{key}={value}")])
        }
    };
    let short_end = scene.parse::<Table>().ok().and_then(|t| t.get("time")?.get("dt")?.as_float()).map(|dt| 2.0 * dt);
    Case { index, base: base.to_string(), scene, sets, short_end }
}

#[test]
fn edges_of_radii_prony_terms_rubber_coefficients_and_command_line_values_never_panic_or_hang() {
    let scenes_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let texts: Vec<(String, String)> = ["grains_many.toml", "grains_3d.toml", "relaxation.toml"].iter().map(|n| (n.to_string(), std::fs::read_to_string(scenes_dir.join(n)).unwrap())).collect();
    let mut rng = SmallRng::seed_from_u64(setting("BIFIRST_FUZZ_SEED", SEED) ^ 0x57);
    let count = setting("BIFIRST_FUZZ_CASES", CASES as u64) as usize / 8;
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz_edges");
    std::fs::create_dir_all(&dir).unwrap();
    let mut failures: Vec<String> = (0..count).map(|i| targeted(i, &texts, &mut rng)).filter_map(|case| check_case(&case, &dir).problem).collect();
    // The command-line values: each ends with exit 0 (accepted), 1 (a variant did not finish)
    // or 2 (refused), promptly.
    let bar = scenes_dir.join("bar_impact.toml");
    let bar = bar.to_str().unwrap();
    let study = ["--set", "time.end=5e-4", "--over", "time.dt=5e-5"];
    for flag in ["--threads", "--max-wall", "--max-sweeps", "--repeat"] {
        let mut values: Vec<String> = ["nan", "-1", "0", "1e308", "inf", "100000", "3"].iter().map(|v| v.to_string()).collect();
        values.extend((0..4).map(|_| nasty_text(&mut rng)));
        for value in values {
            let mut command = bifirst(&dir);
            match flag {
                "--threads" => command.args([flag, &value, "check", bar]),
                "--repeat" => command.args(["accuracy", bar]).args(study).args([flag, &value]),
                _ => command.args(["stability", bar]).args(study).args([flag, &value]),
            };
            let what = format!("{flag} {value:?}");
            let (code, stderr) = outcome(command, &what);
            if !(0..=2).contains(&code) || stderr.contains("panicked") {
                failures.push(format!("{what}: exited {code}: {stderr}"));
            }
        }
    }
    assert!(failures.is_empty(), "{} cases failed:\n{}", failures.len(), failures.join("\n"));
}
