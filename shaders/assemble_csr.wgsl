// Stiffness values of the sparse pattern, one non-zero per invocation: the sum of the element
// tangent entries that land on it, listed by the gather map in element order, so the result
// does not depend on scheduling (no float atomics). CPU twin: `cpu::assemble_csr`.

struct Coefficients {
    // Multiplies every tangent entry (ξ of the theta method).
    factor: real,
    c1: real,
}

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> element_out: array<real>;
@group(0) @binding(1) var<storage, read> gather_start: array<u32>;
@group(0) @binding(2) var<storage, read> gather: array<u32>;
@group(0) @binding(3) var<uniform> coefficients: Coefficients;
@group(0) @binding(4) var<storage, read_write> values: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = id.x + id.y * groups.x * WORKGROUP;
    if k >= arrayLength(&values) {
        return;
    }
    var sum = real(0.0);
    for (var j = gather_start[k]; j < gather_start[k + 1u]; j++) {
        sum += coefficients.factor * element_out[gather[j]];
    }
    values[k] = sum;
}
