// The stopping rule of the device's Uzawa iterations after every sweep of `uzawa_sweep`, for
// each contact problem of the solve: the problem's largest change of a nodal force and largest
// nodal force (`include/uzawa_nodal.wgsl`), then `judged` (`include/uzawa.wgsl`,
// `Judge::after`). A problem that converges, or spends its max_iterations, stops: its points'
// `live` flags go to 0, so that the sweeps after leave its reactions as they are, and the host
// reads back only where each problem ended. One workgroup per problem.
// CPU twin: `cpu::uzawa_judge`, which this file follows line by line.

// The reactions after the sweep and their change over it, 3 reals per point (the problems, their
// states, the node gather and the count are `include/uzawa_nodal.wgsl`'s).
@group(0) @binding(6) var<storage, read> r: array<real>;
@group(0) @binding(7) var<storage, read> dr: array<real>;
@group(0) @binding(5) var<storage, read_write> live: array<u32>;

var<workgroup> ended: u32;

@compute @workgroup_size(UZAWA_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = problem_index(workgroup, groups);
    if !live_problem(lane, k) {
        return;
    }
    let p = problems[k];
    let extremes = nodal_extremes(lane, p);
    if lane == 0u {
        let s = judged(p, states[k], extremes.x, extremes.y);
        states[k] = s;
        ended = u32(s.status != UZAWA_LIVE);
    }
    if workgroupUniformLoad(&ended) == 1u {
        for (var i = p.point_start + lane; i < p.point_end; i += UZAWA_WORKGROUP) {
            live[i] = 0u;
        }
    }
}
