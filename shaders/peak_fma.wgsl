// The arithmetic throughput of the device: per invocation, eight independent chains of STEPS
// fused multiply-adds (2 floating-point operations each) on registers only, what `bifirst bench`
// takes as the adapter's peak. CPU twin: `cpu::peak_fma`.

const WORKGROUP = 256u;
const STEPS = 256u;

@group(0) @binding(0) var<storage, read> source: array<real>;
@group(0) @binding(1) var<storage, read_write> destination: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = id.x + id.y * groups.x * WORKGROUP;
    if i >= arrayLength(&destination) {
        return;
    }
    let x = source[i];
    var a = vec4<real>(x, x + real(1.0), x + real(2.0), x + real(3.0));
    var b = a + vec4<real>(real(0.5));
    let m = vec4<real>(real(0.999));
    let c = vec4<real>(real(0.001));
    for (var s = 0u; s < STEPS; s++) {
        a = fma(a, m, c);
        b = fma(b, m, c);
    }
    destination[i] = (a.x + a.y) + (a.z + a.w) + ((b.x + b.y) + (b.z + b.w));
}
