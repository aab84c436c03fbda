//! Model settings, with the paper's values (section 4 and the authors' `experiments/base.yaml`) as defaults.
use super::architectures::{self, Registration};
use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

/// Which demonstrator frames the policy sees (the context ablation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ContextMode {
    /// `context_frames` frames, one from each equal segment of the video, first and last forced.
    #[default]
    Spread,
    /// The first and the last frame.
    FirstLast,
    /// The last frame only, repeated `context_frames` times (the authors' final-frame ablation).
    Final,
}

/// Which frames a demonstration (context) frame attends to in the transformer's causal layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ContextAttention {
    /// Context frames at or before it, like every frame (the authors' `NonLocalLayer`: a lower-triangular mask
    /// over all frames).
    #[default]
    Causal,
    /// Every context frame, in both directions (agent frames still see only the past).
    Full,
}

/// How the transformer computes its task embedding from [context, first agent frame].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TaskPass {
    /// A second pass of the trunk features of those frames through positional encoding and the causal layers,
    /// with batch-norm statistics and dropout draws of its own (the authors' `inverse_module.py`).
    #[default]
    Separate,
    /// Those frames' tokens sliced out of the pass over all frames.
    Shared,
}

/// Which features `model.object_attention` reads in each agent frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ObjectAttentionInput {
    /// The tokens after the causal layers, where each agent frame has mixed with the demonstration's.
    #[default]
    Mixed,
    /// The trunk's own tokens, before positional encoding and the causal layers (as `localise` reads them).
    Trunk,
    /// The tokens of a second trunk, a frozen copy of the pretrained one (`selection_backbone.*`, batch norm in
    /// evaluation mode), while the policy's own trunk is fine-tuned: the selection the pretraining gave cannot
    /// decay under the other losses. Needs pretrained trunk weights.
    FrozenTrunk,
}

impl ObjectAttentionInput {
    /// Whether it reads trunk tokens (the pretrained trunk's or a frozen copy's), as `localise` does.
    pub fn reads_trunk(self) -> bool {
        matches!(self, ObjectAttentionInput::Trunk | ObjectAttentionInput::FrozenTrunk)
    }
}

/// What `model.object_attention` asks for in each agent frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ObjectAttentionQuery {
    /// The task embedding.
    #[default]
    Embedding,
    /// The task head's predicted distribution over the sixteen tasks, detached: once the head is right, the
    /// one-hot that `localise --object-attention` queries with.
    TaskHead,
}

/// What `model.pose_head` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PoseHeadInput {
    /// The task embedding and each frame's features (and the robot's state, with `model.concat_state`), as the
    /// action head reads them.
    #[default]
    Joint,
    /// The task embedding, detached, and the object attention's positions alone: the pose loss then trains the
    /// attention and the trunk to find the named object, and leaves the task embedding to the other losses.
    Object,
}

/// Initial value of the action head's learned log-scales.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LogScaleInit {
    /// Normal draws divided by sqrt(8) (the authors').
    #[default]
    Random,
    /// Zero (a scale of 1).
    Zero,
}

/// The policy architecture: a name registered in `model::architectures` (the paper's model, its ablations and
/// the baselines).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(transparent)]
pub struct Architecture(pub String);

impl Architecture {
    /// The architecture registered as `name`.
    pub fn named(name: &str) -> Architecture {
        Architecture(name.to_string())
    }

    /// Its registry entry; none for a name nobody registered.
    pub fn registration(&self) -> Option<&'static Registration> {
        architectures::find(&self.0)
    }
}

impl Default for Architecture {
    /// The paper's transformer.
    fn default() -> Self {
        Architecture::named(architectures::transformer::TRANSFORMER.name)
    }
}

/// Architecture and head sizes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    pub architecture: Architecture,
    /// ResNet-18 base width (64 is the standard net; smaller widths for CPU runs).
    pub backbone_width: i64,
    /// Residual stages of the ResNet-18 kept (4: the whole trunk, the paper's; 3 ends at stride 16, with a
    /// feature map twice as fine, for small frames).
    pub backbone_stages: usize,
    /// Optional safetensors file of torchvision ResNet-18 weights (names like `layer1.0.conv1.weight`; for DAML,
    /// VGG-16's `features.0.*` and `features.2.*`); a relative path is read from the experiment file's folder. Its
    /// content, not its path, goes into the training's key.
    pub pretrained_backbone: Option<String>,
    /// Keeps the pretrained trunk's weights fixed during training (its BatchNorm statistics still follow the
    /// data). A departure: the authors fine-tune the whole network (false).
    pub freeze_backbone: bool,
    /// Attention layers over context + agent frames.
    pub attention_layers: usize,
    /// Inner width of the query/key/value projections.
    pub attention_inner: i64,
    /// Attention heads of each non-local layer (the inner width is split between them).
    pub attention_heads: i64,
    /// Which frames a context frame attends to in the causal layers (`causal`, the authors', or `full`).
    pub context_attention: ContextAttention,
    /// Whether the task embedding takes its own pass through the causal layers (`separate`, the authors') or
    /// slices the pass over all frames (`shared`).
    pub task_pass: TaskPass,
    /// Softmax temperature; default sqrt(feature channels), 512 in the paper.
    pub attention_temperature: Option<f64>,
    /// Dropout probability after the positional encoding, in the attention layers and the embedding MLPs.
    pub dropout: f64,
    /// Hidden width of the frame and task embedding MLPs.
    pub embed_hidden: i64,
    /// Width of the L2-normalised frame and task embeddings.
    pub latent: i64,
    /// Hidden width of the policy and inverse-dynamics MLPs.
    pub policy_hidden: i64,
    /// Hidden width of the point head.
    pub point_hidden: i64,
    /// State width of the Contextual-LSTM baseline's encoder and decoder.
    pub lstm_hidden: i64,
    /// Logistic mixture components per action dimension.
    pub mixtures: i64,
    /// Discretisation bins of each action dimension.
    pub bins: i64,
    /// Lower bound of the action head's log-scales (the authors' -7).
    pub log_scale_min: f64,
    /// Initial value of the action head's log-scales (`random`, the authors' normal / sqrt(8), or `zero`).
    pub log_scale_init: LogScaleInit,
    pub context: ContextMode,
    /// Demonstrator frames for `context = "spread"` and `"final"`.
    pub context_frames: usize,
    /// Agent frames in a training window (actions = frames - 1).
    pub agent_frames: usize,
    /// An extra head on the architectures with the paper's heads: the grasp and drop positions (the targets of
    /// DAML's auxiliary head) regressed from [task, frame] at every agent frame, trained with weight
    /// `train.loss.pose`. It makes each frame's embedding locate the demonstrated object. A departure: the
    /// authors' transformer has no such head (false).
    pub pose_head: bool,
    /// An extra head on the architectures with the paper's heads: the task (which object to which bin, one of
    /// sixteen) classified from the task embedding alone, trained with weight `train.loss.task`. It asks the
    /// context to say which task it shows, the selection a policy must make. A departure: the authors have no
    /// such head (false).
    pub task_head: bool,
    /// An extra path on the transformer (and its no-attention ablation): attention from the task embedding over
    /// each agent frame's spatial tokens, `attention_heads` maps whose expected (x, y) join the frame's embedding
    /// in the action, inverse and pose heads. It lets the network combine which object the demonstration names
    /// with where that object is in the agent's view. A departure: the authors read each agent frame only through
    /// its spatial softmax (false).
    pub object_attention: bool,
    /// Which tokens the object attention reads: `mixed` (after the causal layers), `trunk` (the trunk's own,
    /// as `localise --object-attention` reads them) or `frozen_trunk` (a frozen copy of the pretrained trunk's,
    /// beside the fine-tuned one; needs `[pretrain]` or `pretrained_backbone`). Only with `object_attention`.
    pub object_attention_input: ObjectAttentionInput,
    /// What the object attention queries with: `embedding` (the task embedding) or `task_head` (the task head's
    /// predicted distribution, detached; needs `task_head`). Only with `object_attention`.
    pub object_attention_query: ObjectAttentionQuery,
    /// What the pose head reads: `joint` (what the action is read from: the task embedding, the frame's features
    /// and, with `concat_state`, the robot's state) or `object` (the task embedding, detached, and the object
    /// attention's positions; needs `pose_head` and `object_attention`).
    pub pose_head_input: PoseHeadInput,
    /// The robot's own state (end-effector position and orientation, finger joints: the authors' `ee_aa` and
    /// `gripper_qpos`) joined to each agent frame's embedding where the action is read, as the authors'
    /// `concat_state` does; on the architectures with the paper's heads. A departure: their experiments leave it
    /// off (false), so the policy sees only pictures.
    pub concat_state: bool,
    /// With `concat_state`, the fingers' change since the window's previous frame joins the state (none at the
    /// window's first frame, as after the agent's window is cleared in evaluation), so one frame can show
    /// whether a grip has stopped closing. A departure of this tool's (false: the authors' state alone).
    pub finger_motion: bool,
    /// Starting weights of the object attention (`object_attention.*`), set by the train stage from a `[pretrain]`
    /// whose `object_attention_steps` trained one; not an experiment-file key.
    #[serde(skip)]
    #[schemars(skip)]
    pub pretrained_object_attention: Option<String>,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            architecture: Architecture::default(),
            backbone_width: 64,
            backbone_stages: 4,
            pretrained_backbone: None,
            freeze_backbone: false,
            attention_layers: 2,
            attention_inner: 128,
            attention_heads: 4,
            context_attention: ContextAttention::Causal,
            task_pass: TaskPass::Separate,
            attention_temperature: None,
            dropout: 0.2,
            embed_hidden: 256,
            latent: 40,
            policy_hidden: 32,
            point_hidden: 40,
            lstm_hidden: 256,
            mixtures: 2,
            bins: 256,
            log_scale_min: -7.0,
            log_scale_init: LogScaleInit::Random,
            context: ContextMode::Spread,
            context_frames: 4,
            agent_frames: 7,
            pose_head: false,
            task_head: false,
            object_attention: false,
            object_attention_input: ObjectAttentionInput::Mixed,
            object_attention_query: ObjectAttentionQuery::Embedding,
            pose_head_input: PoseHeadInput::Joint,
            concat_state: false,
            finger_motion: false,
            pretrained_object_attention: None,
        }
    }
}

/// The largest width, hidden size or count a model key may take: far above the paper's (512 channels).
const MAX_WIDTH: i64 = 1 << 16;

impl ModelConfig {
    /// Number of demonstrator frames the policy sees.
    pub fn context_len(&self) -> usize {
        match self.context {
            ContextMode::Spread | ContextMode::Final => self.context_frames,
            ContextMode::FirstLast => 2,
        }
    }

    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if self.architecture.registration().is_none() {
            bail!(
                "model.architecture = {:?} is not one of the registered architectures: {}",
                self.architecture.0,
                architectures::names().join(", ")
            );
        }
        let positive = [
            ("backbone_width", self.backbone_width),
            ("attention_inner", self.attention_inner),
            ("attention_heads", self.attention_heads),
            ("embed_hidden", self.embed_hidden),
            ("latent", self.latent),
            ("policy_hidden", self.policy_hidden),
            ("point_hidden", self.point_hidden),
            ("lstm_hidden", self.lstm_hidden),
            ("mixtures", self.mixtures),
        ];
        for (key, v) in positive {
            if !(1..=MAX_WIDTH).contains(&v) {
                bail!("model.{key} = {v} out of range 1..={MAX_WIDTH}");
            }
        }
        if !(1..=4).contains(&self.backbone_stages) {
            bail!("model.backbone_stages = {} out of range 1..=4", self.backbone_stages);
        }
        if self.attention_inner % self.attention_heads != 0 {
            bail!("model.attention_inner = {} is not divisible by attention_heads", self.attention_inner);
        }
        if self.bins < 2 {
            bail!("model.bins = {} must be at least 2", self.bins);
        }
        if !(0.0..1.0).contains(&self.dropout) {
            bail!("model.dropout = {} out of range [0, 1)", self.dropout);
        }
        if let Some(t) = self.attention_temperature.filter(|t| !(t.is_finite() && *t > 0.0)) {
            bail!("model.attention_temperature = {t} must be a positive number");
        }
        if !self.log_scale_min.is_finite() {
            bail!("model.log_scale_min = {} must be a number", self.log_scale_min);
        }
        if self.context != ContextMode::FirstLast && self.context_frames < 2 {
            bail!("model.context_frames = {} must be at least 2", self.context_frames);
        }
        let registration = self.architecture.registration().expect("checked above");
        if self.pose_head && !registration.paper_heads {
            bail!(
                "model.pose_head = true needs an architecture that ends in the paper's heads, not {:?}",
                self.architecture.0
            );
        }
        if self.concat_state && !registration.paper_heads {
            bail!(
                "model.concat_state = true needs an architecture that ends in the paper's heads, not {:?}",
                self.architecture.0
            );
        }
        if self.finger_motion && !self.concat_state {
            bail!("model.finger_motion = true needs model.concat_state = true: it adds to the state the network reads");
        }
        if self.task_head && !registration.paper_heads {
            bail!(
                "model.task_head = true needs an architecture that ends in the paper's heads, not {:?}",
                self.architecture.0
            );
        }
        if self.object_attention && !registration.spatial_tokens {
            bail!(
                "model.object_attention = true needs an architecture that keeps each frame's spatial tokens \
                 (transformer, temporal_conv), not {:?}",
                self.architecture.0
            );
        }
        if self.object_attention_input != ObjectAttentionInput::Mixed && !self.object_attention {
            bail!(
                "model.object_attention_input chooses the input of model.object_attention: set model.object_attention = true"
            );
        }
        if self.object_attention_query == ObjectAttentionQuery::TaskHead && !(self.object_attention && self.task_head) {
            bail!("model.object_attention_query = \"task_head\" needs model.object_attention and model.task_head");
        }
        if self.pose_head_input == PoseHeadInput::Object && !(self.pose_head && self.object_attention) {
            bail!("model.pose_head_input = \"object\" needs model.pose_head and model.object_attention");
        }
        if self.agent_frames < 2 {
            bail!("model.agent_frames = {} must be at least 2 (one action)", self.agent_frames);
        }
        Ok(())
    }
}
