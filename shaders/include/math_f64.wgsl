// Natural logarithm in f64 (Vulkan's `log` is 32-bit only, and naga's f64 `frexp` needs 64-bit
// integers): x = m 2^e with m in [√½, √2] by exact halvings and doublings, then
// ln m = 2 atanh(s), s = (m - 1)/(m + 1), |s| < 0.172, whose series reaches 1e-17 in 12 terms.
fn ln_real(x: real) -> real {
    var m = x;
    var e = real(0.0);
    // The bounds on k stop the loops for 0, infinity and NaN (the result is then meaningless,
    // as on the CPU; the element kernel rejects those states first).
    for (var k = 0; k < 1100 && m > real(1.4142135623730951); k++) {
        m = m * real(0.5);
        e = e + real(1.0);
    }
    for (var k = 0; k < 1100 && m < real(0.7071067811865476); k++) {
        m = m * real(2.0);
        e = e - real(1.0);
    }
    let s = (m - real(1.0)) / (m + real(1.0));
    let s2 = s * s;
    var term = s;
    var sum = s;
    for (var k = 1; k < 12; k++) {
        term = term * s2;
        sum += term / real(2 * k + 1);
    }
    return real(2.0) * sum + e * real(0.6931471805599453);
}

// Cube root in f64 (no f64 `pow` either): the f32 power as the start, then two Newton steps
// on y³ = x (each squares the relative error: 1e-7, 1e-14, round-off). For x > 0.
fn cbrt_real(x: real) -> real {
    var y = real(pow(f32(x), 1.0 / 3.0));
    for (var k = 0; k < 2; k++) {
        y = y - (y * y * y - x) / (real(3.0) * y * y);
    }
    return y;
}

// Exponential in f64 (Vulkan's `exp` is 32-bit only): x = k ln 2 + r with |r| <= ln 2 / 2, exp r
// by its Taylor series (14 terms: 1e-17 at |r| = 0.35), times 2^k by exact doublings or halvings.
fn exp_real(x: real) -> real {
    let ln2 = real(0.6931471805599453);
    let k = floor(x / ln2 + real(0.5));
    let r = x - k * ln2;
    var sum = real(1.0);
    for (var n = 14; n > 0; n--) {
        sum = real(1.0) + sum * r / real(n);
    }
    // The bounds stop the loops for infinity and NaN, as in `ln_real`.
    for (var j = 0; j < 1100 && real(j) < k; j++) {
        sum = sum * real(2.0);
    }
    for (var j = 0; j < 1100 && real(j) < -k; j++) {
        sum = sum * real(0.5);
    }
    return sum;
}
