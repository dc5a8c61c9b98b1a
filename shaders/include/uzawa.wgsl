// What the Uzawa kernels `uzawa_sweep`, `uzawa_judge` and `uzawa_solve` share: a point's data,
// a problem of a solve and where its iterations stand, and the stopping rule
// (`contact::uzawa::Judge::after`). CPU side: `gpu::uzawa_sweep`.

struct UzawaLocal {
    // Free velocity in the contact frame [n, t1, t2].
    v_free_n: real,
    v_free_t1: real,
    v_free_t2: real,
    // Added to the normal velocity (gap and drift correction).
    shift: real,
    mu: real,
    rho: real,
    // The settling test of the local steps: |step| <= settle max(|r|, floor).
    floor: real,
    settle: real,
}

struct UzawaProblem {
    // Its points: point_start .. point_end; its nodes: node_start .. node_end.
    point_start: u32,
    point_end: u32,
    node_start: u32,
    node_end: u32,
    max_iterations: u32,
    // For `uzawa_solve`: its colours are colour_start[colour_first .. colour_first + colours + 1].
    colour_first: u32,
    colours: u32,
    pad: u32,
    tolerance: real,
    floor: real,
}

struct UzawaJudgeState {
    status: u32,
    // Sweeps judged so far.
    iterations: u32,
    pad0: u32,
    pad1: u32,
    // The last sweep's largest change of a nodal force (negative before the first sweep).
    previous: real,
    // That change over the scale max(largest nodal force, floor) (`Outcome::change`).
    change: real,
}

// The problem count (the buffers may hold more), and the sweeps one dispatch of `uzawa_solve`
// may take.
struct SolveCount {
    problems: u32,
    sweeps: u32,
    pad0: u32,
    pad1: u32,
}

// `UzawaJudgeState.status`.
const UZAWA_LIVE = 0u;
const UZAWA_CONVERGED = 1u;
// max_iterations sweeps without converging.
const UZAWA_SPENT = 2u;

const UZAWA_WORKGROUP = 64u;

// Problem k of a dispatch of one workgroup per problem, in rows of at most 65535 workgroups:
// it sits at (k mod row, k / row).
fn problem_index(workgroup: vec3<u32>, count: vec3<u32>) -> u32 {
    return workgroup.x + workgroup.y * count.x;
}

fn norm(x: vec3<real>) -> real {
    return sqrt(x.x * x.x + x.y * x.y + x.z * x.z);
}

// Problem p's state after a sweep whose largest change of a nodal force is `change` and largest
// nodal force `size`: the distance to the fixed point estimated from the contraction of the
// last two changes, against the tolerance.
fn judged(p: UzawaProblem, state: UzawaJudgeState, change: real, size: real) -> UzawaJudgeState {
    var s = state;
    s.iterations += 1u;
    let scale = max(max(size, p.floor), REAL_MIN_POSITIVE);
    // Before the first sweep the ratio is 0, as the CPU's change over an infinite one.
    var q = real(0.0);
    if s.previous >= real(0.0) {
        q = change / s.previous;
    }
    s.previous = change;
    var error = REAL_MAX;
    if q < real(1.0) {
        error = change * q / (real(1.0) - q);
    }
    // Far below the tolerance the ratio is round-off; a change that small is converged.
    let converged = change <= real(1e-3) * p.tolerance * scale || (change <= p.tolerance * scale && error <= p.tolerance * scale);
    s.change = change / scale;
    if converged {
        s.status = UZAWA_CONVERGED;
    } else if s.iterations >= p.max_iterations {
        s.status = UZAWA_SPENT;
    }
    return s;
}
