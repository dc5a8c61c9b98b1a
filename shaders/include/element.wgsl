// What the element kernels share: reading an element's nodal displacements and its reference
// geometry, and the deformation gradient. The kernels declare the bindings `geometry`,
// `connectivity` and `u` it reads; the prelude defines NEN and DIM.

// Per element: NQP points of [dN_a/dX (3 reals per node), dV].
const POINT_STRIDE = NEN * 3u + 1u;

// The displacements of element `e`'s nodes, padded to 3 components.
fn element_displacements(e: u32) -> array<vec3<real>, NEN> {
    var ue: array<vec3<real>, NEN>;
    for (var a = 0u; a < NEN; a++) {
        let n = connectivity[e * NEN + a];
        var d = vec3<real>(real(0.0));
        for (var i = 0u; i < DIM; i++) {
            d[i] = u[n * DIM + i];
        }
        ue[a] = d;
    }
    return ue;
}

// `dN_a/dX` at the quadrature point starting at `point`.
fn gradient(point: u32, a: u32) -> vec3<real> {
    return vec3<real>(geometry[point + a * 3u], geometry[point + a * 3u + 1u], geometry[point + a * 3u + 2u]);
}

// `dV` of the quadrature point starting at `point`.
fn point_volume(point: u32) -> real {
    return geometry[point + NEN * 3u];
}

// `F = I + Σ_a u_a ⊗ dN_a/dX`.
fn deformation_gradient(point: u32, ue: array<vec3<real>, NEN>) -> Mat3 {
    var f = identity3();
    for (var a = 0u; a < NEN; a++) {
        let g = gradient(point, a);
        // Column k of u_a ⊗ g is u_a g_k.
        f[0] += ue[a] * g.x;
        f[1] += ue[a] * g.y;
        f[2] += ue[a] * g.z;
    }
    return f;
}
