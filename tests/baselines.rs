//! ScanContext and M2DP: hand-made clouds with known answers, and a cross-check against the
//! numpy transcription of the reference code (`scripts/baselines_reference.py`) on the real
//! scans of `../shared/data`.

use crate::util::{self, python_with, root, shared_data};
use toporec::homology::Point;
use toporec::methods::Computed as _;
use toporec::methods::m2dp;
use toporec::methods::scancontext::{self, ScanContextParams};
use toporec::methods::scancontext_pp::{self, CartParams, PolarParams, Variant};
use toporec::methods::solid::{self, SolidParams};

pub(crate) fn turned(points: &[Point], degrees: f64) -> Vec<Point> {
    let (s, c) = degrees.to_radians().sin_cos();
    points.iter().map(|p| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]).collect()
}

/// A cloud with one point at the centre of every third bin, heights varying by bin.
fn bin_centre_cloud(p: &ScanContextParams) -> Vec<Point> {
    let mut out = Vec::new();
    for ring in 0..p.rings {
        for sector in (0..p.sectors).filter(|s| (s * 7 + ring) % 3 != 0) {
            let r = (ring as f64 + 0.5) * p.max_radius / p.rings as f64;
            let theta = ((sector as f64 + 0.5) * 360.0 / p.sectors as f64).to_radians();
            let z = ((ring * 31 + sector * 17) % 23) as f64 * 0.25 - 1.5;
            out.push([r * theta.cos(), r * theta.sin(), z]);
        }
    }
    out
}

#[test]
fn scancontext_puts_a_point_in_its_bin_with_the_height_offset() {
    let p = ScanContextParams::default();
    // r = 14.14 m -> ring ceil(14.14 / 80 * 20) = 4; azimuth 45 deg -> sector ceil(45 / 6) = 8.
    let sc = scancontext::describe(&[[10.0, 10.0, 1.0], [10.0, 10.0, 0.5]], &p);
    assert_eq!(sc.len(), 1200);
    let at = 3 * 60 + 7;
    assert_eq!(sc[at], 3.0, "max z + lidar height 2 m");
    assert_eq!(sc.iter().filter(|&&v| v != 0.0).count(), 1, "every other bin empty");
    // Azimuth 200 deg (third quadrant), r = 50 m -> ring 13, sector ceil(200 / 6) = 34.
    let (s, c) = 200f64.to_radians().sin_cos();
    let sc = scancontext::describe(&[[50.0 * c, 50.0 * s, -0.5]], &p);
    assert_eq!(sc[12 * 60 + 33], 1.5);
    // Beyond 80 m: left out (the C++ reference; MATLAB would use the last ring).
    let sc = scancontext::describe(&[[81.0, 0.0, 1.0]], &p);
    assert!(sc.iter().all(|&v| v == 0.0));
    // The keys: ring means and sector means.
    let sc = scancontext::describe(&[[10.0, 10.0, 1.0]], &p);
    let rk = scancontext::ring_key(&sc, &p);
    assert!((rk[3] - 3.0 / 60.0).abs() < 1e-7);
    let sk = scancontext::sector_key(&sc, &p);
    assert!((sk[7] - 3.0 / 20.0).abs() < 1e-12);
}

#[test]
fn scancontext_of_a_turned_scan_matches_at_the_turning_shift() {
    let p = ScanContextParams::default();
    let cloud = bin_centre_cloud(&p);
    let original = scancontext::describe(&cloud, &p);
    for (degrees, shift) in [(42.0, 7usize), (6.0, 1), (180.0, 30), (354.0, 59), (0.0, 0)] {
        let query = scancontext::describe(&turned(&cloud, degrees), &p);
        let (d, s) = scancontext::distance(&query, &original, &p);
        assert_eq!(s, shift, "turned by {degrees} deg");
        assert!(d.abs() < 1e-9, "turned by {degrees} deg: distance {d}");
        assert!((scancontext::yaw_degrees(s, &p) - degrees).abs() < 1e-9);
    }
    // Another place: a clearly larger distance.
    let other: Vec<Point> = cloud.iter().map(|q| [q[0], q[1], -q[2] * 0.5 + 3.0]).collect();
    let (d, _) = scancontext::distance(&scancontext::describe(&other, &p), &original, &p);
    assert!(d > 0.01, "distance to another place {d}");
}

/// A cloud with clearly different spreads along three skewed axes.
fn anisotropic_cloud() -> Vec<Point> {
    let mut rng = toporec::rng::SplitMix64(7);
    (0..3000)
        .map(|_| {
            let (a, b, c) = (rng.next_f64() - 0.5, rng.next_f64() - 0.5, rng.next_f64() - 0.5);
            [40.0 * a + 3.0 * b, 15.0 * b - 2.0 * c, 4.0 * c + 0.5 * a]
        })
        .collect()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn m2dp_is_invariant_to_rotations_the_sign_convention_keeps() {
    let cloud = anisotropic_cloud();
    let d0 = m2dp::describe(&cloud);
    assert_eq!(d0.len(), 192);
    let norm = |v: &[f32]| v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    assert!((norm(&d0[..64]) - 1.0).abs() < 1e-6 && (norm(&d0[64..]) - 1.0).abs() < 1e-6);
    assert!(d0[..64].iter().sum::<f32>() >= 0.0, "left singular vector signed to a non-negative sum");
    // Small rotations about z (here up to 35 deg) keep each principal axis' largest component positive,
    // so the aligned cloud, and the descriptor, are unchanged; so are a shift and the order.
    for degrees in [10.0, -30.0, 35.0] {
        let d = m2dp::describe(&turned(&cloud, degrees));
        assert!(max_abs_diff(&d, &d0) < 1e-5, "turned {degrees} deg: {}", max_abs_diff(&d, &d0));
    }
    let shifted: Vec<Point> = cloud.iter().rev().map(|p| [p[0] + 100.0, p[1] - 7.0, p[2] + 2.0]).collect();
    assert!(max_abs_diff(&m2dp::describe(&shifted), &d0) < 1e-5);
    // A turn of 180 deg makes the convention pick the other sign of the first two axes: the
    // aligned cloud is the original's turned 180 deg about its third axis, which M2DP (as the
    // reference) does not see as the same cloud.
    let d = m2dp::describe(&turned(&cloud, 180.0));
    assert!(max_abs_diff(&d, &d0) > 1e-3, "turned 180 deg: {}", max_abs_diff(&d, &d0));
    // Degenerate clouds: zeros, not a panic.
    assert!(m2dp::describe(&[[1.0, 2.0, 3.0]]).iter().all(|&v| v == 0.0));
    assert!(m2dp::describe(&[[1.0, 2.0, 3.0]; 10]).iter().all(|&v| v == 0.0));
    // Another place: another descriptor.
    let other: Vec<Point> = cloud.iter().map(|p| [p[0], p[1] * 0.2, p[2] + p[0] * 0.3]).collect();
    assert!(max_abs_diff(&m2dp::describe(&other), &d0) > 1e-2);
}

/// A line `<cloud>,<kind>,<values…>` that a reference transcription printed.
pub(crate) struct ReferenceLine {
    /// Which of the scans it is about.
    pub cloud: usize,
    pub kind: String,
    pub values: Vec<f64>,
}

/// The clouds of `scans` as toporec reads them, handed to `scripts/SCRIPT` as exact CSV in
/// a scratch folder `name`: the clouds, and the lines the script printed.
pub(crate) fn reference_output(
    name: &str,
    script: &str,
    scans: &[std::path::PathBuf],
) -> (Vec<Vec<Point>>, Vec<ReferenceLine>) {
    let dir = util::scratch_dir(name);
    let mut csvs = Vec::new();
    let mut clouds = Vec::new();
    for (i, scan) in scans.iter().enumerate() {
        let cloud = util::read_cloud(scan);
        let path = dir.join(format!("cloud{i}.csv"));
        let mut text = String::from("x,y,z\n");
        for p in &cloud {
            text.push_str(&format!("{:?},{:?},{:?}\n", p[0], p[1], p[2]));
        }
        std::fs::write(&path, text).unwrap();
        csvs.push(path);
        clouds.push(cloud);
    }
    let out = std::process::Command::new("python3")
        .arg(root().join("scripts").join(script))
        .args(&csvs)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let lines = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            ReferenceLine {
                cloud: csvs.iter().position(|c| c.to_str() == Some(fields[0])).expect("a cloud of ours"),
                kind: fields[1].to_string(),
                values: fields[2..].iter().map(|v| v.parse().unwrap()).collect(),
            }
        })
        .collect();
    (clouds, lines)
}

/// ScanContext and M2DP equal the numpy transcription of the reference code within 1e-6 on
/// real KITTI and NCLT scans (the clouds as toporec reads them, handed over as exact CSV).
#[test]
fn baselines_match_the_reference_transcription_on_real_scans() {
    let Some(data) = shared_data("baselines_match_the_reference_transcription_on_real_scans") else { return };
    if !python_with("baselines_match_the_reference_transcription_on_real_scans", &["numpy"]) {
        return;
    }
    let scans = [
        data.join("kitti/sequences/00/velodyne/000000.bin"),
        data.join("kitti/sequences/08/velodyne/000006.bin"),
        data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"),
    ];
    let (clouds, lines) = reference_output("baselines_reference", "baselines_reference.py", &scans);
    let p = ScanContextParams::default();
    let mut checked = 0;
    for line in &lines {
        let (i, kind, values) = (line.cloud, line.kind.as_str(), &line.values);
        let ours: Vec<f64> = match kind {
            "scancontext" => scancontext::describe(&clouds[i], &p).iter().map(|&v| v as f64).collect(),
            "m2dp" => m2dp::describe(&clouds[i]).iter().map(|&v| v as f64).collect(),
            "scdist" => {
                let q = scancontext::describe(&turned(&clouds[i], 42.0), &p);
                let (d, s) = scancontext::distance(&q, &scancontext::describe(&clouds[i], &p), &p);
                assert!((6..=8).contains(&s), "{}: a 42 deg turn found at shift {s}", scans[i].display());
                vec![d, s as f64]
            }
            other => panic!("unknown line kind {other}"),
        };
        assert_eq!(ours.len(), values.len(), "{} {}", scans[i].display(), kind);
        let worst = ours.iter().zip(values).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(worst <= 1e-6, "{} {}: max difference {worst:e}", scans[i].display(), kind);
        println!("{} {}: {} values, max difference {worst:e}", scans[i].display(), kind, ours.len());
        checked += 1;
    }
    assert_eq!(checked, 3 * scans.len());
}

/// SOLiD by hand, default settings (HDL-64E: 40 range bins of 2 m, 60 azimuth bins of 6°, 32
/// elevation bins of 26.8° / 32 = 0.8375° from −24.8°).
#[test]
fn solid_by_hand() {
    let p = SolidParams::default();
    let at = |d: f64, deg: f64, z: f64| -> Point {
        let (s, c) = deg.to_radians().sin_cos();
        [d * c, d * s, z]
    };
    // A: range 10 m (bin 5), 3° (azimuth bin 0), level (elevation 24.8 / 0.8375 = 29.6: bin 29).
    // B: 21 m (bin 10), 93° (bin 15), z = −2: atan(2 / 21) = 5.44°, (24.8 − 5.44) / 0.8375 = 23.1:
    //    bin 23. C: 31 m (bin 15), 183° (bin 30), z = −2.5: 4.61°, 24.1: bin 24.
    // D: 21 m (bin 10), 213° (bin 35), z = −2: bin 23.
    let (a, b, c, d) =
        (at(10.0, 3.0, 0.0), at(21.0, 93.0, -2.0), at(31.0, 183.0, -2.5), at(21.0, 213.0, -2.0));
    // Elevation counts: bin 29: 1, bin 23: 2, bin 24: 1, the other 29 bins 0; min-max
    // normalised: 0.5, 1, 0.5. r: range bin 5: 0.5 (A), 10: 1 + 1 (B, D), 15: 0.5 (C).
    // a: azimuth bin 0: 0.5, 15: 1, 30: 0.5, 35: 1.
    let full = solid::describe(&[a, b, c, d], &p);
    let mut r = vec![0.0f32; 40];
    (r[5], r[10], r[15]) = (0.5, 2.0, 0.5);
    let mut az = vec![0.0f32; 60];
    (az[0], az[15], az[30], az[35]) = (0.5, 1.0, 0.5, 1.0);
    assert_eq!(full, [r, az].concat());
    // Without B and D the weights are 1 (bins 29 and 24) and r = (1 at bin 5, 1 at bin 15): the
    // cosine with (0.5, 2, 0.5) is (0.5 + 0.5) / (√4.5 · √2) = 1 / 3.
    let two = solid::describe(&[a, c], &p);
    assert!((solid::distance(&two, &full, &p) - 2.0 / 3.0).abs() < 1e-12);
    // Turned by 90° (15 azimuth bins): the same r, distance 0, and the shift of 15 bins, 90°.
    let turned_full = solid::describe(&turned(&[a, b, c, d], 90.0), &p);
    assert!(solid::distance(&turned_full, &full, &p).abs() < 1e-12);
    let shift = solid::yaw_shift(&turned_full, &full, &p);
    assert_eq!((shift, solid::yaw_degrees(shift, &p)), (15, 90.0));
    // The preprocessing drops what is within 3 m or beyond 80 m (3D distance).
    let kept = solid::preprocess(
        &[a, [2.0, 1.0, 0.5], [79.0, 0.0, 13.0], b],
        &SolidParams { voxel: 0.0, ..p.clone() },
    );
    assert_eq!(kept, [a, b]);
    // An empty scan: all zero, at distance 1 from any scan.
    let empty = solid::describe(&[], &p);
    assert!(empty.iter().all(|&v| v == 0.0));
    assert_eq!(solid::distance(&empty, &full, &p), 1.0);
}

/// What a cross-check of SOLiD, Scan Context++ or LiDAR-Iris runs on: three KITTI scans and an
/// NCLT one, the clouds as read, and the lines `script` (in `scripts/`) prints for them. `None` (a skip, or a failure in CI) without `../shared/data` or numpy.
#[allow(clippy::type_complexity)]
fn cross_check(
    test: &str,
    script: &str,
) -> Option<([std::path::PathBuf; 4], Vec<Vec<Point>>, Vec<ReferenceLine>)> {
    let data = shared_data(test)?;
    if !python_with(test, &["numpy"]) {
        return None;
    }
    let scans = [
        data.join("kitti/sequences/00/velodyne/000000.bin"),
        data.join("kitti/sequences/08/velodyne/000006.bin"),
        data.join("kitti/sequences/05/velodyne/000003.bin"),
        data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"),
    ];
    let (clouds, lines) = reference_output(script.trim_end_matches(".py"), script, &scans);
    Some((scans, clouds, lines))
}

/// SOLiD equals the numpy transcription of the reference code (`scripts/solid_reference.py`)
/// on real KITTI and NCLT scans, within 1e-6 relative (values) and 1e-9 (distances), and both
/// find a turn by 42° at the same shift.
#[test]
fn solid_matches_the_reference_transcription_on_real_scans() {
    let test = "solid_matches_the_reference_transcription_on_real_scans";
    let Some((scans, clouds, lines)) = cross_check(test, "solid_reference.py") else { return };
    // No voxel grid: the reference's (PCL, Open3D) and toporec's place their cells differently.
    let p = SolidParams { voxel: 0.0, ..SolidParams::default() };
    let ours = |cloud: &[Point]| solid::describe(&solid::preprocess(cloud, &p), &p);
    let mut checked = 0;
    for line in &lines {
        let (i, kind, values) = (line.cloud, line.kind.as_str(), &line.values);
        let name = scans[i].display();
        match kind {
            "solid" => {
                let d: Vec<f64> = ours(&clouds[i]).iter().map(|&v| v as f64).collect();
                assert_eq!(d.len(), values.len(), "{name}");
                assert!(d.iter().any(|&v| v > 0.0), "{name}: an empty descriptor");
                let worst =
                    d.iter().zip(values).map(|(a, b)| (a - b).abs() / b.abs().max(1.0)).fold(0.0, f64::max);
                assert!(worst <= 1e-6, "{name}: max relative difference {worst:e}");
                println!("{name} solid: {} values, max relative difference {worst:e}", d.len());
            }
            "soliddist" => {
                let (q, c) = (ours(&turned(&clouds[i], 42.0)), ours(&clouds[i]));
                let (dist, shift) = (solid::distance(&q, &c, &p), solid::yaw_shift(&q, &c, &p));
                assert!((dist - values[0]).abs() <= 1e-9, "{name}: distance {dist} against {}", values[0]);
                assert_eq!(shift as f64, values[1], "{name}: shift");
                assert_eq!(shift, 7, "{name}: a 42° turn is 7 azimuth bins");
                println!("{name} soliddist: {dist:e}, shift {shift}");
            }
            other => panic!("unknown line kind {other}"),
        }
        checked += 1;
    }
    assert_eq!(checked, 2 * scans.len());
}

/// Scan Context++ worked by hand on a few points.
#[test]
fn scancontext_pp_by_hand() {
    let p = PolarParams { voxel: 0.0, min_points: 2, ..PolarParams::default() };
    // Five points at (11, 11) and two at (−31, 0.5), z = 0.1 + 0.1 i; the lidar height adds
    // 1.9 m. From the sensor: r = 15.56 m, ring ⌊15.56 / 4⌋ = 3, azimuth 45°, sector
    // ⌈45 / 6⌉ = 8 → bin (3, 7), top z 0.5 + 1.9 = 2.4; r = 31.00 m, ring 7, azimuth 179.08°,
    // sector ⌈29.85⌉ = 30 → bin (7, 29), 0.7 + 1.9 = 2.6. A lone point at (51, 0.5) has too
    // few (1 < 2): its bin stays 0.
    let mut cloud: Vec<Point> = (1..=5).map(|i| [11.0, 11.0, 0.1 * i as f64]).collect();
    cloud.extend([[-31.0, 0.5, 0.6], [-31.0, 0.5, 0.7], [51.0, 0.5, 9.0]]);
    let d = scancontext_pp::describe_polar(&cloud, &p);
    assert_eq!(d.len(), 3 * 1200);
    let own = &d[..1200];
    assert!((own[3 * 60 + 7] - 2.4).abs() < 1e-6 && (own[7 * 60 + 29] - 2.6).abs() < 1e-6);
    assert_eq!(own.iter().filter(|&&v| v != 0.0).count(), 2);
    // The second copy's origin is at (0, −2): the first group is at (11, 13), r = 17.03 m
    // (ring 4), azimuth 49.76° (sector ⌈8.29⌉ = 9).
    let moved = &d[1200..2400];
    assert!((moved[4 * 60 + 8] - 2.4).abs() < 1e-6);
    // A scan is at distance 0 from itself, and a copy matches the scan seen from 2 m aside (a
    // sensor at (0, −2) sees every point 2 m further along y).
    let v = Variant::Polar(p.clone());
    assert_eq!(scancontext_pp::compare(&d, &d, &v).distance, 0.0);
    let aside: Vec<Point> = cloud.iter().map(|q| [q[0], q[1] + 2.0, q[2]]).collect();
    let query = scancontext_pp::describe_polar(&aside, &p);
    let m = scancontext_pp::compare(&query, &d, &v);
    assert!(m.distance < 1e-12 && m.shift == 0, "{m:?}");
    // Turned by 90° (15 sectors): the yaw is 90°.
    let q = scancontext_pp::describe_polar(&turned(&cloud, 90.0), &p);
    let m = scancontext_pp::compare(&q, &d, &v);
    assert_eq!((m.distance < 1e-12, m.yaw_degrees(&v)), (true, 90.0));

    // The Cartesian context: (11, 11) is row ⌊111 / 5⌋ = 22, column ⌊51 / 2⌋ = 25; (−31, 0.5)
    // row ⌊69 / 5⌋ = 13, column ⌊40.5 / 2⌋ = 20; (51, 0.5) row 30, column 20 (no minimum count
    // here). No point lies on a bin edge, so turning by 180° reverses the bins exactly.
    let c = CartParams { voxel: 0.0, ..CartParams::default() };
    let cc = scancontext_pp::describe_cart(&cloud, &c);
    assert_eq!((c.rows(), c.columns(), cc.len()), (40, 40, 1600));
    let at = |row: usize, col: usize| cc[row * 40 + col];
    assert!((at(22, 25) - 2.4).abs() < 1e-6 && (at(13, 20) - 2.6).abs() < 1e-6);
    assert!((at(30, 20) - 10.9).abs() < 1e-6);
    assert_eq!(cc.iter().filter(|&&v| v != 0.0).count(), 3);
    // Driven the other way: the scan turned by 180° (its bins reversed) matches, reversed.
    let v = Variant::Cart(c.clone());
    let back = scancontext_pp::describe_cart(&turned(&cloud, 180.0), &c);
    let m = scancontext_pp::compare(&back, &cc, &v);
    assert!(m.distance < 1e-12 && m.reversed, "{m:?}");
    assert_eq!(m.yaw_degrees(&v), 180.0);
    let no_reverse = Variant::Cart(CartParams { reverse: false, ..c.clone() });
    assert!(scancontext_pp::compare(&back, &cc, &no_reverse).distance > 0.1);
    // Moved 2 m to the right (y − 2, one column down): the candidate's column 25 lines up with
    // the query's 24, a shift of −1 ≡ 39.
    let right: Vec<Point> = cloud.iter().map(|q| [q[0], q[1] - 2.0, q[2]]).collect();
    let m = scancontext_pp::compare(&scancontext_pp::describe_cart(&right, &c), &cc, &v);
    assert!(m.distance < 1e-12 && !m.reversed && m.shift == 39, "{m:?}");
}

/// Scan Context++ equals the numpy transcription of the reference code
/// (`scripts/scancontext_pp_reference.py`) on real KITTI and NCLT scans: contexts within 1e-6
/// relative, distances within 1e-9, the same shifts.
#[test]
fn scancontext_pp_matches_the_reference_transcription_on_real_scans() {
    let test = "scancontext_pp_matches_the_reference_transcription_on_real_scans";
    let Some((scans, clouds, lines)) = cross_check(test, "scancontext_pp_reference.py") else { return };
    let polar = PolarParams { voxel: 0.0, ..PolarParams::default() };
    let cart = CartParams { voxel: 0.0, ..CartParams::default() };
    let close = |ours: &[f32], theirs: &[f64], name: &str, what: &str| {
        assert_eq!(ours.len(), theirs.len(), "{name} {what}");
        assert!(ours.iter().filter(|&&v| v != 0.0).count() > 100, "{name} {what}: nearly empty");
        let worst = ours
            .iter()
            .zip(theirs)
            .map(|(&a, b)| (a as f64 - b).abs() / b.abs().max(1.0))
            .fold(0.0, f64::max);
        assert!(worst <= 1e-6, "{name} {what}: max relative difference {worst:e}");
        println!("{name} {what}: {} values, max relative difference {worst:e}", ours.len());
    };
    let mut checked = 0;
    for line in &lines {
        let (i, kind, values) = (line.cloud, line.kind.as_str(), &line.values);
        let name = scans[i].display().to_string();
        match kind {
            "pp-polar" => close(&scancontext_pp::describe_polar(&clouds[i], &polar), values, &name, "polar"),
            "pp-cart" => close(&scancontext_pp::describe_cart(&clouds[i], &cart), values, &name, "cart"),
            "pp-polardist" => {
                let q = scancontext_pp::describe_polar(&turned(&clouds[i], 42.0), &polar);
                let c = scancontext_pp::describe_polar(&clouds[i], &polar);
                let m = scancontext_pp::compare(&q, &c, &Variant::Polar(polar.clone()));
                assert!(
                    (m.distance - values[0]).abs() <= 1e-9,
                    "{name}: {} against {}",
                    m.distance,
                    values[0]
                );
                assert_eq!((m.shift as f64, m.shift), (values[1], 7), "{name}: a 42° turn is 7 sectors");
                println!("{name} polar distance {:e}, shift {}", m.distance, m.shift);
            }
            "pp-cartdist" => {
                let q = scancontext_pp::describe_cart(&turned(&clouds[i], 180.0), &cart);
                let c = scancontext_pp::describe_cart(&clouds[i], &cart);
                let m = scancontext_pp::compare(&q, &c, &Variant::Cart(cart.clone()));
                assert!(
                    (m.distance - values[0]).abs() <= 1e-9,
                    "{name}: {} against {}",
                    m.distance,
                    values[0]
                );
                assert_eq!((m.shift as f64, m.reversed as u8 as f64), (values[1], values[2]), "{name}");
                println!(
                    "{name} cartesian distance {:e}, shift {}, reversed {}",
                    m.distance, m.shift, m.reversed
                );
            }
            other => panic!("unknown line kind {other}"),
        }
        checked += 1;
    }
    assert_eq!(checked, 4 * scans.len());
}

#[test]
fn every_computed_method_refuses_its_bad_settings_by_key() {
    use toporec::methods::Method;
    let bad = [
        ("m2dp", serde_json::json!({ "voxel": -1.0 }), "m2dp.voxel"),
        ("scancontext", serde_json::json!({ "rings": 0 }), "scancontext"),
        ("scancontext-pp", serde_json::json!({ "copies": 2 }), "scancontext-pp.copies"),
        ("scancontext-pp-cart", serde_json::json!({ "voxel": -1.0 }), "scancontext-pp-cart.voxel"),
        ("solid", serde_json::json!({ "rings": 0 }), "solid.rings"),
        ("lidar-iris", serde_json::json!({ "sigma_on_f": 1.0 }), "lidar-iris.sigma_on_f"),
        ("toporec-plus", serde_json::json!({ "turns": 0 }), "toporec-plus.turns"),
    ];
    for (name, settings, key) in bad {
        let err = Method::from_settings(name, &settings).expect_err(name);
        assert!(err.contains(key), "{name}: {err}");
    }
    assert!(Method::from_settings("m2dp", &serde_json::json!({ "voxel": 0.5 })).is_ok());
}

/// LiDAR-Iris worked by hand on a few points (default settings: rows of 1 m, columns of 1°,
/// bit ⌈z + 5⌉).
#[test]
fn lidar_iris_by_hand() {
    use toporec::methods::lidar_iris::{self, COLUMNS, IrisParams, ROWS};
    let p = IrisParams::default();
    let at = |r: f64, degrees: f64, z: f64| {
        let (s, c) = degrees.to_radians().sin_cos();
        [r * c, r * s, z]
    };
    // 10.5 m at 10.2°: row 10, column ⌊10.2 + 180.5⌋ = 190, bit ⌈−1.2 + 5⌉ = 4 (16); a second
    // point in that pixel at z 0.3 sets bit ⌈5.3⌉ = 6 (64). 20.2 m at −99.8°: row 20, column
    // ⌊80.7⌋ = 80, bit ⌈5.5⌉ = 6. 30.7 m at 150.3°: row 30, column 330, z 2.7 → bit ⌈7.7⌉ = 8,
    // clamped to 7 (128). 100 m at −60°: the last row (79), column 120, z −6 → bit −1, clamped
    // to 0 (1).
    let cloud = vec![
        at(10.5, 10.2, -1.2),
        at(10.6, 10.3, 0.3),
        at(20.2, -99.8, 0.5),
        at(30.7, 150.3, 2.7),
        at(100.0, -60.0, -6.0),
    ];
    let d = lidar_iris::describe(&cloud, &p);
    assert_eq!(d.len(), ROWS * COLUMNS + 3 * 4 * ROWS * COLUMNS / 8);
    assert_eq!(d.len(), p.len());
    let pixel = |r: usize, c: usize| d[r * COLUMNS + c];
    assert_eq!([pixel(10, 190), pixel(20, 80), pixel(30, 330), pixel(79, 120)], [80.0, 64.0, 128.0, 1.0]);
    assert_eq!(d[..ROWS * COLUMNS].iter().filter(|&&v| v != 0.0).count(), 4);
    // The row key counts the height bits of each row: two in row 10, one in rows 20, 30, 79.
    let key = lidar_iris::row_key(&d);
    assert_eq!((key[10], key[20], key[30], key[79], key.iter().sum::<f32>()), (2.0, 1.0, 1.0, 1.0, 5.0));
    // Template and mask, bit (plane, row, column), packed 45 bytes a row, first column highest.
    let plane = ROWS * COLUMNS / 8;
    let bit = |start: usize, plane_no: usize, r: usize, c: usize| {
        d[start + plane_no * plane + r * COLUMNS / 8 + c / 8] as u8 & (0x80 >> (c % 8)) != 0
    };
    let (template, mask) = (ROWS * COLUMNS, ROWS * COLUMNS + 8 * plane);
    // An empty row: every mask bit set, no template bit (its filter output is exactly 0).
    assert!((0..COLUMNS).all(|c| bit(mask, 0, 5, c) && !bit(template, 0, 5, c) && !bit(template, 4, 5, c)));
    // A lone pixel of value v at column c filters to v · h(n − c), h the inverse DFT of the real
    // one-sided filter: h(0) = Σ H(k) > 0 and real. So at the pixel, the real bit of every scale
    // is set, the mask is not, and the imaginary part is exactly 0: no bit (the reference reads
    // the sign of its rounding noise there).
    for s in 0..4 {
        assert!(
            bit(template, s, 20, 80) && !bit(template, 4 + s, 20, 80) && !bit(mask, s, 20, 80),
            "scale {s}"
        );
    }
    // A scan against itself: distance 0, yaw 0. Turned by 90° (every point 90 columns over, none
    // crossing the ±180° seam): distance 0, yaw 90°, with and without the reverse check.
    let m = lidar_iris::compare(&d, &d, &p);
    assert_eq!((m.distance, m.yaw_degrees), (0.0, 0.0));
    let q = lidar_iris::describe(&turned(&cloud, 90.0), &p);
    assert_eq!(&q[..ROWS * COLUMNS][20 * COLUMNS + 170], &64.0);
    for reverse in [true, false] {
        let m = lidar_iris::compare(&q, &d, &IrisParams { reverse, ..p.clone() });
        assert_eq!((m.distance, m.yaw_degrees), (0.0, 90.0), "reverse {reverse}");
    }
    // An empty scan has no comparable bit with any scan: distance 1.
    let empty = lidar_iris::describe(&[], &p);
    assert_eq!(lidar_iris::compare(&empty, &d, &p).distance, 1.0);
    assert_eq!(lidar_iris::compare(&d, &empty, &p).distance, 1.0);
}

/// LiDAR-Iris equals the numpy transcription of the reference code
/// (`scripts/lidar_iris_reference.py`) on real KITTI and NCLT scans: the image, template and
/// mask bit for bit, the distances (exact fractions of bit counts) within 1e-12, the yaws and
/// the direction found equal.
#[test]
fn lidar_iris_matches_the_reference_transcription_on_real_scans() {
    use toporec::methods::lidar_iris::{self, IrisParams};
    let test = "lidar_iris_matches_the_reference_transcription_on_real_scans";
    let Some((scans, clouds, lines)) = cross_check(test, "lidar_iris_reference.py") else { return };
    let p = IrisParams::default();
    let described: Vec<Vec<f32>> = clouds.iter().map(|c| lidar_iris::describe(c, &p)).collect();
    let mut checked = 0;
    for line in &lines {
        let (i, kind, values) = (line.cloud, line.kind.as_str(), &line.values);
        let name = scans[i].display();
        let check = |m: lidar_iris::Match, what: &str| {
            assert!(
                (m.distance - values[0]).abs() <= 1e-12,
                "{name} {what}: distance {} against {}",
                m.distance,
                values[0]
            );
            assert_eq!(
                (m.yaw_degrees, m.reversed as u8 as f64),
                (values[1], values[2]),
                "{name} {what}: yaw, reversed"
            );
            println!(
                "{name} {what}: distance {:.6}, yaw {}°, reversed {}",
                m.distance, m.yaw_degrees, m.reversed
            );
        };
        match kind {
            "iris" => {
                let ours: Vec<f64> = described[i].iter().map(|&v| v as f64).collect();
                assert_eq!(ours.len(), values.len(), "{name}");
                let differ = ours.iter().zip(values).filter(|(a, b)| a != b).count();
                assert_eq!(differ, 0, "{name}: {differ} of {} bytes differ", ours.len());
                let set: u32 = described[i].iter().map(|&v| (v as u8).count_ones()).sum();
                assert!(set > 10_000, "{name}: {set} bits set");
                println!("{name} iris: {} bytes equal, {set} bits set", ours.len());
            }
            "irisdist" => {
                let q = lidar_iris::describe(&turned(&clouds[i], 42.0), &p);
                let m = lidar_iris::compare(&q, &described[i], &p);
                assert!(m.distance < 0.2, "{name}: a turned scan at {}", m.distance);
                assert!((m.yaw_degrees - 42.0).abs() <= 1.0, "{name}: yaw {}", m.yaw_degrees);
                check(m, "turned by 42°");
            }
            "irispair" => {
                let j = (i + 1) % clouds.len();
                check(lidar_iris::compare(&described[j], &described[i], &p), "the next scan against it");
            }
            other => panic!("unknown line kind {other}"),
        }
        checked += 1;
    }
    assert_eq!(checked, 3 * scans.len());
}
