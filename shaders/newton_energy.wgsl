// The strain energy of each member of a device Newton call where its iterations ended: the sum
// of its elements' energies (`element_energy`, run over the call's list just before), in element
// order as the host sums them, so that one number per member comes back instead of one per
// element. One member per invocation. CPU twin: `cpu::newton_energy`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> energy: array<real>;
@group(0) @binding(1) var<storage, read> members: array<MemberRange>;
@group(0) @binding(2) var<storage, read> jobs: array<Active>;
@group(0) @binding(3) var<storage, read> dispatch: array<u32>;
@group(0) @binding(4) var<storage, read_write> member_energy: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= dispatch[CALL_COUNT] {
        return;
    }
    let m = jobs[id.x].member;
    let range = members[m];
    var total = real(0.0);
    for (var e = range.element_start; e < range.element_start + range.elements; e++) {
        total += energy[e];
    }
    member_energy[m] = total;
}
