//! The Contextual-LSTM baseline of the paper: per-frame ResNet-18 + spatial softmax + MLP embeddings, an encoder
//! LSTM over the context, and a decoder LSTM over the agent's frames that attends over the encoded context and its
//! own past states; the same action head. The paper trains it with behaviour cloning only (set the inverse and
//! point loss weights to 0); with the full losses, its inverse-dynamics head reads consecutive frame embeddings
//! and its point head the encoded context.
use super::Registration;
use crate::autocast::full_precision;
use crate::model::config::ModelConfig;
use crate::model::heads::{EmbeddingMlp, PointHead, spatial_softmax};
use crate::model::mixture::{MixtureHead, MixtureSpec};
use crate::model::output::PolicyOutput;
use crate::model::policy::PolicyNet;
use crate::model::resnet::ResNet18;
use tch::nn::{self, Module, ModuleT, RNN};
use tch::{Kind, Tensor};

/// The paper's Contextual-LSTM baseline.
pub const CONTEXTUAL_LSTM: Registration = Registration {
    name: "contextual_lstm",
    description: "the Contextual-LSTM baseline: encoder and decoder LSTMs over frame embeddings",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: false,
    spatial_tokens: false,
    bf16: true,
    build: |vs, config| Box::new(ContextualLstm::new(vs, config)),
};

/// The baseline network.
#[derive(Debug)]
pub struct ContextualLstm {
    trunk: ResNet18,
    embed: EmbeddingMlp,
    encoder: nn::LSTM,
    decoder: nn::LSTM,
    policy: nn::Linear,
    action_head: MixtureHead,
    inverse: nn::Linear,
    point_head: PointHead,
}

impl ContextualLstm {
    /// Builds the network under `vs`.
    pub fn new(vs: &nn::Path, config: &ModelConfig) -> ContextualLstm {
        let trunk = ResNet18::new(&(vs / "backbone"), config.backbone_width, config.backbone_stages);
        let c = trunk.out_channels();
        let (latent, hidden) = (config.latent, config.lstm_hidden);
        let rnn = nn::RNNConfig { batch_first: true, ..Default::default() };
        ContextualLstm {
            trunk,
            embed: EmbeddingMlp::new(&(vs / "frame_embed"), 2 * c, config.embed_hidden, latent, config.dropout),
            encoder: nn::lstm(vs / "encoder", latent, hidden, rnn),
            decoder: nn::lstm(vs / "decoder", latent, hidden, rnn),
            policy: nn::linear(vs / "policy", 2 * hidden, config.policy_hidden, Default::default()),
            action_head: MixtureHead::new(&(vs / "action_head"), config.policy_hidden, MixtureSpec::for_model(config)),
            // Built last, so that the weights above are drawn as they were before these heads existed.
            inverse: nn::linear(vs / "inverse", 2 * latent, config.policy_hidden, Default::default()),
            point_head: PointHead::new(&(vs / "point_head"), hidden, config.point_hidden),
        }
    }

    fn embed_frames(&self, images: &Tensor, train: bool) -> Tensor {
        let s = images.size();
        let f = self.trunk.forward_t(&images.view([s[0] * s[1], s[2], s[3], s[4]]), train);
        self.embed.forward_t(&spatial_softmax(&f), train).view([s[0], s[1], -1])
    }
}

impl PolicyNet for ContextualLstm {
    fn set_channels_last(&mut self, on: bool) {
        self.trunk.set_channels_last(on)
    }

    fn forward_t(&self, context: &Tensor, agent: &Tensor, _states: Option<&Tensor>, train: bool) -> PolicyOutput {
        let (tc, ta) = (context.size()[1], agent.size()[1]);
        let context_frames = self.embed_frames(context, train);
        let frames = self.embed_frames(agent, train);
        // The recurrences run in fp32 under bf16 autocast too (see `full_precision`).
        let (encoded, decoded) = full_precision(|| {
            let (encoded, state) = self.encoder.seq(&context_frames.to_kind(Kind::Float));
            let (decoded, _) = self.decoder.seq_init(&frames.to_kind(Kind::Float), &state);
            (encoded, decoded)
        });
        // Each decoder step attends over every context step and the decoder steps up to itself.
        let memory = Tensor::cat(&[&encoded, &decoded], 1);
        let scale = (decoded.size()[2] as f64).sqrt();
        let scores = decoded.matmul(&memory.transpose(1, 2)) / scale;
        let device = scores.device();
        let q = Tensor::arange(ta, (Kind::Int64, device)).unsqueeze(1);
        let k = Tensor::arange(tc + ta, (Kind::Int64, device)).unsqueeze(0);
        let visible = k.lt(tc).logical_or(&(k - tc).le_tensor(&q));
        let attended =
            scores.masked_fill(&visible.logical_not(), f64::NEG_INFINITY).softmax(-1, Kind::Float).matmul(&memory);
        let hidden = self.policy.forward(&Tensor::cat(&[decoded, attended], -1)).relu();
        let pairs = Tensor::cat(&[frames.narrow(1, 0, ta - 1), frames.narrow(1, 1, ta - 1)], -1);
        let context_summary = encoded.select(1, tc - 1);
        PolicyOutput {
            actions: self.action_head.forward(&hidden),
            inverse: Some(self.action_head.forward(&self.inverse.forward(&pairs).relu())),
            point: Some(self.point_head.forward(&context_summary)),
            poses: None,
            task_logits: None,
        }
    }
}
