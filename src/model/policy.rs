//! The interface every policy architecture implements, and the policy a configuration builds through the
//! registry in [`super::architectures`].
use super::architectures::Registration;
use super::config::ModelConfig;
use super::heads::point_nll;
use super::mixture::{MixtureParams, MixtureSpec, mixture_nll};
use super::output::PolicyOutput;
use crate::model::batch::DeviceBatch;
use tch::{Kind, Tensor, nn};

/// The training losses of one batch; a loss whose head the architecture lacks is zero.
pub struct Losses {
    /// Behaviour cloning: NLL of the expert's actions at the agent positions that have one.
    pub bc: Tensor,
    /// Inverse dynamics: NLL of each action from the frames before and after it.
    pub inverse: Tensor,
    /// NLL of the end-effector pixel at the end of the window.
    pub point: Tensor,
    /// Squared error (metres) of the predicted grasp and drop positions (architectures with a pose head, and
    /// `model.pose_head`), weighted by `train.loss.pose`.
    pub pose: Tensor,
    /// Cross-entropy of the demonstrated task from the task embedding (`model.task_head`), weighted by
    /// `train.loss.task`.
    pub task: Tensor,
}

/// A policy architecture: how it is queried for actions and how it is trained.
pub trait PolicyNet: std::fmt::Debug + Send {
    /// Predictions for `context` `[B, Tc, 3, H, W]`, agent frames `[B, Ta, 3, H, W]` and the robot's state at
    /// each `[B, Ta, STATE_DIM]` (read only by a network built with `model.concat_state`, which needs it); agent
    /// frame t's outputs depend only on the context and agent frames (and states) 0..=t.
    fn forward_t(&self, context: &Tensor, agent: &Tensor, states: Option<&Tensor>, train: bool) -> PolicyOutput;

    /// Runs the image trunk on channels-last tensors (see [`super::resnet::ResNet18::set_channels_last`]).
    fn set_channels_last(&mut self, on: bool);

    /// The losses of `batch`; by default the NLL of every head [`Self::forward_t`] returns.
    fn losses(&self, batch: &DeviceBatch, spec: MixtureSpec, train: bool) -> Losses {
        head_losses(&self.forward_t(&batch.context, &batch.agent, Some(&batch.states), train), batch, spec)
    }

    /// The grasp and drop positions `[B, 6]` (metres) predicted from the context and each episode's first agent
    /// frame `agent[:, 0]`; none for architectures without a pose head.
    fn predict_poses(&self, _context: &Tensor, _agent: &Tensor) -> Option<Tensor> {
        None
    }
}

/// The NLL of each head of `out` on `batch` (the paper's Sec. 3 objectives).
pub fn head_losses(out: &PolicyOutput, batch: &DeviceBatch, spec: MixtureSpec) -> Losses {
    let zero = || Tensor::zeros([], (Kind::Float, batch.actions.device()));
    let steps = batch.actions.size()[1];
    let acted = MixtureParams {
        means: out.actions.means.narrow(1, 0, steps),
        log_scales: out.actions.log_scales.narrow(1, 0, steps),
        logits: out.actions.logits.narrow(1, 0, steps),
    };
    Losses {
        bc: mixture_nll(&acted, &batch.actions, spec),
        inverse: out.inverse.as_ref().map_or_else(zero, |p| mixture_nll(p, &batch.actions, spec)),
        point: out.point.as_ref().map_or_else(zero, |p| point_nll(p, &batch.points)),
        pose: out.poses.as_ref().map_or_else(zero, |p| {
            // The squared error's mean over the frames the batch weights (all of them, or a trajectory's first).
            let target = batch.poses.unsqueeze(1).expand_as(p);
            let per_frame = (p.to_kind(Kind::Float) - target).square().mean_dim([-1i64].as_slice(), false, Kind::Float);
            let weights = batch.pose_weights.to_kind(Kind::Float);
            (per_frame * &weights).sum(Kind::Float) / weights.sum(Kind::Float).clamp_min(1.0)
        }),
        task: out
            .task_logits
            .as_ref()
            .map_or_else(zero, |l| l.to_kind(Kind::Float).cross_entropy_for_logits(&batch.tasks)),
    }
}

/// A policy network and the configuration it was built from.
#[derive(Debug)]
pub struct Policy {
    config: ModelConfig,
    registration: &'static Registration,
    net: Box<dyn PolicyNet>,
}

impl Policy {
    /// Builds the network of `config` under `vs` (call `config.validate()` first, which checks the architecture
    /// is registered).
    pub fn new(vs: &nn::Path, config: &ModelConfig) -> Policy {
        let registration = config.architecture.registration().expect("model.architecture validated");
        Policy { config: config.clone(), registration, net: (registration.build)(vs, config) }
    }

    /// Runs the trunk on channels-last tensors.
    pub fn set_channels_last(&mut self, on: bool) {
        self.net.set_channels_last(on)
    }

    /// The settings this network was built with.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The registry entry of its architecture.
    pub fn registration(&self) -> &'static Registration {
        self.registration
    }

    /// See [`PolicyNet::forward_t`], without states (a network built with `model.concat_state` panics).
    pub fn forward_t(&self, context: &Tensor, agent: &Tensor, train: bool) -> PolicyOutput {
        self.net.forward_t(context, agent, None, train)
    }

    /// See [`PolicyNet::forward_t`].
    pub fn forward_with_states(&self, context: &Tensor, agent: &Tensor, states: &Tensor, train: bool) -> PolicyOutput {
        self.net.forward_t(context, agent, Some(states), train)
    }

    /// See [`PolicyNet::predict_poses`].
    pub fn predict_poses(&self, context: &Tensor, agent: &Tensor) -> Option<Tensor> {
        self.net.predict_poses(context, agent)
    }

    /// See [`PolicyNet::losses`].
    pub fn losses(&self, batch: &DeviceBatch, train: bool) -> Losses {
        self.net.losses(batch, MixtureSpec::for_model(&self.config), train)
    }
}
