// The Gauss-Seidel Uzawa iterations of the contact problems of a solve, whole, in one dispatch:
// one workgroup per problem sweeps its colours one after the other (the colour's points shared
// among its invocations, `include/uzawa_visit.wgsl`, a storage barrier between colours), judges
// the problem after every sweep as `uzawa_judge` does, and stops when it converges or spends
// its max_iterations, or after `count.sweeps` sweeps of this dispatch (the host then dispatches
// again). No dispatch per colour and sweep, no sweep of a problem that has stopped: for
// problems whose colours are small enough for one workgroup (grains); larger ones take
// `uzawa_sweep` and `uzawa_judge`.
// CPU twin: `cpu::uzawa_solve`, which this file follows line by line.

@group(0) @binding(0) var<storage, read> blocks: array<real>;
@group(0) @binding(1) var<storage, read> row_start: array<u32>;
@group(0) @binding(2) var<storage, read> row_entries: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> locals: array<UzawaLocal>;
// Each problem's points colour by colour: colour c of problem p is
// order[colour_start[p.colour_first + c] .. colour_start[p.colour_first + c + 1]].
@group(0) @binding(4) var<storage, read> order: array<u32>;
@group(0) @binding(5) var<storage, read> colour_start: array<u32>;
@group(0) @binding(6) var<storage, read_write> r: array<real>;
@group(0) @binding(7) var<storage, read_write> dr: array<real>;
// The problems, their states, the node gather and the count are `include/uzawa_nodal.wgsl`'s.

var<workgroup> ended: u32;

@compute @workgroup_size(UZAWA_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = problem_index(workgroup, groups);
    if !live_problem(lane, k) {
        return;
    }
    let p = problems[k];
    let colour_count = p.colours;
    for (var sweep = 0u; sweep < count.sweeps; sweep++) {
        for (var c = 0u; c < colour_count; c++) {
            let end = colour_start[p.colour_first + c + 1u];
            for (var x = colour_start[p.colour_first + c] + lane; x < end; x += UZAWA_WORKGROUP) {
                step_point(order[x]);
            }
            // The next colour reads this one's reactions.
            storageBarrier();
        }
        let extremes = nodal_extremes(lane, p);
        if lane == 0u {
            let s = judged(p, states[k], extremes.x, extremes.y);
            states[k] = s;
            ended = u32(s.status != UZAWA_LIVE);
        }
        if workgroupUniformLoad(&ended) == 1u {
            break;
        }
    }
}
