// Writes reals that went up with their indices into a buffer: what changed at a few dofs of a
// member's span in a host mirror (`GpuWorld`'s contact forces of device Newton calls, nonzero
// at the nodes in contact), instead of the whole span. Every index appears once. CPU twin:
// `cpu::scatter_reals`.

const WORKGROUP = 64u;

// The entries to write.
struct ScatterCount {
    count: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<storage, read> indices: array<u32>;
@group(0) @binding(1) var<storage, read> values: array<real>;
@group(0) @binding(2) var<storage, read_write> destination: array<real>;
@group(0) @binding(3) var<uniform> count: ScatterCount;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // Rows of at most 65535 workgroups: entry i sits at (i mod row, i / row).
    let i = id.x + id.y * groups.x * WORKGROUP;
    if i >= count.count {
        return;
    }
    destination[indices[i]] = values[i];
}
