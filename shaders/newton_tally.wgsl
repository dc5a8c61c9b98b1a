// The sums the host books at the end of a step over the members of a device Newton call that
// keep their step's end on the device (the first KEPT_COUNT of the call's list) and converged,
// from their `newton_summary` rows, so that a step in which nothing needs the host reads no
// energy term member by member. TALLY_LEN reals into `tally`:
//   [the members, Σ m (v - v_t)², Σ force dissipation, Σ strain energy, max |v|², max residual]
// One workgroup: invocation `lane` takes the members lane, lane + NEWTON_WORKGROUP, ...; the
// lanes' sums are added by halves (`reduce_sum4`). CPU twin: `cpu::newton_tally`.

@group(0) @binding(0) var<storage, read> call: array<Active>;
@group(0) @binding(1) var<storage, read> dispatch: array<u32>;
@group(0) @binding(2) var<storage, read> state: array<NewtonState>;
@group(0) @binding(3) var<storage, read> rows: array<real>;
@group(0) @binding(4) var<storage, read_write> tally: array<real>;

@compute @workgroup_size(NEWTON_WORKGROUP)
fn main(@builtin(local_invocation_index) lane: u32) {
    let kept = dispatch[KEPT_COUNT];
    var sums = vec4<real>(real(0.0));
    var speed2 = real(0.0);
    var residual = real(0.0);
    for (var k = lane; k < kept; k += NEWTON_WORKGROUP) {
        let m = call[k].member;
        if state[m].status == CONVERGED {
            let row = m * TALLY_ROW;
            sums += vec4<real>(real(1.0), rows[row + 2u], rows[row + 3u], rows[row + 1u]);
            speed2 = max(speed2, rows[row + 4u]);
            residual = max(residual, rows[row]);
        }
    }
    let total = reduce_sum4(lane, sums);
    let fastest = reduce_max(lane, speed2);
    let worst = reduce_max(lane, residual);
    if lane == 0u {
        tally[0] = total.x;
        tally[1] = total.y;
        tally[2] = total.z;
        tally[3] = total.w;
        tally[4] = fastest;
        tally[5] = worst;
    }
}
