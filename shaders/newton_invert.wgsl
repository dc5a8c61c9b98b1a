// K̄⁻¹ of the listed members from their effective stiffness K̄ = ξ K + c1 M (the values the host
// factorised: the lower triangle of the free dofs, column by column in their pattern), into
// each member's slot of `inverse` as the lower triangle row by row (`packed`): a dense Cholesky
// factorisation K̄ = L Lᵀ in the slot, L⁻¹ in place, then K̄⁻¹ = L⁻ᵀ L⁻¹ in place. So the host
// sends a grain's non-zeros instead of its inverse (a tenth of the bytes for a 2D grain) and
// computes no inverse. Where the device still holds the stiffness values ξ K the host read back
// and factorised (`diagonal_only`), only K̄'s diagonal goes up, a value per free dof: the other
// entries are those of `values`. A K̄ that is not positive definite leaves NaN, which the iterations'
// residual hands to the host. One workgroup per listed member; each entry is summed by one
// invocation in a fixed order. CPU twin: `cpu::newton_invert`.
//
// `refactor`: within a Newton call, for each member of its refactorisation list (REFACTOR, the
// list `newton_compact`'s `refactor` made, one workgroup each, `workgroup.z`), K̄ = ξ K + c1 M
// from the stiffness values the tangent pass just assembled at its iterate and the masses of
// its free dofs (`Body::factorize_effective`), inverted as above; its displacement into
// `u_factored` (the host factorises there too) and one more in its `refactors`. CPU twin:
// `cpu::newton_invert_refactor`.

struct Inversion {
    member: u32,
    // Where its K̄ values start in `effective` (its diagonal, one per free dof, if
    // `diagonal_only`).
    values_start: u32,
    // Where its pattern starts in `patterns`: column starts (free + 1), then row indices.
    pattern_start: u32,
    // 1: the entries off the diagonal are the member's `values`.
    diagonal_only: u32,
}

@group(0) @binding(0) var<storage, read_write> inverse: array<real>;
@group(0) @binding(1) var<storage, read> newton: array<NewtonMember>;
@group(0) @binding(2) var<storage, read> effective: array<real>;
@group(0) @binding(3) var<storage, read> patterns: array<u32>;
@group(0) @binding(4) var<storage, read> inversions: array<Inversion>;
@group(0) @binding(5) var<storage, read> values: array<real>;
@group(0) @binding(6) var<storage, read> members: array<MemberRange>;
// `refactor`'s: its list, each member's pattern start in `patterns`, the free dofs, the step's
// masses, c1, the iterate and where it goes, the members' states.
@group(0) @binding(7) var<storage, read> jobs: array<Active>;
@group(0) @binding(8) var<storage, read> pattern_of: array<u32>;
@group(0) @binding(9) var<storage, read> free_dofs: array<u32>;
@group(0) @binding(10) var<storage, read> step: array<DofStep>;
@group(0) @binding(11) var<uniform> coefficients: Coefficients;
@group(0) @binding(12) var<storage, read> u: array<real>;
@group(0) @binding(13) var<storage, read_write> u_factored: array<real>;
@group(0) @binding(14) var<storage, read_write> state: array<NewtonState>;

var<workgroup> column: array<real, MAX_FREE>;
var<workgroup> pivot: real;

@compute @workgroup_size(NEWTON_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let job = inversions[workgroup.x];
    let row = newton[job.member];
    let n = row.free_count;
    let at = row.inverse_start;
    let rows = job.pattern_start + n + 1u;
    for (var e = lane; e < n * (n + 1u) / 2u; e += NEWTON_WORKGROUP) {
        inverse[at + e] = real(0.0);
    }
    storageBarrier();
    let own = members[job.member].nonzero_start;
    for (var j = lane; j < n; j += NEWTON_WORKGROUP) {
        for (var k = patterns[job.pattern_start + j]; k < patterns[job.pattern_start + j + 1u]; k++) {
            let i = patterns[rows + k];
            var value: real;
            if job.diagonal_only == 0u {
                value = effective[job.values_start + k];
            } else if i == j {
                value = effective[job.values_start + j];
            } else {
                value = values[own + k];
            }
            inverse[at + packed(i, j)] = value;
        }
    }
    storageBarrier();
    invert_in_place(lane, at, n);
}

@compute @workgroup_size(NEWTON_WORKGROUP)
fn refactor(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let m = jobs[workgroup.z].member;
    let row = newton[m];
    let range = members[m];
    let n = row.free_count;
    let at = row.inverse_start;
    let first = pattern_of[m];
    let rows = first + n + 1u;
    for (var e = lane; e < n * (n + 1u) / 2u; e += NEWTON_WORKGROUP) {
        inverse[at + e] = real(0.0);
    }
    storageBarrier();
    for (var j = lane; j < n; j += NEWTON_WORKGROUP) {
        for (var k = patterns[first + j]; k < patterns[first + j + 1u]; k++) {
            let i = patterns[rows + k];
            var value = values[range.nonzero_start + k];
            if i == j {
                value += coefficients.c1 * step[range.dof_start + free_dofs[row.free_start + j]].mass;
            }
            inverse[at + packed(i, j)] = value;
        }
    }
    storageBarrier();
    invert_in_place(lane, at, n);
    for (var d = lane; d < range.dofs; d += NEWTON_WORKGROUP) {
        u_factored[range.dof_start + d] = u[range.dof_start + d];
    }
    if lane == 0u {
        state[m].refactors += 1u;
    }
}

// K̄⁻¹ in place of K̄ (the lower triangle of an n x n slot at `at`): L, column by column (the
// pivot, the column below it, the trailing triangle), L⁻¹, then L⁻ᵀ L⁻¹.
fn invert_in_place(lane: u32, at: u32, n: u32) {
    for (var k = 0u; k < n; k++) {
        if lane == 0u {
            let d = sqrt(inverse[at + packed(k, k)]);
            inverse[at + packed(k, k)] = d;
            pivot = real(1.0) / d;
        }
        storageBarrier();
        let scale = workgroupUniformLoad(&pivot);
        for (var i = k + 1u + lane; i < n; i += NEWTON_WORKGROUP) {
            inverse[at + packed(i, k)] *= scale;
        }
        storageBarrier();
        for (var i = k + 1u + lane; i < n; i += NEWTON_WORKGROUP) {
            let lik = inverse[at + packed(i, k)];
            for (var j = k + 1u; j < i + 1u; j++) {
                inverse[at + packed(i, j)] -= lik * inverse[at + packed(j, k)];
            }
        }
        storageBarrier();
    }
    // L⁻¹ in place, from the last column back: column j is -(T a) / L_jj, with T the inverted
    // block below and right of the pivot and a the column below it.
    for (var t = 0u; t < n; t++) {
        let j = n - 1u - t;
        for (var i = j + 1u + lane; i < n; i += NEWTON_WORKGROUP) {
            column[i] = inverse[at + packed(i, j)];
        }
        if lane == 0u {
            pivot = real(1.0) / inverse[at + packed(j, j)];
        }
        let p = workgroupUniformLoad(&pivot);
        for (var i = j + 1u + lane; i < n; i += NEWTON_WORKGROUP) {
            var x = real(0.0);
            for (var k = j + 1u; k < i + 1u; k++) {
                x += inverse[at + packed(i, k)] * column[k];
            }
            inverse[at + packed(i, j)] = -p * x;
        }
        if lane == 0u {
            inverse[at + packed(j, j)] = p;
        }
        storageBarrier();
        workgroupBarrier();
    }
    // K̄⁻¹ = L⁻ᵀ L⁻¹, row by row: row i reads rows i and below of L⁻¹ only, so it is written
    // over once all of it is summed.
    for (var i = 0u; i < n; i++) {
        for (var j = lane; j < i + 1u; j += NEWTON_WORKGROUP) {
            var x = real(0.0);
            for (var k = i; k < n; k++) {
                x += inverse[at + packed(k, i)] * inverse[at + packed(k, j)];
            }
            column[j] = x;
        }
        workgroupBarrier();
        for (var j = lane; j < i + 1u; j += NEWTON_WORKGROUP) {
            inverse[at + packed(i, j)] = column[j];
        }
        storageBarrier();
        workgroupBarrier();
    }
}
