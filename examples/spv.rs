use bifirst::gpu::shaders::{source, ElementVariant};
use bifirst::precision::Precision;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let precision = if args[1] == "f64" { Precision::F64 } else { Precision::F32 };
    let kind = bifirst::mesh::ElementKind::Tri3;
    let variant = ElementVariant { kind, formulation: bifirst::element::Formulation::Displacement, material: "blatz_ko" };
    let text = source("element_force_tangent", precision, Some(variant), 49152).unwrap();
    let (module, info) = bifirst::gpu::shaders::validated(&text, precision).unwrap();
    let mut options = naga::back::spv::Options::default();
    options.flags = naga::back::spv::WriterFlags::empty();
    let pipeline = naga::back::spv::PipelineOptions { shader_stage: naga::ShaderStage::Compute, entry_point: args[2].clone() };
    let words = naga::back::spv::write_vec(&module, &info, &options, Some(&pipeline)).unwrap();
    std::fs::write(&args[3], bytemuck::cast_slice::<u32, u8>(&words)).unwrap();
    // Capabilities (17), extensions (10), execution modes (16), ext inst imports (11)
    let mut i = 5;
    let mut counts = std::collections::BTreeMap::new();
    while i < words.len() {
        let op = words[i] & 0xffff; let n = (words[i] >> 16) as usize;
        match op {
            17 => println!("OpCapability {}", words[i+1]),
            10 | 11 => println!("op {op} {:?}", String::from_utf8_lossy(bytemuck::cast_slice::<u32,u8>(&words[i+if op==11 {2} else {1}..i+n]))),
            16 => println!("OpExecutionMode {:?}", &words[i+1..i+n]),
            _ => { *counts.entry(op).or_insert(0) += 1; }
        }
        i += n.max(1);
    }
    println!("{:?}", counts);
}
