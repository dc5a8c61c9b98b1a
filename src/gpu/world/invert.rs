//! `K̄⁻¹` of a small body's factorisation for its device Newton iterations: what goes up for it
//! (`K̄` itself, by its diagonal where the device holds the rest, or `K̄⁻¹` made on the host),
//! and the `newton_invert` pass that makes it on the device.

use super::newton::NewtonBuffers;
use super::{buffer, GpuWorld, Pass};
use crate::gpu::types::{packed_len, Inversion, MemberRange, NewtonMember};
use crate::gpu::{Gpu, GpuError};
use crate::precision::{Precision, Real};
use wgpu::{Buffer, BufferUsages, ComputePipeline};

/// A factorisation's `K̄⁻¹` for a device that does not hold it yet.
pub enum Inverse {
    /// `K̄` itself, the values factorised in the body's stiffness pattern: the device makes
    /// `K̄⁻¹` (`newton_invert`), and the bytes that go up are the non-zeros, or the diagonal
    /// alone where the others are the stiffness values the device holds and the host read back
    /// (`Batch::handed`).
    Effective(Vec<Real>),
    /// `K̄` as [`Inverse::Effective`], made at the iterate where a device Newton call handed
    /// the body back ([`super::NewtonCall::tangent_held`]) from the host's own tangent there: while
    /// the device still holds its tangent of that iterate, only the diagonal goes up and
    /// `newton_invert` takes the rest from the device's values (the two tangents, of the same
    /// displacements, agree to round-off).
    AtHandBack(Vec<Real>),
    /// `K̄⁻¹` made on the host, its lower triangle row by row (`gpu::types::packed`).
    Dense(Vec<Real>),
}

/// A fingerprint of a member's stiffness values off the diagonal (its pattern at
/// `pattern_start` of `patterns`, `n` free dofs): the bits of each in order, mixed (FNV-1a over
/// the words), so that two sets of values match only if they are the same, bit for bit, but
/// for a collision once in 2⁶⁴.
pub(in crate::gpu) fn off_diagonal_print(values: &[Real], patterns: &[u32], pattern_start: u32, n: usize) -> u64 {
    let (starts, rows) = columns(patterns, pattern_start, n);
    let mut print: u64 = 0xcbf2_9ce4_8422_2325;
    for j in 0..n {
        for k in starts[j] as usize..starts[j + 1] as usize {
            if rows[k] as usize != j {
                print = (print ^ values[k].to_bits()).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    print
}

/// A member's pattern of `n` free dofs at `pattern_start` of `patterns`: its column starts and
/// row indices.
fn columns(patterns: &[u32], pattern_start: u32, n: usize) -> (&[u32], &[u32]) {
    let at = pattern_start as usize;
    (&patterns[at..][..n + 1], &patterns[at + n + 1..])
}

/// A member's values on the diagonal, one per free dof, from its values in its pattern.
pub(super) fn diagonal_of(values: &[Real], patterns: &[u32], pattern_start: u32, n: usize) -> Vec<Real> {
    let (starts, rows) = columns(patterns, pattern_start, n);
    (0..n).map(|j| (starts[j] as usize..starts[j + 1] as usize).find(|&k| rows[k] as usize == j).map_or(0.0, |k| values[k])).collect()
}

/// The most loop iterations an invocation of `newton_invert` runs for a member of `n` free dofs
/// (its first lane, which takes the most rows of every loop over rows).
pub fn invert_loops(n: usize) -> usize {
    let lanes = crate::gpu::types::NEWTON_WORKGROUP;
    let rows = |count: usize| count.div_ceil(lanes);
    let cholesky: usize = (0..n).map(|k| 1 + rows(n - k - 1) * (2 + (n - k - 1))).sum();
    let triangle: usize = (0..n).map(|j| 2 + rows(n - j - 1) * (2 + (n - j - 1))).sum();
    let product: usize = (0..n).map(|i| 1 + rows(i + 1) * (2 + (n - i))).sum();
    rows(packed_len(n)) + rows(n) * (1 + n) + cholesky + triangle + product
}

impl GpuWorld {
    /// Whether the device makes `K̄⁻¹` of a member of `free` free dofs (`newton_invert`): on a
    /// software adapter only where the kernel's loops stay within what its invocations run
    /// ([`crate::gpu::uzawa_sweep::SOFTWARE_LOOP_BUDGET`]: llvmpipe ends a loop past it without an
    /// error; about 150 free dofs); else the host sends `K̄⁻¹`.
    pub fn inverts(&self, free: usize) -> bool {
        !self.software() || invert_loops(free) <= crate::gpu::uzawa_sweep::SOFTWARE_LOOP_BUDGET
    }
}

/// The inverses a call's members need, as they go up: `K̄⁻¹` made on the host in runs of
/// consecutive slots (one write each; after a step that refactorised every grain, one inverse
/// per grain): `(offset, end, inverses)`; and `K̄` of the members whose `K̄⁻¹` the device makes,
/// end to end, with their `newton_invert` jobs.
#[derive(Default)]
pub(super) struct NewInverses {
    pub(super) runs: Vec<(u64, u64, Vec<Vec<Real>>)>,
    pub(super) effective: Vec<Real>,
    pub(super) inversions: Vec<Inversion>,
}

impl NewInverses {
    /// Member `m`'s (its pattern at `pattern_start`; `sizes`: its triangle's and its pattern's
    /// reals), its slot at byte `offset`.
    /// `diagonal`: `K̄`'s diagonal, where the device holds its other entries (the stiffness
    /// values the host read back): only those go up.
    pub(super) fn add(&mut self, inverse: Inverse, [triangle, nonzeros]: [usize; 2], offset: u64, (m, pattern_start): (usize, u32), diagonal: Option<Vec<Real>>) {
        match inverse {
            Inverse::Dense(inverse) => {
                assert_eq!(inverse.len(), triangle, "the lower triangle of K̄⁻¹ of the member's free dofs");
                let end = offset + std::mem::size_of_val(&inverse[..]) as u64;
                match self.runs.last_mut() {
                    Some((_, last, run)) if *last == offset => {
                        *last = end;
                        run.push(inverse);
                    }
                    _ => self.runs.push((offset, end, vec![inverse])),
                }
            }
            Inverse::Effective(values) | Inverse::AtHandBack(values) => {
                assert_eq!(values.len(), nonzeros, "K̄ in the member's pattern");
                let diagonal_only = diagonal.is_some() as u32;
                self.inversions.push(Inversion { member: m as u32, values_start: self.effective.len() as u32, pattern_start, diagonal_only });
                self.effective.extend_from_slice(diagonal.as_deref().unwrap_or(&values));
            }
        }
    }

    /// The `newton_invert` pass of the inversions (with the batch's stiffness values and
    /// members), and the buffers of `K̄` and of the jobs it binds (for the uploads).
    pub(super) fn invert_pass(&self, gpu: &Gpu, pipeline: ComputePipeline, n: &NewtonBuffers, (stiffness, members): (&Buffer, &Buffer)) -> (Pass, Buffer, Buffer) {
        let storage = BufferUsages::STORAGE | BufferUsages::COPY_DST;
        let (values, jobs) = (buffer(gpu, "effective stiffness", std::mem::size_of_val(&self.effective[..]), storage), buffer(gpu, "inversions", std::mem::size_of_val(&self.inversions[..]), storage));
        let pass = Pass::bound(gpu, pipeline, ("newton_invert", "main"), None, &[("inverse", &n.inverse), ("newton", &n.newton), ("effective", &values), ("patterns", &n.patterns), ("inversions", &jobs), ("values", stiffness), ("members", members)]);
        (pass, values, jobs)
    }
}

/// `newton_invert` alone on an f64 device: the `inverse` buffer (`inverse_len` reals, zero
/// first) after the listed inversions, for the parity tests with the CPU twin.
pub fn run_newton_invert(gpu: &Gpu, newton: &[NewtonMember<Real>], inverse_len: usize, effective: &[Real], (values, members): (&[Real], &[MemberRange]), patterns: &[u32], inversions: &[Inversion]) -> Result<Vec<Real>, GpuError> {
    assert_eq!(gpu.precision, Precision::F64, "device Newton iterations need f64 kernels");
    let storage = BufferUsages::STORAGE;
    let init = |label: &str, bytes: &[u8], usage: BufferUsages| super::buffer_init(gpu, label, bytes, usage);
    let inverse = init("inverse", bytemuck::cast_slice(&vec![0.0 as Real; inverse_len]), storage | BufferUsages::COPY_SRC);
    let buffers = [
        ("newton", init("newton", bytemuck::cast_slice(newton), storage)),
        ("effective", init("effective", bytemuck::cast_slice(effective), storage)),
        ("patterns", init("patterns", bytemuck::cast_slice(patterns), storage)),
        ("inversions", init("inversions", bytemuck::cast_slice(inversions), storage)),
        ("values", init("values", bytemuck::cast_slice(values), storage)),
        ("members", init("members", bytemuck::cast_slice(members), storage)),
    ];
    let mut bindings: Vec<(&str, &Buffer)> = buffers.iter().map(|(name, b)| (*name, b)).collect();
    bindings.push(("inverse", &inverse));
    let pass = Pass::bound(gpu, gpu.pipeline_at("newton_invert", "main", None)?, ("newton_invert", "main"), None, &bindings);
    let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("newton invert") });
    {
        let mut compute = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("newton invert"), timestamp_writes: None });
        pass.dispatch(gpu, &mut compute, inversions.len() as u32);
    }
    let bytes = (inverse_len * std::mem::size_of::<Real>()) as u64;
    let staging = buffer(gpu, "invert read-back", bytes as usize, BufferUsages::MAP_READ | BufferUsages::COPY_DST);
    encoder.copy_buffer_to_buffer(&inverse, 0, &staging, 0, bytes);
    gpu.submit(encoder)?;
    Ok(bytemuck::pod_collect_to_vec(&gpu.read_range("newton_invert", &staging, bytes)?))
}
