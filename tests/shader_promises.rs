//! What the kernels promise so that wgpu may compile them without its runtime checks
//! (`gpu::context::SHADER_CHECKS`): every loop counts up to a bound (or is listed with why it
//! ends), and every integer division or remainder is by a non-zero constant. No GPU needed.

use bifirst::gpu::shaders::{is_element_kernel, material_includes, source, tangent_workgroup, validated, ElementVariant, INCLUDES, LEAST_WORKGROUP_BYTES, SHADERS};
use bifirst::precision::Precision;

/// The source with its `//` comments blanked out.
fn code(text: &str) -> String {
    text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// Why a loop header `init; condition; update` may run forever, if it may: the condition must
/// start with `x < bound` (then the update `x++` or `x += STEP`) or `x > 0u` (then `x /= 2u`).
fn unbounded(header: &str) -> Option<String> {
    let parts: Vec<&str> = header.split(';').map(str::trim).collect();
    let [_, condition, update] = parts[..] else { return Some(format!("`for ({header})` has no three parts")) };
    let first = condition.split("&&").next().unwrap_or("").trim();
    let words: Vec<&str> = first.split_whitespace().collect();
    let counts = match words[..] {
        [x, "<", _, ..] => update == format!("{x}++") || update.strip_prefix(&format!("{x} += ")).is_some_and(|step| step.chars().all(|c| c.is_ascii_uppercase() || c == '_') || step.trim_end_matches('u').parse::<u32>().is_ok_and(|s| s > 0)),
        [x, ">", "0u"] => update == format!("{x} /= 2u"),
        _ => false,
    };
    (!counts).then(|| format!("`for ({header})` does not count up to a bound"))
}

/// The `while` loops that are not counted, each with why it ends.
const WHILE_LOOPS: [(&str, &str, &str); 1] = [("element_force_tangent", "while pair >= NEN - a {", "pair < PAIRS falls by NEN - a >= 1 each pass")];

fn loop_faults(name: &str, text: &str) -> Vec<String> {
    let mut text = code(text);
    for (kernel, header, _) in WHILE_LOOPS {
        if kernel == name {
            text = text.replacen(header, "{", 1);
        }
    }
    let mut faults = Vec::new();
    for word in ["while", "loop"] {
        let found = text.split(|c: char| !(c.is_alphanumeric() || c == '_')).any(|w| w == word);
        if found {
            faults.push(format!("{name}: `{word}` (write a counted `for`, or list it in WHILE_LOOPS with why it ends)"));
        }
    }
    for (at, _) in text.match_indices("for (") {
        let rest = &text[at + 5..];
        let mut depth = 1;
        let end = rest.char_indices().find(|&(_, c)| {
            depth += match c {
                '(' => 1,
                ')' => -1,
                _ => 0,
            };
            depth == 0
        });
        match end {
            Some((end, _)) => faults.extend(unbounded(&rest[..end]).map(|f| format!("{name}: {f}"))),
            None => faults.push(format!("{name}: an unclosed `for (`")),
        }
    }
    faults
}

#[test]
fn every_loop_counts_up_to_a_bound() {
    let materials: Vec<(String, &str)> = material_includes().collect();
    let sources = SHADERS.iter().chain(INCLUDES).map(|&(name, text)| (name, text)).chain(materials.iter().map(|(name, text)| (name.as_str(), *text)));
    let faults: Vec<String> = sources.flat_map(|(name, text)| loop_faults(name, text)).collect();
    assert!(faults.is_empty(), "{}", faults.join("\n"));
}

#[test]
fn the_loop_check_rejects_loops_without_a_bound() {
    assert!(loop_faults("ok", "for (var i = 0u; i < n; i++) {}\nfor (var h = W / 2u; h > 0u; h /= 2u) {}\nfor (; a < NEN && p >= NEN - a; a++) {}\nfor (var j = lane; j < n; j += WORKGROUP) {}").is_empty());
    // `// while` in a comment is not code; a listed `while` is allowed in its kernel only.
    assert!(loop_faults("comment", "// while the loop runs").is_empty());
    assert!(loop_faults("element_force_tangent", "while pair >= NEN - a { pair -= NEN - a; a++; }").is_empty());
    assert_eq!(loop_faults("element_energy", "while pair >= NEN - a { pair -= NEN - a; a++; }").len(), 1);
    for bad in ["loop { break; }", "while x > 0.0 { x -= 1.0; }", "for (var i = 0u; i < n; i--) {}", "for (var i = 0u; x < n; i++) {}", "for (var i = 0u; i != n; i++) {}", "for (var i = 0u; i < n; i += 0u) {}"] {
        assert_eq!(loop_faults("bad", bad).len(), 1, "{bad}");
    }
}

/// The integer divisions and remainders of a module whose divisor is not a non-zero constant.
fn unchecked_divisions(text: &str, precision: Precision) -> Vec<String> {
    let (module, info) = validated(text, precision).expect("the kernel validates");
    let non_zero = |e: &naga::Expression| match e {
        naga::Expression::Literal(l) => !matches!(l, naga::Literal::U32(0) | naga::Literal::I32(0)),
        _ => false,
    };
    let functions = module.functions.iter().map(|(h, f)| (f, &info[h])).chain(module.entry_points.iter().enumerate().map(|(i, e)| (&e.function, info.get_entry_point(i))));
    let mut faults = Vec::new();
    for (function, function_info) in functions {
        for (handle, expression) in function.expressions.iter() {
            let naga::Expression::Binary { op: naga::BinaryOperator::Divide | naga::BinaryOperator::Modulo, left, right } = *expression else { continue };
            let integer = function_info[left].ty.inner_with(&module.types).scalar_kind().is_some_and(|k| matches!(k, naga::ScalarKind::Sint | naga::ScalarKind::Uint));
            let divisor = match &function.expressions[right] {
                naga::Expression::Constant(c) => &module.global_expressions[module.constants[*c].init],
                e => e,
            };
            if integer && !non_zero(divisor) {
                faults.push(format!("{}: {handle:?} divides by {divisor:?}", function.name.as_deref().unwrap_or("?")));
            }
        }
    }
    faults
}

#[test]
fn every_integer_division_is_by_a_non_zero_constant() {
    for (name, _) in SHADERS {
        let variants: Vec<Option<ElementVariant>> = if is_element_kernel(name) { ElementVariant::all().into_iter().map(Some).collect() } else { vec![None] };
        for precision in [Precision::F32, Precision::F64] {
            for variant in &variants {
                let faults = unchecked_divisions(&source(name, precision, *variant, LEAST_WORKGROUP_BYTES).unwrap(), precision);
                assert!(faults.is_empty(), "{name} {variant:?} ({}):\n{}", precision.name(), faults.join("\n"));
            }
        }
    }
}

#[test]
fn the_division_check_rejects_a_divisor_that_may_be_zero() {
    let kernel = |body: &str| format!("@group(0) @binding(0) var<storage, read_write> v: array<u32>;\nconst TWO = 2u;\n@compute @workgroup_size(1) fn main() {{ {body} }}");
    let faults = |body: &str| unchecked_divisions(&kernel(body), Precision::F32);
    assert!(faults("v[0] = v[1] / 2u + v[2] % TWO; v[3] = u32(f32(v[4]) / f32(v[5]));").is_empty());
    assert_eq!(faults("v[0] = v[1] / v[2];").len(), 1);
    assert_eq!(faults("var x = 7u; x %= v[2]; v[0] = x;").len(), 1);
}

#[test]
fn the_tangent_workgroup_fits_the_workgroup_memory_it_is_sized_for() {
    let variant = ElementVariant::all().into_iter().find(|v| v.kind == bifirst::mesh::ElementKind::Hex8).unwrap();
    let mut sizes = Vec::new();
    for precision in [Precision::F32, Precision::F64] {
        for bytes in [LEAST_WORKGROUP_BYTES, 32768, 49152] {
            let module = naga::front::wgsl::parse_str(&source("element_force_tangent", precision, Some(variant), bytes).unwrap()).unwrap();
            let used: u32 = module.global_variables.iter().filter(|(_, g)| g.space == naga::AddressSpace::WorkGroup).map(|(_, g)| module.types[g.ty].inner.size(module.to_ctx())).sum();
            assert!(used <= bytes, "{} at {bytes} bytes uses {used}", precision.name());
            sizes.push(tangent_workgroup(precision, bytes));
        }
    }
    // f32 takes 64 points everywhere; f64 32 in the least memory and 64 in an H100's 48 KiB.
    assert_eq!(sizes, [64, 64, 64, 32, 64, 64]);
}
