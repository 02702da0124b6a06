//! The Delaunay complex of a point cloud as flat arrays: deduplication, affine dimension,
//! triangulation, and enumeration of edges / triangles / tetrahedra with the incidences the
//! filtration and the persistence pairing need.
//!
//! Owns the simplex numbering. Vertex ids index the *deduplicated* points (first occurrence
//! kept); `input_index` maps them back.

use super::delaunay::{
    Geometry3, GeometryPlanar, INFINITE, Triangulation, link_cell, link_mirror, orient3d, planar_lift,
};
use super::exact::Point;
use super::spatial_sort::brio_order;
use std::collections::HashMap;

/// Marker for the outside cell (the infinite part of the triangulation) in coface arrays.
pub(crate) const OUTSIDE: u32 = u32::MAX;

/// Error building a complex.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum ComplexError {
    /// A coordinate is NaN or infinite.
    #[error("point {index} has a non-finite coordinate ({x}, {y}, {z})")]
    NonFinite {
        /// Index of the point in the input.
        index: usize,
        /// Its coordinates.
        x: f64,
        /// Its coordinates.
        y: f64,
        /// Its coordinates.
        z: f64,
    },
    /// Distinct points closer than the engine resolves exactly, relative to the cloud's extent.
    #[error(
        "distinct points closer than 2^{min_exponent} of the cloud's extent (here 2^{found}): \
         outside the scales the engine computes exactly"
    )]
    TooClose {
        /// The smallest supported ratio, as a power of two.
        min_exponent: i32,
        /// The ratio found (a lower bound on it), as a power of two.
        found: i32,
    },
    /// Squared radii that a double cannot hold.
    #[error(
        "squared radii from 2^{lo} to 2^{hi}: outside the range of doubles (2^-1022 to 2^1023); \
         scale the cloud into that range"
    )]
    OutOfRange {
        /// log2 of the smallest positive squared radius.
        lo: i32,
        /// log2 of the largest squared radius.
        hi: i32,
    },
    /// More simplices than the 32-bit indices allow.
    #[error("cloud too large: {points} points exceed the 32-bit simplex numbering")]
    TooLarge {
        /// Number of points.
        points: usize,
    },
    /// A Delaunay triangulation with more cells than the engine numbers.
    #[error(
        "cloud too large: its Delaunay triangulation needs more than {limit} cells, the engine's \
         limit (clouds whose points lie on a few lines or curves need the most)"
    )]
    TooManyCells {
        /// The limit.
        limit: usize,
    },
}

/// The Delaunay complex (all finite simplices of the Delaunay triangulation).
#[derive(Debug, Default)]
pub struct DelaunayComplex {
    /// Deduplicated points in insertion order; vertex `v` is `points[v]`.
    pub points: Vec<Point>,
    /// Input index of each vertex (the first occurrence of its point).
    pub input_index: Vec<u32>,
    /// Dimension of the affine hull (0 to 3); that of the complex.
    pub dim: usize,
    /// Edges `[u, v]`, `u < v`, grouped by `u`.
    pub edges: Vec<[u32; 2]>,
    /// Triangles (vertex triples).
    pub triangles: Vec<[u32; 3]>,
    /// Tetrahedra (positively oriented vertex quadruples).
    pub tets: Vec<[u32; 4]>,
    /// For each triangle, the edge opposite each of its vertices.
    pub tri_edges: Vec<[u32; 3]>,
    /// For each tetrahedron, the triangle opposite each of its vertices.
    pub tet_tris: Vec<[u32; 4]>,
    /// For each triangle (3D), its two tetrahedra; `OUTSIDE` for the hull side.
    pub tri_cofaces: Vec<[u32; 2]>,
    /// For each edge (2D), its two triangles; `OUTSIDE` for the hull side.
    pub edge_cofaces: Vec<[u32; 2]>,
}

impl DelaunayComplex {
    /// Builds the Delaunay complex of `input` (duplicates merged, as GUDHI does).
    pub fn new(input: &[Point]) -> Result<Self, ComplexError> {
        let (points, input_index) = dedup(input)?;
        if points.len() >= (u32::MAX / 64) as usize {
            return Err(ComplexError::TooLarge { points: points.len() });
        }
        // Vertices are renumbered in insertion (BRIO + Hilbert) order: spatially close
        // vertices get close ids, which keeps every later pass cache-friendly.
        let order = brio_order(&points);
        let mut c = DelaunayComplex {
            points: order.iter().map(|&i| points[i as usize]).collect(),
            input_index: order.iter().map(|&i| input_index[i as usize]).collect(),
            ..Default::default()
        };
        let n = c.points.len();
        if n <= 1 {
            c.dim = 0;
            return Ok(c);
        }
        let order: Vec<u32> = (0..n as u32).collect();
        let pts = &c.points;
        // Affine dimension: a second point, a non-collinear third, a non-coplanar fourth.
        let a = order[0];
        let b = order[1];
        let third =
            order.iter().position(|&i| !collinear(&pts[a as usize], &pts[b as usize], &pts[i as usize]));
        let Some(ci) = third else {
            c.build_1d();
            return Ok(c);
        };
        let cc = order[ci];
        let fourth = order.iter().position(|&i| {
            orient3d(&pts[a as usize], &pts[b as usize], &pts[cc as usize], &pts[i as usize]) != 0.0
        });
        match fourth {
            None => {
                let lift = planar_lift(&pts[a as usize], &pts[b as usize], &pts[cc as usize])
                    .expect("three non-collinear points have an off-plane lift");
                let g = GeometryPlanar { pts, lift };
                let mut t = Triangulation::<3>::new(&g, [a, b, cc], n, 2 * n + 8);
                for &i in &order {
                    if i != a && i != b && i != cc {
                        t.insert(&g, i).map_err(|l| ComplexError::TooManyCells { limit: l.0 })?;
                    }
                }
                c.build_2d(&t);
            }
            Some(di) => {
                let d = order[di];
                let g = Geometry3 { pts };
                let mut t = Triangulation::<4>::new(&g, [a, b, cc, d], n, 7 * n + 16);
                for &i in &order {
                    if i != a && i != b && i != cc && i != d {
                        t.insert(&g, i).map_err(|l| ComplexError::TooManyCells { limit: l.0 })?;
                    }
                }
                c.build_3d(&t);
            }
        }
        Ok(c)
    }

    fn build_1d(&mut self) {
        self.dim = 1;
        let pts = &self.points;
        let (p0, p1) = (&pts[0], &pts[1]);
        let k = (0..3).max_by(|&i, &j| (p0[i] - p1[i]).abs().total_cmp(&(p0[j] - p1[j]).abs())).unwrap_or(0);
        let mut idx: Vec<u32> = (0..pts.len() as u32).collect();
        idx.sort_by(|&i, &j| pts[i as usize][k].total_cmp(&pts[j as usize][k]));
        let mut edges: Vec<[u32; 2]> = idx.windows(2).map(|w| [w[0].min(w[1]), w[0].max(w[1])]).collect();
        edges.sort_unstable();
        self.edges = edges;
    }

    fn build_2d(&mut self, t: &Triangulation<3>) {
        self.dim = 2;
        let cell_to_tri = number_finite_cells(t);
        self.triangles =
            (0..t.cells.len()).filter(|&c| cell_to_tri[c] != OUTSIDE).map(|c| t.cells[c].v).collect();
        let nt = self.triangles.len();
        // Every edge is a facet: number them from the finite side with the smaller id.
        let mut raw: Vec<([u32; 2], u32, u32)> = Vec::with_capacity(nt * 3 / 2 + 8);
        let mut tri_edges = vec![[u32::MAX; 3]; nt];
        for (c, &tid) in cell_to_tri.iter().enumerate() {
            if tid == OUTSIDE {
                continue;
            }
            for i in 0..3 {
                let nb = link_cell(t.cells[c].n[i]) as usize;
                let other = cell_to_tri[nb];
                if other == OUTSIDE || tid < other {
                    let v = t.cells[c].v;
                    let (x, y) = match i {
                        0 => (v[1], v[2]),
                        1 => (v[0], v[2]),
                        _ => (v[0], v[1]),
                    };
                    raw.push(([x.min(y), x.max(y)], tid, other));
                }
            }
        }
        raw.sort_unstable_by_key(|r| r.0);
        self.edges = raw.iter().map(|r| r.0).collect();
        self.edge_cofaces = raw.iter().map(|r| [r.1, r.2]).collect();
        for (e, r) in raw.iter().enumerate() {
            for &tid in &[r.1, r.2] {
                if tid == OUTSIDE {
                    continue;
                }
                let v = self.triangles[tid as usize];
                let i = (0..3).find(|&i| !r.0.contains(&v[i])).expect("edge of its triangle");
                tri_edges[tid as usize][i] = e as u32;
            }
        }
        self.tri_edges = tri_edges;
    }

    fn build_3d(&mut self, t: &Triangulation<4>) {
        self.dim = 3;
        let cell_to_tet = number_finite_cells(t);
        self.tets = (0..t.cells.len()).filter(|&c| cell_to_tet[c] != OUTSIDE).map(|c| t.cells[c].v).collect();
        let ntet = self.tets.len();
        let mut tet_tris = vec![[u32::MAX; 4]; ntet];
        let mut triangles = Vec::with_capacity(2 * ntet + 8);
        let mut tri_cofaces = Vec::with_capacity(2 * ntet + 8);
        for (c, &a) in cell_to_tet.iter().enumerate() {
            if a == OUTSIDE {
                continue;
            }
            for i in 0..4 {
                let nb = link_cell(t.cells[c].n[i]) as usize;
                let b = cell_to_tet[nb];
                if b == OUTSIDE || a < b {
                    let tid = triangles.len() as u32;
                    let v = t.cells[c].v;
                    let mut f = [0u32; 3];
                    let mut k = 0;
                    for (s, &x) in v.iter().enumerate() {
                        if s != i {
                            f[k] = x;
                            k += 1;
                        }
                    }
                    triangles.push(f);
                    tri_cofaces.push([a, b]);
                    tet_tris[a as usize][i] = tid;
                    if b != OUTSIDE {
                        let j = link_mirror(t.cells[c].n[i]);
                        tet_tris[b as usize][j] = tid;
                    }
                }
            }
        }
        self.triangles = triangles;
        self.tri_cofaces = tri_cofaces;
        self.tet_tris = tet_tris;
        self.enumerate_edges_from_triangles();
    }

    /// Numbers the edges of all triangles (CSR by smaller vertex) and fills `tri_edges`.
    fn enumerate_edges_from_triangles(&mut self) {
        let n = self.points.len();
        let mut start = vec![0u32; n + 1];
        for t in &self.triangles {
            for i in 0..3 {
                let (x, y) = tri_edge(t, i);
                start[x.min(y) as usize + 1] += 1;
            }
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        // (other vertex, triangle * 3 + local index)
        let mut slots = vec![(0u32, 0u32); start[n] as usize];
        for (tid, t) in self.triangles.iter().enumerate() {
            for i in 0..3 {
                let (x, y) = tri_edge(t, i);
                let lo = x.min(y) as usize;
                slots[fill[lo] as usize] = (x.max(y), (tid * 3 + i) as u32);
                fill[lo] += 1;
            }
        }
        let mut tri_edges = vec![[u32::MAX; 3]; self.triangles.len()];
        let mut edges = Vec::with_capacity(start[n] as usize / 3);
        // Edge id of (v, w) for the current v, valid while owner[w] == v: no sorting needed.
        let mut owner = vec![u32::MAX; n];
        let mut id_of = vec![0u32; n];
        for v in 0..n {
            for &(w, r) in &slots[start[v] as usize..start[v + 1] as usize] {
                if owner[w as usize] != v as u32 {
                    owner[w as usize] = v as u32;
                    id_of[w as usize] = edges.len() as u32;
                    edges.push([v as u32, w]);
                }
                tri_edges[(r / 3) as usize][(r % 3) as usize] = id_of[w as usize];
            }
        }
        self.edges = edges;
        self.tri_edges = tri_edges;
    }

    /// Number of simplices per dimension (vertices, edges, triangles, tetrahedra).
    pub fn simplex_counts(&self) -> [usize; 4] {
        let v = if self.dim == 0 { self.points.len().min(1) } else { self.points.len() };
        [v, self.edges.len(), self.triangles.len(), self.tets.len()]
    }
}

/// The edge of triangle `t` opposite its vertex `i`.
#[inline]
fn tri_edge(t: &[u32; 3], i: usize) -> (u32, u32) {
    match i {
        0 => (t[1], t[2]),
        1 => (t[0], t[2]),
        _ => (t[0], t[1]),
    }
}

fn number_finite_cells<const K: usize>(t: &Triangulation<K>) -> Vec<u32> {
    let mut next = 0u32;
    (0..t.cells.len())
        .map(|c| {
            if t.is_alive(c) && !t.cells[c].v.contains(&INFINITE) {
                next += 1;
                next - 1
            } else {
                OUTSIDE
            }
        })
        .collect()
}

/// Exact collinearity of three points (all three coordinate projections degenerate).
fn collinear(a: &Point, b: &Point, c: &Point) -> bool {
    let o = |i: usize, j: usize| {
        robust::orient2d(
            robust::Coord { x: a[i], y: a[j] },
            robust::Coord { x: b[i], y: b[j] },
            robust::Coord { x: c[i], y: c[j] },
        )
    };
    o(0, 1) == 0.0 && o(1, 2) == 0.0 && o(0, 2) == 0.0
}

/// Removes exact duplicates (`-0.0 == 0.0`), keeping first occurrences in input order.
fn dedup(input: &[Point]) -> Result<(Vec<Point>, Vec<u32>), ComplexError> {
    let mut seen: HashMap<[u64; 3], ()> = HashMap::with_capacity(input.len());
    let mut points = Vec::with_capacity(input.len());
    let mut index = Vec::with_capacity(input.len());
    for (i, p) in input.iter().enumerate() {
        if !p.iter().all(|x| x.is_finite()) {
            return Err(ComplexError::NonFinite { index: i, x: p[0], y: p[1], z: p[2] });
        }
        let key = p.map(|x| (x + 0.0).to_bits());
        if seen.insert(key, ()).is_none() {
            points.push(p.map(|x| x + 0.0));
            index.push(i as u32);
        }
    }
    Ok((points, index))
}
