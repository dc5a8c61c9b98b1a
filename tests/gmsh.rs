//! Gmsh input: physical groups become node sets, and a Gmsh mesh gives the same answer as the
//! identical generated mesh.

#[path = "common/gmsh.rs"]
mod common_gmsh;
#[path = "common/run.rs"]
mod common_run;

use bifirst::mesh::{gmsh, ElementKind};
use common_run::{read_log, temp_path};

#[test]
fn reads_nodes_elements_and_physical_groups() {
    let mesh = gmsh::read(common_gmsh::unit_square_msh(false).as_bytes(), None).expect("valid msh");
    assert_eq!(mesh.kind, ElementKind::Tri3);
    assert_eq!(mesh.nodes.len(), 4);
    assert_eq!(mesh.element_count(), 2);
    assert_eq!(mesh.node_sets["left"], vec![0, 3]);
    assert_eq!(mesh.node_sets["domain"].len(), 4);
}

fn scene(mesh: &str) -> String {
    format!(
        r#"gravity = [0.0, -9.81]
[time]
end = 0.2
dt = 0.01
[material.rubber]
model = "neo_hookean"
G = 100.0
K = 300.0
density = 1.0
[body.square]
material = "rubber"
mesh = {mesh}
[boundary.clamp]
body = "square"
nodes = "{{clamp}}"
"#
    )
}

#[test]
fn gmsh_square_matches_generated_square() {
    let dir = temp_path("gmsh_square");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("square.msh"), common_gmsh::unit_square_msh(false)).unwrap();
    let variants = [("file", scene(r#"{ file = "square.msh" }"#).replace("{clamp}", "left")), ("generated", scene(r#"{ generator = "rectangle", element = "tri3", size = [1.0, 1.0], divisions = [1, 1] }"#).replace("{clamp}", "x_min"))];
    let mut finals = Vec::new();
    for (tag, text) in variants {
        let path = dir.join(format!("{tag}.toml"));
        std::fs::write(&path, text).unwrap();
        let loaded = bifirst::scene::load_scene(&path, &[]).expect("scene loads");
        let out = dir.join(format!("{tag}.mcap"));
        bifirst::run::run_scene(&loaded, &out, &Default::default(), &mut bifirst::run::Silent).expect("runs");
        let log = read_log(&out);
        finals.push((log.series("/energy", "total"), log.vectors("/reaction/clamp", "force")));
    }
    let (a, b) = (&finals[0], &finals[1]);
    for (x, y) in a.0.iter().zip(&b.0) {
        assert!((x - y).abs() <= 1e-12 * x.abs().max(1.0), "energies differ: {x} vs {y}");
    }
    let weight = 9.81;
    let last = a.1.last().unwrap();
    assert!(last[1] > 0.0 && last[1] < 3.0 * weight, "the clamp holds the square up: {last:?}");
}

/// Caught by a user's Gmsh 2.2 file: the parser's first line ("During parsing...") was all the
/// message said.
#[test]
fn an_older_msh_version_is_named_with_the_fix() {
    let legacy = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n$Elements\n1\n1 2 2 0 1 1 2 3\n$EndElements\n";
    let message = gmsh::read(legacy.as_bytes(), None).unwrap_err().to_string();
    assert!(message.contains("MSH version 2.2 is not supported") && message.contains("-format msh41"), "{message}");
}

/// Caught by a second-order mesh: "no Tri3, Quad4, Tet4 or Hex8 elements" did not say what the file had.
#[test]
fn a_second_order_mesh_names_what_it_has() {
    let tri6 = common_gmsh::unit_square_msh(false).replace("2 1 2 2\n2 1 2 3\n3 1 3 4", "2 1 9 2\n2 1 2 3 1 2 3\n3 1 3 4 1 3 4");
    let message = gmsh::read(tri6.as_bytes(), None).unwrap_err().to_string();
    assert!(message.contains("(it has Lin2, Tri6)") && message.contains("first-order"), "{message}");
}

/// The parser's chain of contexts is kept (it was cut to its first line), its hex dump left out.
#[test]
fn a_parse_error_says_where_the_file_is_broken() {
    let broken = common_gmsh::unit_square_msh(false).replace("0 1 0\n$EndNodes", "0 1 x\n");
    let message = gmsh::read(broken.as_bytes(), None).unwrap_err().to_string();
    assert!(message.contains("in node coordinates") && message.contains("z coordinate"), "{message}");
    assert!(!message.contains("Hex dump") && !message.contains('\n'), "{message}");
}

/// `tests/data/five_grains.msh`: five square grains (2 x 2 Quad4 each) stacked with gaps of
/// 0.05, each its own surface and physical group `grain_1`..`grain_5` (written by hand with a
/// short script, as Gmsh would write it).
fn five_grains_scene() -> String {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/five_grains.msh");
    let mut scene = String::from("gravity = [0.0, -10.0]\n[time]\nend = 0.5\ndt = 0.005\nxi = 1.0\ntheta = 1.0\n[material.rubber]\nmodel = \"neo_hookean\"\nG = 1000.0\nK = 2000.0\ndensity = 1.0\n[contact]\nfriction = 0.3\ntwo_pass = true\n[obstacle.floor]\nshape = \"plane\"\npoint = [0.0, 0.0]\nnormal = [0.0, 1.0]\n");
    for g in 1..=5 {
        scene += &format!("[body.grain_{g}]\nmaterial = \"rubber\"\nmesh = {{ file = {:?}, group = \"grain_{g}\" }}\n", file.display().to_string());
    }
    scene
}

/// Caught by the issue: grains meshed in one Gmsh file became one body, without self-contact,
/// so they could pass through each other. Each physical group is now a body of its own.
#[test]
fn five_grains_of_one_gmsh_file_are_five_bodies_that_land_on_each_other() {
    let path = temp_path("five_grains.toml");
    std::fs::write(&path, five_grains_scene()).unwrap();
    let loaded = bifirst::scene::load_scene(&path, &[]).unwrap();
    let mut sim = bifirst::solver::build_simulation(&loaded).unwrap();
    assert_eq!(sim.bodies().len(), 5);
    assert!(sim.bodies().iter().all(|b| b.mesh().element_count() == 4 && b.mesh().nodes.len() == 9), "each body holds its own group");
    let h = sim.bodies().iter().map(|b| b.length_scale()).fold(f64::INFINITY, f64::min);
    sim.start();
    let mut deepest: f64 = 0.0;
    while !sim.finished() {
        let report = sim.advance().unwrap_or_else(|f| panic!("step {} failed: {}", f.step, f.failure));
        deepest = deepest.max(report.contact.max_overlap);
    }
    // Each grain rests on the one below: four body pairs carry a reaction.
    let mut pairs: Vec<(u32, u32)> = sim
        .contact_points()
        .iter()
        .filter(|c| c.r[0] > 0.0)
        .filter_map(|c| match c.master {
            bifirst::contact::Master::Body(m) => Some((c.slave_body.min(m), c.slave_body.max(m))),
            _ => None,
        })
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    assert_eq!(pairs, [(0, 1), (1, 2), (2, 3), (3, 4)], "grains in contact at the end");
    assert!(deepest < 0.01 * h, "a node went {deepest:e} into another grain");
    let tops: Vec<f64> = sim.bodies().iter().map(|b| (0..b.mesh().nodes.len()).map(|n| b.position(n)[1]).fold(f64::NEG_INFINITY, f64::max)).collect();
    assert!(tops.windows(2).all(|w| w[1] > w[0] + 0.3), "the stack keeps its order: {tops:?}");
}

#[test]
fn a_missing_physical_group_names_the_groups_there_are() {
    let bytes = std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/five_grains.msh")).unwrap();
    let message = gmsh::read(&bytes, Some("grain_9")).unwrap_err().to_string();
    assert!(message.contains("no physical group `grain_9` of quad4 elements") && message.contains("grain_1, grain_2, grain_3, grain_4, grain_5"), "{message}");
}
