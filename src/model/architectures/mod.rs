//! The registry of policy architectures: each is one module here and one line of [`ARCHITECTURES`].
//! `model.architecture` names an entry; building, training and evaluation reach the network only through
//! [`super::policy::PolicyNet`].
pub mod ablated;
pub mod daml;
pub mod daml_trunk;
pub mod lstm;
pub mod transformer;

use super::config::ModelConfig;
use super::policy::PolicyNet;
use tch::nn;

/// One architecture: its name in `model.architecture`, what it is, and how it is built.
#[derive(Debug)]
pub struct Registration {
    pub name: &'static str,
    pub description: &'static str,
    /// Whether it has the inverse-dynamics and point heads (their loss weights must be zero otherwise).
    pub auxiliary_heads: bool,
    /// Whether it predicts the grasp and drop positions (what `eval.control = "scripted_poses"` executes).
    pub pose_head: bool,
    /// Whether it ends in the paper's heads, to which `model.pose_head` and `model.task_head` can add.
    pub paper_heads: bool,
    /// Whether it keeps each agent frame's spatial tokens after mixing, over which `model.object_attention`
    /// attends.
    pub spatial_tokens: bool,
    /// Whether it trains faithfully under bf16 autocast (`train.precision = "bf16"`).
    pub bf16: bool,
    pub build: fn(&nn::Path, &ModelConfig) -> Box<dyn PolicyNet>,
}

/// Every architecture `model.architecture` may name.
pub static ARCHITECTURES: &[Registration] = &[
    transformer::TRANSFORMER,
    transformer::TEMPORAL_CONV,
    lstm::CONTEXTUAL_LSTM,
    ablated::CONV,
    ablated::CONV_LSTM,
    ablated::RESNET,
    ablated::RESNET_LSTM,
    daml::DAML,
    daml::DAML_RESNET,
];

/// The entry named `name`.
pub fn find(name: &str) -> Option<&'static Registration> {
    ARCHITECTURES.iter().find(|r| r.name == name)
}

/// The registered names, for error messages.
pub fn names() -> Vec<&'static str> {
    ARCHITECTURES.iter().map(|r| r.name).collect()
}
