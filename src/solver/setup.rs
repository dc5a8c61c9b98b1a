//! Builds a [`Simulation`] from a validated scene: meshes, materials, constraints, probes.
//! Every failure here is a [`SceneError`] pointing at the key responsible.

use super::body::{Body, NodalLoad, Prescribed};
use super::state_overlaps;
use super::topology::{Topology, TopologyKey};
use super::{BoundarySet, Probe, Simulation};
use crate::contact::obstacle::Shape;
use crate::contact::overlap::{Host, Overlap};
use crate::contact::pairs::{BodyPairs, Rank};
use crate::contact::{ContactModel, Motion, Obstacle, Settings, Surface};
use crate::element::{Formulation, Patches, ReferenceGeometry, FBAR_ABOVE_K_OVER_G};
use crate::material::{Model, Prony, Viscoelastic};
use crate::mesh::{generate, gmsh, ElementKind, Mesh};
use crate::precision::Real;
use crate::scene::SceneErrorKind::{Invalid, Mesh as MeshError, Reference};
use crate::scene::LARGEST_INPUT;
use crate::scene::{AngularVelocity, Axis, FormulationChoice, Generator, Interpolation, LoadSpec, LoadedScene, MaterialSpec, MeshSpec, ObstacleShape, SceneError};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// A body's element formulation: the scene's choice, or for `auto` F-bar where K/G exceeds
/// [`FBAR_ABOVE_K_OVER_G`] (on Quad4 and Hex8 elements, on the cells a generator split into
/// simplices, or on patches of any other simplices). Displacement elements chosen for a nearly
/// incompressible material get a notice that they lock.
fn formulation_of(material: &str, choice: FormulationChoice, model: &Model, notices: &mut Vec<String>) -> Formulation {
    let (k, g) = model.bulk_shear();
    let ratio = k / g;
    match choice {
        FormulationChoice::Fbar => Formulation::Fbar,
        FormulationChoice::Auto if ratio > FBAR_ABOVE_K_OVER_G => Formulation::Fbar,
        FormulationChoice::Auto => Formulation::Displacement,
        FormulationChoice::Displacement => {
            if ratio > FBAR_ABOVE_K_OVER_G {
                let notice = format!("material `{material}` (K/G = {ratio:.3e}) on displacement elements locks: the bodies will be too stiff (formulation = \"auto\" takes F-bar)");
                if !notices.contains(&notice) {
                    notices.push(notice);
                }
            }
            Formulation::Displacement
        }
    }
}

/// The cell kind a generated Tri3 or Tet4 mesh splits (its F-bar patches), if it has cells:
/// rectangles, disks and annuli split quadrilaterals, boxes and balls hexahedra.
fn simplex_cells(spec: &MeshSpec, kind: ElementKind) -> Option<ElementKind> {
    let cells = matches!(spec.generator, Some(Generator::Rectangle | Generator::Disk | Generator::Annulus | Generator::Box | Generator::Ball));
    match kind {
        ElementKind::Tri3 if cells => Some(ElementKind::Quad4),
        ElementKind::Tet4 if cells => Some(ElementKind::Hex8),
        _ => None,
    }
}

/// The largest small-strain K/G a material may have: beyond it f64 leaves the shear response
/// fewer than four digits (regression: the fuzz test's K = 1e28 on G = 1000 created energy).
pub const MAX_K_OVER_G: Real = 1e12;

/// The material's Prony series, if it has one.
pub fn viscoelastic_of(m: &MaterialSpec) -> Option<Viscoelastic> {
    let terms = m.viscoelastic.as_ref()?;
    Some(Viscoelastic { terms: terms.iter().map(|t| Prony { g: t.g, tau: t.tau }).collect() })
}

/// The model of a material the scene's checks passed (its name is the registry's).
pub fn model_of(m: &MaterialSpec) -> Model {
    Model::from_parameters(&m.model.0, &m.parameters).expect("a model name is checked as the scene is read")
}

/// The mesh a body's `mesh` table describes (generated, or read from its file).
pub fn build_mesh(loaded: &LoadedScene, key: &str, spec: &MeshSpec) -> Result<Mesh, SceneError> {
    let v = |o: &Option<Vec<Real>>, i: usize| o.as_ref().map(|x| x[i]).unwrap_or(0.0);
    let kind = spec.element;
    let mut mesh = match (spec.generator, &spec.file) {
        (Some(Generator::Rectangle), _) => {
            let (s, d) = (spec.size.as_ref().expect("validated"), spec.divisions.as_ref().expect("validated"));
            generate::rectangle([v(&spec.origin, 0), v(&spec.origin, 1)], [s[0], s[1]], [d[0], d[1]], kind.expect("validated"))
        }
        (Some(Generator::Disk), _) => generate::disk([v(&spec.center, 0), v(&spec.center, 1)], spec.radius.expect("validated"), spec.divisions.as_ref().expect("validated")[0], kind.expect("validated")),
        (Some(Generator::Annulus), _) => {
            let (r, d) = (spec.radii.as_ref().expect("validated"), spec.divisions.as_ref().expect("validated"));
            generate::annulus([v(&spec.center, 0), v(&spec.center, 1)], [r[0], r[1]], spec.angle.unwrap_or(360.0), [d[0], d[1]], kind.expect("validated"))
        }
        (Some(Generator::Polygon), _) => {
            let points: Vec<[Real; 2]> = spec.points.as_ref().expect("validated").iter().map(|p| [p[0], p[1]]).collect();
            generate::polygon(&points, spec.divisions.as_ref().expect("validated")[0])
        }
        (Some(Generator::Box), _) => {
            let (s, d) = (spec.size.as_ref().expect("validated"), spec.divisions.as_ref().expect("validated"));
            generate::cuboid([v(&spec.origin, 0), v(&spec.origin, 1), v(&spec.origin, 2)], [s[0], s[1], s[2]], [d[0], d[1], d[2]], kind.expect("validated"))
        }
        (None, Some(file)) => {
            let path = loaded.base_dir().join(file);
            let bytes = std::fs::read(&path).map_err(|e| loaded.error(Reference, &format!("{key}.file"), format!("cannot read the mesh file `{}`: {e}.", path.display())))?;
            gmsh::read(&bytes, spec.group.as_deref()).map_err(|e| loaded.error(MeshError, &format!("{key}.file"), format!("the Gmsh file `{}` is not usable: {e}.", path.display())))?
        }
        (Some(Generator::Ball), _) => generate::ball([v(&spec.center, 0), v(&spec.center, 1), v(&spec.center, 2)], spec.radius.expect("validated"), spec.divisions.as_ref().expect("validated")[0], kind.expect("validated")),
        (None, None) => unreachable!("validated: a mesh has a generator or a file"),
    };
    if let Some(w) = &spec.rotation {
        generate::rotate(&mut mesh, [w[0], w[1], w[2]]);
    }
    Ok(mesh)
}

/// The most time steps a wave may cross a free body's smallest element in: the mass term
/// `c1 M ~ ρ h^d / dt²` of `K̄` holds off the body's rigid modes, and past this it falls below
/// the round-off of the stiffness (`~ G h^(d-2)`) by more than f64 resolves, and the
/// factorisation fails (grains of radius 1e-30 under a step of 1e-3: "not positive definite").
pub const MAX_FREE_BODY_COURANT: Real = 1e6;

/// A body without supports must have its rigid modes held by the mass term of `K̄`: refused
/// when `time.dt` is beyond [`MAX_FREE_BODY_COURANT`] times the time a pressure wave takes
/// across its smallest element `h`.
fn free_body_step(loaded: &LoadedScene, body: &Body, density: Real) -> Result<(), SceneError> {
    let (k, g) = body.def.model.bulk_shear();
    let (h, body) = (body.length_scale(), &body.def.name);
    let wave_speed = ((k + 4.0 * g / 3.0) / density).sqrt();
    let dt = loaded.scene.time.dt;
    let courant = wave_speed * dt / h;
    if courant > MAX_FREE_BODY_COURANT || !courant.is_finite() {
        let message = format!(
            "the step is {courant:.3e} times the time a wave takes across the smallest element of body `{body}` (h = {h:.3e}, wave speed {wave_speed:.3e}), beyond {MAX_FREE_BODY_COURANT:.0e}: the mass term that holds an unsupported body's rigid modes is below the round-off of its stiffness; lower time.dt or give the body larger elements (grains: packing.radius)."
        );
        return Err(loaded.error(Invalid, "time.dt", message));
    }
    Ok(())
}

const RANGE_WHY: &str = " (energies multiply such numbers and must stay finite)";

fn within_range(v: &[Real]) -> bool {
    v.iter().all(|x| x.abs() <= LARGEST_INPUT)
}

/// The nodal forces of a surface load: each boundary facet whose nodes all belong to the load's
/// node set carries its area times the traction (or the pressure against its outward normal),
/// in equal shares to its nodes (the consistent forces of a segment or a triangle, and of a
/// parallelogram).
fn nodal_load(loaded: &LoadedScene, key: &str, spec: &LoadSpec, mesh: &Mesh) -> Result<NodalLoad, SceneError> {
    let nodes = mesh.node_sets.get(&spec.nodes).ok_or_else(|| {
        let known: Vec<&str> = mesh.node_sets.keys().map(String::as_str).collect();
        loaded.error(Reference, &format!("{key}.nodes"), format!("body `{}` has no node set `{}` (it has: {}).", spec.body, spec.nodes, known.join(", ")))
    })?;
    let dim = mesh.dim();
    let surface = Surface::of(mesh);
    let mut force = vec![0.0; mesh.nodes.len() * dim];
    let mut loaded_facets = 0;
    for f in 0..surface.facet_count() {
        let facet = surface.facet(f);
        if !facet.iter().all(|n| nodes.binary_search(n).is_ok()) {
            continue;
        }
        loaded_facets += 1;
        let (points, count) = surface.facet_points(&mesh.nodes, f);
        let normal = crate::contact::detect::facet_normal(&points[..count]);
        let area = normal.iter().map(|x| x * x).sum::<Real>().sqrt();
        let total: [Real; 3] = match (&spec.traction, spec.pressure) {
            (Some(t), _) => std::array::from_fn(|i| t.get(i).map_or(0.0, |ti| ti * area)),
            (None, Some(p)) => normal.map(|n| -p * n),
            (None, None) => unreachable!("validated: a traction or a pressure"),
        };
        for &n in facet {
            for i in 0..dim {
                force[n as usize * dim + i] += total[i] / count as Real;
            }
        }
    }
    if loaded_facets == 0 {
        return Err(loaded.error(Invalid, &format!("{key}.nodes"), format!("no boundary facet of body `{}` has all its nodes in `{}`: the load would act on nothing.", spec.body, spec.nodes)));
    }
    let forces = force.into_iter().enumerate().filter(|(_, f)| *f != 0.0).collect();
    Ok(NodalLoad { forces, ramp: spec.ramp })
}

/// A body's mesh as its elements are integrated: its name, the mesh, the F-bar patches of an
/// unstructured simplex mesh, the reference geometry and the formulation.
type BodyMesh = (String, Mesh, Option<Patches>, ReferenceGeometry, Formulation);

/// Sets up every body, boundary set and probe of the scene.
pub fn build_simulation(loaded: &LoadedScene) -> Result<Simulation, SceneError> {
    let scene = &loaded.scene;
    check_materials(loaded)?;
    let mut notices = Vec::new();
    let (meshes, dim) = body_meshes(loaded, &mut notices)?;
    let body_index: HashMap<&str, usize> = scene.body.keys().enumerate().map(|(i, n)| (n.as_str(), i)).collect();
    let (sets, prescribed) = prescribed_dofs(loaded, &meshes, &body_index, dim)?;
    let mut bodies = build_bodies(loaded, meshes, prescribed, dim)?;
    for (name, spec) in &scene.load {
        let b = body_index[spec.body.as_str()];
        let load = nodal_load(loaded, &format!("load.{name}"), spec, &bodies[b].def.mesh)?;
        bodies[b].def.loads.push(load);
    }
    let probes = scene
        .probe
        .iter()
        .map(|(name, p)| {
            let b = body_index[p.body.as_str()];
            let mesh = &bodies[b].def.mesh;
            let dist = |x: &[Real; 3]| (0..dim).map(|i| (x[i] - p.point[i]).powi(2)).sum::<Real>();
            let node = (0..mesh.nodes.len()).min_by(|&i, &j| dist(&mesh.nodes[i]).total_cmp(&dist(&mesh.nodes[j]))).expect("a mesh has nodes");
            let elements = (0..mesh.element_count()).filter(|&e| mesh.element(e).contains(&(node as u32))).collect();
            Probe { name: name.clone(), body: b, node, elements }
        })
        .collect();
    let mut gravity = [0.0; 3];
    if let Some(g) = &scene.gravity {
        components_check(loaded, "gravity", g, dim)?;
        range_check(loaded, "gravity", g)?;
        gravity[..dim].copy_from_slice(g);
    }
    let contact = build_contact(loaded, &bodies, dim)?;
    check_initial_state(loaded, &mut bodies, contact.as_ref(), &gravity)?;
    Ok(Simulation {
        notices,
        dim,
        bodies,
        sets,
        probes,
        gravity,
        t: 0.0,
        step: 0,
        end: scene.time.end,
        dt: scene.time.dt,
        xi: scene.time.xi,
        theta: scene.time.theta,
        residual_tolerance: scene.solver.residual_tolerance,
        increment_tolerance: scene.solver.increment_tolerance,
        max_iterations: scene.solver.max_iterations,
        max_cutbacks: scene.solver.max_cutbacks,
        max_overlap: scene.solver.max_overlap,
        max_step_energy_gain: scene.solver.max_step_energy_gain,
        level: 0,
        easy_steps: 0,
        last_overlap: 0.0,
        external_work: 0.0,
        friction_dissipation: 0.0,
        viscous_dissipation: 0.0,
        numerical_dissipation: 0.0,
        contact_correction: 0.0,
        initial_energy: 0.0,
        obstacle_reactions: vec![[0.0; 3]; contact.as_ref().map_or(0, |c| c.obstacles.len())],
        contact,
        contact_points: Vec::new(),
        world: None,
        interrupt: None,
        first_step: (0.0, 0),
        restored_warm_start: None,
        kept_pairs: Default::default(),
        committed: None,
        spare_configuration: Default::default(),
        hold_states: false,
    })
}

/// Every material's K/G within what f64 resolves.
fn check_materials(loaded: &LoadedScene) -> Result<(), SceneError> {
    for (name, material) in &loaded.scene.material {
        let (k, g) = model_of(material).bulk_shear();
        if k / g > MAX_K_OVER_G {
            let message = format!("K/G = {:.3e} is beyond {MAX_K_OVER_G:.0e}: the shear stresses would be below the round-off of the volumetric ones in f64 (rubber is 1e3 to 1e5).", k / g);
            let bulk = Model::entry(&material.model.0).map_or("K", |e| e.bulk);
            return Err(loaded.error(Invalid, &format!("material.{name}.{bulk}"), message));
        }
    }
    Ok(())
}

/// A value within what the energies can multiply.
fn range_check(loaded: &LoadedScene, key: &str, v: &[Real]) -> Result<(), SceneError> {
    if within_range(v) {
        Ok(())
    } else {
        Err(loaded.error(Invalid, key, format!("{v:?} is beyond ±{LARGEST_INPUT:e}{RANGE_WHY}.")))
    }
}

/// A vector with the scene's number of components.
fn components_check(loaded: &LoadedScene, key: &str, v: &[Real], dim: usize) -> Result<(), SceneError> {
    if v.len() == dim {
        Ok(())
    } else {
        Err(loaded.error(Invalid, key, format!("expected {dim} components (the scene is {dim}D), got {}.", v.len())))
    }
}

/// Every body's mesh, as its elements are integrated, and the scene's dimension.
fn body_meshes(loaded: &LoadedScene, notices: &mut Vec<String>) -> Result<(Vec<BodyMesh>, usize), SceneError> {
    let scene = &loaded.scene;
    let mut meshes = Vec::new();
    let mut dim = None;
    for (name, spec) in &scene.body {
        let key = format!("body.{name}.mesh");
        let mesh = build_mesh(loaded, &key, &spec.mesh)?;
        match dim {
            Some(d) if d != mesh.dim() => return Err(loaded.error(Invalid, &key, format!("a {}D mesh in a {d}D scene.", mesh.dim()))),
            _ => dim = Some(mesh.dim()),
        }
        let where_ = if spec.mesh.file.is_some() { format!("{key}.file") } else { key.clone() };
        if let Some((n, x)) = mesh.nodes.iter().enumerate().find(|(_, x)| !within_range(&x[..])) {
            return Err(loaded.error(Invalid, &where_, format!("node {n} is at {x:?}, beyond ±{LARGEST_INPUT:e}{RANGE_WHY}.")));
        }
        let cells = simplex_cells(&spec.mesh, mesh.kind);
        let formulation = formulation_of(&spec.material, spec.formulation.unwrap_or_default(), &model_of(&scene.material[&spec.material]), notices);
        let bad_geometry = |e: crate::element::BadReferenceElement| loaded.error(MeshError, &where_, format!("{e}; the mesh must have positive element volumes at t = 0."));
        // F-bar on simplices averages the volume change over the cells a generator split (the
        // body is meshed by its cells, each integrated as its simplices), or over patches of
        // neighbouring simplices.
        let (mesh, patches, geometry) = match (formulation, cells) {
            (Formulation::Fbar, Some(cell)) => {
                let cells = build_mesh(loaded, &key, &MeshSpec { element: Some(cell), ..spec.mesh.clone() })?;
                let geometry = ReferenceGeometry::simplex_patches(&cells).map_err(bad_geometry)?;
                (cells, None, geometry)
            }
            (Formulation::Fbar, None) if !Formulation::fbar_applies(mesh.kind) => {
                let simplices = ReferenceGeometry::new(&mesh).map_err(bad_geometry)?;
                let patches = Patches::group(&mesh);
                let geometry = ReferenceGeometry::grouped(&simplices, &mesh, &patches);
                (mesh, Some(patches), geometry)
            }
            _ => {
                let geometry = ReferenceGeometry::new(&mesh).map_err(bad_geometry)?;
                (mesh, None, geometry)
            }
        };
        meshes.push((name.clone(), mesh, patches, geometry, formulation));
    }
    Ok((meshes, dim.expect("a scene has a body")))
}

/// The boundary sets, and per body its prescribed dofs.
fn prescribed_dofs(loaded: &LoadedScene, meshes: &[BodyMesh], body_index: &HashMap<&str, usize>, dim: usize) -> Result<(Vec<BoundarySet>, Vec<Vec<Prescribed>>), SceneError> {
    let mut sets = Vec::new();
    let mut prescribed: Vec<Vec<Prescribed>> = vec![Vec::new(); meshes.len()];
    let mut owner: HashMap<(usize, usize), String> = HashMap::new();
    for (set_index, (name, bc)) in loaded.scene.boundary.iter().enumerate() {
        let key = format!("boundary.{name}");
        let b = body_index[bc.body.as_str()];
        let mesh = &meshes[b].1;
        let nodes = mesh.node_sets.get(&bc.nodes).ok_or_else(|| {
            let known: Vec<&str> = mesh.node_sets.keys().map(String::as_str).collect();
            loaded.error(Reference, &format!("{key}.nodes"), format!("body `{}` has no node set `{}` (it has: {}).", bc.body, bc.nodes, known.join(", ")))
        })?;
        if nodes.is_empty() {
            return Err(loaded.error(Invalid, &format!("{key}.nodes"), format!("the node set `{}` of body `{}` names no nodes.", bc.nodes, bc.body)));
        }
        let velocity = bc.velocity.clone().unwrap_or_else(|| vec![0.0; dim]);
        let until = bc.until.unwrap_or(Real::INFINITY);
        components_check(loaded, &format!("{key}.velocity"), &velocity, dim)?;
        let components: Vec<usize> = match &bc.components {
            Some(c) => c
                .iter()
                .map(|a| match a {
                    Axis::X => 0,
                    Axis::Y => 1,
                    Axis::Z => 2,
                })
                .collect(),
            None => (0..dim).collect(),
        };
        if components.iter().any(|&c| c >= dim) {
            return Err(loaded.error(Invalid, &format!("{key}.components"), format!("`z` in a {dim}D scene.")));
        }
        for &n in nodes {
            for &c in &components {
                let dof = n as usize * dim + c;
                if let Some(first) = owner.get(&(b, dof)) {
                    // A dof shared by two sets keeps its first owner; their velocities must agree.
                    let existing = prescribed[b].iter().find(|p| p.dof == dof).expect("owned dof is prescribed");
                    if (existing.velocity - velocity[c]).abs() > 0.0 || (existing.until != until && existing.velocity != 0.0) {
                        return Err(loaded.error(Invalid, &format!("{key}.velocity"), format!("node {n} is also prescribed by `boundary.{first}` with another velocity.")));
                    }
                    continue;
                }
                owner.insert((b, dof), name.clone());
                prescribed[b].push(Prescribed { dof, velocity: velocity[c], set: set_index, until });
            }
        }
        sets.push(BoundarySet { name: name.clone(), body: b });
    }
    Ok((sets, prescribed))
}

/// The bodies, in parallel (a grain packing has thousands), on one topology per distinct body
/// (connectivity and prescribed dofs), built in parallel and shared; a failure is reported for
/// the first body in the scene's order that has it.
fn build_bodies(loaded: &LoadedScene, meshes: Vec<BodyMesh>, prescribed: Vec<Vec<Prescribed>>, dim: usize) -> Result<Vec<Body>, SceneError> {
    let scene = &loaded.scene;
    let ordering = scene.solver.ordering;
    let elements = |b: usize| meshes[b].2.as_ref().map_or(&meshes[b].1, |p: &Patches| &p.cells);
    let keys: Vec<Option<TopologyKey>> = (0..meshes.len()).into_par_iter().map(|b| Topology::key(elements(b), &prescribed[b], ordering)).collect();
    let mut first_of: HashMap<&TopologyKey, usize> = HashMap::new();
    let owner_of: Vec<usize> = keys.iter().enumerate().map(|(b, key)| key.as_ref().map_or(b, |k| *first_of.entry(k).or_insert(b))).collect();
    let built_topologies: HashMap<usize, Result<Topology, String>> =
        owner_of.iter().enumerate().filter(|(b, owner)| b == *owner).map(|(b, _)| b).collect::<Vec<_>>().into_par_iter().map(|b| (b, Topology::new(elements(b), &prescribed[b], ordering).map_err(|e| e.to_string()))).collect();
    let topologies: Vec<&Result<Topology, String>> = owner_of.iter().map(|o| &built_topologies[o]).collect();
    let specs: Vec<_> = scene.body.values().collect();
    let inputs = meshes.into_par_iter().zip(specs).zip(prescribed).zip(topologies);
    let built: Vec<Result<Body, SceneError>> = inputs.map(|(((mesh, spec), prescribed), topology)| build_body(loaded, mesh, spec, prescribed, topology, dim)).collect();
    built.into_iter().collect()
}

/// One body: its initial velocity (translation and rotation about its centre of mass), its
/// material and its step bound.
fn build_body(loaded: &LoadedScene, (name, mesh, patches, geometry, formulation): BodyMesh, spec: &crate::scene::BodySpec, prescribed: Vec<Prescribed>, topology: &Result<Topology, String>, dim: usize) -> Result<Body, SceneError> {
    let scene = &loaded.scene;
    let key = format!("body.{name}");
    let material = &scene.material[&spec.material];
    let v0 = spec.initial_velocity.clone().unwrap_or_else(|| vec![0.0; dim]);
    components_check(loaded, &format!("{key}.initial_velocity"), &v0, dim)?;
    range_check(loaded, &format!("{key}.initial_velocity"), &v0)?;
    let omega = match (&spec.angular_velocity, dim) {
        (None, _) => [0.0; 3],
        (Some(AngularVelocity::Planar(w)), 2) => [0.0, 0.0, *w],
        (Some(AngularVelocity::Spatial(w)), 3) if w.len() == 3 => [w[0], w[1], w[2]],
        _ => return Err(loaded.error(Invalid, &format!("{key}.angular_velocity"), "give one number in 2D and a vector of 3 components in 3D.")),
    };
    range_check(loaded, &format!("{key}.angular_velocity"), &omega)?;
    let masses = geometry.lumped_masses(patches.as_ref().map_or(&mesh, |p| &p.cells), material.density);
    let total: Real = masses.iter().sum();
    let mut c = [0.0; 3];
    for (m, x) in masses.iter().zip(&mesh.nodes) {
        for i in 0..3 {
            c[i] += m * x[i] / total;
        }
    }
    let mut v = [0.0; 3];
    v[..dim].copy_from_slice(&v0);
    let initial = move |x: [Real; 3]| {
        let r = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
        [v[0] + omega[1] * r[2] - omega[2] * r[1], v[1] + omega[2] * r[0] - omega[0] * r[2], v[2] + omega[0] * r[1] - omega[1] * r[0]]
    };
    let topology = topology.as_ref().map_err(|e| loaded.error(MeshError, &format!("{key}.mesh"), e.clone()))?;
    let mut body = Body::new(name.clone(), mesh, patches, geometry, model_of(material), formulation, material.density, prescribed, initial, topology);
    if body.def.prescribed.is_empty() {
        free_body_step(loaded, &body, material.density)?;
    }
    body.def.reuse_factorization = scene.solver.reuse_factorization;
    if let Some(viscoelastic) = viscoelastic_of(material) {
        body.set_viscoelastic(viscoelastic);
    }
    Ok(body)
}

/// The state at t = 0: no body inside another (pushed apart first if the scene asks), every
/// energy finite.
fn check_initial_state(loaded: &LoadedScene, bodies: &mut [Body], contact: Option<&ContactModel>, gravity: &[Real; 3]) -> Result<(), SceneError> {
    if let Some(model) = contact {
        if loaded.scene.contact.resolve_initial_overlap {
            separate_initial_overlaps(bodies, model).map_err(|(key, message)| loaded.error(Invalid, &key, message))?;
        }
        if let Some(o) = initial_overlaps(bodies, model).into_iter().max_by(|a, b| a.ratio().total_cmp(&b.ratio())) {
            let (key, message) = describe_overlap(bodies, model, &o);
            return Err(loaded.error(Invalid, &key, format!("{message}; move them apart, or set `contact.resolve_initial_overlap = true` to push them apart before the first step.")));
        }
    }
    for b in bodies.iter() {
        let (kinetic, strain, potential) = (b.kinetic_energy(), b.strain_energy().expect("a state the host holds before the first step"), b.potential_energy(gravity));
        if ![kinetic, strain, potential].iter().all(|e| e.is_finite()) {
            return Err(loaded.error(
                Invalid,
                &format!("body.{}", b.def.name),
                format!("the initial state has a non-finite energy (kinetic {kinetic:e}, strain {strain:e}, potential {potential:e}): its density, size, velocities and the gravity are too large together."),
            ));
        }
    }
    Ok(())
}

/// Overlaps at t = 0 smaller than this (in element sizes) are round-off of bodies that touch.
const INITIAL_OVERLAP: Real = 1e-6;
/// Rounds of rigid translations [`separate_initial_overlaps`] may take.
const SEPARATION_ROUNDS: usize = 200;

fn initial_overlaps(bodies: &[Body], model: &ContactModel) -> Vec<Overlap> {
    state_overlaps(bodies, model, 0.0).into_iter().filter(|o| o.ratio() > INITIAL_OVERLAP).collect()
}

/// The scene key and the words of an overlap: the bodies (or obstacle), the node and the depth.
fn describe_overlap(bodies: &[Body], model: &ContactModel, o: &Overlap) -> (String, String) {
    let body = &bodies[o.body as usize];
    let x = body.position(o.node as usize);
    let at: Vec<String> = x[..body.def.dim].iter().map(|c| format!("{c:.6}")).collect();
    let into = match o.host {
        Host::Body(m) => format!("inside body `{}`", bodies[m as usize].def.name),
        Host::Obstacle(k) => format!("behind obstacle `{}`", model.obstacles[k as usize].name),
    };
    let key = match o.host {
        Host::Obstacle(k) => format!("obstacle.{}", model.obstacles[k as usize].name),
        Host::Body(_) => format!("body.{}", body.def.name),
    };
    (key, format!("body `{}` overlaps at t = 0: its node {} at [{}] is {:.3e} {into} ({:.2} elements deep)", body.def.name, o.node, at.join(", "), o.depth, o.ratio()))
}

/// Pushes overlapping bodies apart by rigid translations of their meshes. Each round, every
/// body with a node behind an obstacle moves along the obstacle's normal, and every body with a
/// node inside another body moves away from it (along the line between their centroids: a
/// deep node's nearest way out may lead through the other body), each by the depth of its
/// deepest node. A body held by boundary conditions stays, and the other body of the pair moves
/// the other way. Rigid motions leave the bodies unstrained. An error names what could not be
/// separated.
fn separate_initial_overlaps(bodies: &mut [Body], model: &ContactModel) -> Result<(), (String, String)> {
    let movable: Vec<bool> = bodies.iter().map(|b| b.def.prescribed.is_empty()).collect();
    let centroid = |b: &Body| {
        let n = b.def.mesh.nodes.len() as Real;
        b.def.mesh.nodes.iter().fold([0.0; 3], |c, x| [c[0] + x[0] / n, c[1] + x[1] / n, c[2] + x[2] / n])
    };
    for _ in 0..SEPARATION_ROUNDS {
        let found = initial_overlaps(bodies, model);
        if found.is_empty() {
            return Ok(());
        }
        let mut moves: Vec<Option<[Real; 3]>> = vec![None; bodies.len()];
        for o in &found {
            let direction = match o.host {
                Host::Obstacle(_) => o.out,
                Host::Body(m) => {
                    let (a, b) = (centroid(&bodies[o.body as usize]), centroid(&bodies[m as usize]));
                    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
                    let length = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    if length > 1e-9 * o.size {
                        d.map(|c| c / length)
                    } else {
                        o.out
                    }
                }
            };
            // A little past the surface, so that the node ends outside.
            let push = direction.map(|c| c * (o.depth * 1.01 + 1e-6 * o.size));
            let (body, push) = match o.host {
                _ if movable[o.body as usize] => (o.body as usize, push),
                Host::Body(m) if movable[m as usize] => (m as usize, push.map(|c| -c)),
                _ => {
                    let (key, message) = describe_overlap(bodies, model, o);
                    return Err((key, format!("{message}, and boundary conditions hold the bodies in place, so they cannot be pushed apart.")));
                }
            };
            let length = |v: &[Real; 3]| v.iter().map(|c| c * c).sum::<Real>();
            if moves[body].is_none_or(|m| length(&m) < length(&push)) {
                moves[body] = Some(push);
            }
        }
        for (b, m) in moves.iter().enumerate() {
            if let Some(m) = m {
                for x in &mut bodies[b].def.mesh.nodes {
                    for i in 0..3 {
                        x[i] += m[i];
                    }
                }
            }
        }
    }
    let o = initial_overlaps(bodies, model).into_iter().next().expect("overlaps remain");
    let (key, message) = describe_overlap(bodies, model, &o);
    Err((key, format!("{message} after {SEPARATION_ROUNDS} rounds of pushing the bodies apart.")))
}

fn vec3(v: &[Real]) -> [Real; 3] {
    let mut x = [0.0; 3];
    x[..v.len()].copy_from_slice(v);
    x
}

/// The contact model: boundary surfaces, obstacles and the friction of each body pair; `None`
/// when nothing in the scene can touch anything.
fn build_contact(loaded: &LoadedScene, bodies: &[Body], dim: usize) -> Result<Option<ContactModel>, SceneError> {
    let scene = &loaded.scene;
    let spec = &scene.contact;
    let index: HashMap<&str, usize> = scene.body.keys().enumerate().map(|(i, n)| (n.as_str(), i)).collect();
    let n = bodies.len();
    // Slave/master roles: the pair's `slave`, else the finer mesh, then the one with more
    // boundary nodes, then the first in the scene; with two passes, the other way round too.
    // A surface depends on the connectivity only: bodies that share a topology (a packing's
    // grains of one shape) share the boundary search of one of them.
    let mut first_of: HashMap<*const crate::assembly::StiffnessPattern, usize> = HashMap::new();
    let firsts: Vec<usize> = bodies.iter().enumerate().map(|(b, body)| *first_of.entry(Arc::as_ptr(&body.def.pattern)).or_insert(b)).collect();
    let searched: HashMap<usize, Surface> = first_of.into_values().collect::<Vec<_>>().into_par_iter().map(|b| (b, Surface::of(&bodies[b].def.mesh))).collect();
    let surfaces: Vec<Surface> = firsts.iter().zip(bodies).map(|(b, body)| searched[b].on(&body.def.mesh)).collect();
    let ranks = bodies.iter().zip(&surfaces).map(|(b, s)| Rank { length_scale: b.length_scale(), boundary_nodes: s.nodes.len() }).collect();
    let mut pairs = BodyPairs::new(ranks, spec.all_pairs.then_some(spec.friction), spec.two_pass);
    for pair in spec.pair.values() {
        let (a, b) = (index[pair.bodies[0].as_str()], index[pair.bodies[1].as_str()]);
        pairs.list(a, b, pair.friction.unwrap_or(spec.friction), pair.slave.as_ref().map(|slave| index[slave.as_str()]));
    }
    let mut obstacles = Vec::new();
    for (name, o) in &scene.obstacle {
        let key = format!("obstacle.{name}");
        let check = |field: &str, v: &Option<Vec<Real>>| match v {
            Some(v) if v.len() != dim => Err(loaded.error(Invalid, &format!("{key}.{field}"), format!("expected {dim} components (the scene is {dim}D), got {}.", v.len()))),
            _ => Ok(()),
        };
        for (field, v) in [("point", &o.point), ("normal", &o.normal), ("min", &o.min), ("max", &o.max), ("velocity", &o.velocity)] {
            check(field, v)?;
        }
        if dim == 3 && o.points.is_some() {
            return Err(loaded.error(Invalid, &format!("{key}.shape"), "polygons and polylines are 2D obstacles; use planes or boxes in 3D."));
        }
        let points = || o.points.as_ref().expect("validated").iter().map(|p| vec3(p)).collect::<Vec<_>>();
        let (shape, (faces, mode)) = match o.shape {
            ObstacleShape::Plane => {
                let (point, normal) = (vec3(o.point.as_deref().expect("validated")), vec3(o.normal.as_deref().expect("validated")));
                (Shape::Plane { point, normal }, Obstacle::plane(point, normal))
            }
            ObstacleShape::Box => {
                let (min, max) = (vec3(o.min.as_deref().expect("validated")), vec3(o.max.as_deref().expect("validated")));
                (Shape::Box { min, max }, Obstacle::cuboid(min, max, dim, o.inside.unwrap_or(false)))
            }
            ObstacleShape::Polygon => (Shape::Polygon(points()), Obstacle::polygon(&points())),
            ObstacleShape::Polyline => (Shape::Polyline(points()), Obstacle::polyline(&points())),
        };
        let motion = match (&o.velocity, &o.motion) {
            (Some(v), _) => Motion { rows: vec![(0.0, vec3(v))], linear: false },
            (None, Some(rows)) => {
                if let Some(i) = rows.iter().position(|r| r.len() != dim + 1) {
                    return Err(loaded.error(Invalid, &format!("{key}.motion.{i}"), format!("each row is [t, velocity] with {dim} velocity components.")));
                }
                Motion { rows: rows.iter().map(|r| (r[0], vec3(&r[1..]))).collect(), linear: o.interpolation != Some(Interpolation::Step) }
            }
            (None, None) => Motion::default(),
        };
        let touches = match &o.bodies {
            Some(list) => (0..n).map(|b| list.iter().any(|name| index[name.as_str()] == b)).collect(),
            None => vec![true; n],
        };
        obstacles.push(Obstacle { name: name.clone(), shape, faces, mode, friction: o.friction.unwrap_or(spec.friction), motion, bodies: touches });
    }
    if obstacles.is_empty() && !pairs.any() {
        return Ok(None);
    }
    let settings = Settings { tolerance: spec.tolerance, max_iterations: spec.max_iterations, sweep: spec.sweep, acceleration: spec.acceleration, fallback: spec.fallback };
    Ok(Some(ContactModel { settings, surfaces, obstacles, pairs }))
}
