//! The 8-D action: an absolute end-effector target [x, y, z, angle/pi, axis_x, axis_y, axis_z, gripper],
//! and its normalisation to [-1, 1] (ranges from the authors' `custom_ik_wrapper.py`).
use serde::{Deserialize, Serialize};

/// Number of action dimensions.
pub const ACTION_DIM: usize = 8;

/// Absolute lower and upper bound of each action dimension.
pub const ACTION_RANGES: [[f64; 2]; ACTION_DIM] =
    [[0.44, 0.74], [-0.33, 0.5], [0.82, 1.11], [0.85, 1.08], [-1.0, 1.0], [-1.0, 1.0], [-1.0, 1.0], [-1.0, 1.0]];

/// An end-effector target in absolute units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Action(pub [f64; ACTION_DIM]);

impl Action {
    /// Builds an action from position, (angle/pi, axis) orientation and gripper command (+1 closes).
    pub fn new(pos: [f64; 3], angle_over_pi: f64, axis: [f64; 3], gripper: f64) -> Action {
        Action([pos[0], pos[1], pos[2], angle_over_pi, axis[0], axis[1], axis[2], gripper])
    }

    /// The action clipped into its absolute ranges.
    pub fn clipped(self) -> Action {
        let mut a = self.0;
        for (v, [lo, hi]) in a.iter_mut().zip(ACTION_RANGES) {
            *v = v.clamp(lo, hi);
        }
        Action(a)
    }

    /// Each dimension mapped linearly from its range to [-1, 1] (clipped first).
    pub fn normalized(self) -> [f32; ACTION_DIM] {
        let a = self.clipped().0;
        std::array::from_fn(|i| {
            let [lo, hi] = ACTION_RANGES[i];
            (2.0 * (a[i] - lo) / (hi - lo) - 1.0) as f32
        })
    }

    /// Inverse of [`Action::normalized`]; values outside [-1, 1] are clipped.
    pub fn from_normalized(n: &[f32]) -> Action {
        Action(std::array::from_fn(|i| {
            let [lo, hi] = ACTION_RANGES[i];
            lo + (f64::from(n[i]).clamp(-1.0, 1.0) + 1.0) / 2.0 * (hi - lo)
        }))
    }

    /// Target position.
    pub fn pos(&self) -> [f64; 3] {
        [self.0[0], self.0[1], self.0[2]]
    }

    /// Gripper command in [-1, 1]; +1 closes.
    pub fn gripper(&self) -> f64 {
        self.0[7]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalisation_round_trips_and_clips() {
        let a = Action::new([0.6, 0.1, 0.9], 1.0, [0.0, 1.0, 0.0], -1.0);
        let n = a.normalized();
        assert!(n.iter().all(|v| (-1.0..=1.0).contains(v)));
        let back = Action::from_normalized(&n);
        for (x, y) in back.0.iter().zip(a.0) {
            assert!((x - y).abs() < 1e-6);
        }
        let far = Action::new([5.0, -5.0, 0.0], 1.0, [0.0, 1.0, 0.0], 1.0).normalized();
        assert_eq!(&far[..3], &[1.0, -1.0, -1.0]);
    }
}
