//! TUM trajectories (`t x y z qx qy qz qw`, seconds; `#` comments): what KISS-ICP and most SLAM
//! systems write. Yaw from the quaternion, z up as written.

use super::{Pose, PoseTable};
use std::path::Path;

/// TUM trajectory text: `t x y z qx qy qz qw` per line (seconds), `#` comments.
pub fn parse_tum(text: &str, path: &Path) -> PoseTable {
    let mut gt = PoseTable { path: path.to_owned(), ..Default::default() };
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
