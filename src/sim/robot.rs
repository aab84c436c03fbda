//! The two robots of the world: the Sawyer demonstrator and the Panda agent.
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Which robot arm (with its own gripper) stands in the scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Robot {
    /// Rethink Sawyer with the Rethink two-finger gripper: the filmed demonstrator.
    Sawyer,
    /// Franka Panda with the Panda gripper: the controlled agent.
    Panda,
}

/// Static facts about one robot: asset files, joint names, initial pose and finger commands.
pub struct RobotSpec {
    /// Robot folder under robosuite's `robots/`.
    pub robot_dir: &'static str,
    /// Gripper file under robosuite's `grippers/`.
    pub gripper_file: &'static str,
    /// Body of the arm the gripper attaches to.
    pub hand_body: &'static str,
    /// Arm joint names, base to wrist.
    pub arm_joints: [&'static str; 7],
    /// Finger joint names, in the order of `open_ctrl` / `closed_ctrl`.
    pub finger_joints: [&'static str; 2],
    /// World position of the arm's base. The bins sit about 0.6 m in front of it (robosuite's bins
    /// layout); the shorter-reaching Panda stands 0.1 m closer so the whole source bin is in reach.
    pub base_pos: [f64; 3],
    /// Initial arm joint angles (the authors' robosuite fork).
    pub init_qpos: [f64; 7],
    /// Finger actuator targets when fully open.
    pub open_ctrl: [f64; 2],
    /// Finger actuator targets when fully closed.
    pub closed_ctrl: [f64; 2],
}

impl Robot {
    /// Both robots, demonstrator first.
    pub const ALL: [Robot; 2] = [Robot::Sawyer, Robot::Panda];

    /// The robot's assets and constants.
    pub fn spec(self) -> RobotSpec {
        match self {
            Robot::Sawyer => RobotSpec {
                robot_dir: "sawyer",
                gripper_file: "rethink_gripper.xml",
                hand_body: "right_hand",
                arm_joints: ["right_j0", "right_j1", "right_j2", "right_j3", "right_j4", "right_j5", "right_j6"],
                finger_joints: ["r_finger_joint", "l_finger_joint"],
                base_pos: [0.0, 0.0, 0.912],
                init_qpos: [0.0, -1.18, 0.0, 2.18, 0.0, 0.57, 3.3161],
                open_ctrl: [-0.0115, 0.0115],
                closed_ctrl: [0.020833, -0.020833],
            },
            Robot::Panda => RobotSpec {
                robot_dir: "panda",
                gripper_file: "panda_gripper.xml",
                hand_body: "right_hand",
                arm_joints: ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7"],
                finger_joints: ["finger_joint1", "finger_joint2"],
                base_pos: [0.1, 0.0, 0.912],
                init_qpos: [0.0, PI / 16.0, 0.0, -5.0 * PI / 6.0, 0.0, PI - 0.2, -PI / 4.0],
                open_ctrl: [0.04, -0.04],
                closed_ctrl: [0.0, 0.0],
            },
        }
    }

    /// Lower-case name, as used in files and configs.
    pub fn name(self) -> &'static str {
        match self {
            Robot::Sawyer => "sawyer",
            Robot::Panda => "panda",
        }
    }
}

impl std::fmt::Display for Robot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
