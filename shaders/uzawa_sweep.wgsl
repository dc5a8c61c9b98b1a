// One colour of a Gauss-Seidel sweep of the Uzawa iterations (paper eq. 10; `contact::uzawa`):
// one invocation per point of the colour. No two points of a colour share a body, so none reads
// a reaction another one writes, and a sweep of dispatches colour after colour gives the
// iterates of a sequential sweep in that order. A point takes up to LOCAL_STEPS
// predictor/corrector steps against the others' reactions, `v = v_free + shift n + W r`, until a
// step moves its reaction by at most `settle max(|r|, floor)`; its change goes into `dr`, which
// `uzawa_judge` reads after the sweep.
// CPU twin: `contact::uzawa::uzawa_sweep` (`gauss_seidel_point` per invocation), which this file
// follows line by line. The law is `include/contact_law.wgsl`; `real` (f32 or f64) is defined by
// the prelude added when the pipeline is made.

struct UzawaLocal {
    // Free velocity in the contact frame [n, t1, t2].
    v_free_n: real,
    v_free_t1: real,
    v_free_t2: real,
    // Added to the normal velocity (gap and drift correction).
    shift: real,
    mu: real,
    rho: real,
    // The settling test of the local steps: |step| <= settle max(|r|, floor).
    floor: real,
    settle: real,
}

// The points of the colour: order[start .. start + count].
struct ColourRange {
    start: u32,
    count: u32,
}

const NO_BLOCK = 0xffffffffu;
const WORKGROUP = 64u;

// The 3 x 3 blocks of W, row-major in contact frames, 9 reals each.
@group(0) @binding(0) var<storage, read> blocks: array<real>;
// Point i's row of W: row_entries[row_start[i] .. row_start[i + 1]], each (column point, block).
@group(0) @binding(1) var<storage, read> row_start: array<u32>;
@group(0) @binding(2) var<storage, read> row_entries: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> locals: array<UzawaLocal>;
// The points, colour by colour.
@group(0) @binding(4) var<storage, read> order: array<u32>;
// 0 for the points of a problem that has converged: they keep their reactions.
@group(0) @binding(5) var<storage, read> live: array<u32>;
// The reactions, 3 reals per point: in, the iterate; out, the colour's points stepped.
@group(0) @binding(6) var<storage, read_write> r: array<real>;
@group(0) @binding(7) var<uniform> colour: ColourRange;
// The change of each point's reaction over its visit, 3 reals per point.
@group(0) @binding(8) var<storage, read_write> dr: array<real>;

fn reaction(i: u32) -> vec3<real> {
    return vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]);
}

fn norm(x: vec3<real>) -> real {
    return sqrt(x.x * x.x + x.y * x.y + x.z * x.z);
}

// out + W_b x
fn add_block_times(out: vec3<real>, b: u32, x: vec3<real>) -> vec3<real> {
    let w = 9u * b;
    return vec3<real>(
        out.x + (blocks[w] * x.x + blocks[w + 1u] * x.y + blocks[w + 2u] * x.z),
        out.y + (blocks[w + 3u] * x.x + blocks[w + 4u] * x.y + blocks[w + 5u] * x.z),
        out.z + (blocks[w + 6u] * x.x + blocks[w + 7u] * x.y + blocks[w + 8u] * x.z),
    );
}

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
    let l = locals[i];
    // W r without the point's own block, whose product changes with every local step.
    var wr = vec3<real>(real(0.0));
    var own = NO_BLOCK;
    for (var e = row_start[i]; e < row_start[i + 1u]; e++) {
        let j = row_entries[e].x;
        let b = row_entries[e].y;
        if j == i {
            own = b;
            continue;
        }
        wr = add_block_times(wr, b, reaction(j));
    }
    let base = vec3<real>(l.v_free_n + wr.x + l.shift, l.v_free_t1 + wr.y, l.v_free_t2 + wr.z);
    var ri = reaction(i);
    for (var s = 0u; s < LOCAL_STEPS; s++) {
        var v = base;
        if own != NO_BLOCK {
            v = add_block_times(v, own, ri);
        }
        let stepped = uzawa_step(ri, v, l.mu, l.rho).r;
        let moved = norm(stepped - ri);
        ri = stepped;
        if moved <= l.settle * max(norm(ri), l.floor) {
            break;
        }
    }
    let before = reaction(i);
    dr[3u * i] = ri.x - before.x;
    dr[3u * i + 1u] = ri.y - before.y;
    dr[3u * i + 2u] = ri.z - before.z;
    r[3u * i] = ri.x;
    r[3u * i + 1u] = ri.y;
    r[3u * i + 2u] = ri.z;
}
