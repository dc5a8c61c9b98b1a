//! Contact detection: boundary surfaces of every element kind, the narrow-phase projections,
//! the broad phase against brute force, and node-to-segment contact between two bodies with the
//! two-pass treatment.

#[path = "common/run.rs"]
mod common_run;
use bifirst::contact::detect::{detect, Detection};
use bifirst::contact::geometry::{dot, on_quad, on_segment, sub};
use bifirst::contact::pairs::{BodyPairs, Rank};
use bifirst::contact::{Configuration, ContactModel, Master, Settings, Surface, Sweep};
use bifirst::mesh::generate::{cuboid, disk, rectangle};
use bifirst::mesh::{ElementKind, Mesh};
use bifirst::scene::parse_scene;

/// Two bodies, the upper one (1) the slave on the lower one (0).
fn upper_on_lower(mu: f64) -> BodyPairs {
    let rank = Rank { length_scale: 1.0, boundary_nodes: 0 };
    let mut pairs = BodyPairs::new(vec![rank; 2], None, false);
    pairs.list(0, 1, mu, Some(1));
    pairs
}

/// The contact model of two bodies, the upper one (1) the slave on the lower one (0), friction
/// 0.2, and the meshes' nodes as the positions.
fn upper_on_lower_model(meshes: &[Mesh]) -> (ContactModel, Vec<Vec<[f64; 3]>>) {
    let model = ContactModel {
        settings: Settings { tolerance: 1e-8, max_iterations: 10, sweep: Sweep::GaussSeidel, acceleration: Default::default(), fallback: Default::default() },
        surfaces: meshes.iter().map(Surface::of).collect(),
        obstacles: Vec::new(),
        pairs: upper_on_lower(0.2),
    };
    (model, meshes.iter().map(|m| m.nodes.clone()).collect())
}

fn facet_normal(mesh: &Mesh, facet: &[u32]) -> [f64; 3] {
    let x: Vec<[f64; 3]> = facet.iter().map(|&n| mesh.nodes[n as usize]).collect();
    match x.len() {
        2 => {
            let d = sub(x[1], x[0]);
            [d[1], -d[0], 0.0]
        }
        3 => bifirst::contact::geometry::cross(sub(x[1], x[0]), sub(x[2], x[0])),
        _ => bifirst::contact::geometry::cross(sub(x[2], x[0]), sub(x[3], x[1])),
    }
}

/// Facets of a convex body point away from its centre.
fn assert_outward(mesh: &Mesh, surface: &Surface) {
    let n = mesh.nodes.len() as f64;
    let c = [0, 1, 2].map(|i| mesh.nodes.iter().map(|x| x[i]).sum::<f64>() / n);
    for f in 0..surface.facet_count() {
        let facet = surface.facet(f);
        let m = [0, 1, 2].map(|i| facet.iter().map(|&k| mesh.nodes[k as usize][i]).sum::<f64>() / facet.len() as f64);
        assert!(dot(facet_normal(mesh, facet), sub(m, c)) > 0.0, "facet {facet:?} points inwards");
    }
}

#[test]
fn boundary_surfaces_of_every_element_kind() {
    for (kind, per_cell) in [(ElementKind::Quad4, 1), (ElementKind::Tri3, 1)] {
        let mesh = rectangle([0.0, 0.0], [2.0, 1.0], [4, 3], kind);
        let s = Surface::of(&mesh);
        assert_eq!(s.facet_count(), per_cell * 2 * (4 + 3), "{kind:?}");
        assert_eq!(s.nodes.len(), 2 * (4 + 3));
        assert_outward(&mesh, &s);
    }
    for (kind, per_face) in [(ElementKind::Hex8, 1), (ElementKind::Tet4, 2)] {
        let mesh = cuboid([0.0; 3], [1.0, 2.0, 3.0], [2, 3, 4], kind);
        let s = Surface::of(&mesh);
        assert_eq!(s.facet_count(), per_face * 2 * (2 * 3 + 3 * 4 + 2 * 4), "{kind:?}");
        assert_eq!(s.nodes.len(), 3 * 4 * 5 - 2 * 3);
        assert_outward(&mesh, &s);
    }
    let mesh = disk([0.0, 0.0], 1.0, 3, ElementKind::Quad4);
    let s = Surface::of(&mesh);
    assert_eq!(s.facet_count(), 4 * 6);
    assert_outward(&mesh, &s);
}

#[test]
fn projections_give_gap_weights_and_frame() {
    let p = on_segment([0.25, 0.5, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0).unwrap();
    // Outward normal of a -> b is the direction turned clockwise: -y here, so the point above has
    // a negative gap (it is inside the body that owns the segment).
    assert!((p.gap + 0.5).abs() < 1e-15 && (p.weights[0] - 0.75).abs() < 1e-15 && (p.weights[1] - 0.25).abs() < 1e-15);
    assert!(on_segment([1.5, 0.5, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.02).is_none());
    // A quadrilateral face (counter-clockwise seen from +z, normal +z).
    let quad = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let p = on_quad([0.5, 0.25, 0.1], quad, 0.0).unwrap();
    assert!((p.gap - 0.1).abs() < 1e-15);
    // The weights interpolate the foot of the projection and sum to one.
    let foot = [0, 1, 2].map(|i| (0..4).map(|k| p.weights[k] * quad[k][i]).sum::<f64>());
    assert!((foot[0] - 0.5).abs() < 1e-14 && (foot[1] - 0.25).abs() < 1e-14 && foot[2].abs() < 1e-15);
    assert!((p.weights.iter().sum::<f64>() - 1.0).abs() < 1e-15);
}

/// Two boxes, one slightly sunk into the other: the grid finds the same points as trying every
/// facet, for node counts where the grid has many cells.
#[test]
fn broad_phase_finds_what_brute_force_finds() {
    for kind in [ElementKind::Hex8, ElementKind::Tet4] {
        let lower = cuboid([0.0; 3], [1.0, 1.0, 0.5], [6, 6, 3], kind);
        let mut upper = cuboid([0.13, 0.21, 0.49], [0.6, 0.5, 0.4], [5, 4, 3], kind);
        // A wavy bottom: some nodes in contact, some open, some just out of reach.
        for x in &mut upper.nodes {
            if x[2] < 0.5 {
                x[2] += 0.015 * (11.0 * x[0]).sin() * (7.0 * x[1]).cos();
            }
        }
        let meshes = [lower, upper];
        let surfaces: Vec<Surface> = meshes.iter().map(Surface::of).collect();
        let (model, positions) = upper_on_lower_model(&meshes);
        let margin = 0.01;
        let mut config = Configuration::new(&model, positions.clone());
        let found = detect(&model, &mut config, &|_, _| unreachable!("every body is placed"), 3, 0.0, 0.1, margin, &mut Default::default());
        // Brute force: every boundary node of the slave against every facet of the master.
        let mut expected = 0;
        for &node in &surfaces[1].nodes {
            let x = positions[1][node as usize];
            let best = (0..surfaces[0].facet_count())
                .filter_map(|f| {
                    let fx: Vec<[f64; 3]> = surfaces[0].facet(f).iter().map(|&n| positions[0][n as usize]).collect();
                    let p = if fx.len() == 3 { bifirst::contact::geometry::on_triangle(x, fx[0], fx[1], fx[2], 0.02) } else { on_quad(x, [fx[0], fx[1], fx[2], fx[3]], 0.02) }?;
                    let size = (0..fx.len()).flat_map(|i| (0..fx.len()).map(move |j| (i, j))).map(|(i, j)| dot(sub(fx[i], fx[j]), sub(fx[i], fx[j])).sqrt()).fold(0.0, f64::max);
                    (p.gap <= margin && p.gap >= -0.5 * size).then_some(p.gap)
                })
                .min_by(|a, b| a.abs().total_cmp(&b.abs()));
            if let Some(gap) = best {
                expected += 1;
                let c = found.iter().find(|c| c.slave_node == node).unwrap_or_else(|| panic!("node {node} missed"));
                assert!((c.gap - gap).abs() < 1e-14, "node {node}: gap {} vs {gap}", c.gap);
                assert_eq!(c.master, Master::Body(0));
            }
        }
        assert_eq!(found.len(), expected, "{kind:?}");
        assert!(expected > 10, "the test must exercise real contacts ({expected})");
    }
}

/// Two identical confined bars meet head-on (node-to-segment, both bodies slave in turn): each
/// behaves as a bar hitting a wall, so contact lasts 2 L / c and the velocities swap.
#[test]
fn two_bars_head_on_with_two_passes() {
    let text = std::fs::read_to_string(common_run::scene_path("bar_impact")).unwrap();
    let text = text.split("[obstacle.wall]").next().unwrap().replace("[body.bar]", "[body.left]").replace("body = \"bar\"", "body = \"left\"");
    let text = format!(
        "{text}\n[contact]\nfriction = 0.0\ntwo_pass = true\n\n[body.right]\nmaterial = \"bar\"\nmesh = {{ generator = \"rectangle\", element = \"quad4\", origin = [1.002, 0.0], size = [1.0, 0.01], divisions = [200, 1] }}\ninitial_velocity = [-0.5, 0.0]\n\n[boundary.confine_right]\nbody = \"right\"\nnodes = \"all\"\ncomponents = [\"y\"]\n"
    );
    let text = text.replacen("initial_velocity = [-0.5, 0.0]", "initial_velocity = [0.5, 0.0]", 1).replace("origin = [0.001, 0.0]", "origin = [0.0, 0.0]");
    let path = common_run::temp_path("two_bars.toml");
    std::fs::write(&path, &text).unwrap();
    let loaded = parse_scene(&path, text, &[]).expect("scene parses");
    let out = common_run::temp_path("two_bars.mcap");
    bifirst::run::run_scene(&loaded, &out, &Default::default(), &mut bifirst::run::Silent).expect("run");
    let log = common_run::read_log(&out);
    let t = log.series("/contact", "t");
    let active = log.series("/contact", "active");
    let touching: Vec<f64> = t.iter().zip(&active).filter(|(_, &a)| a > 0.0).map(|(t, _)| *t).collect();
    let duration = touching.last().unwrap() - touching.first().unwrap() + (t[1] - t[0]);
    let v = |b: &str| {
        let m = log.topics[&format!("/body/{b}")].last().unwrap().clone();
        m["linear_momentum"][0].as_f64().unwrap() / m["mass"].as_f64().unwrap()
    };
    let (left, right) = (v("left"), v("right"));
    let penetration = log.series("/contact", "max_penetration").into_iter().fold(0.0, f64::max);
    println!("two bars: duration {duration:.5} (2L/c = 0.02), velocities {left:.4} / {right:.4}, penetration {penetration:.1e}");
    assert!((duration - 0.02).abs() <= 0.03 * 0.02);
    assert!((left + 0.5).abs() <= 0.02 * 0.5 && (right - 0.5).abs() <= 0.02 * 0.5);
    assert!((left + right).abs() < 1e-9, "momentum is conserved");
    assert!(penetration <= 0.01 * 0.005);
}

/// A slave node in a concave corner of its master (a notch in the master's top, the slave's
/// bottom shaped to it) is held by both facets of the corner; over a flat top, by one. Held by
/// the nearer facet alone, grains pressed into a dented neighbour sank through the other facet
/// by 2.9 % of an element, whatever the step (`grains_many` at 10x the wall speed).
#[test]
fn a_node_in_a_concave_corner_is_held_by_both_facets() {
    for notch in [0.1, 0.0] {
        let mut lower = rectangle([0.0, 0.0], [2.0, 1.0], [4, 2], ElementKind::Quad4);
        let mut upper = rectangle([0.9, 0.0], [0.2, 0.1], [2, 1], ElementKind::Quad4);
        // The master's top: down by `notch` at x = 1, straight to x = 0.5 and 1.5.
        let top = |x: f64| 1.0 - notch * (1.0 - (x - 1.0).abs() / 0.5).max(0.0);
        for x in &mut lower.nodes {
            if x[1] == 1.0 {
                x[1] = top(x[0]);
            }
        }
        // The slave's bottom 0.005 above it, its top 0.1 higher.
        for x in &mut upper.nodes {
            x[1] += top(x[0]) + 0.005;
        }
        let meshes = [lower, upper];
        let (model, positions) = upper_on_lower_model(&meshes);
        let mut config = Configuration::new(&model, positions.clone());
        let found = detect(&model, &mut config, &|_, _| unreachable!("every body is placed"), 2, 0.0, 0.1, 0.01, &mut Default::default());
        let middle = upper_node(&meshes[1], 1.0);
        let at_middle: Vec<_> = found.iter().filter(|c| c.slave_node == middle).collect();
        assert_eq!(found.len(), if notch > 0.0 { 4 } else { 3 }, "notch {notch}: {} points", found.len());
        assert!(found.iter().all(|c| c.slave_body == 1 && c.master == Master::Body(0) && (c.gap - 0.005 * (1.0 / (1.0 + 4.0 * notch * notch)).sqrt()).abs() < 1e-12));
        if notch > 0.0 {
            assert_eq!(at_middle.len(), 2);
            assert!(!at_middle[0].corner && at_middle[1].corner);
            assert_ne!(at_middle[0].key(), at_middle[1].key(), "each keeps its own warm start");
            // One point on each side of the notch: normals mirrored about the vertical.
            let (a, b) = (at_middle[0].frame[0], at_middle[1].frame[0]);
            assert!((a[0] + b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12 && a[0].abs() > 0.1, "{a:?} {b:?}");
        } else {
            assert_eq!(at_middle.len(), 1);
            assert!(!at_middle[0].corner);
        }
    }
}

/// The lowest node of a mesh at x.
fn upper_node(mesh: &Mesh, x: f64) -> u32 {
    let column = |p: &&[f64; 3]| (p[0] - x).abs() < 1e-12;
    let lowest = mesh.nodes.iter().filter(column).map(|p| p[1]).fold(f64::INFINITY, f64::min);
    mesh.nodes.iter().position(|p| column(&p) && p[1] == lowest).expect("a node at x") as u32
}

/// Caught by issue 59's falling packing: two bodies whose boxes come within half a facet of
/// each other, but farther apart than the search margin, were placed for the narrow phase every
/// step (the body pairs' boxes were grown by the depth a point may have as well), and a device
/// that kept the grains' states sent each such grain's displacements back: 55 bytes a grain a
/// step of the 236 that 20 000 falling grains moved. No node of either can make a point with
/// the other, so neither is placed; within the margin, both are, and their points found.
#[test]
fn bodies_farther_apart_than_the_margin_are_not_placed_for_the_narrow_phase() {
    let margin = 0.01;
    for (gap, placed) in [(0.05, false), (0.005, true)] {
        let lower = rectangle([0.0, 0.0], [1.0, 0.5], [4, 2], ElementKind::Quad4);
        let upper = rectangle([0.2, 0.5 + gap], [1.0, 0.5], [4, 2], ElementKind::Quad4);
        let meshes = [lower, upper];
        let (model, positions) = upper_on_lower_model(&meshes);
        let mut config = Configuration::new(&model, positions);
        // The facets are 0.25 long: half of one (the deepest a point may be) is beyond the gap.
        assert!(gap < 0.5 * 0.25);
        let detection = Detection::new(&model, &config, 0.0, 0.1, margin, &mut Default::default());
        assert_eq!(detection.needed, vec![placed; 2], "gap {gap}");
        let found = detection.points(&model, &mut config, &|_, _| unreachable!("every body is placed"), 2, margin);
        assert_eq!(found.is_empty(), !placed, "gap {gap}: {} points", found.len());
    }
}

/// The 3D twin of the corner rule (issue 55, item 2): a slave node on a concave edge of its
/// master (a V-shaped groove along y in the master's top, the slave's bottom shaped to it) is
/// held by a facet on each side of the groove; over a flat top, by one. Held by the nearer
/// facet alone, a node pressed into a dent's edge could sink through the facet across it.
#[test]
fn a_node_on_a_concave_edge_is_held_by_both_sides_in_3d() {
    for notch in [0.1, 0.0] {
        let mut lower = cuboid([0.0, 0.0, 0.0], [2.0, 1.0, 1.0], [4, 2, 2], ElementKind::Hex8);
        let mut upper = cuboid([0.9, 0.25, 0.0], [0.2, 0.5, 0.1], [2, 2, 1], ElementKind::Hex8);
        // The master's top: down by `notch` at x = 1, straight to x = 0.5 and 1.5.
        let top = |x: f64| 1.0 - notch * (1.0 - (x - 1.0).abs() / 0.5).max(0.0);
        for x in &mut lower.nodes {
            if x[2] == 1.0 {
                x[2] = top(x[0]);
            }
        }
        // The slave's bottom 0.005 above it, its top 0.1 higher.
        for x in &mut upper.nodes {
            x[2] += top(x[0]) + 0.005;
        }
        let meshes = [lower, upper];
        let (model, positions) = upper_on_lower_model(&meshes);
        let mut config = Configuration::new(&model, positions.clone());
        let found = detect(&model, &mut config, &|_, _| unreachable!("every body is placed"), 3, 0.0, 0.1, 0.01, &mut Default::default());
        // The slave's bottom: 3 x 3 nodes, the middle row (x = 1) on the groove's edge.
        let slave = &meshes[1].nodes;
        let on_edge: Vec<u32> = (0..slave.len() as u32).filter(|&n| (slave[n as usize][0] - 1.0).abs() < 1e-12 && slave[n as usize][2] < top(1.0) + 0.01).collect();
        assert_eq!(on_edge.len(), 3);
        let gap = 0.005 * (1.0 / (1.0 + 4.0 * notch * notch)).sqrt();
        assert!(found.iter().all(|c| c.slave_body == 1 && c.master == Master::Body(0) && (c.gap - gap).abs() < 1e-12), "notch {notch}: gaps {:?}", found.iter().map(|c| c.gap).collect::<Vec<_>>());
        assert_eq!(found.len(), if notch > 0.0 { 12 } else { 9 }, "notch {notch}: {} points", found.len());
        for node in on_edge {
            let here: Vec<_> = found.iter().filter(|c| c.slave_node == node).collect();
            if notch > 0.0 {
                assert_eq!(here.len(), 2, "node {node}");
                assert!(!here[0].corner && here[1].corner);
                // One point on each side of the groove: normals mirrored about the vertical.
                let (a, b) = (here[0].frame[0], here[1].frame[0]);
                assert!((a[0] + b[0]).abs() < 1e-12 && a[1].abs() < 1e-12 && b[1].abs() < 1e-12 && (a[2] - b[2]).abs() < 1e-12 && a[0].abs() > 0.1, "{a:?} {b:?}");
            } else {
                assert_eq!(here.len(), 1);
                assert!(!here[0].corner);
            }
        }
    }
}

/// A slave node inside the corner of a box (behind the top by 0.03, behind the side by 0.01)
/// is held by the side, which is askew to the node's downward normal, and not by the top that
/// faces it: out through the nearer facet. A node as far behind the top but farther behind the
/// side stays on the top.
#[test]
fn a_node_inside_a_box_corner_is_held_by_the_nearer_askew_facet() {
    for (side, askew_holds) in [(0.01, true), (0.025, false)] {
        let lower = cuboid([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2, 2, 2], ElementKind::Hex8);
        // The slave's bottom middle node (normal straight down) at x = 1 - side, 0.03 below the top.
        let mut upper = cuboid([0.0, 0.0, 0.0], [0.2, 0.2, 0.1], [2, 2, 1], ElementKind::Hex8);
        for x in &mut upper.nodes {
            (x[0], x[1], x[2]) = (x[0] + 0.9 - side, x[1] + 0.4, x[2] + 0.97);
        }
        let meshes = [lower, upper];
        let middle = meshes[1].nodes.iter().position(|x| (x[0] - (1.0 - side)).abs() < 1e-12 && (x[1] - 0.5).abs() < 1e-12 && (x[2] - 0.97).abs() < 1e-12).expect("the middle node") as u32;
        let (model, positions) = upper_on_lower_model(&meshes);
        let mut config = Configuration::new(&model, positions);
        let found = detect(&model, &mut config, &|_, _| unreachable!("every body is placed"), 3, 0.0, 0.1, 0.01, &mut Default::default());
        let here: Vec<_> = found.iter().filter(|c| c.slave_node == middle).collect();
        assert_eq!(here.len(), 1, "side {side}: {} points", here.len());
        let (n, gap) = (here[0].frame[0], here[0].gap);
        if askew_holds {
            assert!((n[0] - 1.0).abs() < 1e-12 && (gap + side).abs() < 1e-12, "side {side}: normal {n:?}, gap {gap}");
        } else {
            assert!((n[2] - 1.0).abs() < 1e-12 && (gap + 0.03).abs() < 1e-12, "side {side}: normal {n:?}, gap {gap}");
        }
    }
}
