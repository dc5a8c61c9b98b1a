// The stopping rule of the device's Uzawa iterations, after every sweep (`uzawa_sweep`), for
// each contact problem of the solve: the largest change of a nodal force over the sweep and the
// largest nodal force (`NodalMap::change`: the bodies see the nodal forces, not the split of a
// reaction between nearly redundant points), then `Judge::after`: the distance to the fixed
// point estimated from the contraction of the last two changes. A problem that converges, or
// spends its max_iterations, stops: its points' `live` flags go to 0, so that the sweeps after
// leave its reactions as they are, and the host reads back only where each problem ended.
// One workgroup per problem. CPU twin: `cpu::uzawa_judge`, which this file follows line by line.

struct UzawaProblem {
    // Its points: point_start .. point_end; its nodes: node_start .. node_end.
    point_start: u32,
    point_end: u32,
    node_start: u32,
    node_end: u32,
    max_iterations: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    tolerance: real,
    floor: real,
}

struct UzawaJudgeState {
    status: u32,
    // Sweeps judged so far.
    iterations: u32,
    pad0: u32,
    pad1: u32,
    // The last sweep's largest change of a nodal force (negative before the first sweep).
    previous: real,
    // That change over the scale max(largest nodal force, floor) (`Outcome::change`).
    change: real,
}

// The problem count: the buffers may hold more.
struct JudgeCount {
    problems: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// `UzawaJudgeState.status`.
const LIVE = 0u;
const CONVERGED = 1u;
// max_iterations sweeps without converging.
const SPENT = 2u;

const JUDGE_WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> problems: array<UzawaProblem>;
@group(0) @binding(1) var<storage, read_write> states: array<UzawaJudgeState>;
// Node n gathers the points node_points[node_start[n] .. node_start[n + 1]] (ascending), each
// with its coefficient in node_coefs.
@group(0) @binding(2) var<storage, read> node_start: array<u32>;
@group(0) @binding(3) var<storage, read> node_points: array<u32>;
@group(0) @binding(4) var<storage, read> node_coefs: array<real>;
// Point i's frame [n, t1, t2], row by row: 9 reals.
@group(0) @binding(5) var<storage, read> frames: array<real>;
// The reactions after the sweep and their change over it, 3 reals per point.
@group(0) @binding(6) var<storage, read> r: array<real>;
@group(0) @binding(7) var<storage, read> dr: array<real>;
@group(0) @binding(8) var<storage, read_write> live: array<u32>;
@group(0) @binding(9) var<uniform> count: JudgeCount;

var<workgroup> partial: array<vec2<real>, JUDGE_WORKGROUP>;
var<workgroup> go: u32;
var<workgroup> ended: u32;

// x (contact frame of point i) in global coordinates.
fn global(i: u32, x: vec3<real>) -> vec3<real> {
    let f = 9u * i;
    return vec3<real>(
        x.x * frames[f] + x.y * frames[f + 3u] + x.z * frames[f + 6u],
        x.x * frames[f + 1u] + x.y * frames[f + 4u] + x.z * frames[f + 7u],
        x.x * frames[f + 2u] + x.y * frames[f + 5u] + x.z * frames[f + 8u],
    );
}

fn reaction(i: u32) -> vec3<real> {
    return vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]);
}

fn reaction_change(i: u32) -> vec3<real> {
    return vec3<real>(dr[3u * i], dr[3u * i + 1u], dr[3u * i + 2u]);
}

fn norm(x: vec3<real>) -> real {
    return sqrt(x.x * x.x + x.y * x.y + x.z * x.z);
}

@compute @workgroup_size(JUDGE_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // Rows of at most 65535 workgroups: problem k sits at (k mod row, k / row).
    let k = workgroup.x + workgroup.y * groups.x;
    if lane == 0u {
        go = u32(k < count.problems && states[k].status == LIVE);
    }
    if workgroupUniformLoad(&go) == 0u {
        return;
    }
    let p = problems[k];
    // Largest change of a nodal force and largest nodal force, each node's sum in point order.
    var most = vec2<real>(real(0.0));
    for (var n = p.node_start + lane; n < p.node_end; n += JUDGE_WORKGROUP) {
        var d = vec3<real>(real(0.0));
        var a = vec3<real>(real(0.0));
        for (var e = node_start[n]; e < node_start[n + 1u]; e++) {
            let i = node_points[e];
            let coef = node_coefs[e];
            d += coef * global(i, reaction_change(i));
            a += coef * global(i, reaction(i));
        }
        most = max(most, vec2<real>(norm(d), norm(a)));
    }
    partial[lane] = most;
    workgroupBarrier();
    for (var half = JUDGE_WORKGROUP / 2u; half > 0u; half /= 2u) {
        if lane < half {
            partial[lane] = max(partial[lane], partial[lane + half]);
        }
        workgroupBarrier();
    }
    if lane == 0u {
        let change = partial[0].x;
        let size = partial[0].y;
        var s = states[k];
        s.iterations += 1u;
        let scale = max(max(size, p.floor), REAL_MIN_POSITIVE);
        // Before the first sweep the ratio is 0, as the CPU's change over an infinite one.
        var q = real(0.0);
        if s.previous >= real(0.0) {
            q = change / s.previous;
        }
        s.previous = change;
        var error = REAL_MAX;
        if q < real(1.0) {
            error = change * q / (real(1.0) - q);
        }
        // Far below the tolerance the ratio is round-off; a change that small is converged.
        let converged = change <= real(1e-3) * p.tolerance * scale || (change <= p.tolerance * scale && error <= p.tolerance * scale);
        s.change = change / scale;
        if converged {
            s.status = CONVERGED;
        } else if s.iterations >= p.max_iterations {
            s.status = SPENT;
        }
        states[k] = s;
        ended = u32(s.status != LIVE);
    }
    if workgroupUniformLoad(&ended) == 1u {
        for (var i = p.point_start + lane; i < p.point_end; i += JUDGE_WORKGROUP) {
            live[i] = 0u;
        }
    }
}
