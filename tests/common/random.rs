// Shared by the test files through `#[path]`: random deformations with det F in [0.5, 2].
#![allow(dead_code)]
use bifirst::material::tensor::Mat3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

pub fn rng(seed: u64) -> SmallRng {
    SmallRng::seed_from_u64(seed)
}

/// A random deformation gradient with det F uniform in [0.5, 2].
pub fn random_f(rng: &mut SmallRng) -> Mat3 {
    loop {
        let f = Mat3::identity() + Mat3::from_fn(|_, _| rng.random_range(-0.4..0.4));
        let det = f.determinant();
        if det > 0.05 {
            let target: f64 = rng.random_range(0.5..2.0);
            return f * (target / det).cbrt();
        }
    }
}
