//! What a network trains on: one batch of training samples as tensors on its device.
use tch::Tensor;

/// A batch on a device: `context` `[B, Tc, 3, H, W]`, `agent` `[B, Ta, 3, H, W]`, `actions` `[B, Ta - 1, 8]`,
/// `states` `[B, Ta, STATE_DIM]` (the robot's own state at each agent frame), `points` `[B, 2]`, `poses` `[B, 6]`,
/// `pose_weights` `[B, Ta]` (each agent frame's weight in the pose loss), `tasks` `[B]` (int64: the task each
/// sample demonstrates).
pub struct DeviceBatch {
    pub context: Tensor,
    pub agent: Tensor,
    pub actions: Tensor,
    pub states: Tensor,
    pub points: Tensor,
    pub poses: Tensor,
    pub pose_weights: Tensor,
    pub tasks: Tensor,
}
