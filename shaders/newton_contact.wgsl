// The contact of the groups that take their Newton iterations on the device, around the bodies'
// own kernels: per iteration `prepare` (the contact-free increment and the free velocities),
// `uzawa_solve` (the reactions), `forces` (the contact forces `Hᵀ r` and how much they changed),
// then `newton_update` with those forces, the evaluation, `newton_judge`, and `judge`, which
// holds a group's members to one verdict. A group that comes to the call unevaluated (the first
// round of a step) is evaluated first, with `first_forces` before `newton_judge` and
// `first_judge` after it. One workgroup per group (each group has one contact
// problem, numbered as `uzawa_solve` numbers them); a group no longer iterating does nothing.
// The Delassus blocks are built here (`delassus`, once at the call's start) from the members'
// K̄⁻¹ as the device holds them, not sent up, and again (`rebuild`) for a group whose members
// refactorised within the call.
// The host's increment this repeats: `ContactStep::prepare` and `ContactStep::apply`; its test:
// `Group::converged`. CPU twins: `cpu::newton_contact_prepare`, `cpu::newton_contact_forces`,
// `cpu::newton_contact_judge`, `cpu::newton_contact_first_forces`,
// `cpu::newton_contact_first_judge`, `cpu::newton_contact_delassus`,
// `cpu::newton_contact_rebuild`, which follow this file line by line.

// A group: its members (batch member indices, the first its leader) and what its test needs.
struct ContactGroup {
    member_start: u32,
    member_count: u32,
    // 1: the points' step lengths are the Jacobi sweep's (`Delassus::rho`).
    jacobi: u32,
    // 1: a member whose residual contracts too slowly refactorises within the call (REFACTOR)
    // rather than handing the group back.
    refactor: u32,
    // contact.tolerance: the contact forces' change must be below it.
    tolerance: real,
    // A velocity that matters in the step (`ContactStep::velocity_scale`): the floor of the
    // reactions is the largest step length times it.
    velocity_scale: real,
}

// Where a group's contact stands after its last increment, written by `forces` (and
// `tightened` by `judge`).
struct ContactState {
    // Uzawa sweeps in this call, and the status of the last solve (`UzawaJudgeState.status`).
    sweeps: u32,
    uzawa: u32,
    // Times `judge` solved the group's problem tighter (`ContactStep::tighten`).
    tightened: u32,
    // Increments in a row whose solve did not converge, counted on from the host's
    // (`NewtonState::uzawa_stalls`).
    stalls: u32,
    // The change of the contact forces over the last increment, over their scale
    // max(largest contact force, floor) (`ContactStep::apply`).
    change: real,
}

struct ContactCall {
    problems: u32,
    dim: u32,
    pad0: u32,
    pad1: u32,
    theta_dt: real,
}

@group(0) @binding(0) var<storage, read> inverse: array<real>;
@group(0) @binding(1) var<storage, read> free_dofs: array<u32>;
@group(0) @binding(2) var<storage, read> newton: array<NewtonMember>;
@group(0) @binding(3) var<storage, read_write> state: array<NewtonState>;
@group(0) @binding(4) var<storage, read> dof_out: array<DofOut>;
@group(0) @binding(5) var<storage, read> u: array<real>;
@group(0) @binding(6) var<storage, read> members: array<MemberRange>;
// Per dof: the contact-free increment K̄⁻¹(-g) (zero off the free dofs), u_t + dt (1 - θ) v_t
// (the trial velocity is (u - u_base) / θdt), the contact forces.
@group(0) @binding(7) var<storage, read_write> x0: array<real>;
@group(0) @binding(8) var<storage, read> u_base: array<real>;
@group(0) @binding(9) var<storage, read_write> contact: array<real>;
@group(0) @binding(10) var<storage, read> groups: array<ContactGroup>;
@group(0) @binding(11) var<storage, read> group_members: array<u32>;
@group(0) @binding(12) var<storage, read_write> locals: array<UzawaLocal>;
@group(0) @binding(13) var<storage, read_write> uzawa_states: array<UzawaJudgeState>;
@group(0) @binding(14) var<storage, read_write> problems: array<UzawaProblem>;
// Point i's terms: (node slot, coefficient) for e in term_start[i] .. term_start[i + 1].
@group(0) @binding(15) var<storage, read> term_start: array<u32>;
@group(0) @binding(16) var<storage, read> term_slots: array<u32>;
@group(0) @binding(17) var<storage, read> term_coefs: array<real>;
// Point i's obstacle velocity at the end of the step (global), and its frame [n, t1, t2] row by
// row.
@group(0) @binding(18) var<storage, read> obstacle: array<real>;
@group(0) @binding(19) var<storage, read> frames: array<real>;
// Node slot n: the batch dof of its first component, and the points acting on it (ascending)
// with their coefficients.
@group(0) @binding(20) var<storage, read> node_dof: array<u32>;
@group(0) @binding(21) var<storage, read> node_start: array<u32>;
@group(0) @binding(22) var<storage, read> node_points: array<u32>;
@group(0) @binding(23) var<storage, read> node_coefs: array<real>;
@group(0) @binding(24) var<storage, read> r: array<real>;
@group(0) @binding(25) var<storage, read_write> contact_states: array<ContactState>;
@group(0) @binding(26) var<uniform> call: ContactCall;
// The staged problems' W: 3 x 3 blocks row-major in contact frames, and per point (row) its
// entries (column point, block), all points of the call numbered one after the other.
@group(0) @binding(27) var<storage, read_write> blocks: array<real>;
@group(0) @binding(28) var<storage, read> row_start: array<u32>;
@group(0) @binding(29) var<storage, read> row_entries: array<vec2<u32>>;
// Node slot n: the batch member of its body.
@group(0) @binding(30) var<storage, read> node_member: array<u32>;
// Per point, the step length `delassus` gave it, for the host.
@group(0) @binding(31) var<storage, read_write> step_lengths: array<real>;
// Per batch dof: its free index in its member's K̄⁻¹, NOT_FREE for a prescribed one.
@group(0) @binding(32) var<storage, read> free_of: array<u32>;
const NOT_FREE: u32 = 0xffffffffu;

var<workgroup> go: u32;
var<workgroup> rhs: array<real, MAX_FREE>;

// Point i's relative velocity at the end of the step, in its contact frame: its terms' trial
// velocities (u - u_base) / θdt, with the contact-free increments x0 / θdt where `free` (the
// free velocity of an increment), less the obstacle's.
fn point_velocity(i: u32, free: bool) -> vec3<real> {
    let tdt = call.theta_dt;
    var g = -vec3<real>(obstacle[3u * i], obstacle[3u * i + 1u], obstacle[3u * i + 2u]);
    for (var e = term_start[i]; e < term_start[i + 1u]; e++) {
        let d0 = node_dof[term_slots[e]];
        let coef = term_coefs[e];
        for (var c = 0u; c < call.dim; c++) {
            let d = d0 + c;
            var v = (u[d] - u_base[d]) / tdt;
            if free {
                v += x0[d] / tdt;
            }
            g[c] += coef * v;
        }
    }
    let f = 9u * i;
    return vec3<real>(
        frames[f] * g.x + frames[f + 1u] * g.y + frames[f + 2u] * g.z,
        frames[f + 3u] * g.x + frames[f + 4u] * g.y + frames[f + 5u] * g.z,
        frames[f + 6u] * g.x + frames[f + 7u] * g.y + frames[f + 8u] * g.z,
    );
}

// The contact force on node slot n: its points' reactions in global coordinates, each times its
// coefficient, in point order.
fn node_force(n: u32) -> vec3<real> {
    var f = vec3<real>(real(0.0));
    for (var e = node_start[n]; e < node_start[n + 1u]; e++) {
        let i = node_points[e];
        f += node_coefs[e] * global(i, vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]));
    }
    return f;
}

// Whether group k (of the rows of workgroups) exists; the same for every invocation of the
// workgroup.
fn exists(lane: u32, k: u32) -> bool {
    if lane == 0u {
        go = u32(k < call.problems);
    }
    return workgroupUniformLoad(&go) == 1u;
}

// Whether group k (of the rows of workgroups) exists and is still iterating; the same for every
// invocation of the workgroup.
fn iterating(lane: u32, k: u32) -> bool {
    if lane == 0u {
        go = u32(k < call.problems && state[group_members[groups[k].member_start]].status == ITERATING);
    }
    return workgroupUniformLoad(&go) == 1u;
}

// The contact-free increment x0 = K̄⁻¹(-g) of every member, then each point's free velocity
// (the trial velocity plus x0 / θdt, in the contact frame) and the settling bound of its local
// steps into the Uzawa points, and the problem live again from its first sweep.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn prepare(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if !iterating(lane, k) {
        return;
    }
    let grp = groups[k];
    for (var a = 0u; a < grp.member_count; a++) {
        let m = group_members[grp.member_start + a];
        let row = newton[m];
        let n = row.free_count;
        let dof_start = members[m].dof_start;
        for (var j = lane; j < n; j += NEWTON_WORKGROUP) {
            rhs[j] = -dof_out[dof_start + free_dofs[row.free_start + j]].g;
        }
        workgroupBarrier();
        for (var f = lane; f < n; f += NEWTON_WORKGROUP) {
            var x = real(0.0);
            for (var j = 0u; j < n; j++) {
                x += inverse[row.inverse_start + packed(j, f)] * rhs[j];
            }
            x0[dof_start + free_dofs[row.free_start + f]] = x;
        }
        workgroupBarrier();
    }
    // The points read the increments of every lane.
    storageBarrier();
    let p = problems[k];
    for (var i = p.point_start + lane; i < p.point_end; i += NEWTON_WORKGROUP) {
        let v = point_velocity(i, true);
        locals[i].v_free_n = v.x;
        locals[i].v_free_t1 = v.y;
        locals[i].v_free_t2 = v.z;
        locals[i].settle = SETTLE * p.tolerance;
    }
    if lane == 0u {
        var s = UzawaJudgeState();
        s.status = UZAWA_LIVE;
        s.previous = real(-1.0);
        uzawa_states[k] = s;
    }
}

// The solved reactions as the members' contact forces, each node's sum in point order, and the
// largest change of a contact force over the largest one (or the floor); the solve's sweeps and
// outcome into the group's contact state.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn forces(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if !iterating(lane, k) {
        return;
    }
    let p = problems[k];
    var change = real(0.0);
    var size = real(0.0);
    for (var n = p.node_start + lane; n < p.node_end; n += NEWTON_WORKGROUP) {
        let f = node_force(n);
        let d0 = node_dof[n];
        for (var c = 0u; c < call.dim; c++) {
            let before = contact[d0 + c];
            change = max(change, abs(f[c] - before));
            size = max(size, abs(f[c]));
            contact[d0 + c] = f[c];
        }
    }
    change = reduce_max(lane, change);
    size = reduce_max(lane, size);
    if lane == 0u {
        var s = contact_states[k];
        let solved = uzawa_states[k];
        s.sweeps += solved.iterations;
        s.uzawa = solved.status;
        s.stalls = select(s.stalls + 1u, 0u, solved.status == UZAWA_CONVERGED);
        s.change = change / max(max(size, p.floor), REAL_MIN_POSITIVE);
        contact_states[k] = s;
    }
}

// After `newton_judge`: the group's verdict for all its members, as `Group::converged` gives
// it. Converged when every member passed its own test and the contact forces settled with a
// converged solve; the host takes the group (every member HOST) when a member needs it or
// failed, a solve was cut short (still live: a software adapter's dispatches), UZAWA_STALLS
// solves in a row spent their sweeps (the host then gives the step up), or the budget is
// spent; else every member iterates on (after a solve that spent its sweeps too, as the host's
// Newton loop goes on), and when only the increments are left after TIGHTEN_AFTER iterations
// the problem is solved ten times tighter from then on (down to TIGHTEST_INNER of the contact
// tolerance). A member whose residual contracted less than tenfold (one that passed its own
// test too) is refactorised, as `Body::refresh_factor` does: within the call (REFACTOR) where
// the group may (`refactor`; newton_judge's HOST for it alone then does not count), else by
// the host, which takes the group. A group that stopped earlier keeps its verdict. One
// invocation per group.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn judge(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = id.x + id.y * count.x * NEWTON_WORKGROUP;
    if k >= call.problems {
        return;
    }
    let grp = groups[k];
    let lead = group_members[grp.member_start];
    var all_converged = true;
    var all_balanced = true;
    var to_host = false;
    var slow = false;
    for (var a = 0u; a < grp.member_count; a++) {
        let s = state[group_members[grp.member_start + a]];
        all_converged = all_converged && s.status == CONVERGED;
        all_balanced = all_balanced && s.balanced == 1u;
        // (newton_judge hands a member to the host for a residual that is not finite, a spent
        // budget, tested below, or a slow contraction)
        let lost = s.status == HOST && (grp.refactor == 0u || !is_finite(s.residual));
        to_host = to_host || lost || s.status == FAILED;
        slow = slow || contracts_slowly(s);
    }
    let c = contact_states[k];
    let settled = c.change <= grp.tolerance && c.uzawa == UZAWA_CONVERGED;
    let iterations = state[lead].iterations;
    var verdict = ITERATING;
    if to_host {
        verdict = HOST;
    } else if all_converged && settled {
        verdict = CONVERGED;
    } else if c.uzawa == UZAWA_LIVE || c.stalls >= UZAWA_STALLS || iterations >= newton[lead].budget || (slow && grp.refactor == 0u) {
        verdict = HOST;
    } else if iterations >= TIGHTEN_AFTER && settled && all_balanced {
        problems[k].tolerance = max(real(0.1) * problems[k].tolerance, real(TIGHTEST_INNER) * grp.tolerance);
        contact_states[k].tightened += 1u;
    }
    for (var a = 0u; a < grp.member_count; a++) {
        let m = group_members[grp.member_start + a];
        let s = state[m];
        if s.status != FAILED {
            state[m].status = select(verdict, REFACTOR, verdict == ITERATING && contracts_slowly(s));
        }
    }
}

// Whether a member's last evaluation contracted its residual less than tenfold
// (`Body::refresh_factor`'s rule).
fn contracts_slowly(s: NewtonState) -> bool {
    return s.residual > real(REFACTOR_CONTRACTION) * max(s.previous_residual, REAL_MIN_POSITIVE);
}

// A group's first evaluation of a step, before `newton_judge`: the contact forces of the
// reactions the step starts from (last step's, where a point had one), each node's sum in
// point order, as `ContactStep::apply_forces` gives them to the host's test.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn first_forces(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if !iterating(lane, k) {
        return;
    }
    let p = problems[k];
    for (var n = p.node_start + lane; n < p.node_end; n += NEWTON_WORKGROUP) {
        let f = node_force(n);
        let d0 = node_dof[n];
        for (var c = 0u; c < call.dim; c++) {
            contact[d0 + c] = f[c];
        }
    }
}

// After `newton_judge` of a first evaluation: the group's verdict as `Group::converged` gives
// it before any Uzawa sweep of the step. Converged when every member passed its own test, every
// point had a reaction to start from (rho > 0) and the law holds at the trial velocities
// (`ContactStep::complementarity`: one Uzawa step from the reactions changes the nodal forces
// by at most the contact tolerance of their size); the host takes the group when a member needs
// it or failed; else every member iterates. Each point's step goes into its free velocity,
// which `prepare` sets anew before a solve reads it.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn first_judge(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if !exists(lane, k) {
        return;
    }
    let p = problems[k];
    var cold = 0u;
    for (var i = p.point_start + lane; i < p.point_end; i += NEWTON_WORKGROUP) {
        let l = locals[i];
        let ri = vec3<real>(r[3u * i], r[3u * i + 1u], r[3u * i + 2u]);
        var step = vec3<real>(real(0.0));
        if l.rho == real(0.0) {
            cold = 1u;
        } else {
            var v = point_velocity(i, false);
            v.x += l.shift;
            step = uzawa_step(ri, v, l.mu, l.rho).r - ri;
        }
        locals[i].v_free_n = step.x;
        locals[i].v_free_t1 = step.y;
        locals[i].v_free_t2 = step.z;
    }
    // The nodes read the steps of every lane.
    storageBarrier();
    workgroupBarrier();
    var worst = real(0.0);
    var size = real(0.0);
    for (var n = p.node_start + lane; n < p.node_end; n += NEWTON_WORKGROUP) {
        var d = vec3<real>(real(0.0));
        for (var e = node_start[n]; e < node_start[n + 1u]; e++) {
            let i = node_points[e];
            d += node_coefs[e] * global(i, vec3<real>(locals[i].v_free_n, locals[i].v_free_t1, locals[i].v_free_t2));
        }
        worst = max(worst, norm(d));
        size = max(size, norm(node_force(n)));
    }
    worst = reduce_max(lane, worst);
    size = reduce_max(lane, size);
    let any_cold = reduce_max(lane, real(cold));
    if lane != 0u {
        return;
    }
    let complementarity = worst / max(max(size, p.floor), REAL_MIN_POSITIVE);
    let grp = groups[k];
    var all_converged = true;
    var to_host = false;
    for (var a = 0u; a < grp.member_count; a++) {
        let s = state[group_members[grp.member_start + a]];
        all_converged = all_converged && s.status == CONVERGED;
        to_host = to_host || s.status == HOST || s.status == FAILED;
    }
    var verdict = ITERATING;
    if to_host {
        verdict = HOST;
    } else if all_converged && any_cold == real(0.0) && complementarity <= grp.tolerance {
        verdict = CONVERGED;
    }
    for (var a = 0u; a < grp.member_count; a++) {
        let m = group_members[grp.member_start + a];
        if state[m].status != FAILED {
            state[m].status = verdict;
        }
    }
}

// The Delassus blocks W = H K̄⁻¹ Hᵀ / θdt of group k's problem from its members' K̄⁻¹, as the
// host's `ContactStep::build_delassus` gives them from its factorisations: block (i, j), entry
// (c, a), sums over the terms of points i and j on one body of coef_s coef_t Fi[c]ᵀ K̄⁻¹ Fj[a]
// (prescribed dofs respond to nothing); a frictionless column point keeps its normal column only
// (its tangential reactions stay zero). Then each point's step length from its row (`Delassus::rho`:
// one over the sum of the ∞-norms of its own block, or of every block of its row for Jacobi
// sweeps; zero for an empty sum), and the problem's floor, the largest step length times the
// group's velocity scale. One workgroup per group, one invocation per point (row).
@compute @workgroup_size(NEWTON_WORKGROUP)
fn delassus(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if !exists(lane, k) {
        return;
    }
    build_w(lane, k);
}

// After a refactorisation within the call (`newton_invert`'s `refactor`): W of each group with
// a member in REFACTOR built again from the new K̄⁻¹, as `delassus` builds it, and those members
// ITERATING again.
@compute @workgroup_size(NEWTON_WORKGROUP)
fn rebuild(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) workgroup: vec3<u32>, @builtin(num_workgroups) count: vec3<u32>) {
    let k = problem_index(workgroup, count);
    if lane == 0u {
        var refactoring = false;
        if k < call.problems {
            let grp = groups[k];
            for (var a = 0u; a < grp.member_count; a++) {
                refactoring = refactoring || state[group_members[grp.member_start + a]].status == REFACTOR;
            }
        }
        go = u32(refactoring);
    }
    if workgroupUniformLoad(&go) == 0u {
        return;
    }
    build_w(lane, k);
    if lane == 0u {
        let grp = groups[k];
        for (var a = 0u; a < grp.member_count; a++) {
            let m = group_members[grp.member_start + a];
            if state[m].status == REFACTOR {
                state[m].status = ITERATING;
            }
        }
    }
}

// Group k's W: every block its rows list, then each point's step length and the floor.
fn build_w(lane: u32, k: u32) {
    let p = problems[k];
    let grp = groups[k];
    let dim = call.dim;
    var largest = real(0.0);
    for (var i = p.point_start + lane; i < p.point_end; i += NEWTON_WORKGROUP) {
        var sum = real(0.0);
        for (var e = row_start[i]; e < row_start[i + 1u]; e++) {
            let j = row_entries[e].x;
            var w: array<real, 9>;
            for (var s = term_start[i]; s < term_start[i + 1u]; s++) {
                let m = node_member[term_slots[s]];
                let start = newton[m].inverse_start;
                for (var t = term_start[j]; t < term_start[j + 1u]; t++) {
                    if node_member[term_slots[t]] != m {
                        continue;
                    }
                    let coef = term_coefs[s] * term_coefs[t];
                    for (var q = 0u; q < dim; q++) {
                        let fs = free_of[node_dof[term_slots[s]] + q];
                        if fs == NOT_FREE {
                            continue;
                        }
                        for (var x = 0u; x < dim; x++) {
                            let ft = free_of[node_dof[term_slots[t]] + x];
                            if ft == NOT_FREE {
                                continue;
                            }
                            let kinv = coef * inverse[start + packed(fs, ft)];
                            for (var c = 0u; c < dim; c++) {
                                for (var a = 0u; a < dim; a++) {
                                    w[3u * c + a] += frames[9u * i + 3u * c + q] * kinv * frames[9u * j + 3u * a + x];
                                }
                            }
                        }
                    }
                }
            }
            let columns = select(dim, 1u, locals[j].mu == real(0.0));
            let b = 9u * row_entries[e].y;
            var norm = real(0.0);
            for (var c = 0u; c < 3u; c++) {
                var row = real(0.0);
                for (var a = 0u; a < 3u; a++) {
                    let value = select(real(0.0), w[3u * c + a] / call.theta_dt, a < columns);
                    blocks[b + 3u * c + a] = value;
                    row += abs(value);
                }
                norm = max(norm, row);
            }
            if grp.jacobi == 1u || j == i {
                sum += norm;
            }
        }
        let rho = select(real(0.0), real(1.0) / sum, sum > real(0.0));
        locals[i].rho = rho;
        step_lengths[i] = rho;
        largest = max(largest, rho);
    }
    let floor = grp.velocity_scale * reduce_max(lane, largest);
    for (var i = p.point_start + lane; i < p.point_end; i += NEWTON_WORKGROUP) {
        locals[i].floor = floor;
    }
    if lane == 0u {
        problems[k].floor = floor;
    }
}
