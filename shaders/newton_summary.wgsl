// What the host books at the end of a step for each member of a device Newton call that keeps
// its step's end on the device (the first KEPT_COUNT of the call's list), whose step the device
// began (its committed state is the step's start), at the iterate where its iterations ended.
// What the host reads every step, `summary_len(dim)` reals at `m * stride`:
//   [status + 4 x iterations (NewtonState, exact in a real), Σ m v² / 2, Σ m x (dim),
//    Σ m v (dim), Σ m_node x × v (1 in 2D, 3 in 3D)]
// and the box of x in f32 rounded outward (the largest f32 not above the low corner, the
// smallest not below the high one) at `m * 2 * dim` of `boxes`: low (dim), high (dim). The
// contact search only needs a box that holds the nodes; half the bytes of the exact one.
// What `newton_tally` sums over the members instead, TALLY_ROW reals at `m * TALLY_ROW` of
// `rows`:
//   [the residual, the strain energy E (`newton_finish`'s), Σ m (v - v_t)²,
//    Σ Δu ((1 - ξ) f_int,t + ξ f_int) - (E - E_t), max over nodes of |v|²]
// with v the theta rule's velocity (eq. 15, as `step_commit` computes it), x = X + u, E_t the
// committed state's strain energy. The host then needs neither the member's displacements nor
// its forces: its momenta, centre of mass and contact box come from these. One member per
// invocation. CPU twin: `cpu::newton_summary`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<uniform> motion: StepMotion;
@group(0) @binding(1) var<uniform> coefficients: Coefficients;
@group(0) @binding(2) var<storage, read> committed: array<DofState>;
@group(0) @binding(3) var<storage, read> step: array<DofStep>;
@group(0) @binding(4) var<storage, read> reference: array<real>;
@group(0) @binding(5) var<storage, read> u: array<real>;
@group(0) @binding(6) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(7) var<storage, read> members: array<MemberRange>;
@group(0) @binding(8) var<storage, read> jobs: array<Active>;
@group(0) @binding(9) var<storage, read> dispatch: array<u32>;
@group(0) @binding(10) var<storage, read_write> summary: array<real>;
@group(0) @binding(11) var<storage, read> state: array<NewtonState>;
@group(0) @binding(12) var<storage, read> member_energy: array<real>;
@group(0) @binding(13) var<storage, read_write> boxes: array<f32>;
@group(0) @binding(14) var<storage, read> committed_energy: array<real>;
@group(0) @binding(15) var<storage, read_write> rows: array<real>;

// The smallest normal f32: the step away from zero (a subnormal may be flushed to zero).
const F32_TINY = 1.17549435e-38f;

// The largest f32 not above x (f32(x) rounds by less than a unit in the last place).
fn f32_below(x: real) -> f32 {
    let y = f32(x);
    if real(y) <= x {
        return y;
    }
    if y > 0.0f {
        return bitcast<f32>(bitcast<u32>(y) - 1u);
    }
    if y < 0.0f {
        return bitcast<f32>(bitcast<u32>(y) + 1u);
    }
    return -F32_TINY;
}

// The smallest f32 not below x.
fn f32_above(x: real) -> f32 {
    return -f32_below(-x);
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= dispatch[KEPT_COUNT] {
        return;
    }
    let m = jobs[id.x].member;
    let range = members[m];
    // A motion not written yet (no step begun on the device: nothing reads these summaries)
    // still gives a dimension the loop steps by.
    let dim = clamp(u32(motion.dim), 2u, 3u);
    let angular = select(3u, 1u, dim == 2u);
    let xi = coefficients.factor;
    var kinetic = real(0.0);
    var theta_term = real(0.0);
    var force_work = real(0.0);
    var speed2 = real(0.0);
    var mx = vec3<real>(real(0.0));
    var p = vec3<real>(real(0.0));
    var l = vec3<real>(real(0.0));
    var lo = vec3<real>(real(0.0));
    var hi = vec3<real>(real(0.0));
    let nodes = select(range.dofs / 3u, range.dofs / 2u, dim == 2u);
    for (var n = 0u; n < nodes; n++) {
        let first = range.dof_start + n * dim;
        let node_mass = step[first].mass;
        var x = vec3<real>(real(0.0));
        var v = vec3<real>(real(0.0));
        var s2 = real(0.0);
        for (var i = 0u; i < dim; i++) {
            let d = first + i;
            let c = committed[d];
            let mass = step[d].mass;
            let vi = (u[d] - c.u - motion.dt_explicit * c.v) / motion.theta_dt;
            kinetic += mass * vi * vi;
            theta_term += mass * (vi - c.v) * (vi - c.v);
            force_work += (u[d] - c.u) * ((real(1.0) - xi) * c.f_int + xi * dof_out[d].f_int);
            s2 += vi * vi;
            x[i] = reference[d] + u[d];
            v[i] = vi;
            mx[i] += mass * x[i];
            p[i] += mass * vi;
            if n == 0u || x[i] < lo[i] {
                lo[i] = x[i];
            }
            if n == 0u || x[i] > hi[i] {
                hi[i] = x[i];
            }
        }
        speed2 = max(speed2, s2);
        l += node_mass * cross(x, v);
    }
    let head = m * (2u + 2u * dim + angular);
    summary[head] = real(state[m].status + 4u * state[m].iterations);
    summary[head + 1u] = real(0.5) * kinetic;
    for (var i = 0u; i < dim; i++) {
        summary[head + 2u + i] = mx[i];
        summary[head + 2u + dim + i] = p[i];
        boxes[m * 2u * dim + i] = f32_below(lo[i]);
        boxes[m * 2u * dim + dim + i] = f32_above(hi[i]);
    }
    if dim == 2u {
        summary[head + 2u + 2u * dim] = l.z;
    } else {
        for (var i = 0u; i < 3u; i++) {
            summary[head + 2u + 2u * dim + i] = l[i];
        }
    }
    let strain = member_energy[m];
    let row = m * TALLY_ROW;
    rows[row] = state[m].residual;
    rows[row + 1u] = strain;
    rows[row + 2u] = theta_term;
    rows[row + 3u] = force_work - (strain - committed_energy[m]);
    rows[row + 4u] = speed2;
}
