//! The normal equations of a pose graph, solved by a block Cholesky factorization: one `D × D`
//! block per pose (3 in the plane, 6 in space), the poses eliminated in a minimum-degree order
//! of the graph (fill kept low: each pose, once eliminated, links its remaining neighbours),
//! the pattern worked out once ([`Pattern`]) and the numbers each iteration ([`Factor`]).

use nalgebra::{SMatrix, SVector};
use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};

/// The structure of the factor: the elimination order and, for each pose in it, the later
/// poses its column holds (the graph's edges and the fill).
#[derive(Clone, Debug)]
pub struct Pattern {
    /// The variable at each position of the order.
    order: Vec<usize>,
    /// The position of each variable.
    position: Vec<usize>,
    /// For each position, the later positions below it in its column, ascending.
    below: Vec<Vec<usize>>,
}

impl Pattern {
    /// The pattern of `n` variables linked by `edges` (pairs of variables), in a minimum-degree
    /// order (ties to the smallest variable, so the order is the same on every machine).
    pub fn new(n: usize, edges: &[(usize, usize)]) -> Self {
        let mut adjacent: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
        for &(a, b) in edges {
            if a != b {
                adjacent[a].insert(b);
                adjacent[b].insert(a);
            }
        }
        let mut heap: BinaryHeap<Reverse<(usize, usize)>> =
            (0..n).map(|v| Reverse((adjacent[v].len(), v))).collect();
        let mut eliminated = vec![false; n];
        let mut order = Vec::with_capacity(n);
        let mut neighbours_at: Vec<Vec<usize>> = vec![Vec::new(); n];
        while let Some(Reverse((degree, v))) = heap.pop() {
            if eliminated[v] || degree != adjacent[v].len() {
                continue;
            }
            eliminated[v] = true;
            order.push(v);
            let neighbours: Vec<usize> = std::mem::take(&mut adjacent[v]).into_iter().collect();
            for &u in &neighbours {
                adjacent[u].remove(&v);
                for &w in &neighbours {
                    if w != u {
                        adjacent[u].insert(w);
                    }
                }
                heap.push(Reverse((adjacent[u].len(), u)));
            }
            neighbours_at[v] = neighbours;
        }
        let mut position = vec![0; n];
        for (p, &v) in order.iter().enumerate() {
            position[v] = p;
        }
        let below = order
            .iter()
            .map(|&v| {
                let mut b: Vec<usize> = neighbours_at[v].iter().map(|&u| position[u]).collect();
                b.sort_unstable();
                b
            })
            .collect();
        Pattern { order, position, below }
    }

    /// The number of variables.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Where the block `(a, b)` of two distinct variables lives: (column position, index in it).
    fn slot(&self, a: usize, b: usize) -> (usize, usize) {
        let (pa, pb) = (self.position[a], self.position[b]);
        let (col, row) = if pa < pb { (pa, pb) } else { (pb, pa) };
        let at = self.below[col].binary_search(&row).expect("an edge of the pattern");
        (col, at)
    }

    /// Blocks below the diagonal (the factor's size).
    pub fn blocks(&self) -> usize {
        self.below.iter().map(Vec::len).sum()
    }
}

/// A symmetric block matrix on a [`Pattern`] (its diagonal and the lower blocks the pattern
/// holds), assembled, then factored in place.
#[derive(Clone)]
pub struct Factor<'p, const D: usize> {
    pattern: &'p Pattern,
    /// By position.
    diagonal: Vec<SMatrix<f64, D, D>>,
    /// By position, aligned with the pattern's `below`: the block (row, column).
    lower: Vec<Vec<SMatrix<f64, D, D>>>,
}

/// A factorization that met a block that is not positive definite.
#[derive(Debug)]
pub struct NotPositive;

impl<'p, const D: usize> Factor<'p, D> {
    /// A zero matrix on `pattern`.
    pub fn zeros(pattern: &'p Pattern) -> Self {
        Factor {
            pattern,
            diagonal: vec![SMatrix::zeros(); pattern.len()],
            lower: pattern.below.iter().map(|b| vec![SMatrix::zeros(); b.len()]).collect(),
        }
    }

    /// Adds `block` to the diagonal block of variable `v`.
    pub fn add_diagonal(&mut self, v: usize, block: &SMatrix<f64, D, D>) {
        self.diagonal[self.pattern.position[v]] += block;
    }

    /// Adds `block` to the block (`a`, `b`) (and its transpose to (`b`, `a`)).
    pub fn add_off(&mut self, a: usize, b: usize, block: &SMatrix<f64, D, D>) {
        let (col, at) = self.pattern.slot(a, b);
        // Stored as (row, column) with the row later in the order.
        if self.pattern.position[a] > self.pattern.position[b] {
            self.lower[col][at] += block;
        } else {
            self.lower[col][at] += block.transpose();
        }
    }

    /// The diagonal block of `v` (for a damping proportional to it).
    pub fn diagonal_of(&self, v: usize) -> &SMatrix<f64, D, D> {
        &self.diagonal[self.pattern.position[v]]
    }

    /// Factors the matrix in place (`L Lᵀ`, right-looking over the pattern's columns).
    pub fn factor(&mut self) -> Result<(), NotPositive> {
        let p = self.pattern;
        for k in 0..p.len() {
            let l_kk = self.diagonal[k].cholesky().ok_or(NotPositive)?.l();
            let inverse_t = l_kk.try_inverse().ok_or(NotPositive)?.transpose();
            self.diagonal[k] = l_kk;
            let column: Vec<SMatrix<f64, D, D>> = self.lower[k].iter().map(|a| a * inverse_t).collect();
            for (s, &i) in p.below[k].iter().enumerate() {
                let l_ik = &column[s];
                self.diagonal[i] -= l_ik * l_ik.transpose();
                for (t, &j) in p.below[k].iter().enumerate().take(s) {
                    // Block (i, j), i later than j: in column j.
                    let at = p.below[j].binary_search(&i).expect("the fill is closed");
                    self.lower[j][at] -= l_ik * column[t].transpose();
                }
            }
            self.lower[k] = column;
        }
        Ok(())
    }

    /// Solves the factored system for `rhs` (by variable), returning the solution by variable.
    pub fn solve(&self, rhs: &[SVector<f64, D>]) -> Vec<SVector<f64, D>> {
        let p = self.pattern;
        let n = p.len();
        let mut y: Vec<SVector<f64, D>> = p.order.iter().map(|&v| rhs[v]).collect();
        for k in 0..n {
            let l = &self.diagonal[k];
            let yk = l.solve_lower_triangular(&y[k]).expect("a factored diagonal");
            for (s, &i) in p.below[k].iter().enumerate() {
                y[i] -= self.lower[k][s] * yk;
            }
            y[k] = yk;
        }
        for k in (0..n).rev() {
            let mut r = y[k];
            for (s, &i) in p.below[k].iter().enumerate() {
                r -= self.lower[k][s].transpose() * y[i];
            }
            y[k] = self.diagonal[k].transpose().solve_upper_triangular(&r).expect("a factored diagonal");
        }
        let mut out = vec![SVector::zeros(); n];
        for (k, &v) in p.order.iter().enumerate() {
            out[v] = y[k];
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// A random symmetric positive definite block matrix on a chain with loops, solved here and
    /// by a dense Cholesky.
    #[test]
    fn solves_as_a_dense_cholesky_does() {
        let n = 12;
        let mut edges: Vec<(usize, usize)> = (0..n - 1).map(|i| (i, i + 1)).collect();
        edges.extend([(0, 7), (3, 11), (2, 9)]);
        let pattern = Pattern::new(n, &edges);
        let mut rng = crate::rng::SplitMix64(3);
        let mut r = || rng.next_u64() as f64 / u64::MAX as f64 - 0.5;
        let mut dense = DMatrix::<f64>::zeros(3 * n, 3 * n);
        let mut f = Factor::<3>::zeros(&pattern);
        for &(a, b) in &edges {
            let j = SMatrix::<f64, 3, 3>::from_fn(|_, _| r());
            // Jᵢ = −J, Jⱼ = J: blocks JᵀJ on both diagonals and −JᵀJ off them.
            let jtj = j.transpose() * j;
            f.add_diagonal(a, &jtj);
            f.add_diagonal(b, &jtj);
            f.add_off(a, b, &(-jtj));
            for (x, y, m) in [(a, a, jtj), (b, b, jtj), (a, b, -jtj), (b, a, -jtj)] {
                let mut view = dense.view_mut((3 * x, 3 * y), (3, 3));
                view += m;
            }
        }
        for v in 0..n {
            let d = SMatrix::<f64, 3, 3>::identity() * 0.5;
            f.add_diagonal(v, &d);
            let mut view = dense.view_mut((3 * v, 3 * v), (3, 3));
            view += d;
        }
        let rhs: Vec<SVector<f64, 3>> = (0..n).map(|_| SVector::from_fn(|_, _| r())).collect();
        f.factor().unwrap();
        let x = f.solve(&rhs);
        let b = nalgebra::DVector::from_iterator(3 * n, rhs.iter().flat_map(|v| v.iter().copied()));
        let want = dense.cholesky().unwrap().solve(&b);
        for v in 0..n {
            for k in 0..3 {
                assert!((x[v][k] - want[3 * v + k]).abs() < 1e-9, "{v} {k}");
            }
        }
    }
}
