// One pass of a sum: each workgroup of REDUCE_WIDTH invocations adds REDUCE_WIDTH consecutive
// values by halving (pairs at distance 128, 64, ..., 1) and writes one partial sum. Passes repeat
// until one value is left; the order is fixed, so the sum is deterministic.
// CPU twin: `cpu::reduce_sum`.

const REDUCE_WIDTH = 256u;

@group(0) @binding(0) var<storage, read> input: array<real>;
@group(0) @binding(1) var<storage, read_write> partial: array<real>;

var<workgroup> scratch: array<real, REDUCE_WIDTH>;

@compute @workgroup_size(REDUCE_WIDTH)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) group: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let block = group.x + group.y * groups.x;
    let i = block * REDUCE_WIDTH + lane;
    scratch[lane] = select(real(0.0), input[min(i, arrayLength(&input) - 1u)], i < arrayLength(&input));
    workgroupBarrier();
    for (var width = REDUCE_WIDTH / 2u; width > 0u; width /= 2u) {
        if lane < width {
            scratch[lane] += scratch[lane + width];
        }
        workgroupBarrier();
    }
    if lane == 0u && block < arrayLength(&partial) {
        partial[block] = scratch[0];
    }
}
