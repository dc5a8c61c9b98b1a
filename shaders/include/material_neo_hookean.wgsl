// Compressible Neo-Hookean: W = G/2 (tr C - 3) - G ln J + λ/2 (ln J)², λ = K - 2G/3.
// CPU twin: `material::NeoHookean`. `ln_real` comes from the precision prelude (Vulkan has no
// f64 logarithm).

fn lambda() -> real {
    return material.k - real(2.0) * material.g / real(3.0);
}

fn material_energy(e: Mat3) -> real {
    let c = e * real(2.0) + identity3();
    let ln_j = real(0.5) * ln_real(determinant(c));
    return real(0.5) * material.g * (trace3(c) - real(3.0)) - material.g * ln_j + real(0.5) * lambda() * ln_j * ln_j;
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    let c = e * real(2.0) + identity3();
    let ln_j = real(0.5) * ln_real(determinant(c));
    let ci = inverse3(c);
    return (identity3() - ci) * material.g + ci * (lambda() * ln_j);
}

// S and dS/dE = λ C⁻¹⊗C⁻¹ + 2(G - λ ln J) C⁻¹⊙C⁻¹, sharing ln J and C⁻¹.
fn material_stress_tangent(e: Mat3) -> StressTangent {
    let c = e * real(2.0) + identity3();
    let ln_j = real(0.5) * ln_real(determinant(c));
    let ci = inverse3(c);
    var d: Tangent;
    add_outer(&d, ci, ci, lambda());
    add_odot(&d, ci, ci, real(2.0) * (material.g - lambda() * ln_j));
    return StressTangent((identity3() - ci) * material.g + ci * (lambda() * ln_j), d);
}
