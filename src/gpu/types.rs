//! The `#[repr(C)]` structs that cross to the kernels, generic over the real type (f32 or f64);
//! tests check them against naga's layouts. The CPU twins use their `Real` instances.

use bytemuck::{Pod, Zeroable};

/// `struct MaterialParams` of `shaders/include/tensor.wgsl`: G, K, a1..a5 and one unused slot
/// (zero where a model has no such parameter, see `Model::parameters`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MaterialParams<R> {
    pub g: R,
    pub k: R,
    pub a1: R,
    pub a2: R,
    pub a3: R,
    pub a4: R,
    pub a5: R,
    pub unused: R,
}

/// `struct Coefficients` of the assembly kernels: `factor` (ξ) multiplies the tangent and the
/// new internal force, `c1 = 1/(θ dt²)` the inertia.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Coefficients<R> {
    pub factor: R,
    pub c1: R,
}

/// `struct DofStep` of `assemble_residual`: what a dof needs from the start of the step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DofStep<R> {
    pub mass: R,
    /// `u_t + dt v_t`.
    pub u_pred: R,
    pub f_int_t: R,
    pub f_ext: R,
}

/// `struct DofOut` of `assemble_residual`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DofOut<R> {
    pub f_int: R,
    pub g: R,
}

// SAFETY: each is `repr(C)` with all fields of one type `R`: no padding, and every bit pattern of
// f32 or f64 is valid.
macro_rules! pod {
    ($($t:ident),*) => {$(
        unsafe impl<R: Pod> Zeroable for $t<R> {}
        unsafe impl<R: Pod> Pod for $t<R> {}
    )*};
}
pod!(MaterialParams, Coefficients, DofStep, DofOut);

impl MaterialParams<f64> {
    pub fn of(model: &crate::material::Model) -> Self {
        let [g, k, a1, a2, a3, a4, a5] = model.parameters();
        Self { g, k, a1, a2, a3, a4, a5, unused: 0.0 }
    }
}
