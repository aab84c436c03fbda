//! Training settings, with the paper's values as defaults.
use crate::data::augment::Augmentation;
use crate::data::loader::Batch;
use crate::data::pairs::{AUTHORS_WINDOW_END, Windows};
use crate::model::config::ModelConfig;
use crate::model::policy::Losses;
use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};
use tch::{Device, Tensor};

/// Weights of the three losses; 0 switches a loss off (the loss ablations).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LossWeights {
    /// Behaviour cloning: the NLL of the expert's actions under the mixture head.
    pub bc: f64,
    /// Inverse dynamics: the NLL of each action from the frames before and after it (the paper's ablation sets
    /// it to 0).
    pub inverse: f64,
    /// The end-effector pixel at the end of the window, from the task embedding.
    pub point: f64,
    /// Grasp-and-drop position regression (metres squared): DAML's auxiliary loss, which the authors add
    /// unweighted (1), and `model.pose_head`'s.
    pub pose: f64,
    /// Cross-entropy of the demonstrated task from the task embedding (`model.task_head`'s; a departure).
    pub task: f64,
}

/// The authors' probability that a training window starts at its trajectory's first frame.
pub const AUTHORS_WINDOW_START: f64 = 0.2;

/// The authors' quantisation of recorded actions: multiples of 1/128 in normalised units.
pub const AUTHORS_ACTION_RESOLUTION: u32 = 128;

/// The most optimiser steps a training may ask for: far above the paper's 60,000.
const MAX_STEPS: u64 = 100_000_000;
/// The largest batch a training may ask for: far above the paper's 30.
const MAX_BATCH: usize = 1 << 16;

impl TrainConfig {
    /// Where training windows are drawn.
    pub fn windows(&self) -> Windows {
        Windows::Training { start: self.window_start }
    }

    /// A batch's targets as this training scores them: actions quantised (`train.action_resolution`), the pose
    /// loss's frames chosen (`train.pose_frames`).
    pub fn targets(&self, batch: Batch) -> Batch {
        batch.quantise_actions(self.action_resolution).pose_at_start_only(self.pose_frames == PoseFrames::First)
    }
}

impl LossWeights {
    /// The weighted sum of `losses` that is optimised.
    pub fn total(&self, losses: &Losses) -> Tensor {
        &losses.bc * self.bc
            + &losses.inverse * self.inverse
            + &losses.point * self.point
            + &losses.pose * self.pose
            + &losses.task * self.task
    }
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights { bc: 1.0, inverse: 1.0, point: 0.1, pose: 1.0, task: 1.0 }
    }
}

/// How the learning rate moves over training.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    /// `lr` throughout (the authors').
    #[default]
    Constant,
    /// A linear warm-up over `lr_warmup` steps, then a cosine decay from `lr` to 0 at the last step: for short
    /// runs, where a large step early and a small one late both matter.
    Cosine,
}

/// Layout of image tensors in the trunk; the numbers are the same, the speed is not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MemoryFormat {
    /// Channels before rows and columns (NCHW), PyTorch's default.
    #[default]
    Contiguous,
    /// Channels last (NHWC strides): faster convolutions, batch norm and pooling on CPU and on tensor cores.
    ChannelsLast,
}

/// Which agent frames the pose loss (`model.pose_head`) scores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PoseFrames {
    /// Every frame of the window.
    #[default]
    Window,
    /// Only a trajectory's first frame (windows drawn at its start): there the arm has not moved, so only the
    /// picture can say where the named object lies; later frames also show where the arm is heading.
    First,
}

/// Where training frames are augmented and normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum AugmentOn {
    /// By the threads that build each batch, on the host.
    #[default]
    Host,
    /// On the training device, as tensor operations on raw frames: the same draws and, up to float rounding,
    /// the same frames, with a quarter of the bytes copied (what keeps a GPU fed).
    Device,
}

/// The number type of the forward pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    /// Everything in fp32 (the authors').
    #[default]
    Fp32,
    /// bf16 autocast: matrix products and convolutions in bf16, weights, gradients and the optimiser in fp32.
    Bf16,
}

impl Precision {
    /// The autocast scope this precision needs on `device`, if any.
    pub fn scope(self, device: Device) -> Option<crate::autocast::Autocast> {
        (self == Precision::Bf16).then(|| crate::autocast::Autocast::bf16(device))
    }
}

/// How to train.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Optimiser steps (the authors evaluate after 60,000).
    pub steps: u64,
    /// Training samples (demonstration and agent window pairs) per step.
    pub batch_size: usize,
    /// Adam's learning rate (the peak of the cosine schedule).
    pub lr: f64,
    /// How the learning rate moves over training (`constant`, the authors', or `cosine`).
    pub lr_schedule: LrSchedule,
    /// Warm-up steps of the cosine schedule.
    pub lr_warmup: u64,
    /// Seeds the network's initial weights, the batches and dropout; the grid's `seeds` set it per cell.
    pub seed: u64,
    /// `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N`.
    pub device: String,
    /// Layout of the trunk's image tensors (an execution detail like `device`: not part of a stage's key).
    pub memory_format: MemoryFormat,
    /// Where frames are augmented (an execution detail like `device`: not part of a stage's key).
    pub augment_on: AugmentOn,
    /// Number type of the forward pass (changes results slightly, so it is part of a stage's key unless fp32).
    pub precision: Precision,
    /// Steps between validation passes (and loss-curve points).
    pub val_interval: u64,
    /// Fixed validation batches per pass.
    pub val_batches: u64,
    /// Steps between checkpoints.
    pub checkpoint_interval: u64,
    /// Fraction of each task's trajectories held out for validation.
    pub val_fraction: f64,
    /// Image augmentation of training samples (the augmentation ablation turns it off).
    pub augment: bool,
    /// Its ranges.
    pub augmentation: Augmentation,
    pub loss: LossWeights,
    /// Probability that a training window starts at its trajectory's first frame, where only the picture says
    /// where the object is (the authors' 0.2; each window also ends the trajectory with probability 0.2).
    pub window_start: f64,
    /// Training actions (and the inverse model's targets) are quantised to multiples of 1 / this in normalised
    /// units, truncated towards zero, as the authors' recorded actions are (`normalize_action` in
    /// `custom_ik_wrapper.py`: 128); 0 keeps them exact.
    pub action_resolution: u32,
    /// Which agent frames the pose loss scores: `window` (all) or `first` (a trajectory's first frame only).
    pub pose_frames: PoseFrames,
    /// Batches prepared ahead of the training step on a background thread; 0 prepares each when it is needed
    /// (faster where the cores are few: the two do not compete).
    pub prefetch: usize,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            steps: 60_000,
            batch_size: 30,
            lr: 5e-4,
            lr_schedule: LrSchedule::Constant,
            lr_warmup: 0,
            seed: 0,
            device: "auto".into(),
            memory_format: MemoryFormat::Contiguous,
            augment_on: AugmentOn::Host,
            precision: Precision::Fp32,
            val_interval: 1000,
            val_batches: 4,
            checkpoint_interval: 2000,
            val_fraction: 0.1,
            augment: true,
            augmentation: Augmentation::default(),
            loss: LossWeights::default(),
            window_start: AUTHORS_WINDOW_START,
            action_resolution: AUTHORS_ACTION_RESOLUTION,
            pose_frames: PoseFrames::Window,
            prefetch: 4,
        }
    }
}

impl TrainConfig {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_STEPS).contains(&self.steps) || !(1..=MAX_BATCH).contains(&self.batch_size) {
            bail!(
                "train.steps = {} and train.batch_size = {} must lie in 1..={MAX_STEPS} and 1..={MAX_BATCH}",
                self.steps,
                self.batch_size
            );
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            bail!("train.lr = {} must be positive", self.lr);
        }
        if self.lr_warmup >= self.steps {
            bail!("train.lr_warmup = {} must be below train.steps = {}", self.lr_warmup, self.steps);
        }
        if self.val_interval == 0 || self.val_batches == 0 || self.checkpoint_interval == 0 {
            bail!("train.val_interval, train.val_batches and train.checkpoint_interval must be at least 1");
        }
        if !(self.val_fraction > 0.0 && self.val_fraction < 1.0) {
            bail!("train.val_fraction = {} out of range (0, 1)", self.val_fraction);
        }
        let w = &self.loss;
        for (key, v) in [("bc", w.bc), ("inverse", w.inverse), ("point", w.point), ("pose", w.pose), ("task", w.task)] {
            if !(v >= 0.0 && v.is_finite()) {
                bail!("train.loss.{key} = {v} must be a non-negative number");
            }
        }
        if w.bc + w.inverse + w.point + w.pose == 0.0 {
            bail!("train.loss: every loss weight is 0");
        }
        if !(0.0..=1.0 - AUTHORS_WINDOW_END).contains(&self.window_start) {
            bail!(
                "train.window_start = {} out of range [0, {}] (windows also end their trajectory with probability {})",
                self.window_start,
                1.0 - AUTHORS_WINDOW_END,
                AUTHORS_WINDOW_END
            );
        }
        self.augmentation.validate()?;
        crate::device::check_device_name(&self.device)?;
        Ok(())
    }

    /// The learning rate of `step` (1-based) of `steps`.
    pub fn lr_at(&self, step: u64) -> f64 {
        match self.lr_schedule {
            LrSchedule::Constant => self.lr,
            LrSchedule::Cosine if step <= self.lr_warmup => self.lr * step as f64 / self.lr_warmup.max(1) as f64,
            LrSchedule::Cosine => {
                let span = (self.steps - self.lr_warmup).max(1) as f64;
                let f = (step - self.lr_warmup) as f64 / span;
                self.lr * 0.5 * (1.0 + (std::f64::consts::PI * f).cos())
            }
        }
    }

    /// The torch device named by `device`.
    pub fn device(&self) -> Result<Device> {
        crate::device::parse_device(&self.device)
    }
}

/// Checks that the architecture trains faithfully at `train.precision`.
pub fn check_precision(model: &ModelConfig, train: &TrainConfig) -> Result<()> {
    let supported = model.architecture.registration().is_none_or(|r| r.bf16);
    if train.precision == Precision::Bf16 && !supported {
        bail!(
            "train.precision = \"bf16\" is not supported by model.architecture = {:?}: its gradient is not \
             faithful in bf16 (tests/it/precision.rs); use \"fp32\"",
            model.architecture.0
        );
    }
    Ok(())
}

/// Checks that every weighted loss has a head in the architecture (the Contextual-LSTM has only the action head).
pub fn check_heads(model: &ModelConfig, train: &TrainConfig) -> Result<()> {
    let heads = model.architecture.registration().is_none_or(|r| r.auxiliary_heads);
    if !heads && (train.loss.inverse != 0.0 || train.loss.point != 0.0) {
        bail!(
            "model.architecture = {:?} has no inverse-dynamics or point head: \
             set train.loss.inverse and train.loss.point to 0",
            model.architecture.0
        );
    }
    let has_pose = model.architecture.registration().is_some_and(|r| r.pose_head) || model.pose_head;
    if !has_pose && train.loss.pose != 1.0 {
        bail!(
            "train.loss.pose = {} weights a head model.architecture = {:?} lacks: set model.pose_head = true",
            train.loss.pose,
            model.architecture.0
        );
    }
    if !has_pose && train.pose_frames != PoseFrames::Window {
        bail!(
            "train.pose_frames = \"first\" chooses the frames of a pose head the model lacks: set model.pose_head = true"
        );
    }
    if train.pose_frames == PoseFrames::First && train.window_start == 0.0 {
        bail!(
            "train.pose_frames = \"first\" scores windows at their trajectory's start: train.window_start = 0 draws none"
        );
    }
    if !model.task_head && train.loss.task != 1.0 {
        bail!("train.loss.task = {} weights a head the model lacks: set model.task_head = true", train.loss.task);
    }
    Ok(())
}
