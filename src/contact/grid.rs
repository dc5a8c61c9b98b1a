//! Broad phase: spatial hashing of facet bounding boxes on a uniform grid. Cells are hashed into
//! a table of about twice as many buckets as entries, stored as one compressed array (counting
//! sort), so building and querying cost time linear in the number of facets and queries. Two
//! cells may share a bucket; the narrow phase rejects the extra facets that brings.

use super::geometry::Vec3;
use crate::precision::Real;

pub struct Grid {
    cell: Real,
    mask: usize,
    /// Bucket `b` holds `ids[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    ids: Vec<u32>,
}

fn hash(c: [i64; 3]) -> usize {
    // Large primes from Teschner et al. (2003), "Optimized spatial hashing for collision detection".
    ((c[0].wrapping_mul(73_856_093)) ^ (c[1].wrapping_mul(19_349_663)) ^ (c[2].wrapping_mul(83_492_791))) as usize
}

impl Grid {
    /// `boxes` yields `(id, min, max)`; `cell` is the edge of a grid cell.
    pub fn new(boxes: impl Iterator<Item = (u32, Vec3, Vec3)>, cell: Real) -> Self {
        let mut entries: Vec<(usize, u32)> = Vec::new();
        for (id, lo, hi) in boxes {
            let (a, b) = (Self::key(lo, cell), Self::key(hi, cell));
            for i in a[0]..=b[0] {
                for j in a[1]..=b[1] {
                    for k in a[2]..=b[2] {
                        entries.push((hash([i, j, k]), id));
                    }
                }
            }
        }
        let buckets = (2 * entries.len()).next_power_of_two().max(1);
        let mask = buckets - 1;
        let mut start = vec![0u32; buckets + 1];
        for &(h, _) in &entries {
            start[(h & mask) + 1] += 1;
        }
        for b in 0..buckets {
            start[b + 1] += start[b];
        }
        let mut fill = start.clone();
        let mut ids = vec![0u32; entries.len()];
        for &(h, id) in &entries {
            let b = h & mask;
            ids[fill[b] as usize] = id;
            fill[b] += 1;
        }
        Self { cell, mask, start, ids }
    }

    fn key(x: Vec3, cell: Real) -> [i64; 3] {
        x.map(|c| (c / cell).floor() as i64)
    }

    /// Ids of the boxes registered in the bucket of the cell that holds `x` (a superset of the
    /// boxes that overlap that cell).
    pub fn query(&self, x: Vec3) -> &[u32] {
        self.bucket(Self::key(x, self.cell))
    }

    /// `f` on the bucket of every cell the box `lo`..`hi` covers (an id may come more than once).
    pub fn for_each_cell(&self, lo: Vec3, hi: Vec3, mut f: impl FnMut(&[u32])) {
        let (a, b) = (Self::key(lo, self.cell), Self::key(hi, self.cell));
        for i in a[0]..=b[0] {
            for j in a[1]..=b[1] {
                for k in a[2]..=b[2] {
                    f(self.bucket([i, j, k]));
                }
            }
        }
    }

    fn bucket(&self, cell: [i64; 3]) -> &[u32] {
        let b = hash(cell) & self.mask;
        &self.ids[self.start[b] as usize..self.start[b + 1] as usize]
    }
}
