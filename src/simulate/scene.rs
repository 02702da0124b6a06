//! The procedural town: a ground plane (optionally sloped) and primitives — buildings
//! (boxes turned about z), walls and parked cars (boxes), poles, tree trunks and pedestrians
//! (vertical cylinders), tree crowns (ellipsoids) — with exact ray intersection, and a 2D
//! grid over the plan so a ray only tests what lies along its path.

use crate::rng::SplitMix64;

/// What a surface is (sets the simulated intensity).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Material {
    /// Road and pavement.
    Ground,
    /// Facades, walls.
    Building,
    /// Trunks and crowns.
    Vegetation,
    /// Parked cars.
    Car,
    /// Poles.
    Pole,
    /// Pedestrians.
    Person,
}

impl Material {
    /// Mean intensity (0–255).
    pub fn intensity(self) -> f64 {
        match self {
            Material::Ground => 25.0,
            Material::Building => 70.0,
            Material::Vegetation => 40.0,
            Material::Car => 110.0,
            Material::Pole => 150.0,
            Material::Person => 55.0,
        }
    }
}

/// A primitive shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A box: centre, half extents, yaw about z.
    Box {
        /// Centre.
        c: [f64; 3],
        /// Half extents along its own axes.
        h: [f64; 3],
        /// Rotation about z (rad).
        yaw: f64,
    },
    /// A vertical cylinder from z0 to z1.
    Cylinder {
        /// Axis position.
        c: [f64; 2],
        /// Radius.
        r: f64,
        /// Bottom.
        z0: f64,
        /// Top.
        z1: f64,
    },
    /// An axis-aligned ellipsoid.
    Ellipsoid {
        /// Centre.
        c: [f64; 3],
        /// Radii.
        r: [f64; 3],
    },
}

/// A primitive of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Primitive {
    /// Geometry.
    pub shape: Shape,
    /// Surface kind.
    pub material: Material,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Shape {
    /// Nearest hit distance `t > 1e-9` along the unit ray `o + t·d`, if any.
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3]) -> Option<f64> {
        match *self {
            Shape::Box { c, h, yaw } => {
                let (s, co) = yaw.sin_cos();
                let p = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
                // Into the box frame (rotate by −yaw).
                let lo = [co * p[0] + s * p[1], -s * p[0] + co * p[1], p[2]];
                let ld = [co * d[0] + s * d[1], -s * d[0] + co * d[1], d[2]];
                let (mut tmin, mut tmax) = (f64::NEG_INFINITY, f64::INFINITY);
                for k in 0..3 {
                    if ld[k].abs() < 1e-15 {
                        if lo[k].abs() > h[k] {
                            return None;
                        }
                    } else {
                        let (a, b) = ((-h[k] - lo[k]) / ld[k], (h[k] - lo[k]) / ld[k]);
                        tmin = tmin.max(a.min(b));
                        tmax = tmax.min(a.max(b));
                    }
                }
                if tmax < tmin || tmax <= 1e-9 {
                    return None;
                }
                Some(if tmin > 1e-9 { tmin } else { tmax })
            }
            Shape::Cylinder { c, r, z0, z1 } => {
                let (px, py) = (o[0] - c[0], o[1] - c[1]);
                let a = d[0] * d[0] + d[1] * d[1];
                let mut best = f64::INFINITY;
                if a > 1e-15 {
                    let b = px * d[0] + py * d[1];
                    let q = px * px + py * py - r * r;
                    let disc = b * b - a * q;
                    if disc >= 0.0 {
                        let sq = disc.sqrt();
                        for t in [(-b - sq) / a, (-b + sq) / a] {
                            let z = o[2] + t * d[2];
                            if t > 1e-9 && z >= z0 && z <= z1 {
                                best = best.min(t);
                            }
                        }
                    }
                }
                // End caps.
                if d[2].abs() > 1e-15 {
                    for zc in [z0, z1] {
                        let t = (zc - o[2]) / d[2];
                        let (x, y) = (px + t * d[0], py + t * d[1]);
                        if t > 1e-9 && x * x + y * y <= r * r {
                            best = best.min(t);
                        }
                    }
                }
                best.is_finite().then_some(best)
            }
            Shape::Ellipsoid { c, r } => {
                let p = [(o[0] - c[0]) / r[0], (o[1] - c[1]) / r[1], (o[2] - c[2]) / r[2]];
                let q = [d[0] / r[0], d[1] / r[1], d[2] / r[2]];
                let a = dot(q, q);
                let b = dot(p, q);
                let disc = b * b - a * (dot(p, p) - 1.0);
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                [(-b - sq) / a, (-b + sq) / a].into_iter().find(|&t| t > 1e-9)
            }
        }
    }

    /// Plan-view bounding box `[xmin, ymin, xmax, ymax]`.
    pub fn plan_bounds(&self) -> [f64; 4] {
        match *self {
            Shape::Box { c, h, yaw } => {
                let (s, co) = yaw.sin_cos();
                let ex = h[0] * co.abs() + h[1] * s.abs();
                let ey = h[0] * s.abs() + h[1] * co.abs();
                [c[0] - ex, c[1] - ey, c[0] + ex, c[1] + ey]
            }
            Shape::Cylinder { c, r, .. } => [c[0] - r, c[1] - r, c[0] + r, c[1] + r],
            Shape::Ellipsoid { c, r } => [c[0] - r[0], c[1] - r[1], c[0] + r[0], c[1] + r[1]],
        }
    }

    /// Signed-ish distance of a point to the surface (0 on it), for tests: exact for
    /// boxes and cylinders, the algebraic distance scaled by the smallest radius for
    /// ellipsoids.
    pub fn surface_distance(&self, p: [f64; 3]) -> f64 {
        match *self {
            Shape::Box { c, h, yaw } => {
                let (s, co) = yaw.sin_cos();
                let q = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                let l = [co * q[0] + s * q[1], -s * q[0] + co * q[1], q[2]];
                let out: [f64; 3] = [0, 1, 2].map(|k| l[k].abs() - h[k]);
                let outside = out.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
                outside + out.iter().copied().fold(f64::NEG_INFINITY, f64::max).min(0.0).abs()
            }
            Shape::Cylinder { c, r, z0, z1 } => {
                let radial = ((p[0] - c[0]).hypot(p[1] - c[1]) - r).abs();
                let inside_z = p[2] >= z0 && p[2] <= z1;
                let cap = (p[2] - z0).abs().min((p[2] - z1).abs());
                if inside_z { radial.min(cap) } else { radial.max(cap) }
            }
            Shape::Ellipsoid { c, r } => {
                let v = (0..3).map(|k| ((p[k] - c[k]) / r[k]).powi(2)).sum::<f64>().sqrt();
                (v - 1.0).abs() * r.iter().copied().fold(f64::INFINITY, f64::min)
            }
        }
    }
}

/// Town parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct TownParams {
    /// Blocks per side.
    pub blocks: usize,
    /// Street grid spacing (m).
    pub block_size: f64,
    /// Road width (m).
    pub road_width: f64,
    /// Ground slope (dz/dx, dz/dy).
    pub slope: [f64; 2],
}

impl Default for TownParams {
    fn default() -> Self {
        TownParams { blocks: 3, block_size: 60.0, road_width: 12.0, slope: [0.0, 0.0] }
    }
}

/// The scene of one session: static town plus that session's movable things.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Parameters.
    pub params: TownParams,
    /// All primitives.
    pub primitives: Vec<Primitive>,
    grid: Grid,
}

#[derive(Clone, Debug)]
struct Grid {
    origin: [f64; 2],
    cell: f64,
    dims: [usize; 2],
    cells: Vec<Vec<u32>>,
}

impl Scene {
    /// Builds the town for `seed`, as seen in session `session` (static geometry depends on
    /// the seed only; parked cars, pedestrians and crown sizes also on the session).
    pub fn town(params: &TownParams, seed: u64, session: u64) -> Self {
        let mut fixed = SplitMix64(seed ^ 0x746F_776E);
        let mut varying = SplitMix64(seed ^ 0x7365_7373 ^ session.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let mut prims = Vec::new();
        let (b, w) = (params.block_size, params.road_width);
        let ground_z = |x: f64, y: f64| params.slope[0] * x + params.slope[1] * y;
        let sidewalk = 3.0;
        let n = params.blocks;
        for i in 0..n {
            for j in 0..n {
                let (x0, y0) = (i as f64 * b + w / 2.0 + sidewalk, j as f64 * b + w / 2.0 + sidewalk);
                let size = b - w - 2.0 * sidewalk;
                // 2 x 2 lots, each usually one building, sometimes a walled yard with trees.
                for (li, lj) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let lot = size / 2.0;
                    let (lx, ly) = (x0 + li as f64 * lot, y0 + lj as f64 * lot);
                    let kind = fixed.next_f64();
                    if kind < 0.5 {
                        let fx = lot * (0.55 + 0.35 * fixed.next_f64());
                        let fy = lot * (0.55 + 0.35 * fixed.next_f64());
                        let height = 4.0 + 18.0 * fixed.next_f64().powi(2);
                        let cx = lx + lot / 2.0 + (fixed.next_f64() - 0.5) * (lot - fx) * 0.8;
                        let cy = ly + lot / 2.0 + (fixed.next_f64() - 0.5) * (lot - fy) * 0.8;
                        let yaw = if fixed.next_f64() < 0.25 { (fixed.next_f64() - 0.5) * 0.4 } else { 0.0 };
                        let gz = ground_z(cx, cy);
                        prims.push(Primitive {
                            shape: Shape::Box {
                                c: [cx, cy, gz + height / 2.0 - 1.0],
                                h: [fx / 2.0, fy / 2.0, height / 2.0 + 1.0],
                                yaw,
                            },
                            material: Material::Building,
                        });
                    } else if kind < 0.75 {
                        // An open lot (parking): a few cars.
                        for _ in 0..fixed.below(4) {
                            let (cx, cy) = (
                                lx + 3.0 + (lot - 6.0) * fixed.next_f64(),
                                ly + 3.0 + (lot - 6.0) * fixed.next_f64(),
                            );
                            if varying.next_f64() < 0.7 {
                                let gz = ground_z(cx, cy);
                                prims.push(Primitive {
                                    shape: Shape::Box {
                                        c: [cx, cy, gz + 0.8],
                                        h: [2.25, 0.9, 0.75],
                                        yaw: 0.0,
                                    },
                                    material: Material::Car,
                                });
                            }
                        }
                    } else {
                        // A yard: a wall along the street side and a few trees.
                        let wall_h = 1.0 + 1.5 * fixed.next_f64();
                        let cy = ly + 0.3;
                        prims.push(Primitive {
                            shape: Shape::Box {
                                c: [lx + lot / 2.0, cy, ground_z(lx, cy) + wall_h / 2.0 - 0.5],
                                h: [lot / 2.0, 0.15, wall_h / 2.0 + 0.5],
                                yaw: 0.0,
                            },
                            material: Material::Building,
                        });
                        for _ in 0..2 + fixed.below(3) {
                            let (tx, ty) = (
                                lx + 2.0 + (lot - 4.0) * fixed.next_f64(),
                                ly + 2.0 + (lot - 4.0) * fixed.next_f64(),
                            );
                            tree(&mut prims, tx, ty, ground_z(tx, ty), &mut fixed, &mut varying);
                        }
                    }
                }
            }
        }
        // Along every street: poles and street trees on the sidewalks, parked-car slots.
        let extent = n as f64 * b;
        for line in 0..=n {
            let c = line as f64 * b;
            for horizontal in [false, true] {
                let mut s = 5.0;
                while s < extent - 5.0 {
                    let at = |along: f64, across: f64| {
                        if horizontal { (along, c + across) } else { (c + across, along) }
                    };
                    let near_crossing = (s % b) < w / 2.0 + 2.0 || (s % b) > b - w / 2.0 - 2.0;
                    for side in [-1.0, 1.0] {
                        let curb = side * (w / 2.0 + 0.8);
                        if !near_crossing {
                            match fixed.below(6) {
                                0 => {
                                    let (x, y) = at(s, curb);
                                    let gz = ground_z(x, y);
                                    let height = 6.0 + 3.0 * fixed.next_f64();
                                    prims.push(Primitive {
                                        shape: Shape::Cylinder {
                                            c: [x, y],
                                            r: 0.15,
                                            z0: gz - 0.5,
                                            z1: gz + height,
                                        },
                                        material: Material::Pole,
                                    });
                                }
                                1 | 2 => {
                                    let (x, y) = at(s, curb + side * 0.5);
                                    tree(&mut prims, x, y, ground_z(x, y), &mut fixed, &mut varying);
                                }
                                _ => {}
                            }
                            // A parked-car slot: present with p = 0.6, re-drawn per session.
                            let static_present = fixed.next_f64() < 0.6;
                            let changes = varying.next_f64() < 0.3;
                            let present = static_present != changes;
                            let shift = (varying.next_f64() - 0.5) * if changes { 2.0 } else { 0.0 };
                            if present {
                                let (x, y) = at(s + shift, side * (w / 2.0 - 1.3));
                                let gz = ground_z(x, y);
                                let yaw = if horizontal { 0.0 } else { std::f64::consts::FRAC_PI_2 };
                                prims.push(Primitive {
                                    shape: Shape::Box { c: [x, y, gz + 0.8], h: [2.25, 0.9, 0.75], yaw },
                                    material: Material::Car,
                                });
                            }
                        }
                        // Pedestrians: session-only.
                        if varying.next_f64() < 0.04 {
                            let (x, y) = at(s, side * (w / 2.0 + 1.5));
                            let gz = ground_z(x, y);
                            prims.push(Primitive {
                                shape: Shape::Cylinder { c: [x, y], r: 0.3, z0: gz, z1: gz + 1.75 },
                                material: Material::Person,
                            });
                        }
                    }
                    s += 8.0;
                }
            }
        }
        let grid = Grid::build(&prims, 8.0);
        Scene { params: params.clone(), primitives: prims, grid }
    }

    /// Ground height at (x, y).
    pub fn ground_z(&self, x: f64, y: f64) -> f64 {
        self.params.slope[0] * x + self.params.slope[1] * y
    }

    /// Nearest hit along the unit ray within `max_range`: (distance, material).
    pub fn cast(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        max_range: f64,
        mailbox: &mut Mailbox,
    ) -> Option<(f64, Material)> {
        let mut best = (max_range, None);
        // The ground plane z = sx·x + sy·y.
        let n = [-self.params.slope[0], -self.params.slope[1], 1.0];
        let denom = dot(n, d);
        if denom.abs() > 1e-12 {
            let t = -dot(n, o) / denom;
            if t > 1e-9 && t < best.0 {
                best = (t, Some(Material::Ground));
            }
        }
        mailbox.ray += 1;
        self.grid.walk(o, d, best.0, |ids, t_enter| {
            if t_enter > best.0 {
                return false;
            }
            for &id in ids {
                let slot = &mut mailbox.seen[id as usize];
                if *slot == mailbox.ray {
                    continue;
                }
                *slot = mailbox.ray;
                let p = &self.primitives[id as usize];
                if let Some(t) = p.shape.intersect(o, d)
                    && t < best.0
                {
                    best = (t, Some(p.material));
                }
            }
            true
        });
        best.1.map(|m| (best.0, m))
    }

    /// A mailbox sized for this scene (one per thread).
    pub fn mailbox(&self) -> Mailbox {
        Mailbox { ray: 0, seen: vec![0; self.primitives.len()] }
    }
}

/// Per-thread scratch: which primitives the current ray already tested.
pub struct Mailbox {
    ray: u64,
    seen: Vec<u64>,
}

fn tree(
    prims: &mut Vec<Primitive>,
    x: f64,
    y: f64,
    gz: f64,
    fixed: &mut SplitMix64,
    varying: &mut SplitMix64,
) {
    let trunk = 2.0 + 1.5 * fixed.next_f64();
    let crown = 1.5 + 1.5 * fixed.next_f64();
    // Vegetation changes a little between sessions.
    let grow = 1.0 + 0.06 * (varying.next_f64() - 0.5);
    prims.push(Primitive {
        shape: Shape::Cylinder { c: [x, y], r: 0.2, z0: gz - 0.3, z1: gz + trunk + 0.5 },
        material: Material::Vegetation,
    });
    let r = crown * grow;
    prims.push(Primitive {
        shape: Shape::Ellipsoid { c: [x, y, gz + trunk + r * 0.9], r: [r, r, r * 1.2] },
        material: Material::Vegetation,
    });
}

impl Grid {
    fn build(prims: &[Primitive], cell: f64) -> Self {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in prims {
            let b = p.shape.plan_bounds();
            lo = [lo[0].min(b[0]), lo[1].min(b[1])];
            hi = [hi[0].max(b[2]), hi[1].max(b[3])];
        }
        if prims.is_empty() {
            lo = [0.0; 2];
            hi = [cell; 2];
        }
        let dims = [
            ((hi[0] - lo[0]) / cell).ceil().max(1.0) as usize,
            ((hi[1] - lo[1]) / cell).ceil().max(1.0) as usize,
        ];
        let mut cells = vec![Vec::new(); dims[0] * dims[1]];
        for (id, p) in prims.iter().enumerate() {
            let b = p.shape.plan_bounds();
            let ix = |v: f64, k: usize| (((v - lo[k]) / cell).floor().max(0.0) as usize).min(dims[k] - 1);
            for gx in ix(b[0], 0)..=ix(b[2], 0) {
                for gy in ix(b[1], 1)..=ix(b[3], 1) {
                    cells[gy * dims[0] + gx].push(id as u32);
                }
            }
        }
        Grid { origin: lo, cell, dims, cells }
    }

    /// Visits the cells the ray's plan projection crosses, in order, with the ray distance at
    /// which it enters each; stops when `visit` returns false or past `max_t`.
    fn walk(&self, o: [f64; 3], d: [f64; 3], max_t: f64, mut visit: impl FnMut(&[u32], f64) -> bool) {
        let size = [self.dims[0] as f64 * self.cell, self.dims[1] as f64 * self.cell];
        let p = [o[0] - self.origin[0], o[1] - self.origin[1]];
        // Clip the ray to the grid rectangle.
        let (mut t0, mut t1) = (0.0f64, max_t);
        for k in 0..2 {
            if d[k].abs() < 1e-15 {
                if p[k] < 0.0 || p[k] > size[k] {
                    return;
                }
            } else {
                let (a, b) = ((0.0 - p[k]) / d[k], (size[k] - p[k]) / d[k]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 > t1 {
            return;
        }
        let start = [p[0] + t0 * d[0], p[1] + t0 * d[1]];
        let mut c =
            [0, 1].map(|k| ((start[k] / self.cell).floor().max(0.0) as i64).min(self.dims[k] as i64 - 1));
        let step = [0, 1].map(|k| if d[k] > 0.0 { 1i64 } else { -1 });
        let mut t_next = [0, 1].map(|k| {
            if d[k].abs() < 1e-15 {
                f64::INFINITY
            } else {
                let edge = (c[k] + (step[k] > 0) as i64) as f64 * self.cell;
                (edge - p[k]) / d[k]
            }
        });
        let dt = [0, 1].map(|k| if d[k].abs() < 1e-15 { f64::INFINITY } else { self.cell / d[k].abs() });
        let mut t_enter = t0;
        loop {
            let ids = &self.cells[c[1] as usize * self.dims[0] + c[0] as usize];
            if !visit(ids, t_enter) {
                return;
            }
            let k = if t_next[0] < t_next[1] { 0 } else { 1 };
            t_enter = t_next[k];
            if t_enter > t1 {
                return;
            }
            c[k] += step[k];
            if c[k] < 0 || c[k] >= self.dims[k] as i64 {
                return;
            }
            t_next[k] += dt[k];
        }
    }
}
