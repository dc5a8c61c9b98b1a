// Finite-strain viscoelasticity: a step's relaxation of the material's stress at one point,
// `S - c Dev S + H` with `Dev S = S - (S:C)/3 C⁻¹`, and its tangent
// `D - c sym(D - ⅓ C⁻¹ ⊗ (C:D + 2S) + ⅔ (S:C) C⁻¹ ⊙ C⁻¹)`. The step's `c` and each point's
// history `H` (Voigt order) lie in the kernel's `history` binding from `MemberRange.history`.
// CPU twin: `material::viscous`.

const NO_HISTORY = 0xffffffffu;

// `c` of the member whose history starts at `start`.
fn step_relaxation(start: u32) -> real {
    return history[start];
}

// `H` of the member's point `point` (its index among the member's quadrature points).
fn point_history(start: u32, point: u32) -> Mat3 {
    let at = start + 1u + 6u * point;
    let xy = history[at + 3u];
    let yz = history[at + 4u];
    let xz = history[at + 5u];
    return Mat3(history[at], xy, xz, xy, history[at + 1u], yz, xz, yz, history[at + 2u]);
}

fn double_dot(a: Mat3, b: Mat3) -> real {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
}

fn relaxed_stress(s: Mat3, e: Mat3, c: real, h: Mat3) -> Mat3 {
    let cg = identity3() + e * real(2.0);
    return relaxed_from(s, inverse3(cg), double_dot(s, cg), c, h);
}

// `S - c Dev S + H` from `C⁻¹` and `t = S:C`.
fn relaxed_from(s: Mat3, ci: Mat3, t: real, c: real, h: Mat3) -> Mat3 {
    return s * (real(1.0) - c) + ci * (c * t / real(3.0)) + h;
}

// The relaxed stress and tangent of a material call.
fn relax(st: StressTangent, e: Mat3, c: real, h: Mat3) -> StressTangent {
    let cg = identity3() + e * real(2.0);
    let ci = inverse3(cg);
    let t = double_dot(st.s, cg);
    // X = C:D + 2S, a shear entry of C counting twice in the contraction.
    var x = st.s * real(2.0);
    for (var col = 0u; col < 6u; col++) {
        var sum = real(0.0);
        for (var r = 0u; r < 6u; r++) {
            sum += select(real(2.0), real(1.0), r < 3u) * at(cg, voigt_i(r), voigt_j(r)) * st.d[r * 6u + col];
        }
        let i = voigt_i(col);
        let j = voigt_j(col);
        x[j][i] += sum;
        if i != j {
            x[i][j] += sum;
        }
    }
    var d = st.d;
    for (var r = 0u; r < 36u; r++) {
        d[r] *= real(1.0) - c;
    }
    add_outer(&d, ci, x, c / real(6.0));
    add_outer(&d, x, ci, c / real(6.0));
    add_odot(&d, ci, ci, real(-2.0) * c * t / real(3.0));
    return StressTangent(relaxed_from(st.s, ci, t, c, h), d);
}
