//! `toporec simulate`: ray-cast a rotating multi-beam LiDAR through a procedural town along a
//! closed route, for several sessions (days), and write the scans in the formats the sources
//! read — an NCLT layout (`velodyne_data/<date>/velodyne_sync/*.bin` + `ground_truth/`), an
//! MCAP with ROS 2 PointCloud2 messages (zstd chunks) + poses, and KITTI `.bin` + poses.
//!
//! Deterministic: the town depends on the seed, each session's movable objects and route
//! noise on (seed, session), each scan's noise on (seed, session, scan); scans are ray-cast in
//! parallel and written in order, a chunk at a time (memory does not grow with the count).

mod bags;
pub mod scene;

use crate::error::{Error, Result, ResultExt};
use crate::ranges;
use crate::rng::SplitMix64;
use crate::sources::pointcloud2::{self, Encoding, PointCloud2, PointField, datatype};
use rayon::prelude::*;
use scene::{Scene, TownParams};
use std::path::{Path, PathBuf};

/// A rotating multi-beam LiDAR.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    /// Beam elevations (degrees), beam index = ring.
    pub elevations: Vec<f64>,
    /// Azimuth step (degrees).
    pub azimuth_res: f64,
    /// Maximum range (m).
    pub max_range: f64,
    /// Range noise σ (m).
    pub range_noise: f64,
    /// Probability that a return is lost.
    pub dropout: f64,
    /// Mounting height above the ground (m).
    pub height: f64,
}

/// Sensor models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SensorModel {
    /// 32 beams, −30.67° to +10.67° (Velodyne HDL-32E, NCLT's sensor).
    Hdl32,
    /// 64 beams, −24.9° to +2° (Velodyne HDL-64E, KITTI's sensor).
    Hdl64,
    /// 16 beams, −15° to +15° (Velodyne VLP-16).
    Vlp16,
}

impl Sensor {
    /// The model with toporec's defaults (0.2° azimuth, 100 m, 2 cm noise, 8 % dropouts, 1.9 m).
    pub fn new(model: SensorModel) -> Self {
        let spread =
            |n: usize, lo: f64, hi: f64| (0..n).map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64).collect();
        let elevations = match model {
            SensorModel::Hdl32 => spread(32, -30.67, 10.67),
            SensorModel::Hdl64 => spread(64, -24.9, 2.0),
            SensorModel::Vlp16 => spread(16, -15.0, 15.0),
        };
        Sensor {
            elevations,
            azimuth_res: 0.2,
            max_range: 100.0,
            range_noise: 0.02,
            dropout: 0.08,
            height: 1.9,
        }
    }

    /// Rays per revolution.
    pub fn rays(&self) -> usize {
        self.elevations.len() * self.columns()
    }

    fn columns(&self) -> usize {
        (360.0 / self.azimuth_res).round() as usize
    }
}

/// A simulated scan: points in the sensor frame (x forward, y left, z up).
#[derive(Clone, Debug, PartialEq)]
pub struct SimScan {
    /// Session index.
    pub session: usize,
    /// Scan index in the session.
    pub index: usize,
    /// Timestamp (µs).
    pub utime: i64,
    /// Sensor pose in the town: x, y, z, yaw.
    pub pose: [f64; 4],
    /// The sensor's pose as the vehicle's odometry has it (x, y, z, yaw): the true pose unless
    /// [`SimParams::drift`] says otherwise.
    pub odometry: [f64; 4],
    /// Points.
    pub points: Vec<[f32; 3]>,
    /// Intensity 0–255.
    pub intensity: Vec<u8>,
    /// Beam index.
    pub ring: Vec<u16>,
}

/// Output formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// NCLT layout.
    Nclt,
    /// ROS 2 MCAP.
    Mcap,
    /// KITTI odometry layout.
    Kitti,
    /// A ROS 1 bag (`bag/<date>.bag`): the clouds on /velodyne_points, the vehicle's odometry
    /// on /odom, its transforms on /tf and the sensor's mounting on /tf_static.
    Bag,
    /// A rosbag2 folder with MCAP storage (`rosbag2/<date>/`), the same topics in CDR.
    Rosbag2,
}

/// Everything `simulate` needs.
#[derive(Clone, Debug)]
pub struct SimParams {
    /// Town.
    pub town: TownParams,
    /// Sensor.
    pub sensor: Sensor,
    /// Sessions (days).
    pub sessions: usize,
    /// Seed.
    pub seed: u64,
    /// Scans per session (None: one loop).
    pub scans: Option<usize>,
    /// Speed (m/s).
    pub speed: f64,
    /// Scan rate (Hz).
    pub rate: f64,
    /// Odd sessions drive the loop the other way.
    pub reverse: bool,
    /// Laps of the loop per session: even laps (the 2nd, 4th…) the other way, each lap
    /// `lap_offset` further right, the scene's parked cars, pedestrians and crowns changed
    /// between laps. With one lap, a session of more scans than a loop drives on around it.
    pub laps: usize,
    /// Lateral offset of each lap from the one before (m).
    pub lap_offset: f64,
    /// Lateral lane offset between sessions (m).
    pub lane_offset: f64,
    /// Heading noise σ (degrees).
    pub heading_noise: f64,
    /// How the logged odometry (`/odom`, `/tf` of bags and rosbag2 folders) drifts.
    pub drift: Drift,
}

/// An odometry that drifts as a wheel or LiDAR odometry does. Each step between two scans is
/// measured `scale` too long (a fraction), turns `heading_deg_per_m` degrees a metre too far to
/// the left, and has zero-mean noise of σ `noise` m on each axis and `noise` rad of heading per
/// metre driven; the steps are chained from the session's first pose. With `own_frames`, each
/// session's odometry starts at the origin, heading along x, as a robot's does when switched on.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Drift {
    /// Scale error (0.02: 2 % long).
    pub scale: f64,
    /// Heading bias (degrees a metre, to the left).
    pub heading_deg_per_m: f64,
    /// Noise per metre (m on each axis; rad of heading).
    pub noise: f64,
    /// Each session in a frame of its own.
    pub own_frames: bool,
}

impl Drift {
    /// Whether the odometry differs from the truth.
    pub fn any(&self) -> bool {
        self.scale != 0.0 || self.heading_deg_per_m != 0.0 || self.noise != 0.0 || self.own_frames
    }
}

/// The odometry of `session`'s scans (x, y, yaw by scan index; see [`Drift`]).
pub fn odometry(p: &SimParams, session: usize) -> Vec<[f64; 3]> {
    let d = p.drift;
    let n = scans_per_session(p);
    let truth: Vec<[f64; 4]> = (0..n).map(|i| pose(p, session, i)).collect();
    let mut rng = SplitMix64(p.seed ^ 0x6F64_6F6D ^ (session as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let start = if d.own_frames { [0.0, 0.0, 0.0] } else { [truth[0][0], truth[0][1], truth[0][3]] };
    let mut out = vec![start];
    for k in 1..n {
        let (a, b) = (truth[k - 1], truth[k]);
        let (c, s) = (a[3].cos(), a[3].sin());
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let (forward, left) = (c * dx + s * dy, -s * dx + c * dy);
        let metres = forward.hypot(left);
        let sigma = d.noise * metres;
        let forward = forward * (1.0 + d.scale) + sigma * rng.normal();
        let left = left * (1.0 + d.scale) + sigma * rng.normal();
        let turn = (b[3] - a[3]) + (d.heading_deg_per_m * metres).to_radians() + sigma * rng.normal();
        let [x, y, yaw] = out[k - 1];
        let (c, s) = (yaw.cos(), yaw.sin());
        out.push([x + c * forward - s * left, y + s * forward + c * left, yaw + turn]);
    }
    out
}

impl Default for SimParams {
    fn default() -> Self {
        SimParams {
            town: TownParams::default(),
            sensor: Sensor::new(SensorModel::Hdl32),
            sessions: 2,
            seed: 1,
            scans: None,
            speed: 10.0,
            rate: 10.0,
            reverse: false,
            laps: 1,
            lap_offset: 0.0,
            lane_offset: 1.5,
            heading_noise: 1.5,
            drift: Drift::default(),
        }
    }
}

/// Arguments of `toporec simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Formats to write.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "nclt")]
    pub format: Vec<Format>,
    /// Sessions (days) driving the same loop: [1, 1000].
    #[arg(long, default_value_t = 2, value_parser = |s: &str| ranges::count_within(s, 1, 1000))]
    pub sessions: usize,
    /// Seed of the town, routes and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scans per session, [1, ∞) (default: one loop).
    #[arg(long, value_parser = ranges::count)]
    pub scans: Option<usize>,
    /// Sensor model.
    #[arg(long, value_enum, default_value = "hdl32")]
    pub sensor: SensorModel,
    /// Azimuth resolution (degrees): [0.01, 10].
    #[arg(long, default_value_t = 0.2, value_parser = ranges::azimuth_resolution)]
    pub azimuth_res: f64,
    /// Driving speed (m/s): (0, ∞).
    #[arg(long, default_value_t = 10.0, value_parser = ranges::positive)]
    pub speed: f64,
    /// Scan rate (Hz): (0, ∞).
    #[arg(long, default_value_t = 10.0, value_parser = ranges::positive)]
    pub rate: f64,
    /// Blocks per side of the town: [1, 50].
    #[arg(long, default_value_t = 3, value_parser = ranges::blocks)]
    pub blocks: usize,
    /// Street spacing (m): (20, 10000].
    #[arg(long, default_value_t = 60.0, value_parser = ranges::block_size)]
    pub block_size: f64,
    /// Ground slope along x and y (dz/dx,dz/dy), each in [-1, 1].
    #[arg(long, value_delimiter = ',', default_value = "0,0", value_parser = |s: &str| ranges::within(s, -1.0, 1.0))]
    pub slope: Vec<f64>,
    /// Odd sessions drive the loop in the opposite direction.
    #[arg(long)]
    pub reverse: bool,
    /// Laps of the loop per session, [1, 1000]: even laps (2nd, 4th…) the other way, each lap
    /// `--lap-offset` metres further right, the parked cars moved between laps.
    #[arg(long, default_value_t = 1, value_parser = |s: &str| ranges::count_within(s, 1, 1000))]
    pub laps: usize,
    /// Lateral offset of each lap from the one before (m), [-20, 20].
    #[arg(long, default_value_t = 0.0, value_parser = |s: &str| ranges::within(s, -20.0, 20.0))]
    pub lap_offset: f64,
    /// Probability that a return is lost: [0, 1).
    #[arg(long, default_value_t = 0.08, value_parser = ranges::probability)]
    pub dropout: f64,
    /// Maximum range (m): (0, 10000].
    #[arg(long, default_value_t = 100.0, value_parser = |s: &str| ranges::within(s, f64::MIN_POSITIVE, 10_000.0))]
    pub max_range: f64,
    /// Range noise σ (m): [0, ∞).
    #[arg(long, default_value_t = 0.02, value_parser = ranges::non_negative)]
    pub range_noise: f64,
    /// Sensor height above the ground (m): [-100, 100].
    #[arg(long, default_value_t = 1.9, value_parser = |s: &str| ranges::within(s, -100.0, 100.0))]
    pub height: f64,
    /// The logged odometry (bags' and rosbag2 folders' /odom and /tf) reads each step this
    /// fraction too long, [-0.5, 0.5] (0.02: 2 %); the true poses go to `truth/<session>.tum`.
    #[arg(long, default_value_t = 0.0, value_parser = |s: &str| ranges::within(s, -0.5, 0.5))]
    pub drift_scale: f64,
    /// The logged odometry turns this many degrees a metre too far to the left, [-10, 10].
    #[arg(long, default_value_t = 0.0, value_parser = |s: &str| ranges::within(s, -10.0, 10.0))]
    pub drift_heading: f64,
    /// The logged odometry's noise per metre driven: σ in m on each axis and in rad of heading,
    /// [0, 1].
    #[arg(long, default_value_t = 0.0, value_parser = |s: &str| ranges::within(s, 0.0, 1.0))]
    pub drift_noise: f64,
    /// Each session's logged odometry starts at the origin, in a frame of its own.
    #[arg(long)]
    pub own_frames: bool,
    /// Worker threads.
    #[command(flatten)]
    pub threads: crate::flags::Threads,
}

impl SimulateArgs {
    /// The simulation these arguments ask for, checked.
    pub fn params(&self) -> Result<SimParams> {
        let a = self;
        if a.slope.len() != 2 {
            return Err(Error::invalid("--slope: expected two numbers dz/dx,dz/dy"));
        }
        if a.laps == 0 || !(a.lap_offset.is_finite() && a.lap_offset.abs() <= 20.0) {
            return Err(Error::invalid("simulate: need laps >= 1 and a lap offset within [-20, 20] m"));
        }
        if a.blocks == 0 || a.block_size <= 20.0 || a.rate <= 0.0 || a.speed <= 0.0 || a.azimuth_res <= 0.0 {
            return Err(Error::invalid(
                "simulate: need blocks >= 1, block size > 20 m, and positive rate, speed and azimuth resolution",
            ));
        }
        let mut sensor = Sensor::new(a.sensor);
        sensor.azimuth_res = a.azimuth_res;
        sensor.dropout = a.dropout;
        sensor.max_range = a.max_range;
        sensor.range_noise = a.range_noise;
        sensor.height = a.height;
        Ok(SimParams {
            town: TownParams {
                blocks: a.blocks,
                block_size: a.block_size,
                slope: [a.slope[0], a.slope[1]],
                ..TownParams::default()
            },
            sensor,
            sessions: a.sessions,
            seed: a.seed,
            scans: a.scans,
            speed: a.speed,
            rate: a.rate,
            reverse: a.reverse,
            laps: a.laps,
            lap_offset: a.lap_offset,
            drift: Drift {
                scale: a.drift_scale,
                heading_deg_per_m: a.drift_heading,
                noise: a.drift_noise,
                own_frames: a.own_frames,
            },
            ..SimParams::default()
        })
    }
}

/// Session names: dates from 2026-01-01 on (NCLT names sessions by date).
pub(crate) fn session_name(session: usize) -> String {
    format!("2026-{:02}-{:02}", 1 + session / 28 % 12, 1 + session % 28)
}

fn session_base_utime(session: usize) -> i64 {
    // 2026-01-01T10:00:00Z plus whole days.
    1_767_261_600_000_000 + session as i64 * 86_400_000_000
}

/// The closed route: a rectangle along street centre lines (around the inner blocks when
/// there are at least 3 per side).
pub(crate) fn route_corners(t: &TownParams) -> [[f64; 2]; 4] {
    let b = t.block_size;
    let (lo, hi) = if t.blocks >= 3 { (b, (t.blocks - 1) as f64 * b) } else { (0.0, t.blocks as f64 * b) };
    [[lo, lo], [hi, lo], [hi, hi], [lo, hi]]
}

/// Position and heading at arc length `s` along the loop (counter-clockwise), with a lateral
/// offset to the right of travel.
fn along_route(corners: &[[f64; 2]; 4], s: f64, lateral: f64, reverse: bool) -> [f64; 3] {
    let len = |i: usize| {
        let (a, b) = (corners[i], corners[(i + 1) % 4]);
        (b[0] - a[0]).hypot(b[1] - a[1])
    };
    let total: f64 = (0..4).map(len).sum();
    let mut s = s.rem_euclid(total);
    if reverse {
        s = total - s;
    }
    let mut i = 0;
    while s > len(i) {
        s -= len(i);
        i = (i + 1) % 4;
    }
    let (a, b) = (corners[i], corners[(i + 1) % 4]);
    let l = len(i);
    let dir = [(b[0] - a[0]) / l, (b[1] - a[1]) / l];
    let dir = if reverse { [-dir[0], -dir[1]] } else { dir };
    let right = [dir[1], -dir[0]];
    [
        a[0] + (b[0] - a[0]) * s / l + right[0] * lateral,
        a[1] + (b[1] - a[1]) * s / l + right[1] * lateral,
        dir[1].atan2(dir[0]),
    ]
}

/// Loop length (m).
pub(crate) fn route_length(t: &TownParams) -> f64 {
    let c = route_corners(t);
    (0..4).map(|i| (c[(i + 1) % 4][0] - c[i][0]).hypot(c[(i + 1) % 4][1] - c[i][1])).sum()
}

/// Scans in one loop of the route.
fn scans_per_loop(p: &SimParams) -> usize {
    (route_length(&p.town) / (p.speed / p.rate)).floor().max(1.0) as usize
}

/// Scans per session (explicit, or one loop a lap).
pub fn scans_per_session(p: &SimParams) -> usize {
    p.scans.unwrap_or_else(|| p.laps.max(1) * scans_per_loop(p))
}

/// The lap of scan `index` (0 the first) and its position within the lap; with one lap, the
/// session is one lap however long.
pub fn lap_of(p: &SimParams, index: usize) -> (usize, usize) {
    if p.laps <= 1 {
        return (0, index);
    }
    let per = scans_per_loop(p);
    (index / per, index % per)
}

/// The scene variant of a lap of a session: the session's own for the first lap (so a one-lap
/// drive is unchanged), another for each later lap (its parked cars moved).
pub fn scene_variant(session: usize, lap: usize) -> u64 {
    session as u64 | (lap as u64) << 32
}

/// The pose of scan `index` of `session`.
pub fn pose(p: &SimParams, session: usize, index: usize) -> [f64; 4] {
    let mut rng = SplitMix64(p.seed ^ 0x726F_7574 ^ (session as u64).wrapping_mul(0xA24B_AED4_963E_E407));
    let lane = if session.is_multiple_of(2) { -1.0 } else { 1.0 } * p.lane_offset / 2.0 + 0.3 * rng.normal();
    let start = 0.37 * session as f64 * p.speed / p.rate;
    let mut scan_rng = SplitMix64(rng.next_u64() ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let (lap, in_lap) = lap_of(p, index);
    let s = start + in_lap as f64 * p.speed / p.rate;
    let reverse = (p.reverse && session % 2 == 1) != (lap % 2 == 1);
    let lateral = lane + lap as f64 * p.lap_offset;
    let [x, y, yaw] = along_route(&route_corners(&p.town), s, lateral, reverse);
    [x, y, 0.0, yaw + (p.heading_noise * scan_rng.normal()).to_radians()]
}

/// Ray-casts one scan.
pub fn scan(
    p: &SimParams,
    scene: &Scene,
    session: usize,
    index: usize,
    mailbox: &mut scene::Mailbox,
) -> SimScan {
    let sensor = &p.sensor;
    let [x, y, _, yaw] = pose(p, session, index);
    let z = scene.ground_z(x, y) + sensor.height;
    let mut rng = SplitMix64(p.seed ^ (session as u64) << 32 ^ index as u64 ^ 0x7363_616E);
    let cols = sensor.columns();
    let mut out = SimScan {
        session,
        index,
        utime: session_base_utime(session) + (index as f64 * 1e6 / p.rate).round() as i64,
        pose: [x, y, z, yaw],
        odometry: [x, y, z, yaw],
        points: Vec::with_capacity(sensor.rays() * 2 / 3),
        intensity: Vec::new(),
        ring: Vec::new(),
    };
    let ego = scene::Shape::Box { c: [0.0, 0.0, -EGO_ROOF - 0.75], h: [2.25, 0.9, 0.75], yaw: 0.0 };
    let elevations: Vec<(f64, f64)> = sensor.elevations.iter().map(|e| e.to_radians().sin_cos()).collect();
    for c in 0..cols {
        let (sa, ca) = ((c as f64 * sensor.azimuth_res).to_radians()).sin_cos();
        let (sw, cw) = ((c as f64 * sensor.azimuth_res).to_radians() + yaw).sin_cos();
        for (ring, &(se, ce)) in elevations.iter().enumerate() {
            let d_world = [ce * cw, ce * sw, se];
            // The ego vehicle's roof blocks the steep beams fore and aft (filtered, as drivers do).
            if ego.intersect([0.0; 3], [ce * ca, ce * sa, se]).is_some() {
                continue;
            }
            let hit = scene.cast([x, y, z], d_world, sensor.max_range, mailbox);
            let chance = rng.next_f64();
            let noise = rng.normal() * sensor.range_noise;
            let jitter = rng.next_f64();
            if let Some((t, material)) = hit
                && chance < return_probability(sensor, t, se, material)
            {
                let r = t + noise;
                out.points.push([(r * ce * ca) as f32, (r * ce * sa) as f32, (r * se) as f32]);
                out.intensity.push((material.intensity() * (0.85 + 0.3 * jitter)).clamp(0.0, 255.0) as u8);
                out.ring.push(ring as u16);
            }
        }
    }
    out
}

/// Height of the sensor above the ego vehicle's roof (m).
const EGO_ROOF: f64 = 0.6;

/// Probability that a hit gives a return: the sensor's dropout, weaker echoes far away
/// (−60 % at max range), glass (15 % of facade hits lost), and road hit at grazing angles
/// (fading below 3° of elevation).
fn return_probability(sensor: &Sensor, range: f64, sin_elevation: f64, material: scene::Material) -> f64 {
    let mut p = (1.0 - sensor.dropout) * (1.0 - 0.6 * (range / sensor.max_range).powi(2));
    match material {
        scene::Material::Building => p *= 0.85,
        scene::Material::Ground => p *= (sin_elevation.abs() / 3f64.to_radians().sin()).min(1.0),
        _ => {}
    }
    p
}

/// Writes all sessions in `formats` under `out`; returns the number of scans written.
pub fn simulate(p: &SimParams, formats: &[Format], out: &Path) -> Result<usize> {
    let per = scans_per_session(p);
    let mut total = 0;
    for session in 0..p.sessions {
        let mut writers: Vec<Box<dyn SessionWriter>> = formats
            .iter()
            .map(|f| -> Result<Box<dyn SessionWriter>> {
                Ok(match f {
                    Format::Nclt => Box::new(NcltWriter::new(out, session)?),
                    Format::Mcap => Box::new(McapWriter::new(out, session)?),
                    Format::Kitti => Box::new(KittiWriter::new(out, session, p.rate)?),
                    Format::Bag => Box::new(bags::Ros1Writer::new(out, session)?),
                    Format::Rosbag2 => Box::new(bags::Rosbag2Writer::new(out, session)?),
                })
            })
            .collect::<Result<_>>()?;
        // The odometry as logged, and the truth beside it, when the two differ.
        let odometry = p.drift.any().then(|| odometry(p, session));
        let mut truth = String::new();
        let chunk = 4 * rayon::current_num_threads().max(1);
        let mut scene = (usize::MAX, None);
        let mut start = 0;
        while start < per {
            // Chunks end where a lap does: one scene a chunk.
            let lap = lap_of(p, start).0;
            let lap_end = if p.laps > 1 { (lap + 1) * scans_per_loop(p) } else { per };
            let end = (start + chunk).min(per).min(lap_end);
            if scene.0 != lap {
                scene = (lap, Some(Scene::town(&p.town, p.seed, scene_variant(session, lap))));
            }
            let scene = scene.1.as_ref().expect("built");
            let mut scans: Vec<SimScan> = (start..end)
                .into_par_iter()
                .map_init(|| scene.mailbox(), |mb, i| scan(p, scene, session, i, mb))
                .collect();
            if let Some(odometry) = &odometry {
                for s in &mut scans {
                    let [x, y, yaw] = odometry[s.index];
                    s.odometry = [x, y, s.pose[2], yaw];
                    let [x, y, z, yaw] = s.pose;
                    let (qz, qw) = ((yaw / 2.0).sin(), (yaw / 2.0).cos());
                    truth +=
                        &format!("{:.6} {x:.6} {y:.6} {z:.6} 0 0 {qz:.9} {qw:.9}\n", s.utime as f64 / 1e6);
                }
            }
            for s in &scans {
                for w in &mut writers {
                    w.write(s)?;
                }
            }
            total += scans.len();
            start = end;
        }
        for w in writers {
            w.finish()?;
        }
        if odometry.is_some() {
            let dir = out.join("truth");
            std::fs::create_dir_all(&dir).at(&dir)?;
            crate::fsutil::write_atomic(
                &dir.join(format!("{}.tum", session_name(session))),
                truth.as_bytes(),
            )?;
        }
    }
    Ok(total)
}

/// A row of an NCLT ground-truth CSV (x north, y east, z down, heading) for a scan's pose.
fn ground_truth_row(s: &SimScan) -> String {
    let [x, y, z, yaw] = s.pose;
    format!("{},{:?},{:?},{:?},0.0,0.0,{:?}\n", s.utime, x, -y, -z, -yaw)
}

pub(crate) trait SessionWriter {
    fn write(&mut self, s: &SimScan) -> Result<()>;
    fn finish(self: Box<Self>) -> Result<()>;
}

/// NCLT: `velodyne_data/<date>/velodyne_sync/<utime>.bin` (5 mm, z down) and
/// `ground_truth/groundtruth_<date>.csv` (x north, y east, z down, heading).
struct NcltWriter {
    dir: PathBuf,
    gt_path: PathBuf,
    gt: String,
}

impl NcltWriter {
    fn new(out: &Path, session: usize) -> Result<Self> {
        let name = session_name(session);
        let dir = out.join("velodyne_data").join(&name).join("velodyne_sync");
        std::fs::create_dir_all(&dir).at(&dir)?;
        let gt_path = out.join("ground_truth").join(format!("groundtruth_{name}.csv"));
        Ok(NcltWriter { dir, gt_path, gt: String::new() })
    }
}

impl SessionWriter for NcltWriter {
    fn write(&mut self, s: &SimScan) -> Result<()> {
        let mut bytes = Vec::with_capacity(s.points.len() * 8);
        for ((p, &i), &r) in s.points.iter().zip(&s.intensity).zip(&s.ring) {
            let q = [p[0] as f64, -p[1] as f64, -p[2] as f64]
                .map(|v| ((v + 100.0) / 0.005).round().clamp(0.0, 65535.0) as u16);
            q.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
            bytes.push(i);
            bytes.push(r as u8);
        }
        crate::fsutil::write_atomic(&self.dir.join(format!("{}.bin", s.utime)), &bytes)?;
        self.gt += &ground_truth_row(s);
        Ok(())
    }

    fn finish(self: Box<Self>) -> Result<()> {
        crate::fsutil::write_atomic(&self.gt_path, self.gt.as_bytes())
    }
}

/// MCAP: `mcap/<date>.mcap` (ROS 2 PointCloud2 on /velodyne_points, zstd chunks) and
/// `mcap/groundtruth_<date>.csv`.
struct McapWriter {
    path: PathBuf,
    writer: ::mcap::Writer<crate::fsutil::AtomicFile>,
    channel: u16,
    gt_path: PathBuf,
    gt: String,
}

const POINTCLOUD2_MSG: &str = "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n";

/// An MCAP file of ROS 2 messages in zstd chunks at `path`, written atomically (the simulator's
/// MCAP copy and its rosbag2 folders).
fn ros2_mcap(path: &Path) -> Result<::mcap::Writer<crate::fsutil::AtomicFile>> {
    let file = crate::fsutil::AtomicFile::create(path)?;
    ::mcap::WriteOptions::new()
        .compression(Some(::mcap::Compression::Zstd))
        .profile("ros2")
        .library("toporec-simulate")
        .create(file)
        .at(path)
}

impl McapWriter {
    fn new(out: &Path, session: usize) -> Result<Self> {
        let name = session_name(session);
        let dir = out.join("mcap");
        let path = dir.join(format!("{name}.mcap"));
        let mut writer = ros2_mcap(&path)?;
        let schema = writer
            .add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", POINTCLOUD2_MSG.as_bytes())
            .at(&path)?;
        let channel = writer.add_channel(schema, "/velodyne_points", "cdr", &Default::default()).at(&path)?;
        let gt_path = dir.join(format!("groundtruth_{name}.csv"));
        Ok(McapWriter { path, writer, channel, gt_path, gt: String::new() })
    }
}

impl SessionWriter for McapWriter {
    fn write(&mut self, s: &SimScan) -> Result<()> {
        let bytes = cloud_message(s, Encoding::Cdr);
        let t = (s.utime * 1000) as u64;
        let header = ::mcap::records::MessageHeader {
            channel_id: self.channel,
            sequence: s.index as u32,
            log_time: t,
            publish_time: t,
        };
        self.writer.write_to_known_channel(&header, &bytes).at(&self.path)?;
        self.gt += &ground_truth_row(s);
        Ok(())
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.writer.finish().at(&self.path)?;
        self.writer.into_inner().commit()?;
        crate::fsutil::write_atomic(&self.gt_path, self.gt.as_bytes())
    }
}

/// A scan as a `sensor_msgs/PointCloud2` in `encoding` (frame `velodyne`, stamped at its time):
/// x, y, z, intensity (float32) and ring (uint16), 20 bytes a point.
pub(crate) fn cloud_message(s: &SimScan, encoding: Encoding) -> Vec<u8> {
    let mut data = Vec::with_capacity(s.points.len() * 20);
    for ((p, &i), &r) in s.points.iter().zip(&s.intensity).zip(&s.ring) {
        p.iter().for_each(|v| data.extend(v.to_le_bytes()));
        data.extend((i as f32).to_le_bytes());
        data.extend(r.to_le_bytes());
        data.extend([0u8; 2]);
    }
    let f = |name: &str, offset, dt| PointField { name: name.into(), offset, datatype: dt, count: 1 };
    let cloud = PointCloud2 {
        stamp_ns: s.utime * 1000,
        frame_id: "velodyne".into(),
        height: 1,
        width: s.points.len() as u32,
        fields: vec![
            f("x", 0, datatype::FLOAT32),
            f("y", 4, datatype::FLOAT32),
            f("z", 8, datatype::FLOAT32),
            f("intensity", 12, datatype::FLOAT32),
            f("ring", 16, datatype::UINT16),
        ],
        is_bigendian: false,
        point_step: 20,
        row_step: 20 * s.points.len() as u32,
        data: &data,
    };
    pointcloud2::serialize(&cloud, encoding)
}

/// KITTI: `kitti/sequences/<NN>/velodyne/<frame>.bin`, `times.txt`, `poses.txt` (camera 0
/// frame: x right, y down, z forward; in the town frame, not relative to frame 0).
struct KittiWriter {
    dir: PathBuf,
    rate: f64,
    times: String,
    poses: String,
}

impl KittiWriter {
    fn new(out: &Path, session: usize, rate: f64) -> Result<Self> {
        let dir = out.join("kitti").join("sequences").join(format!("{session:02}"));
        std::fs::create_dir_all(dir.join("velodyne")).at(&dir.join("velodyne"))?;
        Ok(KittiWriter { dir, rate, times: String::new(), poses: String::new() })
    }
}

impl SessionWriter for KittiWriter {
    fn write(&mut self, s: &SimScan) -> Result<()> {
        let mut bytes = Vec::with_capacity(s.points.len() * 16);
        for (p, &i) in s.points.iter().zip(&s.intensity) {
            p.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
            bytes.extend((i as f32 / 255.0).to_le_bytes());
        }
        crate::fsutil::write_atomic(&self.dir.join("velodyne").join(format!("{:06}.bin", s.index)), &bytes)?;
        self.times += &format!("{:e}\n", s.index as f64 / self.rate);
        let [x, y, z, yaw] = s.pose;
        let (sy, cy) = yaw.sin_cos();
        // Columns: camera x (right), y (down), z (forward) in camera-0 coordinates
        // (x_c = −y, y_c = −z, z_c = x of the town frame); translation likewise.
        let r = [[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]];
        let t = [-y, -z, x];
        let row = |k: usize| format!("{:e} {:e} {:e} {:e}", r[k][0], r[k][1], r[k][2], t[k]);
        self.poses += &format!("{} {} {}\n", row(0), row(1), row(2));
        Ok(())
    }

    fn finish(self: Box<Self>) -> Result<()> {
        crate::fsutil::write_atomic(&self.dir.join("times.txt"), self.times.as_bytes())?;
        crate::fsutil::write_atomic(&self.dir.join("poses.txt"), self.poses.as_bytes())
    }
}
