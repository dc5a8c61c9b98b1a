// One colour of a Gauss-Seidel sweep of the Uzawa iterations (paper eq. 10; `contact::uzawa`):
// one invocation per point of the colour. No two points of a colour share a body, so none reads
// a reaction another one writes, and a sweep of dispatches colour after colour gives the
// iterates of a sequential sweep in that order. Each point's visit is `include/uzawa_visit.wgsl`;
// its change goes into `dr`, which `uzawa_judge` reads after the sweep. For problems too large
// for one workgroup's `uzawa_solve`.
// CPU twin: `contact::uzawa::uzawa_sweep` (`gauss_seidel_point` per invocation), which this file
// follows line by line. The law is `include/contact_law.wgsl`; `real` (f32 or f64) is defined by
// the prelude added when the pipeline is made.

// The points of the colour: order[start .. start + count].
struct ColourRange {
    start: u32,
    count: u32,
}

const WORKGROUP = 64u;

// The 3 x 3 blocks of W, row-major in contact frames, 9 reals each.
@group(0) @binding(0) var<storage, read> blocks: array<real>;
// Point i's row of W: row_entries[row_start[i] .. row_start[i + 1]], each (column point, block).
@group(0) @binding(1) var<storage, read> row_start: array<u32>;
@group(0) @binding(2) var<storage, read> row_entries: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> locals: array<UzawaLocal>;
// The points, colour by colour.
@group(0) @binding(4) var<storage, read> order: array<u32>;
// 0 for the points of a problem that has stopped: they keep their reactions.
@group(0) @binding(5) var<storage, read> live: array<u32>;
// The reactions, 3 reals per point: in, the iterate; out, the colour's points stepped.
@group(0) @binding(6) var<storage, read_write> r: array<real>;
@group(0) @binding(7) var<uniform> colour: ColourRange;
// The change of each point's reaction over its visit, 3 reals per point.
@group(0) @binding(8) var<storage, read_write> dr: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // Rows of at most 65535 workgroups: item k sits at (k mod row, k / row).
    let k = id.x + id.y * groups.x * WORKGROUP;
    if k >= colour.count {
        return;
    }
    let i = order[colour.start + k];
    if live[i] == 0u {
        return;
    }
    step_point(i);
}
