// Logarithm, exponential and cube root in f64: Vulkan has them in 32 bits only. Each is a
// multiply-add polynomial with precomputed constants and at most one f64 division (a dozen
// instructions on a GPU, where the old series divided once per term). Powers of two go through
// `ldexp`, exact over the whole f64 range.

// Natural logarithm: x = m 2^e with m in [√½, √2] (e from the f32 logarithm, then exact
// halvings or doublings: at most one, unless x is beyond f32's range), ln m = 2 atanh(s), s = (m - 1)/(m + 1),
// |s| < 0.172, whose series reaches 1e-17 in 12 terms, summed by Horner's rule in s².
fn ln_real(x: real) -> real {
    var e = i32(clamp(round(log2(f32(x))), -126.0, 126.0));
    var m = ldexp(x, -e);
    // The bounds on k stop the loops for 0, infinity and NaN (the result is then meaningless,
    // as on the CPU; the element kernel rejects those states first).
    for (var k = 0; k < 1100 && m > real(1.4142135623730951); k++) {
        m = m * real(0.5);
        e = e + 1;
    }
    for (var k = 0; k < 1100 && m < real(0.7071067811865476); k++) {
        m = m * real(2.0);
        e = e - 1;
    }
    let s = (m - real(1.0)) / (m + real(1.0));
    let s2 = s * s;
    // 1/(2k + 1) for k = 11 down to 1.
    var p = real(0.043478260869565216);
    p = p * s2 + real(0.047619047619047616);
    p = p * s2 + real(0.05263157894736842);
    p = p * s2 + real(0.058823529411764705);
    p = p * s2 + real(0.06666666666666667);
    p = p * s2 + real(0.07692307692307693);
    p = p * s2 + real(0.09090909090909091);
    p = p * s2 + real(0.1111111111111111);
    p = p * s2 + real(0.14285714285714285);
    p = p * s2 + real(0.2);
    p = p * s2 + real(0.3333333333333333);
    p = p * s2 + real(1.0);
    return real(2.0) * s * p + real(e) * real(0.6931471805599453);
}

// x^(-1/3), for x > 0: the f32 power as the start, then two Newton steps on y⁻³ = x, y ← y (4 -
// x y³) / 3 (each squares the relative error: 1e-7, 1e-14, round-off), with no division.
fn inverse_cbrt_real(x: real) -> real {
    var y = real(pow(f32(x), -1.0 / 3.0));
    for (var k = 0; k < 2; k++) {
        y = y * (real(4.0) - x * y * y * y) * real(0.3333333333333333);
    }
    return y;
}

// Cube root, for x > 0: x (x^(-1/3))².
fn cbrt_real(x: real) -> real {
    let y = inverse_cbrt_real(x);
    return x * y * y;
}

// Exponential: x = k ln 2 + r with |r| <= ln 2 / 2, exp r by its Taylor series (14 terms: 1e-17
// at |r| = 0.35) in Horner's form with the constants 1/n, times 2^k by `ldexp`.
fn exp_real(x: real) -> real {
    // The bounds keep k an i32 for infinity (NaN stays NaN through r).
    let k = clamp(floor(x * real(1.4426950408889634) + real(0.5)), real(-1100.0), real(1100.0));
    let r = x - k * real(0.6931471805599453);
    // 1/n for n = 14 down to 1: sum = 1 + r/1 (1 + r/2 (1 + ... (1 + r/14))).
    var sum = real(1.0) + r * real(0.07142857142857142);
    sum = real(1.0) + r * real(0.07692307692307693) * sum;
    sum = real(1.0) + r * real(0.08333333333333333) * sum;
    sum = real(1.0) + r * real(0.09090909090909091) * sum;
    sum = real(1.0) + r * real(0.1) * sum;
    sum = real(1.0) + r * real(0.1111111111111111) * sum;
    sum = real(1.0) + r * real(0.125) * sum;
    sum = real(1.0) + r * real(0.14285714285714285) * sum;
    sum = real(1.0) + r * real(0.16666666666666666) * sum;
    sum = real(1.0) + r * real(0.2) * sum;
    sum = real(1.0) + r * real(0.25) * sum;
    sum = real(1.0) + r * real(0.3333333333333333) * sum;
    sum = real(1.0) + r * real(0.5) * sum;
    sum = real(1.0) + r * sum;
    return ldexp(sum, i32(k));
}
