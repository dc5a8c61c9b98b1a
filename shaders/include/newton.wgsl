// A step's Newton iterations on the device for bodies that keep their factorisation
// (`newton_update`, `forces`, `assemble_residual`, `newton_judge`, `newton_compact`, and for
// groups in contact `newton_contact` and `uzawa_solve` around them, recorded several times in
// one submission). CPU side: `gpu::newton`; the test it repeats: `Body::converged`.

// What a member's iterations need, set by the host for the call.
struct NewtonMember {
    // Where its K̄⁻¹ (the lower triangle of free x free, row by row: `packed`) starts in
    // `inverse`.
    inverse_start: u32,
    // Where its free dofs (indices into the member's dofs, ascending) start in `free`.
    free_start: u32,
    free_count: u32,
    // The most Newton iterations of its step (`solver.max_iterations`): `NewtonState.iterations`
    // counts the step's, on from those it took before the call.
    budget: u32,
    // The residual's tolerance: residual_tolerance x force scale + floor + floor_per_travel x
    // the largest |u|.
    residual_tolerance: real,
    floor: real,
    floor_per_travel: real,
    // The increment's bound: increment_tolerance x max(|u - u_t|, increment_floor) + round_off x |u|.
    increment_tolerance: real,
    increment_floor: real,
    round_off: real,
}

// Where a member's iterations stand, written by the device.
struct NewtonState {
    status: u32,
    // Increments taken in this call.
    iterations: u32,
    // Whether an increment changed a displacement.
    moved: u32,
    // Whether the last evaluation's residual met its tolerance (`Body::balanced`).
    balanced: u32,
    // Times the member's K̄⁻¹ was made anew in this call (REFACTOR), and its displacement at the
    // last of them in `u_factored`: the host factorises there too.
    refactors: u32,
    pad: u32,
    // Residual norms of the last evaluation and of the one before, and the last increment's norm.
    residual: real,
    previous_residual: real,
    increment: real,
}

// `NewtonState.status`.
const ITERATING = 0u;
const CONVERGED = 1u;
// Not converged, and the device cannot go on: the factorisation contracts too slowly, the
// budget is spent, or the residual is not finite. The host takes over.
const HOST = 2u;
// The element kernel rejected the state (`failure`).
const FAILED = 3u;
// A member of a group in contact whose residual contracted less than tenfold: the device makes
// its K̄⁻¹ anew at this iterate (`newton_invert`'s `refactor`) and builds its group's W again
// (`newton_contact`'s `rebuild`), which sets it ITERATING again, all within the call.
const REFACTOR = 4u;

// The module's prelude sets MAX_FREE (the most free dofs a member may have: `newton_update`
// keeps the right-hand side in workgroup memory), NEWTON_WORKGROUP, REFACTOR_CONTRACTION
// (`Body::refresh_factor`'s rule), TALLY_ROW and TALLY_LEN (`newton_summary`'s rows and
// `newton_tally`'s sums) from the engine's constants.

// `dispatch`: the indirect arguments (x, y, z) of update, forces, residual and judge, then the
// length of the call's list, then how many of its first members keep their step's end on the
// device; `newton_compact` sets every z to the members still iterating.
const DISPATCHES = 4u;
const CALL_COUNT = 12u;
const KEPT_COUNT = 13u;

// Sums over a workgroup by halves, four at a time (the CPU twins add in the same order), and
// a largest value.
var<workgroup> partial4: array<vec4<real>, NEWTON_WORKGROUP>;
var<workgroup> partial: array<real, NEWTON_WORKGROUP>;

fn reduce_sum4(lane: u32, value: vec4<real>) -> vec4<real> {
    partial4[lane] = value;
    workgroupBarrier();
    for (var half = NEWTON_WORKGROUP / 2u; half > 0u; half /= 2u) {
        if lane < half {
            partial4[lane] += partial4[lane + half];
        }
        workgroupBarrier();
    }
    let sum = partial4[0];
    workgroupBarrier();
    return sum;
}

fn reduce_max(lane: u32, value: real) -> real {
    partial[lane] = value;
    workgroupBarrier();
    for (var half = NEWTON_WORKGROUP / 2u; half > 0u; half /= 2u) {
        if lane < half {
            partial[lane] = max(partial[lane], partial[lane + half]);
        }
        workgroupBarrier();
    }
    let most = partial[0];
    workgroupBarrier();
    return most;
}

// Where entry (i, j) of a symmetric matrix lies in its lower triangle stored row by row: half
// the entries of the full matrix, read the same (K̄⁻¹ is symmetric).
fn packed(i: u32, j: u32) -> u32 {
    let a = max(i, j);
    return a * (a + 1u) / 2u + min(i, j);
}
