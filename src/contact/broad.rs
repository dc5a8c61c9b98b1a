//! Broad phase between bodies: which bodies are near enough to each other for their nodes and
//! facets (or elements) to be searched at all. In a packing most grains touch none or a few
//! others, so the node-facet search of a step costs what is near, not the number of bodies.

use super::geometry::Vec3;
use super::grid::Grid;
use crate::precision::Real;
use rayon::prelude::*;

/// An axis-aligned box: `(min, max)`.
pub type Aabb = (Vec3, Vec3);

pub fn intersect(a: Aabb, b: Aabb) -> bool {
    (0..3).all(|i| a.0[i] <= b.1[i] && b.0[i] <= a.1[i])
}

/// `a` grown by `r` on every side.
pub fn grown(a: Aabb, r: Real) -> Aabb {
    (a.0.map(|c| c - r), a.1.map(|c| c + r))
}

/// Per body, the other bodies whose boxes meet its own and that `can_touch` it, in increasing
/// order. A hash grid of cells as large as the largest box: each box covers at most 2^dim
/// cells, so the cost is linear in the number of bodies and of the pairs found.
pub fn neighbours(boxes: &[Aabb], can_touch: impl Fn(usize, usize) -> bool + Sync) -> Vec<Vec<u32>> {
    let cell = boxes.iter().map(|(lo, hi)| (0..3).map(|i| hi[i] - lo[i]).fold(0.0, Real::max)).fold(0.0, Real::max);
    if boxes.len() < 2 || !cell.is_finite() {
        return vec![Vec::new(); boxes.len()];
    }
    let grid = Grid::new(boxes.iter().enumerate().map(|(i, &(lo, hi))| (i as u32, lo, hi)), cell.max(Real::MIN_POSITIVE));
    boxes
        .par_iter()
        .enumerate()
        .map(|(a, &(lo, hi))| {
            let mut found: Vec<u32> = Vec::new();
            grid.for_each_cell(lo, hi, |ids| {
                found.extend(ids.iter().filter(|&&b| b as usize != a && intersect(boxes[a], boxes[b as usize]) && can_touch(a, b as usize)));
            });
            found.sort_unstable();
            found.dedup();
            found
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The grid finds exactly the pairs a test of every pair finds.
    #[test]
    fn neighbours_are_the_meeting_boxes_of_a_test_of_every_pair() {
        // A fixed scatter of boxes of mixed sizes, some far apart, some overlapping.
        let mut seed = 7u64;
        let mut unit = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as Real / (1u64 << 53) as Real
        };
        let boxes: Vec<Aabb> = (0..300)
            .map(|_| {
                let c = [unit() * 20.0, unit() * 20.0, unit() * 4.0];
                let r = [0.1 + unit(), 0.1 + unit(), 0.1 + 0.5 * unit()];
                ([c[0] - r[0], c[1] - r[1], c[2] - r[2]], [c[0] + r[0], c[1] + r[1], c[2] + r[2]])
            })
            .collect();
        let can_touch = |a: usize, b: usize| (a + b) % 7 != 0;
        let found = neighbours(&boxes, can_touch);
        let mut pairs = 0;
        for a in 0..boxes.len() {
            let expected: Vec<u32> = (0..boxes.len()).filter(|&b| b != a && intersect(boxes[a], boxes[b]) && can_touch(a, b)).map(|b| b as u32).collect();
            assert_eq!(found[a], expected, "body {a}");
            pairs += expected.len();
        }
        assert!(pairs > 100, "the case has pairs to find: {pairs}");
    }
}
