//! Poses as the optimizer moves them: SE(2) and SE(3), each with its composition, inverse, and
//! exponential and logarithm maps (the whole group's, as GTSAM's `Pose2` and `Pose3` charts at
//! the identity: a translation's local coordinate is `V(ω)⁻¹ t`, not `t`).
//!
//! A pose's tangent vector is ordered as g2o orders an edge's error, so g2o's information
//! matrices apply to it as written: `[x, y, θ]` in SE(2), `[x, y, z, ωx, ωy, ωz]` in SE(3). A
//! pose moves on the right: `X ⊕ δ = X · Exp(δ)`.

use nalgebra::{
    Isometry2, Isometry3, Matrix3, SVector, Translation3, UnitComplex, UnitQuaternion, Vector2, Vector3,
};

/// A pose of SE(2) or SE(3), with `D` degrees of freedom.
pub trait Pose<const D: usize>: Copy + Send + Sync + std::fmt::Debug + 'static {
    /// The identity.
    fn identity() -> Self;
    /// `self · other`.
    fn compose(&self, other: &Self) -> Self;
    /// `self⁻¹`.
    fn inverse(&self) -> Self;
    /// The group exponential of a tangent vector.
    fn exp(v: &SVector<f64, D>) -> Self;
    /// The group logarithm: the tangent vector at the identity.
    fn log(&self) -> SVector<f64, D>;
    /// Its position (x, y, z; z = 0 in the plane).
    fn position(&self) -> [f64; 3];
    /// The same pose as a 3D isometry (in the plane z = 0).
    fn to_3d(&self) -> Isometry3<f64>;
    /// The pose of a 3D isometry (its planar part, for SE(2)).
    fn from_3d(iso: &Isometry3<f64>) -> Self;

    /// The right-perturbed pose `self · Exp(δ)`.
    fn retract(&self, delta: &SVector<f64, D>) -> Self {
        self.compose(&Self::exp(delta))
    }

    /// The error of a relative pose `measured` between `self` and `other`: `Log(Z⁻¹ · X_i⁻¹ ·
    /// X_j)` (GTSAM's `BetweenFactor`).
    fn between_error(&self, other: &Self, measured_inverse: &Self) -> SVector<f64, D> {
        measured_inverse.compose(&self.inverse().compose(other)).log()
    }
}

/// A planar pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se2(pub Isometry2<f64>);

/// A pose in space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3(pub Isometry3<f64>);

/// `(sin θ / θ, (1 − cos θ) / θ)`, by series near 0.
fn sinc_cosc(theta: f64) -> (f64, f64) {
    if theta.abs() < 1e-6 {
        let t2 = theta * theta;
        (1.0 - t2 / 6.0, theta / 2.0 - theta * t2 / 24.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta)
    }
}

impl Pose<3> for Se2 {
    fn identity() -> Self {
        Se2(Isometry2::identity())
    }

    fn compose(&self, other: &Self) -> Self {
        Se2(self.0 * other.0)
    }

    fn inverse(&self) -> Self {
        Se2(self.0.inverse())
    }

    fn exp(v: &SVector<f64, 3>) -> Self {
        let theta = v[2];
        let (a, b) = sinc_cosc(theta);
        let t = Vector2::new(a * v[0] - b * v[1], b * v[0] + a * v[1]);
        Se2(Isometry2::from_parts(t.into(), UnitComplex::new(theta)))
    }

    fn log(&self) -> SVector<f64, 3> {
        let theta = self.0.rotation.angle();
        let (a, b) = sinc_cosc(theta);
        // V = [[a, −b], [b, a]]; V⁻¹ = [[a, b], [−b, a]] / (a² + b²).
        let t = self.0.translation.vector;
        let n = a * a + b * b;
        SVector::<f64, 3>::new((a * t.x + b * t.y) / n, (-b * t.x + a * t.y) / n, theta)
    }

    fn position(&self) -> [f64; 3] {
        [self.0.translation.x, self.0.translation.y, 0.0]
    }

    fn to_3d(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.0.translation.x, self.0.translation.y, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.0.rotation.angle()),
        )
    }

    fn from_3d(iso: &Isometry3<f64>) -> Self {
        let t = iso.translation.vector;
        let (_, _, yaw) = iso.rotation.euler_angles();
        Se2(Isometry2::new(Vector2::new(t.x, t.y), yaw))
    }
}

/// `[ω]×`.
fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// `V(ω) = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²`, the translation part of SE(3)'s
/// exponential.
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = w.norm_squared();
    let theta = theta2.sqrt();
    let k = hat(w);
    let (b, c) = if theta < 1e-5 {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    Matrix3::identity() + k * b + k * k * c
}

/// `V(ω)⁻¹ = I − ½[ω]× + (1/θ²)(1 − θ sin θ / (2(1 − cos θ))) [ω]×²`.
fn left_jacobian_inverse(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = w.norm_squared();
    let theta = theta2.sqrt();
    let k = hat(w);
    let c = if theta < 1e-5 {
        1.0 / 12.0 + theta2 / 720.0
    } else {
        (1.0 - theta * theta.sin() / (2.0 * (1.0 - theta.cos()))) / theta2
    };
    Matrix3::identity() - k * 0.5 + k * k * c
}

impl Pose<6> for Se3 {
    fn identity() -> Self {
        Se3(Isometry3::identity())
    }

    fn compose(&self, other: &Self) -> Self {
        Se3(self.0 * other.0)
    }

    fn inverse(&self) -> Self {
        Se3(self.0.inverse())
    }

    fn exp(v: &SVector<f64, 6>) -> Self {
        let rho = Vector3::new(v[0], v[1], v[2]);
        let w = Vector3::new(v[3], v[4], v[5]);
        let t = left_jacobian(&w) * rho;
        Se3(Isometry3::from_parts(t.into(), UnitQuaternion::from_scaled_axis(w)))
    }

    fn log(&self) -> SVector<f64, 6> {
        let w = self.0.rotation.scaled_axis();
        let rho = left_jacobian_inverse(&w) * self.0.translation.vector;
        SVector::<f64, 6>::new(rho.x, rho.y, rho.z, w.x, w.y, w.z)
    }

    fn position(&self) -> [f64; 3] {
        let t = self.0.translation.vector;
        [t.x, t.y, t.z]
    }

    fn to_3d(&self) -> Isometry3<f64> {
        self.0
    }

    fn from_3d(iso: &Isometry3<f64>) -> Self {
        Se3(*iso)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close<const D: usize>(a: &SVector<f64, D>, b: &SVector<f64, D>) -> bool {
        (a - b).norm() < 1e-9
    }

    #[test]
    fn exp_and_log_are_inverse() {
        for v in [[0.3, -1.2, 0.7], [1e-8, 2.0, -1e-9], [5.0, 1.0, 3.0]] {
            let v = SVector::<f64, 3>::from(v);
            assert!(close(&Se2::exp(&v).log(), &v), "{v:?}");
        }
        for v in [
            [0.3, -1.2, 0.7, 0.1, -0.4, 0.2],
            [1.0, 2.0, 3.0, 1e-9, 0.0, 2e-9],
            [0.0, 0.0, 0.0, 2.5, 0.3, -0.1],
        ] {
            let v = SVector::<f64, 6>::from(v);
            assert!(close(&Se3::exp(&v).log(), &v), "{v:?}");
        }
    }

    #[test]
    fn a_pure_rotation_and_a_pure_translation_by_hand() {
        // A pure translation: its log is the translation itself.
        let t = Se3(Isometry3::translation(1.0, 2.0, 3.0));
        assert!(close(&t.log(), &SVector::<f64, 6>::new(1.0, 2.0, 3.0, 0.0, 0.0, 0.0)));
        // A quarter turn about z with a translation along x: V⁻¹ t = (π/4, −π/4, 0).
        let q = Se2(Isometry2::new(Vector2::new(1.0, 0.0), std::f64::consts::FRAC_PI_2));
        let l = q.log();
        let p = std::f64::consts::FRAC_PI_4;
        assert!(close(&l, &SVector::<f64, 3>::new(p, -p, std::f64::consts::FRAC_PI_2)), "{l:?}");
    }
}
