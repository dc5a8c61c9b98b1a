// Natural logarithm in f32: the built-in.
fn ln_real(x: real) -> real {
    return log(x);
}
