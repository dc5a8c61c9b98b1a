//! Mirrors sent up dof by dof: a member whose values changed at a few dofs of its span sends
//! those alone, with their indices, and `scatter_reals` (`shaders/scatter_reals.wgsl`) writes
//! them into the buffer at the head of the next submission. The contact forces of a group in
//! contact are nonzero at its nodes in contact only, and only those change from call to call:
//! whole spans of them were a tenth of the bytes a pressed packing moved a step on lavapipe.

use super::mirror::{split_spans, Mirror};
use super::{buffer_init, GpuWorld};
use crate::gpu::Gpu;
use crate::precision::Real;
use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;
use wgpu::{Buffer, BufferUsages};

/// The number of entries `scatter_reals` writes (`struct ScatterCount` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct ScatterCount {
    pub count: u32,
    pub pad: [u32; 3],
}

/// Entries of a batch's mirror waiting for the next submission, each index once.
pub(super) struct Scattered {
    batch: usize,
    mirror: Mirror,
    destination: Buffer,
    indices: Vec<u32>,
    values: Vec<Real>,
}

impl Scattered {
    pub(super) fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// Keeps the entries whose index `keep` takes.
    fn retain(&mut self, keep: impl Fn(u32) -> bool) {
        let kept: Vec<(u32, Real)> = self.indices.iter().zip(&self.values).filter(|(&i, _)| keep(i)).map(|(&i, &v)| (i, v)).collect();
        (self.indices, self.values) = kept.into_iter().unzip();
    }
}

/// Per span `(start, values)` of a host mirror (sorted, disjoint): the positions where the
/// values differ from the mirror, bit for bit, which take the values.
fn changed_positions(mirror: &mut [Real], spans: &[(usize, &[Real])]) -> Vec<Vec<u32>> {
    split_spans(mirror, spans)
        .into_par_iter()
        .map(|(start, mine, values)| {
            let mut changed = Vec::new();
            for (k, (m, &v)) in mine.iter_mut().zip(values).enumerate() {
                if m.to_bits() != v.to_bits() {
                    *m = v;
                    changed.push((start + k) as u32);
                }
            }
            changed
        })
        .collect()
}

/// Whether `changed` of a span of `span` reals go up better with their indices than whole.
fn sparse(changed: usize, span: usize, real: usize) -> bool {
    changed * (real + 4) < span * real
}

impl GpuWorld {
    /// As [`GpuWorld::stage_mirror`] for a mirror of one real a dof, dof by dof: of each listed
    /// member (`(member, values)`, in member order) whose values changed, the changed dofs
    /// with their indices where that is fewer bytes, else its whole span.
    pub(super) fn stage_mirror_by_dof(&mut self, batch: usize, mirror: Mirror, mine: &[(usize, &[Real])]) {
        let real = self.gpu.precision.size();
        let b = &mut self.batches[batch];
        let spans: Vec<(usize, &[Real])> = mine.iter().map(|&(m, values)| (b.members[m].dof_start as usize, values)).collect();
        let (host, destination, per_dof) = b.mirror(mirror);
        debug_assert_eq!(per_dof, 1);
        let changed = changed_positions(host, &spans);
        let (mut whole, mut indices, mut values) = (Vec::new(), Vec::new(), Vec::new());
        for ((&(m, v), &(start, _)), positions) in mine.iter().zip(&spans).zip(changed) {
            if positions.is_empty() {
                continue;
            }
            if sparse(positions.len(), v.len(), real) {
                values.extend(positions.iter().map(|&p| v[p as usize - start]));
                indices.extend(positions);
            } else {
                whole.push(m);
            }
        }
        self.upload_mirror(batch, mirror, &whole);
        if !indices.is_empty() {
            self.scatter(batch, mirror, destination, indices, values);
        }
    }

    /// Queues `values` for their `indices` of a mirror's buffer, replacing those queued for the
    /// same indices.
    fn scatter(&mut self, batch: usize, mirror: Mirror, destination: Buffer, indices: Vec<u32>, values: Vec<Real>) {
        match self.scattered.iter_mut().find(|s| s.batch == batch && s.mirror == mirror) {
            Some(s) => {
                let mut newer = indices.clone();
                newer.sort_unstable();
                s.retain(|i| newer.binary_search(&i).is_err());
                s.indices.extend(indices);
                s.values.extend(values);
            }
            None => self.scattered.push(Scattered { batch, mirror, destination, indices, values }),
        }
    }

    /// Drops the queued entries of a mirror within `range` (of its reals): a whole span that
    /// goes up after them is newer.
    pub(super) fn drop_scattered(&mut self, batch: usize, mirror: Mirror, range: std::ops::Range<usize>) {
        for s in self.scattered.iter_mut().filter(|s| s.batch == batch && s.mirror == mirror) {
            s.retain(|i| !range.contains(&(i as usize)));
        }
    }

    /// Records the queued entries, one `scatter_reals` dispatch per buffer, and counts their
    /// bytes as sent.
    pub(super) fn record_scattered(&mut self, encoder: &mut wgpu::CommandEncoder) {
        let scattered = std::mem::take(&mut self.scattered);
        if scattered.iter().all(Scattered::is_empty) {
            return;
        }
        let pipeline = match &self.scatter_pipeline {
            Some(p) => p.clone(),
            None => {
                let p = self.gpu.pipeline("scatter_reals", None).expect("scatter_reals compiles wherever the world's kernels did");
                self.scatter_pipeline = Some(p.clone());
                p
            }
        };
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("scatter_reals"), timestamp_writes: None });
        for s in scattered.iter().filter(|s| !s.is_empty()) {
            let up = record_one(&self.gpu, &mut pass, &pipeline, s);
            self.traffic.up += up;
        }
    }
}

/// Records one buffer's entries; returns the bytes sent.
fn record_one(gpu: &Gpu, pass: &mut wgpu::ComputePass, pipeline: &wgpu::ComputePipeline, s: &Scattered) -> u64 {
    let storage = BufferUsages::STORAGE;
    let values = super::to_device(gpu.precision, &s.values);
    let count = ScatterCount { count: s.indices.len() as u32, pad: [0; 3] };
    let indices = buffer_init(gpu, "scatter indices", bytemuck::cast_slice(&s.indices), storage);
    let values_buffer = buffer_init(gpu, "scatter values", &values, storage);
    let count_buffer = buffer_init(gpu, "scatter count", bytemuck::bytes_of(&count), BufferUsages::UNIFORM);
    let group = gpu.bind_named(pipeline, ("scatter_reals", "main", None), &[("indices", &indices), ("values", &values_buffer), ("destination", &s.destination), ("count", &count_buffer)]);
    let (x, y) = crate::gpu::dispatch_rows(s.indices.len().div_ceil(64));
    gpu.dispatch(pass, ("scatter_reals", "main"), |pass| {
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    });
    (s.indices.len() * 4 + values.len() + std::mem::size_of::<ScatterCount>()) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mirror_takes_the_changed_values_and_names_their_positions() {
        let mut mirror = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, Real::NAN, 7.0];
        let (z, a, b) = ([-0.0], [1.0, 2.5, 3.0], [6.0, 7.0]);
        let spans: [(usize, &[Real]); 3] = [(0, &z), (1, &a), (6, &b)];
        let changed = changed_positions(&mut mirror, &spans);
        assert_eq!(changed, vec![vec![0], vec![2], vec![6]], "bits that differ: -0.0, a value, NaN");
        assert_eq!(mirror.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), [-0.0, 1.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0].iter().map(|x: &Real| x.to_bits()).collect::<Vec<_>>());
        assert!(changed_positions(&mut mirror, &spans).iter().all(Vec::is_empty), "nothing the second time");
    }

    #[test]
    fn a_few_changed_reals_go_up_with_their_indices_and_many_whole() {
        assert!(sparse(2, 60, 8));
        assert!(!sparse(40, 60, 8));
        assert!(!sparse(1, 1, 8));
    }
}
