// 3 x 3 blocks that a 2D round uploads as their planar upper-left 2 x 2 (4 reals a block, not
// 9), written out whole: the Delassus blocks the Uzawa kernels read, and the points' frames
// (`[n, t1, 0]`, rows `(x, y, 0)`). The third row and column are zeros, written here so that the
// kernels read them from memory and their products keep the signs of zero of the host's sweeps
// over whole blocks (a planar product in the sweeps did not). CPU twin: `cpu::planar_unpack`.

const WORKGROUP = 64u;

// The blocks to write.
struct UnpackCount {
    blocks: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// Block k's planar entries, row-major: planar[4k .. 4k + 4].
@group(0) @binding(0) var<storage, read> planar: array<real>;
// Block k, row-major: blocks[9k .. 9k + 9].
@group(0) @binding(1) var<storage, read_write> blocks: array<real>;
@group(0) @binding(2) var<uniform> count: UnpackCount;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // Rows of at most 65535 workgroups: block k sits at (k mod row, k / row).
    let k = id.x + id.y * groups.x * WORKGROUP;
    if k >= count.blocks {
        return;
    }
    let p = 4u * k;
    let w = 9u * k;
    let zero = real(0.0);
    blocks[w] = planar[p];
    blocks[w + 1u] = planar[p + 1u];
    blocks[w + 2u] = zero;
    blocks[w + 3u] = planar[p + 2u];
    blocks[w + 4u] = planar[p + 3u];
    blocks[w + 5u] = zero;
    blocks[w + 6u] = zero;
    blocks[w + 7u] = zero;
    blocks[w + 8u] = zero;
}
