//! The WGSL sources of `shaders/`, compiled into the binary, and their precision prelude.

use crate::precision::Precision;

/// Every kernel: its name (the file stem, and the name of its CPU twin) and source.
pub const SHADERS: &[(&str, &str)] = &[("uzawa_step", include_str!("../../shaders/uzawa_step.wgsl"))];

/// The source of a kernel with `real` defined for `precision`.
pub fn source(kernel: &str, precision: Precision) -> Option<String> {
    SHADERS.iter().find(|(name, _)| *name == kernel).map(|(_, text)| precision.wgsl_prelude() + text)
}

/// Parses and validates a kernel with naga, as the device would (no GPU needed).
pub fn validate(kernel: &str, precision: Precision) -> Result<naga::Module, String> {
    let text = source(kernel, precision).ok_or_else(|| format!("no shader `{kernel}`"))?;
    let module = naga::front::wgsl::parse_str(&text).map_err(|e| e.emit_to_string(&text))?;
    let capabilities = match precision {
        Precision::F64 => naga::valid::Capabilities::FLOAT64,
        Precision::F32 => naga::valid::Capabilities::empty(),
    };
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities)
        .validate(&module)
        .map_err(|e| e.emit_to_string(&text))?;
    Ok(module)
}
