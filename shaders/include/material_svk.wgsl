// Saint Venant-Kirchhoff: W = λ/2 (tr E)² + μ tr(E²), S = λ tr(E) I + 2μ E, with μ = G and λ in
// a1. CPU twin: `material::Svk`.

fn material_energy(e: Mat3) -> real {
    let t = trace3(e);
    return real(0.5) * material.a1 * t * t + material.g * trace3(e * e);
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    return identity3() * (material.a1 * trace3(e)) + e * (real(2.0) * material.g);
}

// S and the constant dS/dE = λ I⊗I + 2μ I⊙I.
fn material_stress_tangent(e: Mat3) -> StressTangent {
    let i = identity3();
    var d: Tangent;
    add_outer(&d, i, i, material.a1);
    add_odot(&d, i, i, real(2.0) * material.g);
    return StressTangent(material_stress(e), d);
}
