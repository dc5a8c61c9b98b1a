// Internal force and tangent stiffness of one element per invocation (total Lagrangian), with
// the material's stress and tangent at each quadrature point. CPU twin:
// `element::element_force_tangent`, which this file follows step by step.
// The prelude defines `real`, the element constants NEN (nodes), NQP (quadrature points), DIM,
// NDOF = NEN * DIM, and includes `element.wgsl` and the material (`material_stress_tangent`).

// Per element out: NDOF forces, then the NDOF x NDOF tangent row-major, local order
// (node a, component i) -> a * DIM + i.
const OUT_STRIDE = NDOF + NDOF * NDOF;
const NONE = 0xffffffffu;
const INVERTED = 0u;
const NON_FINITE = 1u;
const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> material: MaterialParams;
@group(0) @binding(1) var<storage, read> geometry: array<real>;
@group(0) @binding(2) var<storage, read> connectivity: array<u32>;
@group(0) @binding(3) var<storage, read> u: array<real>;
@group(0) @binding(4) var<storage, read_write> element_out: array<real>;
// The lowest element that failed, per failure kind (NONE when none): deterministic.
@group(0) @binding(5) var<storage, read_write> failure: array<atomic<u32>, 2>;

fn is_finite(x: real) -> bool {
    return abs(x) <= REAL_MAX;
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let e = id.x + id.y * groups.x * WORKGROUP;
    if e >= arrayLength(&connectivity) / NEN {
        return;
    }
    let ue = element_displacements(e);
    var force: array<real, NDOF>;
    var tangent: array<real, NDOF * NDOF>;
    var b: array<array<real, 6>, NDOF>;
    var inverted = false;
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let dv = point_volume(point);
        let f = deformation_gradient(point, ue);
        let det = determinant(f);
        if !(det > real(0.0)) {
            inverted = true;
            break;
        }
        let strain = green_lagrange(f);
        // Stress and tangent from one material call.
        let st = material_stress_tangent(strain);
        let s = st.s;
        let d = st.d;
        let fs = f * s;
        for (var a = 0u; a < NEN; a++) {
            let g = gradient(point, a);
            for (var i = 0u; i < DIM; i++) {
                force[a * DIM + i] += dv * (at(fs, i, 0u) * g.x + at(fs, i, 1u) * g.y + at(fs, i, 2u) * g.z);
            }
        }
        // Nonlinear strain-displacement operator, engineering shear components.
        for (var a = 0u; a < NEN; a++) {
            let g = gradient(point, a);
            for (var i = 0u; i < DIM; i++) {
                for (var r = 0u; r < 6u; r++) {
                    let k = VOIGT_I[r];
                    let l = VOIGT_J[r];
                    if k == l {
                        b[a * DIM + i][r] = at(f, i, k) * g[k];
                    } else {
                        b[a * DIM + i][r] = at(f, i, k) * g[l] + at(f, i, l) * g[k];
                    }
                }
            }
        }
        // The quadrature weight is folded into D B and S, once per point; the tangent is
        // symmetric, so only its upper triangle (row <= col) is integrated.
        let s_dv = s * dv;
        for (var col = 0u; col < NDOF; col++) {
            // dv D B_col, then B_row · dv D B_col for every row up to col.
            var db: array<real, 6>;
            for (var r = 0u; r < 6u; r++) {
                var sum = real(0.0);
                for (var c = 0u; c < 6u; c++) {
                    sum += d[r * 6u + c] * b[col][c];
                }
                db[r] = sum * dv;
            }
            let bn = col / DIM;
            let j = col % DIM;
            let sgb = s_dv * gradient(point, bn);
            for (var row = 0u; row <= col; row++) {
                var k = real(0.0);
                for (var r = 0u; r < 6u; r++) {
                    k += b[row][r] * db[r];
                }
                if row % DIM == j {
                    k += dot(sgb, gradient(point, row / DIM));
                }
                tangent[row * NDOF + col] += k;
            }
        }
    }
    let base = e * OUT_STRIDE;
    var finite = true;
    for (var r = 0u; r < NDOF; r++) {
        element_out[base + r] = force[r];
        finite = finite && is_finite(force[r]);
    }
    for (var r = 0u; r < NDOF; r++) {
        for (var c = 0u; c < NDOF; c++) {
            // The lower triangle mirrors the upper one.
            let k = tangent[min(r, c) * NDOF + max(r, c)];
            element_out[base + NDOF + r * NDOF + c] = k;
            finite = finite && is_finite(k);
        }
    }
    if inverted {
        atomicMin(&failure[INVERTED], e);
    } else if !finite {
        atomicMin(&failure[NON_FINITE], e);
    }
}
