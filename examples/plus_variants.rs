//! The toporec-plus design measurements (docs/evaluation.md, "Design: what was measured"):
//! per-cell variants on the 20 × 60 polar grid, each matched exhaustively as toporec-plus
//! matches (columns filled in both, the rings both reach, every shift, the query turned by
//! `1/TURNS` of a sector), day 2 against day 1 of a simulated drive in the NCLT layout; prints
//! R@1 within 2 m / nearest database scan (%) per condition (`CONDS`, default the five of the
//! equal-budget tables).
//!
//! ```text
//! cargo run --release --example plus_variants -- DRIVE/velodyne_data VARIANT[,VARIANT...]
//! ```
//!
//! Variants (`a+b` puts channels side by side, each compared on its own and averaged;
//! `a*0.5` weighs one; `a^0.5` raises its values to a power; a trailing `q` stores them as 256
//! levels of the scan's largest):
//!
//! * `alpha`, `alpha-h0`: the alpha persistence of the 0.6 m voxel centroids, each H0 and H1
//!   pair's persistence (radii) where its class dies (`alpha_persistence_located`), shared
//!   between the nearest cells; `alpha-h0` the H0 pairs alone;
//! * `voxels`: the occupied 0.6 m voxels of a cell, shared likewise;
//! * `height`: the highest 0.5 m voxel centroid of a cell, plus 2 m (ScanContext's bin);
//! * `peaksC`, `saddlesC`: the height field of `C`-metre squares (the highest return above
//!   each), its superlevel-set H0 pairs, each pair's persistence at its peak or at its saddle;
//! * `reliefC`: every square's relief (its height above where its H0 class dies), shared
//!   between the nearest cells — toporec-plus's first channel;
//! * `toporec-plus`: the method as built (`toporec_plus::describe` and `distance`, every shift).

use rayon::prelude::*;
use toporec::eval::conditions::Condition;
use toporec::sources::nclt::NcltSpec;
use toporec::types::Point;

/// A scan of the drive.
struct Scan {
    id: String,
    session: String,
    xy: [f64; 2],
    points: Vec<Point>,
    ring: Option<Vec<u16>>,
}

/// A polar grid: channels × rings × sectors.
#[derive(Clone)]
struct Grid {
    ch: usize,
    rings: usize,
    sectors: usize,
    v: Vec<f32>,
}

const RINGS: usize = 20;
const SECTORS: usize = 60;
const RMAX: f64 = 80.0;

/// Shares `w` at (x, y) between the two nearest rings and sectors of channel `c`.
fn splat(g: &mut Grid, c: usize, x: f64, y: f64, w: f64) {
    let (rings, sectors) = (g.rings, g.sectors);
    let range = x.hypot(y);
    if range > RMAX {
        return;
    }
    let u = (range / RMAX * rings as f64 - 0.5).clamp(0.0, (rings - 1) as f64);
    let inner = (u as usize).min(rings - 1);
    let outer = (inner + 1).min(rings - 1);
    let wr = u - inner as f64;
    let v = y.atan2(x).to_degrees().rem_euclid(360.0) / (360.0 / sectors as f64) - 0.5;
    let (first, ws) = (v.floor(), v - v.floor());
    let before = (first as i64).rem_euclid(sectors as i64) as usize;
    let after = (before + 1) % sectors;
    for (ring, wt) in [(inner, 1.0 - wr), (outer, wr)] {
        let row = (c * rings + ring) * sectors;
        g.v[row + before] += (wt * (1.0 - ws) * w) as f32;
        g.v[row + after] += (wt * ws * w) as f32;
    }
}

fn hard_bin(x: f64, y: f64, rings: usize, sectors: usize) -> Option<(usize, usize)> {
    let range = x.hypot(y);
    if range > RMAX {
        return None;
    }
    let r = ((range / RMAX * rings as f64) as usize).min(rings - 1);
    let s =
        ((y.atan2(x).to_degrees().rem_euclid(360.0) / (360.0 / sectors as f64)) as usize).min(sectors - 1);
    Some((r, s))
}

fn new_grid(ch: usize) -> Grid {
    Grid { ch, rings: RINGS, sectors: SECTORS, v: vec![0.0; ch * RINGS * SECTORS] }
}

fn voxels(points: &[Point], size: f64) -> Vec<Point> {
    let kept = points.iter().filter(|q| q.iter().all(|c| c.is_finite()) && q[0].hypot(q[1]) <= RMAX);
    toporec::preprocess::voxel_grid_centred(kept, size)
}

/// Union-find.
struct Uf {
    parent: Vec<u32>,
}
impl Uf {
    fn new(n: usize) -> Self {
        Uf { parent: (0..n as u32).collect() }
    }
    fn find(&mut self, mut a: u32) -> u32 {
        while self.parent[a as usize] != a {
            let p = self.parent[a as usize];
            self.parent[a as usize] = self.parent[p as usize];
            a = p;
        }
        a
    }
}

/// A bird's-eye height field: squares of `cell` metres, the highest z above each (NaN empty).
struct HeightField {
    n: usize,
    cell: f64,
    height: Vec<f32>,
}

fn height_field(points: &[Point], cell: f64) -> HeightField {
    let n = (2.0 * RMAX / cell).ceil() as usize;
    let mut height = vec![f32::NAN; n * n];
    for q in points {
        if !(q[0].is_finite() && q[1].is_finite() && q[2].is_finite()) || q[0].hypot(q[1]) > RMAX {
            continue;
        }
        let (i, j) = (((q[0] + RMAX) / cell) as usize, ((q[1] + RMAX) / cell) as usize);
        if i >= n || j >= n {
            continue;
        }
        let h = &mut height[i * n + j];
        if h.is_nan() || q[2] as f32 > *h {
            *h = q[2] as f32;
        }
    }
    HeightField { n, cell, height }
}

impl HeightField {
    fn centre(&self, k: usize) -> (f64, f64) {
        let (i, j) = (k / self.n, k % self.n);
        ((i as f64 + 0.5) * self.cell - RMAX, (j as f64 + 0.5) * self.cell - RMAX)
    }

    /// The filled squares, highest first (ties by position).
    fn order(&self) -> Vec<usize> {
        let f = &self.height;
        let mut order: Vec<usize> = (0..f.len()).filter(|&k| !f[k].is_nan()).collect();
        order.sort_unstable_by(|&a, &b| f[b].total_cmp(&f[a]).then(a.cmp(&b)));
        order
    }

    /// The filled 8-neighbours of square `k` entered before it.
    fn entered_neighbours(&self, k: usize, entered: &[bool]) -> Vec<usize> {
        let n = self.n as i64;
        let (i, j) = ((k / self.n) as i64, (k % self.n) as i64);
        let mut out = Vec::new();
        for di in -1..=1i64 {
            for dj in -1..=1i64 {
                let (a, b) = (i + di, j + dj);
                if (di, dj) != (0, 0) && a >= 0 && b >= 0 && a < n && b < n && entered[(a * n + b) as usize] {
                    out.push((a * n + b) as usize);
                }
            }
        }
        out
    }

    /// Superlevel-set H0: per square, the peak of the class it joined; per peak, the height and
    /// square where its class dies (the lowest square's height, and no square, for a class that
    /// never dies).
    fn classes(&self) -> (Vec<usize>, Vec<(f32, Option<usize>)>) {
        let f = &self.height;
        let mut uf = Uf::new(f.len());
        let mut class = vec![usize::MAX; f.len()];
        let mut death = vec![(f32::NAN, None); f.len()];
        let mut entered = vec![false; f.len()];
        let order = self.order();
        for &k in &order {
            let mut roots: Vec<u32> = Vec::new();
            for m in self.entered_neighbours(k, &entered) {
                let r = uf.find(m as u32);
                if !roots.contains(&r) {
                    roots.push(r);
                }
            }
            entered[k] = true;
            // The elder class: the highest peak (a root is its class's peak).
            roots.sort_by(|&a, &b| f[b as usize].total_cmp(&f[a as usize]).then(a.cmp(&b)));
            let Some(&elder) = roots.first() else {
                class[k] = k;
                continue;
            };
            class[k] = elder as usize;
            uf.parent[k] = elder;
            for &younger in &roots[1..] {
                death[younger as usize] = (f[k], Some(k));
                uf.parent[younger as usize] = elder;
            }
        }
        let lowest = order.last().map_or(0.0, |&k| f[k]);
        for d in death.iter_mut().filter(|d| d.0.is_nan()) {
            d.0 = lowest;
        }
        (class, death)
    }
}

fn describe(variant: &str, points: &[Point]) -> Grid {
    let size =
        |prefix: &str| -> f64 { variant.strip_prefix(prefix).and_then(|s| s.parse().ok()).unwrap_or(1.0) };
    let mut g = new_grid(1);
    match variant {
        "alpha" | "alpha-h0" => {
            let dims = if variant == "alpha" { 2 } else { 1 };
            g = new_grid(dims);
            let cloud = voxels(points, 0.6);
            for l in toporec::homology::alpha_persistence_located(&cloud).unwrap_or_default() {
                let (Some(at), dim) = (l.at, l.pair.dim as usize) else { continue };
                let persistence = l.pair.death.sqrt() - l.pair.birth.sqrt();
                if dim < dims && persistence > 0.0 {
                    splat(&mut g, dim, at[0], at[1], persistence);
                }
            }
        }
        "voxels" => voxels(points, 0.6).iter().for_each(|q| splat(&mut g, 0, q[0], q[1], 1.0)),
        "height" => {
            for q in voxels(points, 0.5) {
                if let Some((r, s)) = hard_bin(q[0], q[1], RINGS, SECTORS) {
                    let k = r * SECTORS + s;
                    g.v[k] = g.v[k].max((q[2] + 2.0) as f32);
                }
            }
        }
        v if v.starts_with("peaks") || v.starts_with("saddles") => {
            let field = height_field(points, size(if v.starts_with("peaks") { "peaks" } else { "saddles" }));
            let (class, death) = field.classes();
            for (k, &peak) in class.iter().enumerate() {
                if peak != k {
                    continue;
                }
                let (height, at) = death[k];
                let square = if v.starts_with("peaks") { Some(k) } else { at };
                if let Some(square) = square {
                    let (x, y) = field.centre(square);
                    splat(&mut g, 0, x, y, (field.height[k] - height) as f64);
                }
            }
        }
        v if v.starts_with("relief") => {
            let field = height_field(points, size("relief"));
            let (class, death) = field.classes();
            for (k, &peak) in class.iter().enumerate() {
                if peak != usize::MAX {
                    let (x, y) = field.centre(k);
                    splat(&mut g, 0, x, y, ((field.height[k] - death[peak].0) as f64).max(1e-3));
                }
            }
        }
        other => panic!("unknown variant `{other}`"),
    }
    g
}

/// Ready: per channel group, unit columns (sector-major), filled, raw, reach.
struct Ready {
    groups: Vec<ReadyGroup>,
}

struct ReadyGroup {
    cols: Vec<f32>,
    filled: Vec<bool>,
    raw: Vec<f32>,
    reach: usize,
    ch: usize,
    rings: usize,
    sectors: usize,
    weight: f64,
}

fn ready_group(g: &Grid, weight: f64) -> ReadyGroup {
    let (ch, rings, sectors) = (g.ch, g.rings, g.sectors);
    let h = ch * rings;
    let mut raw = vec![0f32; sectors * h];
    for c in 0..ch {
        for r in 0..rings {
            for s in 0..sectors {
                raw[s * h + c * rings + r] = g.v[(c * rings + r) * sectors + s];
            }
        }
    }
    let reach = (0..rings)
        .rev()
        .find(|&r| (0..ch).any(|c| (0..sectors).any(|s| g.v[(c * rings + r) * sectors + s] != 0.0)))
        .map_or(0, |r| r + 1);
    let mut cols = raw.clone();
    let mut filled = vec![false; sectors];
    for s in 0..sectors {
        let col = &mut cols[s * h..(s + 1) * h];
        let n = col.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        filled[s] = n > 0.0;
        if n > 0.0 {
            col.iter_mut().for_each(|v| *v = (*v as f64 / n) as f32);
        }
    }
    ReadyGroup { cols, filled, raw, reach, ch, rings, sectors, weight }
}

fn ready(gs: &[(Grid, f64)]) -> Ready {
    Ready { groups: gs.iter().map(|(g, w)| ready_group(g, *w)).collect() }
}

fn group_distance(qv: &ReadyGroup, c: &ReadyGroup, shift: usize, reach_all: usize) -> f64 {
    let (ch, rings, sectors) = (c.ch, c.rings, c.sectors);
    let h = ch * rings;
    let reach0 = reach_all.max(1);
    let cut = reach0 < rings;
    let reach = if cut { (reach0 - 1).max(1) } else { reach0 };
    let (mut sum, mut count) = (0.0f64, 0usize);
    for b in 0..sectors {
        let a = (b + shift) % sectors;
        if !(qv.filled[a] && c.filled[b]) {
            continue;
        }
        if cut {
            let (qa, cb) = (&qv.raw[a * h..(a + 1) * h], &c.raw[b * h..(b + 1) * h]);
            let (mut dot, mut nq, mut nc) = (0.0f64, 0.0f64, 0.0f64);
            for k in 0..ch {
                for r in 0..reach {
                    let (x, y) = (qa[k * rings + r] as f64, cb[k * rings + r] as f64);
                    dot += x * y;
                    nq += x * x;
                    nc += y * y;
                }
            }
            if nq > 0.0 && nc > 0.0 {
                sum += dot / (nq * nc).sqrt();
                count += 1;
            }
        } else {
            let (qa, cb) = (&qv.cols[a * h..(a + 1) * h], &c.cols[b * h..(b + 1) * h]);
            sum += qa.iter().zip(cb).map(|(x, y)| x * y).sum::<f32>() as f64;
            count += 1;
        }
    }
    if count > 0 { 1.0 - sum / count as f64 } else { 1.0 }
}

/// Overlap-aware column-cosine distance over all shifts (and the query's fractional shifts).
fn distance(q: &[Ready], c: &Ready) -> f64 {
    let sectors = c.groups[0].sectors;
    // Reach: over all groups.
    let qreach = q[0].groups.iter().map(|g| g.reach).max().unwrap();
    let creach = c.groups.iter().map(|g| g.reach).max().unwrap();
    let reach = qreach.min(creach);
    let wsum: f64 = c.groups.iter().map(|g| g.weight).sum();
    let mut best = f64::INFINITY;
    for qv in q {
        for shift in 0..sectors {
            let d: f64 = qv
                .groups
                .iter()
                .zip(&c.groups)
                .map(|(a, b)| b.weight * group_distance(a, b, shift, reach))
                .sum::<f64>()
                / wsum;
            best = best.min(d);
        }
    }
    best
}

/// The query made ready at fractional sector shifts 0, 1/k, ..., by linear interpolation.
fn fractional(gs: &[(Grid, f64)], k: usize) -> Vec<Ready> {
    (0..k)
        .map(|i| {
            let f = i as f32 / k as f32;
            let shifted: Vec<(Grid, f64)> = gs
                .iter()
                .map(|(g, w)| {
                    let mut h = g.clone();
                    let s = g.sectors;
                    for row in 0..g.ch * g.rings {
                        for j in 0..s {
                            h.v[row * s + j] = (1.0 - f) * g.v[row * s + j] + f * g.v[row * s + (j + 1) % s];
                        }
                    }
                    (h, *w)
                })
                .collect();
            ready(&shifted)
        })
        .collect()
}

/// A variant "a+b*0.5+c": channel groups with weights.
fn describe_all(variant: &str, points: &[Point]) -> Vec<(Grid, f64)> {
    variant
        .split('+')
        .map(|part| {
            let (name, w) = match part.split_once('*') {
                Some((n, w)) => (n, w.parse().unwrap()),
                None => (part, 1.0),
            };
            // name[^power][q]: values raised to a power, then quantized to 255 levels per scan.
            let (name, quant) = match name.strip_suffix('q') {
                Some(n) => (n, true),
                None => (name, false),
            };
            let (name, power) = match name.split_once('^') {
                Some((n, p)) => (n, p.parse::<f32>().unwrap()),
                None => (name, 1.0),
            };
            let mut g = describe(name, points);
            if power != 1.0 {
                g.v.iter_mut().for_each(|v| *v = v.max(0.0).powf(power));
            }
            if quant {
                let m = g.v.iter().copied().fold(0.0f32, f32::max);
                if m > 0.0 {
                    g.v.iter_mut().for_each(|v| *v = (*v / m * 255.0).round());
                }
            }
            (g, w)
        })
        .collect()
}

/// Whether the top-1 is within 2 m, and whether it is the nearest database scan.
fn judged(q: &Scan, db: &[&Scan], top: usize) -> (bool, bool) {
    let dist = |s: &Scan| (s.xy[0] - q.xy[0]).hypot(s.xy[1] - q.xy[1]);
    let nearest = db.iter().map(|s| dist(s)).fold(f64::INFINITY, f64::min);
    (dist(db[top]) <= 2.0, dist(db[top]) <= nearest + 1e-6)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (Some(dir), Some(variants)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: plus_variants DRIVE/velodyne_data VARIANT[,VARIANT...]");
        std::process::exit(2);
    };
    let turns: usize = std::env::var("TURNS").ok().and_then(|s| s.parse().ok()).unwrap_or(3);
    let conditions: Vec<Condition> = std::env::var("CONDS")
        .unwrap_or("as-recorded,occlusion,offset,beams=16,max-range".into())
        .split(',')
        .flat_map(|c| Condition::parse(c).expect("a condition"))
        .collect();
    let scans: Vec<Scan> = NcltSpec::sessions(vec![dir.into()])
        .open()
        .expect("an NCLT drive")
        .filter_map(|s| s.ok())
        .map(|s| Scan {
            xy: s.pose.map(|p| [p.x, p.y]).unwrap_or([f64::NAN; 2]),
            id: s.id,
            session: s.session,
            points: s.points,
            ring: s.ring,
        })
        .collect();
    let sessions: std::collections::BTreeSet<&str> = scans.iter().map(|s| s.session.as_str()).collect();
    let sessions: Vec<&str> = sessions.into_iter().collect();
    let db: Vec<&Scan> = scans.iter().filter(|s| s.session == sessions[0]).collect();
    let queries: Vec<&Scan> = scans.iter().filter(|s| s.session == sessions[1]).collect();
    println!(
        "R@1 within 2 m / nearest (%), {} queries against {} scans; conditions: {}",
        queries.len(),
        db.len(),
        conditions.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
    );
    let changed = |q: &Scan, c: &Condition| {
        c.apply(&q.points, q.ring.as_deref(), toporec::preprocess::seed_of(&q.id), 1.0).expect("applicable")
    };
    let rate = |res: Vec<(bool, bool)>| {
        let n = res.len() as f64;
        let (a, b) = (res.iter().filter(|r| r.0).count(), res.iter().filter(|r| r.1).count());
        format!(" {:5.1} / {:5.1}", a as f64 * 100.0 / n, b as f64 * 100.0 / n)
    };
    for variant in variants.split(',') {
        let mut line = format!("{variant:28} |");
        if variant == "toporec-plus" {
            let p =
                toporec::methods::toporec_plus::PlusParams { turns, search_ratio: 1.0, ..Default::default() };
            let describe =
                |pts: &[Point]| toporec::methods::toporec_plus::describe(pts, &p).expect("a descriptor");
            let described: Vec<Vec<f32>> = db.par_iter().map(|s| describe(&s.points)).collect();
            for c in &conditions {
                let res = queries
                    .par_iter()
                    .map(|q| {
                        let d = describe(&changed(q, c));
                        let top = (0..db.len())
                            .map(|i| (toporec::methods::toporec_plus::distance(&d, &described[i], &p).0, i))
                            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a })
                            .1;
                        judged(q, &db, top)
                    })
                    .collect();
                line += &rate(res);
            }
        } else {
            let described: Vec<Ready> =
                db.par_iter().map(|s| ready(&describe_all(variant, &s.points))).collect();
            for c in &conditions {
                let res = queries
                    .par_iter()
                    .map(|q| {
                        let turned = fractional(&describe_all(variant, &changed(q, c)), turns);
                        let top = (0..db.len())
                            .map(|i| (distance(&turned, &described[i]), i))
                            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a })
                            .1;
                        judged(q, &db, top)
                    })
                    .collect();
                line += &rate(res);
            }
        }
        println!("{line}");
    }
}
