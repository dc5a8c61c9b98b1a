// Internal force and contact-free residual of the theta method, one dof of a batch's active
// members per invocation (`batch.wgsl`):
//   f_int = Σ element forces on the dof (gather map, element order: deterministic)
//   g     = c1 m (u - u_pred) - (1-ξ)(f_ext - f_int,t) - ξ (f_ext - f_int),  c1 = 1/(θ dt²)
// where u_pred = u_t + dt v_t. CPU twin: `cpu::assemble_residual`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> element_out: array<real>;
@group(0) @binding(1) var<storage, read> gather_start: array<u32>;
@group(0) @binding(2) var<storage, read> gather: array<u32>;
@group(0) @binding(3) var<uniform> coefficients: Coefficients;
@group(0) @binding(4) var<storage, read> u: array<real>;
@group(0) @binding(5) var<storage, read> step: array<DofStep>;
@group(0) @binding(6) var<storage, read_write> dof_out: array<DofOut>;
@group(0) @binding(7) var<storage, read> members: array<MemberRange>;
@group(0) @binding(8) var<storage, read> jobs: array<Active>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let range = members[jobs[workgroup.z].member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if local >= range.dofs {
        return;
    }
    let d = range.dof_start + local;
    var f = real(0.0);
    for (var j = gather_start[d]; j < gather_start[d + 1u]; j++) {
        f += element_out[gather[j]];
    }
    let xi = coefficients.factor;
    let s = step[d];
    let inertia = coefficients.c1 * s.mass * (u[d] - s.u_pred);
    dof_out[d] = DofOut(f, inertia - (real(1.0) - xi) * (s.f_ext - s.f_int_t) - xi * (s.f_ext - f));
}
