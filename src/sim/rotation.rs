//! Rotation helpers: MuJoCo's row-major matrices and the action's axis-angle form.
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

/// Rotation from MuJoCo's row-major 3x3 array.
pub fn mat_from_mj(m: &[f64; 9]) -> Matrix3<f64> {
    Matrix3::from_row_slice(m)
}

/// The action's orientation form: (angle / pi, unit axis), with the axis sign fixed so that rotations by
/// about pi (where axis and -axis mean the same) have one representation.
pub fn to_angle_axis(r: &Matrix3<f64>) -> (f64, [f64; 3]) {
    // Through the quaternion: Rotation3::axis_angle loses the axis of half turns, the common case here.
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    match q.axis_angle() {
        None => (0.0, [0.0, 0.0, 1.0]),
        Some((axis, angle)) => {
            let mut a = axis.into_inner();
            let mut angle = angle;
            // Near a half turn, axis and -axis are the same rotation: keep the one with y (else x, z) >= 0.
            if (std::f64::consts::PI - angle).abs() < 1e-6 {
                let key = if a[1].abs() > 1e-9 {
                    a[1]
                } else if a[0].abs() > 1e-9 {
                    a[0]
                } else {
                    a[2]
                };
                if key < 0.0 {
                    a = -a;
                }
            }
            if angle < 0.0 {
                angle = -angle;
                a = -a;
            }
            (angle / std::f64::consts::PI, [a[0], a[1], a[2]])
        }
    }
}

/// Rotation from the action's (angle / pi, axis) form; a zero axis means no rotation.
pub fn from_angle_axis(angle_over_pi: f64, axis: [f64; 3]) -> Matrix3<f64> {
    let v = Vector3::from(axis);
    if v.norm() < 1e-9 {
        return Matrix3::identity();
    }
    Rotation3::from_axis_angle(&Unit::new_normalize(v), angle_over_pi * std::f64::consts::PI).into_inner()
}

/// The state's form of an orientation given in the action's form: (angle / pi in [0, 2], unit axis) of the
/// quaternion on the side of the gripper pointing straight down (a half turn about +y). The authors read theirs,
/// in the same range, from MuJoCo's hand quaternion, which moves continuously with the joints; the action's form
/// flips its axis near a half turn, where the gripper always is, so the state must not use it as it is.
pub fn state_angle_axis(angle_over_pi: f64, axis: [f64; 3]) -> (f64, [f64; 3]) {
    let Some(unit) = Vector3::from(axis).try_normalize(1e-12) else {
        return (0.0, [0.0, 0.0, 1.0]);
    };
    let half = angle_over_pi * std::f64::consts::PI / 2.0;
    let (mut w, mut v) = (half.cos(), unit * half.sin());
    if v[1] < 0.0 {
        (w, v) = (-w, -v);
    }
    let norm = v.norm();
    if norm < 1e-12 {
        return (0.0, [0.0, 0.0, 1.0]);
    }
    (2.0 * norm.atan2(w) / std::f64::consts::PI, [v[0] / norm, v[1] / norm, v[2] / norm])
}

/// Rotation vector (axis * angle) taking `from` to `to`, expressed in the world frame.
pub fn rotation_error(to: &Matrix3<f64>, from: &Matrix3<f64>) -> Vector3<f64> {
    let rel = Rotation3::from_matrix_unchecked(to * from.transpose());
    nalgebra::UnitQuaternion::from_rotation_matrix(&rel).scaled_axis()
}

/// Gripper pointing straight down, rotated by `yaw` about the vertical.
pub fn downward(yaw: f64) -> Matrix3<f64> {
    (Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI))
    .into_inner()
}

/// The yaw `y` for which [`downward`]`(y)` is closest to `r`: read from where `r` sends the gripper's x axis.
pub fn yaw_of(r: &Matrix3<f64>) -> f64 {
    let x = r * Vector3::x();
    (-x[1]).atan2(-x[0])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_axis_round_trips() {
        for yaw in [-1.2, -0.3, 0.0, 0.4, 1.5] {
            let r = downward(yaw);
            let (a, axis) = to_angle_axis(&r);
            assert!((a - 1.0).abs() < 1e-9, "downward is a half turn, got {a}");
            let back = from_angle_axis(a, axis);
            assert!((back - r).norm() < 1e-9);
        }
        let r = Rotation3::from_euler_angles(0.3, -0.2, 0.9).into_inner();
        let (a, axis) = to_angle_axis(&r);
        assert!((from_angle_axis(a, axis) - r).norm() < 1e-9);
    }

    #[test]
    fn state_form_is_continuous_where_the_action_form_flips() {
        // A gripper turned back and forth about its half-turn axis by a hundredth of a radian: the action's form
        // flips its axis where the turn passes pi.
        let tilt = |e: f64| downward(0.0) * Rotation3::from_axis_angle(&Vector3::y_axis(), e).into_inner();
        let state = |e: f64| {
            let (a, axis) = to_angle_axis(&tilt(e));
            let (sa, saxis) = state_angle_axis(a, axis);
            assert!((from_angle_axis(sa, saxis) - tilt(e)).norm() < 1e-9, "same rotation at {e}");
            (a, axis, sa, saxis)
        };
        let (_, axis_p, sa_p, saxis_p) = state(0.01);
        let (_, axis_m, sa_m, saxis_m) = state(-0.01);
        let jump = |p: [f64; 3], m: [f64; 3]| p.iter().zip(m).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(jump(axis_p, axis_m) > 1.0, "the action's form flips: {axis_p:?} {axis_m:?}");
        assert!(jump(saxis_p, saxis_m) < 0.02 && (sa_p - sa_m).abs() < 0.02, "{sa_p} {saxis_p:?} {sa_m} {saxis_m:?}");
        assert!(sa_p > 1.0 || sa_m > 1.0, "past a half turn the angle goes on above pi");
        assert_eq!(state_angle_axis(0.0, [0.0; 3]), (0.0, [0.0, 0.0, 1.0]), "no rotation, whatever the axis");
    }

    #[test]
    fn yaw_of_inverts_downward() {
        for yaw in [-2.5, -0.3, 0.0, 1.2, 3.0] {
            assert!((yaw_of(&downward(yaw)) - yaw).abs() < 1e-9);
        }
    }

    #[test]
    fn rotation_error_is_zero_at_target() {
        let r = downward(0.7);
        assert!(rotation_error(&r, &r).norm() < 1e-12);
        let e = rotation_error(&downward(0.2), &downward(0.0));
        assert!((e - Vector3::new(0.0, 0.0, 0.2)).norm() < 1e-9);
    }
}
