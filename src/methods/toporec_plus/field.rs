//! The height field of a raw scan, its persistence (the relief of each square) and the polar
//! grid of codes: the descriptor ([`describe`]).

use super::{HEIGHT_SCALE, LEVELS, PlusParams, RELIEF};
use crate::types::Point;

/// The squares on a side of the height field: an even number, so that the sensor sits on a
/// corner and a quarter turn maps the squares onto themselves.
pub(super) fn side(p: &PlusParams) -> usize {
    2 * (p.max_radius / p.cell).ceil() as usize
}

/// Range and azimuth (degrees, [0, 360), counter-clockwise from x) of (x, y). The angle is
/// taken within the quadrant, after turning (x, y) into the first one exactly, so that a point
/// turned by a quarter turn gets the same numbers plus 90°.
pub(super) fn polar(x: f64, y: f64) -> (f64, f64) {
    let (quadrant, u, v) = if x > 0.0 && y >= 0.0 {
        (0.0, x, y)
    } else if x <= 0.0 && y > 0.0 {
        (90.0, y, -x)
    } else if x < 0.0 && y <= 0.0 {
        (180.0, -x, -y)
    } else {
        (270.0, -y, x)
    };
    (u.hypot(v), quadrant + v.atan2(u).to_degrees())
}

/// The height field of a raw scan: per square (row-major, `side` × `side`), the highest z
/// above it (NaN when none), and the filled squares.
pub(super) struct HeightField {
    side: usize,
    height: Vec<f32>,
    filled: Vec<u32>,
}

pub(super) fn height_field(points: &[Point], p: &PlusParams) -> HeightField {
    let side = side(p);
    let half = (side / 2) as f64;
    let mut height = vec![f32::NAN; side * side];
    let mut filled = Vec::new();
    for q in points {
        if !q.iter().all(|c| c.is_finite()) || q[0].hypot(q[1]) > p.max_radius {
            continue;
        }
        let (i, j) = ((q[0] / p.cell + half).floor(), (q[1] / p.cell + half).floor());
        if !(0.0..side as f64).contains(&i) || !(0.0..side as f64).contains(&j) {
            continue;
        }
        let k = i as usize * side + j as usize;
        let z = q[2] as f32;
        let h = &mut height[k];
        if h.is_nan() {
            filled.push(k as u32);
            *h = z;
        } else if z > *h {
            *h = z;
        }
    }
    HeightField { side, height, filled }
}

impl HeightField {
    /// The centre (x, y) of square `k`.
    pub(super) fn centre(&self, k: usize, cell: f64) -> (f64, f64) {
        let half = (self.side / 2) as f64;
        let (i, j) = ((k / self.side) as f64, (k % self.side) as f64);
        ((i - half + 0.5) * cell, (j - half + 0.5) * cell)
    }

    /// Each filled square's relief (in the order of `filled` sorted by height, highest first,
    /// ties by position), with the squares in that order: the superlevel-set H0 persistence,
    /// by union-find.
    pub(super) fn relief(&self) -> (Vec<u32>, Vec<f32>) {
        let side = self.side;
        // Highest first; equal heights by position. The key orders f32 totally.
        let key = |k: u32| {
            let bits = self.height[k as usize].to_bits();
            let ordered = if bits >> 31 == 1 { !bits } else { bits | 0x8000_0000 };
            ((!ordered as u64) << 32) | k as u64
        };
        let mut keys: Vec<u64> = self.filled.iter().map(|&k| key(k)).collect();
        keys.sort_unstable();
        let order: Vec<u32> = keys.iter().map(|k| *k as u32).collect();
        let n = order.len();
        // The entry rank of each square (u32::MAX: empty).
        let mut rank = vec![u32::MAX; side * side];
        for (r, &k) in order.iter().enumerate() {
            rank[k as usize] = r as u32;
        }
        // Union-find over ranks. A component's root is its highest square (its lowest rank),
        // which is the peak of the class it stands for: the elder of two is the lower root.
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let find = |parent: &mut Vec<u32>, mut a: u32| {
            while parent[a as usize] != a {
                let up = parent[parent[a as usize] as usize];
                parent[a as usize] = up;
                a = up;
            }
            a
        };
        let mut class = vec![0u32; n];
        let mut death = vec![f32::NAN; n];
        let mut roots: Vec<u32> = Vec::with_capacity(8);
        for r in 0..n {
            let k = order[r] as usize;
            let (i, j) = (k / side, k % side);
            roots.clear();
            for di in [-1i64, 0, 1] {
                for dj in [-1i64, 0, 1] {
                    let (a, b) = (i as i64 + di, j as i64 + dj);
                    if (di == 0 && dj == 0) || a < 0 || b < 0 || a >= side as i64 || b >= side as i64 {
                        continue;
                    }
                    let m = rank[a as usize * side + b as usize];
                    if m < r as u32 {
                        let root = find(&mut parent, m);
                        if !roots.contains(&root) {
                            roots.push(root);
                        }
                    }
                }
            }
            let Some(&elder) = roots.iter().min() else {
                class[r] = r as u32;
                continue;
            };
            class[r] = elder;
            parent[r] = elder;
            for &younger in roots.iter().filter(|&&root| root != elder) {
                death[younger as usize] = self.height[k];
                parent[younger as usize] = elder;
            }
        }
        let lowest = order.last().map_or(0.0, |&k| self.height[k as usize]);
        let relief = (0..n)
            .map(|r| {
                let d = death[class[r] as usize];
                self.height[order[r] as usize] - if d.is_nan() { lowest } else { d }
            })
            .collect();
        (order, relief)
    }
}

/// Where a place falls on the polar grid, given its range in rings and its azimuth in sectors
/// from the grid's origin (0 at the origin and at azimuth 0).
pub(super) struct Place {
    /// The cell it lies in: (ring, sector).
    pub(super) cell: (usize, usize),
    /// Its two nearest ring centres, with their linear weights (the same ring twice, weights
    /// 1 and 0, inside the first centre and outside the last).
    pub(super) rings: [(usize, f64); 2],
    /// Its two nearest sector centres, with their linear weights.
    pub(super) sectors: [(usize, f64); 2],
}

impl Place {
    pub(super) fn at(ring: f64, sector: f64, p: &PlusParams) -> Self {
        let (rings, sectors) = (p.rings, p.sectors);
        let u = (ring - 0.5).clamp(0.0, (rings - 1) as f64);
        let inner = (u as usize).min(rings - 1);
        let w = u - inner as f64;
        let v = sector - 0.5;
        let (first, ws) = (v.floor(), v - v.floor());
        let before = (first as i64).rem_euclid(sectors as i64) as usize;
        Place {
            cell: ((ring as usize).min(rings - 1), (sector as usize).min(sectors - 1)),
            rings: [(inner, 1.0 - w), ((inner + 1).min(rings - 1), w)],
            sectors: [(before, 1.0 - ws), ((before + 1) % sectors, ws)],
        }
    }
}

/// The code of a share of a channel's scale: its square root in 256 levels.
pub(super) fn code(share: f64) -> f32 {
    (share.min(1.0).sqrt() * LEVELS).round() as f32
}

/// The descriptor of a raw scan (sensor frame, metres, z up): `2 × rings × sectors` codes in
/// `0..=255` (`[channel][ring][sector]`, channel 0 the relief, 1 the height), then the
/// Cartesian image's `image_side²` height codes (`[x cell][y cell]`, [`super::pose`]). An error
/// for a scan with no return within `max_radius`: it has no descriptor (an error row), never a
/// zero vector.
pub fn describe(points: &[Point], p: &PlusParams) -> Result<Vec<f32>, String> {
    let field = height_field(points, p);
    if field.filled.is_empty() {
        return Err(format!("no return within {} m of the sensor", p.max_radius));
    }
    let (order, relief) = field.relief();
    let (rings, sectors) = (p.rings, p.sectors);
    let mut grid = vec![0f64; p.polar_len()];
    let sector = p.sector_degrees();
    for (&k, &r) in order.iter().zip(&relief) {
        let (x, y) = field.centre(k as usize, p.cell);
        let (range, azimuth) = polar(x, y);
        if range > p.max_radius {
            continue;
        }
        let at = Place::at(range / p.max_radius * rings as f64, azimuth / sector, p);
        // Relief: shared between the two nearest ring centres and the two nearest sector
        // centres, linearly.
        let value = r as f64;
        let [(before, w_before), (after, w_after)] = at.sectors;
        for (ring, weight) in at.rings {
            let row = &mut grid[(RELIEF * rings + ring) * sectors..(RELIEF * rings + ring + 1) * sectors];
            row[before] += weight * w_before * value;
            row[after] += weight * w_after * value;
        }
        // Height: the highest square of the cell it falls in.
        let (ring, s) = at.cell;
        let h = (field.height[k as usize] as f64 + p.lidar_height).max(0.0);
        let cell = &mut grid[((1 - RELIEF) * rings + ring) * sectors + s];
        *cell = cell.max(h);
    }
    let mut out = vec![0f32; p.polar_len()];
    for (ch, (codes, values)) in
        out.chunks_exact_mut(rings * sectors).zip(grid.chunks_exact(rings * sectors)).enumerate()
    {
        // The relief relative to the scan's largest, the heights on a fixed scale (metres).
        let largest = if ch == RELIEF { values.iter().copied().fold(0.0, f64::max) } else { HEIGHT_SCALE };
        if largest > 0.0 {
            for (c, &v) in codes.iter_mut().zip(values) {
                *c = code(v / largest);
            }
        }
    }
    // The Cartesian image: each square's height code, the highest in an image cell.
    let height = |k: usize| code((field.height[k] as f64 + p.lidar_height).max(0.0) / HEIGHT_SCALE);
    let squares = field.filled.iter().map(|&k| (field.centre(k as usize, p.cell), height(k as usize)));
    out.extend(super::pose::image(squares, p));
    Ok(out)
}
