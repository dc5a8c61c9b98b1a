//! Structured mesh generators: rectangle, disk, annulus and convex polygon in 2D, box and ball
//! in 3D.
//!
//! Node sets: `all` always; rectangle and box add `x_min`, `x_max`, `y_min`, `y_max`
//! (and `z_min`, `z_max`); the disk and the polygon add `boundary` and `center`; the annulus
//! adds `inner`, `outer` and, for a sector, `start` and `end` (its straight edges).

use super::{ElementKind, Mesh};
use super::{CUBE_TETRAHEDRA, QUAD_TRIANGLES};
use crate::precision::Real;
use std::collections::BTreeMap;

/// Rectangle `[x0, x0+lx] x [y0, y0+ly]` with `nx x ny` cells; Tri3 splits each cell in two.
pub fn rectangle(origin: [Real; 2], size: [Real; 2], div: [usize; 2], kind: ElementKind) -> Mesh {
    let [nx, ny] = div;
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1));
    for j in 0..=ny {
        for i in 0..=nx {
            nodes.push([origin[0] + size[0] * i as Real / nx as Real, origin[1] + size[1] * j as Real / ny as Real, 0.0]);
        }
    }
    let connectivity = quad_grid_cells(nx, ny, kind, id);
    let mut sets = BTreeMap::new();
    sets.insert("x_min".into(), (0..=ny).map(|j| id(0, j)).collect());
    sets.insert("x_max".into(), (0..=ny).map(|j| id(nx, j)).collect());
    sets.insert("y_min".into(), (0..=nx).map(|i| id(i, 0)).collect());
    sets.insert("y_max".into(), (0..=nx).map(|i| id(i, ny)).collect());
    let mut mesh = Mesh { kind, nodes, connectivity, node_sets: sets };
    mesh.finish_sets();
    mesh
}

fn quad_grid_cells(nx: usize, ny: usize, kind: ElementKind, id: impl Fn(usize, usize) -> u32) -> Vec<u32> {
    let mut conn = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            let cell = [a, b, c, d];
            match kind {
                ElementKind::Quad4 => conn.extend(cell),
                _ => conn.extend(QUAD_TRIANGLES.iter().flatten().map(|&k| cell[k])),
            }
        }
    }
    conn
}

/// Disk of radius `r` about `center`: a `2n x 2n` square grid mapped onto the disk by the
/// elliptical grid mapping `(u √(1 - v²/2), v √(1 - u²/2))`. Cells near the 45° diagonals are
/// the most distorted; every Jacobian stays positive.
pub fn disk(center: [Real; 2], radius: Real, n: usize, kind: ElementKind) -> Mesh {
    let m = 2 * n;
    let id = |i: usize, j: usize| (j * (m + 1) + i) as u32;
    let mut nodes = Vec::with_capacity((m + 1) * (m + 1));
    let mut boundary = Vec::new();
    for j in 0..=m {
        for i in 0..=m {
            let u = -1.0 + 2.0 * i as Real / m as Real;
            let v = -1.0 + 2.0 * j as Real / m as Real;
            let x = u * (1.0 - 0.5 * v * v).sqrt();
            let y = v * (1.0 - 0.5 * u * u).sqrt();
            nodes.push([center[0] + radius * x, center[1] + radius * y, 0.0]);
            if i == 0 || j == 0 || i == m || j == m {
                boundary.push(id(i, j));
            }
        }
    }
    let connectivity = quad_grid_cells(m, m, kind, id);
    let mut sets = BTreeMap::new();
    sets.insert("boundary".into(), boundary);
    sets.insert("center".into(), vec![id(n, n)]);
    let mut mesh = Mesh { kind, nodes, connectivity, node_sets: sets };
    mesh.finish_sets();
    mesh
}

/// Annulus (or a sector of one) about `center`: radii `[a, b]`, opening `angle` in degrees
/// from the x axis counter-clockwise, `[nr, nt]` cells across and around. A full ring (360°)
/// closes on itself.
pub fn annulus(center: [Real; 2], [a, b]: [Real; 2], angle: Real, [nr, nt]: [usize; 2], kind: ElementKind) -> Mesh {
    let full = angle >= 360.0;
    let columns = if full { nt } else { nt + 1 };
    let id = |i: usize, j: usize| ((j % columns) * (nr + 1) + i) as u32;
    let mut nodes = Vec::with_capacity(columns * (nr + 1));
    for j in 0..columns {
        let phi = angle.to_radians() * j as Real / nt as Real;
        for i in 0..=nr {
            let r = a + (b - a) * i as Real / nr as Real;
            nodes.push([center[0] + r * phi.cos(), center[1] + r * phi.sin(), 0.0]);
        }
    }
    // Cells run outwards (i) then counter-clockwise (j): counter-clockwise corners.
    let connectivity = quad_grid_cells(nr, nt, kind, id);
    let mut sets = BTreeMap::new();
    sets.insert("inner".into(), (0..columns).map(|j| id(0, j)).collect());
    sets.insert("outer".into(), (0..columns).map(|j| id(nr, j)).collect());
    if !full {
        sets.insert("start".into(), (0..=nr).map(|i| id(i, 0)).collect());
        sets.insert("end".into(), (0..=nr).map(|i| id(i, nt)).collect());
    }
    let mut mesh = Mesh { kind, nodes, connectivity, node_sets: sets };
    mesh.finish_sets();
    mesh
}

/// Convex polygon (vertices in either order) in Tri3: the fan of triangles from the vertex
/// centroid to each edge, each split into `n x n` similar triangles, so that `n` rings of
/// nodes run parallel to the outline (ring `k` has `k` nodes per edge).
pub fn polygon(vertices: &[[Real; 2]], n: usize) -> Mesh {
    let mut v = vertices.to_vec();
    let area2: Real = (0..v.len()).map(|i| v[i][0] * v[(i + 1) % v.len()][1] - v[(i + 1) % v.len()][0] * v[i][1]).sum();
    if area2 < 0.0 {
        v.reverse();
    }
    let m = v.len();
    let c = [0, 1].map(|a| v.iter().map(|p| p[a]).sum::<Real>() / m as Real);
    // Ring k starts after the centre and the k-1 inner rings (m j nodes each, j < k).
    let ring_start = |k: usize| 1 + m * k * (k - 1) / 2;
    let id = |k: usize, edge: usize, j: usize| if k == 0 { 0 } else { (ring_start(k) + (edge * k + j) % (m * k)) as u32 };
    let mut nodes = vec![[c[0], c[1], 0.0]];
    for k in 1..=n {
        for e in 0..m {
            let (a, b) = (v[e], v[(e + 1) % m]);
            for j in 0..k {
                let s = j as Real / k as Real;
                let r = k as Real / n as Real;
                nodes.push([0, 1, 2].map(|i| if i == 2 { 0.0 } else { c[i] + r * (a[i] + s * (b[i] - a[i]) - c[i]) }));
            }
        }
    }
    let mut connectivity = Vec::with_capacity(3 * m * n * n);
    for k in 1..=n {
        for e in 0..m {
            for j in 0..k {
                connectivity.extend([id(k, e, j), id(k, e, j + 1), id(k - 1, e, j)]);
                if j + 1 < k {
                    connectivity.extend([id(k - 1, e, j), id(k, e, j + 1), id(k - 1, e, j + 1)]);
                }
            }
        }
    }
    let mut sets = BTreeMap::new();
    sets.insert("boundary".into(), (0..m * n).map(|i| (ring_start(n) + i) as u32).collect());
    sets.insert("center".into(), vec![0]);
    let mut mesh = Mesh { kind: ElementKind::Tri3, nodes, connectivity, node_sets: sets };
    mesh.finish_sets();
    mesh
}

/// Box `origin + [0,lx]x[0,ly]x[0,lz]` with `nx x ny x nz` cells; Tet4 uses the six-tetrahedron
/// Kuhn split of each cell (conforming across cells).
pub fn cuboid(origin: [Real; 3], size: [Real; 3], div: [usize; 3], kind: ElementKind) -> Mesh {
    let [nx, ny, nz] = div;
    let id = |i: usize, j: usize, k: usize| ((k * (ny + 1) + j) * (nx + 1) + i) as u32;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([origin[0] + size[0] * i as Real / nx as Real, origin[1] + size[1] * j as Real / ny as Real, origin[2] + size[2] * k as Real / nz as Real]);
            }
        }
    }
    let mut conn = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = [id(i, j, k), id(i + 1, j, k), id(i + 1, j + 1, k), id(i, j + 1, k), id(i, j, k + 1), id(i + 1, j, k + 1), id(i + 1, j + 1, k + 1), id(i, j + 1, k + 1)];
                match kind {
                    ElementKind::Hex8 => conn.extend(c),
                    _ => conn.extend(CUBE_TETRAHEDRA.iter().flatten().map(|&k| c[k])),
                }
            }
        }
    }
    let mut sets: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                let n = id(i, j, k);
                for (name, on) in [("x_min", i == 0), ("x_max", i == nx), ("y_min", j == 0), ("y_max", j == ny), ("z_min", k == 0), ("z_max", k == nz)] {
                    if on {
                        sets.entry(name.into()).or_default().push(n);
                    }
                }
            }
        }
    }
    let mut mesh = Mesh { kind, nodes, connectivity: conn, node_sets: sets };
    mesh.finish_sets();
    mesh
}

/// Ball of radius `r` about `center`: a `2n x 2n x 2n` cube of cells (`kind`: Hex8, or Tet4 by
/// the cube's split) mapped onto the ball by the 3D elliptical grid mapping
/// `x = u √(1 - v²/2 - w²/2 + v²w²/3)` (and its permutations), the 3D form of [`disk`]'s: the
/// cube's faces land on the sphere and every Jacobian stays positive.
pub fn ball(center: [Real; 3], radius: Real, n: usize, kind: ElementKind) -> Mesh {
    let m = 2 * n;
    let cube = cuboid([-1.0; 3], [2.0; 3], [m, m, m], kind);
    let on_sphere = |[u, v, w]: [Real; 3]| {
        let (u2, v2, w2) = (u * u, v * v, w * w);
        [u * (1.0 - 0.5 * v2 - 0.5 * w2 + v2 * w2 / 3.0).sqrt(), v * (1.0 - 0.5 * w2 - 0.5 * u2 + w2 * u2 / 3.0).sqrt(), w * (1.0 - 0.5 * u2 - 0.5 * v2 + u2 * v2 / 3.0).sqrt()]
    };
    let nodes = cube
        .nodes
        .iter()
        .map(|&p| {
            let x = on_sphere(p);
            [0, 1, 2].map(|i| center[i] + radius * x[i])
        })
        .collect();
    let faces = ["x_min", "x_max", "y_min", "y_max", "z_min", "z_max"];
    let boundary: Vec<u32> = faces.iter().flat_map(|f| cube.node_sets[*f].iter().copied()).collect();
    let middle = ((n * (m + 1) + n) * (m + 1) + n) as u32;
    let mut sets = BTreeMap::new();
    sets.insert("boundary".into(), boundary);
    sets.insert("center".into(), vec![middle]);
    let mut mesh = Mesh { kind, nodes, connectivity: cube.connectivity, node_sets: sets };
    mesh.finish_sets();
    mesh
}

/// Rotates `mesh` by the rotation vector `w` (axis times angle, radians) about the mean of its
/// nodes (Rodrigues' formula).
pub fn rotate(mesh: &mut Mesh, w: [Real; 3]) {
    let angle = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    if angle == 0.0 {
        return;
    }
    let k = w.map(|c| c / angle);
    let (sin, cos) = angle.sin_cos();
    let count = mesh.nodes.len() as Real;
    let c = [0, 1, 2].map(|i| mesh.nodes.iter().map(|x| x[i]).sum::<Real>() / count);
    for x in &mut mesh.nodes {
        let r = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
        let kxr = [k[1] * r[2] - k[2] * r[1], k[2] * r[0] - k[0] * r[2], k[0] * r[1] - k[1] * r[0]];
        let kr = k[0] * r[0] + k[1] * r[1] + k[2] * r[2];
        *x = [0, 1, 2].map(|i| c[i] + r[i] * cos + kxr[i] * sin + k[i] * kr * (1.0 - cos));
    }
}
