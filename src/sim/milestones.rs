//! Staged success milestones (the paper's Table 1, as the authors' `test_transformers.py` computes it): reached, picked,
//! placed. Each stage latches once achieved.
use serde::{Deserialize, Serialize};

/// Distance (m) in the gripper frame's xy plane (across the approach axis) under which the object counts as
/// reached.
pub const REACH_RADIUS: f64 = 0.03;
/// Lift (m) above the starting height that counts as picked.
pub const LIFT_HEIGHT: f64 = 0.05;
/// Height band (m) of an object resting in the target bin.
pub const PLACED_Z: (f64, f64) = (0.80, 0.90);

/// Which stages an episode has achieved so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Milestones {
    pub reached: bool,
    pub picked: bool,
    pub placed: bool,
    /// The object rested in the target bin in a quadrant other than the task's (the paper's "wrong bin" failure).
    /// Left out of serialised stages when false, so trajectories recorded before it read and write the same.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub wrong_bin: bool,
}

/// The facts one step's stage update needs.
pub struct MilestoneInputs {
    /// Object position in the gripper's frame (x across the fingers, z along them).
    pub object_in_gripper: [f64; 3],
    /// Object height now and at the episode's start.
    pub object_z: f64,
    pub start_z: f64,
    /// Whether the object's (x, y) lies in the task's target quadrant.
    pub in_target: bool,
    /// Whether the object's (x, y) lies in another quadrant of the target bin.
    pub in_other_quadrant: bool,
}

impl Milestones {
    /// Latches every stage that `s` shows achieved.
    pub fn update(&mut self, s: &MilestoneInputs) {
        let [x, y, _] = s.object_in_gripper;
        if x.hypot(y) < REACH_RADIUS {
            self.reached = true;
        }
        if self.reached && s.object_z > s.start_z + LIFT_HEIGHT {
            self.picked = true;
        }
        let resting = s.object_z > PLACED_Z.0 && s.object_z < PLACED_Z.1;
        if s.in_target && resting {
            self.placed = true;
        }
        if s.in_other_quadrant && resting {
            self.wrong_bin = true;
        }
    }

    /// The stages as 0/1 bytes [reached, picked, placed].
    pub fn as_bytes(&self) -> [u8; 3] {
        [self.reached as u8, self.picked as u8, self.placed as u8]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(g: [f64; 3], z: f64, in_target: bool) -> MilestoneInputs {
        MilestoneInputs { object_in_gripper: g, object_z: z, start_z: 0.85, in_target, in_other_quadrant: false }
    }

    #[test]
    fn stages_follow_the_definitions_and_latch() {
        let mut s = Milestones::default();
        s.update(&inputs([0.03, 0.01, 0.0], 0.85, false));
        assert_eq!(s, Milestones::default(), "3.2 cm to the side is not reached");
        s.update(&inputs([0.01, 0.02, 0.2], 0.85, false));
        assert!(s.reached && !s.picked, "within 3 cm across the approach axis is reached, at any height");
        s.update(&inputs([0.5, 0.5, 0.5], 0.95, false));
        assert!(s.picked, "lifted after reaching");
        s.update(&inputs([0.0, 0.0, 0.0], 1.05, true));
        assert!(!s.placed, "carried high above the quadrant is not placed");
        s.update(&inputs([0.0, 0.0, 0.3], 0.86, true));
        assert_eq!(s.as_bytes(), [1, 1, 1]);
        assert!(!s.wrong_bin);
    }

    #[test]
    fn resting_in_another_quadrant_is_the_wrong_bin_not_placed() {
        let mut s = Milestones::default();
        let other = |z| MilestoneInputs { in_other_quadrant: true, ..inputs([0.0, 0.0, 0.3], z, false) };
        s.update(&other(1.0));
        assert!(!s.wrong_bin, "carried high over another quadrant is not yet the wrong bin");
        s.update(&other(0.86));
        assert!(s.wrong_bin && !s.placed);
    }

    #[test]
    fn lifting_without_reaching_is_not_picking() {
        let mut s = Milestones::default();
        s.update(&inputs([0.2, 0.0, 0.0], 1.0, false));
        assert!(!s.picked);
    }
}
