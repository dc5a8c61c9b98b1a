//! Broad phase: a uniform hash grid over facet bounding boxes. Building and querying cost time
//! linear in the number of facets and queries when facets have similar sizes.

use super::geometry::Vec3;
use crate::precision::Real;
use std::collections::HashMap;

type Cell = [i64; 3];

pub struct Grid {
    cell: Real,
    cells: HashMap<Cell, Vec<u32>>,
}

impl Grid {
    /// `boxes` yields `(id, min, max)`; `cell` is the edge of a grid cell.
    pub fn new(boxes: impl Iterator<Item = (u32, Vec3, Vec3)>, cell: Real) -> Self {
        let mut cells: HashMap<Cell, Vec<u32>> = HashMap::new();
        for (id, lo, hi) in boxes {
            let (a, b) = (Self::key(lo, cell), Self::key(hi, cell));
            for i in a[0]..=b[0] {
                for j in a[1]..=b[1] {
                    for k in a[2]..=b[2] {
                        cells.entry([i, j, k]).or_default().push(id);
                    }
                }
            }
        }
        Self { cell, cells }
    }

    fn key(x: Vec3, cell: Real) -> Cell {
        x.map(|c| (c / cell).floor() as i64)
    }

    /// Ids of the boxes registered in the cell that holds `x`.
    pub fn query(&self, x: Vec3) -> &[u32] {
        self.cells.get(&Self::key(x, self.cell)).map(Vec::as_slice).unwrap_or(&[])
    }
}
