//! The paper's policy: a ResNet-18 trunk per frame, positional encoding, causal non-local attention over
//! [context frames, agent frames], frame and task embeddings, and the action, inverse-dynamics and point heads.
use super::Registration;
use crate::model::attention::{
    AttentionLayer, AttentionSpec, ConvBlock, conv3d_config, frame_causal_mask, positional_encoding,
};
use crate::model::config::{ContextAttention, ModelConfig, ObjectAttentionInput, ObjectAttentionQuery, TaskPass};
use crate::model::heads::{EmbeddingMlp, ObjectAttention, PolicyHeads, spatial_softmax};
use crate::model::output::PolicyOutput;
use crate::model::policy::PolicyNet;
use crate::model::resnet::ResNet18;
use tch::Tensor;
use tch::nn::{self, ModuleT};

/// Where the frozen copy of the pretrained trunk lives (`model.object_attention_input = "frozen_trunk"`).
pub const SELECTION_TRUNK: &str = "selection_backbone";

/// The paper's model.
pub const TRANSFORMER: Registration = Registration {
    name: "transformer",
    description: "non-local attention over all tokens of all frames (the paper's model)",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: true,
    bf16: true,
    build: |vs, config| Box::new(TransformerPolicy::new(vs, config, Mixing::Attention)),
};

/// The paper's "no attention" ablation.
pub const TEMPORAL_CONV: Registration = Registration {
    name: "temporal_conv",
    description: "the no-attention ablation: causal bottleneck blocks around a 5x5x5 spatio-temporal convolution",
    auxiliary_heads: true,
    pose_head: false,
    paper_heads: true,
    spatial_tokens: true,
    // Under bf16 autocast on a CPU with AVX512-BF16 (AMD EPYC, 2026-12-02) its 5x5x5 convolution's gradient came
    // out at a cosine of 0.0 from fp32's (tests/it/precision.rs), at this commit and the one before: refused.
    bf16: false,
    build: |vs, config| Box::new(TransformerPolicy::new(vs, config, Mixing::TemporalConv)),
};

/// How the layers between trunk and embeddings mix information across frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mixing {
    Attention,
    TemporalConv,
}

/// A layer that mixes information across frames.
#[derive(Debug)]
enum Mixer {
    Attention(Box<AttentionLayer>),
    Conv(Box<ConvBlock>),
}

impl Mixer {
    fn new(vs: &nn::Path, mixing: Mixing, spec: AttentionSpec, causal: bool) -> Mixer {
        match mixing {
            Mixing::TemporalConv => {
                Mixer::Conv(Box::new(ConvBlock::new(vs, spec.channels, spec.inner, causal, spec.dropout)))
            }
            Mixing::Attention => Mixer::Attention(Box::new(AttentionLayer::new(vs, spec))),
        }
    }

    /// Tokens of `frames` frames of `h x w`; `mask` restricts attention (the convolution is causal by padding).
    fn forward(&self, x: &Tensor, mask: Option<&Tensor>, (frames, h, w): (i64, i64, i64), train: bool) -> Tensor {
        match self {
            Mixer::Attention(a) => a.forward(x, mask, train),
            Mixer::Conv(c) => c.forward(x, frames, h, w, train),
        }
    }
}

/// The transformer policy.
#[derive(Debug)]
pub struct TransformerPolicy {
    trunk: ResNet18,
    dropout: f64,
    context_attention: ContextAttention,
    task_pass: TaskPass,
    causal: Vec<Mixer>,
    task_attention: Mixer,
    task_conv: nn::Conv<[i64; 3]>,
    /// One MLP embeds agent frames and the task alike (the authors share it).
    embed: EmbeddingMlp,
    /// `model.object_attention`: where the task's object is in each agent frame, beside its embedding.
    object_attention: Option<ObjectAttention>,
    /// The tokens it reads.
    object_attention_input: ObjectAttentionInput,
    /// `object_attention_input = "frozen_trunk"`: the frozen copy of the pretrained trunk it reads.
    selection_trunk: Option<ResNet18>,
    /// What it queries with.
    object_attention_query: ObjectAttentionQuery,
    heads: PolicyHeads,
}

impl TransformerPolicy {
    /// Builds the network under `vs` (call `config.validate()` first).
    pub fn new(vs: &nn::Path, config: &ModelConfig, mixing: Mixing) -> TransformerPolicy {
        let trunk = ResNet18::new(&(vs / "backbone"), config.backbone_width, config.backbone_stages);
        let c = trunk.out_channels();
        let spec = AttentionSpec {
            channels: c,
            inner: config.attention_inner,
            heads: config.attention_heads,
            temperature: config.attention_temperature.unwrap_or((c as f64).sqrt()),
            dropout: config.dropout,
        };
        let causal =
            (0..config.attention_layers).map(|i| Mixer::new(&(vs / "attention" / i), mixing, spec, true)).collect();
        let (hidden, latent) = (config.embed_hidden, config.latent);
        let query_width = match config.object_attention_query {
            ObjectAttentionQuery::Embedding => latent,
            ObjectAttentionQuery::TaskHead => crate::sim::task::NUM_TASKS as i64,
        };
        let object_attention = config.object_attention.then(|| {
            let vs = vs / "object_attention";
            ObjectAttention::new(&vs, query_width, c, config.attention_heads, config.attention_inner)
        });
        let object = object_attention.as_ref().map_or(0, ObjectAttention::width);
        let selection_trunk = (config.object_attention
            && config.object_attention_input == ObjectAttentionInput::FrozenTrunk)
            .then(|| ResNet18::new(&(vs / SELECTION_TRUNK), config.backbone_width, config.backbone_stages));
        let frame = latent + object;
        TransformerPolicy {
            trunk,
            dropout: config.dropout,
            context_attention: config.context_attention,
            task_pass: config.task_pass,
            causal,
            task_attention: Mixer::new(&(vs / "task_attention"), mixing, spec, false),
            task_conv: nn::conv(vs / "task_conv", c, c, [3, 1, 1], conv3d_config([0, 0, 0])),
            embed: EmbeddingMlp::new(&(vs / "embed"), 2 * c, hidden, latent, config.dropout),
            object_attention,
            object_attention_input: config.object_attention_input,
            selection_trunk,
            object_attention_query: config.object_attention_query,
            heads: PolicyHeads::new(vs, latent, frame, object, config),
        }
    }

    /// Trunk features `[B, T, C, h, w]` of normalised images `[B, T, 3, H, W]`.
    fn features(&self, images: &Tensor, train: bool) -> Tensor {
        Self::features_of(&self.trunk, images, train)
    }

    /// Features `[B, T, C, h, w]` of `trunk` for images `[B, T, 3, H, W]`.
    fn features_of(trunk: &ResNet18, images: &Tensor, train: bool) -> Tensor {
        let s = images.size();
        let f = trunk.forward_t(&images.view([s[0] * s[1], s[2], s[3], s[4]]), train);
        let fs = f.size();
        f.view([s[0], s[1], fs[1], fs[2], fs[3]])
    }
}

impl PolicyNet for TransformerPolicy {
    fn set_channels_last(&mut self, on: bool) {
        self.trunk.set_channels_last(on);
        if let Some(trunk) = &mut self.selection_trunk {
            trunk.set_channels_last(on);
        }
    }

    fn forward_t(&self, context: &Tensor, agent: &Tensor, states: Option<&Tensor>, train: bool) -> PolicyOutput {
        let tc = context.size()[1];
        let ta = agent.size()[1];
        let feats = self.features(&Tensor::cat(&[context, agent], 1), train);
        let (b, t, c, h, w) = (feats.size()[0], tc + ta, feats.size()[2], feats.size()[3], feats.size()[4]);
        let hw = h * w;
        // [B, T, C, h, w] -> tokens [B, T*h*w, C]
        let tokens = feats.permute([0, 1, 3, 4, 2]).reshape([b, t * hw, c]);
        let x = self.mix(&tokens, tc, (t, h, w), train);
        let frames = x.view([b, t, h, w, c]).permute([0, 1, 4, 2, 3]);

        // Frame embeddings of the agent frames.
        let agent_frames = frames.narrow(1, tc, ta);
        let agent_feats = agent_frames.reshape([b * ta, c, h, w]);
        let e = self.embed.forward_t(&spatial_softmax(&agent_feats), train).view([b, ta, -1]);

        // Task embedding from the context and the first agent frame; the temporal convolution is unpadded.
        let task_tokens = match self.task_pass {
            TaskPass::Shared => x.narrow(1, 0, (tc + 1) * hw),
            TaskPass::Separate => self.mix(&tokens.narrow(1, 0, (tc + 1) * hw), tc, (tc + 1, h, w), train),
        };
        let task_tokens = self.task_attention.forward(&task_tokens, None, (tc + 1, h, w), train);
        let task_frames = task_tokens.view([b, tc + 1, h, w, c]).permute([0, 4, 1, 2, 3]);
        let pooled = task_frames.apply(&self.task_conv).mean_dim([2i64].as_slice(), false, tch::Kind::Float);
        let task = self.embed.forward_t(&spatial_softmax(&pooled), train);

        let e = match &self.object_attention {
            Some(attention) => {
                let read = match self.object_attention_input {
                    ObjectAttentionInput::Mixed => agent_frames,
                    ObjectAttentionInput::Trunk => feats.narrow(1, tc, ta),
                    // Frozen: no gradient, and batch norm keeps the pretraining's statistics.
                    ObjectAttentionInput::FrozenTrunk => {
                        let trunk = self.selection_trunk.as_ref().expect("built with the frozen_trunk input");
                        tch::no_grad(|| Self::features_of(trunk, agent, false))
                    }
                };
                let query = match self.object_attention_query {
                    ObjectAttentionQuery::Embedding => task.shallow_clone(),
                    ObjectAttentionQuery::TaskHead => {
                        let logits = self.heads.task_logits(&task).expect("validated: the task head is on");
                        logits.detach().softmax(-1, tch::Kind::Float)
                    }
                };
                Tensor::cat(&[e, attention.forward(&query, &read)], -1)
            }
            None => e,
        };
        self.heads.forward(&task, &e, states)
    }
}

impl TransformerPolicy {
    /// Positional encoding, dropout and the causal layers over trunk tokens `[B, frames*h*w, C]` whose first
    /// `context` frames are the demonstration's.
    fn mix(&self, tokens: &Tensor, context: i64, (frames, h, w): (i64, i64, i64), train: bool) -> Tensor {
        let (hw, c, device) = (h * w, tokens.size()[2], tokens.device());
        let mut x = (tokens + positional_encoding(frames * hw, c, device).unsqueeze(0)).dropout(self.dropout, train);
        let visible = match self.context_attention {
            ContextAttention::Causal => 0,
            ContextAttention::Full => context,
        };
        let mask = frame_causal_mask(frames, hw, visible, device);
        for layer in &self.causal {
            x = layer.forward(&x, Some(&mask), (frames, h, w), train);
        }
        x
    }
}
