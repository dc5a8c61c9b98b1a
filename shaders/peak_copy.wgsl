// The copy bandwidth of the device: one vec4 of reals per invocation, read once and written
// once, what `bifirst bench` takes as the adapter's peak memory bandwidth. CPU twin:
// `cpu::peak_copy`.

const WORKGROUP = 256u;

@group(0) @binding(0) var<storage, read> source: array<vec4<real>>;
@group(0) @binding(1) var<storage, read_write> destination: array<vec4<real>>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = id.x + id.y * groups.x * WORKGROUP;
    if i < arrayLength(&destination) {
        destination[i] = source[i];
    }
}
