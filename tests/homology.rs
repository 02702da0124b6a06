//! The engine against GUDHI 3.13 reference output, exact invariants and a naive oracle.

use crate::util::*;
use proptest::prelude::*;
use toporec::homology::{DelaunayComplex, Filtration, Point, alpha_persistence, persistence::persistence};
use toporec::rng::SplitMix64;

/// GUDHI's `safe` values differ from exactly rounded ones by up to 2.2e-10 relative on
/// uniform_cube_4096 (checked against `precision='exact'`), so 1e-9 is the tolerance.
const FIXTURE_TOL: f64 = 1e-9;

const FIXTURES: [&str; 8] = [
    "uniform_cube_500",
    "uniform_cube_4096",
    "two_spheres_800",
    "torus_1000",
    "lattice_6x6x6_degenerate",
    "duplicates_300x2",
    "planar_400_degenerate",
    "lidar_like_4096",
];

#[test]
fn diagrams_equal_gudhi_on_every_fixture() {
    let dir = root().join("tests/fixtures");
    for name in FIXTURES {
        let pts = read_cloud(&dir.join(format!("clouds/{name}.csv")));
        let ours = alpha_persistence(&pts).unwrap();
        let reference = read_diagram_csv(&dir.join(format!("diagrams/{name}.csv")));
        assert_diagrams_match(&by_dim(&ours), &reference, FIXTURE_TOL, name);
    }
}

#[test]
fn simplex_counts_equal_gudhi_on_non_degenerate_fixtures() {
    let dir = root().join("tests/fixtures");
    for name in FIXTURES {
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(format!("diagrams/{name}.json"))).unwrap(),
        )
        .unwrap();
        let pts = read_cloud(&dir.join(format!("clouds/{name}.csv")));
        let c = DelaunayComplex::new(&pts).unwrap();
        let expected: Vec<usize> = meta["simplices_by_dim"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as usize)
            .collect();
        assert_eq!(c.simplex_counts()[0], expected[0], "{name}: vertices (duplicates merged)");
        if !meta["degenerate"].as_bool().unwrap() {
            assert_eq!(c.simplex_counts().to_vec(), expected, "{name}: simplices by dimension");
        }
    }
}

#[test]
fn golden_50_points_every_precision_mode() {
    let g: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("tests/fixtures/golden/alpha_atol_golden.json")).unwrap(),
    )
    .unwrap();
    let pts: Vec<Point> = g["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let p = p.as_array().unwrap();
            [p[0].as_f64().unwrap(), p[1].as_f64().unwrap(), p[2].as_f64().unwrap()]
        })
        .collect();
    let ours = by_dim(&alpha_persistence(&pts).unwrap());
    let exact_counts = ["0", "1", "2"].map(|d| g["diagrams_exact"][d].as_array().unwrap().len());
    assert_eq!(ours.each_ref().map(Vec::len), exact_counts, "pair counts of GUDHI `exact`");
    let c = DelaunayComplex::new(&pts).unwrap();
    let simplices: Vec<usize> =
        g["num_simplices_by_dim"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
    assert_eq!(c.simplex_counts().to_vec(), simplices, "GUDHI's simplex counts");
    for mode in ["diagrams_exact", "diagrams_safe", "diagrams_fast"] {
        let reference: [Vec<(f64, f64)>; 3] = [0, 1, 2].map(|d| {
            g[mode][d.to_string()]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap_or(f64::INFINITY)))
                .collect()
        });
        // Against `exact` (correctly rounded) the values agree to a few ulps.
        let tol = if mode == "diagrams_exact" { 1e-14 } else { FIXTURE_TOL };
        assert_diagrams_match(&ours, &reference, tol, mode);
    }
}

fn diagram(pts: &[Point]) -> [Vec<(f64, f64)>; 3] {
    by_dim(&alpha_persistence(pts).unwrap())
}

#[test]
fn reference_facts_octahedron_cube_tetrahedron() {
    // GUDHI 3.13 facts, identical in its three precision modes.
    let octa = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let d = diagram(&octa);
    assert_eq!(d[0].iter().filter(|p| p.1 == 0.5).count(), 5);
    assert!(d[0].contains(&(0.0, f64::INFINITY)));
    assert_eq!(d[1].len(), 7);
    assert!(d[1].iter().all(|p| p.0 == 0.5 && (p.1 - 2.0 / 3.0).abs() < 1e-15));
    assert_eq!(d[2].len(), 1);
    assert!((d[2][0].0 - 2.0 / 3.0).abs() < 1e-15 && d[2][0].1 == 1.0);

    let mut cube = Vec::new();
    for i in 0..8 {
        cube.push([(i & 1) as f64, (i >> 1 & 1) as f64, (i >> 2 & 1) as f64]);
    }
    let d = diagram(&cube);
    assert_eq!(d[0].len(), 8);
    assert_eq!(d[0].iter().filter(|p| p.1 == 0.25).count(), 7);
    assert_eq!(d[1], vec![(0.25, 0.5); 5]);
    assert_eq!(d[2], vec![(0.5, 0.75)]);

    let tet = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let d = diagram(&tet);
    assert_eq!(d[0].len(), 4);
    assert!(d[1].is_empty() && d[2].is_empty(), "the zero-length pairs are dropped");
}

#[test]
fn low_dimensional_inputs_give_gudhis_answer() {
    // GUDHI 3.13's edge cases.
    assert!(alpha_persistence(&[]).unwrap().is_empty());
    assert!(alpha_persistence(&[[1.0, 2.0, 3.0]]).unwrap().is_empty(), "one point: not even (0, inf)");
    assert!(alpha_persistence(&[[1.0, 2.0, 3.0]; 5]).unwrap().is_empty(), "duplicates of one point");
    let d = diagram(&[[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]]);
    assert_eq!(d[0], vec![(0.0, 1.0), (0.0, f64::INFINITY)]);
    // Collinear: H0 only, deaths = squared half gaps.
    let d = diagram(&[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [3.0, 3.0, 3.0], [-2.0, -2.0, -2.0]]);
    let mut deaths: Vec<f64> = d[0].iter().map(|p| p.1).collect();
    deaths.sort_by(f64::total_cmp);
    assert_eq!(deaths, vec![0.75, 3.0, 3.0, f64::INFINITY]);
    assert!(d[1].is_empty() && d[2].is_empty());
    // Co-planar square of side 2: a 2-dimensional complex. The sides enter at 1 and close a
    // loop that the two triangles (circumradius² 2) fill; the diagonal is Gabriel (its
    // opposite vertices lie on its diametral circle) and enters at 2 with them.
    let d = diagram(&[[0.0, 0.0, 5.0], [2.0, 0.0, 5.0], [0.0, 2.0, 5.0], [2.0, 2.0, 5.0]]);
    assert_eq!(d[0], vec![(0.0, 1.0), (0.0, 1.0), (0.0, 1.0), (0.0, f64::INFINITY)]);
    assert_eq!(d[1], vec![(1.0, 2.0)]);
    assert!(d[2].is_empty());
}

#[test]
fn non_finite_points_are_rejected() {
    let e = alpha_persistence(&[[0.0, 0.0, 0.0], [f64::NAN, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        .unwrap_err();
    assert!(e.to_string().contains("point 1"), "{e}");
}

/// Full boundary-matrix reduction over Z/2 of every simplex, in the same total order: an
/// independent check of the union-find / duality / compression shortcuts.
fn naive_diagram(pts: &[Point]) -> [Vec<(f64, f64)>; 3] {
    let c = DelaunayComplex::new(pts).unwrap();
    let f = Filtration::new(&c);
    // (dim, id) in filtration order: vertices, then edges/triangles/tets merged by exact value.
    let mut order: Vec<(usize, u32)> = (0..c.points.len() as u32).map(|v| (0, v)).collect();
    let mut rest: Vec<(usize, u32)> = Vec::new();
    rest.extend(f.edge_order.iter().map(|&e| (1, e)));
    rest.extend(f.triangle_order.iter().map(|&t| (2, t)));
    rest.extend(f.tet_order.iter().map(|&t| (3, t)));
    let val = |s: &(usize, u32)| match s.0 {
        1 => f.edges[s.1 as usize],
        2 => f.triangles[s.1 as usize],
        _ => f.tets[s.1 as usize],
    };
    let rank_in = |s: &(usize, u32)| match s.0 {
        1 => f.edge_order.iter().position(|&x| x == s.1).unwrap(),
        2 => f.triangle_order.iter().position(|&x| x == s.1).unwrap(),
        _ => f.tet_order.iter().position(|&x| x == s.1).unwrap(),
    };
    rest.sort_by(|a, b| f.cmp(val(a), val(b)).then(a.0.cmp(&b.0)).then(rank_in(a).cmp(&rank_in(b))));
    order.extend(rest);
    let mut pos = std::collections::HashMap::new();
    for (i, s) in order.iter().enumerate() {
        pos.insert(*s, i);
    }
    let verts = |s: &(usize, u32)| -> Vec<u32> {
        match s.0 {
            0 => vec![s.1],
            1 => c.edges[s.1 as usize].to_vec(),
            2 => c.triangles[s.1 as usize].to_vec(),
            _ => c.tets[s.1 as usize].to_vec(),
        }
    };
    let mut face_id = std::collections::HashMap::new();
    for s in &order {
        let mut v = verts(s);
        v.sort();
        face_id.insert(v, *s);
    }
    let value = |s: &(usize, u32)| if s.0 == 0 { 0.0 } else { val(s).value };
    let mut low_owner: std::collections::HashMap<usize, Vec<usize>> = Default::default();
    let mut out: [Vec<(f64, f64)>; 3] = Default::default();
    let mut paired = vec![false; order.len()];
    for (j, s) in order.iter().enumerate() {
        let mut col: Vec<usize> = Vec::new();
        if s.0 > 0 {
            let v = verts(s);
            for skip in 0..v.len() {
                let mut face: Vec<u32> =
                    v.iter().enumerate().filter(|(k, _)| *k != skip).map(|(_, &x)| x).collect();
                face.sort();
                col.push(pos[&face_id[&face]]);
            }
            col.sort();
        }
        while let Some(&low) = col.last() {
            match low_owner.get(&low) {
                Some(other) => {
                    let mut merged: Vec<usize> = col.iter().filter(|x| !other.contains(x)).copied().collect();
                    merged.extend(other.iter().filter(|x| !col.contains(x)));
                    merged.sort();
                    col = merged;
                }
                None => break,
            }
        }
        if let Some(&low) = col.last() {
            low_owner.insert(low, col.clone());
            paired[low] = true;
            paired[j] = true;
            let b = &order[low];
            // Vertices are born at 0 and every edge value is positive; otherwise the engine's
            // zero-length rule (this oracle checks the pairing, not that rule).
            let pair = if b.0 == 0 { Some((0.0, value(s))) } else { f.pair_values(val(b), val(s)) };
            if let Some(p) = pair {
                out[b.0].push(p);
            }
        }
    }
    for (i, s) in order.iter().enumerate() {
        if !paired[i] && s.0 < 3 {
            out[s.0].push((value(s), f64::INFINITY));
        }
    }
    out
}

fn random_cloud(n: usize, seed: u64) -> Vec<Point> {
    let mut rng = SplitMix64(seed);
    (0..n).map(|_| [rng.next_f64(), rng.next_f64(), rng.next_f64()]).collect()
}

#[test]
fn fast_pairing_equals_naive_reduction() {
    let mut clouds: Vec<Vec<Point>> = (0..4).map(|s| random_cloud(60 + 20 * s as usize, s)).collect();
    // Degenerate ones too: a small lattice and a co-planar set.
    let mut lattice = Vec::new();
    for i in 0..27 {
        lattice.push([(i % 3) as f64, (i / 3 % 3) as f64, (i / 9) as f64]);
    }
    clouds.push(lattice);
    clouds.push(random_cloud(40, 99).into_iter().map(|p| [p[0], p[1], 0.25]).collect());
    for (k, pts) in clouds.iter().enumerate() {
        let fast = by_dim(&persistence(&Filtration::new(&DelaunayComplex::new(pts).unwrap())));
        let naive = naive_diagram(pts);
        assert_diagrams_match(&fast, &naive, 0.0, &format!("cloud {k}"));
    }
}

/// Euler characteristic of the Delaunay complex of a point set in general position is 1
/// (a triangulated ball); every tetrahedron is positive and its circumsphere empty.
fn check_delaunay(pts: &[Point]) {
    let c = DelaunayComplex::new(pts).unwrap();
    let [v, e, t, k] = c.simplex_counts();
    assert_eq!(v as i64 - e as i64 + t as i64 - k as i64, 1, "Euler characteristic");
    let coord = |i: u32| {
        let p = c.points[i as usize];
        robust::Coord3D { x: p[0], y: p[1], z: p[2] }
    };
    for tet in &c.tets {
        assert!(robust::orient3d(coord(tet[0]), coord(tet[1]), coord(tet[2]), coord(tet[3])) > 0.0);
        for q in 0..c.points.len() as u32 {
            if !tet.contains(&q) {
                let s =
                    robust::insphere(coord(tet[0]), coord(tet[1]), coord(tet[2]), coord(tet[3]), coord(q));
                assert!(s <= 0.0, "vertex {q} strictly inside the circumsphere of {tet:?}");
            }
        }
    }
}

#[test]
fn delaunay_is_empty_sphere_on_degenerate_inputs() {
    let mut lattice = Vec::new();
    for i in 0..64 {
        lattice.push([(i % 4) as f64, (i / 4 % 4) as f64, (i / 16) as f64]);
    }
    check_delaunay(&lattice);
    // 5 mm quantized points, like NCLT.
    let q: Vec<Point> =
        random_cloud(300, 5).iter().map(|p| p.map(|x| (x * 40.0).round() * 0.005 - 100.0)).collect();
    check_delaunay(&q);
}

fn rotate(p: &Point, m: &[[f64; 3]; 3], t: &Point) -> Point {
    [0, 1, 2].map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + t[i])
}

fn rotation(a: f64, b: f64, c: f64) -> [[f64; 3]; 3] {
    let (sa, ca, sb, cb, sc, cc) = (a.sin(), a.cos(), b.sin(), b.cos(), c.sin(), c.cos());
    [
        [ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
        [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
        [-sb, cb * sc, cb * cc],
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// Rigid motions and permutations leave the diagram unchanged within floating tolerance
    /// (1e-9 relative: a rotation moves coordinates by ~1e-16 relative).
    #[test]
    fn diagram_invariant_under_rigid_motion_and_permutation(
        seed in 0u64..1_000_000, n in 20usize..150,
        a in 0.0f64..6.3, b in 0.0f64..6.3, c in 0.0f64..6.3,
        tx in -10.0f64..10.0, ty in -10.0f64..10.0, tz in -10.0f64..10.0,
    ) {
        let pts = random_cloud(n, seed);
        let m = rotation(a, b, c);
        let mut moved: Vec<Point> = pts.iter().map(|p| rotate(p, &m, &[tx, ty, tz])).collect();
        // A seeded permutation.
        let mut rng = SplitMix64(seed ^ 0xABCD);
        for i in (1..moved.len()).rev() {
            let j = (rng.next_f64() * (i + 1) as f64) as usize;
            moved.swap(i, j.min(i));
        }
        assert_diagrams_match(&diagram(&moved), &diagram(&pts), 1e-9, "moved");
    }

    /// Every tetrahedron of the triangulation passes an exact empty-sphere check.
    #[test]
    fn delaunay_empty_sphere_on_random_clouds(seed in 0u64..1_000_000, n in 5usize..120) {
        check_delaunay(&random_cloud(n, seed));
    }

    /// The filtered predicates agree in sign with `robust`'s exact ones, near-degenerate
    /// inputs included (points on a coarse grid).
    #[test]
    fn filtered_predicates_agree_with_exact(seed in 0u64..1_000_000, grid in prop::bool::ANY) {
        let mut pts = random_cloud(5, seed);
        if grid {
            for p in &mut pts { *p = p.map(|x| (x * 4.0).round()); }
        }
        let c = |p: &Point| robust::Coord3D { x: p[0], y: p[1], z: p[2] };
        let o = toporec::homology::delaunay::orient3d(&pts[0], &pts[1], &pts[2], &pts[3]);
        let r = robust::orient3d(c(&pts[0]), c(&pts[1]), c(&pts[2]), c(&pts[3]));
        prop_assert_eq!(o.signum() * (o != 0.0) as i32 as f64, r.signum() * (r != 0.0) as i32 as f64);
        let s = toporec::homology::delaunay::insphere(&pts[0], &pts[1], &pts[2], &pts[3], &pts[4]);
        let t = robust::insphere(c(&pts[0]), c(&pts[1]), c(&pts[2]), c(&pts[3]), c(&pts[4]));
        prop_assert_eq!(s.signum() * (s != 0.0) as i32 as f64, t.signum() * (t != 0.0) as i32 as f64);
    }
}

#[test]
fn real_nclt_scan_matches_gudhi_exact_counts() {
    // GUDHI 3.13 on this scan (23,540 distinct points): exact (23540, 17409, 5546);
    // safe (23540, 17549, 5631) and fast (23540, 17480, 5633) keep sub-ulp pairs that the
    // 5 mm quantization creates (GUDHI 3.13, run on this scan). toporec follows `exact`.
    let Some(data) = shared_data("real_nclt_scan_matches_gudhi_exact_counts") else { return };
    let pts = read_cloud(&data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"));
    assert_eq!(pts.len(), 23_546);
    assert_eq!(alpha_persistence(&pts).unwrap().counts(), [23_540, 17_409, 5_546]);
}

#[test]
fn random_clouds_match_gudhi_exact() {
    // 40 clouds (generic, 5 mm-quantized, lattices with duplicates, near-planar) through the
    // binary and through GUDHI 3.13 `precision='exact'`: scripts/gudhi_crosscheck.py.
    if !python_with("random_clouds_match_gudhi_exact", &["gudhi", "numpy"]) {
        return;
    }
    let o = std::process::Command::new("python3")
        .arg(root().join("scripts/gudhi_crosscheck.py"))
        .args(["--toporec", env!("CARGO_BIN_EXE_toporec"), "--clouds", "40"])
        .output()
        .unwrap();
    let out = text(&o.stdout);
    println!("{out}");
    assert!(o.status.success(), "{out}{}", text(&o.stderr));
    assert!(out.contains("40 of 40 clouds match GUDHI exact"), "{out}");
}

/// `x · 2^k` (exact for results in the normal range).
fn times_pow2(x: f64, k: i32) -> f64 {
    let (a, b) = (k / 2, k - k / 2);
    x * 2f64.powi(a) * 2f64.powi(b)
}

#[test]
fn scaled_clouds_give_exactly_scaled_diagrams() {
    // Scaling by 2^k is exact in floating point, so the diagram of 2^k · P must be exactly
    // 4^k times that of P (squared radii), for every k that keeps those values normal.
    let mut clouds = vec![(
        "unit_cube_300_rng1",
        read_cloud(&root().join("tests/fixtures/clouds/unit_cube_300_rng1.csv")),
    )];
    if let Some(data) = shared_data("scaled KITTI scan") {
        let kitti = read_cloud(&data.join("kitti/sequences/00/velodyne/000000.bin"));
        clouds.push(("kitti_00_000000 (every 60th point)", kitti.into_iter().step_by(60).collect()));
    }
    for (name, cloud) in clouds {
        let reference = alpha_persistence(&cloud).unwrap();
        for k in (-400..=400).step_by(7) {
            let scaled: Vec<Point> = cloud.iter().map(|p| p.map(|c| times_pow2(c, k))).collect();
            let d = alpha_persistence(&scaled).unwrap_or_else(|e| panic!("{name}, k = {k}: {e}"));
            assert_eq!(d.len(), reference.len(), "{name}, k = {k}: pair count");
            for (a, b) in d.pairs().iter().zip(reference.pairs()) {
                let (birth, death) = (times_pow2(b.birth, 2 * k), times_pow2(b.death, 2 * k));
                assert!(
                    a.dim == b.dim && a.birth == birth && a.death == death,
                    "{name}, k = {k}: {a:?} vs {b:?}"
                );
            }
        }
        // Beyond: exactly scaled, or refused with the range named; never a panic.
        for k in (-1000..=1000).step_by(37).filter(|k: &i32| k.abs() > 400) {
            let scaled: Vec<Point> = cloud.iter().map(|p| p.map(|c| times_pow2(c, k))).collect();
            match std::panic::catch_unwind(|| alpha_persistence(&scaled)) {
                Ok(Ok(d)) => assert_eq!(d.len(), reference.len(), "{name}, k = {k}"),
                Ok(Err(e)) => {
                    assert!(e.to_string().contains("range of doubles") || e.to_string().contains("2^"), "{e}")
                }
                Err(_) => panic!("{name}, k = {k}: panicked"),
            }
        }
    }
}

#[test]
fn scaled_clouds_beyond_the_band_match_gudhi_exact_or_are_refused() {
    // Outside |k| <= 400, each 2^k-scaled cloud gives GUDHI `exact`'s diagram of the same input,
    // or a one-line refusal naming the supported range: scripts/gudhi_scale_check.py.
    if !python_with("scaled_clouds_beyond_the_band", &["gudhi", "numpy"]) {
        return;
    }
    let mut clouds = vec![root().join("tests/fixtures/clouds/unit_cube_300_rng1.csv")];
    if let Some(data) = shared_data("scaled KITTI scan beyond the band") {
        let kitti = read_cloud(&data.join("kitti/sequences/00/velodyne/000000.bin"));
        let dir = scratch_dir("homology_scale_check");
        let path = dir.join("kitti_00_000000_every_60th.csv");
        let mut text = String::from("x,y,z\n");
        for p in kitti.iter().step_by(60) {
            text += &format!("{:?},{:?},{:?}\n", p[0], p[1], p[2]);
        }
        std::fs::write(&path, text).unwrap();
        clouds.push(path);
    }
    let o = std::process::Command::new("python3")
        .arg(root().join("scripts/gudhi_scale_check.py"))
        .args(["--toporec", env!("CARGO_BIN_EXE_toporec")])
        .args(&clouds)
        .output()
        .unwrap();
    let out = text(&o.stdout);
    println!("{out}");
    assert!(o.status.success(), "{out}{}", text(&o.stderr));
}

/// Every bit of a located diagram: dimension, birth, death and where the class dies.
fn located_bits(pts: &[Point]) -> Vec<(u8, u64, u64, Option<[u64; 3]>)> {
    toporec::homology::alpha_persistence_located(pts)
        .unwrap()
        .iter()
        .map(|l| {
            (l.pair.dim, l.pair.birth.to_bits(), l.pair.death.to_bits(), l.at.map(|p| p.map(f64::to_bits)))
        })
        .collect()
}

#[test]
fn diagrams_and_located_pairs_are_bit_identical_for_any_thread_count() {
    // Large enough that the filtration and persistence split across threads (at least 2,048
    // points, tens of thousands of simplices), general position and degenerate: a 2
    // cm-quantized LiDAR-like cloud has many co-spherical and tied simplices.
    let lidar = read_cloud(&root().join("tests/fixtures/clouds/lidar_like_4096.csv"));
    let quantized: Vec<Point> = lidar.iter().map(|p| p.map(|c| (c * 50.0).round() / 50.0)).collect();
    let mut lattice = Vec::new();
    for i in 0..13 * 13 * 13 {
        lattice.push([(i % 13) as f64, (i / 13 % 13) as f64, (i / 169) as f64]);
    }
    for (name, pts) in [
        ("lidar_like_4096", lidar),
        ("quantized", quantized),
        ("lattice", lattice),
        ("random", random_cloud(12_000, 5)),
    ] {
        let pool = |n: usize| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        let one = pool(1).install(|| (alpha_persistence(&pts).unwrap(), located_bits(&pts)));
        assert!(one.0.counts()[1] > 0, "{name}: a diagram with loops");
        for threads in [2, 3, 4] {
            let many = pool(threads).install(|| (alpha_persistence(&pts).unwrap(), located_bits(&pts)));
            let bits = |d: &toporec::homology::Diagram| {
                d.pairs().iter().map(|p| (p.dim, p.birth.to_bits(), p.death.to_bits())).collect::<Vec<_>>()
            };
            assert_eq!(bits(&one.0), bits(&many.0), "{name}: diagram on {threads} threads");
            assert_eq!(one.1, many.1, "{name}: located pairs on {threads} threads");
        }
    }
}
