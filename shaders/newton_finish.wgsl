// What each member of a device Newton call leaves for the host where its iterations ended: its
// strain energy, the sum of its elements' energies (`element_energy`, run over the call's list
// just before) in element order as the host sums them, and its internal forces packed per dof,
// from which the host computes the residual itself (`Body::finish_device_newton`), so that 8
// bytes a dof come back instead of `DofOut`'s 16. One member per invocation. CPU twin:
// `cpu::newton_finish`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> energy: array<real>;
@group(0) @binding(1) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(2) var<storage, read> members: array<MemberRange>;
@group(0) @binding(3) var<storage, read> jobs: array<Active>;
@group(0) @binding(4) var<storage, read> dispatch: array<u32>;
@group(0) @binding(5) var<storage, read_write> member_energy: array<real>;
@group(0) @binding(6) var<storage, read_write> forces: array<real>;

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
    for (var d = range.dof_start; d < range.dof_start + range.dofs; d++) {
        forces[d] = dof_out[d].f_int;
    }
}
