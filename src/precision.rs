//! The one place that chooses floating-point precision.
//!
//! The CPU engine runs in f64 ([`Real`]), the factorisation included. GPU kernels run in the
//! [`Precision`] of their pipeline: the WGSL sources in `shaders/` are written against an alias
//! `real`, which [`Precision::wgsl_prelude`] defines as `f32` or `f64` when a pipeline is made.

/// The floating-point type of the CPU engine.
pub type Real = f64;

/// Name of [`Real`] as written to logs (`/run.precision`).
pub const PRECISION_NAME: &str = "f64";

/// Whether two slices hold the same values bit for bit (`==` would take -0 for 0 and never NaN
/// for NaN): what decides that an evaluation's inputs, or a device copy, are unchanged.
pub fn same_bits<T: bytemuck::Pod>(a: &[T], b: &[T]) -> bool {
    bytemuck::cast_slice::<T, u8>(a) == bytemuck::cast_slice::<T, u8>(b)
}

/// Precision of a GPU pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    F32,
    F64,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    /// Bytes of one `real`.
    pub fn size(self) -> usize {
        match self {
            Precision::F32 => 4,
            Precision::F64 => 8,
        }
    }

    /// Prepended to every shader source: the `real` alias, its largest finite value and its
    /// smallest positive normal one.
    pub fn wgsl_prelude(self) -> String {
        let (max, min_positive) = match self {
            Precision::F32 => ("3.4028234663852886e38", "1.1754943508222875e-38"),
            Precision::F64 => ("1.7976931348623157e308", "2.2250738585072014e-308"),
        };
        // (`is_finite`: false for an infinity and for NaN, which compares false)
        format!("alias real = {};\nconst REAL_MAX = real({max});\nconst REAL_MIN_POSITIVE = real({min_positive});\nfn is_finite(x: real) -> bool {{\n    return abs(x) <= REAL_MAX;\n}}\n", self.name())
    }
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Self::F32),
            "f64" => Ok(Self::F64),
            _ => Err(format!("unknown precision `{s}` (f32 or f64)")),
        }
    }
}
