//! Where a message log's scans take their poses from: the log's own transforms and odometry,
//! or a pose file.
//!
//! **From the log.** One pass over the log gathers `/tf` and `/tf_static` (`tf2_msgs/TFMessage`)
//! into a transform tree, and every `nav_msgs/Odometry`, `geometry_msgs/PoseStamped` and
//! `geometry_msgs/PoseWithCovarianceStamped` topic into a track. The pose of a scan is the pose
//! of its cloud's `header.frame_id` at its header stamp:
//!
//! * with a transform chain (`pose_frames = "odom:velodyne"`, or found): the product of the
//!   transforms from the root frame down to the cloud's frame, each dynamic one interpolated;
//! * with a pose topic (`poses_topic = "/odom"`, or the only one): its track interpolated, then
//!   the mounting from `/tf_static` applied when the frame its poses are of is not the cloud's:
//!   Odometry's `child_frame_id`, the second frame of `pose_frames` for the others, else the
//!   cloud's own frame (a PoseStamped names no frame: it is taken as the sensor's unless said).
//!
//! Without a choice: the transform chain when `/tf` and `/tf_static` link the cloud's frame to a
//! root through at least one moving transform; else the only pose topic; else none (several
//! topics and no chain: an error naming them). Interpolation is linear in translation and
//! spherical (slerp) in rotation, between the two samples around the stamp when they lie within
//! twice the tolerance of each other; else the nearest sample within the tolerance; a scan with
//! none keeps no pose, counted by reason.
//!
//! **From a file** (`poses`): NCLT's ground-truth CSV, TUM's `t x y z qx qy qz qw`, or KITTI's
//! 3 × 4 rows (the sensor's pose, z up, as KISS-ICP writes it) with the times of `poses_times`
//! (seconds, one per row; relative times start at the session's first scan), joined by the
//! nearest time within the tolerance.

use super::groundtruth::GroundTruth;
use super::mcap_reader::{ChannelInfo, is_point_cloud};
use super::rosmsg::{Iso, PoseKind, Stamped, decode, yaw_of};
use super::wire::Wire;
use super::{NoPose, Pose, SourceError};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// The layout of a pose file.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum PoseFormat {
    /// NCLT's ground-truth CSV (`utime, x, y, z, roll, pitch, heading`).
    #[default]
    Nclt,
    /// TUM's `t x y z qx qy qz qw` (seconds).
    Tum,
    /// KITTI's 3 × 4 rows of the sensor's pose (z up), with their times from `poses_times`.
    Kitti,
}

impl PoseFormat {
    /// Its name, as `poses_format` and `--poses-format` spell it.
    pub fn name(self) -> &'static str {
        match self {
            PoseFormat::Nclt => "nclt",
            PoseFormat::Tum => "tum",
            PoseFormat::Kitti => "kitti",
        }
    }
}

/// Poses over time of one frame, sorted by time.
#[derive(Clone, Debug, Default)]
pub struct Track {
    samples: Vec<(i64, Iso)>,
}

impl Track {
    fn push(&mut self, t: i64, pose: Iso) {
        self.samples.push((t, pose));
    }

    fn sort(&mut self) {
        self.samples.sort_by_key(|s| s.0);
        self.samples.dedup_by_key(|s| s.0);
    }

    /// Samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether it has no sample.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// First and last times (ns).
    pub fn span(&self) -> Option<(i64, i64)> {
        Some((self.samples.first()?.0, self.samples.last()?.0))
    }

    /// The pose at `t` (ns): interpolated between the samples around it when they are within
    /// `2 tol` of each other, else the nearest within `tol`.
    pub fn at(&self, t: i64, tol: i64) -> Option<Iso> {
        let i = self.samples.partition_point(|s| s.0 < t);
        if let Some(&(t1, p1)) = self.samples.get(i) {
            if t1 == t {
                return Some(p1);
            }
            if let Some(&(t0, p0)) = i.checked_sub(1).and_then(|j| self.samples.get(j))
                && t1 - t0 <= 2 * tol
            {
                let f = (t - t0) as f64 / (t1 - t0) as f64;
                let translation = p0.translation.vector.lerp(&p1.translation.vector, f);
                let rotation = p0.rotation.slerp(&p1.rotation, f);
                return Some(Iso::from_parts(translation.into(), rotation));
            }
        }
        let near = [i.checked_sub(1), Some(i)].into_iter().flatten().filter_map(|j| self.samples.get(j));
        near.min_by_key(|s| s.0.abs_diff(t)).filter(|s| s.0.abs_diff(t) <= tol as u64).map(|s| s.1)
    }
}

/// The transforms of `/tf` (moving, tracks) and `/tf_static` (fixed), by child frame.
#[derive(Clone, Debug, Default)]
pub struct TfTree {
    parent: HashMap<String, String>,
    fixed: HashMap<String, Iso>,
    moving: HashMap<String, Track>,
}

impl TfTree {
    fn add(&mut self, s: Stamped, is_static: bool) {
        if s.child.is_empty() || s.parent.is_empty() {
            return;
        }
        self.parent.entry(s.child.clone()).or_insert_with(|| s.parent.clone());
        if is_static {
            self.fixed.insert(s.child, s.pose);
        } else {
            self.moving.entry(s.child).or_default().push(s.stamp_ns, s.pose);
        }
    }

    fn sort(&mut self) {
        self.moving.values_mut().for_each(Track::sort);
    }

    /// The frames from `frame` up to its root (`frame` first, the root last).
    pub fn chain(&self, frame: &str) -> Vec<String> {
        let mut out = vec![frame.to_string()];
        while let Some(p) = self.parent.get(out.last().expect("not empty")) {
            if out.contains(p) || out.len() > 64 {
                break;
            }
            out.push(p.clone());
        }
        out
    }

    /// Whether the chain from `frame` up to `root` moves (holds a `/tf` transform).
    fn moves(&self, root: &str, frame: &str) -> bool {
        let chain = self.chain(frame);
        let upto = chain.iter().position(|f| f == root).unwrap_or(chain.len());
        chain[..upto].iter().any(|f| self.moving.contains_key(f))
    }

    /// `frame`'s pose in `root` at `t` (ns), when the chain reaches `root` and each moving
    /// transform of it has a pose then.
    pub fn pose(&self, root: &str, frame: &str, t: i64, tol: i64) -> Option<Iso> {
        let chain = self.chain(frame);
        let upto = chain.iter().position(|f| f == root)?;
        let mut pose = Iso::identity();
        for child in chain[..upto].iter().rev() {
            let step = match self.fixed.get(child) {
                Some(p) => *p,
                None => self.moving.get(child)?.at(t, tol)?,
            };
            pose *= step;
        }
        Some(pose)
    }

    /// `frame`'s pose in `root` from the fixed transforms alone (a mounting).
    fn fixed_pose(&self, root: &str, frame: &str) -> Option<Iso> {
        let chain = self.chain(frame);
        let upto = chain.iter().position(|f| f == root)?;
        chain[..upto]
            .iter()
            .rev()
            .try_fold(Iso::identity(), |pose, child| Some(pose * self.fixed.get(child)?))
    }
}

/// What a log holds of poses, gathered in one pass.
#[derive(Clone, Debug, Default)]
pub struct LogPoses {
    /// The transform tree.
    pub tf: TfTree,
    /// Every pose topic: its kind, the frame its poses are in and of (Odometry's
    /// `child_frame_id`; empty for the others), and its track.
    pub topics: BTreeMap<String, (PoseKind, String, String, Track)>,
    /// The point clouds' `header.frame_id` (the first one's).
    pub cloud_frame: Option<String>,
    /// The point clouds' stamps (ns), in log order.
    pub cloud_stamps: Vec<i64>,
}

/// The pose keys of a message-log source.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseKeys {
    /// `poses_topic`: a pose topic, or `/tf` for the transform chain.
    pub topic: Option<String>,
    /// `pose_frames = "parent:child"`.
    pub frames: Option<(String, String)>,
}

/// How a log's scans take their poses, decided.
#[derive(Clone, Debug, PartialEq)]
pub enum Choice {
    /// The transform chain from `root` down to `frame` (the cloud's).
    Chain {
        /// The root frame.
        root: String,
        /// The cloud's frame.
        frame: String,
    },
    /// A pose topic, then the mounting to the cloud's frame.
    Topic {
        /// The topic.
        topic: String,
        /// The frame its poses are of.
        of: String,
        /// The cloud's frame.
        frame: String,
    },
}

impl Choice {
    /// In words, for `inspect` and the summaries.
    pub fn describe(&self) -> String {
        match self {
            Choice::Chain { root, frame } => format!("/tf chain {root} → {frame}"),
            Choice::Topic { topic, of, frame } if of == frame => format!("{topic} (poses of {frame})"),
            Choice::Topic { topic, of, frame } => {
                format!("{topic} (poses of {of}, mounted {of} → {frame} by /tf_static)")
            }
        }
    }

    /// The pipeline keys that choose it (`poses_topic`, `pose_frames`).
    pub fn keys(&self) -> PoseKeys {
        match self {
            Choice::Chain { root, frame } => {
                PoseKeys { topic: Some("/tf".into()), frames: Some((root.clone(), frame.clone())) }
            }
            Choice::Topic { topic, of, frame } => PoseKeys {
                topic: Some(topic.clone()),
                frames: (of != frame).then(|| (of.clone(), frame.clone())),
            },
        }
    }
}

/// Whether a topic is one of the transform topics.
fn is_tf_topic(topic: &str) -> bool {
    topic == "/tf" || topic == "/tf_static" || topic == "tf" || topic == "tf_static"
}

impl LogPoses {
    /// Gathers the poses of a log's messages (`cloud_topic`: the point-cloud topic read).
    pub(crate) fn gather(
        path: &Path,
        channels: &[ChannelInfo],
        messages: super::logs::Messages,
        cloud_topic: &str,
    ) -> Result<Self, SourceError> {
        let kinds: HashMap<&str, PoseKind> = channels
            .iter()
            .filter_map(|c| PoseKind::of_schema(&c.schema_name).map(|k| (c.topic.as_str(), k)))
            .collect();
        let mut out = LogPoses::default();
        for m in messages {
            let Ok(m) = m else { continue };
            let wire = if m.channel.message_encoding == "cdr" { Wire::Cdr } else { Wire::Ros1 };
            if m.channel.topic == cloud_topic && is_point_cloud(&m.channel) {
                let encoding = super::pointcloud2::Encoding::of_channel(&m.channel.message_encoding);
                if let Ok(c) = super::pointcloud2::parse(&m.data, encoding) {
                    out.cloud_frame.get_or_insert(c.frame_id);
                    out.cloud_stamps.push(if c.stamp_ns != 0 { c.stamp_ns } else { m.log_time as i64 });
                }
                continue;
            }
            let Some(&kind) = kinds.get(m.channel.topic.as_str()) else { continue };
            let stamped = decode(kind, &m.data, wire).map_err(|e| {
                SourceError::invalid(path, format!("a {} message on {}: {e}", kind.name(), m.channel.topic))
            })?;
            if kind == PoseKind::Tf {
                let is_static = m.channel.topic.ends_with("tf_static");
                stamped.into_iter().for_each(|s| out.tf.add(s, is_static));
                continue;
            }
            for s in stamped {
                let entry = out
                    .topics
                    .entry(m.channel.topic.clone())
                    .or_insert_with(|| (kind, s.parent.clone(), s.child.clone(), Track::default()));
                entry.3.push(s.stamp_ns, s.pose);
            }
        }
        out.tf.sort();
        out.topics.values_mut().for_each(|t| t.3.sort());
        Ok(out)
    }

    /// The pose topics (not `/tf`), as `topic (kind, n poses)`.
    pub fn topic_list(&self) -> Vec<String> {
        self.topics
            .iter()
            .filter(|(t, _)| !is_tf_topic(t))
            .map(|(t, (k, _, child, track))| {
                let of = if child.is_empty() { String::new() } else { format!(", of {child}") };
                format!("{t} ({}{of}, {} poses)", k.name(), track.len())
            })
            .collect()
    }

    /// The choice `keys` make (or, without keys, the one found; `None` when the log holds no
    /// pose), checked: an error names the file and what to pass.
    pub fn choose(&self, path: &Path, keys: &PoseKeys) -> Result<Option<Choice>, SourceError> {
        let bad = |m: String| Err(SourceError::invalid(path, m));
        let Some(frame) = self.cloud_frame.clone() else {
            return if keys.topic.is_some() || keys.frames.is_some() {
                bad("no point cloud with a frame id: no pose can be joined".into())
            } else {
                Ok(None)
            };
        };
        let chain_to = |root: &str, to: &str| -> Result<Choice, SourceError> {
            if self.tf.chain(to).iter().any(|f| f == root) {
                Ok(Choice::Chain { root: root.into(), frame: to.into() })
            } else {
                Err(SourceError::invalid(
                    path,
                    format!(
                        "no /tf chain from {root} to {to} (the chain from {to} reaches {}); give other --pose-frames",
                        self.tf.chain(to).join(" → ")
                    ),
                ))
            }
        };
        match (&keys.topic, &keys.frames) {
            (Some(t), frames) if is_tf_topic(t) => match frames {
                Some((root, to)) => chain_to(root, to).map(Some),
                None => {
                    let root = self.tf.chain(&frame).last().cloned().unwrap_or_default();
                    chain_to(&root, &frame).map(Some)
                }
            },
            (Some(t), frames) => {
                let Some((_, _, child, _)) = self.topics.get(t) else {
                    return bad(format!("no pose topic {t} (pose topics: {})", self.topic_list().join(", ")));
                };
                let of = match frames {
                    Some((of, _)) => of.clone(),
                    None if !child.is_empty() => child.clone(),
                    None => frame.clone(),
                };
                self.mounted(path, t, &of, &frame).map(Some)
            }
            (None, Some((root, to))) => chain_to(root, to).map(Some),
            (None, None) => {
                let root = self.tf.chain(&frame).last().cloned().unwrap_or_default();
                if root != frame && self.tf.moves(&root, &frame) {
                    return Ok(Some(Choice::Chain { root, frame }));
                }
                let topics: Vec<&String> = self.topics.keys().filter(|t| !is_tf_topic(t)).collect();
                match topics.as_slice() {
                    [] => Ok(None),
                    [t] => {
                        let child = &self.topics[*t].2;
                        let of = if child.is_empty() { frame.clone() } else { child.clone() };
                        self.mounted(path, t, &of, &frame).map(Some)
                    }
                    _ => bad(format!(
                        "several pose topics ({}) and no /tf chain to {frame}: choose one with --poses-topic",
                        self.topic_list().join(", ")
                    )),
                }
            }
        }
    }

    /// A topic's choice, checked: the mounting from the frame its poses are of to the cloud's.
    fn mounted(&self, path: &Path, topic: &str, of: &str, frame: &str) -> Result<Choice, SourceError> {
        if of != frame && self.tf.fixed_pose(of, frame).is_none() {
            return Err(SourceError::invalid(
                path,
                format!(
                    "{topic} gives poses of {of}, and /tf_static does not link {of} to the cloud's frame {frame}; \
                     give --pose-frames {of}:{frame} with the transforms, or another --poses-topic"
                ),
            ));
        }
        Ok(Choice::Topic { topic: topic.into(), of: of.into(), frame: frame.into() })
    }

    /// The pose of the cloud frame at `t` (ns) as `choice` takes it.
    pub fn pose_at(&self, choice: &Choice, t: i64, tol: i64) -> Option<Iso> {
        match choice {
            Choice::Chain { root, frame } => self.tf.pose(root, frame, t, tol),
            Choice::Topic { topic, of, frame } => {
                let pose = self.topics.get(topic)?.3.at(t, tol)?;
                if of == frame { Some(pose) } else { Some(pose * self.tf.fixed_pose(of, frame)?) }
            }
        }
    }

    /// Checks that `choice` gives a pose to some scan: an error names the times when none does.
    pub fn check_overlap(&self, path: &Path, choice: &Choice, tol: i64) -> Result<(), SourceError> {
        if self.cloud_stamps.is_empty()
            || self.cloud_stamps.iter().any(|&t| self.pose_at(choice, t, tol).is_some())
        {
            return Ok(());
        }
        let span = |v: Option<(i64, i64)>| match v {
            Some((a, b)) => format!("{:.3} s to {:.3} s", a as f64 * 1e-9, b as f64 * 1e-9),
            None => "none".into(),
        };
        let scans =
            span(self.cloud_stamps.iter().min().copied().zip(self.cloud_stamps.iter().max().copied()));
        let poses = match choice {
            Choice::Topic { topic, .. } => span(self.topics.get(topic).and_then(|t| t.3.span())),
            Choice::Chain { frame, .. } => {
                let spans: Vec<(i64, i64)> = self.tf.moving.values().filter_map(Track::span).collect();
                span(spans.iter().map(|s| s.0).min().zip(spans.iter().map(|s| s.1).max()))
                    + &format!(" (the chain to {frame})")
            }
        };
        Err(SourceError::invalid(
            path,
            format!(
                "{}: no pose within {} ms of any scan (scans {scans}, poses {poses}); check the topic and the clocks, \
                 or widen tolerance_ms",
                choice.describe(),
                tol / 1_000_000
            ),
        ))
    }
}

/// A transform as toporec keeps a scan's pose: position, and yaw about z.
pub fn pose_of(iso: &Iso) -> Pose {
    let t = iso.translation.vector;
    Pose { x: t.x, y: t.y, z: t.z, yaw: yaw_of(iso) }
}

/// A log's scan poses: from the log (its poses and the choice), or from a file.
#[derive(Clone, Debug)]
pub enum ScanPoses {
    /// From the log.
    Log(std::sync::Arc<LogPoses>, Choice),
    /// From a file.
    File(std::sync::Arc<GroundTruth>),
}

impl ScanPoses {
    /// The pose at `stamp_ns` within `tol_ns`, or why there is none.
    pub fn at(&self, stamp_ns: i64, tol_ns: i64) -> Result<Pose, NoPose> {
        match self {
            ScanPoses::Log(poses, choice) => {
                poses.pose_at(choice, stamp_ns, tol_ns).map(|p| pose_of(&p)).ok_or(NoPose::NoRowNear)
            }
            ScanPoses::File(gt) => gt.pose_at(stamp_ns.div_euclid(1000), tol_ns / 1000),
        }
    }
}

/// Reads a pose file of `format` (`times`: KITTI's `times.txt`; `first_us`: the session's first
/// scan time, for relative times) as a time-indexed table. A file that cannot be read is named
/// as the pose file (or its times file).
pub fn read_file(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<GroundTruth, SourceError> {
    read_file_unnamed(path, format, times, first_us).map_err(|e| match e {
        SourceError::Io { path: p, source } => {
            let what = if p == path { "the pose file" } else { "the pose file's times" };
            SourceError::invalid(&p, format!("cannot read {what}: {source}"))
        }
        e => e,
    })
}

fn read_file_unnamed(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<GroundTruth, SourceError> {
    let text =
        || std::fs::read_to_string(path).map_err(|source| SourceError::Io { path: path.to_owned(), source });
    match format {
        PoseFormat::Nclt => GroundTruth::read(path),
        PoseFormat::Tum => Ok(parse_tum(&text()?, path)),
        PoseFormat::Kitti => {
            let Some(times) = times else {
                return Err(SourceError::invalid(
                    path,
                    "a KITTI poses file has no times: give `poses_times` (its times.txt, seconds per row)",
                ));
            };
            let times_text = std::fs::read_to_string(times)
                .map_err(|source| SourceError::Io { path: times.to_owned(), source })?;
            let mut secs = Vec::new();
            for (i, l) in times_text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
                let t: f64 = l.trim().parse().map_err(|_| SourceError::Parse {
                    path: times.to_owned(),
                    line: i + 1,
                    message: "expected a time in seconds".into(),
                })?;
                secs.push(t);
            }
            // Relative times (a sequence's times.txt starts at 0) start at the first scan.
            let offset = match (secs.first(), first_us) {
                (Some(&t0), Some(first)) if t0.abs() < 1e6 => first,
                _ => 0,
            };
            let rows = kitti_rows(path, &text()?)?;
            if rows.len() != secs.len() {
                return Err(SourceError::invalid(
                    path,
                    format!(
                        "{} poses and {} times in {}: one time per pose",
                        rows.len(),
                        secs.len(),
                        times.display()
                    ),
                ));
            }
            let mut gt = GroundTruth { path: path.to_owned(), ..Default::default() };
            gt.rows =
                rows.into_iter().zip(&secs).map(|(p, t)| ((t * 1e6).round() as i64 + offset, p)).collect();
            gt.rows.sort_by_key(|r| r.0);
            Ok(gt)
        }
    }
}

/// [`read_file`], refusing a file that holds no pose of its layout (the wrong layout, most
/// likely): the error names the file and `--poses-format`.
pub fn read_nonempty(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<GroundTruth, SourceError> {
    let gt = read_file(path, format, times, first_us)?;
    if gt.rows.is_empty() {
        let layout = match format {
            PoseFormat::Nclt => "NCLT: utime,x,y,z,roll,pitch,heading",
            PoseFormat::Tum => "TUM: t x y z qx qy qz qw",
            PoseFormat::Kitti => "KITTI: 3 x 4 rows",
        };
        return Err(SourceError::invalid(
            path,
            format!("no pose read as {layout}; give its layout with --poses-format (tum, kitti, nclt)"),
        ));
    }
    Ok(gt)
}

/// The poses of KITTI-layout text: 3 × 4 row-major `[R | t]` per line (the sensor's pose, z up);
/// `None` for a row with a non-finite value.
pub fn kitti_rows(path: &Path, text: &str) -> Result<Vec<Option<Pose>>, SourceError> {
    let mut out = Vec::new();
    for (i, l) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let v: Option<Vec<f64>> = l.split_whitespace().map(|x| x.parse().ok()).collect();
        let v = v.filter(|v| v.len() == 12).ok_or_else(|| SourceError::Parse {
            path: path.to_owned(),
            line: i + 1,
            message: "expected 12 numbers (a 3x4 pose)".into(),
        })?;
        let (x, y, z, yaw) = (v[3], v[7], v[11], v[4].atan2(v[0]));
        out.push([x, y, z, yaw].iter().all(|c| c.is_finite()).then_some(Pose { x, y, z, yaw }));
    }
    Ok(out)
}

/// TUM trajectory text: `t x y z qx qy qz qw` per line (seconds), `#` comments.
pub fn parse_tum(text: &str, path: &Path) -> GroundTruth {
    let mut gt = GroundTruth { path: path.to_owned(), ..Default::default() };
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Option<Vec<f64>> = line.split_whitespace().map(|f| f.parse().ok()).collect();
        match v.filter(|v| v.len() >= 8 && v[0].is_finite()) {
            Some(v) => {
                let [x, y, z, qx, qy, qz, qw] = [v[1], v[2], v[3], v[4], v[5], v[6], v[7]];
                let yaw = (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
                let pose = Pose { x, y, z, yaw };
                let finite = [x, y, z, yaw].iter().all(|c| c.is_finite());
                if !finite {
                    gt.non_finite_rows += 1;
                }
                gt.rows.push(((v[0] * 1e6).round() as i64, finite.then_some(pose)));
            }
            None => gt.bad_lines.push(format!("line {}: expected 8 numbers: t x y z qx qy qz qw", i + 1)),
        }
    }
    gt.rows.sort_by_key(|r| r.0);
    gt
}

/// `parent:child` as the two frames.
pub fn parse_frames(s: &str) -> Result<(String, String), String> {
    match s.split_once(':') {
        Some((a, b)) if !a.trim().is_empty() && !b.trim().is_empty() => {
            Ok((a.trim().into(), b.trim().into()))
        }
        _ => Err(format!("`{s}`: expected two frames, parent:child (odom:velodyne)")),
    }
}

/// Where the poses of some sessions come from: a pose file, or a log's own messages. A run
/// records one per file or log in the manifest (`info` shows them), with the fingerprint of
/// the poses its rows carry.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseOrigin {
    /// The sessions whose scans take them.
    pub sessions: Vec<String>,
    /// Where they come from, in words (the file and its layout, or the log's topic or chain),
    /// with the join's tolerance.
    pub origin: String,
    /// The pose file, when they come from one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<std::path::PathBuf>,
    /// xxh3-64 of the pose file's bytes (and of its times file's), 16 hex digits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file_xxh3: Option<String>,
    /// Scans of those sessions in the index, after the run.
    #[serde(default)]
    pub scans: u64,
    /// Of those, scans with a pose.
    #[serde(default)]
    pub with_pose: u64,
    /// xxh3-64 of every scan's id, time and pose in those sessions, in id order: equal for two
    /// indexes exactly when their rows carry the same poses.
    #[serde(default)]
    pub poses_xxh3: String,
    /// The pose file's time span (µs), for the message when it joins no scan.
    #[serde(skip)]
    pub span_us: Option<(i64, i64)>,
    /// Lines of the pose file that could not be read, and the first one's message.
    #[serde(skip)]
    pub bad_lines: (usize, Option<String>),
}

impl PoseOrigin {
    /// The origin of a pose file's poses (`times`: a KITTI file's times), read now for its
    /// fingerprint, its span and its bad lines; `joined` says how scans take them.
    pub fn of_file(
        sessions: Vec<String>,
        file: &Path,
        times: Option<&Path>,
        table: &GroundTruth,
        joined: &str,
    ) -> Self {
        let mut hash = crate::fingerprint::Streaming::default();
        for p in std::iter::once(file).chain(times) {
            if let Ok(bytes) = std::fs::read(p) {
                hash.write(&bytes);
            }
        }
        let times_said = times.map(|t| format!(", times {}", t.display())).unwrap_or_default();
        PoseOrigin {
            sessions,
            origin: format!("{}{times_said} ({joined})", file.display()),
            file: Some(file.to_owned()),
            file_xxh3: Some(crate::fingerprint::hex(hash.take())),
            span_us: table.rows.first().map(|f| f.0).zip(table.rows.last().map(|l| l.0)),
            bad_lines: (table.bad_lines.len(), table.bad_lines.first().cloned()),
            ..Default::default()
        }
    }

    /// What a manifest records of it (the counts and fingerprints, not what reading the file
    /// found on the way).
    pub fn recorded(&self) -> Self {
        PoseOrigin { span_us: None, bad_lines: (0, None), ..self.clone() }
    }

    /// The origin of poses read from a source's own data (a log's messages, a dataset's
    /// side files).
    pub fn of_source(sessions: Vec<String>, origin: String) -> Self {
        PoseOrigin { sessions, origin, ..Default::default() }
    }

    /// The warning for the pose file's unreadable lines, once: how many, and the first.
    pub fn bad_lines_warning(&self) -> Option<String> {
        let (n, first) = &self.bad_lines;
        let file = self.file.as_deref()?;
        (*n > 0).then(|| {
            format!(
                "{}: {n} line{} could not be read as poses and {} left out (first: {})",
                file.display(),
                if *n == 1 { "" } else { "s" },
                if *n == 1 { "was" } else { "were" },
                first.as_deref().unwrap_or_default()
            )
        })
    }
}
