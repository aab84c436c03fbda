//! Closed-loop evaluation on unseen task instances: per-episode staged success and its aggregates.
//!
//! The protocol follows the authors' `test_transformers.py`: episode i runs task i mod 16 (of the evaluated
//! tasks) on a fresh layout, with a fresh demonstration by the Sawyer's expert on another layout; the network sees
//! context frames drawn like in training and its own recent frames (see [`history`]), and its action at the
//! window's last position is sampled; the rotation is replaced by the agent's fixed orientation and the gripper
//! binarised.
pub mod actor;
pub mod carries;
pub mod choice;
pub mod config;
pub mod grasps;
pub mod grip_probe;
pub mod history;
pub mod holds;
pub mod layouts;
pub mod probe;
pub mod rollout;
pub mod run;
pub mod stats;
pub mod strip;
pub mod summary;
pub mod video;
pub mod workers;

pub use actor::{Actor, ActorFiles, Weights};
pub use config::{ActionChoice, EvalConfig};

use crate::sim::action::ACTION_DIM;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One episode's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    pub index: usize,
    pub task: usize,
    pub agent_seed: u64,
    pub demo_seed: u64,
    pub reached: bool,
    pub picked: bool,
    pub placed: bool,
    /// The object came to rest in another quadrant of the target bin (the paper's "wrong bin").
    #[serde(default)]
    pub wrong_bin: bool,
    /// Actions taken (the episode stops once placed).
    pub steps: usize,
    /// First step after which each stage held.
    pub first_reached: Option<usize>,
    pub first_picked: Option<usize>,
    pub first_placed: Option<usize>,
    /// Where the task's object was when the agent first commanded its gripper more than half closed (a command
    /// above 0); none if it never did, and in episodes recorded before it was kept.
    #[serde(default)]
    pub first_close: Option<GripperClose>,
}

/// The task's object relative to the gripper after the step that first commanded the gripper closed: what a
/// failed grasp missed by.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GripperClose {
    /// That step (1-based, as `first_reached`).
    pub step: usize,
    /// The object in the gripper's frame (x across the fingers, z along them), metres.
    pub object_in_gripper: [f64; 3],
}

/// One step of an episode as it was executed: what a grasp did, step by step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TraceStep {
    /// The step (1-based, as `first_reached`).
    pub step: usize,
    /// The command executed: target position (m), orientation (angle / pi, axis), gripper (+1 closes).
    pub action: [f64; ACTION_DIM],
    /// The gripper's position afterwards (world, metres).
    pub gripper_pos: [f64; 3],
    /// The fingers' joint positions afterwards (metres; the Panda's are +0.04 and -0.04 fully open, 0 closed).
    pub fingers: [f64; 2],
    /// The task's object in the gripper's frame afterwards (x across the fingers, z along them), metres.
    pub object_in_gripper: [f64; 3],
    pub reached: bool,
    pub picked: bool,
    pub placed: bool,
}

/// The steps of one episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeTrace {
    pub index: usize,
    pub steps: Vec<TraceStep>,
}

/// Where strips and videos go, if any are asked for.
pub struct EvalOutput {
    pub strips_dir: Option<PathBuf>,
    pub videos_dir: Option<PathBuf>,
}
