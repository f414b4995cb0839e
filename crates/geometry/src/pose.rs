//! Rigid transforms named `a_from_b`: `X_a = R · X_b + T` (metres).

use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::GeometryError;

/// Tolerance on `RᵀR = I` and `det R = 1` when a rotation is read from numbers: files store
/// 6-9 significant digits, so 1e-5 accepts them and rejects anything that is not a rotation.
const ROTATION_TOLERANCE: f64 = 1e-5;

/// The angle of the rotation `r`, radians, in [0, π]: `atan2(sin θ, cos θ)` with
/// `sin θ = |vee(R − Rᵀ)| / 2` and `cos θ = (trace R − 1) / 2`. nalgebra's `Rotation3::angle`
/// is `acos(cos θ)`: NaN when rounding puts `cos θ` an ulp above 1, as in a near-identity
/// rotation read from a file and re-orthonormalised (`kfuse rig show` printed "rotation NaN°"
/// for the simulated sensor's own rig), and only half the digits near 0. Every angle of a
/// rotation in the workspace goes through this.
pub fn rotation_angle(r: &Rotation3<f64>) -> f64 {
    let m = r.matrix();
    let vee = Vector3::new(m[(2, 1)] - m[(1, 2)], m[(0, 2)] - m[(2, 0)], m[(1, 0)] - m[(0, 1)]);
    (vee.norm() / 2.0).atan2((m.trace() - 1.0) / 2.0)
}

/// A rigid transform `X_a = rotation · X_b + translation`. Name variables after the frames
/// they connect (`color_from_depth`), never a bare `pose`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    /// Rotation part.
    pub rotation: Rotation3<f64>,
    /// Translation part, metres.
    pub translation: Vector3<f64>,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::identity()
    }
}

impl RigidTransform {
    /// The identity.
    pub fn identity() -> Self {
        Self { rotation: Rotation3::identity(), translation: Vector3::zeros() }
    }

    /// From a rotation and a translation (metres).
    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Self { rotation, translation }
    }

    /// From a Rodrigues / axis-angle vector (radians) and a translation (metres), as OpenCV's
    /// `rvec, tvec` and Bouguet's `om, T`.
    pub fn from_axis_angle(rvec: Vector3<f64>, translation: Vector3<f64>) -> Self {
        Self { rotation: Rotation3::new(rvec), translation }
    }

    /// From a 3x3 matrix that must be a rotation (orthonormal, det = +1 within 1e-5).
    pub fn from_matrix(r: Matrix3<f64>, translation: Vector3<f64>) -> Result<Self, GeometryError> {
        let orth = (r.transpose() * r - Matrix3::identity()).abs().max();
        let det = r.determinant();
        if !r.iter().all(|v| v.is_finite())
            || orth > ROTATION_TOLERANCE
            || (det - 1.0).abs() > ROTATION_TOLERANCE
        {
            return Err(GeometryError::InvalidParameter(format!(
                "rotation is not a rotation matrix (|RᵀR - I| = {orth:.2e}, det = {det:.6}): {}",
                one_line(&r)
            )));
        }
        if !translation.iter().all(|v| v.is_finite()) {
            return Err(GeometryError::InvalidParameter(format!(
                "translation is not finite: [{}, {}, {}]",
                short(translation.x),
                short(translation.y),
                short(translation.z)
            )));
        }
        // Re-orthonormalise so later compositions stay exact.
        Ok(Self { rotation: Rotation3::from_matrix(&r), translation })
    }

    /// The Rodrigues vector (axis × angle, radians); zero for the identity.
    pub fn axis_angle(&self) -> Vector3<f64> {
        self.rotation
            .axis()
            .map_or_else(Vector3::zeros, |a| a.into_inner() * rotation_angle(&self.rotation))
    }

    /// Rotation angle in degrees, in [0, 180] ([`rotation_angle`]).
    pub fn angle_deg(&self) -> f64 {
        rotation_angle(&self.rotation).to_degrees()
    }

    /// Applies the transform to a point.
    #[inline]
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// The inverse: if `self` is `a_from_b`, the result is `b_from_a`.
    pub fn inverse(&self) -> Self {
        let r = self.rotation.inverse();
        Self { rotation: r, translation: -(r * self.translation) }
    }

    /// Composition: `a_from_b.then_from(b_from_c)` is `a_from_c`.
    pub fn compose(&self, b_from_c: &RigidTransform) -> Self {
        Self {
            rotation: self.rotation * b_from_c.rotation,
            translation: self.rotation * b_from_c.translation + self.translation,
        }
    }

    /// The 4x4 homogeneous matrix.
    pub fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(self.rotation.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }
}

/// On-disk form: rotation as a row-major 3x3 matrix, translation in metres.
#[derive(Serialize, Deserialize)]
struct RigidTransformFile {
    rotation: [[f64; 3]; 3],
    translation_m: [f64; 3],
}

impl Serialize for RigidTransform {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let m = self.rotation.matrix();
        let mut rotation = [[0.0; 3]; 3];
        for (i, row) in rotation.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = m[(i, j)];
            }
        }
        let t = self.translation;
        RigidTransformFile { rotation, translation_m: [t.x, t.y, t.z] }.serialize(s)
    }
}

impl<'de> Deserialize<'de> for RigidTransform {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let f = RigidTransformFile::deserialize(d)?;
        let r = Matrix3::from_fn(|i, j| f.rotation[i][j]);
        RigidTransform::from_matrix(r, Vector3::from(f.translation_m))
            .map_err(serde::de::Error::custom)
    }
}

/// A 3x3 matrix on one line, rows in brackets (for error messages).
fn one_line(m: &Matrix3<f64>) -> String {
    let rows: Vec<String> = m
        .row_iter()
        .map(|r| format!("[{}, {}, {}]", short(r[0]), short(r[1]), short(r[2])))
        .collect();
    format!("[{}]", rows.join(", "))
}

/// `v` for a message: as written when it is of a size a pose has, in exponent form otherwise
/// (`{}` wrote 1e300 as 301 digits, a message of 1 200 characters for one bad matrix).
fn short(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn inverse_and_compose_round_trip() {
        let a_from_b = RigidTransform::from_axis_angle(
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(0.05, 0.0, -0.01),
        );
        let p = Vector3::new(0.3, -0.4, 2.0);
        let back = a_from_b.inverse().apply(&a_from_b.apply(&p));
        // 1e-14: f64 round-off of a rotation and a translation on O(1) values (~1e-16 per
        // operation, a few dozen operations), with margin; a wrong inverse is off by O(0.1).
        assert_relative_eq!(back, p, epsilon = 1e-14);
        let id = a_from_b.compose(&a_from_b.inverse());
        assert_relative_eq!(id.matrix(), Matrix4::identity(), epsilon = 1e-14);
        assert_relative_eq!(a_from_b.axis_angle(), Vector3::new(0.1, -0.2, 0.3), epsilon = 1e-14);
    }

    /// A near-identity rotation whose trace rounds to 3 + 4.4e-16 (cos θ one ulp above 1):
    /// nalgebra's acos gives NaN, [`rotation_angle`] 0; and small and large angles against
    /// the angle they were built from (1e-12 rad: f64 round-off of a few operations).
    #[test]
    fn rotation_angle_is_finite_next_to_the_identity() {
        let m = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1.0 + 4.0 * f64::EPSILON));
        let r = Rotation3::from_matrix_unchecked(m);
        assert!(r.angle().is_nan(), "nalgebra's angle of this matrix is NaN");
        assert_eq!(rotation_angle(&r), 0.0);
        let t = RigidTransform::new(r, Vector3::zeros());
        assert_eq!(t.angle_deg(), 0.0);
        assert_eq!(t.axis_angle(), Vector3::zeros());
        for angle in [1e-9, 1e-4, 0.5, 3.0] {
            let r = Rotation3::new(Vector3::new(0.6, -0.8, 0.0) * angle);
            assert!((rotation_angle(&r) - angle).abs() < 1e-12, "{angle}: {}", rotation_angle(&r));
        }
    }

    #[test]
    fn json_round_trip_and_non_rotation_rejected() {
        let t = RigidTransform::from_axis_angle(
            Vector3::new(-0.001, 0.025, 0.007),
            Vector3::new(-0.052, -0.0003, 0.0006),
        );
        let s = serde_json::to_string(&t).unwrap();
        let back: RigidTransform = serde_json::from_str(&s).unwrap();
        assert_relative_eq!(back.matrix(), t.matrix(), epsilon = 1e-15);
        let bad = r#"{"rotation":[[2,0,0],[0,1,0],[0,0,1]],"translation_m":[0,0,0]}"#;
        // Well-formed JSON holding a matrix that is not a rotation: refused by from_matrix's
        // check (a data error naming the rotation), not by the JSON parser.
        let e = serde_json::from_str::<RigidTransform>(bad).unwrap_err();
        assert!(e.is_data() && e.to_string().contains("not a rotation matrix"), "{e}");
    }
}
