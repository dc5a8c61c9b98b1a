// One Uzawa step per contact point (paper eq. 10), in the contact frame [n, t1, t2]:
//   predictor  tau = r - rho (v_t + (v_n + mu |v_t|) n)
//   corrector  r   = proj(tau, K_mu),  K_mu = { r : |r_t| <= mu r_n }
// v is the end-of-step relative velocity with its normal part already shifted by the gap term.
// CPU twin: `contact::law::uzawa_step`. The law itself is `include/contact_law.wgsl`; `real`
// (f32 or f64) is defined by the prelude added when the pipeline is made.

struct UzawaPoint {
    // Reaction: in, the current iterate; out, the stepped one.
    r_n: real,
    r_t1: real,
    r_t2: real,
    v_n: real,
    v_t1: real,
    v_t2: real,
    mu: real,
    rho: real,
    // Out: 0 separated, 1 sticking, 2 sliding (`contact::Status::code`).
    status: real,
}

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read_write> points: array<UzawaPoint>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // Rows of at most 65535 workgroups: point i sits at (i mod row, i / row).
    let i = id.x + id.y * groups.x * WORKGROUP;
    if i >= arrayLength(&points) {
        return;
    }
    let p = points[i];
    let out = uzawa_step(vec3<real>(p.r_n, p.r_t1, p.r_t2), vec3<real>(p.v_n, p.v_t1, p.v_t2), p.mu, p.rho);
    points[i].r_n = out.r.x;
    points[i].r_t1 = out.r.y;
    points[i].r_t2 = out.r.z;
    points[i].status = out.status;
}
