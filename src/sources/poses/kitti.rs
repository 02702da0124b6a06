//! KITTI's pose layout, read once for every reader: 3 × 4 row-major `[R | t]` per line, and
//! `times.txt` (seconds, one per line). The rows are either the sensor's pose, z up (as
//! KISS-ICP writes them), or camera 0's pose in camera 0's frame at frame 0 (KITTI odometry's
//! `poses.txt`), turned z up.

use super::Pose;
use crate::sources::SourceError;
use std::path::Path;

/// Which frame a KITTI pose file's rows are the pose of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KittiFrame {
    /// The sensor's pose, z up (`--poses` files, KISS-ICP's output).
    Sensor,
    /// Camera 0's pose in camera 0's frame at frame 0 (x right, y down, z forward): KITTI
    /// odometry's `poses.txt`. Turned z up: `(t_z, −t_x, −t_y)`, yaw from the camera's forward
    /// axis (its third column) in that frame.
    Camera,
}

/// The text of `path`, without the byte-order mark editors on Windows write.
fn text_of(path: &Path) -> Result<String, SourceError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    Ok(text.strip_prefix('\u{feff}').map(str::to_string).unwrap_or(text))
}

/// The poses of a KITTI-layout file, one per non-empty line, as the pose of `frame`; `None`
/// for a row with a non-finite value. A line that is not 12 numbers is an error naming it.
pub fn kitti_rows(path: &Path, frame: KittiFrame) -> Result<Vec<Option<Pose>>, SourceError> {
    let mut out = Vec::new();
    for (i, l) in text_of(path)?.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let v: Option<Vec<f64>> = l.split_whitespace().map(|x| x.parse().ok()).collect();
        let v = v.filter(|v| v.len() == 12).ok_or_else(|| SourceError::Parse {
            path: path.to_owned(),
            line: i + 1,
            message: "expected 12 numbers (a 3x4 pose)".into(),
        })?;
        let pose = match frame {
            KittiFrame::Sensor => Pose { x: v[3], y: v[7], z: v[11], yaw: v[4].atan2(v[0]) },
            KittiFrame::Camera => {
                let (tx, ty, tz) = (v[3], v[7], v[11]);
                Pose { x: tz, y: -tx, z: -ty, yaw: (-v[2]).atan2(v[10]) }
            }
        };
        out.push([pose.x, pose.y, pose.z, pose.yaw].iter().all(|c| c.is_finite()).then_some(pose));
    }
    Ok(out)
}

/// A `times.txt`: seconds, one per non-empty line (`None` for a non-finite one). A line that is
/// not a number is an error naming it.
pub fn read_times(path: &Path) -> Result<Vec<Option<f64>>, SourceError> {
    let mut out = Vec::new();
    for (i, l) in text_of(path)?.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let t = l.trim().parse::<f64>().map_err(|_| SourceError::Parse {
            path: path.to_owned(),
            line: i + 1,
            message: "expected a time in seconds".into(),
        })?;
        out.push(t.is_finite().then_some(t));
    }
    Ok(out)
}
