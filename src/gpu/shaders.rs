//! The WGSL sources of `shaders/`, compiled into the binary, and how a kernel's module is
//! composed: the precision prelude, the batch layout (`include/batch.wgsl`) for the kernels that
//! run over a batch of bodies, the contact law (`include/contact_law.wgsl`) and the CPU's
//! `LOCAL_STEPS` for the Uzawa kernels, then for element kernels the element constants and the shared
//! includes of `shaders/include/`, then the kernel; last, the loops marked `// unroll` are
//! unrolled (`unroll.rs`).

mod unroll;

use crate::element::Formulation;
use crate::material::Model;
use crate::mesh::ElementKind;
use crate::precision::Precision;

/// Every kernel: its name (the file stem, and the name of its CPU twin) and source.
pub const SHADERS: &[(&str, &str)] = &[
    ("assemble_csr", include_str!("../../shaders/assemble_csr.wgsl")),
    ("assemble_residual", include_str!("../../shaders/assemble_residual.wgsl")),
    ("element_energy", include_str!("../../shaders/element_energy.wgsl")),
    ("element_force_tangent", include_str!("../../shaders/element_force_tangent.wgsl")),
    ("newton_compact", include_str!("../../shaders/newton_compact.wgsl")),
    ("newton_contact", include_str!("../../shaders/newton_contact.wgsl")),
    ("newton_finish", include_str!("../../shaders/newton_finish.wgsl")),
    ("newton_invert", include_str!("../../shaders/newton_invert.wgsl")),
    ("newton_judge", include_str!("../../shaders/newton_judge.wgsl")),
    ("newton_summary", include_str!("../../shaders/newton_summary.wgsl")),
    ("newton_tally", include_str!("../../shaders/newton_tally.wgsl")),
    ("newton_update", include_str!("../../shaders/newton_update.wgsl")),
    ("planar_unpack", include_str!("../../shaders/planar_unpack.wgsl")),
    ("peak_copy", include_str!("../../shaders/peak_copy.wgsl")),
    ("scatter_reals", include_str!("../../shaders/scatter_reals.wgsl")),
    ("step_begin", include_str!("../../shaders/step_begin.wgsl")),
    ("step_commit", include_str!("../../shaders/step_commit.wgsl")),
    ("peak_fma", include_str!("../../shaders/peak_fma.wgsl")),
    ("uzawa_judge", include_str!("../../shaders/uzawa_judge.wgsl")),
    ("uzawa_solve", include_str!("../../shaders/uzawa_solve.wgsl")),
    ("uzawa_step", include_str!("../../shaders/uzawa_step.wgsl")),
    ("uzawa_sweep", include_str!("../../shaders/uzawa_sweep.wgsl")),
];

/// The shared includes of `shaders/include/`; the materials' come from their models ([`material_includes`]).
pub const INCLUDES: &[(&str, &str)] = &[
    ("batch", include_str!("../../shaders/include/batch.wgsl")),
    ("contact_frame", include_str!("../../shaders/include/contact_frame.wgsl")),
    ("contact_law", include_str!("../../shaders/include/contact_law.wgsl")),
    ("decoupled", include_str!("../../shaders/include/decoupled.wgsl")),
    ("element", include_str!("../../shaders/include/element.wgsl")),
    ("fbar", include_str!("../../shaders/include/fbar.wgsl")),
    ("math_f32", include_str!("../../shaders/include/math_f32.wgsl")),
    ("math_f64", include_str!("../../shaders/include/math_f64.wgsl")),
    ("newton", include_str!("../../shaders/include/newton.wgsl")),
    ("tensor", include_str!("../../shaders/include/tensor.wgsl")),
    ("uzawa", include_str!("../../shaders/include/uzawa.wgsl")),
    ("uzawa_nodal", include_str!("../../shaders/include/uzawa_nodal.wgsl")),
    ("uzawa_visit", include_str!("../../shaders/include/uzawa_visit.wgsl")),
    ("viscous", include_str!("../../shaders/include/viscous.wgsl")),
];

/// The materials the element kernels can be built for (`Model::name`), in the registry's order.
pub fn materials() -> impl Iterator<Item = &'static str> {
    Model::ENTRIES.iter().map(|e| e.name)
}

/// Whether a material is written as `Ŵ(Ī₁, Ī₂) + U(J)`: its include gives `Ŵ` alone, and
/// `include/decoupled.wgsl` the stress and tangent.
pub fn is_decoupled(material: &str) -> bool {
    Model::entry(material).is_some_and(|e| e.decoupled)
}

/// Every material's include (`material_<name>`, the registry's `Law::WGSL`).
pub fn material_includes() -> impl Iterator<Item = (String, &'static str)> {
    Model::ENTRIES.iter().map(|e| (format!("material_{}", e.name), e.wgsl))
}

/// The element, formulation and material an element kernel is built for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ElementVariant {
    pub kind: ElementKind,
    pub formulation: Formulation,
    pub material: &'static str,
}

impl ElementVariant {
    /// Every element kind with every material, and the F-bar element where it applies.
    pub fn all() -> Vec<Self> {
        let kinds = [ElementKind::Tri3, ElementKind::Quad4, ElementKind::Tet4, ElementKind::Hex8];
        let elements = kinds.iter().flat_map(|&kind| {
            let fbar = Formulation::fbar_applies(kind).then_some((kind, Formulation::Fbar));
            std::iter::once((kind, Formulation::Displacement)).chain(fbar)
        });
        elements.flat_map(|(kind, formulation)| materials().map(move |material| Self { kind, formulation, material })).collect()
    }
}

/// Whether a kernel is built per element variant.
pub fn is_element_kernel(kernel: &str) -> bool {
    kernel.starts_with("element_")
}

/// Whether a kernel steps contact points with the engine's contact law (its include,
/// `ContactLaw::INCLUDE`: `include/contact_law.wgsl` for Coulomb).
pub fn is_contact_kernel(kernel: &str) -> bool {
    kernel.starts_with("uzawa_")
}

/// Whether a kernel runs over the members of a batch (`shaders/include/batch.wgsl`).
pub fn is_batch_kernel(kernel: &str) -> bool {
    is_element_kernel(kernel) || kernel.starts_with("assemble_") || kernel.starts_with("step_") || is_newton_kernel(kernel)
}

/// Whether a kernel is one of a device Newton iteration's own (`shaders/include/newton.wgsl`).
pub fn is_newton_kernel(kernel: &str) -> bool {
    kernel.starts_with("newton_")
}

fn include(name: &str) -> Result<&'static str, String> {
    INCLUDES.iter().find(|(n, _)| *n == name).map(|(_, text)| *text).ok_or_else(|| format!("no include `{name}`"))
}

/// The workgroup memory every adapter has (WebGPU's least `maxComputeWorkgroupStorageSize`).
pub const LEAST_WORKGROUP_BYTES: u32 = 16384;

/// Quadrature points per workgroup of `element_force_tangent`'s tangent entry point (one per
/// invocation): 64 where what their phase 1 leaves fits `workgroup_bytes`, else 32, which fit
/// [`LEAST_WORKGROUP_BYTES`] in f64. On an H100, 64 ran the Hex8 f64 kernel 1.4x faster than
/// 32 (doc/benchmarks.md, "Shader runtime checks").
pub fn tangent_workgroup(precision: Precision, workgroup_bytes: u32) -> u32 {
    // Per point: its `POINT_REALS` (54) reals and a flag.
    let per_point = 54 * precision.size() as u32 + 4;
    if 64 * per_point <= workgroup_bytes {
        64
    } else {
        32
    }
}

/// The module of a kernel at `precision`; element kernels need their variant. `workgroup_bytes`
/// is the device's workgroup memory, which sizes `element_force_tangent`'s workgroups.
pub fn source(kernel: &str, precision: Precision, variant: Option<ElementVariant>, workgroup_bytes: u32) -> Result<String, String> {
    let text = SHADERS.iter().find(|(name, _)| *name == kernel).map(|(_, text)| *text).ok_or_else(|| format!("no shader `{kernel}`"))?;
    let mut module = precision.wgsl_prelude();
    if is_batch_kernel(kernel) {
        module += include("batch")?;
    }
    if is_newton_kernel(kernel) {
        use super::types::{NEWTON_MAX_FREE, NEWTON_WORKGROUP, TALLY_LEN, TALLY_ROW};
        module += &format!("const MAX_FREE = {NEWTON_MAX_FREE}u;\nconst NEWTON_WORKGROUP = {NEWTON_WORKGROUP}u;\nconst REFACTOR_CONTRACTION = {:?};\n", crate::policy::REFACTOR_CONTRACTION);
        module += &format!("const TALLY_ROW = {TALLY_ROW}u;\nconst TALLY_LEN = {TALLY_LEN}u;\n");
        module += include("newton")?;
        if kernel == "newton_contact" {
            // The Uzawa points, problems and states it prepares and reads (`uzawa_solve`'s).
            module += &format!(
                "const TIGHTEN_AFTER = {}u;\nconst UZAWA_STALLS = {}u;\nconst TIGHTEST_INNER = {:?};\nconst SETTLE = {:?};\n",
                crate::policy::TIGHTEN_AFTER,
                crate::policy::UZAWA_STALLS,
                crate::policy::TIGHTEST_INNER,
                crate::contact::uzawa::SETTLE
            );
            module += include("uzawa")?;
            module += include("contact_frame")?;
            // `first_judge`'s test of the law at the reactions a step starts from.
            module += include(<crate::contact::law::Law as crate::contact::law::ContactLaw>::INCLUDE)?;
        }
    }
    if is_contact_kernel(kernel) {
        // The CPU twin's bound, so that both sweeps stop a point's local steps alike.
        module += &format!("const LOCAL_STEPS = {}u;\n", crate::contact::uzawa::LOCAL_STEPS);
        module += include(<crate::contact::law::Law as crate::contact::law::ContactLaw>::INCLUDE)?;
        if kernel != "uzawa_step" {
            module += include("uzawa")?;
        }
        if matches!(kernel, "uzawa_sweep" | "uzawa_solve") {
            module += include("uzawa_visit")?;
        }
        if matches!(kernel, "uzawa_judge" | "uzawa_solve") {
            module += include("uzawa_nodal")?;
            module += include("contact_frame")?;
        }
    }
    match (is_element_kernel(kernel), variant) {
        (false, _) => {}
        (true, None) => return Err(format!("kernel `{kernel}` needs an element kind and a material")),
        (true, Some(v)) => {
            let (nen, dim) = (v.kind.nodes(), v.kind.dim());
            let nqp = crate::element::shape::quadrature(v.kind).len();
            let fbar = v.formulation == Formulation::Fbar;
            module += &format!("const NEN = {nen}u;\nconst NQP = {nqp}u;\nconst DIM = {dim}u;\nconst NDOF = {}u;\nconst FBAR = {fbar};\n", nen * dim);
            module += include(&format!("math_{}", precision.name()))?;
            module += include("tensor")?;
            module += include("element")?;
            module += include("fbar")?;
            let material = Model::entry(v.material).ok_or_else(|| format!("no material `{}`", v.material))?;
            if material.decoupled {
                module += include("decoupled")?;
            }
            module += material.wgsl;
            if kernel == "element_force_tangent" {
                module += include("viscous")?;
                module += &format!("const TANGENT_WORKGROUP = {}u;\n", tangent_workgroup(precision, workgroup_bytes));
            }
        }
    }
    unroll::unroll(&(module + text))
}

/// Parses and validates a kernel with naga, as the device would (no GPU needed), as composed
/// for an adapter with the least workgroup memory.
pub fn validate(kernel: &str, precision: Precision, variant: Option<ElementVariant>) -> Result<naga::Module, String> {
    validated(&source(kernel, precision, variant, LEAST_WORKGROUP_BYTES)?, precision).map(|(module, _)| module)
}

/// A module's text parsed and validated with naga at `precision`, with the types and uses
/// naga worked out for each expression.
pub fn validated(text: &str, precision: Precision) -> Result<(naga::Module, naga::valid::ModuleInfo), String> {
    let module = naga::front::wgsl::parse_str(text).map_err(|e| e.emit_to_string(text))?;
    let capabilities = match precision {
        Precision::F64 => naga::valid::Capabilities::FLOAT64,
        Precision::F32 => naga::valid::Capabilities::empty(),
    };
    let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities).validate(&module).map_err(|e| e.emit_to_string(text))?;
    Ok((module, info))
}
