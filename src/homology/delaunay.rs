//! Incremental Delaunay triangulation (Bowyer–Watson) of points whose affine hull has
//! dimension 2 or 3, with an infinite vertex and exact predicates.
//!
//! Owns: the cell/neighbour arrays, point location by a stochastic visibility walk, cavity
//! search and re-triangulation. Does not own: deduplication, the choice of dimension and the
//! insertion order (see [`super::complex::DelaunayComplex::new`]), nor anything about filtrations.
//!
//! Cells are `[u32; K]` vertex arrays (K = 4 tetrahedra, K = 3 triangles) in flat vectors;
//! neighbour `i` of a cell is the cell across the facet opposite vertex `i`. Every cell is
//! positively oriented; a cell holding `INFINITE` is positive when the infinite vertex,
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
pub(crate) const INFINITE: u32 = u32::MAX;
const NO_CELL: u32 = u32::MAX;

/// Predicates over the input points for cells of `K` vertices.
pub(crate) trait Geometry<const K: usize> {
    /// Sign of the orientation of a finite cell (> 0 positive).
    fn orient(&self, v: &[u32; K]) -> f64;
    /// Whether `p` lies strictly inside the circumsphere of the positive finite cell `v`.
    fn in_sphere(&self, v: &[u32; K], p: u32) -> bool;
    /// Whether `p` lies on the plane (line) of the finite facet `f` and strictly inside its
    /// circumcircle (the open segment).
    fn in_degenerate_facet(&self, f: &[u32], p: u32) -> bool;
}

/// One cell: its vertices and its neighbours (`n[i]` across the facet opposite `v[i]`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cell<const K: usize> {
    /// Vertices ([`INFINITE`] for the infinite vertex; `v[0] == DEAD` for a free slot).
    pub v: [u32; K],
    /// Neighbour links, `cell << 2 | mirror` (see [`link`]): the neighbour and the slot of the
    /// shared facet in it, so that crossing a facet never searches for the way back.
    pub n: [u32; K],
}

/// A neighbour link: cell `c`, whose facet opposite slot `mirror` is the shared one.
#[inline]
pub fn link(c: u32, mirror: usize) -> u32 {
    c << 2 | mirror as u32
}

/// The cell of a neighbour link.
#[inline]
pub(crate) fn link_cell(l: u32) -> u32 {
    l >> 2
}

/// The mirror slot of a neighbour link.
#[inline]
pub(crate) fn link_mirror(l: u32) -> usize {
    (l & 3) as usize
}

const DEAD: u32 = u32::MAX - 1;

/// A Delaunay triangulation with cells of `K` vertices.
pub(crate) struct Triangulation<const K: usize> {
    /// Every cell slot (free slots included, see [`Triangulation::is_alive`]).
    pub cells: Vec<Cell<K>>,
    free: Vec<u32>,
    // Per-cell visit mark of the current insertion: 2·stamp = in conflict,
    // 2·stamp + 1 = tested, not in conflict.
    mark: Vec<u32>,
    stamp: u32,
    stack: Vec<u32>,
    cavity: Vec<u32>,
    boundary: Vec<BoundaryFacet<K>>,
    locals: LocalIds,
    local_ridges: Vec<u64>,
    ridges: RidgeTable,
    rng: u64,
    hint: u32,
    /// Most cells the triangulation may hold ([`MAX_CELLS`]).
    max_cells: usize,
}

/// Most cells of a triangulation: links keep a cell id in 30 bits.
pub(crate) const MAX_CELLS: usize = 1 << 30;

/// A triangulation that would need more than its cell limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CellLimit(pub usize);

struct BoundaryFacet<const K: usize> {
    verts: [u32; K],
    /// Cavity-local ids of `verts` (see [`LocalIds`]); the slot of the new point unused.
    local: [u8; K],
    slot: u8,
    outside: u32,
    outside_slot: u8,
}

impl<const K: usize> Triangulation<K> {
    /// Starts a triangulation of vertices `0..vertices` with the positive simplex `first`
    /// and its `K` infinite cells.
    pub(crate) fn new<G: Geometry<K>>(g: &G, mut first: [u32; K], vertices: usize, capacity: usize) -> Self {
        if g.orient(&first) < 0.0 {
            first.swap(0, 1);
        }
        let mut t = Triangulation {
            cells: Vec::with_capacity(capacity),
            free: Vec::new(),
            mark: Vec::with_capacity(capacity),
            stamp: 0,
            stack: Vec::new(),
            cavity: Vec::new(),
            boundary: Vec::new(),
            locals: LocalIds::new(vertices),
            local_ridges: vec![0; LOCAL_IDS * LOCAL_IDS],
            ridges: RidgeTable::new(),
            rng: 0x9E37_79B9_7F4A_7C15,
            hint: 0,
            max_cells: crate::fault::cell_limit(MAX_CELLS),
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
                let va = t.cells[a].v;
                let vb = t.cells[b].v;
                let missing: Vec<usize> = (0..K).filter(|&s| !vb.contains(&va[s])).collect();
                let mirror: Vec<usize> = (0..K).filter(|&s| !va.contains(&vb[s])).collect();
                if missing.len() == 1 {
                    t.cells[a].n[missing[0]] = link(b as u32, mirror[0]);
                }
            }
        }
        t
    }

    fn push_cell(&mut self, v: [u32; K]) -> u32 {
        let cell = Cell { v, n: [NO_CELL; K] };
        if let Some(c) = self.free.pop() {
            self.cells[c as usize] = cell;
            c
        } else {
            // `insert` has checked the limit ([`MAX_CELLS`]: links keep a cell id in 30 bits).
            self.cells.push(cell);
            self.mark.push(0);
            (self.cells.len() - 1) as u32
        }
    }

    /// Whether cell slot `c` holds a live cell.
    pub(crate) fn is_alive(&self, c: usize) -> bool {
        self.cells[c].v[0] != DEAD
    }

    /// Whether cell `c` has the infinite vertex.
    #[inline]
    pub(crate) fn is_infinite(&self, c: u32) -> bool {
        has_infinite(&self.cells[c as usize].v)
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
        if !self.is_alive(c as usize) || self.is_infinite(c) {
            c = (0..self.cells.len() as u32)
                .find(|&x| self.is_alive(x as usize) && !self.is_infinite(x))
                .expect("a triangulation always has a finite cell");
        }
        // The facet just crossed (`came_from`) has `p` on the inner side: not tested again.
        let mut came_from = K;
        'walk: loop {
            let off = (self.next_random() % K as u64) as usize;
            for k in 0..K {
                let i = (off + k) % K;
                if i == came_from {
                    continue;
                }
                let cell = &self.cells[c as usize];
                let mut v = cell.v;
                v[i] = p;
                if g.orient(&v) < 0.0 {
                    let l = cell.n[i];
                    let n = link_cell(l);
                    if self.is_infinite(n) {
                        return n;
                    }
                    c = n;
                    came_from = link_mirror(l);
                    continue 'walk;
                }
            }
            return c;
        }
    }

    fn in_conflict<G: Geometry<K>>(&self, g: &G, c: u32, p: u32) -> bool {
        let v = &self.cells[c as usize].v;
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

    /// Inserts point `p` (not a duplicate of an inserted point). Fails, leaving the
    /// triangulation unusable, when it would need more cells than its limit.
    pub(crate) fn insert<G: Geometry<K>>(&mut self, g: &G, p: u32) -> Result<(), CellLimit> {
        let start = self.locate(g, p);
        self.stamp += 1;
        let (conflict, outside) = (2 * self.stamp, 2 * self.stamp + 1);
        self.stack.clear();
        self.cavity.clear();
        self.boundary.clear();
        self.stack.push(start);
        self.mark[start as usize] = conflict;
        while let Some(c) = self.stack.pop() {
            self.cavity.push(c);
            let cell = self.cells[c as usize];
            for i in 0..K {
                let n = link_cell(cell.n[i]);
                let m = self.mark[n as usize];
                if m == conflict {
                    continue;
                }
                if m != outside && self.in_conflict(g, n, p) {
                    self.mark[n as usize] = conflict;
                    self.stack.push(n);
                } else {
                    self.mark[n as usize] = outside;
                    let outside_slot = link_mirror(cell.n[i]);
                    let mut v = cell.v;
                    v[i] = p;
                    self.boundary.push(BoundaryFacet {
                        verts: v,
                        local: [0; K],
                        slot: i as u8,
                        outside: n,
                        outside_slot: outside_slot as u8,
                    });
                }
            }
        }
        for &c in &self.cavity {
            self.cells[c as usize].v[0] = DEAD;
            self.free.push(c);
        }
        // The new cells fit in the freed slots and the room left below the limit?
        if self.boundary.len() > self.free.len() + self.max_cells.saturating_sub(self.cells.len()) {
            return Err(CellLimit(self.max_cells));
        }
        // Each ridge of the cavity boundary is shared by exactly two new cells. Ridges are
        // matched in a small table indexed by cavity-local vertex ids (a cavity has ~15
        // boundary vertices); a huge cavity (co-spherical input) falls back to hashing.
        let mut boundary = std::mem::take(&mut self.boundary);
        let local = self.locals.assign(&mut boundary);
        let tag = (self.locals.stamp as u64) << 34;
        if !local {
            self.ridges.clear();
        }
        let mut last_finite = NO_CELL;
        for f in &boundary {
            let nc = self.push_cell(f.verts);
            let i = f.slot as usize;
            self.cells[nc as usize].n[i] = link(f.outside, f.outside_slot as usize);
            self.cells[f.outside as usize].n[f.outside_slot as usize] = link(nc, i);
            if !has_infinite(&f.verts) {
                last_finite = nc;
            }
            for j in 0..K {
                if j == i {
                    continue;
                }
                let matched = if local {
                    let e = &mut self.local_ridges[local_ridge_index(&f.local, i, j)];
                    if *e >> 34 == tag >> 34 {
                        let found = (*e as u32, ((*e >> 32) & 3) as u8);
                        *e = 0;
                        Some(found)
                    } else {
                        *e = tag | (j as u64) << 32 | nc as u64;
                        None
                    }
                } else {
                    self.ridges.take_or_insert(ridge_key(&f.verts, i, j), nc, j as u8)
                };
                if let Some((other, oj)) = matched {
                    self.cells[nc as usize].n[j] = link(other, oj as usize);
                    self.cells[other as usize].n[oj as usize] = link(nc, j);
                }
            }
        }
        self.boundary = boundary;
        if last_finite != NO_CELL {
            self.hint = last_finite;
        }
        Ok(())
    }
}

/// Whether a cell holds the infinite vertex (branch-free: the walk asks this at every step).
#[inline]
pub(crate) fn has_infinite<const K: usize>(v: &[u32; K]) -> bool {
    v.iter().fold(false, |any, &x| any | (x == INFINITE))
}

/// Cavity-local vertex ids fit in a byte-sized table side.
const LOCAL_IDS: usize = 64;

/// Numbers the vertices of one cavity boundary `0..LOCAL_IDS` (per-vertex stamps, so no
/// clearing between insertions).
struct LocalIds {
    tag: Vec<u32>,
    id: Vec<u8>,
    infinite_tag: u32,
    infinite_id: u8,
    /// Current insertion; below 2^30 (32-bit cell ids and 2-bit slots share the u64 entry).
    stamp: u32,
}

impl LocalIds {
    fn new(vertices: usize) -> Self {
        LocalIds { tag: vec![0; vertices], id: vec![0; vertices], infinite_tag: 0, infinite_id: 0, stamp: 0 }
    }

    /// Gives every boundary vertex (the new point's slot excepted) a local id; false when
    /// the boundary has more than [`LOCAL_IDS`] vertices.
    fn assign<const K: usize>(&mut self, boundary: &mut [BoundaryFacet<K>]) -> bool {
        self.stamp += 1;
        let stamp = self.stamp;
        let mut next = 0usize;
        for f in boundary.iter_mut() {
            for k in 0..K {
                if k == f.slot as usize {
                    continue;
                }
                let v = f.verts[k];
                let (tag, id) = if v == INFINITE {
                    (&mut self.infinite_tag, &mut self.infinite_id)
                } else {
                    (&mut self.tag[v as usize], &mut self.id[v as usize])
                };
                if *tag != stamp {
                    if next == LOCAL_IDS {
                        return false;
                    }
                    *tag = stamp;
                    *id = next as u8;
                    next += 1;
                }
                f.local[k] = *id;
            }
        }
        true
    }
}

/// Table index of the ridge of a new cell opposite slots `i` and `j`, from local ids.
#[inline]
fn local_ridge_index<const K: usize>(local: &[u8; K], i: usize, j: usize) -> usize {
    let mut r = [0usize; 2];
    let mut n = 0;
    for (k, &x) in local.iter().enumerate() {
        if k != i && k != j {
            r[n] = x as usize;
            n += 1;
        }
    }
    if n == 1 { r[0] } else { r[0].min(r[1]) * LOCAL_IDS + r[0].max(r[1]) }
}

/// Open-addressing table matching the ridges of new cells during one insertion; cleared in
/// O(1) by a generation stamp.
struct RidgeTable {
    slots: Vec<(u64, u32, u32, u8)>,
    generation: u32,
    len: usize,
}

impl RidgeTable {
    fn new() -> Self {
        RidgeTable { slots: vec![(0, 0, 0, 0); 256], generation: 1, len: 0 }
    }
    fn clear(&mut self) {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.slots.iter_mut().for_each(|s| s.2 = 0);
            self.generation = 1;
        }
        self.len = 0;
    }
    /// Returns the cell already waiting on `key` (and removes it), or stores `(cell, slot)`.
    #[inline]
    fn take_or_insert(&mut self, key: u64, cell: u32, slot: u8) -> Option<(u32, u8)> {
        if 2 * (self.len + 1) > self.slots.len() {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut h = (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize & mask;
        loop {
            let s = &mut self.slots[h];
            if s.2 != self.generation {
                *s = (key, cell, self.generation, slot);
                self.len += 1;
                return None;
            }
            if s.0 == key && s.1 != u32::MAX {
                let found = (s.1, s.3);
                s.1 = u32::MAX; // tombstone: matched
                return Some(found);
            }
            h = (h + 1) & mask;
        }
    }
    fn grow(&mut self) {
        let live: Vec<_> =
            self.slots.iter().filter(|s| s.2 == self.generation && s.1 != u32::MAX).copied().collect();
        let n = self.slots.len() * 2;
        self.slots = vec![(0, 0, 0, 0); n];
        self.generation = 1;
        self.len = 0;
        for (k, c, _, sl) in live {
            self.take_or_insert(k, c, sl);
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
pub(crate) struct Geometry3<'a> {
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
        orient3d(&p[v[0] as usize], &p[v[1] as usize], &p[v[2] as usize], &p[v[3] as usize])
    }
    #[inline]
    fn in_sphere(&self, v: &[u32; 4], q: u32) -> bool {
        let p = self.pts;
        insphere(&p[v[0] as usize], &p[v[1] as usize], &p[v[2] as usize], &p[v[3] as usize], &p[q as usize])
            > 0.0
    }
    fn in_degenerate_facet(&self, f: &[u32], q: u32) -> bool {
        let p = self.pts;
        let (a, b, c) = (&p[f[0] as usize], &p[f[1] as usize], &p[f[2] as usize]);
        match planar_lift(a, b, c) {
            Some(e) => in_circle_coplanar(a, b, c, &e, &p[q as usize]),
            None => false,
        }
    }
}

// Semi-static filters: the determinant in f64 on coordinates translated to the last point,
// certified by a bound from the largest translated coordinate per axis (derived like
// Shewchuk's error bounds: (k + O(ε))ε × permanent, with the permanent bounded by the
// maxima). Out of the safe magnitude range, or within the bound, `robust` decides exactly.
const ORIENT_BOUND: f64 = 6.0e-15;
const INSPHERE_BOUND: f64 = 2.0e-13;
const SAFE_MIN: f64 = 1e-58;
const SAFE_MAX: f64 = 1e58;

/// Orientation of `a b c d` (sign as `robust::orient3d`), filtered.
#[inline]
pub fn orient3d(a: &Point, b: &Point, c: &Point, d: &Point) -> f64 {
    let (adx, ady, adz) = (a[0] - d[0], a[1] - d[1], a[2] - d[2]);
    let (bdx, bdy, bdz) = (b[0] - d[0], b[1] - d[1], b[2] - d[2]);
    let (cdx, cdy, cdz) = (c[0] - d[0], c[1] - d[1], c[2] - d[2]);
    let det = adx * (bdy * cdz - bdz * cdy) + bdx * (cdy * adz - cdz * ady) + cdx * (ady * bdz - adz * bdy);
    let mx = adx.abs().max(bdx.abs()).max(cdx.abs());
    let my = ady.abs().max(bdy.abs()).max(cdy.abs());
    let mz = adz.abs().max(bdz.abs()).max(cdz.abs());
    let lo = mx.min(my).min(mz);
    let hi = mx.max(my).max(mz);
    if lo > SAFE_MIN && hi < SAFE_MAX {
        let eps = ORIENT_BOUND * mx * my * mz;
        if det > eps || det < -eps {
            return det;
        }
    }
    orient3d_exact(a, b, c, d)
}

#[cold]
#[inline(never)]
fn orient3d_exact(a: &Point, b: &Point, c: &Point, d: &Point) -> f64 {
    robust::orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// In-sphere test of `e` against positive `a b c d` (sign as `robust::insphere`), filtered.
#[inline]
pub fn insphere(a: &Point, b: &Point, c: &Point, d: &Point, e: &Point) -> f64 {
    let t = |p: &Point| [p[0] - e[0], p[1] - e[1], p[2] - e[2]];
    let (pa, pb, pc, pd) = (t(a), t(b), t(c), t(d));
    let lift = |p: &[f64; 3]| p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    let (la, lb, lc, ld) = (lift(&pa), lift(&pb), lift(&pc), lift(&pd));
    // 2x2 minors on x, y.
    let ab = pa[0] * pb[1] - pb[0] * pa[1];
    let bc = pb[0] * pc[1] - pc[0] * pb[1];
    let cd = pc[0] * pd[1] - pd[0] * pc[1];
    let da = pd[0] * pa[1] - pa[0] * pd[1];
    let ac = pa[0] * pc[1] - pc[0] * pa[1];
    let bd = pb[0] * pd[1] - pd[0] * pb[1];
    let abc = pa[2] * bc - pb[2] * ac + pc[2] * ab;
    let bcd = pb[2] * cd - pc[2] * bd + pd[2] * bc;
    let cda = pc[2] * da + pd[2] * ac + pa[2] * cd;
    let dab = pd[2] * ab + pa[2] * bd + pb[2] * da;
    let det = (ld * abc - lc * dab) + (lb * cda - la * bcd);
    let mx = pa[0].abs().max(pb[0].abs()).max(pc[0].abs()).max(pd[0].abs());
    let my = pa[1].abs().max(pb[1].abs()).max(pc[1].abs()).max(pd[1].abs());
    let mz = pa[2].abs().max(pb[2].abs()).max(pc[2].abs()).max(pd[2].abs());
    let lo = mx.min(my).min(mz);
    let hi = mx.max(my).max(mz);
    if lo > SAFE_MIN && hi < SAFE_MAX {
        let eps = INSPHERE_BOUND * mx * my * mz * hi * hi;
        if det > eps || det < -eps {
            return det;
        }
    }
    insphere_exact(a, b, c, d, e)
}

#[cold]
#[inline(never)]
fn insphere_exact(a: &Point, b: &Point, c: &Point, d: &Point, e: &Point) -> f64 {
    robust::insphere(c3(a), c3(b), c3(c), c3(d), c3(e))
}

/// A point off the plane of `a b c` (which must not be collinear).
pub(crate) fn planar_lift(a: &Point, b: &Point, c: &Point) -> Option<Point> {
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&i, &j| n[j].abs().total_cmp(&n[i].abs()));
    for k in axes {
        let mut e = *a;
        e[k] += a[k].abs().max(1.0);
        if orient3d(a, b, c, &e) != 0.0 {
            return Some(e);
        }
    }
    None
}

/// Whether `q`, co-planar with `a b c`, lies strictly inside their circumcircle. `e` is any
/// point off the plane: the sphere through `a b c e` cuts the plane in that circle.
#[inline]
fn in_circle_coplanar(a: &Point, b: &Point, c: &Point, e: &Point, q: &Point) -> bool {
    let o = orient3d(a, b, c, e);
    let s = insphere(a, b, c, e, q);
    if o > 0.0 { s > 0.0 } else { s < 0.0 }
}

/// Predicates for co-planar points in R³ (a 2-dimensional triangulation in their plane).
pub(crate) struct GeometryPlanar<'a> {
    /// The points (all on one plane).
    pub pts: &'a [Point],
    /// A point off that plane; orientation and in-circle tests are taken relative to it.
    pub lift: Point,
}

impl Geometry<3> for GeometryPlanar<'_> {
    #[inline]
    fn orient(&self, v: &[u32; 3]) -> f64 {
        let p = self.pts;
        orient3d(&p[v[0] as usize], &p[v[1] as usize], &p[v[2] as usize], &self.lift)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Neighbour links are symmetric and neighbours share all but one vertex.
    fn assert_linked<const K: usize>(t: &Triangulation<K>) {
        for c in (0..t.cells.len()).filter(|&c| t.is_alive(c)) {
            for i in 0..K {
                let n = link_cell(t.cells[c].n[i]) as usize;
                assert!(t.is_alive(n), "cell {c} links a dead cell");
                let back = t.cells[n].n[link_mirror(t.cells[c].n[i])];
                assert_eq!(back, link(c as u32, i), "link {c} -> {n} is one-way");
                let shared = t.cells[c].v.iter().filter(|v| t.cells[n].v.contains(v)).count();
                assert_eq!(shared, K - 1);
            }
        }
    }

    #[test]
    fn a_cavity_too_large_for_local_ids_is_linked_by_hashing() {
        // Integer points on one sphere, then its centre: the centre is strictly inside every
        // cell's circumsphere (the sphere itself), so its cavity is every finite cell and its
        // boundary has all sphere points as vertices (> LOCAL_IDS). Each hull triangle then
        // makes one tetrahedron with the centre: 2V - 4 of them.
        let r2 = 425;
        let mut pts: Vec<Point> = Vec::new();
        for x in -21i32..=21 {
            for y in -21i32..=21 {
                for z in -21i32..=21 {
                    if x * x + y * y + z * z == r2 {
                        pts.push([x as f64, y as f64, z as f64]);
                    }
                }
            }
        }
        let sphere = pts.len();
        assert!(sphere > LOCAL_IDS, "{sphere} points");
        pts.push([0.0; 3]);
        let g = Geometry3 { pts: &pts };
        let d = (3..sphere).find(|&d| orient3d(&pts[0], &pts[1], &pts[2], &pts[d]) != 0.0).unwrap();
        let mut t = Triangulation::<4>::new(&g, [0, 1, 2, d as u32], pts.len(), 16);
        for i in (3..sphere).filter(|&i| i != d) {
            t.insert(&g, i as u32).expect("below the cell limit");
        }
        t.insert(&g, sphere as u32).expect("below the cell limit");
        assert_linked(&t);
        let finite = (0..t.cells.len()).filter(|&c| t.is_alive(c) && !t.is_infinite(c as u32)).count();
        assert_eq!(finite, 2 * sphere - 4);
    }
}
