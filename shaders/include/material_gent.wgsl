// Gent: Ŵ = -(G Jm / 2) ln(1 - (Ī₁ - 3) / Jm), G in g, Jm in a1 (`decoupled.wgsl`); beyond
// the limit every value is REAL_MAX, so that the stress is not finite and the element fails.
// CPU twin: `material::Gent`.

// 1 - (Ī₁ - 3) / Jm, the distance to the limit.
fn gent_reserve(i1: real) -> real {
    return real(1.0) - (i1 - real(3.0)) / material.a1;
}

fn isochoric_energy(i1: real, i2: real) -> real {
    let r = gent_reserve(i1);
    if !(r > real(0.0)) {
        return REAL_MAX;
    }
    return real(-0.5) * material.g * material.a1 * ln_real(r);
}

fn isochoric_derivatives(i1: real, i2: real) -> Isochoric {
    let r = gent_reserve(i1);
    if !(r > real(0.0)) {
        return Isochoric(REAL_MAX, real(0.0), REAL_MAX, real(0.0), real(0.0));
    }
    return Isochoric(real(0.5) * material.g / r, real(0.0), real(0.5) * material.g / (material.a1 * r * r), real(0.0), real(0.0));
}
