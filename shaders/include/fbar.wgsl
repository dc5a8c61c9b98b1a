// The F-bar element of nearly incompressible materials (CPU twin: `element/fbar.rs`): each point
// sees F̄ = α F on the first DIM rows and columns, α = (θ / J)^(1/DIM), θ = Σ J dV / Σ dV the
// element's mean dilatation, so det F̄ = θ. The prelude sets FBAR; the displacement element
// (FBAR false) never calls these.

// α = (θ / J)^(1/DIM).
fn fbar_alpha(theta: real, j: real) -> real {
    if DIM == 2u {
        return sqrt(theta / j);
    }
    return cbrt_real(theta / j);
}

// α F on the first DIM rows and columns.
fn fbar_scale(f: Mat3, alpha: real) -> Mat3 {
    var g = f;
    for (var k = 0u; k < DIM; k++) {
        for (var i = 0u; i < DIM; i++) {
            g[k][i] = f[k][i] * alpha;
        }
    }
    return g;
}

// S̄ : C over the scaled block.
fn scaled_trace(s: Mat3, c: Mat3) -> real {
    var t = real(0.0);
    for (var k = 0u; k < DIM; k++) {
        for (var l = 0u; l < DIM; l++) {
            t += at(s, k, l) * at(c, k, l);
        }
    }
    return t;
}

// Entry r of C in engineering Voigt form over the scaled block (0 outside it).
fn scaled_voigt(c: Mat3, r: u32) -> real {
    let k = voigt_i(r);
    let l = voigt_j(r);
    if k >= DIM || l >= DIM {
        return real(0.0);
    }
    return select(real(2.0), real(1.0), k == l) * at(c, k, l);
}

// The element's mean dilatation θ from its points' F.
fn mean_dilatation(e: u32, fq: array<Mat3, NQP>) -> real {
    var volume = real(0.0);
    var big_theta = real(0.0);
    for (var q = 0u; q < NQP; q++) {
        let dv = point_volume((e * NQP + q) * POINT_STRIDE);
        volume += dv;
        big_theta += dv * determinant(fq[q]);
    }
    return big_theta / volume;
}

// θ̂_a = (dθ/du_a) / θ = Σ_q dV J h_a / Σ_q dV J, with h_a = F⁻ᵀ dN_a/dX.
fn dilatation_gradient(e: u32, fq: array<Mat3, NQP>) -> array<vec3<real>, NEN> {
    var out: array<vec3<real>, NEN>;
    var big_theta = real(0.0);
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        let w = point_volume(point) * determinant(fq[q]);
        let inv_t = transpose(inverse3(fq[q]));
        big_theta += w;
        for (var a = 0u; a < NEN; a++) {
            out[a] += w * (inv_t * gradient(point, a));
        }
    }
    let inverse = real(1.0) / big_theta;
    for (var a = 0u; a < NEN; a++) {
        out[a] = out[a] * inverse;
    }
    return out;
}
