// Strain energy of one element per invocation, `Σ_q dV W(E)`. CPU twin: `element::element_energy`.
// Same inputs and prelude as `element_force_tangent`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> material: MaterialParams;
@group(0) @binding(1) var<storage, read> geometry: array<real>;
@group(0) @binding(2) var<storage, read> connectivity: array<u32>;
@group(0) @binding(3) var<storage, read> u: array<real>;
@group(0) @binding(4) var<storage, read_write> energy: array<real>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let e = id.x + id.y * groups.x * WORKGROUP;
    if e >= arrayLength(&energy) {
        return;
    }
    let ue = element_displacements(e);
    var w = real(0.0);
    for (var q = 0u; q < NQP; q++) {
        let point = (e * NQP + q) * POINT_STRIDE;
        w += point_volume(point) * material_energy(green_lagrange(deformation_gradient(point, ue)));
    }
    energy[e] = w;
}
