// How the kernels of a batch find their work. A batch holds the elements of many bodies (its
// "members"), each owning a range of elements, stiffness non-zeros and dofs. A dispatch runs
// over the list of active members: one z-slice of workgroups per active member, x (and y past
// MAX_ROW) counting the workgroups inside the member, so the work follows the bodies that are
// still iterating, not the size of the world. CPU side: `gpu::world`.

struct MemberRange {
    element_start: u32,
    elements: u32,
    nonzero_start: u32,
    nonzeros: u32,
    dof_start: u32,
    dofs: u32,
    material: u32,
    // Where the member's viscoelastic history starts in `history` (`include/viscous.wgsl`), or
    // NO_HISTORY.
    history: u32,
}

// An active member and what is asked of it.
struct Active {
    member: u32,
    mode: u32,
}

// Modes: the internal force (and residual), or also the tangent (and stiffness values).
const FORCES = 1u;
const TANGENT = 2u;
// `Active.member` of a slot of a step pass's list that no member holds.
const NO_MEMBER = 0xffffffffu;
const MAX_ROW = 65535u;

// The workgroup's index inside its member.
fn chunk_of(workgroup: vec3<u32>) -> u32 {
    return workgroup.x + workgroup.y * MAX_ROW;
}

// What the assembly and Newton kernels take and give per dof.
struct Coefficients {
    // Multiplies every tangent entry and the new internal force (ξ of the theta method).
    factor: real,
    // 1/(θ dt²): multiplies the inertia.
    c1: real,
    // How far the scene's fastest motion goes in the step: the floor of the Newton increment's
    // bound (`newton_judge`), one for every member, so that a member's own row does not change
    // from step to step while the scene speeds up. Zero outside Newton calls.
    motion: real,
}

// What a dof needs from the start of the step.
struct DofStep {
    mass: real,
    u_pred: real,
    f_int_t: real,
    f_ext: real,
}

struct DofOut {
    f_int: real,
    g: real,
}

// A dof's committed state, which the device keeps between the steps of a body that steps there
// (`step_begin`, `step_commit`).
struct DofState {
    u: real,
    v: real,
    f_int: real,
}

// The theta rule of one step: its length, dt (1 - θ) and θ dt.
struct StepMotion {
    dt: real,
    dt_explicit: real,
    theta_dt: real,
    // The scene's dimension (2 or 3).
    dim: real,
}
