// Arruda-Boyce, its five-term series: Ŵ = μ Σᵢ Cᵢ / λm^(2i-2) (Ī₁ⁱ - 3ⁱ), μ in a1, λm in a2
// (`decoupled.wgsl`). CPU twin: `material::ArrudaBoyce`.

// Cᵢ, the inverse Langevin function's expansion (`material::rubber::ARRUDA_BOYCE`).
fn arruda_boyce_c(i: u32) -> real {
    switch i {
        case 0u: { return real(0.5); }
        case 1u: { return real(1.0) / real(20.0); }
        case 2u: { return real(11.0) / real(1050.0); }
        case 3u: { return real(19.0) / real(7000.0); }
        default: { return real(519.0) / real(673750.0); }
    }
}

fn isochoric_energy(i1: real, i2: real) -> real {
    let inv2 = real(1.0) / (material.a2 * material.a2);
    var scale = material.a1;
    var w = real(0.0);
    var x = real(1.0);
    var three = real(1.0);
    for (var i = 0u; i < 5u; i++) {
        x *= i1;
        three *= real(3.0);
        w += scale * arruda_boyce_c(i) * (x - three);
        scale *= inv2;
    }
    return w;
}

// Σ i βᵢ Ī₁^(i-1) and Σ i (i-1) βᵢ Ī₁^(i-2), βᵢ = μ Cᵢ / λm^(2i-2).
fn isochoric_derivatives(i1: real, i2: real) -> Isochoric {
    let inv2 = real(1.0) / (material.a2 * material.a2);
    var scale = material.a1;
    var d1 = real(0.0);
    var d11 = real(0.0);
    var x = real(1.0);
    var x_before = real(0.0);
    for (var i = 0u; i < 5u; i++) {
        let n = real(i + 1u);
        let beta = scale * arruda_boyce_c(i);
        d1 += n * beta * x;
        d11 += n * (n - real(1.0)) * beta * x_before;
        x_before = x;
        x *= i1;
        scale *= inv2;
    }
    return Isochoric(d1, real(0.0), d11, real(0.0), real(0.0));
}
