// The local contact law of eq. (10), shared by the Uzawa kernels: de Saxce's bi-potential
// predictor and the projection onto the Coulomb cone, in the contact frame [n, t1, t2].
// CPU twin: `contact::law` (`uzawa_step`, `project_on_cone`), which this file follows line by line.

struct Projection {
    r: vec3<real>,
    status: real,
}

const SEPARATED = 0.0;
const STICKING = 1.0;
const SLIDING = 2.0;

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

