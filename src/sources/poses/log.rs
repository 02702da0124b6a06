//! A log's own poses: `/tf` and `/tf_static` gathered into a transform tree, every pose topic
//! into a track, in one pass; the choice of how scans take theirs (a transform chain, or a topic
//! with the sensor's mounting), and the pose of a scan's frame at its stamp.

use crate::sources::SourceError;
use crate::sources::mcap_reader::{ChannelInfo, Messages, is_point_cloud};
use crate::sources::rosmsg::{Iso, PoseKind, Stamped, decode};
use crate::sources::wire::Wire;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

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
        messages: Messages,
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
                let encoding = crate::sources::pointcloud2::Encoding::of_channel(&m.channel.message_encoding);
                if let Ok(c) = crate::sources::pointcloud2::parse(&m.data, encoding) {
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

/// `parent:child` as the two frames.
pub fn parse_frames(s: &str) -> Result<(String, String), String> {
    match s.split_once(':') {
        Some((a, b)) if !a.trim().is_empty() && !b.trim().is_empty() => {
            Ok((a.trim().into(), b.trim().into()))
        }
        _ => Err(format!("`{s}`: expected two frames, parent:child (odom:velodyne)")),
    }
}
