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

/// Body pairs kept between steps (a Verlet list of boxes): the pairs whose boxes, each grown by
/// a skin, meet, found again only when a body's box leaves the grown box its pairs were found
/// with. Until then they hold every pair whose boxes meet, so that a packing at rest does not
/// rebuild its grid every step.
#[derive(Debug, Clone, Default)]
pub struct KeptPairs {
    /// Each body's box, grown by the skin, when the pairs were found.
    boxes: Vec<Aabb>,
    /// Per body, the bodies whose grown boxes met its own then (as [`neighbours`] gives them).
    near: Vec<Vec<u32>>,
    /// Times the pairs were found, for the tests.
    pub rebuilds: usize,
}

impl KeptPairs {
    /// Per body, a superset (in increasing order) of the bodies whose `boxes` meet its own and
    /// that `can_touch` it: the kept pairs, found again with boxes grown by `skin` when a box
    /// has left its grown one (or the number of bodies changed).
    pub fn near(&mut self, boxes: &[Aabb], skin: Real, can_touch: impl Fn(usize, usize) -> bool + Sync) -> &[Vec<u32>] {
        let inside = |a: &Aabb, b: &Aabb| (0..3).all(|i| b.0[i] <= a.0[i] && a.1[i] <= b.1[i]);
        let valid = self.boxes.len() == boxes.len() && boxes.iter().zip(&self.boxes).all(|(now, kept)| inside(now, kept));
        if !valid {
            self.boxes = boxes.iter().map(|&b| grown(b, skin)).collect();
            self.near = neighbours(&self.boxes, can_touch);
            self.rebuilds += 1;
        }
        &self.near
    }
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
        let can_touch = |a: usize, b: usize| !(a + b).is_multiple_of(7);
        let found = neighbours(&boxes, can_touch);
        let mut pairs = 0;
        for a in 0..boxes.len() {
            let expected: Vec<u32> = (0..boxes.len()).filter(|&b| b != a && intersect(boxes[a], boxes[b]) && can_touch(a, b)).map(|b| b as u32).collect();
            assert_eq!(found[a], expected, "body {a}");
            pairs += expected.len();
        }
        assert!(pairs > 100, "the case has pairs to find: {pairs}");
    }

    /// Kept pairs hold every meeting pair while boxes move within the skin, and are found again
    /// once one leaves it.
    #[test]
    fn kept_pairs_hold_the_meeting_boxes_until_a_box_leaves_its_skin() {
        let boxes: Vec<Aabb> = (0..20).map(|i| ([i as Real, 0.0, 0.0], [i as Real + 0.9, 1.0, 0.0])).collect();
        let mut kept = KeptPairs::default();
        let check = |boxes: &[Aabb], kept: &mut KeptPairs| {
            let fresh = neighbours(boxes, |_, _| true);
            let near = kept.near(boxes, 0.2, |_, _| true).to_vec();
            for (a, list) in fresh.iter().enumerate() {
                assert!(list.iter().all(|b| near[a].contains(b)), "body {a}: {list:?} not in {:?}", near[a]);
            }
        };
        check(&boxes, &mut kept);
        assert_eq!(kept.rebuilds, 1);
        // Within the skin: every other box grown by 0.12, so that it meets its neighbours, 0.1 away.
        let moved: Vec<Aabb> = boxes.iter().enumerate().map(|(i, b)| grown(*b, if i % 2 == 0 { 0.12 } else { 0.0 })).collect();
        assert!(neighbours(&moved, |_, _| true)[0] == [1]);
        check(&moved, &mut kept);
        assert_eq!(kept.rebuilds, 1, "no box left its skin");
        let far: Vec<Aabb> = moved.iter().enumerate().map(|(i, b)| if i == 3 { grown(*b, 1.0) } else { *b }).collect();
        check(&far, &mut kept);
        assert_eq!(kept.rebuilds, 2, "box 3 left its skin");
    }
}
