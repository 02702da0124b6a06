//! The messages a robot's log carries its poses in, read (and, for the simulator, written) in
//! ROS 1 and ROS 2 (CDR) serialization: `nav_msgs/Odometry`, `geometry_msgs/PoseStamped`,
//! `geometry_msgs/PoseWithCovarianceStamped` and `tf2_msgs/TFMessage` (`/tf`, `/tf_static`).
//! Each gives stamped transforms: a child frame's pose in its parent's frame at a time.

use super::wire::{Reader, Wire, Writer};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// A rigid transform (a frame's pose in another's).
pub type Iso = Isometry3<f64>;

/// A kind of message that carries poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseKind {
    /// `nav_msgs/Odometry`: the pose of `child_frame_id` in `header.frame_id`.
    Odometry,
    /// `geometry_msgs/PoseStamped`: a pose in `header.frame_id`, of a frame it does not name.
    PoseStamped,
    /// `geometry_msgs/PoseWithCovarianceStamped`: likewise, with a covariance.
    PoseWithCovarianceStamped,
    /// `tf2_msgs/TFMessage`: transforms, each of `child_frame_id` in `header.frame_id`.
    Tf,
}

impl PoseKind {
    /// The kind of a message schema (`nav_msgs/Odometry`, `nav_msgs/msg/Odometry`).
    pub fn of_schema(schema: &str) -> Option<Self> {
        match schema.replace("/msg/", "/").as_str() {
            "nav_msgs/Odometry" => Some(PoseKind::Odometry),
            "geometry_msgs/PoseStamped" => Some(PoseKind::PoseStamped),
            "geometry_msgs/PoseWithCovarianceStamped" => Some(PoseKind::PoseWithCovarianceStamped),
            "tf2_msgs/TFMessage" | "tf/tfMessage" => Some(PoseKind::Tf),
            _ => None,
        }
    }

    /// Its ROS 1 name.
    pub fn name(self) -> &'static str {
        match self {
            PoseKind::Odometry => "nav_msgs/Odometry",
            PoseKind::PoseStamped => "geometry_msgs/PoseStamped",
            PoseKind::PoseWithCovarianceStamped => "geometry_msgs/PoseWithCovarianceStamped",
            PoseKind::Tf => "tf2_msgs/TFMessage",
        }
    }
}

/// One stamped transform: `child`'s pose in `parent`'s frame at `stamp_ns` (`child` empty for
/// the pose messages that name no frame).
#[derive(Clone, Debug, PartialEq)]
pub struct Stamped {
    /// Header stamp, ns.
    pub stamp_ns: i64,
    /// The frame the pose is expressed in.
    pub parent: String,
    /// The frame whose pose it is.
    pub child: String,
    /// The pose.
    pub pose: Iso,
}

/// A point and a quaternion (x, y, z, w) read as a transform; a quaternion that is not finite
/// or has no length is an error.
fn read_pose(r: &mut Reader<'_>, what: &str) -> Result<Iso, String> {
    let mut v = [0.0; 7];
    for x in &mut v {
        *x = r.f64(what)?;
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    if !v.iter().all(|x| x.is_finite()) || q.norm() < 1e-9 {
        return Err(format!("{what}: not a pose (a non-finite value or a zero quaternion)"));
    }
    // A quaternion written unit is kept as written (normalizing it again moves its last bits).
    let rotation = if (q.norm() - 1.0).abs() < 1e-12 {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    };
    Ok(Iso::from_parts(Translation3::new(v[0], v[1], v[2]), rotation))
}

/// The stamped transforms of one message of `kind`.
pub fn decode(kind: PoseKind, data: &[u8], wire: Wire) -> Result<Vec<Stamped>, String> {
    let mut r = Reader::new(data, wire)?;
    Ok(match kind {
        PoseKind::Odometry => {
            let (stamp_ns, parent) = r.header()?;
            let child = r.string("child_frame_id")?;
            let pose = read_pose(&mut r, "pose.pose")?;
            vec![Stamped { stamp_ns, parent, child, pose }]
        }
        PoseKind::PoseStamped | PoseKind::PoseWithCovarianceStamped => {
            let (stamp_ns, parent) = r.header()?;
            let pose = read_pose(&mut r, "pose")?;
            vec![Stamped { stamp_ns, parent, child: String::new(), pose }]
        }
        PoseKind::Tf => {
            let n = r.u32("transforms")? as usize;
            if n > 1 << 16 {
                return Err(format!("{n} transforms: corrupt message"));
            }
            let mut out = Vec::with_capacity(n);
            for _ in 0..n {
                let (stamp_ns, parent) = r.header()?;
                let child = r.string("child_frame_id")?;
                let pose = read_pose(&mut r, "transform")?;
                out.push(Stamped { stamp_ns, parent, child, pose });
            }
            out
        }
    })
}

fn write_pose(w: &mut Writer, pose: &Iso) {
    let (t, q) = (pose.translation.vector, pose.rotation.quaternion());
    for v in [t.x, t.y, t.z, q.i, q.j, q.k, q.w] {
        w.f64(v);
    }
}

/// A `nav_msgs/Odometry` of `s` (the pose of `s.child` in `s.parent`), its covariances and its
/// twist zero.
pub fn odometry(s: &Stamped, wire: Wire) -> Vec<u8> {
    let mut w = Writer::new(wire, 720);
    w.header(s.stamp_ns, &s.parent);
    w.string(&s.child);
    write_pose(&mut w, &s.pose);
    (0..36 + 6 + 36).for_each(|_| w.f64(0.0));
    w.finish()
}

/// A `tf2_msgs/TFMessage` of `transforms`.
pub fn tf_message(transforms: &[Stamped], wire: Wire) -> Vec<u8> {
    let mut w = Writer::new(wire, 96 * transforms.len() + 8);
    w.u32(transforms.len() as u32);
    for s in transforms {
        w.header(s.stamp_ns, &s.parent);
        w.string(&s.child);
        write_pose(&mut w, &s.pose);
    }
    w.finish()
}

/// The message definitions of the kinds written here (ROS 1 `message_definition`, ROS 2
/// schema text): their own fields, the nested types named as ROS does.
pub fn definition(kind: PoseKind) -> &'static str {
    match kind {
        PoseKind::Odometry => {
            "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n"
        }
        PoseKind::Tf => "geometry_msgs/TransformStamped[] transforms\n",
        PoseKind::PoseStamped => "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
        PoseKind::PoseWithCovarianceStamped => {
            "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n"
        }
    }
}

/// The ROS 1 md5sum of a kind (as `rosmsg md5` gives it).
pub fn md5sum(kind: PoseKind) -> &'static str {
    match kind {
        PoseKind::Odometry => "cd5e73d190d741a2f92e81eda573aca7",
        PoseKind::Tf => "94810edda583a504dfda3829e70d7eec",
        PoseKind::PoseStamped => "d3812c3cbc69362b77dc0b19b345f8f5",
        PoseKind::PoseWithCovarianceStamped => "953b798c0f514ff060a53a3498ce6246",
    }
}

/// The yaw (about z, counter-clockwise) of a rotation.
pub fn yaw_of(pose: &Iso) -> f64 {
    let m = pose.rotation.to_rotation_matrix();
    m[(1, 0)].atan2(m[(0, 0)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odometry_and_tf_round_trip_in_both_serializations() {
        let pose = Iso::from_parts(
            Translation3::new(1.5, -2.0, 0.25),
            UnitQuaternion::from_euler_angles(0.01, -0.02, 1.2),
        );
        let s = Stamped {
            stamp_ns: 1_317_000_000_123_456_789,
            parent: "odom".into(),
            child: "base_link".into(),
            pose,
        };
        for wire in [Wire::Cdr, Wire::Ros1] {
            let got = decode(PoseKind::Odometry, &odometry(&s, wire), wire).unwrap();
            assert_eq!(got, vec![s.clone()], "{wire:?}");
            let two = [s.clone(), Stamped { child: "velodyne".into(), ..s.clone() }];
            assert_eq!(decode(PoseKind::Tf, &tf_message(&two, wire), wire).unwrap(), two.to_vec());
        }
        assert!((yaw_of(&pose) - 1.2).abs() < 1e-12);
        assert_eq!(PoseKind::of_schema("nav_msgs/msg/Odometry"), Some(PoseKind::Odometry));
        assert!(decode(PoseKind::Odometry, &[0, 1, 0, 0, 1], Wire::Cdr).unwrap_err().contains("ends inside"));
    }
}
