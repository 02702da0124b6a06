//! RING (`methods::ring`) and RING++ (`methods::ring_plus`) against the numpy transcriptions of
//! the reference (`scripts/ring_reference.py`, `scripts/ring_plus_reference.py`) on real scans,
//! and cases worked by hand.

use crate::baselines::reference_output;
use crate::util::{python_with, shared_data};
use toporec::homology::Point;
use toporec::methods::ring::{self, RingParams};
use toporec::methods::ring_plus::{self, RingPlusParams};

/// The cloud turned by `yaw` degrees about z, then moved by (dx, dy): as the transcription's
/// `moved`.
fn moved(points: &[Point], yaw: f64, dx: f64, dy: f64) -> Vec<Point> {
    let (s, c) = yaw.to_radians().sin_cos();
    points.iter().map(|p| [c * p[0] - s * p[1] + dx, s * p[0] + c * p[1] + dy, p[2]]).collect()
}

/// RING equals the transcription on real KITTI (sequences 00, 05, 08) and NCLT scans: the
/// sinogram within 1e-6 relative (of max(|value|, 1)), the grid cell for cell, and for three
/// queries made from each scan (turned by 42°; turned by 30° and moved by (3.5, −2) m; turned by
/// 180° and moved by (2, 1) m) the distance within 1e-6, the same shift and the same x, y cells.
#[test]
fn ring_matches_the_reference_transcription_on_real_scans() {
    let test = "ring_matches_the_reference_transcription_on_real_scans";
    let Some(data) = shared_data(test) else { return };
    if !python_with(test, &["numpy", "skimage"]) {
        return;
    }
    let scans = [
        data.join("kitti/sequences/00/velodyne/000000.bin"),
        data.join("kitti/sequences/08/velodyne/000006.bin"),
        data.join("kitti/sequences/05/velodyne/000003.bin"),
        data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"),
    ];
    let (clouds, lines) = reference_output(test, "ring_reference.py", &scans);
    let p = RingParams::default();
    let sinogram = p.angles * p.side;
    let mut checked = 0;
    for line in &lines {
        let (i, values) = (line.cloud, &line.values);
        let name = scans[i].display();
        let ours = ring::describe(&clouds[i], &p);
        match line.kind.as_str() {
            "ring" => {
                assert_eq!(values.len(), sinogram, "{name}");
                let worst = ours[..sinogram]
                    .iter()
                    .zip(values)
                    .map(|(&a, b)| (a as f64 - b).abs() / b.abs().max(1.0))
                    .fold(0.0, f64::max);
                assert!(worst <= 1e-6, "{name}: max relative difference {worst:e}");
                println!("{name} ring: {} values, max relative difference {worst:e}", values.len());
            }
            "ringbev" => {
                let grid = ring::stored_grid(&ours, &p);
                let occupied: Vec<f64> =
                    grid.iter().enumerate().filter(|&(_, &v)| v == 1).map(|(k, _)| k as f64).collect();
                assert_eq!(&occupied, values, "{name}: occupied cells");
                println!("{name} ringbev: {} occupied cells, the same", occupied.len());
            }
            "ringpose" => {
                let (yaw, dx, dy) = (values[0], values[1], values[2]);
                let query = ring::describe(&moved(&clouds[i], yaw, dx, dy), &p);
                let (d, shift) = ring::distance(&query, &ours, &p);
                assert!((d - values[3]).abs() <= 1e-6, "{name} {yaw}°: distance {d} against {}", values[3]);
                assert_eq!(shift as f64, values[4], "{name} {yaw}°: shift");
                let (_, x, y) = ring::pose(&query, &ours, shift, &p);
                assert_eq!((x as f64, y as f64), (values[5], values[6]), "{name} {yaw}°: x, y cells");
                println!(
                    "{name} ringpose {yaw}° ({dx}, {dy}) m: distance {d:.6}, shift {shift}, cells ({x}, {y})"
                );
            }
            other => panic!("unknown line kind {other}"),
        }
        checked += 1;
    }
    assert_eq!(checked, 5 * scans.len());
}

/// Walls 2-6 m high around an irregular courtyard (no symmetry), a post, a few blocks.
fn courtyard() -> Vec<Point> {
    let mut scene: Vec<Point> = Vec::new();
    let mut wall = |from: (f64, f64), to: (f64, f64)| {
        let steps = ((to.0 - from.0).hypot(to.1 - from.1) / 0.3) as usize;
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            for z in [2.0, 4.0, 6.0] {
                scene.push([from.0 + t * (to.0 - from.0), from.1 + t * (to.1 - from.1), z]);
            }
        }
    };
    wall((-20.0, -12.0), (25.0, -15.0));
    wall((25.0, -15.0), (30.0, 18.0));
    wall((30.0, 18.0), (-8.0, 22.0));
    wall((-8.0, 22.0), (-20.0, -12.0));
    wall((5.0, 2.0), (12.0, 9.0));
    wall((-10.0, 5.0), (-4.0, 5.0));
    scene
}

/// The distance and shift of a query against an entry.
type Distance<'a> = &'a dyn Fn(&[f32], &[f32]) -> (f64, i64);
/// The pose (steps, x cells, y cells) of a query against an entry at a shift.
type Pose<'a> = &'a dyn Fn(&[f32], &[f32], i64) -> (i64, i64, i64);

/// A RING-family method as the hand-worked test uses it.
struct Family<'a> {
    describe: &'a dyn Fn(&[Point]) -> Vec<f32>,
    distance: Distance<'a>,
    pose: Pose<'a>,
    method: &'a dyn toporec::methods::Computed,
}

/// Worked by hand: the courtyard, its copy moved by a known yaw and offset. The grid cell is
/// 140/120 m; a yaw of k · 3° is a shift of −k angle steps; the hit reports the turn that brings
/// the entry's view onto the query's and the query's position in the entry's frame.
fn finds_a_known_yaw_and_offset(m: Family<'_>) {
    let cell = RingParams::default().cell();
    let scene = courtyard();
    let entry = (m.describe)(&scene);
    // The same scan: distance at its lowest; the shifts 0 and 60 (180°) tie, as rows θ and
    // θ + 180° of the sinogram are alike, and the first after fftshift (60) is taken; the pose
    // then finds no turn and no offset.
    let (d0, s0) = (m.distance)(&entry, &entry);
    assert_eq!(s0.rem_euclid(60), 0);
    assert_eq!((m.pose)(&entry, &entry, s0), (0, 0, 0));
    for (yaw, dx, dy) in [(45.0, 0.0, 0.0), (-90.0, 2.0 * cell, -3.0 * cell), (180.0, 3.0 * cell, 1.0 * cell)]
    {
        let query = (m.describe)(&moved(&scene, yaw, dx, dy));
        let (d, shift) = (m.distance)(&query, &entry);
        assert!(d >= d0 - 1e-9, "{yaw}°: {d} below the scan's own {d0}");
        // A yaw of k · 3° shows as a shift of −k steps, modulo 180°.
        let steps = (-(yaw / 3.0) as i64).rem_euclid(60);
        assert_eq!(shift.rem_euclid(60), steps, "{yaw}°: shift {shift}");
        let (turn, x, y) = (m.pose)(&query, &entry, shift);
        assert_eq!((turn as f64 * -3.0).rem_euclid(360.0), yaw.rem_euclid(360.0), "{yaw}°: the yaw");
        // The query's sensor sits at −Rᵀ·d in the entry's frame.
        let (s, c) = yaw.to_radians().sin_cos();
        let (ex, ey) = (-(c * dx + s * dy) / cell, -(-s * dx + c * dy) / cell);
        assert!(
            (x as f64 - ex).abs() <= 1.0 && (y as f64 - ey).abs() <= 1.0,
            "{yaw}°: cells ({x}, {y}) against ({ex:.2}, {ey:.2})"
        );
        println!(
            "{yaw}°: distance {d:.4} (own {d0:.4}), shift {shift}, turn {turn}, cells ({x}, {y}) against ({ex:.2}, {ey:.2})"
        );
    }
    // The searcher reports the same as a hit: yaw in degrees, offset in metres.
    let query = (m.describe)(&moved(&scene, 180.0, 3.0 * cell, cell));
    let searcher = m.method.searcher([entry.clone(), entry].concat());
    let (hits, _) = searcher.search(&query, 1, None);
    assert_eq!(hits[0].row, 0);
    assert_eq!(hits[0].yaw_degrees, Some(180.0));
    let [x, y] = hits[0].offset.unwrap();
    assert!((x - 3.0 * cell).abs() <= cell + 1e-9 && (y - cell).abs() <= cell + 1e-9, "offset ({x}, {y})");
    // An empty scan: a descriptor, no panic.
    assert_eq!((m.describe)(&[]).len(), m.method.len());
}

#[test]
fn ring_finds_a_known_yaw_and_offset() {
    let p = RingParams::default();
    finds_a_known_yaw_and_offset(Family {
        describe: &|c| ring::describe(c, &p),
        distance: &|q, e| ring::distance(q, e, &p),
        pose: &|q, e, s| ring::pose(q, e, s, &p),
        method: &p,
    });
}

#[test]
fn ring_plus_finds_a_known_yaw_and_offset() {
    let p = RingPlusParams::default();
    finds_a_known_yaw_and_offset(Family {
        describe: &|c| ring_plus::describe(c, &p).unwrap(),
        distance: &|q, e| ring_plus::distance(q, e, &p),
        pose: &|q, e, s| ring_plus::pose(q, e, s, &p),
        method: &p,
    });
    // Fewer points than neighbours, and a single point: descriptors, no panic.
    for cloud in [courtyard()[..10].to_vec(), vec![[3.0, 4.0, 1.0]]] {
        assert_eq!(ring_plus::describe(&cloud, &p).unwrap().len(), toporec::methods::Computed::len(&p));
    }
}

/// RING++ equals the transcription on real KITTI (sequences 00 and 08) and NCLT scans: the six
/// sinograms within 1e-6 relative (of max(|value|, 1)), the six feature grids within 1e-6, and
/// for the three queries of the RING test the distance within 1e-6, the same shift and the same
/// x, y cells.
#[test]
fn ring_plus_matches_the_reference_transcription_on_real_scans() {
    let test = "ring_plus_matches_the_reference_transcription_on_real_scans";
    let Some(data) = shared_data(test) else { return };
    if !python_with(test, &["numpy", "skimage", "sklearn"]) {
        return;
    }
    let scans = [
        data.join("kitti/sequences/00/velodyne/000000.bin"),
        data.join("kitti/sequences/08/velodyne/000006.bin"),
        data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"),
    ];
    let (clouds, lines) = reference_output(test, "ring_plus_reference.py", &scans);
    let p = RingPlusParams::default();
    let part = ring_plus::FEATURES * p.angles * p.side;
    let mut checked = 0;
    for line in &lines {
        let (i, values) = (line.cloud, &line.values);
        let name = scans[i].display();
        let ours = ring_plus::describe(&clouds[i], &p).unwrap();
        match line.kind.as_str() {
            "ringplus" | "ringplusgrid" => {
                let (mine, scale) = match line.kind.as_str() {
                    "ringplus" => (&ours[..part], 1.0),
                    _ => (&ours[part..], 0.0),
                };
                assert_eq!(values.len(), mine.len(), "{name}");
                let worst = mine
                    .iter()
                    .zip(values)
                    .map(|(&a, b)| (a as f64 - b).abs() / b.abs().max(scale).max(1.0))
                    .fold(0.0, f64::max);
                assert!(worst <= 1e-6, "{name} {}: max difference {worst:e}", line.kind);
                let nonzero = values.iter().filter(|v| **v != 0.0).count();
                println!(
                    "{name} {}: {} values ({nonzero} nonzero), max difference {worst:e}",
                    line.kind,
                    values.len()
                );
            }
            "ringpluspose" => {
                let (yaw, dx, dy) = (values[0], values[1], values[2]);
                let query = ring_plus::describe(&moved(&clouds[i], yaw, dx, dy), &p).unwrap();
                let (d, shift) = ring_plus::distance(&query, &ours, &p);
                assert!((d - values[3]).abs() <= 1e-6, "{name} {yaw}°: distance {d} against {}", values[3]);
                assert_eq!(shift as f64, values[4], "{name} {yaw}°: shift");
                let (_, x, y) = ring_plus::pose(&query, &ours, shift, &p);
                assert_eq!((x as f64, y as f64), (values[5], values[6]), "{name} {yaw}°: x, y cells");
                println!(
                    "{name} ringpluspose {yaw}° ({dx}, {dy}) m: distance {d:.6}, shift {shift}, cells ({x}, {y})"
                );
            }
            other => panic!("unknown line kind {other}"),
        }
        checked += 1;
    }
    assert_eq!(checked, 5 * scans.len());
}
