//! Small geometry helpers shared by tasks, controller and renderer.
//!
//! Rotations are exchanged in the "6D" form: the first two ROWS of the rotation matrix,
//! `[r00, r01, r02, r10, r11, r12]` (the pytorch3d convention used by EquiDiff).

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rapier3d::prelude::{Pose, Vector};

/// The 6D form of a rotation: its first two rows.
pub fn rot6d(q: &UnitQuaternion<f64>) -> [f64; 6] {
    let m = q.to_rotation_matrix();
    let m = m.matrix();
    [m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 0)], m[(1, 1)], m[(1, 2)]]
}

/// Rotation from a 6D form by Gram-Schmidt on the two rows. Returns `None` when `r` does not
/// hold exactly 6 finite values or the rows are (nearly) zero or parallel, where no rotation is
/// defined.
pub fn rotation_from_rot6d(r: &[f64]) -> Option<UnitQuaternion<f64>> {
    if r.len() != 6 || r.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let a = Vector3::new(r[0], r[1], r[2]);
    let b = Vector3::new(r[3], r[4], r[5]);
    let an = a.norm();
    if an < 1e-6 {
        return None;
    }
    let x = a / an;
    let b_perp = b - x * x.dot(&b);
    let bn = b_perp.norm();
    if bn < 1e-6 * b.norm().max(1e-6) || bn < 1e-9 {
        return None;
    }
    let y = b_perp / bn;
    let z = x.cross(&y);
    // The vectors are rows of the rotation matrix.
    let m = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    Some(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m)))
}

/// nalgebra (f64) pose -> rapier (f32) pose.
pub fn to_pose(iso: &Isometry3<f64>) -> Pose {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    Pose::from_parts(
        Vector::new(t.x as f32, t.y as f32, t.z as f32),
        rapier3d::glamx::Quat::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32).normalize(),
    )
}

/// rapier (f32) pose -> nalgebra (f64) pose.
pub fn from_pose(p: &Pose) -> Isometry3<f64> {
    let t = p.translation;
    let q = p.rotation;
    Isometry3::from_parts(
        Translation3::new(t.x as f64, t.y as f64, t.z as f64),
        UnitQuaternion::new_normalize(nalgebra::Quaternion::new(q.w as f64, q.x as f64, q.y as f64, q.z as f64)),
    )
}

pub fn to_vector(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x as f32, v.y as f32, v.z as f32)
}

pub fn from_vector(v: Vector) -> Vector3<f64> {
    Vector3::new(v.x as f64, v.y as f64, v.z as f64)
}

/// Clamp a vector's length.
pub fn clamp_norm(v: Vector3<f64>, max: f64) -> Vector3<f64> {
    let n = v.norm();
    if n > max {
        v * (max / n)
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rot6d_round_trip() {
        let q = UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0);
        let back = rotation_from_rot6d(&rot6d(&q)).unwrap();
        assert!(q.angle_to(&back) < 1e-9);
        assert!(rotation_from_rot6d(&[0.0; 6]).is_none());
        assert!(rotation_from_rot6d(&[1.0, 0.0, 0.0, 2.0, 0.0, 0.0]).is_none());
        // Wrong lengths and non-finite values are refused, not indexed or propagated.
        assert!(rotation_from_rot6d(&[1.0, 0.0, 0.0]).is_none());
        assert!(rotation_from_rot6d(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]).is_none());
        assert!(rotation_from_rot6d(&[1.0, 0.0, f64::NAN, 0.0, 1.0, 0.0]).is_none());
        assert!(rotation_from_rot6d(&[f64::INFINITY, 0.0, 0.0, 0.0, 1.0, 0.0]).is_none());
    }
}
