//! What a policy network's forward pass returns: the action distribution and the auxiliary heads' predictions.
use super::mixture::MixtureParams;
use tch::Tensor;

/// What one forward pass predicts.
pub struct PolicyOutput {
    /// Action distribution at every agent frame: `[B, Ta, 8, mixtures]`.
    pub actions: MixtureParams,
    /// Inverse-dynamics distribution for each consecutive pair of agent frames: `[B, Ta - 1, 8, mixtures]`
    /// (architectures without the head: none).
    pub inverse: Option<MixtureParams>,
    /// End-effector pixel at the end of the window (architectures without the head: none).
    pub point: Option<PointPrediction>,
    /// Grasp and drop positions `[B, Ta, 6]` (metres) at every agent frame (`model.pose_head`; otherwise none).
    pub poses: Option<Tensor>,
    /// Logits `[B, tasks]` of the demonstrated task from the task embedding (`model.task_head`; otherwise none).
    pub task_logits: Option<Tensor>,
}

/// A 2-D Gaussian over the normalised image grid: mean `[B, 2]` and Cholesky factor entries `[B, 3]` (a, c, b
/// of [[a, 0], [c, b]], with a, b > 0).
pub struct PointPrediction {
    pub mean: Tensor,
    pub cholesky: Tensor,
}
