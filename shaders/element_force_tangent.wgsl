// Internal force and tangent stiffness of the elements of one batch (one element kind and one
// material model, the elements of many bodies), total Lagrangian. CPU twin:
// `element::element_force_tangent`; these are its sums, spread over the invocations of a
// workgroup so that no invocation holds a whole element matrix.
// The prelude defines `real`, the element constants NEN (nodes), NQP (quadrature points), DIM,
// NDOF = NEN * DIM, FBAR (the F-bar element, `include/fbar.wgsl`, or the displacement one), and
// includes `element.wgsl`, `fbar.wgsl`, the material (`material_stress` and
// `material_stress_tangent`, which read the private `material`) and `viscous.wgsl` (the step's
// relaxation of a member with a Prony series).
//
// Two entry points:
//   `forces`: one element per invocation, the internal force only (Newton evaluations that keep
//             a factorisation need no tangent).
//   `main`:   force and tangent of ELEMENTS_PER_GROUP elements per workgroup. Phase 1: one
//             invocation per quadrature point computes F, then the material at F (or F̄ for
//             F-bar, which needs the element's other points' J) and leaves in workgroup memory
//             what phase 2 reads. Phase 2: the node pairs (a <= b) of those elements, spread
//             over the invocations, each integrating the DIM x DIM block K_ab and, for a == b,
//             the force of node a. The displacement element contracts each point's pair tensor,
//             (K_ab)_ij = Σ_q g_a · A_ij g_b with A_(iL)(jN) = dV (F_iK C_KLMN F_jM + δ_ij S_LN):
//             the twin's B_aᵀ (dV D) B_b + (g_a · dV S g_b) I, summed in another order (the
//             sums of D B_b a pair would repeat are made once per point). F-bar: `fbar_pair`,
//             from F, dV S and dV D, whose blocks couple every point of the element through θ.
//
// Per element out: NDOF forces, then the upper triangle (row <= col) of the tangent packed row
// by row, local order (node a, component i) -> a * DIM + i.
// Per member of the batch (`batch.wgsl`): its material and the lowest failing element of each
// failure kind; `forces` runs the active members in mode FORCES, `main` those in mode TANGENT.

const PACKED = NDOF * (NDOF + 1u) / 2u;
const OUT_STRIDE = NDOF + PACKED;
const PAIRS = NEN * (NEN + 1u) / 2u;
const WORKGROUP = 64u;
// The tangent entry point: one quadrature point per invocation in phase 1. TANGENT_WORKGROUP
// (32 or 64) comes with the module, the most points whose POINT_REALS fit the device's
// workgroup memory (`gpu::shaders::tangent_workgroup`).
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
// Per viscoelastic member, from its `MemberRange.history`: the step's c, then H of each point.
@group(0) @binding(8) var<storage, read> history: array<real>;

var<private> material: MaterialParams;

// What phase 1 leaves for phase 2, POINT_REALS per quadrature point of the workgroup's elements
// (`gpu::shaders::tangent_workgroup` sizes the workgroups by it). Every point first holds its F
// at F_AT. Then the displacement element holds the packed upper triangle of the pair tensor
// A (row i DIM + L, column j DIM + N) from 0 and dV F S at P_AT, over F; F-bar holds dV S at
// S_AT and dV D at D_AT, beside F. Matrices are column-major, 9 reals.
const POINT_REALS = 54u;
const F_AT = 0u;
const S_AT = 9u;
const D_AT = 18u;
const P_AT = 45u;
var<workgroup> point_data: array<array<real, POINT_REALS>, POINTS_PER_GROUP>;
var<workgroup> point_ok: array<u32, POINTS_PER_GROUP>;

fn point_matrix(slot: u32, at: u32) -> Mat3 {
    var m: Mat3;
    for (var k = 0u; k < 3u; k++) {
        for (var i = 0u; i < 3u; i++) {
            m[k][i] = point_data[slot][at + k * 3u + i];
        }
    }
    return m;
}

fn store_point_matrix(slot: u32, at: u32, m: Mat3) {
    for (var k = 0u; k < 3u; k++) {
        for (var i = 0u; i < 3u; i++) {
            point_data[slot][at + k * 3u + i] = m[k][i];
        }
    }
}

// Index of entry (row, col), row <= col, of the packed triangle of a DIM² x DIM² matrix.
fn packed_pair(row: u32, col: u32) -> u32 {
    return row * DIM * DIM - row * (row + 1u) / 2u + col;
}

// Entry (row, col) of the pair tensor at `slot`, from its upper triangle.
fn pair_tensor(slot: u32, row: u32, col: u32) -> real {
    return point_data[slot][packed_pair(min(row, col), max(row, col))];
}

// A_(iL)(jN) = dV (Σ_KM F_iK C_KLMN F_jM + δ_ij S_LN) (indices below DIM: a plane element's
// F_iz and dN/dz are zero), C_KLMN = D[voigt(K, L)][voigt(M, N)], into `slot`'s upper triangle:
// for each (L, N), the matrix F C_(·L)(·N) Fᵀ. Its loops are unrolled by the composer, so that
// every index into D is a constant and D stays in registers (on lavapipe the tangent kernel
// ran 2.0x faster so for Tri3, 2.6x Tet4, 1.5x Quad4, 1.3x Hex8; doc/benchmarks.md).
fn store_pair_tensor(slot: u32, f: Mat3, st: StressTangent, dv: real) {
    // unroll
    for (var l = 0u; l < DIM; l++) {
        // unroll
        for (var n = 0u; n < DIM; n++) {
            var c = Mat3();
            // unroll
            for (var k = 0u; k < DIM; k++) {
                // unroll
                for (var m = 0u; m < DIM; m++) {
                    c[m][k] = st.d[voigt_of(k, l) * 6u + voigt_of(m, n)];
                }
            }
            let a = f * c * transpose(f);
            // unroll
            for (var i = 0u; i < DIM; i++) {
                // unroll
                for (var j = 0u; j < DIM; j++) {
                    let row = i * DIM + l;
                    let col = j * DIM + n;
                    if row <= col {
                        var sum = a[j][i];
                        if i == j {
                            sum += at(st.s, l, n);
                        }
                        point_data[slot][packed_pair(row, col)] = sum * dv;
                    }
                }
            }
        }
    }
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
    var fq: array<Mat3, NQP>;
    for (var q = 0u; q < NQP; q++) {
        fq[q] = deformation_gradient((e * NQP + q) * POINT_STRIDE, ue);
        if !(determinant(fq[q]) > real(0.0)) {
            fail(job.member, local, INVERTED);
            return;
        }
    }
    var theta = real(1.0);
    var theta_hat: array<vec3<real>, NEN>;
    if FBAR {
        theta = mean_dilatation(e, fq);
        theta_hat = dilatation_gradient(e, fq);
    }
    var force: array<real, NDOF>;
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let f = fq[q];
        if FBAR {
            // f_a = Σ_q dV α² (F S̄ g_a + (S̄ : C) β_a), β_a = (θ̂_a - h_a) / DIM (as a product: an
            // f64 division is a dozen instructions on a GPU; the compiler folds the constant).
            let inverse_dim = real(1.0) / real(DIM);
            let alpha = fbar_alpha(theta, determinant(f));
            let s = point_stress(range, local * NQP + q, green_lagrange(fbar_scale(f, alpha))) * point_volume(point);
            let t = scaled_trace(s, transpose(f) * f);
            let fs = f * s;
            let inv_t = transpose(inverse3(f));
            for (var a = 0u; a < NEN; a++) {
                let g = gradient(point, a);
                let beta = (theta_hat[a] - inv_t * g) * inverse_dim;
                let fa = (fs * g + t * beta) * (alpha * alpha);
                for (var i = 0u; i < DIM; i++) {
                    force[a * DIM + i] += fa[i];
                }
            }
        } else {
            let fs = f * point_stress(range, local * NQP + q, green_lagrange(f)) * point_volume(point);
            for (var a = 0u; a < NEN; a++) {
                let g = fs * gradient(point, a);
                for (var i = 0u; i < DIM; i++) {
                    force[a * DIM + i] += g[i];
                }
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

// The stress at the member's point `point` at strain `e`, relaxed if the member is viscoelastic.
fn point_stress(range: MemberRange, point: u32, e: Mat3) -> Mat3 {
    let s = material_stress(e);
    if range.history == NO_HISTORY {
        return s;
    }
    return relaxed_stress(s, e, step_relaxation(range.history), point_history(range.history, point));
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
    // Phase 1: one quadrature point per invocation, every invocation busy. First F, then (the
    // F-bar element needs every point's J) the material at F or F̄.
    let point_element = first + lane / NQP;
    let busy = job.mode == TANGENT && point_element < range.elements;
    let e = range.element_start + point_element;
    let point = (e * NQP + lane % NQP) * POINT_STRIDE;
    point_ok[lane] = 0u;
    if busy {
        let f = deformation_gradient(point, element_displacements(e));
        store_point_matrix(lane, F_AT, f);
        if determinant(f) > real(0.0) {
            point_ok[lane] = 1u;
        } else {
            fail(job.member, point_element, INVERTED);
        }
    }
    workgroupBarrier();
    let base = lane - lane % NQP;
    if busy && element_ok(base) {
        material = materials[range.material];
        var f = point_matrix(lane, F_AT);
        if FBAR {
            var fq: array<Mat3, NQP>;
            for (var q = 0u; q < NQP; q++) {
                fq[q] = point_matrix(base + q, F_AT);
            }
            f = fbar_scale(f, fbar_alpha(mean_dilatation(e, fq), determinant(f)));
        }
        let strain = green_lagrange(f);
        var st = material_stress_tangent(strain);
        if range.history != NO_HISTORY {
            st = relax(st, strain, step_relaxation(range.history), point_history(range.history, point_element * NQP + lane % NQP));
        }
        let dv = point_volume(point);
        if FBAR {
            store_point_matrix(lane, S_AT, st.s * dv);
            for (var r = 0u; r < 36u; r++) {
                point_data[lane][D_AT + r] = st.d[r] * dv;
            }
        } else {
            // Over F, which only this invocation reads.
            store_point_matrix(lane, P_AT, f * st.s * dv);
            store_pair_tensor(lane, f, st, dv);
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

// Whether every point of the element whose points start at `base` has det F > 0.
fn element_ok(base: u32) -> bool {
    for (var q = 0u; q < NQP; q++) {
        if point_ok[base + q] == 0u {
            return false;
        }
    }
    return true;
}

// The block K_ab of node pair `pair` (a <= b) of element `e`, from the points of phase 1 at
// `base`, and for a == b the force of node a.
fn pair_block(member: u32, e: u32, local: u32, base: u32, pair_index: u32) {
    var pair = pair_index;
    var a = 0u;
    // Not a counted `for`: a build with the bound `a < NEN` here (and no workgroup zero fill)
    // ran the f64 kernels 1.5x to 3x slower on an H100, probably unrolled (doc/benchmarks.md,
    // "Shader runtime checks").
    while pair >= NEN - a {
        pair -= NEN - a;
        a++;
    }
    let b = a + pair;
    if !element_ok(base) {
        // The element is inverted: phase 1 reported it.
        return;
    }
    var k: array<array<real, 3>, 3>;
    var force = vec3<real>(real(0.0));
    if FBAR {
        fbar_pair(e, base, a, b, &k, &force);
    } else {
        for (var q = 0u; q < NQP; q++) {
            let point = (e * NQP + q) * POINT_STRIDE;
            let slot = base + q;
            let ga = gradient(point, a);
            let gb = gradient(point, b);
            for (var i = 0u; i < DIM; i++) {
                for (var j = 0u; j < DIM; j++) {
                    var sum = real(0.0);
                    for (var l = 0u; l < DIM; l++) {
                        var row = real(0.0);
                        for (var n = 0u; n < DIM; n++) {
                            row += pair_tensor(slot, i * DIM + l, j * DIM + n) * gb[n];
                        }
                        sum += ga[l] * row;
                    }
                    k[i][j] += sum;
                }
            }
            if a == b {
                force += point_matrix(slot, P_AT) * ga;
            }
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

// The F-bar block K_ab = Σ_q [B̄_aᵀ (dV D̄) B̄_b + dV α² (t (2 β_a β_bᵀ + β_ab) + 2 (β_a r_bᵀ +
// r_a β_bᵀ) + (g_a · S̄ g_b) I)] and the force of node a (for a == b), with B̄ = α² (B + c βᵀ),
// t = S̄ : C, r = F S̄ g, β = d ln α / du and β_ab = d² ln α / du_a du_b (`element/fbar.rs`).
fn fbar_pair(e: u32, base: u32, a: u32, b: u32, k: ptr<function, array<array<real, 3>, 3>>, force: ptr<function, vec3<real>>) {
    // The element's θ, θ̂_a, θ̂_b and (d²θ/du_a du_b) / θ.
    var volume = real(0.0);
    var big_theta = real(0.0);
    var theta_a = vec3<real>(real(0.0));
    var theta_b = vec3<real>(real(0.0));
    var theta_ab: array<array<real, 3>, 3>;
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let f = point_matrix(base + q, F_AT);
        let dv = point_volume(point);
        let w = dv * determinant(f);
        let inv_t = transpose(inverse3(f));
        let ha = inv_t * gradient(point, a);
        let hb = inv_t * gradient(point, b);
        volume += dv;
        big_theta += w;
        theta_a += w * ha;
        theta_b += w * hb;
        for (var i = 0u; i < DIM; i++) {
            for (var j = 0u; j < DIM; j++) {
                theta_ab[i][j] += w * (ha[i] * hb[j] - ha[j] * hb[i]);
            }
        }
    }
    // Divisions as products (an f64 division is a dozen instructions on a GPU).
    let theta = big_theta / volume;
    let inverse_theta = real(1.0) / big_theta;
    let inverse_dim = real(1.0) / real(DIM);
    theta_a = theta_a * inverse_theta;
    theta_b = theta_b * inverse_theta;
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let f = point_matrix(base + q, F_AT);
        let s = point_matrix(base + q, S_AT);
        let ga = gradient(point, a);
        let gb = gradient(point, b);
        let alpha = fbar_alpha(theta, determinant(f));
        let alpha2 = alpha * alpha;
        let inv_t = transpose(inverse3(f));
        let ha = inv_t * ga;
        let hb = inv_t * gb;
        let c = transpose(f) * f;
        let t = scaled_trace(s, c);
        let beta_a = (theta_a - ha) * inverse_dim;
        let beta_b = (theta_b - hb) * inverse_dim;
        let ra = f * (s * ga);
        let rb = f * (s * gb);
        // (dV D̄) B̄_b, one column per component j of node b. Its loops and the next are unrolled
        // by the composer, so that `db` and the indices into dV D̄ are constants (on lavapipe
        // the F-bar tangent kernels ran 2.1x to 3.5x faster so; doc/benchmarks.md).
        var db: array<vec3<real>, 6>;
        // unroll
        for (var col = 0u; col < 6u; col++) {
            let bc = (b_row(f, gb, col) + scaled_voigt(c, col) * beta_b) * alpha2;
            // unroll
            for (var r = 0u; r < 6u; r++) {
                db[r] += point_data[base + q][D_AT + r * 6u + col] * bc;
            }
        }
        // unroll
        for (var r = 0u; r < 6u; r++) {
            let ba = (b_row(f, ga, r) + scaled_voigt(c, r) * beta_a) * alpha2;
            // unroll
            for (var i = 0u; i < DIM; i++) {
                // unroll
                for (var j = 0u; j < DIM; j++) {
                    (*k)[i][j] += ba[i] * db[r][j];
                }
            }
        }
        let geometric = dot(ga, s * gb);
        for (var i = 0u; i < DIM; i++) {
            for (var j = 0u; j < DIM; j++) {
                let beta_ab = (theta_ab[i][j] * inverse_theta - theta_a[i] * theta_b[j] + ha[j] * hb[i]) * inverse_dim;
                var kij = t * (real(2.0) * beta_a[i] * beta_b[j] + beta_ab) + real(2.0) * (beta_a[i] * rb[j] + ra[i] * beta_b[j]);
                if i == j {
                    kij += geometric;
                }
                (*k)[i][j] += alpha2 * kij;
            }
        }
        if a == b {
            *force += (ra + t * beta_a) * alpha2;
        }
    }
}
