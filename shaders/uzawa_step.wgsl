// One Uzawa step per contact point (paper eq. 10), in the contact frame [n, t1, t2]:
//   predictor  tau = r - rho (v_t + (v_n + mu |v_t|) n)
//   corrector  r   = proj(tau, K_mu),  K_mu = { r : |r_t| <= mu r_n }
// v is the end-of-step relative velocity with its normal part already shifted by the gap term.
// CPU twin: `contact::law::uzawa_step` (and `project_on_cone`), which this file follows line by
// line. `real` (f32 or f64) is defined by the prelude added when the pipeline is made.

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

struct Projection {
    r: vec3<real>,
    status: real,
}

const SEPARATED = 0.0;
const STICKING = 1.0;
const SLIDING = 2.0;
const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read_write> points: array<UzawaPoint>;

fn tangential_norm(x: vec3<real>) -> real {
    return sqrt(x.y * x.y + x.z * x.z);
}

fn project_on_cone(tau: vec3<real>, mu: real) -> Projection {
    let tn = tau.x;
    if mu == real(0.0) {
        // Frictionless fast path: the cone is the normal half-line.
        if tn > real(0.0) {
            return Projection(vec3<real>(tn, real(0.0), real(0.0)), real(SLIDING));
        }
        return Projection(vec3<real>(real(0.0)), real(SEPARATED));
    }
    let tt = tangential_norm(tau);
    if tt <= mu * tn {
        if tn > real(0.0) {
            return Projection(tau, real(STICKING));
        }
        return Projection(tau, real(SEPARATED));
    }
    if mu * tt <= -tn {
        return Projection(vec3<real>(real(0.0)), real(SEPARATED));
    }
    let rn = (tn + mu * tt) / (real(1.0) + mu * mu);
    let s = mu * rn / tt;
    return Projection(vec3<real>(rn, s * tau.y, s * tau.z), real(SLIDING));
}

fn uzawa_step(r: vec3<real>, v: vec3<real>, mu: real, rho: real) -> Projection {
    let vt = tangential_norm(v);
    let tau = vec3<real>(r.x - rho * (v.x + mu * vt), r.y - rho * v.y, r.z - rho * v.z);
    return project_on_cone(tau, mu);
}

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
