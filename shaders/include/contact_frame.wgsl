// A point's contact frame to global coordinates, for the kernels that declare the points'
// frames `frames` ([n, t1, t2] row by row, 9 reals per point) at a binding of their own
// (`uzawa_judge`, `uzawa_solve`, `newton_contact`). CPU twin: `ContactPoint::to_global`.

// x (contact frame of point i) in global coordinates.
fn global(i: u32, x: vec3<real>) -> vec3<real> {
    let f = 9u * i;
    return vec3<real>(
        x.x * frames[f] + x.y * frames[f + 3u] + x.z * frames[f + 6u],
        x.x * frames[f + 1u] + x.y * frames[f + 4u] + x.z * frames[f + 7u],
        x.x * frames[f + 2u] + x.y * frames[f + 5u] + x.z * frames[f + 8u],
    );
}
