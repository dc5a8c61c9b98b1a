//! Outputs that users open in their own tools: VTU/PVD (ParaView), the Foxglove messages in the
//! MCAP, PNG plots, and the log that survives a failure or an interrupt.

#[path = "common/run.rs"]
mod common_run;

use bifirst::output::{plot, read_run, summary};
use bifirst::run::{run_scene, RunOptions, Silent};
use bifirst::scene::load_scene;
use common_run::{scene_path, temp_path};
use serde_json::Value;
use std::path::{Path, PathBuf};
use vtkio::model::{Attribute, DataSet, Vtk};

/// Runs a scene with VTU output into `<tag>.mcap` and `<tag>_vtu/`.
fn run_with_vtu(scene: &str, sets: &[&str], tag: &str) -> (PathBuf, PathBuf) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = load_scene(&scene_path(scene), &sets).expect("scene loads");
    let (out, dir) = (temp_path(&format!("{tag}.mcap")), temp_path(&format!("{tag}_vtu")));
    let _ = std::fs::remove_dir_all(&dir);
    run_scene(&loaded, &out, &RunOptions { vtu: Some(dir.clone()), ..Default::default() }, &mut Silent).expect("run succeeds");
    (out, dir)
}

/// The `file` entries of a `.pvd` collection.
fn pvd_files(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).expect("pvd exists");
    text.lines().filter_map(|l| l.split("file=\"").nth(1)).map(|f| f.trim_end_matches("\"/>").to_string()).collect()
}

struct Grid {
    points: Vec<f64>,
    cells: usize,
    point_data: Vec<(String, usize, Vec<f64>)>,
    cell_data: Vec<(String, usize, Vec<f64>)>,
}

fn arrays(attributes: &[Attribute]) -> Vec<(String, usize, Vec<f64>)> {
    attributes
        .iter()
        .map(|a| match a {
            Attribute::DataArray(d) => (d.name.clone(), d.num_comp(), d.data.cast_into::<f64>().expect("numeric")),
            Attribute::Field { name, .. } => panic!("unexpected field data {name}"),
        })
        .collect()
}

fn read_vtu(path: &Path) -> Grid {
    let vtk = Vtk::import(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else { panic!("an unstructured grid") };
    let piece = pieces.into_iter().next().expect("one piece").into_loaded_piece_data(None).expect("inline piece");
    Grid { points: piece.points.cast_into::<f64>().expect("f64 points"), cells: piece.cells.types.len(), point_data: arrays(&piece.data.point), cell_data: arrays(&piece.data.cell) }
}

fn names(a: &[(String, usize, Vec<f64>)]) -> Vec<(&str, usize)> {
    a.iter().map(|(n, c, _)| (n.as_str(), *c)).collect()
}

#[test]
fn vtu_frames_of_a_2d_and_a_3d_scene_read_back_with_their_arrays() {
    for (scene, sets, body, every) in [("sliding_block", &["time.end=0.02", "output.vtu_every=5"][..], "block", 5), ("stack_3d", &["time.end=0.03"][..], "upper", 1)] {
        let (out, dir) = run_with_vtu(scene, sets, &format!("vtu_{scene}"));
        let loaded = load_scene(&scene_path(scene), &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
        let sim = bifirst::solver::build_simulation(&loaded).unwrap();
        let b = sim.bodies().iter().find(|b| b.name() == body).expect("body");
        let (nodes, elements) = (b.mesh().nodes.len(), b.mesh().element_count());
        let files = pvd_files(&dir.join(format!("{body}.pvd")));
        let frames = sim.step_count().div_ceil(every) + 1;
        assert_eq!(files.len(), frames, "{scene}: one frame per cadence plus the start");
        assert_eq!(pvd_files(&dir.join("contact_points.pvd")).len(), frames);
        let last = read_vtu(&dir.join(files.last().unwrap()));
        assert_eq!(last.points.len(), 3 * nodes);
        assert_eq!(last.cells, elements);
        assert_eq!(names(&last.point_data), [("displacement", 3), ("velocity", 3)]);
        assert_eq!(names(&last.cell_data), [("von_mises", 1), ("cauchy_stress", 9), ("J", 1)]);
        // Points are the current positions: reference + displacement.
        let u = &last.point_data[0].2;
        for n in 0..nodes {
            for i in 0..3 {
                assert!((last.points[3 * n + i] - u[3 * n + i] - b.mesh().nodes[n][i]).abs() < 1e-12);
            }
        }
        let (vm, sigma, j) = (&last.cell_data[0].2, &last.cell_data[1].2, &last.cell_data[2].2);
        assert!(vm.iter().all(|v| v.is_finite() && *v >= 0.0) && vm.iter().any(|v| *v > 0.0), "{scene}: von Mises");
        assert!(j.iter().all(|j| (0.5..2.0).contains(j)), "{scene}: J");
        // The Cauchy stress is symmetric.
        for s in sigma.chunks(9) {
            assert!((s[1] - s[3]).abs() <= 1e-9 * s.iter().fold(1.0, |m, x| f64::max(m, x.abs())));
        }
        let contact = read_vtu(&dir.join(pvd_files(&dir.join("contact_points.pvd")).last().unwrap()));
        assert!(contact.cells > 0, "{scene}: contact points at the end");
        assert_eq!(contact.cells * 3, contact.points.len());
        assert_eq!(names(&contact.point_data), [("gap", 1), ("normal", 3), ("normal_reaction", 1), ("tangential_reaction", 3), ("status", 1)]);
        let status = &contact.point_data[4].2;
        assert!(status.iter().all(|s| [0.0, 1.0, 2.0].contains(s)));
        assert!(contact.point_data[2].2.iter().all(|r| *r >= 0.0), "compressive normal reactions");
        assert!(read_run(&out).unwrap().has_summary);
    }
}

/// Caught in bar_impact: 31 of its contact frames, those before the impact, had no
/// `NumberOfPoints` and `NumberOfCells` (vtkio leaves out zeros), which the VTK XML format requires.
#[test]
fn an_empty_contact_frame_states_its_zero_counts() {
    let (_, dir) = run_with_vtu("bar_impact", &["time.end=0.001"], "vtu_empty_contact");
    let first = dir.join(&pvd_files(&dir.join("contact_points.pvd"))[0]);
    let xml = std::fs::read_to_string(&first).unwrap();
    assert!(xml.contains(r#"<Piece NumberOfPoints="0" NumberOfCells="0">"#), "{}", &xml[..xml.len().min(300)]);
    let grid = read_vtu(&first);
    assert_eq!((grid.points.len(), grid.cells), (0, 0));
    assert_eq!(names(&grid.point_data), [("gap", 1), ("normal", 3), ("normal_reaction", 1), ("tangential_reaction", 3), ("status", 1)]);
}

/// Keys of a message object that its schema does not define, and schema properties the message
/// lacks (the Foxglove schemas allow extra keys, so validation alone would miss a misspelling).
fn strict_mismatches(message: &Value, schema: &Value, at: &str, out: &mut Vec<String>) {
    match (message, schema.get("properties").and_then(Value::as_object)) {
        (Value::Object(m), Some(props)) => {
            for (k, v) in m {
                match props.get(k) {
                    Some(s) => strict_mismatches(v, s, &format!("{at}.{k}"), out),
                    None => out.push(format!("{at}.{k} is not in the schema")),
                }
            }
            out.extend(props.keys().filter(|k| !m.contains_key(*k)).map(|k| format!("{at}.{k} is missing")));
        }
        (Value::Array(items), _) => {
            if let Some(s) = schema.get("items") {
                for (i, v) in items.iter().enumerate() {
                    strict_mismatches(v, s, &format!("{at}[{i}]"), out);
                }
            }
        }
        _ => {}
    }
}

fn official_schema(file: &str) -> Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/output/foxglove").join(file);
    serde_json::from_str(&std::fs::read_to_string(path).expect("schema copy")).expect("schema JSON")
}

/// `bar_impact` with its wall as a solid box instead of a plane.
fn run_box_wall() -> common_run::Log {
    let text = std::fs::read_to_string(scene_path("bar_impact")).unwrap();
    let plane = "shape = \"plane\"\npoint = [0.0, 0.0]\nnormal = [1.0, 0.0]";
    assert!(text.contains(plane));
    let scene = temp_path("box_wall.toml");
    std::fs::write(&scene, text.replace(plane, "shape = \"box\"\nmin = [-1.0, -1.0]\nmax = [0.0, 1.0]")).unwrap();
    let loaded = load_scene(&scene, &["time.end=0.0005".to_string()]).unwrap();
    let out = temp_path("fox_box.mcap");
    run_scene(&loaded, &out, &RunOptions::default(), &mut Silent).expect("runs");
    common_run::read_log(&out)
}

#[test]
fn foxglove_messages_validate_against_the_official_schemas() {
    let mut schemas = boon::Schemas::new();
    let mut compiler = boon::Compiler::new();
    let mut index = std::collections::BTreeMap::new();
    for (name, file) in [("foxglove.SceneUpdate", "SceneUpdate.json"), ("foxglove.Log", "Log.json")] {
        let url = format!("file:///{file}");
        compiler.add_resource(&url, official_schema(file)).unwrap();
        index.insert(name, (compiler.compile(&url, &mut schemas).unwrap(), official_schema(file)));
    }
    // 2D with an obstacle and friction; 3D with two bodies and a floor; a container box and a
    // polygon; a Newton failure for the log lines.
    let runs = [common_run::run("sliding_block", &["time.end=0.05"], "fox_2d"), common_run::run("stack_3d", &["time.end=0.05"], "fox_3d"), run_box_wall()];
    let mut checked = std::collections::BTreeMap::<&str, usize>::new();
    for log in &runs {
        for (topic, messages) in &log.topics {
            let Some((schema_name, _)) = log.schemas.get(topic) else { continue };
            let Some((id, schema)) = index.get(schema_name.as_str()) else { continue };
            for m in messages {
                if let Err(e) = schemas.validate(m, *id) {
                    panic!("{topic}: {e:#}");
                }
                let mut wrong = Vec::new();
                strict_mismatches(m, schema, topic, &mut wrong);
                assert!(wrong.is_empty(), "{wrong:?}");
                *checked.entry(schema_name.as_str()).or_default() += 1;
            }
        }
    }
    assert!(checked["foxglove.SceneUpdate"] > 20, "{checked:?}");
    // What the view shows: 2D boundaries as line lists, 3D boundaries as triangles, obstacles,
    // and contact forces as arrows once the bodies touch.
    let last = |log: &common_run::Log| log.topics["/scene"].last().unwrap()["entities"].as_array().unwrap().clone();
    let entity = |entities: &[Value], id: &str| entities.iter().find(|e| e["id"] == id).unwrap_or_else(|| panic!("entity {id}")).clone();
    let two = last(&runs[0]);
    let block = entity(&two, "body/block");
    // One line list per colour level, each node once in it, the segments as index pairs.
    let levels = block["lines"].as_array().unwrap();
    assert!(levels.iter().all(|l| l["type"] == 2 && l["colors"].as_array().unwrap().is_empty()), "one colour per level");
    let segments: usize = levels.iter().map(|l| l["indices"].as_array().unwrap().len() / 2).sum();
    assert_eq!(segments, 24, "the 24 boundary segments of the 8x4 block");
    let points: usize = levels.iter().map(|l| l["points"].as_array().unwrap().len()).sum();
    assert!((24..48).contains(&points), "the 24 boundary nodes, shared by the segments of a level ({points} points)");
    assert!(!entity(&two, "contact_forces")["arrows"].as_array().unwrap().is_empty());
    assert_eq!(entity(&two, "obstacle/floor")["lines"][0]["points"].as_array().unwrap().len(), 2);
    let three = last(&runs[1]);
    let top = entity(&three, "body/upper");
    assert!(top["triangles"].as_array().unwrap().iter().all(|l| l["indices"].as_array().unwrap().len() % 3 == 0), "whole triangles");
    assert!(!entity(&three, "contact_forces")["arrows"].as_array().unwrap().is_empty());
    assert_eq!(entity(&three, "obstacle/floor")["triangles"][0]["points"].as_array().unwrap().len(), 6);
    let boxed = last(&runs[2]);
    assert_eq!(entity(&boxed, "obstacle/wall")["lines"][0]["type"], 1, "a 2D box is a closed loop");
    // Arrows end at the contact point: tail + length along the pose's x axis.
    let arrow = &entity(&two, "contact_forces")["arrows"][0];
    assert!(arrow["shaft_length"].as_f64().unwrap() >= 0.0 && arrow["head_length"].as_f64().unwrap() > 0.0);
}

#[test]
fn plots_of_a_real_run_are_non_trivial_pngs_and_overlay_several_runs() {
    let a = common_run::run("free_vibration_2d", &["time.end=0.05"], "plot_a");
    let b = common_run::run("free_vibration_2d", &["time.end=0.05", "time.theta=0.6"], "plot_b");
    let dir = temp_path("plots");
    let _ = std::fs::remove_dir_all(&dir);
    let files = plot::plot_runs(&[a.record.clone(), b.record.clone()], &dir, &Default::default()).expect("plots");
    let names: Vec<String> = files.iter().map(|f| f.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, ["energies.png", "solver.png", "probe_tip.png"]);
    for file in &files {
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(file).unwrap()));
        let mut reader = decoder.read_info().expect("a PNG");
        let mut pixels = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut pixels).expect("decodes");
        assert!(info.width >= 1000 && info.height >= 700, "{}: {}x{}", file.display(), info.width, info.height);
        // Lines in both runs' colours (blue, orange) and text, not a blank canvas.
        let rgb: Vec<&[u8]> = pixels.chunks(info.line_size / info.width as usize).collect();
        let has = |c: [u8; 3]| rgb.iter().any(|p| p[..3] == c);
        assert!(has([31, 119, 180]) && has([255, 127, 14]), "{}: both runs drawn", file.display());
        let dark = rgb.iter().filter(|p| p[0] < 80 && p[1] < 80 && p[2] < 80).count();
        assert!(dark > 2000, "{}: labels drawn ({dark} dark pixels)", file.display());
        assert!(std::fs::metadata(file).unwrap().len() > 20_000);
    }
}

#[test]
fn summary_reports_the_totals_of_a_run() {
    let log = common_run::run("bar_impact", &["time.end=0.002"], "summary_bar");
    let s = summary::summarize(&log.record).unwrap();
    assert_eq!((s.status.as_str(), s.steps), ("finished", 40));
    let solver = &log.topics["/solver"];
    assert_eq!(s.newton_iterations, solver.iter().map(|m| m["newton_iterations"].as_u64().unwrap()).sum::<u64>());
    assert!(s.max_penetration > 0.0 && s.max_penetration == log.series("/contact", "max_penetration").into_iter().fold(0.0, f64::max));
    let energy = log.series("/energy", "total");
    assert_eq!(s.energy_drift, energy.last().unwrap() - energy[0]);
    let table = summary::table(&[s.clone(), s]);
    assert!(table.lines().any(|l| l.starts_with("Newton iterations")) && table.contains("wall s, contact"), "{table}");
}

fn bifirst() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_bifirst"))
}

#[test]
fn quiet_json_run_prints_only_the_machine_readable_summary() {
    let out = temp_path("cli_json.mcap");
    let result = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=0.001", "--quiet", "--json", "--out"]).arg(&out).output().unwrap();
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    assert!(result.stderr.is_empty(), "quiet: {}", String::from_utf8_lossy(&result.stderr));
    let summary: Value = serde_json::from_slice(&result.stdout).expect("stdout is JSON");
    assert_eq!((summary["status"].as_str(), summary["steps"].as_u64()), (Some("finished"), Some(20)));
    let table = bifirst().args(["summary", "--json"]).arg(&out).output().unwrap();
    let rows: Value = serde_json::from_slice(&table.stdout).expect("summary --json");
    assert_eq!(rows[0]["steps"], 20);
    let missing = bifirst().args(["summary", "no/such/run.mcap"]).output().unwrap();
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("no/such/run.mcap"));
}

#[test]
fn summary_tells_apart_two_runs_of_one_scene_by_file_and_backend() {
    let run = |backend: &str| {
        let out = temp_path(&format!("summary_{backend}.mcap"));
        let result = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=0.0005", "--quiet", "--backend", backend, "--out"]).arg(&out).output().unwrap();
        assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
        out
    };
    let (cpu, gpu) = (run("cpu"), run("gpu"));
    let table = bifirst().arg("summary").arg(&cpu).arg(&gpu).output().unwrap();
    let text = String::from_utf8_lossy(&table.stdout);
    let row = |label: &str| text.lines().find(|l| l.starts_with(label)).unwrap_or_else(|| panic!("no {label} row:\n{text}")).to_string();
    let files = row("file");
    assert!(files.contains(cpu.to_str().unwrap()) && files.contains(gpu.to_str().unwrap()), "{text}");
    let backend_row = row("backend, precision");
    let backends: Vec<&str> = backend_row.split("  ").map(str::trim).filter(|c| !c.is_empty()).skip(1).collect();
    // The GPU run's precision is the adapter's (f64 on lavapipe, f32 on an adapter without it).
    assert!(backends.len() == 2 && backends[0] == "cpu f64" && backends[1].starts_with("gpu f"), "{text}");
    assert!(text.contains("adapter ") && text.lines().any(|l| l.starts_with("wall s, transfer")), "{text}");
}

/// Starts a long run, waits until it has logged some steps, sends `signal`, and reads the log.
fn interrupt_run(signal: &str, tag: &str, code: i32) -> common_run::Log {
    use std::io::{BufRead, BufReader};
    let out = temp_path(&format!("{tag}.mcap"));
    let mut child = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=100.0", "--out"]).arg(&out).stderr(std::process::Stdio::piped()).spawn().unwrap();
    // Set-up takes well under a second; after two more, thousands of steps are done.
    std::thread::sleep(std::time::Duration::from_secs(2));
    let lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let kill = std::process::Command::new("kill").args([&format!("-{signal}"), &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(code), "{rest:?}");
    assert!(rest.iter().any(|l| l.contains("interrupted")), "{rest:?}");
    common_run::read_log(&out)
}

#[test]
fn sigint_sigterm_and_sighup_stop_a_run_with_a_complete_log() {
    // SIGHUP (a closed terminal) was caught by the issue: it killed the run with no summary.
    for (signal, tag, code) in [("INT", "sigint", 130), ("TERM", "sigterm", 130), ("HUP", "sighup", 129)] {
        let log = interrupt_run(signal, tag, code);
        let last = log.topics["/solver"].last().unwrap();
        assert_eq!(last["status"], "interrupted", "{signal}");
        let summary = &log.topics["/summary"][0];
        assert_eq!(summary["status"], "interrupted");
        let steps = summary["steps"].as_u64().unwrap() as usize;
        assert!(steps > 10, "{signal}: {steps} steps");
        // Every finished step is in the log, and the last one's frame too.
        assert_eq!(log.topics["/energy"].len(), steps + 1);
        let last_scene = log.topics["/scene"].last().unwrap()["entities"][0]["timestamp"].clone();
        let t = log.topics["/energy"].last().unwrap()["t"].as_f64().unwrap();
        let ns = (t * 1e9).round() as u64;
        assert_eq!((last_scene["sec"].as_u64().unwrap(), last_scene["nsec"].as_u64().unwrap()), (ns / 1_000_000_000, ns % 1_000_000_000));
        assert_eq!(log.topics["/log"].last().unwrap()["level"], 3);
    }
}

/// Caught by the issue: a step that never finishes (a fine sliding block, cut back again and
/// again with thousands of Uzawa sweeps per Newton iteration) ignored SIGINT for 90 s, since
/// the flag was read between steps only. Now Newton, the cut-backs and the Uzawa sweeps read it,
/// and the run stops within a Newton iteration with its log closed.
#[test]
fn an_interrupt_stops_a_step_that_never_finishes() {
    let out = temp_path("interrupt_in_step.mcap");
    let mut child = bifirst().args(["run", scene_path("sliding_block").to_str().unwrap(), "--set", "body.block.mesh.divisions=[800,4]", "--quiet", "--out"]).arg(&out).spawn().unwrap();
    // Set-up takes well under a second; the first step alone takes minutes.
    std::thread::sleep(std::time::Duration::from_secs(3));
    assert!(child.try_wait().unwrap().is_none(), "the first step is still running");
    let sent = std::time::Instant::now();
    assert!(std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if sent.elapsed().as_secs() > 20 {
            child.kill().unwrap();
            panic!("SIGINT was not honoured within 20 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    assert_eq!(status.code(), Some(130));
    let log = common_run::read_log(&out);
    let summary = &log.topics["/summary"][0];
    assert_eq!((summary["status"].as_str(), summary["steps"].as_u64()), (Some("interrupted"), Some(0)));
    assert_eq!(log.topics["/solver"].last().unwrap()["status"], "interrupted");
}

/// Caught by the issue: two runs given the same `--out` both exited 0 and left an unreadable
/// file. The second now fails at once (exit 1, naming the file) and the first one's log is
/// whole.
#[test]
fn a_second_run_on_the_same_output_fails_and_leaves_the_first_log_whole() {
    let out = temp_path("same_out.mcap");
    let mut first = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=100.0", "--quiet", "--out"]).arg(&out).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_secs(2));
    let second = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=0.001", "--quiet", "--out"]).arg(&out).output().unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains(&format!("`{}` is being written by another bifirst run", out.display())), "{stderr}");
    assert!(std::process::Command::new("kill").args(["-INT", &first.id().to_string()]).status().unwrap().success());
    assert_eq!(first.wait().unwrap().code(), Some(130));
    let log = common_run::read_log(&out);
    let summary = &log.topics["/summary"][0];
    assert_eq!(summary["status"], "interrupted");
    assert_eq!(log.topics["/energy"].len() as u64, summary["steps"].as_u64().unwrap() + 1, "every finished step is there");
}

/// Caught by the issue: after SIGKILL (or a crash) `summary` and `plot` refused the log
/// ("Chunk ended in the middle of a record", exit 2) and skipped the good files given with it.
/// Now the log is read up to the cut and reported `incomplete`, and an unreadable file is named
/// while the others are still summarised.
#[test]
fn a_killed_run_is_summarised_as_incomplete_next_to_good_files() {
    let killed = temp_path("killed.mcap");
    let mut child = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=100.0", "--quiet", "--out"]).arg(&killed).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_secs(3));
    child.kill().unwrap();
    child.wait().unwrap();
    let good = temp_path("good_next_to_killed.mcap");
    assert!(bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=0.001", "--quiet", "--out"]).arg(&good).status().unwrap().success());
    let missing = temp_path("no_such_run.mcap");
    let out = bifirst().args(["summary", "--json"]).arg(&killed).arg(&missing).arg(&good).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "one file could not be read: {stderr}");
    assert!(stderr.contains("no_such_run.mcap") && !stderr.contains("killed.mcap"), "{stderr}");
    let rows: Value = serde_json::from_slice(&out.stdout).expect("the readable files are summarised");
    assert_eq!(rows.as_array().unwrap().len(), 2);
    assert_eq!(rows[0]["status"], "incomplete");
    assert!(rows[0]["steps"].as_u64().unwrap() > 0, "{}", rows[0]);
    assert_eq!((rows[1]["status"].as_str(), rows[1]["steps"].as_u64()), (Some("finished"), Some(20)));
}

/// A log cut at every 4 KiB boundary (a crash can stop the writer anywhere) reads back every
/// message of the chunks that were complete before the cut (and the whole messages the reader
/// can decompress from the chunk the cut went through), and nothing else: the messages are the
/// full log's, in order, and a later cut never gives fewer.
#[test]
fn a_log_cut_at_any_4_kib_boundary_gives_every_message_of_its_complete_chunks() {
    let full = temp_path("to_cut.mcap");
    let status = bifirst().args(["run", scene_path("bar_impact").to_str().unwrap(), "--set", "time.end=0.02", "--set", "output.scene_every=0", "--quiet", "--out"]).arg(&full).status().unwrap();
    assert!(status.success());
    let bytes = std::fs::read(&full).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a finished log");
    let chunks: Vec<(usize, usize)> = summary.chunk_indexes.iter().map(|c| ((c.chunk_start_offset + c.chunk_length) as usize, summary.stream_chunk(&bytes, c).unwrap().count())).collect();
    assert!(chunks.len() >= 2, "the log spans several chunks: {chunks:?}");
    let whole = bifirst::output::read_run(&full).unwrap();
    let cut_path = temp_path("cut.mcap");
    let mut before = 0;
    for cut in (4096..bytes.len()).step_by(4096) {
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        let record = bifirst::output::read_run(&cut_path).unwrap_or_else(|e| panic!("cut at {cut}: {e}"));
        assert!(!record.has_summary);
        let complete: usize = chunks.iter().filter(|(end, _)| *end <= cut).map(|(_, n)| n).sum();
        let read: usize = record.topics.values().map(Vec::len).sum();
        assert!(read >= complete && read >= before, "cut at {cut}: {read} messages, {complete} in complete chunks, {before} at the last cut");
        before = read;
        for (topic, messages) in &record.topics {
            assert_eq!(messages[..], whole.topics[topic][..messages.len()], "cut at {cut}: {topic}");
        }
    }
}

/// Caught by `--out /dev/full`: the MCAP writer panicked in its destructor after the first
/// failed write and the process aborted (exit 134). A full disk is a failed run (exit 1) that
/// names the file.
#[test]
fn a_full_disk_is_a_failed_run_not_a_panic() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["run", scene_path("bar_impact").to_str().unwrap(), "--backend", "cpu", "--quiet", "--out", "/dev/full"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("`/dev/full`") && !stderr.contains("panicked"), "{stderr}");
}

/// Caught by `bifirst info | head -1`: `println!` panicked on the closed pipe. Now the command
/// ends quietly, as other tools do (SIGPIPE).
#[test]
fn a_closed_stdout_ends_a_command_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_bifirst")).arg("info").stdout(writer).stderr(std::process::Stdio::piped()).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.signal(), Some(13), "ended by SIGPIPE: {:?}", out.status);
}

/// Caught in review: the summary of a log without `/summary` (a killed run) reported 0 steps
/// creating energy whatever the run did. They are now counted from `/energy` by the run's own
/// rule, which gives the run's count when every step is logged.
#[test]
fn an_incomplete_log_counts_the_steps_that_created_energy_as_the_run_did() {
    let fast = common_run::run("bar_impact", &["body.bar.initial_velocity=[-25.0, 0.0]", "time.end=0.01", "output.scene_every=0", "solver.max_step_energy_gain=inf"], "energy_gain_fast_bar");
    let finished = bifirst::output::summary::summarize(&fast.record).unwrap();
    assert!(finished.energy_gain_steps > 0, "at 50 times its speed the bar impact creates energy in some steps");
    let mut cut = fast.record.clone();
    cut.topics.remove("/summary");
    let incomplete = bifirst::output::summary::summarize(&cut).unwrap();
    assert_eq!(incomplete.status, "incomplete");
    assert_eq!(incomplete.energy_gain_steps, finished.energy_gain_steps);
}
