//! Fill-reducing orderings of a body's free dofs for the sparse Cholesky factorisation.
//!
//! faer's default is approximate minimum degree (AMD), which suits 2D meshes and small bodies.
//! On 3D meshes AMD leaves much more fill than nested dissection: a geometric nested dissection
//! (recursive coordinate bisection of the dof graph, separators numbered last) halves the fill
//! of a Hex8 block and cuts its factorisation flops by ~3x (doc/benchmarks.md). A body computes
//! both symbolic factorisations and keeps the smaller factor, so the choice is measured per body.

use crate::precision::Real;

/// Subproblems at most this large are numbered as they come: separators no longer pay.
const LEAF: usize = 48;

/// Which fill-reducing ordering a body's factorisation uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ordering {
    /// faer's approximate minimum degree.
    Amd,
    /// Geometric nested dissection ([`nested_dissection`]).
    NestedDissection,
}

impl Ordering {
    pub fn name(self) -> &'static str {
        match self {
            Ordering::Amd => "amd",
            Ordering::NestedDissection => "nested_dissection",
        }
    }
}

/// The symmetric graph of a lower-triangular CSC pattern (diagonal left out), as adjacency lists
/// in one array: the neighbours of `v` are `adjacency[start[v]..start[v + 1]]`.
fn symmetric_graph(n: usize, col_ptr: &[u32], row_idx: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let mut degree = vec![0u32; n + 1];
    for j in 0..n {
        for &i in &row_idx[col_ptr[j] as usize..col_ptr[j + 1] as usize] {
            if i as usize != j {
                degree[i as usize] += 1;
                degree[j] += 1;
            }
        }
    }
    let mut start = vec![0u32; n + 1];
    for v in 0..n {
        start[v + 1] = start[v] + degree[v];
    }
    let mut fill = start.clone();
    let mut adjacency = vec![0u32; start[n] as usize];
    for j in 0..n {
        for &i in &row_idx[col_ptr[j] as usize..col_ptr[j + 1] as usize] {
            if i as usize != j {
                adjacency[fill[i as usize] as usize] = j as u32;
                fill[i as usize] += 1;
                adjacency[fill[j] as usize] = i;
                fill[j] += 1;
            }
        }
    }
    (start, adjacency)
}

/// A nested-dissection elimination order of the `n` vertices of a lower-triangular CSC pattern,
/// from the coordinates of each vertex: `order[k]` is the vertex eliminated `k`-th.
///
/// Each subproblem is split at the median of its longest coordinate extent; the vertices of
/// the lower half with a neighbour in the upper half form the separator, numbered after both
/// halves (which are split the same way, recursively).
pub fn nested_dissection(col_ptr: &[u32], row_idx: &[u32], coordinates: &[[Real; 3]]) -> Vec<u32> {
    let n = coordinates.len();
    let (start, adjacency) = symmetric_graph(n, col_ptr, row_idx);
    let mut region = vec![0u32; n];
    let mut next_region = 1;
    let mut order = Vec::with_capacity(n);
    let mut ids: Vec<u32> = (0..n as u32).collect();
    dissect(&mut ids, coordinates, &start, &adjacency, &mut region, &mut next_region, &mut order);
    debug_assert_eq!(order.len(), n);
    order
}

fn dissect(ids: &mut [u32], x: &[[Real; 3]], start: &[u32], adjacency: &[u32], region: &mut [u32], next_region: &mut u32, order: &mut Vec<u32>) {
    if ids.len() <= LEAF {
        order.extend_from_slice(ids);
        return;
    }
    let (mut lo, mut hi) = ([Real::INFINITY; 3], [Real::NEG_INFINITY; 3]);
    for &v in ids.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(x[v as usize][k]);
            hi[k] = hi[k].max(x[v as usize][k]);
        }
    }
    let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).expect("three axes");
    let coordinate = |v: u32| x[v as usize][axis];
    ids.sort_unstable_by(|&a, &b| coordinate(a).total_cmp(&coordinate(b)).then(a.cmp(&b)));
    // Split between two distinct coordinates nearest the median, so that a plane of nodes (and
    // the dofs of one node) stays on one side: the separator is then one layer, not one and a half.
    let n = ids.len();
    let boundary = |i: usize| coordinate(ids[i - 1]) != coordinate(ids[i]);
    let mid = (0..n / 2).flat_map(|k| [n / 2 - k, n / 2 + k]).find(|&i| i > 0 && i < n && boundary(i)).unwrap_or(n / 2);
    let (left_id, right_id, separator_id) = (*next_region, *next_region + 1, *next_region + 2);
    *next_region += 3;
    let (left, right) = ids.split_at_mut(mid);
    for &v in left.iter() {
        region[v as usize] = left_id;
    }
    for &v in right.iter() {
        region[v as usize] = right_id;
    }
    for &v in left.iter() {
        let neighbours = &adjacency[start[v as usize] as usize..start[v as usize + 1] as usize];
        if neighbours.iter().any(|&w| region[w as usize] == right_id) {
            region[v as usize] = separator_id;
        }
    }
    // Separator vertices go to the end of the left half (stable order otherwise).
    left.sort_by_key(|&v| (region[v as usize] == separator_id, v));
    let interior = left.iter().take_while(|&&v| region[v as usize] != separator_id).count();
    let (interior_left, separator) = left.split_at_mut(interior);
    let separator = separator.to_vec();
    dissect(interior_left, x, start, adjacency, region, next_region, order);
    dissect(right, x, start, adjacency, region, next_region, order);
    order.extend_from_slice(&separator);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_dissection_is_a_permutation_with_the_separator_last() {
        // A 10 x 10 grid graph, 5-point stencil, lower triangle with the diagonal.
        let m = 10;
        let mut col_ptr = vec![0u32];
        let mut row_idx = Vec::new();
        for j in 0..m * m {
            row_idx.push(j as u32);
            if (j % m) + 1 < m {
                row_idx.push(j as u32 + 1);
            }
            if j + m < m * m {
                row_idx.push((j + m) as u32);
            }
            col_ptr.push(row_idx.len() as u32);
        }
        let x: Vec<[Real; 3]> = (0..m * m).map(|j| [(j % m) as Real, (j / m) as Real, 0.0]).collect();
        let order = nested_dissection(&col_ptr, &row_idx, &x);
        let mut seen = order.clone();
        seen.sort();
        assert_eq!(seen, (0..(m * m) as u32).collect::<Vec<_>>());
        // The top-level separator is a grid line: the last m vertices share one coordinate.
        let last = &order[order.len() - m..];
        let same_x = last.iter().all(|&v| x[v as usize][0] == x[last[0] as usize][0]);
        let same_y = last.iter().all(|&v| x[v as usize][1] == x[last[0] as usize][1]);
        assert!(same_x || same_y, "separator {last:?}");
    }
}
