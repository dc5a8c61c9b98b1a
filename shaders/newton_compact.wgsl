// The members of a device Newton call still ITERATING, in the call's order, into the list the
// next iteration's kernels run over (`jobs`), and their count into every indirect dispatch's z,
// so that converged members cost nothing more. One workgroup: each invocation takes a
// contiguous share of the call's list; the shares' counts are summed in order by invocation 0.
// When the last compaction left no member (no status goes back to ITERATING), the list and the
// counts stay as they are: the empty iterations recorded after a call's members converged
// then cost no scan of the call's list. CPU twin: `cpu::newton_compact`.
//
// `host`: the members of a list (the members of groups in contact, in mode TANGENT) that the
// device hands back to the host (HOST), into the list of the tangent and `assemble_csr`
// passes that follow, their count into the z of those dispatches: the host then renews their
// factorisations without a tangent pass of its own. CPU twin: `cpu::newton_compact_host`.
//
// `refactor`: the members of that list that refactorise within the call (REFACTOR), into the
// same list, for the tangent, `assemble_csr` and `newton_invert`'s `refactor` that follow.
// CPU twin: `cpu::newton_compact_refactor`.

@group(0) @binding(0) var<storage, read> call: array<Active>;
@group(0) @binding(1) var<storage, read> state: array<NewtonState>;
@group(0) @binding(2) var<storage, read_write> jobs: array<Active>;
@group(0) @binding(3) var<storage, read_write> dispatch: array<u32>;

var<workgroup> counts: array<u32, NEWTON_WORKGROUP>;
var<workgroup> left: u32;

@compute @workgroup_size(NEWTON_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32) {
    if lane == 0u {
        left = dispatch[2];
    }
    if workgroupUniformLoad(&left) == 0u {
        return;
    }
    compact(lane, ITERATING);
}

@compute @workgroup_size(NEWTON_WORKGROUP)
fn host(@builtin(local_invocation_index) lane: u32) {
    compact(lane, HOST);
}

@compute @workgroup_size(NEWTON_WORKGROUP)
fn refactor(@builtin(local_invocation_index) lane: u32) {
    compact(lane, REFACTOR);
}

// The members of `call` whose status is `wanted`, in order, into `jobs`; their count into
// every dispatch's z.
fn compact(lane: u32, wanted: u32) {
    let total = dispatch[CALL_COUNT];
    let share = (total + NEWTON_WORKGROUP - 1u) / NEWTON_WORKGROUP;
    let first = min(lane * share, total);
    let end = min(first + share, total);
    var mine = 0u;
    for (var i = first; i < end; i++) {
        mine += u32(state[call[i].member].status == wanted);
    }
    counts[lane] = mine;
    workgroupBarrier();
    if lane == 0u {
        var sum = 0u;
        for (var k = 0u; k < NEWTON_WORKGROUP; k++) {
            let c = counts[k];
            counts[k] = sum;
            sum += c;
        }
        for (var k = 0u; k < DISPATCHES; k++) {
            dispatch[3u * k + 2u] = sum;
        }
    }
    workgroupBarrier();
    var at = counts[lane];
    for (var i = first; i < end; i++) {
        if state[call[i].member].status == wanted {
            jobs[at] = call[i];
            at++;
        }
    }
}
