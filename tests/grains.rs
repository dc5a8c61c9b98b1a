//! Granular measures (`bifirst grains`) against answers known in closed form: lattices of equal
//! disks and spheres under a uniform pressure, a rattler, the exponential force tail; and a run's
//! contact network read back by the command.

#[path = "common/run.rs"]
mod common_run;

use bifirst::grains::{force_distribution, measure, orientation_rose, window_means, Contact, Network, Other, Wall, ROSE_SECTORS};
use common_run::{run, temp_path};
use std::f64::consts::PI;

/// The contact of grain `a` with `b` (or a wall) at `point`, the force `f` pressing along
/// `normal` (from the other side towards `a`).
fn pressing(a: usize, other: Other, point: [f64; 3], normal: [f64; 3], f: f64) -> Contact {
    Contact { body: a, other, point, normal, force: normal.map(|n| f * n), normal_force: f, sliding: false }
}

/// `n` per side equal grains of radius `r` on a simple lattice in `dim` dimensions, each pair of
/// neighbours and each grain on the box's faces pressed by `p` times a grain's cross-section,
/// the walls the box `[0, 2rn]^dim` (obstacle `2i` the lower face along axis `i`, `2i + 1` the
/// upper).
fn simple_lattice(dim: usize, n: usize, r: f64, p: f64) -> Network {
    let cells: Vec<[usize; 3]> = (0..n.pow(dim as u32)).map(|k| std::array::from_fn(|i| if i < dim { (k / n.pow(i as u32)) % n } else { 0 })).collect();
    let index = |c: [usize; 3]| (0..dim).map(|i| c[i] * n.pow(i as u32)).sum::<usize>();
    let center = |c: [usize; 3]| std::array::from_fn(|i| if i < dim { r * (2 * c[i] + 1) as f64 } else { 0.0 });
    let f = p * if dim == 2 { 2.0 * r } else { 4.0 * r * r };
    let side = 2.0 * r * n as f64;
    let mut contacts = Vec::new();
    let mut walls = Vec::new();
    for axis in 0..dim {
        let e: [f64; 3] = std::array::from_fn(|i| (i == axis) as usize as f64);
        walls.push(Wall { obstacle: 2 * axis, point: [0.0; 3], normal: e });
        walls.push(Wall { obstacle: 2 * axis + 1, point: e.map(|x| x * side), normal: e.map(|x| -x) });
        for &c in &cells {
            let (a, x) = (index(c), center(c));
            if c[axis] + 1 < n {
                let mut up = c;
                up[axis] += 1;
                // The lower grain is pressed back by the upper one.
                let point = std::array::from_fn(|i| x[i] + r * e[i]);
                contacts.push(pressing(a, Other::Body(index(up)), point, e.map(|x| -x), f));
            }
            if c[axis] == 0 {
                contacts.push(pressing(a, Other::Obstacle(2 * axis), std::array::from_fn(|i| x[i] - r * e[i]), e, f));
            }
            if c[axis] == n - 1 {
                contacts.push(pressing(a, Other::Obstacle(2 * axis + 1), std::array::from_fn(|i| x[i] + r * e[i]), e.map(|x| -x), f));
            }
        }
    }
    let volume = if dim == 2 { PI * r * r } else { 4.0 / 3.0 * PI * r.powi(3) };
    Network { t: 1.0, dim, centers: cells.iter().map(|c| center(*c)).collect(), volumes: vec![volume; cells.len()], walls, contacts }
}

fn names(dim: usize) -> Vec<String> {
    ["left", "right", "bottom", "top", "back", "front"][..2 * dim].iter().map(|s| s.to_string()).collect()
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance * b.abs().max(1e-300)
}

#[test]
fn a_square_lattice_under_uniform_pressure_has_z_4_an_isotropic_fabric_and_the_walls_stress() {
    let p = 3.5;
    let m = measure(&simple_lattice(2, 6, 0.5, p), &names(2));
    println!("{m:?}");
    assert_eq!((m.grains, m.rattlers), (36, 0));
    assert!(close(m.coordination, 4.0, 1e-12) && close(m.coordination_without_rattlers, 4.0, 1e-12));
    assert!(close(m.fabric[0][0], 0.5, 1e-12) && close(m.fabric[1][1], 0.5, 1e-12) && m.fabric[0][1].abs() < 1e-12 && m.fabric_anisotropy < 1e-12);
    // The Love-Weber stress is the walls' pressure, within 1 %.
    for i in 0..2 {
        assert!(close(m.stress[i][i], p, 0.01), "σ_{i}{i} = {}", m.stress[i][i]);
    }
    assert!(close(m.pressure, m.wall_pressure, 0.01) && close(m.wall_pressure, p, 1e-12) && m.deviator < 1e-9 * p);
    assert!(m.walls.iter().all(|w| close(w.pressure, p, 1e-12)), "{:?}", m.walls);
    assert!(close(m.solid_fraction, PI / 4.0, 1e-12));
    // Half of the normals along x, half along y.
    let rose = orientation_rose(&simple_lattice(2, 6, 0.5, p));
    assert!(close(rose[0], 0.5, 1e-12) && close(rose[ROSE_SECTORS / 2], 0.5, 1e-12), "{rose:?}");
}

/// `--window`: the means over the logged steps within the window before the chosen step, the
/// step at its start included (the times are rounded, as logged times are), each wall by name.
#[test]
fn window_means_take_the_steps_of_the_window_and_no_other() {
    let rows: Vec<_> = (0..=10)
        .map(|k| {
            let mut net = simple_lattice(2, 4, 0.5, k as f64);
            net.t = 0.1 * k as f64;
            measure(&net, &names(2))
        })
        .collect();
    let w = window_means(&rows, 10, 0.3);
    assert_eq!(w.steps, 4, "t = 0.7, 0.8, 0.9 and 1.0");
    assert!(close(w.from, 0.7, 1e-12) && close(w.to, 1.0, 1e-12));
    assert!(close(w.wall_pressure, 8.5, 1e-12) && close(w.pressure, 8.5, 0.01), "{w:?}");
    assert!(w.walls.iter().all(|wall| close(wall.pressure, 8.5, 1e-12)) && w.walls.len() == 4, "{:?}", w.walls);
    assert!(close(w.coordination, rows[10].coordination, 1e-12) && w.deviator < 1e-9);
    let before = window_means(&rows, 5, 0.15);
    assert_eq!((before.steps, before.to), (2, rows[5].t), "the window ends at the chosen step");
    let all = window_means(&rows, 10, 100.0);
    assert!(all.steps == 11 && close(all.wall_pressure, 5.0, 1e-12));
}

#[test]
fn a_simple_cubic_stack_of_spheres_has_z_6_and_the_walls_stress() {
    let p = 0.8;
    let m = measure(&simple_lattice(3, 4, 1.0, p), &names(3));
    assert_eq!((m.grains, m.rattlers), (64, 0));
    assert!(close(m.coordination, 6.0, 1e-12) && close(m.coordination_without_rattlers, 6.0, 1e-12));
    for i in 0..3 {
        assert!(close(m.fabric[i][i], 1.0 / 3.0, 1e-12) && close(m.stress[i][i], p, 0.01), "{:?} {:?}", m.fabric, m.stress);
    }
    assert!(close(m.pressure, m.wall_pressure, 0.01) && m.fabric_anisotropy < 1e-12 && m.deviator < 1e-9);
    assert!(close(m.solid_fraction, PI / 6.0, 1e-12));
}

/// Equal disks on a triangular lattice of `n x n` sites wrapped into a torus: every grain
/// touches six.
#[test]
fn a_hexagonal_lattice_has_z_6_and_an_isotropic_fabric() {
    let (n, r, f) = (8usize, 1.0, 2.0);
    let index = |i: usize, j: usize| (j % n) * n + (i % n);
    let center = |i: usize, j: usize| [2.0 * r * (i as f64 + 0.5 * j as f64), 3f64.sqrt() * r * j as f64, 0.0];
    let mut contacts = Vec::new();
    for j in 0..n {
        for i in 0..n {
            // Three of the six neighbours each; the other three count from their side.
            for (di, dj) in [(1, 0), (0, 1), (n - 1, 1)] {
                let angle: f64 = match (di, dj) {
                    (1, 0) => 0.0,
                    (0, 1) => PI / 3.0,
                    _ => 2.0 * PI / 3.0,
                };
                let e = [angle.cos(), angle.sin(), 0.0];
                let x = center(i, j);
                contacts.push(pressing(index(i, j), Other::Body(index(i + di, j + dj)), std::array::from_fn(|k| x[k] + r * e[k]), e.map(|x| -x), f));
            }
        }
    }
    let net = Network { t: 0.0, dim: 2, centers: (0..n * n).map(|k| center(k % n, k / n)).collect(), volumes: vec![PI * r * r; n * n], walls: Vec::new(), contacts };
    let m = measure(&net, &[]);
    assert!(close(m.coordination, 6.0, 1e-12) && m.rattlers == 0 && close(m.coordination_without_rattlers, 6.0, 1e-12));
    assert!(close(m.fabric[0][0], 0.5, 1e-12) && close(m.fabric[1][1], 0.5, 1e-12) && m.fabric[0][1].abs() < 1e-12);
}

/// A grain resting on one other is a rattler; without it its neighbour keeps four contacts.
#[test]
fn a_grain_with_one_contact_is_a_rattler() {
    let mut net = simple_lattice(2, 3, 0.5, 1.0);
    net.centers.push([1.5, 3.5, 0.0]);
    net.volumes.push(PI * 0.25);
    let top_middle = 7;
    net.contacts.push(pressing(top_middle, Other::Body(9), [1.5, 3.0, 0.0], [0.0, -1.0, 0.0], 0.1));
    let m = measure(&net, &names(2));
    assert_eq!(m.rattlers, 1);
    assert!(close(m.coordination, (36.0 + 2.0) / 10.0, 1e-12), "Z = {}", m.coordination);
    assert!(close(m.coordination_without_rattlers, 4.0, 1e-12), "Z without rattlers = {}", m.coordination_without_rattlers);
}

/// Normal forces at the quantiles of an exponential distribution: the fitted tail decays as
/// `exp(-f/<f>)`.
#[test]
fn the_tail_of_exponentially_distributed_forces_decays_at_rate_one() {
    let count = 20_000;
    let contacts = (0..count).map(|k| pressing(0, Other::Obstacle(0), [0.0; 3], [0.0, 1.0, 0.0], -(1.0 - (k as f64 + 0.5) / count as f64).ln())).collect();
    let net = Network { t: 0.0, dim: 2, centers: vec![[0.0; 3]], volumes: vec![1.0], walls: Vec::new(), contacts };
    let d = force_distribution(&net);
    let beta = d.tail_decay.expect("a tail");
    println!("mean {}, β = {beta}", d.mean_normal_force);
    assert!(close(d.mean_normal_force, 1.0, 0.01) && close(beta, 1.0, 0.1), "β = {beta}");
    let total: f64 = d.bins.iter().map(|b| b[1]).sum::<f64>() * 0.2;
    assert!(close(total, 1.0, 1e-9), "a density: {total}");
}

/// A packing's run logs its contact network, and `bifirst grains` reads it back: the CSV has a
/// row per logged network, the pictures are PNGs, and the measures are those of a packing.
#[test]
fn a_packing_run_logs_its_network_and_the_command_measures_it() {
    let sets = ["packing.count=16", "time.end=0.2", "output.scene_every=0", "output.contacts_every=5"];
    let log = run("grains_many", &sets, "grains_network");
    let networks = &log.topics["/contacts"];
    let run_message = &log.topics["/run"][0];
    assert_eq!(run_message["body_names"].as_array().unwrap().len(), 16);
    assert_eq!(run_message["obstacle_names"].as_array().unwrap().len(), 4);
    let last = networks.last().unwrap();
    assert!(!last["body"].as_array().unwrap().is_empty(), "contacts by the end: {last}");
    let path = temp_path("grains_network.mcap");
    let out = temp_path("grains_network_measures");
    let _ = std::fs::remove_dir_all(&out);
    let result = std::process::Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["grains", path.to_str().unwrap(), "--json", "--out", out.to_str().unwrap()]).output().unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(result.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&result.stdout).expect("a JSON report");
    let csv = std::fs::read_to_string(out.join("grains.csv")).unwrap();
    assert_eq!(csv.lines().count(), networks.len() + 1, "a row per network");
    for png in ["force_chains.png", "grains_series.png", "force_pdf.png", "rose.png"] {
        let bytes = std::fs::read(out.join(png)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{png}");
    }
    let at = &report["at"];
    let fraction = at["solid_fraction"].as_f64().unwrap();
    assert!(fraction > 0.2 && fraction < 0.95, "solid fraction {fraction}");
    assert!(at["contacts"].as_u64().unwrap() > 0 && at["coordination"].as_f64().unwrap() > 0.0, "{at}");
    // Older logs, or runs without a network, are told why.
    let plain = run("bar_impact", &["time.end=0.001", "output.scene_every=0"], "grains_no_network");
    assert!(!plain.topics.contains_key("/contacts"));
    let none = std::process::Command::new(env!("CARGO_BIN_EXE_bifirst")).args(["grains", temp_path("grains_no_network.mcap").to_str().unwrap(), "--out", out.to_str().unwrap()]).output().unwrap();
    assert_eq!(none.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&none.stderr).contains("no contact network"));
}

/// `packing.wall_until` stops the pushing wall: a compression, then a hold in which a packing
/// can come to rest and its Love-Weber stress be compared with the walls'.
#[test]
fn the_pushing_wall_stops_at_wall_until() {
    let sets = ["packing.count=4", "packing.wall_velocity=10.0", "packing.wall_until=0.01", "time.end=0.03", "output.scene_every=0", "output.contacts_every=1"];
    let log = run("grains_many", &sets, "grains_wall_until");
    let left = log.topics["/run"][0]["obstacle_names"].as_array().unwrap().iter().position(|n| n == "left").expect("a left wall");
    let x_of = |m: &serde_json::Value| {
        let k = m["wall"].as_array().unwrap().iter().position(|w| w.as_u64() == Some(left as u64)).unwrap();
        m["wall_point"][2 * k].as_f64().unwrap()
    };
    for m in &log.topics["/contacts"] {
        let (t, x) = (m["t"].as_f64().unwrap(), x_of(m));
        let expected = 10.0 * t.min(0.01);
        assert!((x - expected).abs() < 1e-9, "t = {t}: the wall at {x}, not {expected}");
    }
}
