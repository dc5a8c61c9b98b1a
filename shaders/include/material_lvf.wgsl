// The LVF model, paper eqs. (4)-(5), in the invariants s2 = tr(Ed²), s3 = tr(Ed³), z = tr(E)/√3:
//   W = (G + a3 z²/4) s2 + 3K/2 z² + a1 √6/3 s3 + a2/3 z³ + a4/4 z⁴ + a5/4 s2²
// CPU twin: `material::Lvf` (which explains why eq. (5), not eq. (6), defines the stress).

const SQRT3 = 1.7320508075688772;
const SQRT6 = 2.449489742783178;

fn material_energy(e: Mat3) -> real {
    let ed = dev(e);
    let ed2 = ed * ed;
    let s2 = trace3(ed2);
    let s3 = trace3(ed2 * ed);
    let z = trace3(e) / real(SQRT3);
    let m = material;
    return (m.g + real(0.25) * m.a3 * z * z) * s2 + real(1.5) * m.k * z * z + m.a1 * real(SQRT6) / real(3.0) * s3
        + m.a2 / real(3.0) * z * z * z + real(0.25) * m.a4 * z * z * z * z + real(0.25) * m.a5 * s2 * s2;
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    let ed = dev(e);
    let ed2 = ed * ed;
    let s2 = trace3(ed2);
    let z = trace3(e) / real(SQRT3);
    let m = material;
    let dw_dz = real(0.5) * m.a3 * z * s2 + real(3.0) * m.k * z + m.a2 * z * z + m.a4 * z * z * z;
    let dw_ds2 = m.g + real(0.25) * m.a3 * z * z + real(0.5) * m.a5 * s2;
    return ed * (real(2.0) * dw_ds2) + identity3() * (dw_dz / real(SQRT3)) + dev(ed2) * (m.a1 * real(SQRT6));
}

// S and dS/dE, sharing Ed, Ed², s2 and z.
fn material_stress_tangent(e: Mat3) -> StressTangent {
    let i = identity3();
    let ed = dev(e);
    let ed2 = ed * ed;
    let s2 = trace3(ed2);
    let z = trace3(e) / real(SQRT3);
    let m = material;
    let iz = i * (real(1.0) / real(SQRT3));
    // dW/dz and dW/ds2; ds2/dE = 2 Ed, dz/dE = I/√3, ds3/dE = 3 dev(Ed²).
    let dw_dz = real(0.5) * m.a3 * z * s2 + real(3.0) * m.k * z + m.a2 * z * z + m.a4 * z * z * z;
    let dw_ds2 = m.g + real(0.25) * m.a3 * z * z + real(0.5) * m.a5 * s2;
    let s = ed * (real(2.0) * dw_ds2) + i * (dw_dz / real(SQRT3)) + dev(ed2) * (m.a1 * real(SQRT6));
    let d2w_dz2 = real(0.5) * m.a3 * s2 + real(3.0) * m.k + real(2.0) * m.a2 * z + real(3.0) * m.a4 * z * z;
    let d2w_dzds2 = real(0.5) * m.a3 * z;
    let d2w_ds2ds2 = real(0.5) * m.a5;
    let ded = ed * real(2.0);
    var d: Tangent;
    // Deviatoric projector P = I⊙I - I⊗I/3.
    add_odot(&d, i, i, real(2.0) * dw_ds2);
    add_outer(&d, i, i, -real(2.0) * dw_ds2 / real(3.0));
    add_outer(&d, ded, ded, d2w_ds2ds2);
    add_outer(&d, ded, iz, d2w_dzds2);
    add_outer(&d, iz, ded, d2w_dzds2);
    add_outer(&d, iz, iz, d2w_dz2);
    // d dev(Ed²)/dE = I⊙Ed + Ed⊙I - 2/3 (Ed⊗I + I⊗Ed)
    let a = m.a1 * real(SQRT6);
    add_odot(&d, i, ed, real(2.0) * a);
    add_outer(&d, ed, i, -real(2.0) / real(3.0) * a);
    add_outer(&d, i, ed, -real(2.0) / real(3.0) * a);
    return StressTangent(s, d);
}
