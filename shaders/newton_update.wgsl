// One Newton increment of each active member with its kept factorisation, applied as the dense
// inverse of its effective stiffness (its lower triangle, `packed`) (a small body: at most MAX_FREE free dofs):
//   Δu = K̄⁻¹ (f_c - g) on the free dofs (f_c: the contact forces, zero for a body without
//   contact points; for a group in contact, those `newton_contact`'s `forces` just applied),
//   u += Δu,
// the increment's norm and the count of increments into the member's state. One workgroup per
// member; a member no longer ITERATING does nothing. CPU twin: `cpu::newton_update`.

@group(0) @binding(0) var<storage, read> inverse: array<real>;
@group(0) @binding(1) var<storage, read> free_dofs: array<u32>;
@group(0) @binding(2) var<storage, read> newton: array<NewtonMember>;
@group(0) @binding(3) var<storage, read_write> state: array<NewtonState>;
@group(0) @binding(4) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(5) var<storage, read_write> u: array<real>;
@group(0) @binding(6) var<storage, read> members: array<MemberRange>;
@group(0) @binding(7) var<storage, read> jobs: array<Active>;
@group(0) @binding(8) var<storage, read> contact: array<real>;

var<workgroup> rhs: array<real, MAX_FREE>;
var<workgroup> go: u32;
var<workgroup> any_moved: atomic<u32>;

@compute @workgroup_size(NEWTON_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let m = jobs[workgroup.z].member;
    if lane == 0u {
        go = u32(state[m].status == ITERATING);
        atomicStore(&any_moved, 0u);
    }
    if workgroupUniformLoad(&go) == 0u {
        return;
    }
    let dof_start = members[m].dof_start;
    let row = newton[m];
    let n = row.free_count;
    for (var j = lane; j < n; j += NEWTON_WORKGROUP) {
        let d = dof_start + free_dofs[row.free_start + j];
        rhs[j] = contact[d] - dof_out[d].g;
    }
    workgroupBarrier();
    var sum2 = real(0.0);
    for (var f = lane; f < n; f += NEWTON_WORKGROUP) {
        var du = real(0.0);
        for (var j = 0u; j < n; j++) {
            du += inverse[row.inverse_start + packed(j, f)] * rhs[j];
        }
        let d = dof_start + free_dofs[row.free_start + f];
        u[d] += du;
        sum2 += du * du;
        if du != real(0.0) {
            atomicOr(&any_moved, 1u);
        }
    }
    let total = reduce_sum4(lane, vec4<real>(sum2, real(0.0), real(0.0), real(0.0))).x;
    if lane == 0u {
        state[m].increment = sqrt(total);
        state[m].iterations += 1u;
        state[m].moved |= atomicLoad(&any_moved);
    }
}
