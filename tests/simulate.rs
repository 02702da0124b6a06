//! `toporec simulate`: determinism (the committed sample regenerates byte for byte), static
//! geometry shared by sessions, points on scene surfaces, the sensor's beam pattern and
//! return rate, and the written formats read back by the sources.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::simulate::scene::{Material, Scene, TownParams};
use toporec::simulate::{self, Format, SensorModel, SimParams};
use toporec::sources::{SourceSpec, kitti::KittiSpec, logs::LogSpec, nclt::NcltSpec};

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.path().is_dir() { stack.push(e.path()) } else { out.push(e.path()) }
        }
    }
    out.sort();
    out
}

#[test]
fn committed_sample_regenerates_identically() {
    // The command in samples/README.md.
    let dir = scratch_dir("simulate_sample");
    let out = dir.join("town");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args([
            "simulate",
            "-o",
            out.to_str().unwrap(),
            "--sessions",
            "2",
            "--seed",
            "7",
            "--azimuth-res",
            "1.0",
            "--rate",
            "2",
            "--blocks",
            "3",
            "--block-size",
            "40",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sample = root().join("samples/town");
    let (a, b) = (files(&sample), files(&out));
    let rel = |v: &[PathBuf], base: &Path| {
        v.iter().map(|p| p.strip_prefix(base).unwrap().to_owned()).collect::<Vec<_>>()
    };
    assert_eq!(rel(&a, &sample), rel(&b, &out), "same file names");
    for (x, y) in a.iter().zip(&b) {
        assert!(std::fs::read(x).unwrap() == std::fs::read(y).unwrap(), "{} differs", x.display());
    }
}

#[test]
fn committed_drive_bag_regenerates_identically() {
    // The command in samples/README.md.
    let dir = scratch_dir("simulate_drive_bag");
    let args = "simulate --format bag --sessions 1 --laps 2 --blocks 3 --block-size 60 --sensor vlp16 --azimuth-res 3 --rate 2 --seed 4";
    let mut args: Vec<&str> = args.split(' ').collect();
    args.extend(["-o", dir.to_str().unwrap()]);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_toporec")).args(&args).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let made = std::fs::read(dir.join("bag/2026-01-01.bag")).unwrap();
    assert!(made == std::fs::read(root().join("samples/drive.bag")).unwrap(), "samples/drive.bag differs");
}

fn static_shapes(s: &Scene) -> Vec<String> {
    s.primitives
        .iter()
        .filter(|p| matches!(p.material, Material::Building | Material::Pole))
        .map(|p| format!("{:?}", p.shape))
        .collect()
}

#[test]
fn sessions_share_static_geometry_and_differ_in_movables() {
    let t = TownParams::default();
    let (a, b) = (Scene::town(&t, 3, 0), Scene::town(&t, 3, 1));
    assert!(static_shapes(&a).len() > 30);
    assert_eq!(static_shapes(&a), static_shapes(&b), "buildings, walls and poles identical");
    let cars = |s: &Scene| {
        s.primitives
            .iter()
            .filter(|p| p.material == Material::Car)
            .map(|p| format!("{:?}", p.shape))
            .collect::<Vec<_>>()
    };
    assert_ne!(cars(&a), cars(&b), "parked cars change between sessions");
    assert_ne!(static_shapes(&Scene::town(&t, 4, 0)), static_shapes(&a), "another seed, another town");
}

#[test]
fn points_lie_on_surfaces_with_the_sensor_pattern_and_return_rate() {
    let p = SimParams::default();
    let scene = Scene::town(&p.town, p.seed, 0);
    let mut mb = scene.mailbox();
    let s = simulate::scan(&p, &scene, 0, 5, &mut mb);
    let rays = p.sensor.rays();
    let rate = s.points.len() as f64 / rays as f64;
    assert!((0.5..=0.7).contains(&rate), "returns {:.1} % of {rays} rays", rate * 100.0);
    let [x, y, z, yaw] = s.pose;
    let (sy, cy) = yaw.sin_cos();
    let mut far = 0;
    for (q, &ring) in s.points.iter().zip(&s.ring) {
        let q = q.map(|v| v as f64);
        // Beam pattern: the elevation of every return is its beam's (noise is along the ray).
        let elevation = q[2].atan2(q[0].hypot(q[1])).to_degrees();
        assert!((elevation - p.sensor.elevations[ring as usize]).abs() < 1e-3, "ring {ring}: {elevation}");
        // On a surface within the noise (σ = 2 cm; 5σ allowed, plus float32 rounding).
        let w = [x + cy * q[0] - sy * q[1], y + sy * q[0] + cy * q[1], z + q[2]];
        let ground = (w[2] - scene.ground_z(w[0], w[1])).abs();
        let nearest = scene.primitives.iter().map(|p| p.shape.surface_distance(w)).fold(ground, f64::min);
        if nearest > 0.1 + 1e-4 * q[0].hypot(q[1]) {
            far += 1;
        }
    }
    assert!(far * 10_000 < s.points.len(), "{far} of {} points off every surface", s.points.len());
    // The other sensors have their beam counts.
    for (model, beams) in [(SensorModel::Hdl64, 64), (SensorModel::Vlp16, 16)] {
        assert_eq!(simulate::Sensor::new(model).elevations.len(), beams);
    }
}

#[test]
fn written_formats_read_back_through_the_sources() {
    let dir = scratch_dir("simulate_formats");
    let mut p = SimParams { scans: Some(3), ..SimParams::default() };
    p.sensor.azimuth_res = 2.0;
    let n = simulate::simulate(&p, &[Format::Nclt, Format::Mcap, Format::Kitti], &dir).unwrap();
    assert_eq!(n, 6);
    let read = |spec: SourceSpec| spec.open().unwrap().map(|r| r.unwrap()).collect::<Vec<_>>();
    let nclt = read(SourceSpec::new(NcltSpec::sessions(vec![dir.join("velodyne_data")])));
    let mcaps = [dir.join("mcap/2026-01-01.mcap"), dir.join("mcap/2026-01-02.mcap")];
    let mcap = read(SourceSpec::new(LogSpec {
        poses: Some(dir.join("mcap/groundtruth_2026-01-01.csv")),
        ..LogSpec::path(&mcaps[0])
    }));
    let kitti = read(SourceSpec::new(KittiSpec {
        sequences: vec![dir.join("kitti/sequences/00"), dir.join("kitti/sequences/01")],
    }));
    assert_eq!((nclt.len(), mcap.len(), kitti.len()), (6, 3, 6));
    let scene = Scene::town(&p.town, p.seed, 0);
    let truth = simulate::scan(&p, &scene, 0, 1, &mut scene.mailbox());
    let exact: Vec<[f64; 3]> = truth.points.iter().map(|q| q.map(|v| v as f64)).collect();
    assert_eq!(mcap[1].points, exact, "MCAP: float32 as simulated");
    assert_eq!(kitti[1].points, exact, "KITTI: float32 as simulated");
    assert_eq!(nclt[1].points.len(), exact.len());
    for (a, b) in nclt[1].points.iter().zip(&exact) {
        assert!((0..3).all(|k| (a[k] - b[k]).abs() <= 0.0025 + 1e-9), "NCLT: 5 mm grid: {a:?} vs {b:?}");
    }
    // Poses: all three formats give the simulated sensor position.
    let [x, y, z, yaw] = truth.pose;
    for (name, s) in [("nclt", &nclt[1]), ("mcap", &mcap[1])] {
        let q = s.pose.unwrap_or_else(|| panic!("{name}: no pose"));
        assert_eq!((q.x, q.y, q.z, q.yaw), (x, y, z, yaw), "{name}");
    }
    let q = kitti[1].pose.unwrap();
    assert!(
        (q.x - x).abs() < 1e-9
            && (q.y - y).abs() < 1e-9
            && (q.z - z).abs() < 1e-9
            && (q.yaw - yaw).abs() < 1e-9,
        "kitti {q:?}"
    );
    assert_eq!(nclt[1].ring.as_ref().unwrap(), &truth.ring.to_vec());
}

#[test]
fn laps_alternate_direction_shift_lanes_and_move_parked_cars() {
    let p = SimParams { laps: 3, lap_offset: 1.75, heading_noise: 0.0, sessions: 1, ..SimParams::default() };
    let per = simulate::scans_per_session(&p) / 3;
    assert_eq!(simulate::scans_per_session(&p), 3 * per, "one loop a lap");
    assert_eq!(simulate::lap_of(&p, per + 2), (1, 2));
    // A place of lap 1, and the nearest scan of each later lap: lap 2 drives it the other way,
    // lap 3 the same way 3.5 m (two lap offsets) further right.
    let first = simulate::pose(&p, 0, per / 3);
    let nearest = |lap: usize| {
        (lap * per..(lap + 1) * per)
            .map(|i| simulate::pose(&p, 0, i))
            .min_by(|a, b| {
                let d = |q: &[f64; 4]| (q[0] - first[0]).hypot(q[1] - first[1]);
                d(a).total_cmp(&d(b))
            })
            .unwrap()
    };
    let turn = |a: f64, b: f64| (a - b).sin().atan2((a - b).cos()).abs().to_degrees();
    let (second, third) = (nearest(1), nearest(2));
    assert!((turn(second[3], first[3]) - 180.0).abs() < 1e-6, "lap 2 reversed");
    assert!(turn(third[3], first[3]) < 1e-6, "lap 3 the first lap's way");
    let right = [first[3].sin(), -first[3].cos()];
    let lateral = (third[0] - first[0]) * right[0] + (third[1] - first[1]) * right[1];
    assert!((lateral - 3.5).abs() < 1e-6, "lap 3 is {lateral} m right of lap 1");
    // The parked cars of each lap's scene differ; one lap keeps the session's scene.
    let cars = |lap: usize| {
        Scene::town(&p.town, p.seed, simulate::scene_variant(0, lap))
            .primitives
            .iter()
            .filter(|q| q.material == Material::Car)
            .map(|q| format!("{:?}", q.shape))
            .collect::<Vec<_>>()
    };
    assert_ne!(cars(0), cars(1));
    assert_ne!(cars(1), cars(2));
    assert_eq!(simulate::scene_variant(1, 0), 1);
}
