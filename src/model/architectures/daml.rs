//! DAML (Yu et al., 2018), the paper's meta-learning baseline (Sec. 5, Table 1), as the authors' `DAMLNetwork` and
//! `train_daml_baseline.py` build it: a per-frame conv net (VGG-16's first block, then three 3x3 convolutions of
//! strides 2, 2, 1) and spatial softmax; an action MLP of three 50-wide layers into the shared logistic-mixture head;
//! an auxiliary head regressing the agent's grasp and drop positions from its first frame; and a learned loss, an
//! MLP with LayerNorm over the context frames' features. Per task, the conv net and action MLP take one gradient
//! step (lr 0.1) on the learned loss of the demonstrator's video; the adapted network then acts, frame by frame, and
//! is trained through that step (second order) on behaviour cloning plus the grasp-and-drop regression.
//! `daml_resnet` is the same with the authors' ResNet-18 trunk option (`n_final_convs = "resnet"`).
use super::Registration;
use super::daml_trunk::{self, Trunk, TrunkKind, bias};
use crate::model::batch::DeviceBatch;
use crate::model::config::ModelConfig;
use crate::model::mixture::{MixtureHead, MixtureParams, MixtureSpec, mixture_nll};
use crate::model::output::PolicyOutput;
use crate::model::policy::{Losses, PolicyNet};
use tch::nn::{self, Module};
use tch::{Kind, Reduction, Tensor};

/// The DAML baseline.
pub const DAML: Registration = Registration {
    name: "daml",
    description: "the DAML baseline: MAML with a learned inner loss over the demonstration, and a grasp/drop head",
    auxiliary_heads: false,
    pose_head: true,
    paper_heads: false,
    spatial_tokens: false,
    // Its inner gradient step carries bf16 rounding into the adapted weights: the outer gradient turns away from
    // fp32's (tests/it/precision.rs measured a cosine of 0.4).
    bf16: false,
    build: |vs, config| Box::new(Daml::new(vs, config, TrunkKind::Conv)),
};

/// DAML with the authors' ResNet-18 trunk option: ResNet-18, spatial softmax and an embedding MLP, all adapted by
/// the inner step.
pub const DAML_RESNET: Registration = Registration {
    name: "daml_resnet",
    description: "DAML with a ResNet-18 trunk (the authors' `n_final_convs = \"resnet\"`)",
    build: |vs, config| Box::new(Daml::new(vs, config, TrunkKind::ResNet)),
    ..DAML
};

/// Learning rate of the inner step (the authors' `maml_lr`).
pub const INNER_LR: f64 = 0.1;
/// Width of the action MLP's layers.
const ACTION_HIDDEN: i64 = 50;
/// Hidden width of the grasp-and-drop head.
const POSE_HIDDEN: i64 = 32;
/// Grasp position then drop position, (x, y, z) each, in metres.
pub const POSE_DIM: i64 = 6;

/// The DAML network. Parameters that the inner step adapts (the trunk and the action MLP) are applied
/// functionally, so that a forward pass can run with adapted copies of them.
#[derive(Debug)]
pub struct Daml {
    trunk: Trunk,
    /// How many of the adapted weights are the trunk's (the action MLP's follow).
    trunk_weights: usize,
    action_mlp: Vec<nn::Linear>,
    head: MixtureHead,
    pose: [nn::Linear; 2],
    learned_loss: LearnedLoss,
    channels_last: bool,
}

/// The learned inner loss: Linear, ReLU, LayerNorm, Linear, ReLU, LayerNorm, Linear to a scalar.
#[derive(Debug)]
struct LearnedLoss {
    first: nn::Linear,
    norm1: nn::LayerNorm,
    second: nn::Linear,
    norm2: nn::LayerNorm,
    out: nn::Linear,
}

impl Module for LearnedLoss {
    fn forward(&self, x: &Tensor) -> Tensor {
        let y = self.norm1.forward(&self.first.forward(x).relu());
        let y = self.norm2.forward(&self.second.forward(&y).relu());
        self.out.forward(&y)
    }
}

impl Daml {
    /// Builds the network under `vs` with the given trunk: the conv trunk's channels are `model.backbone_width`
    /// (VGG-16's 64); the ResNet trunk is `model.backbone_width` and `model.backbone_stages` wide and deep, and its
    /// embedding `model.embed_hidden` wide (the authors' 256).
    pub fn new(vs: &nn::Path, config: &ModelConfig, trunk: TrunkKind) -> Daml {
        let trunk = match trunk {
            TrunkKind::Conv => Trunk::conv(vs, config.backbone_width),
            TrunkKind::ResNet => Trunk::resnet(vs, config.backbone_width, config.backbone_stages, config.embed_hidden),
        };
        let features = trunk.features();
        let trunk_weights = trunk.params().len();
        let mlp = vs / "action_mlp";
        let action_mlp = [(features, ACTION_HIDDEN), (ACTION_HIDDEN, ACTION_HIDDEN), (ACTION_HIDDEN, ACTION_HIDDEN)]
            .iter()
            .enumerate()
            .map(|(i, &(a, b))| nn::linear(&mlp / i.to_string(), a, b, Default::default()))
            .collect();
        let pose = vs / "pose";
        let loss = vs / "learned_loss";
        let (wide, narrow) =
            (config.context_len() as i64 * (ACTION_HIDDEN + features), ACTION_HIDDEN * config.context_len() as i64);
        Daml {
            trunk,
            action_mlp,
            head: MixtureHead::new(&(vs / "action_head"), ACTION_HIDDEN, MixtureSpec::for_model(config)),
            pose: [
                nn::linear(&pose / "0", features, POSE_HIDDEN, Default::default()),
                nn::linear(&pose / "1", POSE_HIDDEN, POSE_DIM, Default::default()),
            ],
            learned_loss: LearnedLoss {
                first: nn::linear(&loss / "0", wide, narrow, Default::default()),
                norm1: nn::layer_norm(&loss / "norm1", vec![narrow], Default::default()),
                second: nn::linear(&loss / "1", narrow, narrow, Default::default()),
                norm2: nn::layer_norm(&loss / "norm2", vec![narrow], Default::default()),
                out: nn::linear(&loss / "2", narrow, 1, Default::default()),
            },
            trunk_weights,
            channels_last: false,
        }
    }

    /// The parameters the inner step adapts (the trunk's, then the action MLP's), as they are before it.
    pub fn initial_weights(&self) -> Vec<Tensor> {
        let mlp = self.action_mlp.iter().flat_map(|l| [l.ws.shallow_clone(), bias(&l.bs)]);
        self.trunk.params().into_iter().chain(mlp).collect()
    }

    /// Trunk features `[B, T, F]` of frames `[B, T, 3, H, W]`, each task under its own weights.
    fn embed(&self, weights: &[Tensor], frames: &Tensor, train: bool) -> Tensor {
        self.trunk.embed(&weights[..self.trunk_weights], frames, train, self.channels_last)
    }

    /// The action MLP's output `[B, T, 50]` for features `[B, T, F]`, each task under its own weights.
    fn act(&self, weights: &[Tensor], features: &Tensor) -> Tensor {
        let mut weights = weights[self.trunk_weights..].iter();
        self.action_mlp.iter().fold(features.shallow_clone(), |x, _| daml_trunk::linear(&mut weights, &x).relu())
    }

    /// Each task's weights (`[B, ...]` per parameter) after one inner step on the learned loss of its context
    /// frames (`context` is `[B, Tc, 3, H, W]`). With `train`, an outer loss differentiates through the step's
    /// gradient (second order), which is how the learned loss is trained, and the ResNet trunk normalises with
    /// batch statistics and drops out; otherwise that gradient is a constant (first-order MAML: the outer gradient
    /// still reaches the initial weights, never the learned loss).
    pub fn adapt(&self, context: &Tensor, train: bool) -> Vec<Tensor> {
        let tasks = context.size()[0];
        tch::with_grad(|| {
            let weights: Vec<Tensor> = self
                .initial_weights()
                .iter()
                .map(|w| {
                    let mut repeats = vec![tasks];
                    repeats.extend(std::iter::repeat_n(1, w.dim()));
                    w.unsqueeze(0).repeat(repeats.as_slice())
                })
                .collect();
            let features = self.embed(&weights, context, train);
            let input = Tensor::cat(&[self.act(&weights, &features), features], -1).reshape([tasks, -1]);
            // Tasks are independent, so the gradient of the summed loss is each task's own gradient.
            let loss = self.learned_loss.forward(&input).sum(Kind::Float);
            let grads = Tensor::run_backward(&[loss], &weights, train, train);
            weights
                .iter()
                .zip(grads)
                .map(|(w, g)| if train { w - g * INNER_LR } else { w - g.detach() * INNER_LR })
                .collect()
        })
    }

    /// Action distributions `[B, Ta, 8, mixtures]` and predicted grasp-and-drop positions `[B, 6]` for contexts
    /// `[B, Tc, 3, H, W]` and agent frames `[B, Ta, 3, H, W]`, each task under the weights adapted to its context.
    fn batch_outputs(&self, context: &Tensor, agent: &Tensor, train: bool) -> (MixtureParams, Tensor) {
        let weights = self.adapt(context, train);
        let features = self.embed(&weights, agent, train);
        let actions = self.head.forward(&self.act(&weights, &features));
        let first = features.select(1, 0);
        let poses = self.pose[1].forward(&self.pose[0].forward(&first).relu());
        (actions, poses)
    }
}

impl PolicyNet for Daml {
    fn forward_t(&self, context: &Tensor, agent: &Tensor, _states: Option<&Tensor>, train: bool) -> PolicyOutput {
        PolicyOutput {
            actions: self.batch_outputs(context, agent, train).0,
            inverse: None,
            point: None,
            poses: None,
            task_logits: None,
        }
    }

    fn set_channels_last(&mut self, on: bool) {
        self.channels_last = on;
    }

    /// Behaviour cloning of each task's agent actions under the weights adapted to its demonstration, and the
    /// mean squared error of the grasp-and-drop positions (the authors' outer loss).
    fn losses(&self, batch: &DeviceBatch, spec: MixtureSpec, train: bool) -> Losses {
        let (actions, poses) = self.batch_outputs(&batch.context, &batch.agent, train);
        let steps = batch.actions.size()[1];
        let acted = MixtureParams {
            means: actions.means.narrow(1, 0, steps),
            log_scales: actions.log_scales.narrow(1, 0, steps),
            logits: actions.logits.narrow(1, 0, steps),
        };
        let zero = || Tensor::zeros([], (Kind::Float, batch.actions.device()));
        Losses {
            bc: mixture_nll(&acted, &batch.actions, spec),
            inverse: zero(),
            point: zero(),
            pose: poses.to_kind(Kind::Float).mse_loss(&batch.poses, Reduction::Mean),
            task: zero(),
        }
    }

    fn predict_poses(&self, context: &Tensor, agent: &Tensor) -> Option<Tensor> {
        Some(self.batch_outputs(context, &agent.narrow(1, 0, 1), false).1)
    }
}
