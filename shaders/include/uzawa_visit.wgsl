// A point's Gauss-Seidel visit, shared by `uzawa_sweep` and `uzawa_solve`, which declare the
// buffers it reads (`blocks`, `row_start`, `row_entries`, `locals`, `r`). Up to LOCAL_STEPS
// predictor/corrector steps against the others' reactions, `v = v_free + shift n + W r`, until
// a step moves the reaction by at most `settle max(|r|, floor)`. CPU twin:
// `contact::uzawa::gauss_seidel_point`, which this follows line by line.

const NO_BLOCK = 0xffffffffu;

fn reaction(i: u32) -> vec3<real> {
    return vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]);
}

// out + W_b x
fn add_block_times(out: vec3<real>, b: u32, x: vec3<real>) -> vec3<real> {
    let w = 9u * b;
    return vec3<real>(
        out.x + (blocks[w] * x.x + blocks[w + 1u] * x.y + blocks[w + 2u] * x.z),
        out.y + (blocks[w + 3u] * x.x + blocks[w + 4u] * x.y + blocks[w + 5u] * x.z),
        out.z + (blocks[w + 6u] * x.x + blocks[w + 7u] * x.y + blocks[w + 8u] * x.z),
    );
}

// Point i's reaction after its visit.
fn visit(i: u32) -> vec3<real> {
    let l = locals[i];
    // W r without the point's own block, whose product changes with every local step.
    var wr = vec3<real>(real(0.0));
    var own = NO_BLOCK;
    for (var e = row_start[i]; e < row_start[i + 1u]; e++) {
        let j = row_entries[e].x;
        let b = row_entries[e].y;
        if j == i {
            own = b;
            continue;
        }
        wr = add_block_times(wr, b, reaction(j));
    }
    let base = vec3<real>(l.v_free_n + wr.x + l.shift, l.v_free_t1 + wr.y, l.v_free_t2 + wr.z);
    var ri = reaction(i);
    for (var s = 0u; s < LOCAL_STEPS; s++) {
        var v = base;
        if own != NO_BLOCK {
            v = add_block_times(v, own, ri);
        }
        let stepped = uzawa_step(ri, v, l.mu, l.rho).r;
        let moved = norm(stepped - ri);
        ri = stepped;
        if moved <= l.settle * max(norm(ri), l.floor) {
            break;
        }
    }
    return ri;
}

// Visits point i: its reaction and the change over the visit into `r` and `dr`.
fn step_point(i: u32) {
    let before = reaction(i);
    let ri = visit(i);
    dr[3u * i] = ri.x - before.x;
    dr[3u * i + 1u] = ri.y - before.y;
    dr[3u * i + 2u] = ri.z - before.z;
    r[3u * i] = ri.x;
    r[3u * i + 1u] = ri.y;
    r[3u * i + 2u] = ri.z;
}
