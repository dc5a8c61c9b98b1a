// Yeoh: Ŵ = C10 x + C20 x² + C30 x³, x = Ī₁ - 3; C10, C20, C30 in a1, a2, a3
// (`decoupled.wgsl`). CPU twin: `material::Yeoh`.

fn isochoric_energy(i1: real, i2: real) -> real {
    let x = i1 - real(3.0);
    return x * (material.a1 + x * (material.a2 + x * material.a3));
}

fn isochoric_derivatives(i1: real, i2: real) -> Isochoric {
    let x = i1 - real(3.0);
    let d1 = material.a1 + x * (real(2.0) * material.a2 + real(3.0) * x * material.a3);
    let d11 = real(2.0) * material.a2 + real(6.0) * x * material.a3;
    return Isochoric(d1, real(0.0), d11, real(0.0), real(0.0));
}
