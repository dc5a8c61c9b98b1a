//! The MCAP run log read back: every channel of the contract (doc/mcap.md), its schema, its
//! field names, and one message per step.

#[path = "common/run.rs"]
mod common_run;
use common_run::run;
use serde_json::Value;

fn schema_fields(schema: &Value) -> Vec<String> {
    let mut f: Vec<String> = schema["properties"].as_object().expect("object schema").keys().cloned().collect();
    f.sort();
    f
}

fn message_fields(m: &Value) -> Vec<String> {
    let mut f: Vec<String> = m.as_object().expect("object message").keys().cloned().collect();
    f.sort();
    f
}

fn sorted(v: &[&str]) -> Vec<String> {
    let mut v: Vec<String> = v.iter().map(|s| s.to_string()).collect();
    v.sort();
    v
}

#[test]
fn run_log_has_every_channel_of_the_contract() {
    let log = run("uniaxial_blatz_ko", &["time.end=0.1"], "contract");
    let steps = 10;
    let expected: &[(&str, &str, &[&str], usize)] = &[
        ("/run", "bifirst.Run", &["version", "git_revision", "scene_name", "scene", "scene_file", "backend", "precision", "adapter", "first_step", "batched_bodies", "body_names", "obstacle_names"], 1),
        ("/energy", "bifirst.Energy", &["t", "kinetic", "strain", "potential", "external_work", "friction_dissipation", "viscous_dissipation", "numerical_dissipation", "contact_correction", "total", "energy_balance_error"], steps + 1),
        (
            "/solver",
            "bifirst.Solver",
            &[
                "t",
                "step",
                "dt",
                "newton_iterations",
                "uzawa_iterations",
                "contact_newton_iterations",
                "bodies_iterated",
                "device_iterations",
                "factorizations",
                "residual_norm",
                "cutbacks",
                "substeps",
                "overlap_retries",
                "energy_retries",
                "raised_theta",
                "kept_beyond_bounds",
                "wall_s",
                "bytes_moved",
                "bytes_up",
                "device_submits",
                "status",
                "message",
            ],
            steps,
        ),
        ("/body/cube", "bifirst.Body", &["t", "mass", "center_of_mass", "linear_momentum", "angular_momentum", "kinetic"], steps + 1),
        ("/probe/corner", "bifirst.Probe", &["t", "position", "displacement", "velocity", "von_mises"], steps + 1),
        ("/reaction/pull", "bifirst.Reaction", &["t", "force"], steps + 1),
        ("/reaction/sym_x", "bifirst.Reaction", &["t", "force"], steps + 1),
        (
            "/summary",
            "bifirst.Summary",
            &[
                "scene",
                "status",
                "message",
                "backend",
                "precision",
                "adapter",
                "steps",
                "last_step",
                "t_end",
                "cutbacks",
                "newton_iterations",
                "uzawa_iterations",
                "contact_newton_iterations",
                "bodies_iterated",
                "device_iterations",
                "factorizations",
                "max_penetration",
                "max_overlap",
                "max_overlap_ratio",
                "energy_gain_steps",
                "max_energy_gain",
                "overlap_retries",
                "energy_retries",
                "kept_beyond_bounds",
                "energy_created",
                "wall_s",
                "wall_by_phase",
                "bytes_moved",
                "device_submits",
                "kernel_times",
                "energy",
                "output",
            ],
            1,
        ),
        // Short runs draw the 3D view at every step (about 100 frames per run).
        ("/scene", "foxglove.SceneUpdate", &["deletions", "entities"], steps + 1),
    ];
    for (topic, schema_name, fields, count) in expected {
        let (name, schema) = log.schemas.get(*topic).unwrap_or_else(|| panic!("channel {topic} missing"));
        assert_eq!(name, schema_name);
        if !schema_name.starts_with("foxglove.") {
            assert_eq!(schema_fields(schema), sorted(fields), "{topic} schema fields");
        }
        let messages = &log.topics[*topic];
        assert_eq!(messages.len(), *count, "{topic}: one message per step (plus the initial state)");
        for m in messages {
            assert_eq!(message_fields(m), sorted(fields), "{topic} message fields");
        }
    }
    // Foxglove users find /log in every run: the start and, for a finished run, the totals.
    let lines = &log.topics["/log"];
    let (first, last) = (&lines[0], lines.last().unwrap());
    assert_eq!((first["level"].as_u64(), last["level"].as_u64()), (Some(2), Some(2)), "{lines:?}");
    assert!(first["message"].as_str().unwrap().starts_with("bifirst ") && first["message"].as_str().unwrap().contains("scene `uniaxial_blatz_ko`"), "{first}");
    assert!(last["message"].as_str().unwrap().starts_with("finished: 10 steps"), "{last}");
    let run = &log.topics["/run"][0];
    assert_eq!(run["backend"], "cpu");
    assert_eq!(run["precision"], "f64");
    assert!(run["adapter"].is_null());
    assert_eq!(run["scene_name"], "uniaxial_blatz_ko");
    // The resolved scene carries the --set override and parses back.
    let scene: toml::Table = toml::from_str(run["scene"].as_str().unwrap()).expect("resolved scene is TOML");
    assert_eq!(scene["time"]["end"].as_float(), Some(0.1));
    assert_eq!(log.attachments, vec!["scene.toml".to_string()]);
    assert_eq!(log.metadata, vec!["bifirst.run".to_string()]);
    let meta = &log.record.metadata["bifirst.run"];
    for key in ["version", "git_revision", "backend", "adapter", "precision", "cores", "scene"] {
        assert!(meta.contains_key(key), "metadata has {key}");
    }
    assert!(meta["cores"].parse::<usize>().unwrap() >= 1);
    let summary = &log.topics["/summary"][0];
    assert_eq!(summary["status"], "finished");
    assert_eq!(summary["steps"], steps);
    let wall = &log.topics["/solver"][0]["wall_s"];
    assert_eq!(message_fields(wall), sorted(&["elements", "assembly", "transfer", "factorization", "solve", "contact", "contact_newton", "total"]));
    // Vectors are arrays of 3 numbers in 3D; steps are numbered 1..=N with t increasing.
    assert_eq!(log.topics["/body/cube"][0]["center_of_mass"].as_array().unwrap().len(), 3);
    let step: Vec<u64> = log.topics["/solver"].iter().map(|m| m["step"].as_u64().unwrap()).collect();
    assert_eq!(step, (1..=steps as u64).collect::<Vec<_>>());
    assert!(log.topics["/solver"].iter().all(|m| m["status"] == "converged"));
}

/// A packing's grains share one `/bodies` message per step (`output.bodies = "auto"`), or have a
/// channel each (`"channels"`): the same numbers, and `summary` reads both logs.
#[test]
fn packing_bodies_are_batched_or_per_channel_with_the_same_values() {
    let sets = ["packing.count=12", "time.end=0.015", "output.scene_every=0", "packing.wall_velocity=40.0"];
    let batched = run("grains_many", &sets, "bodies_batched");
    let channels = run("grains_many", &[&sets[..], &["output.bodies=\"channels\""]].concat(), "bodies_channels");
    assert!(!batched.topics.keys().any(|t| t.starts_with("/body/")) && !channels.topics.contains_key("/bodies"));
    let names: Vec<String> = batched.topics["/run"][0]["batched_bodies"]["names"].as_array().unwrap().iter().map(|n| n.as_str().unwrap().to_string()).collect();
    assert_eq!(names.len(), 12);
    assert!(channels.topics["/run"][0]["batched_bodies"].is_null());
    let (_, schema) = &batched.schemas["/bodies"];
    let fields = ["t", "center_of_mass", "linear_momentum", "angular_momentum", "kinetic"];
    assert_eq!(schema_fields(schema), sorted(&fields));
    let steps = batched.topics["/solver"].len();
    assert_eq!(batched.topics["/bodies"].len(), steps + 1, "the initial state and one message per step");
    for (k, name) in names.iter().enumerate() {
        let own = &channels.topics[&format!("/body/{name}")];
        assert_eq!(own.len(), steps + 1);
        for (one, all) in own.iter().zip(&batched.topics["/bodies"]) {
            assert_eq!(message_fields(all), sorted(&fields));
            assert_eq!(one["t"], all["t"]);
            for field in &fields[1..] {
                assert_eq!(one[*field], all[*field][k], "{name}.{field}");
            }
        }
        let mass = batched.topics["/run"][0]["batched_bodies"]["mass"][k].as_f64().unwrap();
        assert_eq!(own[0]["mass"].as_f64(), Some(mass));
    }
    // The wall reached the first column: the values are not all zero.
    assert!(batched.topics["/bodies"].last().unwrap()["kinetic"].as_array().unwrap().iter().any(|k| k.as_f64().unwrap() > 0.0));
    for log in [&batched, &channels] {
        let s = bifirst::output::summary::summarize(&log.record).expect("summary reads the log");
        assert_eq!((s.status.as_str(), s.steps), ("finished", steps as u64));
    }
}

/// Caught by the issue: a packing of more than 65 536 grains failed at the 65 537th channel
/// (`cannot write more than 65536 channels to one MCAP`) and left a 91-byte file.
#[test]
fn a_log_of_more_than_65536_bodies_is_valid() {
    let count = 65_537;
    let sets = [&format!("packing.count={count}")[..], "packing.divisions=1", "packing.polygons=0.0", "time.end=0.01", "output.scene_every=0"];
    let log = run("grains_many", &sets, "bodies_65537");
    assert_eq!(log.topics["/run"][0]["batched_bodies"]["names"].as_array().unwrap().len(), count);
    let bodies = &log.topics["/bodies"];
    assert_eq!(bodies.len(), 3, "the initial state and two steps");
    assert!(bodies.iter().all(|m| m["kinetic"].as_array().unwrap().len() == count && m["center_of_mass"].as_array().unwrap().len() == count));
    assert!(log.schemas.len() < 20, "a handful of channels: {}", log.schemas.len());
    let s = bifirst::output::summary::summarize(&log.record).expect("summary reads the log");
    assert_eq!((s.status.as_str(), s.steps), ("finished", 2));
}

#[test]
fn run_log_vectors_have_two_components_in_2d() {
    let log = run("free_vibration_2d", &["time.end=0.03"], "contract_2d");
    let body = &log.topics["/body/beam"][1];
    assert_eq!(body["center_of_mass"].as_array().unwrap().len(), 2);
    assert!(body["angular_momentum"].is_number(), "2D angular momentum is the z component");
    assert_eq!(log.topics["/probe/tip"][1]["velocity"].as_array().unwrap().len(), 2);
    assert_eq!(log.topics["/reaction/clamp"][1]["force"].as_array().unwrap().len(), 2);
}

#[test]
fn a_failed_run_leaves_a_valid_log_that_reports_the_failure() {
    use bifirst::run::{run_scene, RunError, Silent, Stop};
    // A violent kick inverts elements: every cut-back fails too, and the run must stop cleanly.
    let sets: Vec<String> = ["body.beam.initial_velocity=[0.0, 2000.0]", "solver.max_cutbacks=2", "solver.max_iterations=8"].map(String::from).to_vec();
    let loaded = bifirst::scene::load_scene(&common_run::scene_path("free_vibration_2d"), &sets).unwrap();
    let out = common_run::temp_path("failed_run.mcap");
    let err = run_scene(&loaded, &out, &Default::default(), &mut Silent).expect_err("the run must fail");
    let RunError::Stopped { reason: Stop::Failed(failure), summary } = err else { panic!("expected a step failure, got {err}") };
    assert_eq!(failure.cutbacks, 2);
    let log = common_run::read_log(&out);
    let last = log.topics["/solver"].last().unwrap();
    assert_eq!(last["status"], "failed");
    assert!(last["message"].as_str().unwrap().contains("failed after 2 cut-backs"), "{last}");
    assert_eq!(log.topics["/energy"].len(), summary.steps + 1, "every finished step is in the log");
    // Each cut-back is a Foxglove warning, the failure an error; the totals close the log.
    let lines = &log.topics["/log"];
    assert_eq!(lines.iter().filter(|l| l["level"] == 3).count(), 2, "{lines:?}");
    let last_line = lines.last().unwrap();
    assert_eq!(last_line["level"], 4);
    assert!(last_line["message"].as_str().unwrap().contains("failed after 2 cut-backs"), "{last_line}");
    assert_eq!(log.topics["/summary"][0]["status"], "failed");
    assert_eq!(log.topics["/summary"][0]["steps"], summary.steps);
}

#[test]
fn contact_scenes_log_the_contact_channel_and_obstacle_reactions() {
    let log = run("bar_impact", &["time.end=0.005"], "contract_contact");
    let (name, schema) = &log.schemas["/contact"];
    assert_eq!(name, "bifirst.Contact");
    let fields = ["t", "active", "sticking", "sliding", "max_penetration", "max_overlap", "max_overlap_ratio", "normal_impulse", "friction_dissipation_step"];
    assert_eq!(schema_fields(schema), sorted(&fields));
    assert_eq!(log.topics["/contact"].len(), 100, "one message per step");
    assert!(log.topics["/contact"].iter().all(|m| message_fields(m) == sorted(&fields)));
    // The wall pushes the bar back (+x) once they touch; Uzawa iterations are counted.
    let wall = log.vectors("/reaction/wall", "force");
    assert_eq!(wall.len(), 101);
    assert!(wall.last().unwrap()[0] > 0.0 && wall.last().unwrap()[1] == 0.0);
    assert!(log.topics["/solver"].iter().any(|m| m["uzawa_iterations"].as_u64().unwrap() > 0));
    // Without contact in the scene there is no /contact channel.
    assert!(!run("uniaxial_blatz_ko", &["time.end=0.02"], "contract_no_contact").topics.contains_key("/contact"));
}

/// The channels' schemas are derived from the types the run writes (schemars); every message of
/// a 2D and a 3D run with contact, and the saved state, validates against its channel's schema.
#[test]
fn every_message_validates_against_the_schema_derived_from_its_type() {
    // `/bodies` in 3D (stack_3d's bodies batched) and in 2D (a packing).
    let cases: [(&str, &[&str]); 3] = [
        ("sliding_block", &["time.end=0.02", "output.state_every=5"]),
        ("stack_3d", &["time.end=0.02", "output.state_every=1", "output.bodies=\"batched\""]),
        ("grains_many", &["time.end=0.05", "packing.count=6", "output.scene_every=0", "output.contacts_every=2", "packing.wall_velocity=40.0"]),
    ];
    for (scene, sets) in cases {
        let log = run(scene, sets, &format!("derived_{scene}"));
        assert_eq!(log.topics.contains_key("/bodies"), scene != "sliding_block", "{scene}: /bodies");
        let mut schemas = boon::Schemas::new();
        let mut compiler = boon::Compiler::new();
        let mut checked = 0;
        for (topic, (name, schema)) in log.schemas.iter().filter(|(_, (name, _))| name.starts_with("bifirst.")) {
            assert_eq!(schema["title"], name.as_str(), "{topic}: the schema is titled by its name");
            let url = format!("file:///{}.json", topic.trim_start_matches('/').replace('/', "_"));
            compiler.add_resource(&url, schema.clone()).unwrap();
            let id = compiler.compile(&url, &mut schemas).unwrap_or_else(|e| panic!("{topic}: {e:#}"));
            for m in &log.topics[topic] {
                schemas.validate(m, id).unwrap_or_else(|e| panic!("{scene} {topic}: {e:#}"));
                checked += 1;
            }
        }
        assert!(log.topics.contains_key("/state") && checked > 10, "{scene}: {checked} messages checked");
        if scene == "grains_many" {
            let networks = &log.topics["/contacts"];
            assert!(networks.iter().any(|m| !m["body"].as_array().unwrap().is_empty()), "a contact network with contacts is validated");
        }
    }
}
