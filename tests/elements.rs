//! Elements: homogeneous deformations give the closed-form stress at every quadrature point;
//! the internal force is the gradient of the strain energy and the tangent the gradient of the
//! force (finite differences), for every element type and material.

#[path = "common/random.rs"]
mod common_random;

use bifirst::element::{element_energy, element_force_tangent, element_stresses, ElementOutput, Formulation, Patches, ReferenceGeometry};
use bifirst::material::tensor::{green_lagrange, to_voigt, Mat3};
use bifirst::material::{BlatzKo, Hyperelastic, Lvf, Model, NeoHookean};
use bifirst::mesh::{generate, ElementKind, Mesh};
use common_random::{random_f, rng};
use rand::Rng;

fn models() -> Vec<Model> {
    vec![Model::BlatzKo(BlatzKo { g: 3.0 }), Model::NeoHookean(NeoHookean { g: 2.0, k: 7.0 }), Model::Lvf(Lvf { g: 5.0, k: 3.333, a1: 0.05, a2: 0.05, a3: 0.4, a4: 2.0, a5: 0.1 })]
}

/// One element of each kind with its reference nodes moved randomly (still valid).
fn distorted_element(kind: ElementKind, r: &mut impl Rng) -> Mesh {
    let mut mesh = match kind.dim() {
        2 => generate::rectangle([0.0, 0.0], [1.0, 1.0], [1, 1], kind),
        _ => generate::cuboid([0.0; 3], [1.0; 3], [1, 1, 1], kind),
    };
    for x in &mut mesh.nodes {
        for c in x.iter_mut().take(kind.dim()) {
            *c += r.random_range(-0.1..0.1);
        }
    }
    mesh
}

fn plane_strain(mut f: Mat3) -> Mat3 {
    f[(0, 2)] = 0.0;
    f[(1, 2)] = 0.0;
    f[(2, 0)] = 0.0;
    f[(2, 1)] = 0.0;
    f[(2, 2)] = 1.0;
    f
}

const KINDS: [ElementKind; 4] = [ElementKind::Tri3, ElementKind::Quad4, ElementKind::Tet4, ElementKind::Hex8];

/// Every element kind with every formulation it has.
fn elements() -> Vec<(ElementKind, Formulation)> {
    KINDS.iter().flat_map(|&k| std::iter::once((k, Formulation::Displacement)).chain(Formulation::fbar_applies(k).then_some((k, Formulation::Fbar)))).collect()
}

#[test]
fn homogeneous_deformation_gives_the_closed_form_stress() {
    let mut r = rng(21);
    for (kind, formulation) in elements() {
        for model in models() {
            for _ in 0..10 {
                let mesh = distorted_element(kind, &mut r);
                let geometry = ReferenceGeometry::new(&mesh).unwrap();
                let mut f = random_f(&mut r);
                if kind.dim() == 2 {
                    while plane_strain(f).determinant() <= 0.3 {
                        f = random_f(&mut r);
                    }
                    f = plane_strain(f);
                }
                let u: Vec<[f64; 3]> = mesh
                    .element(0)
                    .iter()
                    .map(|&n| {
                        let x = mesh.nodes[n as usize];
                        let v = (f - Mat3::identity()) * nalgebra::Vector3::new(x[0], x[1], x[2]);
                        [v[0], v[1], v[2]]
                    })
                    .collect();
                let expected = to_voigt(&model.stress(&green_lagrange(&f)));
                for s in element_stresses(&model, geometry.element_points(0), &u, kind.dim(), formulation) {
                    let err = (s - expected).norm() / expected.norm();
                    assert!(err < 1e-10, "{kind:?} {formulation:?} {model:?}: stress error {err:e}");
                }
            }
        }
    }
}

fn random_displacements(mesh: &Mesh, r: &mut impl Rng) -> Vec<[f64; 3]> {
    let dim = mesh.dim();
    mesh.element(0)
        .iter()
        .map(|_| {
            let mut u = [0.0; 3];
            for c in u.iter_mut().take(dim) {
                *c = r.random_range(-0.12..0.12);
            }
            u
        })
        .collect()
}

#[test]
fn force_is_the_gradient_of_the_energy_and_tangent_the_gradient_of_the_force() {
    let mut r = rng(22);
    let mut out = ElementOutput::default();
    let mut plus = ElementOutput::default();
    let mut minus = ElementOutput::default();
    for (kind, formulation) in elements() {
        let dim = kind.dim();
        for model in models() {
            for _ in 0..5 {
                let mesh = distorted_element(kind, &mut r);
                let geometry = ReferenceGeometry::new(&mesh).unwrap();
                let points = geometry.element_points(0);
                let u = random_displacements(&mesh, &mut r);
                element_force_tangent(&model, points, &u, dim, formulation, None, true, &mut out).expect("valid deformation");
                let n = u.len() * dim;
                let h = 1e-6;
                let (mut fd_force, mut fd_tangent) = (vec![0.0; n], vec![0.0; n * n]);
                for j in 0..n {
                    let (mut up, mut um) = (u.clone(), u.clone());
                    up[j / dim][j % dim] += h;
                    um[j / dim][j % dim] -= h;
                    fd_force[j] = (element_energy(&model, points, &up, dim, formulation) - element_energy(&model, points, &um, dim, formulation)) / (2.0 * h);
                    element_force_tangent(&model, points, &up, dim, formulation, None, false, &mut plus).unwrap();
                    element_force_tangent(&model, points, &um, dim, formulation, None, false, &mut minus).unwrap();
                    for i in 0..n {
                        fd_tangent[i * n + j] = (plus.force[i] - minus.force[i]) / (2.0 * h);
                    }
                }
                let rel = |a: &[f64], b: &[f64]| {
                    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
                    d / b.iter().map(|y| y * y).sum::<f64>().sqrt()
                };
                let (ef, ek) = (rel(&fd_force, &out.force), rel(&fd_tangent, &out.tangent));
                assert!(ef < 1e-6, "{kind:?} {formulation:?} {model:?}: force error {ef:e}");
                assert!(ek < 1e-6, "{kind:?} {formulation:?} {model:?}: tangent error {ek:e}");
            }
        }
    }
}

#[test]
fn lumped_masses_sum_to_the_body_mass() {
    for (kind, volume) in [(ElementKind::Tri3, 2.0), (ElementKind::Quad4, 2.0), (ElementKind::Tet4, 6.0), (ElementKind::Hex8, 6.0)] {
        let mesh = match kind.dim() {
            2 => generate::rectangle([0.0, 0.0], [2.0, 1.0], [3, 2], kind),
            _ => generate::cuboid([0.0; 3], [1.0, 2.0, 3.0], [2, 2, 3], kind),
        };
        let m: f64 = ReferenceGeometry::new(&mesh).unwrap().lumped_masses(&mesh, 1.5).iter().sum();
        assert!((m - 1.5 * volume).abs() < 1e-12, "{kind:?}: mass {m}");
    }
    let disk = generate::disk([0.0, 0.0], 1.0, 8, ElementKind::Quad4);
    let area: f64 = ReferenceGeometry::new(&disk).unwrap().volumes.iter().sum();
    assert!((area - std::f64::consts::PI).abs() < 0.02, "disk area {area}");
}

#[test]
fn annulus_mesh_is_positive_closes_on_itself_and_names_its_edges() {
    for kind in [ElementKind::Quad4, ElementKind::Tri3] {
        let ring = generate::annulus([1.0, -1.0], [1.0, 2.0], 360.0, [4, 32], kind);
        assert_eq!(ring.nodes.len(), 32 * 5, "{kind:?}: the full ring shares its first and last spokes");
        let area: f64 = ReferenceGeometry::new(&ring).expect("positive elements").volumes.iter().sum();
        let exact = 3.0 * std::f64::consts::PI;
        assert!((area / exact - 1.0).abs() < 0.01, "{kind:?}: area {area} vs {exact}");
        assert!(!ring.node_sets.contains_key("start") && ring.node_sets["inner"].len() == 32);
        let quarter = generate::annulus([0.0, 0.0], [1.0, 2.0], 90.0, [4, 8], kind);
        let geometry = ReferenceGeometry::new(&quarter).expect("positive elements");
        assert_eq!((quarter.node_sets["start"].len(), quarter.node_sets["end"].len(), quarter.node_sets["outer"].len()), (5, 5, 9));
        assert!(quarter.node_sets["end"].iter().all(|&n| quarter.nodes[n as usize][0].abs() < 1e-12), "`end` lies on the y axis");
        assert!(geometry.volumes.iter().sum::<f64>() < exact / 4.0);
    }
}

#[test]
fn polygon_mesh_is_conforming_positive_and_fills_the_outline() {
    let hexagon: Vec<[f64; 2]> = (0..6).map(|i| (i as f64 * -std::f64::consts::FRAC_PI_3 + 0.2).sin_cos()).map(|(s, c)| [1.0 + c, 2.0 + s]).collect();
    let outlines = [vec![[0.0, 0.0], [2.0, 0.0], [0.5, 1.5]], vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], hexagon];
    for outline in outlines {
        let m = outline.len();
        let area: f64 = (0..m).map(|i| outline[i][0] * outline[(i + 1) % m][1] - outline[(i + 1) % m][0] * outline[i][1]).sum::<f64>().abs() / 2.0;
        for n in [1, 3] {
            let mesh = generate::polygon(&outline, n);
            assert_eq!(mesh.element_count(), m * n * n);
            let geometry = ReferenceGeometry::new(&mesh).expect("every triangle is positively oriented");
            let meshed: f64 = geometry.volumes.iter().sum();
            assert!((meshed - area).abs() < 1e-12 * area, "{m}-gon, n = {n}: area {meshed} vs {area}");
            // Conforming: every edge is shared by two triangles, except the m n edges of the outline.
            let mut edges = std::collections::BTreeMap::new();
            for e in 0..mesh.element_count() {
                let t = mesh.element(e);
                for i in 0..3 {
                    let (a, b) = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                    *edges.entry((a, b)).or_insert(0) += 1;
                }
            }
            assert_eq!(edges.values().filter(|&&c| c == 1).count(), m * n, "{m}-gon, n = {n}: outline edges");
            assert!(edges.values().all(|&c| c <= 2));
            assert_eq!(mesh.node_sets["boundary"].len(), m * n);
        }
    }
}

/// Caught by the issue: a non-finite displacement failed as an "inverted element (det F = NaN)".
#[test]
fn a_non_finite_state_is_not_an_inverted_element() {
    let mesh = generate::rectangle([0.0; 2], [1.0, 1.0], [1, 1], ElementKind::Quad4);
    let geometry = ReferenceGeometry::new(&mesh).unwrap();
    let model = BlatzKo { g: 1000.0 };
    let mut u = vec![[0.0; 3]; 4];
    u[2][0] = f64::NAN;
    let error = element_force_tangent(&model, geometry.element_points(0), &u, 2, Formulation::Displacement, None, true, &mut ElementOutput::default()).unwrap_err();
    assert!(matches!(error, bifirst::element::ElementError::NonFinite), "{error:?}");
    u[2][0] = -3.0;
    let error = element_force_tangent(&model, geometry.element_points(0), &u, 2, Formulation::Displacement, None, true, &mut ElementOutput::default()).unwrap_err();
    assert!(matches!(error, bifirst::element::ElementError::Inverted(_)), "{error:?}");
}

/// The patch test: a homogeneous deformation of a patch of distorted elements is an
/// equilibrium (the interior nodes carry no force), for every element and formulation.
#[test]
fn a_homogeneous_deformation_of_a_distorted_patch_is_in_equilibrium() {
    let mut r = rng(23);
    for (kind, formulation) in elements() {
        let dim = kind.dim();
        let mut mesh = match dim {
            2 => generate::rectangle([0.0, 0.0], [1.0, 1.0], [3, 3], kind),
            _ => generate::cuboid([0.0; 3], [1.0; 3], [3, 3, 3], kind),
        };
        let interior = |x: &[f64; 3]| (0..dim).all(|i| x[i] > 1e-9 && x[i] < 1.0 - 1e-9);
        for x in mesh.nodes.iter_mut().filter(|x| interior(x)) {
            for c in x.iter_mut().take(dim) {
                *c += r.random_range(-0.08..0.08);
            }
        }
        let geometry = ReferenceGeometry::new(&mesh).unwrap();
        for model in models() {
            let mut f = random_f(&mut r);
            if dim == 2 {
                while plane_strain(f).determinant() <= 0.3 {
                    f = random_f(&mut r);
                }
                f = plane_strain(f);
            }
            let u: Vec<f64> = mesh
                .nodes
                .iter()
                .flat_map(|x| {
                    let v = (f - Mat3::identity()) * nalgebra::Vector3::new(x[0], x[1], x[2]);
                    (0..dim).map(move |i| v[i])
                })
                .collect();
            let mut force = vec![0.0; u.len()];
            let mut out = ElementOutput::default();
            for e in 0..mesh.element_count() {
                element_force_tangent(&model, geometry.element_points(e), &mesh.element_displacements(&u, e), dim, formulation, None, false, &mut out).unwrap();
                for (a, &n) in mesh.element(e).iter().enumerate() {
                    for i in 0..dim {
                        force[n as usize * dim + i] += out.force[a * dim + i];
                    }
                }
            }
            let scale = force.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let worst = (0..mesh.nodes.len()).filter(|&n| interior(&mesh.nodes[n])).flat_map(|n| (0..dim).map(move |i| n * dim + i)).fold(0.0f64, |m, d| m.max(force[d].abs()));
            assert!(worst < 1e-11 * scale, "{kind:?} {formulation:?} {model:?}: interior force {worst:e} of {scale:e}");
        }
    }
}

/// Internal forces of a whole mesh (every element, assembled) at nodal displacements `u`.
fn assembled_forces(mesh: &Mesh, geometry: &ReferenceGeometry, model: &Model, u: &[[f64; 3]], formulation: Formulation) -> Vec<f64> {
    let dim = mesh.dim();
    let mut f = vec![0.0; mesh.nodes.len() * dim];
    let mut out = ElementOutput::default();
    for e in 0..mesh.element_count() {
        let nodes = mesh.element(e);
        let ue: Vec<[f64; 3]> = nodes.iter().map(|&n| u[n as usize]).collect();
        element_force_tangent(model, geometry.element_points(e), &ue, dim, formulation, None, false, &mut out).expect("valid deformation");
        for (a, &n) in nodes.iter().enumerate() {
            for i in 0..dim {
                f[n as usize * dim + i] += out.force[a * dim + i];
            }
        }
    }
    f
}

/// F-bar on Tri3 and Tet4 runs the Quad4 and Hex8 kernels on the cells the simplices split
/// (`ReferenceGeometry::simplex_patches`): with the displacement formulation those cells must
/// give the simplices' own forces and masses exactly, and with F-bar a homogeneous deformation
/// must stay the displacement element's (θ = J).
#[test]
fn simplex_patches_are_the_simplices_and_fbar_on_them_passes_the_patch_test() {
    let mut r = rng(29);
    let model = Model::NeoHookean(NeoHookean { g: 1000.0, k: 50_000.0 });
    let meshes = [
        (generate::annulus([0.0, 0.0], [1.0, 2.0], 90.0, [3, 4], ElementKind::Tri3), generate::annulus([0.0, 0.0], [1.0, 2.0], 90.0, [3, 4], ElementKind::Quad4)),
        (generate::ball([0.0; 3], 1.0, 1, ElementKind::Tet4), generate::ball([0.0; 3], 1.0, 1, ElementKind::Hex8)),
    ];
    for (simplices, cells) in meshes {
        let kind = simplices.kind;
        assert_eq!(simplices.nodes, cells.nodes, "{kind:?}: the same nodes");
        let (plain, patches) = (ReferenceGeometry::new(&simplices).unwrap(), ReferenceGeometry::simplex_patches(&cells).unwrap());
        let (m0, m1) = (plain.lumped_masses(&simplices, 2.0), patches.lumped_masses(&cells, 2.0));
        assert!(m0.iter().zip(&m1).all(|(a, b)| (a - b).abs() < 1e-13 * a.abs().max(1e-300)), "{kind:?}: lumped masses");
        let dim = kind.dim();
        let u: Vec<[f64; 3]> = simplices.nodes.iter().map(|_| std::array::from_fn(|i| if i < dim { r.random_range(-0.03..0.03) } else { 0.0 })).collect();
        let (f0, f1) = (assembled_forces(&simplices, &plain, &model, &u, Formulation::Displacement), assembled_forces(&cells, &patches, &model, &u, Formulation::Displacement));
        let scale = f0.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(f0.iter().zip(&f1).all(|(a, b)| (a - b).abs() < 1e-12 * scale), "{kind:?}: forces of the cells integrated as simplices");
        // A homogeneous deformation: every simplex has J = θ, so F-bar changes nothing.
        let f = random_f(&mut r);
        let f = if dim == 2 { plane_strain(f) } else { f };
        let homogeneous: Vec<[f64; 3]> = cells.nodes.iter().map(|x| std::array::from_fn(|i| (0..3).map(|j| (f[(i, j)] - if i == j { 1.0 } else { 0.0 }) * x[j]).sum())).collect();
        let (fd, fb) = (assembled_forces(&cells, &patches, &model, &homogeneous, Formulation::Displacement), assembled_forces(&cells, &patches, &model, &homogeneous, Formulation::Fbar));
        let scale = fd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(fd.iter().zip(&fb).all(|(a, b)| (a - b).abs() < 1e-10 * scale), "{kind:?}: F-bar patches under a homogeneous deformation");
    }
}

/// A Gmsh mesh of `tests/data`.
fn gmsh_mesh(file: &str) -> Mesh {
    let bytes = std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(file)).unwrap();
    bifirst::mesh::gmsh::read(&bytes, None).unwrap()
}

/// Simplices without generator cells (a polygon's fan, Gmsh files): `Patches::group` gathers
/// neighbours into Quad4 or Hex8 cells. Every simplex is in one patch, with its nodes; the
/// patches integrate the simplices' own masses and forces; F-bar on them passes the patch test
/// and its tangent is the derivative of its force, repeated padding nodes included.
#[test]
fn grouped_patches_are_the_simplices_and_fbar_on_them_passes_the_patch_test() {
    let mut r = rng(30);
    let model = Model::NeoHookean(NeoHookean { g: 1000.0, k: 50_000.0 });
    let hexagon: Vec<[f64; 2]> = (0..6).map(|k| std::f64::consts::FRAC_PI_3 * k as f64).map(|a| [a.cos(), a.sin()]).collect();
    // Simplices per patch, at least (2 and 8 at most).
    for (mesh, fill) in [(generate::polygon(&hexagon, 6), 1.9), (gmsh_mesh("beam_tri3.msh"), 1.9), (gmsh_mesh("beam_tet4.msh"), 4.0)] {
        let kind = mesh.kind;
        let dim = kind.dim();
        let patches = Patches::group(&mesh);
        let cells = &patches.cells;
        let mut taken = vec![false; cells.element_count() * patches.points_per_cell];
        for e in 0..mesh.element_count() {
            let (patch, point) = patches.slot(e);
            assert!(!std::mem::replace(&mut taken[patch * patches.points_per_cell + point], true), "{kind:?}: simplex {e} shares its point");
            assert!(mesh.element(e).iter().all(|n| cells.element(patch).contains(n)), "{kind:?}: simplex {e}'s nodes in its patch");
        }
        let per_patch = mesh.element_count() as f64 / cells.element_count() as f64;
        assert!(per_patch >= fill, "{kind:?}: {per_patch:.2} simplices per patch");
        let plain = ReferenceGeometry::new(&mesh).unwrap();
        let grouped = ReferenceGeometry::grouped(&plain, &mesh, &patches);
        let (m0, m1) = (plain.lumped_masses(&mesh, 2.0), grouped.lumped_masses(cells, 2.0));
        assert!(m0.iter().zip(&m1).all(|(a, b)| (a - b).abs() < 1e-13 * a.abs()), "{kind:?}: lumped masses");
        let u: Vec<[f64; 3]> = mesh.nodes.iter().map(|_| std::array::from_fn(|i| if i < dim { r.random_range(-0.01..0.01) } else { 0.0 })).collect();
        let (f0, f1) = (assembled_forces(&mesh, &plain, &model, &u, Formulation::Displacement), assembled_forces(cells, &grouped, &model, &u, Formulation::Displacement));
        let scale = f0.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(f0.iter().zip(&f1).all(|(a, b)| (a - b).abs() < 1e-12 * scale), "{kind:?}: forces of the patches");
        let f = random_f(&mut r);
        let f = if dim == 2 { plane_strain(f) } else { f };
        let homogeneous: Vec<[f64; 3]> = mesh.nodes.iter().map(|x| std::array::from_fn(|i| (0..3).map(|j| (f[(i, j)] - if i == j { 1.0 } else { 0.0 }) * x[j]).sum())).collect();
        let (fd, fb) = (assembled_forces(cells, &grouped, &model, &homogeneous, Formulation::Displacement), assembled_forces(cells, &grouped, &model, &homogeneous, Formulation::Fbar));
        let scale = fd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(fd.iter().zip(&fb).all(|(a, b)| (a - b).abs() < 1e-10 * scale), "{kind:?}: F-bar patches under a homogeneous deformation");
        // The tangent of the first patches, against central differences of the force.
        let (mut out, mut plus, mut minus) = (ElementOutput::default(), ElementOutput::default(), ElementOutput::default());
        for p in 0..3 {
            let points = grouped.element_points(p);
            let ue: Vec<[f64; 3]> = cells.element(p).iter().map(|&n| u[n as usize]).collect();
            element_force_tangent(&model, points, &ue, dim, Formulation::Fbar, None, true, &mut out).unwrap();
            let n = ue.len() * dim;
            let h = 1e-7;
            let mut worst: f64 = 0.0;
            for j in 0..n {
                let (mut up, mut um) = (ue.clone(), ue.clone());
                up[j / dim][j % dim] += h;
                um[j / dim][j % dim] -= h;
                element_force_tangent(&model, points, &up, dim, Formulation::Fbar, None, false, &mut plus).unwrap();
                element_force_tangent(&model, points, &um, dim, Formulation::Fbar, None, false, &mut minus).unwrap();
                for i in 0..n {
                    worst = worst.max(((plus.force[i] - minus.force[i]) / (2.0 * h) - out.tangent[i * n + j]).abs());
                }
            }
            let scale = out.tangent.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(worst < 1e-6 * scale, "{kind:?}: patch {p}'s tangent is {:.2e} from the force's differences", worst / scale);
        }
    }
}

/// Strain energy of the mesh whose boundary nodes (on its bounding box) are held at `u` and
/// whose other nodes are in equilibrium, linearised about the reference state.
fn held_boundary_energy(mesh: &Mesh, geometry: &ReferenceGeometry, model: &Model, formulation: Formulation, u: &[[f64; 3]]) -> f64 {
    let dim = mesh.dim();
    let (lo, hi): (Vec<f64>, Vec<f64>) = (0..dim).map(|i| (mesh.nodes.iter().map(|x| x[i]).fold(f64::MAX, f64::min), mesh.nodes.iter().map(|x| x[i]).fold(f64::MIN, f64::max))).unzip();
    let on_boundary = |x: &[f64; 3]| (0..dim).any(|i| (x[i] - lo[i]).abs() < 1e-9 || (x[i] - hi[i]).abs() < 1e-9);
    let mut free = vec![usize::MAX; mesh.nodes.len() * dim];
    let mut count = 0;
    for (n, x) in mesh.nodes.iter().enumerate() {
        if !on_boundary(x) {
            for i in 0..dim {
                free[n * dim + i] = count;
                count += 1;
            }
        }
    }
    let full: Vec<f64> = mesh.nodes.iter().enumerate().flat_map(|(n, _)| (0..dim).map(move |i| (n, i))).map(|(n, i)| u[n][i]).collect();
    let (mut k, mut rhs) = (nalgebra::DMatrix::<f64>::zeros(count, count), nalgebra::DVector::<f64>::zeros(count));
    let mut out = ElementOutput::default();
    for e in 0..mesh.element_count() {
        let nodes = mesh.element(e);
        element_force_tangent(model, geometry.element_points(e), &vec![[0.0; 3]; nodes.len()], dim, formulation, None, true, &mut out).unwrap();
        let n = nodes.len() * dim;
        let dof = |a: usize| nodes[a / dim] as usize * dim + a % dim;
        for a in 0..n {
            let r = free[dof(a)];
            if r == usize::MAX {
                continue;
            }
            for b in 0..n {
                match free[dof(b)] {
                    usize::MAX => rhs[r] -= out.tangent[a * n + b] * full[dof(b)],
                    c => k[(r, c)] += out.tangent[a * n + b],
                }
            }
        }
    }
    let solved = k.cholesky().expect("positive definite").solve(&rhs);
    let mut x = full.clone();
    for (d, &f) in free.iter().enumerate() {
        if f != usize::MAX {
            x[d] = solved[f];
        }
    }
    (0..mesh.element_count())
        .map(|e| {
            let ue: Vec<[f64; 3]> = mesh.element(e).iter().map(|&n| std::array::from_fn(|i| if i < dim { x[n as usize * dim + i] } else { 0.0 })).collect();
            element_energy(model, geometry.element_points(e), &ue, dim, formulation)
        })
        .sum()
}

/// Pure bending `u = κ (-x y, (x² + y²) / 2)` held on a rectangle's boundary: nearly
/// incompressible, the body between bends with energy `2 G κ² ∫ y² dA` (the pressure `2 G κ y`
/// keeps it in equilibrium). Displacement Tri3 lock, their energy growing with K; F-bar on the
/// grouped patches of a polygon's fan and of a Gmsh mesh stays where it was at K/G = 100.
/// (Tet4 patches are checked by their beam's period, `tests/incompressible.rs`: in this test,
/// with every boundary node held, a coarse Tet4 mesh has about as many patches as free dofs.)
#[test]
fn grouped_fbar_patches_bend_without_locking() {
    let (g, kappa) = (1000.0, 1e-6);
    let rectangle = [[0.0, 0.0], [4.0, 0.0], [4.0, 1.0], [0.0, 1.0]];
    // The F-bar energy's bound against the exact one: the fan's triangles are long and thin.
    for (name, mesh, bound) in [("polygon fan", generate::polygon(&rectangle, 8), 1.7), ("gmsh tri3", gmsh_mesh("beam_tri3.msh"), 1.02)] {
        let plain = ReferenceGeometry::new(&mesh).unwrap();
        let patches = Patches::group(&mesh);
        let grouped = ReferenceGeometry::grouped(&plain, &mesh, &patches);
        let area: f64 = plain.volumes.iter().sum();
        let u: Vec<[f64; 3]> = mesh
            .nodes
            .iter()
            .map(|x| {
                let (x, y) = (x[0], x[1] - 0.5);
                [-kappa * x * y, kappa * (x * x + y * y) / 2.0, 0.0]
            })
            .collect();
        // ∫ y² dA of a 4 x 1 rectangle: its area / 12.
        let exact = 2.0 * g * kappa * kappa * area / 12.0;
        let energies = |k: f64| {
            let model = Model::NeoHookean(NeoHookean { g, k });
            (held_boundary_energy(&mesh, &plain, &model, Formulation::Displacement, &u), held_boundary_energy(&patches.cells, &grouped, &model, Formulation::Fbar, &u))
        };
        let ((locked_100, fbar_100), (locked, fbar)) = (energies(1e5), energies(1e8));
        assert!(locked > 100.0 * locked_100, "{name}: the displacement element locks ({locked:.3e} at K/G = 1e5, {locked_100:.3e} at 1e2)");
        assert!(fbar < 1.05 * fbar_100, "{name}: F-bar patches stiffen with K ({fbar:.3e} at K/G = 1e5, {fbar_100:.3e} at 1e2)");
        assert!(fbar > exact && fbar < bound * exact, "{name}: F-bar patches give {:.3} of the bending energy", fbar / exact);
    }
}
