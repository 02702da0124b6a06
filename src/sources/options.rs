//! The options of sources given on the command line (`toporec run <source>…`, `toporec loops
//! <source>…`, Python's `toporec.loops`): where their scans take their poses, and the topic of a
//! log with several point-cloud topics.

use super::poses::{PoseFormat, parse_frames};
use std::path::PathBuf;

/// Where the scans of sources given on the command line take their poses and topic.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SourceOptions {
    /// Message logs: the point-cloud topic (default: the log's only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// Poses from a file instead of the log's own: TUM (`t x y z qx qy qz qw`), KITTI (3 × 4
    /// rows, with --poses-times) or NCLT (`.csv`) layout, joined by the nearest time.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The layout of --poses (default: `nclt` for `.csv`, `kitti` with --poses-times, else `tum`).
    #[arg(long, value_enum, requires = "poses")]
    pub poses_format: Option<PoseFormat>,
    /// With KITTI-layout --poses: the times of its rows (its `times.txt`, seconds).
    #[arg(long, requires = "poses")]
    pub poses_times: Option<PathBuf>,
    /// Message logs: the pose topic (nav_msgs/Odometry, geometry_msgs/PoseStamped or
    /// PoseWithCovarianceStamped), or `/tf` for the transform chain (default: the chain from the
    /// cloud's frame to its root when /tf moves it, else the log's only pose topic).
    #[arg(long, conflicts_with = "poses")]
    pub poses_topic: Option<String>,
    /// Message logs: `parent:child`, the transform chain from `parent` down to `child` (the
    /// cloud's frame); with --poses-topic, the frame its poses are of and the cloud's.
    #[arg(long, value_parser = parse_frames, conflicts_with = "poses")]
    pub pose_frames: Option<(String, String)>,
    /// The largest time gap of a pose join (ms, ≥ 0).
    #[arg(long, default_value_t = 100.0, value_parser = crate::ranges::non_negative)]
    pub tolerance_ms: f64,
}

impl SourceOptions {
    /// Whether they ask for poses other than a source's own (a file, a topic, frames): only a
    /// message log takes them.
    pub fn asks_for_poses(&self) -> bool {
        self.poses.is_some() || self.poses_topic.is_some() || self.pose_frames.is_some()
    }

    /// The layout of `--poses`: given, or guessed by [`PoseFormat::guess`].
    pub fn poses_layout(&self) -> Option<PoseFormat> {
        let file = self.poses.as_deref()?;
        Some(self.poses_format.unwrap_or_else(|| PoseFormat::guess(file, self.poses_times.as_deref())))
    }
}
