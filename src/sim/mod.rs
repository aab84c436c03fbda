//! The simulated world: scene composition, robots, tasks, control, the scripted expert and rendering.
pub mod action;
pub mod assets;
pub mod camera;
pub mod env;
pub mod expert;
pub mod expert_check;
pub mod ids;
pub mod ik;
pub mod milestones;
pub mod object;
pub mod robot;
pub mod rollout;
pub mod rotation;
pub mod scene;
pub mod task;
