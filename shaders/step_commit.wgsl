// Commits the step each listed member ended on the device (its last Newton iterate `u` and
// internal force, as the host took them): per dof the velocity of the theta rule (eq. 15),
//   v = (u - u_t - dt (1 - θ) v_t) / (θ dt),
// and the new committed state (u, v, f_int), with its strain energy (`newton_finish`'s, where
// the iterations ended: `newton_summary` reads it as the next step's start). Run only for a
// step the host kept, before the next `step_begin`: a rejected attempt leaves the committed
// state as it was. CPU twin: `cpu::step_commit`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<uniform> motion: StepMotion;
@group(0) @binding(1) var<storage, read_write> committed: array<DofState>;
@group(0) @binding(2) var<storage, read> u: array<real>;
@group(0) @binding(3) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(4) var<storage, read> members: array<MemberRange>;
@group(0) @binding(5) var<storage, read> jobs: array<Active>;
@group(0) @binding(6) var<storage, read> member_energy: array<real>;
@group(0) @binding(7) var<storage, read_write> committed_energy: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    // A slot a member left (the host sends the slots that changed).
    let member = jobs[workgroup.z].member;
    if member == NO_MEMBER {
        return;
    }
    let range = members[member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if local == 0u {
        committed_energy[member] = member_energy[member];
    }
    if local >= range.dofs {
        return;
    }
    let d = range.dof_start + local;
    let c = committed[d];
    let v = (u[d] - c.u - motion.dt_explicit * c.v) / motion.theta_dt;
    committed[d] = DofState(u[d], v, dof_out[d].f_int);
}
