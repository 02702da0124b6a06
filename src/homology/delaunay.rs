//! Incremental Delaunay triangulation (Bowyer–Watson) of points whose affine hull has
//! dimension 2 or 3, with an infinite vertex and exact predicates.
//!
//! Owns: the cell/neighbour arrays, point location by a stochastic visibility walk, cavity
//! search and re-triangulation. Does not own: deduplication, the choice of dimension and the
//! insertion order (see [`super::triangulate`]), nor anything about filtrations.
//!
//! Cells are `[u32; K]` vertex arrays (K = 4 tetrahedra, K = 3 triangles) in flat vectors;
//! neighbour `i` of a cell is the cell across the facet opposite vertex `i`. Every cell is
//! positively oriented; a cell holding [`INFINITE`] is positive when the infinite vertex,
//! replaced by a point beyond its hull facet, gives a positive orientation.
//!
//! Degeneracies: a point is in conflict with a cell only if it lies *strictly* inside the
//! circumsphere (for an infinite cell: strictly beyond the hull facet, or on its plane and
//! strictly inside its circumcircle / segment). With exact predicates the cavity is then
//! always star-shaped, so co-spherical and co-planar inputs yield a valid (one of several)
//! Delaunay triangulation without symbolic perturbation; the alpha diagram does not depend on
//! which one.

use super::exact::Point;

/// The infinite vertex.
pub const INFINITE: u32 = u32::MAX;
const NO_CELL: u32 = u32::MAX;

/// Predicates over the input points for cells of `K` vertices.
pub trait Geometry<const K: usize> {
    /// Sign of the orientation of a finite cell (> 0 positive).
    fn orient(&self, v: &[u32; K]) -> f64;
    /// Whether `p` lies strictly inside the circumsphere of the positive finite cell `v`.
    fn in_sphere(&self, v: &[u32; K], p: u32) -> bool;
    /// Whether `p` lies on the plane (line) of the finite facet `f` and strictly inside its
    /// circumcircle (the open segment).
    fn in_degenerate_facet(&self, f: &[u32], p: u32) -> bool;
}

/// A Delaunay triangulation with cells of `K` vertices.
pub struct Triangulation<const K: usize> {
    /// Vertices of every cell slot (free slots included).
    pub verts: Vec<[u32; K]>,
    /// Neighbours of every cell slot.
    pub nbrs: Vec<[u32; K]>,
    alive: Vec<bool>,
    free: Vec<u32>,
    // Scratch state kept across insertions to avoid allocation.
    conflict_stamp: Vec<u32>,
    seen_stamp: Vec<u32>,
    stamp: u32,
    stack: Vec<u32>,
    cavity: Vec<u32>,
    boundary: Vec<BoundaryFacet<K>>,
    ridges: Vec<(u64, u32, u8)>,
    rng: u64,
    hint: u32,
}

struct BoundaryFacet<const K: usize> {
    verts: [u32; K],
    slot: u8,
    outside: u32,
    outside_slot: u8,
}

impl<const K: usize> Triangulation<K> {
    /// Starts a triangulation with the positive simplex `first` and its `K` infinite cells.
    pub fn new<G: Geometry<K>>(g: &G, mut first: [u32; K], capacity: usize) -> Self {
        if g.orient(&first) < 0.0 {
            first.swap(0, 1);
        }
        let mut t = Triangulation {
            verts: Vec::with_capacity(capacity),
            nbrs: Vec::with_capacity(capacity),
            alive: Vec::with_capacity(capacity),
            free: Vec::new(),
            conflict_stamp: Vec::with_capacity(capacity),
            seen_stamp: Vec::with_capacity(capacity),
            stamp: 0,
            stack: Vec::new(),
            cavity: Vec::new(),
            boundary: Vec::new(),
            ridges: Vec::new(),
            rng: 0x9E37_79B9_7F4A_7C15,
            hint: 0,
        };
        t.push_cell(first);
        for i in 0..K {
            let mut v = first;
            v[i] = INFINITE;
            // Flip orientation: the infinite vertex lies on the other side of facet i.
            let (j, k) = other_two::<K>(i);
            v.swap(j, k);
            t.push_cell(v);
        }
        // Link the K + 1 initial cells: two cells are neighbours iff they share K - 1 vertices.
        for a in 0..=K {
            for b in 0..=K {
                if a == b {
                    continue;
                }
                let va = t.verts[a];
                let vb = t.verts[b];
                let missing: Vec<usize> = (0..K).filter(|&s| !vb.contains(&va[s])).collect();
                if missing.len() == 1 {
                    t.nbrs[a][missing[0]] = b as u32;
                }
            }
        }
        t
    }

    fn push_cell(&mut self, v: [u32; K]) -> u32 {
        if let Some(c) = self.free.pop() {
            self.verts[c as usize] = v;
            self.nbrs[c as usize] = [NO_CELL; K];
            self.alive[c as usize] = true;
            c
        } else {
            self.verts.push(v);
            self.nbrs.push([NO_CELL; K]);
            self.alive.push(true);
            self.conflict_stamp.push(0);
            self.seen_stamp.push(0);
            (self.verts.len() - 1) as u32
        }
    }

    /// Whether cell slot `c` holds a live cell.
    pub fn is_alive(&self, c: usize) -> bool {
        self.alive[c]
    }

    /// Whether cell `c` has the infinite vertex.
    #[inline]
    pub fn is_infinite(&self, c: u32) -> bool {
        self.verts[c as usize].contains(&INFINITE)
    }

    #[inline]
    fn next_random(&mut self) -> u64 {
        // xorshift64*: deterministic, only steers the walk.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Finds a cell in conflict with `p`: the finite cell containing it, or an infinite cell
    /// whose hull facet `p` lies strictly beyond.
    fn locate<G: Geometry<K>>(&mut self, g: &G, p: u32) -> u32 {
        let mut c = self.hint;
        if !self.alive[c as usize] || self.is_infinite(c) {
            c = (0..self.verts.len() as u32)
                .find(|&x| self.alive[x as usize] && !self.is_infinite(x))
                .expect("a triangulation always has a finite cell");
        }
        'walk: loop {
            let off = (self.next_random() % K as u64) as usize;
            for k in 0..K {
                let i = (off + k) % K;
                let mut v = self.verts[c as usize];
                v[i] = p;
                if g.orient(&v) < 0.0 {
                    let n = self.nbrs[c as usize][i];
                    if self.is_infinite(n) {
                        return n;
                    }
                    c = n;
                    continue 'walk;
                }
            }
            return c;
        }
    }

    fn in_conflict<G: Geometry<K>>(&self, g: &G, c: u32, p: u32) -> bool {
        let v = &self.verts[c as usize];
        match v.iter().position(|&x| x == INFINITE) {
            None => g.in_sphere(v, p),
            Some(s) => {
                let mut w = *v;
                w[s] = p;
                let o = g.orient(&w);
                if o != 0.0 {
                    return o > 0.0;
                }
                let mut facet = [0u32; 3];
                let mut n = 0;
                for (k, &x) in v.iter().enumerate() {
                    if k != s {
                        facet[n] = x;
                        n += 1;
                    }
                }
                g.in_degenerate_facet(&facet[..n], p)
            }
        }
    }

    /// Inserts point `p` (not a duplicate of an inserted point).
    pub fn insert<G: Geometry<K>>(&mut self, g: &G, p: u32) {
        let start = self.locate(g, p);
        self.stamp += 1;
        let stamp = self.stamp;
        self.stack.clear();
        self.cavity.clear();
        self.boundary.clear();
        self.stack.push(start);
        self.conflict_stamp[start as usize] = stamp;
        while let Some(c) = self.stack.pop() {
            self.cavity.push(c);
            for i in 0..K {
                let n = self.nbrs[c as usize][i];
                if self.conflict_stamp[n as usize] == stamp {
                    continue;
                }
                let known_outside = self.seen_stamp[n as usize] == stamp;
                if !known_outside && self.in_conflict(g, n, p) {
                    self.conflict_stamp[n as usize] = stamp;
                    self.stack.push(n);
                } else {
                    self.seen_stamp[n as usize] = stamp;
                    let outside_slot = self.nbrs[n as usize].iter().position(|&x| x == c).expect("symmetric");
                    let mut v = self.verts[c as usize];
                    v[i] = p;
                    self.boundary.push(BoundaryFacet {
                        verts: v,
                        slot: i as u8,
                        outside: n,
                        outside_slot: outside_slot as u8,
                    });
                }
            }
        }
        for &c in &self.cavity {
            self.alive[c as usize] = false;
            self.free.push(c);
        }
        self.ridges.clear();
        let boundary = std::mem::take(&mut self.boundary);
        let mut last_finite = NO_CELL;
        for f in &boundary {
            let nc = self.push_cell(f.verts);
            let i = f.slot as usize;
            self.nbrs[nc as usize][i] = f.outside;
            self.nbrs[f.outside as usize][f.outside_slot as usize] = nc;
            if !f.verts.contains(&INFINITE) {
                last_finite = nc;
            }
            for j in 0..K {
                if j != i {
                    self.ridges.push((ridge_key(&f.verts, i, j), nc, j as u8));
                }
            }
        }
        self.boundary = boundary;
        self.ridges.sort_unstable_by_key(|r| r.0);
        for pair in self.ridges.chunks_exact(2) {
            debug_assert_eq!(pair[0].0, pair[1].0, "cavity boundary must be a closed manifold");
            self.nbrs[pair[0].1 as usize][pair[0].2 as usize] = pair[1].1;
            self.nbrs[pair[1].1 as usize][pair[1].2 as usize] = pair[0].1;
        }
        if last_finite != NO_CELL {
            self.hint = last_finite;
        }
    }
}

/// The two slots other than `i` used to flip an orientation (K = 3 or 4).
fn other_two<const K: usize>(i: usize) -> (usize, usize) {
    let mut o = (0..K).filter(|&s| s != i);
    (o.next().unwrap_or(0), o.next().unwrap_or(0))
}

/// Key of the ridge of cell `v` opposite slots `i` and `j` (K - 2 vertices, sorted).
#[inline]
fn ridge_key<const K: usize>(v: &[u32; K], i: usize, j: usize) -> u64 {
    let mut r = [0u32; 2];
    let mut n = 0;
    for (k, &x) in v.iter().enumerate() {
        if k != i && k != j {
            r[n] = x;
            n += 1;
        }
    }
    if n == 1 {
        r[0] as u64
    } else {
        let (a, b) = if r[0] < r[1] { (r[0], r[1]) } else { (r[1], r[0]) };
        ((a as u64) << 32) | b as u64
    }
}

/// Predicates for a full-dimensional point set in R³.
pub struct Geometry3<'a> {
    /// The points.
    pub pts: &'a [Point],
}

#[inline]
fn c3(p: &Point) -> robust::Coord3D<f64> {
    robust::Coord3D { x: p[0], y: p[1], z: p[2] }
}

impl Geometry<4> for Geometry3<'_> {
    #[inline]
    fn orient(&self, v: &[u32; 4]) -> f64 {
        let p = self.pts;
        robust::orient3d(
            c3(&p[v[0] as usize]),
            c3(&p[v[1] as usize]),
            c3(&p[v[2] as usize]),
            c3(&p[v[3] as usize]),
        )
    }
    #[inline]
    fn in_sphere(&self, v: &[u32; 4], q: u32) -> bool {
        let p = self.pts;
        robust::insphere(
            c3(&p[v[0] as usize]),
            c3(&p[v[1] as usize]),
            c3(&p[v[2] as usize]),
            c3(&p[v[3] as usize]),
            c3(&p[q as usize]),
        ) > 0.0
    }
    fn in_degenerate_facet(&self, f: &[u32], q: u32) -> bool {
        let p = self.pts;
        let (a, b, c) = (&p[f[0] as usize], &p[f[1] as usize], &p[f[2] as usize]);
        match lift_point(a, b, c) {
            Some(e) => in_circle_coplanar(a, b, c, &e, &p[q as usize]),
            None => false,
        }
    }
}

/// A point off the plane of `a b c` (which must not be collinear).
fn lift_point(a: &Point, b: &Point, c: &Point) -> Option<Point> {
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&i, &j| n[j].abs().total_cmp(&n[i].abs()));
    for k in axes {
        let mut e = *a;
        e[k] += a[k].abs().max(1.0);
        if robust::orient3d(c3(a), c3(b), c3(c), c3(&e)) != 0.0 {
            return Some(e);
        }
    }
    None
}

/// Whether `q`, co-planar with `a b c`, lies strictly inside their circumcircle. `e` is any
/// point off the plane: the sphere through `a b c e` cuts the plane in that circle.
#[inline]
fn in_circle_coplanar(a: &Point, b: &Point, c: &Point, e: &Point, q: &Point) -> bool {
    let o = robust::orient3d(c3(a), c3(b), c3(c), c3(e));
    let s = robust::insphere(c3(a), c3(b), c3(c), c3(e), c3(q));
    if o > 0.0 { s > 0.0 } else { s < 0.0 }
}

/// Predicates for co-planar points in R³ (a 2-dimensional triangulation in their plane).
pub struct GeometryPlanar<'a> {
    /// The points (all on one plane).
    pub pts: &'a [Point],
    /// A point off that plane; orientation and in-circle tests are taken relative to it.
    pub lift: Point,
}

impl Geometry<3> for GeometryPlanar<'_> {
    #[inline]
    fn orient(&self, v: &[u32; 3]) -> f64 {
        let p = self.pts;
        robust::orient3d(c3(&p[v[0] as usize]), c3(&p[v[1] as usize]), c3(&p[v[2] as usize]), c3(&self.lift))
    }
    #[inline]
    fn in_sphere(&self, v: &[u32; 3], q: u32) -> bool {
        let p = self.pts;
        in_circle_coplanar(
            &p[v[0] as usize],
            &p[v[1] as usize],
            &p[v[2] as usize],
            &self.lift,
            &p[q as usize],
        )
    }
    fn in_degenerate_facet(&self, f: &[u32], q: u32) -> bool {
        // `q` is on the line of the hull edge f: in conflict iff strictly between its ends.
        let p = self.pts;
        let (a, b, q) = (&p[f[0] as usize], &p[f[1] as usize], &p[q as usize]);
        let k = (0..3).max_by(|&i, &j| (a[i] - b[i]).abs().total_cmp(&(a[j] - b[j]).abs())).unwrap_or(0);
        let (lo, hi) = if a[k] < b[k] { (a[k], b[k]) } else { (b[k], a[k]) };
        lo < q[k] && q[k] < hi
    }
}

/// Lift point for a co-planar set whose plane passes through the non-collinear `a b c`.
pub fn planar_lift(a: &Point, b: &Point, c: &Point) -> Option<Point> {
    lift_point(a, b, c)
}
