// Strain energy of one element per invocation, `Σ_q dV W(E)` (E of F̄ for the F-bar element), for the active members of a batch
// (`batch.wgsl`). CPU twin: `element::element_energy`. Same inputs and prelude as
// `element_force_tangent`.

const WORKGROUP = 64u;

@group(0) @binding(0) var<storage, read> geometry: array<real>;
@group(0) @binding(1) var<storage, read> connectivity: array<u32>;
@group(0) @binding(2) var<storage, read> u: array<real>;
@group(0) @binding(3) var<storage, read_write> energy: array<real>;
@group(0) @binding(4) var<storage, read> members: array<MemberRange>;
@group(0) @binding(5) var<storage, read> materials: array<MaterialParams>;
@group(0) @binding(6) var<storage, read> jobs: array<Active>;

var<private> material: MaterialParams;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>) {
    let range = members[jobs[workgroup.z].member];
    let local = chunk_of(workgroup) * WORKGROUP + lane;
    if local >= range.elements {
        return;
    }
    let e = range.element_start + local;
    material = materials[range.material];
    let ue = element_displacements(e);
    var fq: array<Mat3, NQP>;
    for (var q = 0u; q < NQP; q++) {
        fq[q] = deformation_gradient((e * NQP + q) * POINT_STRIDE, ue);
    }
    var theta = real(1.0);
    if FBAR {
        theta = mean_dilatation(e, fq);
    }
    var w = real(0.0);
    for (var q = 0u; q < NQP; q++) {
        var f = fq[q];
        if FBAR {
            f = fbar_scale(f, fbar_alpha(theta, determinant(f)));
        }
        w += point_volume((e * NQP + q) * POINT_STRIDE) * material_energy(green_lagrange(f));
    }
    energy[e] = w;
}
