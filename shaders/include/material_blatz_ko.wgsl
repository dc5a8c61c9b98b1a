// Blatz-Ko foam rubber, paper eqs. (2)-(3). CPU twin: `material::BlatzKo`.
//   W = G/2 (I2/I3 + 2 sqrt(I3) - 5),  S = G (sqrt(I3) C⁻¹ - C⁻²),  C = 2E + I.

fn material_energy(e: Mat3) -> real {
    let c = e * real(2.0) + identity3();
    let i3 = determinant(c);
    let c2 = c * c;
    let i2 = real(0.5) * (trace3(c) * trace3(c) - trace3(c2));
    return real(0.5) * material.g * (i2 / i3 + real(2.0) * sqrt(i3) - real(5.0));
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    let c = e * real(2.0) + identity3();
    let ci = inverse3(c);
    return (ci * sqrt(determinant(c)) - ci * ci) * material.g;
}

// S and dS/dE = 2G [ J/2 C⁻¹⊗C⁻¹ - J C⁻¹⊙C⁻¹ + C⁻¹⊙C⁻² + C⁻²⊙C⁻¹ ], sharing J, C⁻¹ and C⁻².
fn material_stress_tangent(e: Mat3) -> StressTangent {
    let c = e * real(2.0) + identity3();
    let j = sqrt(determinant(c));
    let ci = inverse3(c);
    let ci2 = ci * ci;
    let g2 = real(2.0) * material.g;
    var d: Tangent;
    add_outer(&d, ci, ci, g2 * real(0.5) * j);
    add_odot(&d, ci, ci, -g2 * j);
    add_odot(&d, ci, ci2, g2);
    add_odot(&d, ci2, ci, g2);
    return StressTangent((ci * j - ci2) * material.g, d);
}
