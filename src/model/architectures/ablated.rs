//! The paper's architecture ablations (Sec. 5, Fig. 3), as the authors' `_AblatedFeatures` builds them: a
//! per-frame image network (their small 4-layer, 32-channel conv net, or ResNet-18) and spatial softmax; the task
//! embedding an MLP over the concatenated features of the context frames and the first agent frame; each frame's
//! embedding a two-layer MLP, optionally followed by an LSTM running over the context and then the agent frames.
//! No attention anywhere. The heads and losses are the transformer's: behaviour cloning from [task, frame],
//! inverse dynamics from consecutive frames, and the point from the task.
use super::Registration;
use crate::autocast::full_precision;
use crate::model::config::ModelConfig;
use crate::model::heads::{PolicyHeads, spatial_softmax};
use crate::model::output::PolicyOutput;
use crate::model::policy::PolicyNet;
use crate::model::resnet::ResNet18;
use tch::nn::{self, Module, ModuleT, RNN};
use tch::{Kind, Tensor};

/// The small conv net, no recurrence.
pub const CONV: Registration = Registration {
    name: "conv",
    description: "architecture ablation: small 4-layer 32-channel conv net + spatial softmax + MLPs, no attention",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: false,
    bf16: true,
    build: |vs, config| Box::new(AblatedPolicy::new(vs, config, Visual::SmallConv, false)),
};

/// The small conv net with an LSTM over time.
pub const CONV_LSTM: Registration = Registration {
    name: "conv_lstm",
    description: "architecture ablation: the small conv net with an LSTM over context and agent frames",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: false,
    bf16: true,
    build: |vs, config| Box::new(AblatedPolicy::new(vs, config, Visual::SmallConv, true)),
};

/// ResNet-18, no recurrence.
pub const RESNET: Registration = Registration {
    name: "resnet",
    description: "architecture ablation: ResNet-18 + spatial softmax + MLPs, no attention",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: false,
    bf16: true,
    build: |vs, config| Box::new(AblatedPolicy::new(vs, config, Visual::ResNet, false)),
};

/// ResNet-18 with an LSTM over time.
pub const RESNET_LSTM: Registration = Registration {
    name: "resnet_lstm",
    description: "architecture ablation: ResNet-18 with an LSTM over context and agent frames",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: false,
    bf16: true,
    build: |vs, config| Box::new(AblatedPolicy::new(vs, config, Visual::ResNet, true)),
};

/// Which per-frame image network the ablation uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visual {
    /// The authors' `BasicCNN`: four 3x3 convolutions of 32 channels, strides 2, 2, 1, 1.
    SmallConv,
    /// The policy's ResNet-18 trunk (`model.backbone_width`, `model.backbone_stages`).
    ResNet,
}

/// Channels of the small conv net.
const SMALL_CHANNELS: i64 = 32;

/// The authors' `BasicCNN`.
#[derive(Debug)]
struct SmallConv {
    convs: Vec<nn::Conv2D>,
    channels_last: bool,
}

impl SmallConv {
    fn new(vs: &nn::Path) -> SmallConv {
        let convs = [(3, 2), (SMALL_CHANNELS, 2), (SMALL_CHANNELS, 1), (SMALL_CHANNELS, 1)]
            .iter()
            .enumerate()
            .map(|(i, &(input, stride))| {
                let c = nn::ConvConfig { stride, padding: 1, ..Default::default() };
                nn::conv2d(vs / format!("conv{}", i + 1), input, SMALL_CHANNELS, 3, c)
            })
            .collect();
        SmallConv { convs, channels_last: false }
    }
}

impl Module for SmallConv {
    fn forward(&self, x: &Tensor) -> Tensor {
        let mut y = if self.channels_last {
            x.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
        } else {
            x.shallow_clone()
        };
        for (i, conv) in self.convs.iter().enumerate() {
            y = y.apply(conv);
            if i + 1 < self.convs.len() {
                y = y.relu();
            }
        }
        y
    }
}

/// A per-frame image network.
#[derive(Debug)]
enum Trunk {
    Small(SmallConv),
    ResNet(Box<ResNet18>),
}

impl Trunk {
    fn out_channels(&self) -> i64 {
        match self {
            Trunk::Small(_) => SMALL_CHANNELS,
            Trunk::ResNet(r) => r.out_channels(),
        }
    }
}

/// Two linear layers with a ReLU between them.
#[derive(Debug)]
struct TwoLayer {
    first: nn::Linear,
    second: nn::Linear,
}

impl TwoLayer {
    fn new(vs: &nn::Path, input: i64, hidden: i64, output: i64) -> TwoLayer {
        TwoLayer {
            first: nn::linear(vs / "0", input, hidden, Default::default()),
            second: nn::linear(vs / "1", hidden, output, Default::default()),
        }
    }
}

impl Module for TwoLayer {
    fn forward(&self, x: &Tensor) -> Tensor {
        self.second.forward(&self.first.forward(x).relu())
    }
}

/// An architecture-ablation policy.
#[derive(Debug)]
pub struct AblatedPolicy {
    trunk: Trunk,
    to_task: TwoLayer,
    to_latent: TwoLayer,
    lstm: Option<nn::LSTM>,
    heads: PolicyHeads,
}

impl AblatedPolicy {
    /// Builds the network under `vs`.
    pub fn new(vs: &nn::Path, config: &ModelConfig, visual: Visual, lstm: bool) -> AblatedPolicy {
        let trunk = match visual {
            Visual::SmallConv => Trunk::Small(SmallConv::new(&(vs / "visual"))),
            Visual::ResNet => Trunk::ResNet(Box::new(ResNet18::new(
                &(vs / "backbone"),
                config.backbone_width,
                config.backbone_stages,
            ))),
        };
        let features = 2 * trunk.out_channels();
        let latent = config.latent;
        let task_frames = config.context_len() as i64 + 1;
        let rnn = nn::RNNConfig { batch_first: true, ..Default::default() };
        AblatedPolicy {
            trunk,
            to_task: TwoLayer::new(&(vs / "to_task"), task_frames * features, features, latent),
            to_latent: TwoLayer::new(&(vs / "to_latent"), features, latent, latent),
            lstm: lstm.then(|| nn::lstm(vs / "lstm", latent, latent, rnn)),
            heads: PolicyHeads::new(vs, latent, latent, 0, config),
        }
    }

    /// Spatial-softmax features `[B, T, 2C]` of normalised images `[B, T, 3, H, W]`.
    fn features(&self, images: &Tensor, train: bool) -> Tensor {
        let s = images.size();
        let flat = images.view([s[0] * s[1], s[2], s[3], s[4]]);
        let maps = match &self.trunk {
            Trunk::Small(c) => c.forward(&flat),
            Trunk::ResNet(r) => r.forward_t(&flat, train),
        };
        spatial_softmax(&maps).view([s[0], s[1], -1])
    }
}

impl PolicyNet for AblatedPolicy {
    fn set_channels_last(&mut self, on: bool) {
        match &mut self.trunk {
            Trunk::Small(c) => c.channels_last = on,
            Trunk::ResNet(r) => r.set_channels_last(on),
        }
    }

    fn forward_t(&self, context: &Tensor, agent: &Tensor, states: Option<&Tensor>, train: bool) -> PolicyOutput {
        let (b, tc, ta) = (context.size()[0], context.size()[1], agent.size()[1]);
        let feats = self.features(&Tensor::cat(&[context, agent], 1), train);
        let task = self.to_task.forward(&feats.narrow(1, 0, tc + 1).reshape([b, -1]));
        let mut latents = self.to_latent.forward(&feats);
        if let Some(lstm) = &self.lstm {
            // In fp32 under bf16 autocast too (see `full_precision`).
            latents = full_precision(|| lstm.seq(&latents.to_kind(Kind::Float)).0);
        }
        self.heads.forward(&task, &latents.narrow(1, tc, ta), states)
    }
}
