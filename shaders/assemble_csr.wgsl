// Stiffness values of the sparse patterns of a batch's members in mode TANGENT (`batch.wgsl`),
// one non-zero per invocation: the sum of the element tangent entries that land on it, listed
// by the gather map in element order, so the result does not depend on scheduling (no float
// atomics). CPU twin: `cpu::assemble_csr`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> element_out: array<real>;
@group(0) @binding(1) var<storage, read> gather_start: array<u32>;
@group(0) @binding(2) var<storage, read> gather: array<u32>;
@group(0) @binding(3) var<uniform> coefficients: Coefficients;
@group(0) @binding(4) var<storage, read_write> values: array<real>;
@group(0) @binding(5) var<storage, read> members: array<MemberRange>;
@group(0) @binding(6) var<storage, read> jobs: array<Active>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let job = jobs[workgroup.z];
    let range = members[job.member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if job.mode != TANGENT || local >= range.nonzeros {
        return;
    }
    let k = range.nonzero_start + local;
    var sum = real(0.0);
    for (var j = gather_start[k]; j < gather_start[k + 1u]; j++) {
        sum += coefficients.factor * element_out[gather[j]];
    }
    values[k] = sum;
}
