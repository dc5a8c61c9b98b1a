// The start of a step of each listed member from the committed state the device keeps
// (`step_commit`), so that nothing per dof goes up for a body that steps on the device:
//   u_pred = u_t + dt v_t,   step = (m, u_pred, f_int,t, f_ext),   u = u_pred,   u_start = u_t,
//   u_base = u_t + dt (1 - θ) v_t (the base of the trial velocity `newton_contact` takes),
// the mass and external force kept from the member's last uploaded step (a body with neither
// surface loads nor prescribed dofs: they do not change). One dof per invocation, over the
// members as `assemble_residual`. A member whose `adopt_at` is this pass's `epoch` first sets
// its committed state up from the device's last iterate and forces and the host's velocity
// `adopted` (its state was the host's, and its step ended with a device Newton call the host
// took): 8 bytes a dof go up for it, not the 24 of a whole state. CPU twin: `cpu::step_begin`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<uniform> motion: StepMotion;
@group(0) @binding(1) var<storage, read_write> committed: array<DofState>;
@group(0) @binding(2) var<storage, read_write> step: array<DofStep>;
@group(0) @binding(3) var<storage, read_write> u: array<real>;
@group(0) @binding(4) var<storage, read_write> u_start: array<real>;
@group(0) @binding(5) var<storage, read> members: array<MemberRange>;
@group(0) @binding(6) var<storage, read> jobs: array<Active>;
@group(0) @binding(7) var<storage, read_write> u_base: array<real>;
@group(0) @binding(8) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(9) var<storage, read> adopted: array<real>;
@group(0) @binding(10) var<storage, read> adopt_at: array<u32>;
// The pass's number (from 1; `adopt_at` of a member that adopts in no pass is 0).
@group(0) @binding(11) var<uniform> epoch: vec4<u32>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    // A slot a member left (the host sends the slots that changed).
    let member = jobs[workgroup.z].member;
    if member == NO_MEMBER {
        return;
    }
    let range = members[member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if local >= range.dofs {
        return;
    }
    let d = range.dof_start + local;
    var c = committed[d];
    if adopt_at[member] == epoch.x {
        c = DofState(u[d], adopted[d], dof_out[d].f_int);
        committed[d] = c;
    }
    let u_pred = c.u + motion.dt * c.v;
    step[d].u_pred = u_pred;
    step[d].f_int_t = c.f_int;
    u[d] = u_pred;
    u_start[d] = c.u;
    u_base[d] = c.u + motion.dt_explicit * c.v;
}
