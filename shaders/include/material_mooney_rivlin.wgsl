// Mooney-Rivlin: Ŵ = C10 (Ī₁ - 3) + C01 (Ī₂ - 3), C10 in a1, C01 in a2 (`decoupled.wgsl`).
// CPU twin: `material::MooneyRivlin`.

fn isochoric_energy(i1: real, i2: real) -> real {
    return material.a1 * (i1 - real(3.0)) + material.a2 * (i2 - real(3.0));
}

fn isochoric_derivatives(i1: real, i2: real) -> Isochoric {
    return Isochoric(material.a1, material.a2, real(0.0), real(0.0), real(0.0));
}
