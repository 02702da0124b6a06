//! The odometry's veto: a loop that the odometry alone rules out never enters the map.
//!
//! Within one session the odometry says where the query lies from the matched scan, within a σ
//! that grows along the path between them by the map's own drift model (the σ of its odometry
//! edges, given by the map): each step's translation σ, and its yaw σ swinging the rest
//! of the path about the step (first order). A loop whose claimed place lies further from the
//! odometry's than χ² of 3 degrees of freedom at 1 − 10⁻⁶ allows (5.5 σ), the loop's own σ
//! added, is rejected before the solve.
//!
//! Why before: the solve's graduated non-convexity starts every loop at weight 1, from least
//! squares. A few false loops that agree with each other (consecutive scans at a lookalike
//! corner, which pass ICP together) can bend that start so far that a true loop closing the lap
//! looks the inconsistent one, and is rejected with them. The veto is far looser than the
//! solve's own bound (1 − 10⁻⁶ against 0.99), since it weighs a loop against the odometry
//! alone, with no other loop to share the drift: it removes only the loops the odometry cannot
//! have drifted into. Loops between sessions, which share no odometry, are left to the solve.
//!
//! The drift model ([`DriftModel`], `--odometry-drift`) is the map's: the σ of its odometry
//! edges.

use nalgebra::{Isometry3, Vector3};

/// The odometry's drift model (`--odometry-drift TRANSLATION,YAW`): a step's σ is 2 cm +
/// `translation` × its length for each axis of its translation, 0.002 rad + `yaw` rad a metre
/// for its yaw, 0.01 rad for roll and pitch. The default, 2 % and 0.005 rad a metre, allows for
/// a wheel odometry's drift; a tighter model lets the map reject more false loops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftModel {
    /// σ of each axis of a step's translation per metre of it, beyond 2 cm.
    pub translation: f64,
    /// σ of a step's yaw per metre of it (rad), beyond 0.002 rad.
    pub yaw: f64,
}

impl Default for DriftModel {
    fn default() -> Self {
        DriftModel { translation: 0.02, yaw: 0.005 }
    }
}

impl std::str::FromStr for DriftModel {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let number = |t: &str| t.parse::<f64>().ok().filter(|v| v.is_finite() && *v >= 0.0);
        match parts[..] {
            [t, y] => match (number(t), number(y)) {
                (Some(translation), Some(yaw)) => Ok(DriftModel { translation, yaw }),
                _ => Err(format!(
                    "{s}: two numbers ≥ 0 (the translation's σ a metre, the yaw's in rad a metre)"
                )),
            },
            _ => Err(format!("{s}: give TRANSLATION,YAW (for example 0.02,0.005)")),
        }
    }
}

impl DriftModel {
    /// The σ of a step of `step`: translation (m), roll and pitch, yaw (rad).
    pub(super) fn sigmas(&self, step: &Isometry3<f64>) -> (f64, f64, f64) {
        let d = step.translation.vector.norm();
        (0.02 + self.translation * d, 0.01, 0.002 + self.yaw * d)
    }
}

/// χ² of 3 degrees of freedom at probability 1 − 10⁻⁶.
const CHI2_3_VETO: f64 = 30.665;

/// Running sums along each session's odometry, from its first posed scan: for each walk
/// position, the sums over the steps that end at or before it.
#[derive(Clone, Copy, Debug, Default)]
struct Sums {
    /// The session's index, to tell two scans of one session.
    session: usize,
    /// Σ σ_t² (translation, per axis).
    translation: f64,
    /// Σ σ_yaw².
    yaw: f64,
    /// Σ σ_yaw² x (x: the step's end, relative to the session's first scan).
    yaw_x: Vector3<f64>,
    /// Σ σ_yaw² |x|².
    yaw_xx: f64,
    /// The scan's position relative to the session's first scan.
    at: Vector3<f64>,
}

/// The odometry's σ between any two scans of a session, in constant time.
pub(super) struct Drift {
    sums: Vec<Option<Sums>>,
}

impl Drift {
    /// The sums over the walk's scans at `poses` (each scan's stored pose; none: not posed),
    /// chained by the map's odometry `steps` (its walk positions from one posed scan to the next
    /// of its session, in walking order), each step's σ by `model`.
    pub(super) fn new(
        poses: &[Option<Isometry3<f64>>],
        steps: &[(usize, usize)],
        model: &DriftModel,
    ) -> Drift {
        let mut previous = vec![None; poses.len()];
        for &(u, v) in steps {
            previous[v] = Some(u);
        }
        let mut origins: Vec<Vector3<f64>> = Vec::new();
        let mut sums: Vec<Option<Sums>> = vec![None; poses.len()];
        for v in 0..poses.len() {
            let Some(pose) = poses[v] else { continue };
            sums[v] = Some(match previous[v] {
                Some(u) => {
                    let before = sums[u].expect("a step starts at an earlier posed scan");
                    let step = poses[u].expect("posed").inverse() * pose;
                    let (translation, _, yaw) = model.sigmas(&step);
                    let at = pose.translation.vector - origins[before.session];
                    Sums {
                        session: before.session,
                        translation: before.translation + translation * translation,
                        yaw: before.yaw + yaw * yaw,
                        yaw_x: before.yaw_x + yaw * yaw * at,
                        yaw_xx: before.yaw_xx + yaw * yaw * at.norm_squared(),
                        at,
                    }
                }
                // A session's first posed scan starts its chain.
                None => {
                    origins.push(pose.translation.vector);
                    Sums { session: origins.len() - 1, ..Sums::default() }
                }
            });
        }
        Drift { sums }
    }

    /// The odometry's variance (m², per axis) of the later of `a` and `b` seen from the
    /// earlier, when both are posed scans of one session.
    fn variance(&self, a: usize, b: usize) -> Option<f64> {
        let (early, late) = (self.sums[a.min(b)]?, self.sums[a.max(b)]?);
        if early.session != late.session {
            return None;
        }
        let x = late.at;
        let yaw = late.yaw - early.yaw;
        let yaw_x = late.yaw_x - early.yaw_x;
        let yaw_xx = late.yaw_xx - early.yaw_xx;
        // Σ σ_yaw² |x_late − x_i|², expanded over the running sums.
        let swing = yaw * x.norm_squared() - 2.0 * x.dot(&yaw_x) + yaw_xx;
        Some(late.translation - early.translation + swing.max(0.0))
    }

    /// Whether the odometry rules out a loop claiming `claimed` (the query `b`'s pose in the
    /// matched scan `a`'s frame, translation σ² `loop_variance` per axis), where `odometry` is
    /// the stored poses' `a⁻¹ b`.
    pub(super) fn rules_out(
        &self,
        a: usize,
        b: usize,
        odometry: &Isometry3<f64>,
        claimed: &Isometry3<f64>,
        loop_variance: f64,
    ) -> bool {
        let Some(variance) = self.variance(a, b) else { return false };
        let apart = (odometry.inverse() * claimed).translation.vector.norm_squared();
        apart > CHI2_3_VETO * (variance + loop_variance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Steps between walk positions, and the scans' poses.
    type Walk = (Vec<(usize, usize)>, Vec<Option<Isometry3<f64>>>);

    /// `n` scans 2 m apart along x, and their steps, the walk positions starting at `first`.
    fn straight(n: usize, first: usize) -> Walk {
        let steps = (first..first + n - 1).map(|k| (k, k + 1)).collect();
        let poses = (0..n)
            .map(|k| {
                Some(Isometry3::from_parts(
                    Translation3::new(2.0 * k as f64, 0.0, 0.0),
                    UnitQuaternion::identity(),
                ))
            })
            .collect();
        (steps, poses)
    }

    #[test]
    fn the_variance_is_the_sum_along_the_path() {
        let (steps, poses) = straight(11, 0);
        let drift = Drift::new(&poses, &steps, &DriftModel::default());
        // Ten steps of 2 m: σ_t = 0.06 m, σ_yaw = 0.012 rad, the end 2, 4, …, 20 m from each
        // step's end.
        let expected: f64 =
            (0..10).map(|i| 0.06f64.powi(2) + 0.012f64.powi(2) * (2.0 * i as f64).powi(2)).sum();
        let got = drift.variance(0, 10).expect("one session");
        assert!((got - expected).abs() < 1e-9 * expected, "{got} against {expected}");
        assert_eq!(drift.variance(3, 7), drift.variance(7, 3));
        // σ = 0.45 m: a place 2 m from the odometry's is within the veto's 5.5 σ; 3 m is not.
        let odometry = poses[0].unwrap().inverse() * poses[10].unwrap();
        let near = odometry * Isometry3::translation(0.0, 2.0, 0.0);
        let far = odometry * Isometry3::translation(0.0, 3.0, 0.0);
        assert!(!drift.rules_out(0, 10, &odometry, &near, 0.0025));
        assert!(drift.rules_out(0, 10, &odometry, &far, 0.0025));
    }

    #[test]
    fn scans_of_two_sessions_are_left_to_the_solve() {
        let (mut steps, mut poses) = straight(4, 0);
        let (other, other_poses) = straight(4, 4);
        steps.extend(other);
        poses.extend(other_poses);
        let drift = Drift::new(&poses, &steps, &DriftModel::default());
        assert!(drift.variance(1, 2).is_some());
        assert!(drift.variance(1, 6).is_none());
        let far = Isometry3::translation(500.0, 0.0, 0.0);
        assert!(!drift.rules_out(1, 6, &Isometry3::identity(), &far, 0.0025));
    }
}
