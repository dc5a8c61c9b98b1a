// The convergence test of each active member after an evaluation, as `Body::converged` makes
// it: the residual |g - f_c| over the free dofs (f_c: the contact forces) against residual_tolerance x the force scale plus the
// round-off floor, the last increment against increment_tolerance x the step's displacement
// (or the scene's motion) plus the round-off of u. A member that passes is CONVERGED; one that
// fails goes on ITERATING while its factorisation contracts the residual at least tenfold
// (REFACTOR_CONTRACTION) and its budget lasts, else the HOST takes over; an element failure
// of the evaluation makes it FAILED. One workgroup per member. CPU twin: `cpu::newton_judge`.

const NO_FAILURE = 0xffffffffu;

@group(0) @binding(0) var<storage, read> free_dofs: array<u32>;
@group(0) @binding(1) var<storage, read> newton: array<NewtonMember>;
@group(0) @binding(2) var<storage, read_write> state: array<NewtonState>;
@group(0) @binding(3) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(4) var<storage, read> u: array<real>;
@group(0) @binding(5) var<storage, read> u_start: array<real>;
@group(0) @binding(6) var<storage, read> step: array<DofStep>;
@group(0) @binding(7) var<uniform> coefficients: Coefficients;
@group(0) @binding(8) var<storage, read> failure: array<u32>;
@group(0) @binding(9) var<storage, read> members: array<MemberRange>;
@group(0) @binding(10) var<storage, read> jobs: array<Active>;
@group(0) @binding(11) var<storage, read> contact: array<real>;

var<workgroup> go: u32;

@compute @workgroup_size(NEWTON_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let m = jobs[workgroup.z].member;
    if lane == 0u {
        go = u32(state[m].status == ITERATING);
    }
    if workgroupUniformLoad(&go) == 0u {
        return;
    }
    let range = members[m];
    let row = newton[m];
    let xi = coefficients.factor;
    // Every dof: the force scale (as `Body::absorb_residual`) and the travel.
    var scale2 = real(0.0);
    var travel = real(0.0);
    for (var k = lane; k < range.dofs; k += NEWTON_WORKGROUP) {
        let d = range.dof_start + k;
        let out = dof_out[d];
        let s = step[d];
        let inertia = out.g + (real(1.0) - xi) * (s.f_ext - s.f_int_t) + xi * (s.f_ext - out.f_int);
        let a = xi * out.f_int;
        let b = (real(1.0) - xi) * s.f_int_t;
        scale2 += inertia * inertia + a * a + b * b + s.f_ext * s.f_ext;
        travel = max(travel, abs(u[d]));
    }
    // The free dofs: residual, the step's displacement, the size of u.
    var residual2 = real(0.0);
    var step2 = real(0.0);
    var size2 = real(0.0);
    for (var f = lane; f < row.free_count; f += NEWTON_WORKGROUP) {
        let d = range.dof_start + free_dofs[row.free_start + f];
        let g = dof_out[d].g - contact[d];
        let du = u[d] - u_start[d];
        residual2 += g * g;
        step2 += du * du;
        size2 += u[d] * u[d];
    }
    let sums = sqrt(reduce_sum4(lane, vec4<real>(scale2, residual2, step2, size2)));
    let most = reduce_max(lane, travel);
    let scale = sums.x;
    let residual = sums.y;
    let moved = sums.z;
    let size = sums.w;
    if lane != 0u {
        return;
    }
    var s = state[m];
    if failure[2u * m] != NO_FAILURE || failure[2u * m + 1u] != NO_FAILURE {
        s.status = FAILED;
        state[m] = s;
        return;
    }
    let tolerance = row.residual_tolerance * scale + row.floor + row.floor_per_travel * most;
    let allowed = row.increment_tolerance * max(moved, max(row.increment_floor, coefficients.motion)) + row.round_off * size;
    let contraction = residual / max(s.residual, REAL_MIN_POSITIVE);
    s.balanced = u32(residual <= tolerance);
    if residual <= tolerance && s.increment <= allowed {
        s.status = CONVERGED;
    } else if !is_finite(residual) || s.iterations >= row.budget || contraction > real(REFACTOR_CONTRACTION) {
        s.status = HOST;
    }
    s.previous_residual = s.residual;
    s.residual = residual;
    state[m] = s;
}
