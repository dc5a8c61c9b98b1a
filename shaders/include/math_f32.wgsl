// Natural logarithm, cube roots and exponential in f32: the built-ins.
fn ln_real(x: real) -> real {
    return log(x);
}

// x^(-1/3): the built-in power.
fn inverse_cbrt_real(x: real) -> real {
    return pow(x, real(-1.0) / real(3.0));
}

// Cube root in f32: the built-in power.
fn cbrt_real(x: real) -> real {
    return pow(x, real(1.0) / real(3.0));
}

// Exponential in f32: the built-in.
fn exp_real(x: real) -> real {
    return exp(x);
}
