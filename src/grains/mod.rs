//! `bifirst grains`: what granular-mechanics papers plot, from a run's contact network
//! (`/contacts`, [`crate::output::contacts`]): solid fraction, coordination with and without
//! rattlers, sliding contacts, the fabric tensor, the Love-Weber stress beside the walls'
//! pressures, and at one step the distribution of normal forces and of contact orientations.
//! Formulas and sign conventions: doc/grains.md.

pub mod plot;

use crate::output::messages::ContactsMessage;
use crate::output::{read_run_topics, ReadError, RunRecord};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum GrainsError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("`{0}` has no contact network (`/contacts`): the run had no contact, was logged with output.contacts_every = 0 (or output.scene_every = 0 without output.contacts_every), or by a bifirst older than the network; run it again with --set output.contacts_every=N")]
    NoNetwork(PathBuf),
    #[error("`{path}`: the contact network at t = {t} is malformed: {what}")]
    Malformed { path: PathBuf, t: f64, what: String },
    #[error("`{path}`: no contact network at or before t = {at} (the first is at t = {first})")]
    NoneAt { path: PathBuf, at: f64, first: f64 },
    #[error("cannot write `{path}`: {source}")]
    Write { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Plot(#[from] crate::output::plot::PlotError),
}

/// The other side of a contact.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Other {
    Body(usize),
    Obstacle(usize),
}

/// A contact of the network: `force` on `body`, `normal` from the other side towards it.
#[derive(Debug, Clone, Copy)]
pub struct Contact {
    pub body: usize,
    pub other: Other,
    pub point: [f64; 3],
    pub normal: [f64; 3],
    pub force: [f64; 3],
    pub normal_force: f64,
    pub sliding: bool,
}

/// A plane obstacle where it is: a point of it and its normal towards the bodies.
#[derive(Debug, Clone, Copy)]
pub struct Wall {
    pub obstacle: usize,
    pub point: [f64; 3],
    pub normal: [f64; 3],
}

/// One logged step's network.
#[derive(Debug, Clone, Default)]
pub struct Network {
    pub t: f64,
    pub dim: usize,
    pub centers: Vec<[f64; 3]>,
    pub volumes: Vec<f64>,
    pub walls: Vec<Wall>,
    pub contacts: Vec<Contact>,
}

/// `dim` numbers at a time as points.
fn points(flat: &[f64], dim: usize) -> Vec<[f64; 3]> {
    flat.chunks(dim).map(|c| std::array::from_fn(|i| c.get(i).copied().unwrap_or(0.0))).collect()
}

impl Network {
    /// The network of a `/contacts` message of a `dim`-dimensional run, its lengths checked.
    pub fn of(m: &ContactsMessage, dim: usize) -> Result<Self, String> {
        let (bodies, walls, contacts) = (m.body_volume.len(), m.wall.len(), m.body.len());
        let lengths = [
            ("body_center", m.body_center.len(), bodies * dim),
            ("wall_point", m.wall_point.len(), walls * dim),
            ("wall_normal", m.wall_normal.len(), walls * dim),
            ("other", m.other.len(), contacts),
            ("point", m.point.len(), contacts * dim),
            ("normal", m.normal.len(), contacts * dim),
            ("force", m.force.len(), contacts * dim),
            ("normal_force", m.normal_force.len(), contacts),
            ("sliding", m.sliding.len(), contacts),
        ];
        if let Some((name, got, want)) = lengths.iter().find(|(_, got, want)| got != want) {
            return Err(format!("`{name}` has {got} numbers, not {want}"));
        }
        let (point, normal, force) = (points(&m.point, dim), points(&m.normal, dim), points(&m.force, dim));
        let mut list = Vec::with_capacity(contacts);
        for k in 0..contacts {
            let body = m.body[k] as usize;
            let other = if m.other[k] >= 0 { Other::Body(m.other[k] as usize) } else { Other::Obstacle((-1 - m.other[k]) as usize) };
            if body >= bodies || matches!(other, Other::Body(b) if b >= bodies) {
                return Err(format!("contact {k} names a body beyond the {bodies} there are"));
            }
            list.push(Contact { body, other, point: point[k], normal: normal[k], force: force[k], normal_force: m.normal_force[k], sliding: m.sliding[k] });
        }
        let walls = m.wall.iter().zip(points(&m.wall_point, dim)).zip(points(&m.wall_normal, dim)).map(|((&o, point), normal)| Wall { obstacle: o as usize, point, normal }).collect();
        Ok(Network { t: m.t, dim, centers: points(&m.body_center, dim), volumes: m.body_volume.clone(), walls, contacts: list })
    }

    /// The contacts that bear load.
    fn bearing(&self) -> impl Iterator<Item = &Contact> {
        self.contacts.iter().filter(|c| c.normal_force > 0.0)
    }
}

/// A wall's pressure: the normal force of its contacts over its area in the container.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WallPressure {
    pub name: String,
    pub pressure: f64,
}

/// The measures of one logged step (doc/grains.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Measures {
    pub t: f64,
    pub grains: usize,
    /// Load-bearing contacts: between grains, and with obstacles.
    pub contacts: usize,
    pub wall_contacts: usize,
    /// The container's volume (area in 2D): the box the plane walls bound.
    pub container_volume: f64,
    pub solid_fraction: f64,
    /// Mean load-bearing contacts per grain, obstacles included.
    pub coordination: f64,
    /// The same over the grains left when rattlers (fewer than d + 1 contacts, found again as
    /// their neighbours lose them) are taken out.
    pub coordination_without_rattlers: f64,
    pub rattlers: usize,
    pub sliding_fraction: f64,
    /// `(1/C) Σ n ⊗ n` over the contacts between grains, `dim x dim`.
    pub fabric: Vec<Vec<f64>>,
    pub fabric_anisotropy: f64,
    /// The Love-Weber stress over the container, compression positive, `dim x dim`.
    pub stress: Vec<Vec<f64>>,
    /// Mean stress `tr σ / d` and deviator (`√(½ s:s)` in 2D, `√(3/2 s:s)` in 3D).
    pub pressure: f64,
    pub deviator: f64,
    pub walls: Vec<WallPressure>,
    /// The walls' pressures averaged.
    pub wall_pressure: f64,
}

fn outer_add(m: &mut [[f64; 3]; 3], a: [f64; 3], b: [f64; 3], w: f64) {
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] += w * a[i] * b[j];
        }
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i] - b[i])
}

/// The radius of the disk (2D) or ball (3D) of a grain's volume: how its outline is drawn
/// and how far it reaches along an axis no walls bound.
pub fn equivalent_radius(volume: f64, dim: usize) -> f64 {
    if dim == 2 {
        (volume / std::f64::consts::PI).sqrt()
    } else {
        (3.0 * volume / (4.0 * std::f64::consts::PI)).cbrt()
    }
}

/// The box the plane walls bound, axis by axis (`[lower, upper]`); an axis no pair of walls
/// bounds takes the grains' extent (their centres plus the radius of their volume).
pub fn container(net: &Network) -> Vec<[f64; 2]> {
    let d = net.dim;
    (0..d)
        .map(|i| {
            let along = |sign: f64| net.walls.iter().filter(move |w| w.normal[i] * sign > 0.999).map(move |w| w.point[i]);
            let lower = along(1.0).fold(f64::NEG_INFINITY, f64::max);
            let upper = along(-1.0).fold(f64::INFINITY, f64::min);
            let extent = |sign: f64| net.centers.iter().zip(&net.volumes).map(move |(c, v)| c[i] + sign * equivalent_radius(*v, d));
            let lower = if lower.is_finite() { lower } else { extent(-1.0).fold(f64::INFINITY, f64::min) };
            let upper = if upper.is_finite() { upper } else { extent(1.0).fold(f64::NEG_INFINITY, f64::max) };
            [lower, upper]
        })
        .collect()
}

/// Grains with fewer than `d + 1` load-bearing contacts, found again as their neighbours lose
/// the contacts with them; returns the flags and each grain's contacts left.
fn rattlers(net: &Network) -> (Vec<bool>, Vec<usize>) {
    let n = net.centers.len();
    let mut count = vec![0usize; n];
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); n];
    for c in net.bearing() {
        count[c.body] += 1;
        if let Other::Body(b) = c.other {
            count[b] += 1;
            neighbours[c.body].push(b);
            neighbours[b].push(c.body);
        }
    }
    let mut rattler = vec![false; n];
    let mut queue: Vec<usize> = (0..n).filter(|&g| count[g] < net.dim + 1).collect();
    while let Some(g) = queue.pop() {
        if rattler[g] {
            continue;
        }
        rattler[g] = true;
        for &b in &neighbours[g] {
            if !rattler[b] {
                count[b] -= 1;
                if count[b] < net.dim + 1 {
                    queue.push(b);
                }
            }
        }
    }
    (rattler, count)
}

/// The measures of one step; `obstacle_names` name the walls.
pub fn measure(net: &Network, obstacle_names: &[String]) -> Measures {
    let d = net.dim;
    let boxed = container(net);
    let container_volume: f64 = boxed.iter().map(|[lo, hi]| hi - lo).product();
    let grains = net.centers.len();
    let (mut contacts, mut wall_contacts, mut sliding, mut between) = (0, 0, 0, 0);
    let (mut fabric, mut stress) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
    let mut wall_force = vec![0.0; obstacle_names.len().max(net.walls.iter().map(|w| w.obstacle + 1).max().unwrap_or(0))];
    for c in net.bearing() {
        contacts += 1;
        sliding += c.sliding as usize;
        match c.other {
            Other::Body(b) => {
                between += 1;
                outer_add(&mut fabric, c.normal, c.normal, 1.0);
                // Branch from the other grain's centre to this one's, the force on this one.
                outer_add(&mut stress, sub(net.centers[c.body], net.centers[b]), c.force, 1.0);
            }
            Other::Obstacle(k) => {
                wall_contacts += 1;
                outer_add(&mut stress, sub(c.point, net.centers[c.body]), c.force, -1.0);
                if let Some(w) = net.walls.iter().find(|w| w.obstacle == k) {
                    wall_force[k] += (0..3).map(|i| c.force[i] * w.normal[i]).sum::<f64>().abs();
                }
            }
        }
    }
    let (rattler, left) = rattlers(net);
    let kept = rattler.iter().filter(|r| !**r).count();
    let kept_contacts: usize = left.iter().zip(&rattler).filter(|(_, r)| !**r).map(|(c, _)| c).sum();
    let square = |m: &[[f64; 3]; 3], scale: f64| -> Vec<Vec<f64>> { (0..d).map(|i| (0..d).map(|j| 0.5 * (m[i][j] + m[j][i]) * scale).collect()).collect() };
    let fabric = square(&fabric, if between > 0 { 1.0 / between as f64 } else { 0.0 });
    let stress = square(&stress, 1.0 / container_volume);
    let fabric_anisotropy = if d == 2 { 2.0 * (2.0 * deviatoric_norm2(&fabric)).sqrt() } else { 5.0 * (1.5 * deviatoric_norm2(&fabric)).sqrt() };
    let walls: Vec<WallPressure> = net
        .walls
        .iter()
        .filter_map(|w| {
            let axis = (0..d).find(|&i| w.normal[i].abs() > 0.999)?;
            let area: f64 = (0..d).filter(|&j| j != axis).map(|j| boxed[j][1] - boxed[j][0]).product();
            let name = obstacle_names.get(w.obstacle).cloned().unwrap_or_else(|| format!("obstacle {}", w.obstacle));
            Some(WallPressure { name, pressure: wall_force[w.obstacle] / area })
        })
        .collect();
    let wall_pressure = if walls.is_empty() { 0.0 } else { walls.iter().map(|w| w.pressure).sum::<f64>() / walls.len() as f64 };
    let per = |a: usize, b: usize| if b > 0 { a as f64 / b as f64 } else { 0.0 };
    Measures {
        t: net.t,
        grains,
        contacts,
        wall_contacts,
        container_volume,
        solid_fraction: net.volumes.iter().sum::<f64>() / container_volume,
        // A contact between grains counts for both.
        coordination: per(contacts + between, grains),
        coordination_without_rattlers: per(kept_contacts, kept),
        rattlers: grains - kept,
        sliding_fraction: per(sliding, contacts),
        fabric,
        fabric_anisotropy,
        pressure: mean_stress(&stress),
        deviator: deviator(&stress),
        stress,
        walls,
        wall_pressure,
    }
}

/// `tr m / d` of a `d x d` tensor: a stress's mean stress `p`.
fn mean_stress(m: &[Vec<f64>]) -> f64 {
    (0..m.len()).map(|i| m[i][i]).sum::<f64>() / m.len() as f64
}

/// `s:s` of a `d x d` tensor's deviator `s`.
fn deviatoric_norm2(m: &[Vec<f64>]) -> f64 {
    let d = m.len();
    let mean = mean_stress(m);
    (0..d).flat_map(|i| (0..d).map(move |j| (i, j))).map(|(i, j)| (m[i][j] - if i == j { mean } else { 0.0 }).powi(2)).sum::<f64>()
}

/// The deviator of a stress: `√(½ s:s)` in 2D, `√(3/2 s:s)` in 3D.
fn deviator(stress: &[Vec<f64>]) -> f64 {
    let factor = if stress.len() == 2 { 0.5 } else { 1.5 };
    (factor * deviatoric_norm2(stress)).sqrt()
}

/// The means of the stress measures over the logged steps of a time window that ends at the
/// chosen step. While a packing is driven, its grains' inertia (`Σ m x ⊗ a`) stands between the
/// Love-Weber stress and the walls' pressures at any one step; over a window its time mean
/// falls off, and the two means compare as the static balance says (doc/grains.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WindowMeans {
    /// The first and last logged step's times, and how many steps the means take.
    pub from: f64,
    pub to: f64,
    pub steps: usize,
    pub coordination: f64,
    /// The mean Love-Weber stress, its mean stress and deviator.
    pub stress: Vec<Vec<f64>>,
    pub pressure: f64,
    pub deviator: f64,
    pub walls: Vec<WallPressure>,
    pub wall_pressure: f64,
}

/// The means over the rows at times within `window` before row `index`'s, that row included.
pub fn window_means(rows: &[Measures], index: usize, window: f64) -> WindowMeans {
    let to = rows[index].t;
    let reach = to - window - 1e-9 * window.abs().max(to.abs()).max(1.0);
    let first = rows[..=index].iter().rposition(|r| r.t < reach).map_or(0, |k| k + 1);
    let chosen = &rows[first..=index];
    let n = chosen.len() as f64;
    let mean = |f: &dyn Fn(&Measures) -> f64| chosen.iter().map(f).sum::<f64>() / n;
    let d = rows[index].stress.len();
    let stress: Vec<Vec<f64>> = (0..d).map(|i| (0..d).map(|j| mean(&|r| r.stress[i][j])).collect()).collect();
    let walls = rows[index].walls.iter().map(|w| WallPressure { name: w.name.clone(), pressure: mean(&|r| r.walls.iter().find(|v| v.name == w.name).map_or(0.0, |v| v.pressure)) }).collect();
    WindowMeans { from: chosen[0].t, to, steps: chosen.len(), coordination: mean(&|r| r.coordination), pressure: mean_stress(&stress), deviator: deviator(&stress), stress, walls, wall_pressure: mean(&|r| r.wall_pressure) }
}

/// The distribution of the normal forces over their mean at one step: a histogram of bins
/// `width` wide as a probability density, and the slope `-β` of `ln P` against `f/<f>` fitted
/// over the bins above the mean, each weighted by its count (the exponential tail
/// `P ~ exp(-β f/<f>)`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ForceDistribution {
    pub mean_normal_force: f64,
    /// Bin centres (in units of the mean) and densities.
    pub bins: Vec<[f64; 2]>,
    /// `β`, when at least two bins above the mean are filled.
    pub tail_decay: Option<f64>,
    /// `P₀` of the fitted tail `P₀ exp(-β f/<f>)`.
    pub tail_amplitude: Option<f64>,
}

/// Bins of the force distribution, in units of the mean force.
const FORCE_BIN: f64 = 0.2;

pub fn force_distribution(net: &Network) -> ForceDistribution {
    let forces: Vec<f64> = net.bearing().map(|c| c.normal_force).collect();
    let mean = forces.iter().sum::<f64>() / forces.len().max(1) as f64;
    let top = forces.iter().fold(0.0f64, |m, f| m.max(f / mean));
    let count = ((top / FORCE_BIN).floor() as usize + 1).min(10_000);
    let mut histogram = vec![0usize; if forces.is_empty() { 0 } else { count }];
    for f in &forces {
        let bin = ((f / mean / FORCE_BIN) as usize).min(histogram.len() - 1);
        histogram[bin] += 1;
    }
    let density = |n: usize| n as f64 / (forces.len() as f64 * FORCE_BIN);
    let bins: Vec<[f64; 2]> = histogram.iter().enumerate().map(|(k, &n)| [(k as f64 + 0.5) * FORCE_BIN, density(n)]).collect();
    // Each bin weighted by its count: a bin of one force is no measure of the density.
    let tail: Vec<(f64, f64, f64)> = bins.iter().zip(&histogram).filter(|([x, _], n)| *x > 1.0 && **n > 0).map(|([x, p], n)| (*x, p.ln(), *n as f64)).collect();
    let fit = (tail.len() >= 2).then(|| {
        let w: f64 = tail.iter().map(|p| p.2).sum();
        let (mx, my) = (tail.iter().map(|p| p.2 * p.0).sum::<f64>() / w, tail.iter().map(|p| p.2 * p.1).sum::<f64>() / w);
        let slope = tail.iter().map(|(x, y, n)| n * (x - mx) * (y - my)).sum::<f64>() / tail.iter().map(|(x, _, n)| n * (x - mx).powi(2)).sum::<f64>();
        (-slope, (my - slope * mx).exp())
    });
    ForceDistribution { mean_normal_force: mean, bins, tail_decay: fit.map(|f| f.0), tail_amplitude: fit.map(|f| f.1) }
}

/// Sectors of the rose of contact orientations over half a turn.
pub const ROSE_SECTORS: usize = 18;

/// The share of the contacts between grains whose normal lies in each sector of half a turn
/// (normals taken without their sign), in the plane of the first two axes: in 3D, each normal's
/// projection, weighted by its length there.
pub fn orientation_rose(net: &Network) -> Vec<f64> {
    let mut rose = vec![0.0; ROSE_SECTORS];
    for c in net.bearing().filter(|c| matches!(c.other, Other::Body(_))) {
        let [x, y, _] = c.normal;
        let angle = y.atan2(x).rem_euclid(std::f64::consts::PI);
        let sector = ((angle / std::f64::consts::PI * ROSE_SECTORS as f64) as usize).min(ROSE_SECTORS - 1);
        rose[sector] += (x * x + y * y).sqrt();
    }
    let total: f64 = rose.iter().sum();
    if total > 0.0 {
        rose.iter_mut().for_each(|r| *r /= total);
    }
    rose
}

/// A run's networks read back.
pub struct Networks {
    pub path: PathBuf,
    pub scene: String,
    pub dim: usize,
    pub body_names: Vec<String>,
    pub obstacle_names: Vec<String>,
    pub steps: Vec<Network>,
}

/// Reads the contact networks of a log; `progress` sees each step parsed (its number from 1,
/// the count).
pub fn read_networks(path: &Path, mut progress: impl FnMut(usize, usize)) -> Result<Networks, GrainsError> {
    let record: RunRecord = read_run_topics(path, |t| t == "/run" || t == "/contacts")?;
    let run = record.require("/run")?.first().cloned().unwrap_or_default();
    let names = |field: &str| -> Vec<String> { run[field].as_array().map(|a| a.iter().filter_map(|n| n.as_str().map(String::from)).collect()).unwrap_or_default() };
    let messages = record.messages("/contacts");
    if messages.is_empty() {
        return Err(GrainsError::NoNetwork(path.into()));
    }
    let dim_of = |m: &ContactsMessage| if m.body_volume.is_empty() { 2 } else { m.body_center.len() / m.body_volume.len() };
    let mut steps = Vec::with_capacity(messages.len());
    for (k, value) in messages.iter().enumerate() {
        let t = value["t"].as_f64().unwrap_or(f64::NAN);
        let message = ContactsMessage::deserialize(value).map_err(|e| GrainsError::Malformed { path: path.into(), t, what: e.to_string() })?;
        let dim = dim_of(&message);
        steps.push(Network::of(&message, dim).map_err(|what| GrainsError::Malformed { path: path.into(), t, what })?);
        progress(k + 1, messages.len());
    }
    let dim = steps.first().map_or(2, |s| s.dim);
    Ok(Networks { path: path.into(), scene: run["scene_name"].as_str().unwrap_or_default().to_string(), dim, body_names: names("body_names"), obstacle_names: names("obstacle_names"), steps })
}

impl Networks {
    /// The index of the last step at or before `at` (the last step without it).
    pub fn index_at(&self, at: Option<f64>) -> Result<usize, GrainsError> {
        let first = self.steps.first().map_or(f64::NAN, |s| s.t);
        match at {
            None => Ok(self.steps.len() - 1),
            Some(at) => self.steps.iter().rposition(|s| s.t <= at + 1e-9 * at.abs().max(1.0)).ok_or(GrainsError::NoneAt { path: self.path.clone(), at, first }),
        }
    }
}

/// The time series as CSV: one row per logged step.
pub fn csv(rows: &[Measures], dim: usize) -> String {
    let axes = ["x", "y", "z"];
    let pairs: Vec<(usize, usize)> = (0..dim).flat_map(|i| (i..dim).map(move |j| (i, j))).collect();
    let mut header = vec!["t", "solid_fraction", "coordination", "coordination_without_rattlers", "rattlers", "sliding_fraction", "contacts", "wall_contacts", "container_volume"].into_iter().map(String::from).collect::<Vec<_>>();
    header.extend(pairs.iter().map(|(i, j)| format!("fabric_{}{}", axes[*i], axes[*j])));
    header.push("fabric_anisotropy".into());
    header.extend(pairs.iter().map(|(i, j)| format!("stress_{}{}", axes[*i], axes[*j])));
    header.extend(["pressure", "deviator", "wall_pressure"].map(String::from));
    let walls: Vec<String> = rows.first().map_or(Vec::new(), |r| r.walls.iter().map(|w| w.name.clone()).collect());
    header.extend(walls.iter().map(|w| format!("wall_{w}")));
    let mut out = header.join(",") + "\n";
    for r in rows {
        let mut cells: Vec<String> =
            [r.t, r.solid_fraction, r.coordination, r.coordination_without_rattlers, r.rattlers as f64, r.sliding_fraction, r.contacts as f64, r.wall_contacts as f64, r.container_volume].iter().map(|v| format!("{v:e}")).collect();
        cells.extend(pairs.iter().map(|(i, j)| format!("{:e}", r.fabric[*i][*j])));
        cells.push(format!("{:e}", r.fabric_anisotropy));
        cells.extend(pairs.iter().map(|(i, j)| format!("{:e}", r.stress[*i][*j])));
        cells.extend([r.pressure, r.deviator, r.wall_pressure].iter().map(|v| format!("{v:e}")));
        cells.extend(walls.iter().map(|name| r.walls.iter().find(|w| &w.name == name).map_or(String::new(), |w| format!("{:e}", w.pressure))));
        out += &(cells.join(",") + "\n");
    }
    out
}

/// What `bifirst grains --json` prints and writes as `grains.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub log: PathBuf,
    pub scene: String,
    pub dim: usize,
    pub steps: usize,
    /// The measures of the chosen step (`--at`, else the last).
    pub at: Measures,
    /// With `--window T`: the stress measures' means over the logged steps of the `T` before
    /// the chosen step and at it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window: Option<WindowMeans>,
    pub force_distribution: ForceDistribution,
    /// Shares of the contact orientations per sector of `180 / ROSE_SECTORS` degrees.
    pub orientation_rose: Vec<f64>,
    pub files: Vec<PathBuf>,
}

/// Measures every step of `networks` and writes the CSV, the JSON report and the pictures
/// into `out`, with the stress measures' means over `window` before the chosen step if asked;
/// `progress` sees each step measured.
pub fn analyze(networks: &Networks, at: Option<f64>, window: Option<f64>, out: &Path, mut progress: impl FnMut(usize, usize)) -> Result<Report, GrainsError> {
    use rayon::prelude::*;
    std::fs::create_dir_all(out).map_err(|source| GrainsError::Write { path: out.into(), source })?;
    let n = networks.steps.len();
    // In tenths, each in parallel: a line of progress per tenth of a long log.
    let mut rows: Vec<Measures> = Vec::with_capacity(n);
    for chunk in networks.steps.chunks(n.div_ceil(10).max(1)) {
        rows.extend(chunk.par_iter().map(|s| measure(s, &networks.obstacle_names)).collect::<Vec<_>>());
        progress(rows.len(), n);
    }
    let index = networks.index_at(at)?;
    let chosen = &networks.steps[index];
    let write = |name: &str, text: String| -> Result<PathBuf, GrainsError> {
        let path = out.join(name);
        std::fs::write(&path, text).map_err(|source| GrainsError::Write { path: path.clone(), source })?;
        Ok(path)
    };
    let mut files = vec![write("grains.csv", csv(&rows, networks.dim))?];
    let distribution = force_distribution(chosen);
    let rose = orientation_rose(chosen);
    files.extend(plot::pictures(networks, chosen, &rows, &distribution, &rose, out)?);
    let json_path = out.join("grains.json");
    files.push(json_path.clone());
    let window = window.map(|w| window_means(&rows, index, w));
    let report = Report { log: networks.path.clone(), scene: networks.scene.clone(), dim: networks.dim, steps: n, at: rows[index].clone(), window, force_distribution: distribution, orientation_rose: rose, files };
    write("grains.json", serde_json::to_string_pretty(&report).expect("a report serializes"))?;
    Ok(report)
}
