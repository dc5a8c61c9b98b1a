// The largest change of a nodal force over a sweep and the largest nodal force of a problem
// (`NodalMap::change`: the bodies see the nodal forces, not the split of a reaction between
// nearly redundant points), over a workgroup, and the buffers of the problems and their states
// at the bindings both `uzawa_judge` and `uzawa_solve` use; each kernel declares the reactions
// `r` and their changes `dr` (bindings 6 and 7) with its own access. CPU twin: `cpu::uzawa_judge`.

@group(0) @binding(8) var<storage, read> problems: array<UzawaProblem>;
@group(0) @binding(9) var<storage, read_write> states: array<UzawaJudgeState>;
// Node n gathers the points node_points[node_start[n] .. node_start[n + 1]] (ascending), each
// with its coefficient in node_coefs.
@group(0) @binding(10) var<storage, read> node_start: array<u32>;
@group(0) @binding(11) var<storage, read> node_points: array<u32>;
@group(0) @binding(12) var<storage, read> node_coefs: array<real>;
// Point i's frame [n, t1, t2], row by row: 9 reals.
@group(0) @binding(13) var<storage, read> frames: array<real>;
@group(0) @binding(14) var<uniform> count: SolveCount;

var<workgroup> partial: array<vec2<real>, UZAWA_WORKGROUP>;
var<workgroup> go: u32;

// Whether problem k of the dispatch exists and is still live; the same for every invocation of
// the workgroup.
fn live_problem(lane: u32, k: u32) -> bool {
    if lane == 0u {
        go = u32(k < count.problems && states[k].status == UZAWA_LIVE);
    }
    return workgroupUniformLoad(&go) == 1u;
}

fn reaction_at(i: u32) -> vec3<real> {
    return vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]);
}

fn reaction_change(i: u32) -> vec3<real> {
    return vec3<real>(dr[3u * i], dr[3u * i + 1u], dr[3u * i + 2u]);
}

// (largest change of a nodal force, largest nodal force) of problem p, each node's sum in point
// order; every invocation of the workgroup calls it and gets the result.
fn nodal_extremes(lane: u32, p: UzawaProblem) -> vec2<real> {
    var most = vec2<real>(real(0.0));
    for (var n = p.node_start + lane; n < p.node_end; n += UZAWA_WORKGROUP) {
        var d = vec3<real>(real(0.0));
        var a = vec3<real>(real(0.0));
        for (var e = node_start[n]; e < node_start[n + 1u]; e++) {
            let i = node_points[e];
            let coef = node_coefs[e];
            d += coef * global(i, reaction_change(i));
            a += coef * global(i, reaction_at(i));
        }
        most = max(most, vec2<real>(norm(d), norm(a)));
    }
    partial[lane] = most;
    workgroupBarrier();
    for (var half = UZAWA_WORKGROUP / 2u; half > 0u; half /= 2u) {
        if lane < half {
            partial[lane] = max(partial[lane], partial[lane + half]);
        }
        workgroupBarrier();
    }
    let extremes = partial[0];
    workgroupBarrier();
    return extremes;
}
