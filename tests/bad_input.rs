//! Bad input: each kind gives a one-paragraph error naming the file, the line (where one exists)
//! and the key, a non-zero exit, and no panic. Run through the real binary.

#[path = "common/gmsh.rs"]
mod common_gmsh;

use std::path::{Path, PathBuf};
use std::process::Command;

const GOOD: &str = r#"# a valid scene; each test breaks one thing
[time]
end = 0.05
dt = 0.01

[material.rubber]
model = "blatz_ko"
G = 1000.0
density = 1.0

[body.block]
material = "rubber"
mesh = { generator = "rectangle", element = "quad4", size = [1.0, 1.0], divisions = [2, 2] }

[boundary.base]
body = "block"
nodes = "y_min"
"#;

/// `GOOD` with its body meshed from `file` (written to `dir()` by the caller) and the boundary
/// on the node set `nodes`.
fn with_mesh_file(file: &str, nodes: &str) -> String {
    GOOD.replace(r#"{ generator = "rectangle", element = "quad4", size = [1.0, 1.0], divisions = [2, 2] }"#, &format!(r#"{{ file = "{file}" }}"#)).replace("nodes = \"y_min\"", &format!("nodes = \"{nodes}\""))
}

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bad_input");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes `scene` as `<tag>.toml`, runs `bifirst check` on it, returns (exit code, stderr, path).
fn check(tag: &str, scene: &str, sets: &[&str]) -> (i32, String, PathBuf) {
    let path = dir().join(format!("{tag}.toml"));
    std::fs::write(&path, scene).unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_bifirst"));
    cmd.arg("check").arg(&path);
    for s in sets {
        cmd.arg("--set").arg(s);
    }
    let out = cmd.output().expect("binary runs");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.code().unwrap_or(-1), stderr, path)
}

/// The error must name the file, the key (empty: a syntax error, which has none), the line
/// (if given), say `expect`, and not panic.
fn assert_error(tag: &str, scene: &str, sets: &[&str], key: &str, line: Option<usize>, expect: &str) {
    let (code, stderr, path) = check(tag, scene, sets);
    println!("{tag}: {stderr}");
    assert_eq!(code, 2, "{tag}: exit code (stderr: {stderr})");
    assert!(!stderr.contains("panicked"), "{tag}: panicked: {stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{tag}: one paragraph: {stderr}");
    assert!(stderr.contains(&path.display().to_string()), "{tag}: names the file: {stderr}");
    if !key.is_empty() {
        assert!(stderr.contains(&format!("key `{key}`")), "{tag}: names the key `{key}`: {stderr}");
    }
    if let Some(line) = line {
        let named = [",", ":"].iter().any(|end| stderr.contains(&format!("line {line}{end}")));
        assert!(named, "{tag}: names line {line}: {stderr}");
    }
    assert!(stderr.contains(expect), "{tag}: says `{expect}`: {stderr}");
}

#[test]
fn the_good_scene_is_valid() {
    let (code, stderr, _) = check("good", GOOD, &[]);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn unknown_key() {
    assert_error("unknown_key", &GOOD.replace("dt = 0.01", "dt = 0.01\nsteps = 5"), &[], "time.steps", Some(5), "unknown field");
}

#[test]
fn wrong_type() {
    assert_error("wrong_type", &GOOD.replace("dt = 0.01", "dt = \"fast\""), &[], "time.dt", Some(4), "invalid type");
}

#[test]
fn zero_or_negative_modulus() {
    assert_error("negative_modulus", &GOOD.replace("G = 1000.0", "G = -5.0"), &[], "material.rubber.G", Some(8), "positive");
    assert_error("zero_modulus", &GOOD.replace("G = 1000.0", "G = 0"), &[], "material.rubber.G", Some(8), "positive");
}

#[test]
fn negative_density() {
    assert_error("negative_density", &GOOD.replace("density = 1.0", "density = -1.0"), &[], "material.rubber.density", Some(9), "density must be positive");
}

#[test]
fn non_positive_time_step() {
    assert_error("zero_dt", &GOOD.replace("dt = 0.01", "dt = 0.0"), &[], "time.dt", Some(4), "time step must be positive");
    assert_error("negative_dt", &GOOD.replace("dt = 0.01", "dt = -0.01"), &[], "time.dt", Some(4), "time step must be positive");
}

#[test]
fn non_positive_end_time() {
    assert_error("zero_end", &GOOD.replace("end = 0.05", "end = 0"), &[], "time.end", Some(3), "end time must be positive");
}

#[test]
fn unknown_material() {
    assert_error("unknown_material", &GOOD.replace("material = \"rubber\"", "material = \"steel\""), &[], "body.block.material", Some(12), "unknown material `steel`");
}

#[test]
fn missing_mesh_file() {
    assert_error("missing_mesh", &with_mesh_file("nowhere.msh", "y_min"), &[], "body.block.mesh.file", Some(13), "cannot read the mesh file");
}

#[test]
fn malformed_gmsh_file() {
    std::fs::write(dir().join("malformed.msh"), "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 1 2\nthis is not a node block\n").unwrap();
    assert_error("malformed_gmsh", &with_mesh_file("malformed.msh", "y_min"), &[], "body.block.mesh.file", Some(13), "is not usable");
}

#[test]
fn inverted_element_at_t0() {
    std::fs::write(dir().join("inverted.msh"), common_gmsh::unit_square_msh(true)).unwrap();
    assert_error("inverted_element", &with_mesh_file("inverted.msh", "left"), &[], "body.block.mesh.file", Some(13), "element 1 is inverted");
}

#[test]
fn degenerate_element_at_t0() {
    // The generators reject zero sizes before meshing, so collapse a Gmsh triangle instead:
    // node 3 moves onto node 2, and triangle 0 (nodes 1, 2, 3) has zero area.
    let msh = common_gmsh::unit_square_msh(false).replace("1 1 0\n0 1 0\n$EndNodes", "1 0 0\n0 1 0\n$EndNodes");
    std::fs::write(dir().join("degenerate.msh"), msh).unwrap();
    assert_error("degenerate_element", &with_mesh_file("degenerate.msh", "left"), &[], "body.block.mesh.file", Some(13), "element 0 is degenerate");
}

#[test]
fn set_on_a_key_that_does_not_exist() {
    assert_error("set_unknown_field", GOOD, &["time.steps=3"], "time.steps", None, "(from --set time.steps=3)");
    assert_error("set_unknown_entry", GOOD, &["material.steel.G=3"], "material.steel.G", None, "there is no material named `steel`");
}

#[test]
fn set_with_a_bad_value() {
    assert_error("set_bad_literal", GOOD, &["time.dt=fast"], "time.dt", None, "not a TOML literal");
    assert_error("set_negative_dt", GOOD, &["time.dt=-1"], "time.dt", None, "time step must be positive");
}

#[test]
fn node_set_that_names_no_nodes() {
    assert_error("unknown_node_set", &GOOD.replace("nodes = \"y_min\"", "nodes = \"bottom\""), &[], "boundary.base.nodes", Some(17), "has no node set `bottom`");
}

#[test]
fn invalid_toml() {
    assert_error("invalid_toml", &GOOD.replace("dt = 0.01", "dt = = 0.01"), &[], "", Some(4), "not valid TOML");
}

#[test]
fn parameter_of_another_model() {
    assert_error("foreign_parameter", &GOOD.replace("G = 1000.0", "G = 1000.0\na5 = 3.0"), &[], "material.rubber.a5", Some(9), "not a parameter of the blatz_ko model");
}

#[test]
fn missing_scene_file() {
    let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["run", "no/such/scene.toml"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr.contains("no/such/scene.toml") && stderr.contains("cannot read the scene file"), "{stderr}");
}

const WALL: &str = "\n[obstacle.wall]\nshape = \"plane\"\npoint = [0.0, 0.0]\nnormal = [0.0, 1.0]\n";

#[test]
fn negative_friction() {
    assert_error("negative_friction", &format!("{GOOD}{WALL}"), &["contact.friction=-0.2"], "contact.friction", None, "friction coefficient must be zero or positive");
    let scene = format!("{GOOD}{WALL}friction = -1.0\n");
    assert_error("negative_obstacle_friction", &scene, &[], "obstacle.wall.friction", Some(23), "friction coefficient must be zero or positive");
}

#[test]
fn obstacle_missing_or_foreign_fields() {
    assert_error("plane_without_normal", &format!("{GOOD}{WALL}").replace("normal = [0.0, 1.0]\n", ""), &[], "obstacle.wall.normal", Some(19), "this obstacle needs `normal`");
    assert_error("plane_with_box_corner", &format!("{GOOD}{WALL}min = [0.0, 0.0]\n"), &[], "obstacle.wall.min", Some(23), "takes point, normal");
    assert_error("zero_normal", &format!("{GOOD}{WALL}").replace("normal = [0.0, 1.0]", "normal = [0.0, 0.0]"), &[], "obstacle.wall.normal", Some(22), "the normal is zero");
}

#[test]
fn concave_polygon() {
    let polygon = "\n[obstacle.wall]\nshape = \"polygon\"\npoints = [[0.0, 0.0], [2.0, 0.0], [1.0, 0.5], [2.0, 1.0], [0.0, 1.0]]\n";
    assert_error("concave_polygon", &format!("{GOOD}{polygon}"), &[], "obstacle.wall.points", Some(21), "not convex");
}

#[test]
fn obstacle_or_pair_naming_an_unknown_body() {
    assert_error("obstacle_unknown_body", &format!("{GOOD}{WALL}bodies = [\"block\", \"ghost\"]\n"), &[], "obstacle.wall.bodies.1", Some(23), "unknown body `ghost`");
    let pair = "\n[contact.pair.self]\nbodies = [\"block\", \"block\"]\n";
    assert_error("pair_twice_the_same_body", &format!("{GOOD}{pair}"), &[], "contact.pair.self.bodies", Some(20), "two different bodies");
}

#[test]
fn motion_table_with_times_going_back() {
    let scene = format!("{GOOD}{WALL}motion = [[0.0, 0.0, 1.0], [0.5, 0.0, 0.0], [0.2, 0.0, -1.0]]\n");
    assert_error("motion_backwards", &scene, &[], "obstacle.wall.motion.2", Some(23), "must increase");
}

#[test]
fn names_that_cannot_be_topics_or_file_names() {
    let probe = "\n[probe.\"tip/top\"]\nbody = \"block\"\npoint = [0.5, 1.0]\n";
    assert_error("name_with_slash", &format!("{GOOD}{probe}"), &[], "probe.tip/top", Some(19), "letters, digits");
}

#[test]
fn zero_vtu_cadence() {
    assert_error("zero_vtu_cadence", GOOD, &["output.vtu_every=0"], "output.vtu_every", None, "at least 1 step");
}

/// Backend requests that cannot be met are errors before the run starts, never a silent CPU run.
#[test]
fn backend_requests_that_cannot_be_met() {
    let scene = common_scene_path("free_vibration_2d");
    for (args, expect) in [
        (&["--backend", "gpu", "--adapter", "no-such-adapter"][..], "no GPU adapter named like `no-such-adapter`"),
        (&["--backend", "auto", "--adapter", "no-such-adapter"][..], "no GPU adapter named like `no-such-adapter`"),
        (&["--backend", "cpu", "--precision", "f32"][..], "the CPU backend runs in f64 only"),
        (&["--backend", "cpu", "--adapter", "llvmpipe"][..], "--adapter needs a GPU backend"),
        (&["--backend", "cpu", "--uzawa", "gpu"][..], "--uzawa gpu needs a GPU backend"),
        (&["--backend", "tpu"][..], "unknown backend `tpu`"),
        (&["--uzawa", "fpga"][..], "unknown Uzawa placement `fpga`"),
        (&["--precision", "f16"][..], "unknown precision `f16`"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["run", scene.to_str().unwrap(), "--quiet", "--out"]).arg(dir().join("backend_request.mcap")).args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(expect), "{args:?}: {stderr}");
        // Caught when the error was printed with its source appended: the same sentence twice.
        assert_eq!(stderr.matches(expect).count(), 1, "{args:?}: said once: {stderr}");
    }
}

fn common_scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(format!("{name}.toml"))
}

#[test]
fn bad_packing_and_polygon_grains() {
    let packing = format!("{GOOD}\n[packing]\ncount = 4\nmaterial = \"steel\"\n");
    assert_error("packing_material", &packing, &[], "packing.material", Some(21), "unknown material `steel`");
    let rubber = packing.replace("\"steel\"", "\"rubber\"");
    assert_error("packing_radius", &rubber, &["packing.radius=[0.5, 0.2]"], "packing.radius", None, "0 < min <= max");
    // Caught by the fuzz test (seed 1): a huge `packing.divisions` overflowed the disk generator.
    assert_error("packing_divisions", &rubber, &["packing.divisions=9223372036854775807"], "packing.divisions", None, "limits.max_elements");
    assert_error("packing_count", &rubber, &["packing.count=9223372036854775807"], "packing.count", None, "limits.max_elements");
    let concave = r#"{ generator = "polygon", element = "tri3", points = [[0.0, 0.0], [2.0, 0.0], [1.0, 0.3], [1.0, 2.0]], divisions = [3] }"#;
    let polygon = GOOD.replace(r#"{ generator = "rectangle", element = "quad4", size = [1.0, 1.0], divisions = [2, 2] }"#, concave).replace("nodes = \"y_min\"", "nodes = \"center\"");
    // Its own tag: `concave_polygon` (the obstacle test) wrote the same file in parallel.
    assert_error("concave_grain_polygon", &polygon, &[], "body.block.mesh.points", Some(13), "not convex");
    assert_error("polygon_quads", &polygon.replace("[1.0, 0.3]", "[2.0, 2.0]").replace("tri3", "quad4"), &[], "body.block.mesh.element", Some(13), "tri3");
}

/// Caught by fuzzing: `divisions = [9223372036854775807, 2]` panicked ("capacity overflow"),
/// `[20000, 20000]` tried to allocate far more than the machine has, `dt = 1e-20` was accepted
/// (1e20 steps). They are errors at `check` now, and the limits can be raised.
#[test]
fn absurd_sizes_are_errors_that_can_be_overridden() {
    for (tag, set) in [("divisions_overflow", "body.block.mesh.divisions=[9223372036854775807, 2]"), ("divisions_huge", "body.block.mesh.divisions=[20000, 20000]")] {
        assert_error(tag, GOOD, &[set], "body.block.mesh.divisions", None, "limits.max_elements");
    }
    assert_error("dt_tiny", GOOD, &["time.dt=1e-20"], "time.dt", None, "limits.max_steps");
    let (code, stderr, _) = check("dt_small_raised", GOOD, &["time.dt=1e-10", "limits.max_steps=1000000000"]);
    assert_eq!(code, 0, "a raised limit admits the scene: {stderr}");
}

/// Caught by `packing.radius = [0.35, 50]`: `check` refined polygon grains by building their
/// mesh at every level (past 20 s, 1.7 GB); now it answers at once.
#[test]
fn a_packing_of_huge_grains_is_rejected_at_once() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/grains_many.toml");
    let started = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["check", scene.to_str().unwrap(), "--set", "packing.radius=[0.35, 50]"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("limits.max_elements") && !stderr.contains("panicked"), "{stderr}");
    println!("rejected in {:.2} s", started.elapsed().as_secs_f64());
}

/// Caught by the issue: these reached the log as `null` (non-finite energies) or failed as an
/// "inverted element (det F = 0)". Inputs whose products overflow are bad input, named by key.
#[test]
fn inputs_too_large_for_finite_energies() {
    assert_error("huge_gravity", GOOD, &["gravity=[0.0, 1e308]"], "gravity", None, "beyond ±1e100");
    assert_error("huge_initial_velocity", GOOD, &["body.block.initial_velocity=[0.0, 1e200]"], "body.block.initial_velocity", None, "beyond ±1e100");
    assert_error("bulk_modulus_beyond_f64", GOOD, &["material.rubber.model=\"neo_hookean\"", "material.rubber.K=1e28"], "material.rubber.K", None, "round-off");
    assert_error("boundary_stops_before_it_starts", GOOD, &["boundary.base.until=-1.0"], "boundary.base.until", None, "positive");
    // Node 4 of the Gmsh square moved to x = 1e300.
    let msh = common_gmsh::unit_square_msh(false).replace("0 1 0\n$EndNodes", "1e300 1 0\n$EndNodes");
    std::fs::write(dir().join("far_node.msh"), msh).unwrap();
    assert_error("far_node", &with_mesh_file("far_node.msh", "left"), &[], "body.block.mesh.file", Some(13), "node 3 is at");
    assert_error("huge_density", GOOD, &["material.rubber.density=1e200"], "material.rubber.density", None, "outside [1e-100, 1e100]");
    assert_error("tiny_modulus", GOOD, &["material.rubber.G=1e-200"], "material.rubber.G", None, "outside [1e-100, 1e100]");
    // Each input within range, their product beyond f64.
    let sets = ["material.rubber.density=1e100", "body.block.mesh.size=[1e60, 1e60]", "body.block.initial_velocity=[1e100, 0.0]"];
    assert_error("infinite_initial_energy", GOOD, &sets, "body.block", Some(11), "non-finite energy (kinetic inf");
}

#[test]
fn a_bad_load_names_its_key() {
    let with_load = |load: &str| format!("{GOOD}\n[load.pull]\nbody = \"block\"\n{load}\n");
    let line = |scene: &str, text: &str| scene.lines().position(|l| l.contains(text)).map(|i| i + 1);
    let both = with_load("nodes = \"y_max\"\ntraction = [0.0, 1.0]\npressure = 1.0");
    assert_error("load_both", &both, &[], "load.pull", None, "either a `traction`");
    let short = with_load("nodes = \"y_max\"\ntraction = [1.0]");
    assert_error("load_short", &short, &[], "load.pull.traction", line(&short, "traction = [1.0]"), "2 components");
    let ramp = with_load("nodes = \"y_max\"\npressure = 1.0\nramp = -1.0");
    assert_error("load_ramp", &ramp, &[], "load.pull.ramp", line(&ramp, "ramp = -1.0"), "zero or a positive number");
    let set = with_load("nodes = \"top\"\npressure = 1.0");
    assert_error("load_set", &set, &[], "load.pull.nodes", None, "no node set `top`");
    // A disk's centre: a node set with no boundary facet.
    let disk = with_load("nodes = \"center\"\npressure = 1.0")
        .replace(r#"{ generator = "rectangle", element = "quad4", size = [1.0, 1.0], divisions = [2, 2] }"#, r#"{ generator = "disk", element = "quad4", radius = 1.0, divisions = [2] }"#)
        .replace("nodes = \"y_min\"", "nodes = \"boundary\"");
    assert_error("load_nothing", &disk, &[], "load.pull.nodes", None, "the load would act on nothing");
    let nothing = with_load("nodes = \"all\"\npressure = 1.0");
    let (code, stderr, _) = check("load_all", &nothing, &[]);
    assert_eq!(code, 0, "a load on every boundary facet is valid: {stderr}");
}

/// Runs the binary with `args` and returns (exit code, stderr).
fn bifirst(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_bifirst")).args(args).output().expect("binary runs");
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A refusal: exit 2, no panic, the words `expect`.
fn assert_refused(args: &[&str], expect: &str) {
    let (code, stderr) = bifirst(args);
    assert_eq!(code, 2, "{args:?}: exit code: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: panicked: {stderr}");
    assert!(stderr.contains(expect), "{args:?}: says `{expect}`: {stderr}");
}

/// Caught by the issue: `packing.radius = [1e-90, 1e-90]` in 3D passed `check`, then panicked in
/// the contact frame ("an axis not parallel to n"); radii of 1e-30 failed at step 1 as "not
/// positive definite" (the mass term below the stiffness' round-off). Both are refused at
/// `check`, naming the key, and `run` does not panic.
#[test]
fn tiny_grains_in_a_3d_packing_are_refused_before_the_run() {
    let scene = common_scene_path("grains_3d");
    let scene = scene.to_str().unwrap();
    assert_refused(&["check", scene, "--set", "packing.count=8", "--set", "packing.radius=[1e-90, 1e-90]"], "key `packing.radius.0`");
    let out = dir().join("tiny_grains.mcap");
    assert_refused(&["run", scene, "--set", "packing.count=8", "--set", "packing.radius=[1e-90, 1e-90]", "--set", "time.end=0.01", "--quiet", "--out", out.to_str().unwrap()], "below 1e-50");
    assert_refused(&["check", scene, "--set", "packing.count=8", "--set", "packing.radius=[1e-30, 1e-30]"], "key `time.dt`");
    let box_scene = GOOD.replace(r#"{ generator = "rectangle", element = "quad4", size = [1.0, 1.0], divisions = [2, 2] }"#, r#"{ generator = "rectangle", element = "quad4", size = [1e-60, 1.0], divisions = [2, 2] }"#);
    assert_error("tiny_edge", &box_scene, &[], "body.block.mesh.size.0", Some(13), "below 1e-50");
}

/// Caught by the issue: `stability --max-wall nan` panicked converting seconds to a duration
/// (exit 101); `--max-wall=-1` and `--max-sweeps=-1` ran and classed every variant too slow.
#[test]
fn stability_budgets_that_are_no_positive_number_are_refused() {
    let scene = common_scene_path("bar_impact");
    let scene = scene.to_str().unwrap();
    for budget in ["--max-wall=nan", "--max-wall=-1", "--max-sweeps=-1", "--max-sweeps=0"] {
        let flag = budget.split('=').next().unwrap();
        assert_refused(&["stability", scene, "--set", "time.end=5e-4", "--over", "time.dt=5e-5", budget], flag);
    }
}

/// Caught by the issue: `--threads 100000` printed nothing for over a minute (even for `check`)
/// and `--threads 2000` made a 0.05 s run take 7 s. Beyond 1024, or 0, it is refused at once.
#[test]
fn thread_counts_beyond_reason_are_refused_at_once() {
    let scene = common_scene_path("bar_impact");
    let scene = scene.to_str().unwrap();
    for threads in ["100000", "1025", "0"] {
        assert_refused(&["--threads", threads, "check", scene], "--threads");
    }
    let more = (std::thread::available_parallelism().map_or(1, |n| n.get()) + 1).to_string();
    let (code, stderr) = bifirst(&["--threads", &more, "check", scene]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("more than this machine's"), "oversubscription is warned of: {stderr}");
}

/// Caught by the issue: `accuracy --repeat 100000` kept running after SIGTERM (the repeats went
/// on, each stopped at once), and printed nothing until a variant's repeats were done. Each
/// repeat is reported, a signal ends the command with the run in progress, and `--repeat` is
/// at most 1000.
#[test]
fn accuracy_stops_on_a_signal_and_reports_each_repeat() {
    use std::io::{BufRead, BufReader};
    let scene = common_scene_path("bar_impact");
    let scene = scene.to_str().unwrap();
    assert_refused(&["accuracy", scene, "--set", "time.end=5e-4", "--over", "time.dt=5e-5", "--repeat", "100000"], "--repeat");
    let out = dir().join("accuracy_signal");
    let mut child = Command::new(env!("CARGO_BIN_EXE_bifirst"))
        .args(["accuracy", scene, "--set", "time.end=5e-4", "--over", "time.dt=5e-5,1e-4,2e-4", "--repeat", "1000", "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let first = lines.by_ref().map_while(Result::ok).find(|l| l.contains("run 1/1000"));
    assert!(first.is_some(), "a progress line per repeat");
    let sent = std::time::Instant::now();
    assert!(Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap().success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().unwrap();
    let waited = sent.elapsed().as_secs_f64();
    println!("stopped {waited:.3} s after SIGTERM; last lines: {:?}", &rest[rest.len().saturating_sub(3)..]);
    // Three variants of 1000 runs of ~0.03 s would take over a minute.
    assert!(waited < 10.0, "stopped {waited} s after the signal");
    assert!(!status.success(), "an interrupted study is not a success");
    assert!(!rest.iter().any(|l| l.contains("run 1/1000") && l.contains("dt=2e-4")), "no variant starts after the signal: {rest:?}");
}

/// Caught by the issue: Mooney-Rivlin `C10`/`C01`, Yeoh `C20`/`C30`, Ogden `mu`/`alpha` of 1e300
/// passed validation and the run failed at step 1 ("the residual is not finite") without naming
/// the parameter.
#[test]
fn huge_rubber_coefficients_are_named_by_key() {
    let with = |material: &str| GOOD.replace("model = \"blatz_ko\"\nG = 1000.0", material);
    let cases = [
        ("model = \"mooney_rivlin\"\nC10 = 1e300\nC01 = 1.0\nK = 3000.0", "material.rubber.C10"),
        ("model = \"mooney_rivlin\"\nC10 = 400.0\nC01 = -1e300\nK = 3000.0", "material.rubber.C01"),
        ("model = \"yeoh\"\nC10 = 400.0\nC20 = 1e300\nK = 3000.0", "material.rubber.C20"),
        ("model = \"yeoh\"\nC10 = 400.0\nC30 = -1e300\nK = 3000.0", "material.rubber.C30"),
        ("model = \"ogden\"\nmu = [1e300]\nalpha = [2.0]\nK = 3000.0", "material.rubber.mu.0"),
        ("model = \"ogden\"\nmu = [600.0, 1.0]\nalpha = [2.0, 1e300]\nK = 3000.0", "material.rubber.alpha.1"),
    ];
    for (k, (material, key)) in cases.iter().enumerate() {
        assert_error(&format!("huge_coefficient_{k}"), &with(material), &[], key, None, "beyond ±1e100");
    }
}

/// Caught by the issue: an error in a Prony term's `g` or `tau` named the `[material.*]` header
/// line, and the key was spelled `viscoelastic[0].tau` in one message and `viscoelastic.0` in
/// another.
#[test]
fn a_prony_term_error_names_its_own_line_and_key() {
    let scene = GOOD.replace("density = 1.0", "density = 1.0\nviscoelastic = [{ g = 0.3, tau = 0.1 },\n    { g = 0.2, tau = -1.0 }]");
    let line = scene.lines().position(|l| l.contains("tau = -1.0")).unwrap() + 1;
    assert_error("prony_tau", &scene, &[], "material.rubber.viscoelastic.1.tau", Some(line), "positive");
    let scene = GOOD.replace("density = 1.0", "density = 1.0\nviscoelastic = [{ g = \"a\", tau = 0.1 }]");
    let line = scene.lines().position(|l| l.contains("viscoelastic")).unwrap() + 1;
    assert_error("prony_type", &scene, &[], "material.rubber.viscoelastic.0.g", Some(line), "invalid type");
}

/// Caught by the issue: `--vtu` naming an existing file ran the whole scene and then exited 1
/// ("File exists"); an unwritable `--out` failed after the set-up, leaving a stub. Both are
/// refused before the scene is set up, with exit 2 and nothing written.
#[test]
fn outputs_that_cannot_be_written_are_refused_before_the_run() {
    let scene = common_scene_path("bar_impact");
    let scene = scene.to_str().unwrap();
    let file = dir().join("a_regular_file");
    std::fs::write(&file, "x").unwrap();
    let log = dir().join("vtu_refused.mcap");
    let _ = std::fs::remove_file(&log);
    assert_refused(&["run", scene, "--quiet", "--out", log.to_str().unwrap(), "--vtu", file.to_str().unwrap()], "is a file, not a directory");
    assert!(!log.exists(), "nothing written");
    let below_file = file.join("run.mcap");
    assert_refused(&["run", scene, "--quiet", "--out", below_file.to_str().unwrap()], "is a file, not a directory");
    assert_refused(&["run", scene, "--quiet", "--out", dir().to_str().unwrap()], "is a directory");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "x", "the file is left as it was");
}

/// Saint Venant-Kirchhoff's parameters: E and ν, ν within (-1, 1/2), and a ν so near 1/2 that
/// K/G is beyond f64 named as the bulk parameter.
#[test]
fn svk_takes_young_and_poisson_within_their_range() {
    let svk = |params: &str| GOOD.replace("model = \"blatz_ko\"\nG = 1000.0", &format!("model = \"svk\"\n{params}"));
    let (code, stderr, _) = check("svk_good", &svk("E = 2600.0\nnu = 0.3"), &[]);
    assert_eq!(code, 0, "{stderr}");
    assert_error("svk_nu_half", &svk("E = 2600.0\nnu = 0.5"), &[], "material.rubber.nu", Some(9), "(-1, 1/2)");
    assert_error("svk_no_nu", &svk("E = 2600.0"), &[], "material.rubber.nu", None, "needs `nu`");
    assert_error("svk_g", &svk("E = 2600.0\nnu = 0.3\nG = 1.0"), &[], "material.rubber.G", Some(10), "not a parameter of the svk model (it takes E, nu)");
    assert_error("svk_incompressible", &svk("E = 2600.0\nnu = 0.49999999999999"), &[], "material.rubber.nu", None, "round-off");
}

/// Caught by the issue: messages a user could not act on. Ogden `mu = ["630"]` said "did not
/// match any variant of untagged enum Values", `formulation = 1` "unit variant", a seed beyond
/// TOML's integers "strings need quotes"; `packing.polygons` in 3D and `packing.polyhedra` in 2D
/// were ignored.
#[test]
fn unclear_messages_say_what_is_wrong() {
    let ogden = GOOD.replace("model = \"blatz_ko\"\nG = 1000.0", "model = \"ogden\"\nmu = [\"630\"]\nalpha = [2.0]\nK = 3000.0");
    let line = |scene: &str, text: &str| scene.lines().position(|l| l.contains(text)).map(|i| i + 1);
    assert_error("ogden_string", &ogden, &[], "material.rubber.mu.0", line(&ogden, "mu = [\"630\"]"), "invalid type: string \"630\"");
    let formulation = GOOD.replace("divisions = [2, 2] }", "divisions = [2, 2] }\nformulation = 1");
    assert_error("formulation_number", &formulation, &[], "body.block.formulation", line(&formulation, "formulation = 1"), "one of `auto`, `displacement`, `fbar`");
    assert_error("model_number", GOOD, &["material.rubber.model=1"], "material.rubber.model", None, "`blatz_ko`");
    let grains = common_scene_path("grains_many");
    let grains = grains.to_str().unwrap();
    assert_refused(&["check", grains, "--set", "packing.seed=99999999999999999999"], "beyond TOML's integers");
    let source = std::fs::read_to_string(grains).unwrap();
    let seeded = dir().join("huge_seed.toml");
    std::fs::write(&seeded, source.lines().map(|l| if l.starts_with("seed =") { "seed = 99999999999999999999" } else { l }).collect::<Vec<_>>().join("\n")).unwrap();
    assert_refused(&["check", seeded.to_str().unwrap()], "TOML integers are 64-bit");
    assert_refused(&["check", grains, "--set", "packing.polyhedra=0.3"], "key `packing.polyhedra`");
    let grains_3d = common_scene_path("grains_3d");
    assert_refused(&["check", grains_3d.to_str().unwrap(), "--set", "packing.polygons=0.3"], "key `packing.polygons`");
}

/// Caught by the issue: `bench --kernel nonexistent` exited 0 with an empty table, and `sweep
/// --trace` with probes the scene lacks was found only after every variant ran.
#[test]
fn filters_and_probes_that_match_nothing_are_refused_before_any_work() {
    assert_refused(&["bench", "--backend", "cpu", "--kernel", "nonexistent"], "--kernel `nonexistent` matches none of");
    assert_refused(&["bench", "--backend", "cpu", "--material", "steel"], "--material `steel`");
    let scene = common_scene_path("bar_impact");
    let out = dir().join("trace_refused");
    let _ = std::fs::remove_dir_all(&out);
    assert_refused(&["sweep", scene.to_str().unwrap(), "--over", "time.dt=1e-4", "--trace", "a,b,c", "--out", out.to_str().unwrap()], "the probe `a`");
    assert!(!out.exists(), "no variant ran");
}

/// Caught by the issue: K/G = 1e12, or a Yeoh set that loses convexity, failed as "not positive
/// definite" naming neither the material nor the reason. A factorisation that fails now names
/// the body's material model, its K/G and the likely reasons (here a mass term made negative,
/// which no scene reaches since the checks before the run).
#[test]
fn a_failed_factorisation_names_the_material_and_the_reasons() {
    let loaded = bifirst::scene::load_scene(&common_scene_path("bar_impact"), &[]).unwrap();
    let mut sim = bifirst::solver::build_simulation(&loaded).unwrap();
    let body = sim.body_mut(0);
    let error = body.factorize_effective(-1e9, &mut Default::default()).expect_err("a negative mass term is no positive definite K̄").to_string();
    for words in ["body `bar`", "not positive definite", "material model neo_hookean", "K/G = 2.000e0", "lower K/G"] {
        assert!(error.contains(words), "says `{words}`: {error}");
    }
}
