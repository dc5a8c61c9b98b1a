// Internal force and tangent stiffness of the elements of one batch (one element kind and one
// material model, the elements of many bodies), total Lagrangian. CPU twin:
// `element::element_force_tangent`; these are its sums, spread over the invocations of a
// workgroup so that no invocation holds a whole element matrix.
// The prelude defines `real`, the element constants NEN (nodes), NQP (quadrature points), DIM,
// NDOF = NEN * DIM, and includes `element.wgsl` and the material (`material_stress` and
// `material_stress_tangent`, which read the private `material`).
//
// Two entry points:
//   `forces`: one element per invocation, the internal force only (Newton evaluations that keep
//             a factorisation need no tangent).
//   `main`:   force and tangent of ELEMENTS_PER_GROUP elements per workgroup. Phase 1: one
//             invocation per quadrature point computes F, dV S and dV D into workgroup memory.
//             Phase 2: the node pairs (a <= b) of those elements, spread over the invocations,
//             each integrating the DIM x DIM block K_ab = Σ_q B_aᵀ (dV D) B_b + (g_a · dV S g_b) I
//             and, for a == b, the force of node a.
//
// Per element out: NDOF forces, then the upper triangle (row <= col) of the tangent packed row
// by row, local order (node a, component i) -> a * DIM + i.
// Per member of the batch (`batch.wgsl`): its material and the lowest failing element of each
// failure kind; `forces` runs the active members in mode FORCES, `main` those in mode TANGENT.

const PACKED = NDOF * (NDOF + 1u) / 2u;
const OUT_STRIDE = NDOF + PACKED;
const PAIRS = NEN * (NEN + 1u) / 2u;
const WORKGROUP = 64u;
// The tangent entry point: one quadrature point per invocation in phase 1 (32 points of dV D,
// dV S and F fit the 16 KiB of workgroup memory every adapter has, in f64).
const TANGENT_WORKGROUP = 32u;
const ELEMENTS_PER_GROUP = TANGENT_WORKGROUP / NQP;
const POINTS_PER_GROUP = ELEMENTS_PER_GROUP * NQP;
const INVERTED = 0u;
const NON_FINITE = 1u;

@group(0) @binding(0) var<storage, read> geometry: array<real>;
@group(0) @binding(1) var<storage, read> connectivity: array<u32>;
@group(0) @binding(2) var<storage, read> u: array<real>;
@group(0) @binding(3) var<storage, read_write> element_out: array<real>;
// Per member: its lowest failing element (index in the member) per failure kind; the host
// resets them to 0xffffffff.
@group(0) @binding(4) var<storage, read_write> failure: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read> members: array<MemberRange>;
@group(0) @binding(6) var<storage, read> materials: array<MaterialParams>;
@group(0) @binding(7) var<storage, read> jobs: array<Active>;

var<private> material: MaterialParams;

// What phase 1 leaves for phase 2, per quadrature point of the workgroup's elements.
var<workgroup> point_f: array<Mat3, POINTS_PER_GROUP>;
var<workgroup> point_s: array<Mat3, POINTS_PER_GROUP>;
var<workgroup> point_d: array<Tangent, POINTS_PER_GROUP>;
var<workgroup> point_ok: array<u32, POINTS_PER_GROUP>;

fn is_finite(x: real) -> bool {
    return abs(x) <= REAL_MAX;
}

// Index of entry (row, col), row <= col, in the packed upper triangle.
fn packed(row: u32, col: u32) -> u32 {
    return row * NDOF - row * (row + 1u) / 2u + col;
}

fn fail(m: u32, local: u32, kind: u32) {
    atomicMin(&failure[m * 2u + kind], local);
}

@compute @workgroup_size(WORKGROUP)
fn forces(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let job = jobs[workgroup.z];
    let range = members[job.member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if job.mode != FORCES || local >= range.elements {
        return;
    }
    let e = range.element_start + local;
    material = materials[range.material];
    let ue = element_displacements(e);
    var force: array<real, NDOF>;
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let f = deformation_gradient(point, ue);
        if !(determinant(f) > real(0.0)) {
            fail(job.member, local, INVERTED);
            return;
        }
        let fs = f * material_stress(green_lagrange(f)) * point_volume(point);
        for (var a = 0u; a < NEN; a++) {
            let g = fs * gradient(point, a);
            for (var i = 0u; i < DIM; i++) {
                force[a * DIM + i] += g[i];
            }
        }
    }
    var finite = true;
    for (var r = 0u; r < NDOF; r++) {
        element_out[e * OUT_STRIDE + r] = force[r];
        finite = finite && is_finite(force[r]);
    }
    if !finite {
        fail(job.member, local, NON_FINITE);
    }
}

// Row r of B_a (engineering shear), for the DIM components i of node a: dE_r / du_ai.
fn b_row(f: Mat3, g: vec3<real>, r: u32) -> vec3<real> {
    let k = voigt_i(r);
    let l = voigt_j(r);
    var out = vec3<real>(real(0.0));
    for (var i = 0u; i < DIM; i++) {
        if k == l {
            out[i] = at(f, i, k) * g[k];
        } else {
            out[i] = at(f, i, k) * g[l] + at(f, i, l) * g[k];
        }
    }
    return out;
}

@compute @workgroup_size(TANGENT_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let job = jobs[workgroup.z];
    let range = members[job.member];
    let first = chunk_of(workgroup) * ELEMENTS_PER_GROUP;
    // Phase 1: one quadrature point per invocation, every invocation busy.
    let point_element = first + lane / NQP;
    point_ok[lane] = 0u;
    if job.mode == TANGENT && point_element < range.elements {
        let e = range.element_start + point_element;
        material = materials[range.material];
        let point = (e * NQP + lane % NQP) * POINT_STRIDE;
        let f = deformation_gradient(point, element_displacements(e));
        point_f[lane] = f;
        if determinant(f) > real(0.0) {
            let st = material_stress_tangent(green_lagrange(f));
            let dv = point_volume(point);
            point_s[lane] = st.s * dv;
            for (var r = 0u; r < 36u; r++) {
                point_d[lane][r] = st.d[r] * dv;
            }
            point_ok[lane] = 1u;
        } else {
            fail(job.member, point_element, INVERTED);
        }
    }
    workgroupBarrier();
    if job.mode != TANGENT {
        return;
    }
    // Phase 2: the node pairs (a <= b) of the workgroup's elements, spread over the invocations.
    for (var task = lane; task < ELEMENTS_PER_GROUP * PAIRS; task += TANGENT_WORKGROUP) {
        let slot = task / PAIRS;
        let local = first + slot;
        if local < range.elements {
            pair_block(job.member, range.element_start + local, local, slot * NQP, task % PAIRS);
        }
    }
}

// The block K_ab of node pair `pair` (a <= b) of element `e`, from the points of phase 1 at
// `base`, and for a == b the force of node a.
fn pair_block(member: u32, e: u32, local: u32, base: u32, pair_index: u32) {
    var pair = pair_index;
    var a = 0u;
    while pair >= NEN - a {
        pair -= NEN - a;
        a++;
    }
    let b = a + pair;
    for (var q = 0u; q < NQP; q++) {
        if point_ok[base + q] == 0u {
            // The element is inverted: phase 1 reported it.
            return;
        }
    }
    var k: array<array<real, 3>, 3>;
    var force = vec3<real>(real(0.0));
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let f = point_f[base + q];
        let s = point_s[base + q];
        let ga = gradient(point, a);
        let gb = gradient(point, b);
        // (dV D) B_b, one column per component j of node b.
        var db: array<vec3<real>, 6>;
        for (var c = 0u; c < 6u; c++) {
            let bc = b_row(f, gb, c);
            for (var r = 0u; r < 6u; r++) {
                db[r] += point_d[base + q][r * 6u + c] * bc;
            }
        }
        let geometric = dot(ga, s * gb);
        for (var r = 0u; r < 6u; r++) {
            let ba = b_row(f, ga, r);
            for (var i = 0u; i < DIM; i++) {
                for (var j = 0u; j < DIM; j++) {
                    k[i][j] += ba[i] * db[r][j];
                }
            }
        }
        for (var i = 0u; i < DIM; i++) {
            k[i][i] += geometric;
        }
        if a == b {
            force += f * (s * ga);
        }
    }
    let out = e * OUT_STRIDE;
    var finite = true;
    for (var i = 0u; i < DIM; i++) {
        for (var j = 0u; j < DIM; j++) {
            let row = a * DIM + i;
            let col = b * DIM + j;
            if row <= col {
                element_out[out + NDOF + packed(row, col)] = k[i][j];
                finite = finite && is_finite(k[i][j]);
            }
        }
        if a == b {
            element_out[out + a * DIM + i] = force[i];
            finite = finite && is_finite(force[i]);
        }
    }
    if !finite {
        fail(member, local, NON_FINITE);
    }
}
