//! Trunk pretraining, and the localisation check it is made of: can the policy's image trunk find the object at
//! all at a given frame size? A ResNet-18
//! trunk (the policy's widths), spatial softmax and a small MLP are trained to regress positions from each agent
//! trajectory's first frame, where the arm is still at its start pose and only the picture says where the objects
//! lie, and scored on held-out layouts against predicting the mean. Two targets separate two skills: the grasp
//! position of the trajectory's task, told the task (finding *the demonstrated* object, what a policy must do),
//! and the positions of all four objects, told nothing (finding objects at all). It measures the data and the
//! trunk, not the policy: a frame size at which this fails cannot support a policy that succeeds.
use crate::data::augment::{AugmentDraw, Augmentation};
use crate::data::manifest::{Manifest, ManifestEntry};
use crate::data::trajectory::Trajectory;
use crate::model::heads::{ObjectAttention, spatial_softmax};
use crate::model::resnet::ResNet18;
use crate::sim::task::NUM_TASKS;
use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use tch::nn::{self, Module, ModuleT, OptimizerConfig};
use tch::{Device, Kind, Tensor};

/// What the check regresses from a first frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LocaliseTarget {
    /// The grasp position of the trajectory's task, with the task as a one-hot input.
    Grasp,
    /// The x, y of each of the four objects, without the task.
    Objects,
}

/// The trunk and its training.
#[derive(Debug, Clone, PartialEq)]
pub struct LocaliseConfig {
    pub backbone_width: i64,
    pub backbone_stages: usize,
    pub steps: u64,
    pub batch: i64,
    pub lr: f64,
    /// Only the first this many slots of each task are used (none: every trajectory of the collection).
    pub per_task: Option<usize>,
    /// Every this many trajectories (or, where layouts are shared, environments), one is held out (5: a fifth).
    pub hold_out_every: usize,
    /// Errors are measured every this many steps.
    pub report_every: u64,
    pub seed: u64,
    pub target: LocaliseTarget,
    /// Training frames are augmented with these ranges (the policy's `train.augmentation`), or not at all.
    pub augmentation: Option<Augmentation>,
    /// Where to write the trained trunk's weights (torchvision names, as `model.pretrained_backbone` reads them).
    pub trunk_out: Option<PathBuf>,
    /// For `Grasp`: the head also reads where attention from the task over the trunk's feature map lands (the
    /// policy's `model.object_attention`, with the task's one-hot as the query's input).
    pub object_attention: bool,
    /// Start the trunk from these weights (a saved trunk, torchvision names) rather than from scratch.
    pub init_trunk: Option<PathBuf>,
    /// The object attention's heads and inner width.
    pub attention_shape: (i64, i64),
    /// Where to write the trained object attention's weights (the policy's `object_attention.*` names).
    pub attention_out: Option<PathBuf>,
    /// Where to keep the curve as it is measured (JSON lines, rewritten at each measurement), so that a running
    /// pretraining shows how far it is.
    pub curve_out: Option<PathBuf>,
}

/// Heads and inner width of the check's object attention (`localise --object-attention`).
pub const ATTENTION_SHAPE: (i64, i64) = (4, 64);

/// The `[pretrain]` section of an experiment: a stage that trains the policy's image trunk on this check's
/// regression over the agent collection's first frames, then starts the policy from it in place of
/// `model.pretrained_backbone`. A departure: the authors start from ImageNet weights (the section absent).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PretrainConfig {
    /// What the trunk regresses from a first frame: the four objects' positions (`objects`) or the task's grasp
    /// position (`grasp`).
    pub target: LocaliseTarget,
    /// Optimiser steps.
    pub steps: u64,
    /// Frames per step.
    pub batch: i64,
    /// Adam's learning rate.
    pub lr: f64,
    /// Training frames are augmented with these ranges; absent, not at all.
    pub augmentation: Option<Augmentation>,
    /// After `steps`, this many more steps train the trunk to find the object the task names, through an object
    /// attention queried with the task's one-hot (`localise --object-attention`), saved for a policy whose
    /// `model.object_attention_query = "task_head"` asks with the task head's prediction. 0: none.
    pub object_attention_steps: u64,
}

impl Default for PretrainConfig {
    /// The trunk of the learning recipe (docs/research/recipe.md); the `localise` command's defaults too.
    fn default() -> Self {
        PretrainConfig {
            target: LocaliseTarget::Objects,
            steps: 2000,
            batch: 32,
            lr: 1e-3,
            augmentation: None,
            object_attention_steps: 0,
        }
    }
}

impl PretrainConfig {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if self.steps == 0 || self.batch < 1 || !(self.lr.is_finite() && self.lr > 0.0) {
            bail!("pretrain.steps and pretrain.batch must be at least 1 and pretrain.lr positive: {self:?}");
        }
        if let Some(a) = &self.augmentation {
            a.validate().context("pretrain.augmentation")?;
        }
        Ok(())
    }

    /// The check's settings for a trunk of `backbone_width` and `backbone_stages` on the first `per_task` slots
    /// of each task (none: all), seeded by `seed`, saved to `trunk_out` if given (a fifth of the layouts held out, errors
    /// measured ten times).
    pub fn localise(
        &self,
        (backbone_width, backbone_stages): (i64, usize),
        per_task: Option<usize>,
        seed: u64,
        trunk_out: Option<PathBuf>,
    ) -> LocaliseConfig {
        LocaliseConfig {
            backbone_width,
            backbone_stages,
            per_task,
            steps: self.steps,
            batch: self.batch,
            lr: self.lr,
            hold_out_every: 5,
            report_every: (self.steps / 10).max(1),
            seed,
            target: self.target,
            augmentation: self.augmentation.clone(),
            trunk_out,
            object_attention: false,
            init_trunk: None,
            attention_shape: ATTENTION_SHAPE,
            attention_out: None,
            curve_out: None,
        }
    }

    /// The second phase's settings (`object_attention_steps`): the grasp target through an object attention of
    /// `attention_shape`, the trunk starting from and saved back to `trunk`, the attention saved to
    /// `attention_out`. None without that phase.
    pub fn attention_phase(
        &self,
        first: &LocaliseConfig,
        attention_shape: (i64, i64),
        trunk: PathBuf,
        attention_out: PathBuf,
    ) -> Option<LocaliseConfig> {
        (self.object_attention_steps > 0).then(|| LocaliseConfig {
            steps: self.object_attention_steps,
            report_every: (self.object_attention_steps / 10).max(1),
            target: LocaliseTarget::Grasp,
            object_attention: true,
            init_trunk: Some(trunk.clone()),
            trunk_out: Some(trunk),
            attention_shape,
            attention_out: Some(attention_out),
            curve_out: None,
            ..first.clone()
        })
    }
}

/// Mean absolute errors of the target positions (x, y, in metres, averaged over objects) at one step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LocaliseErrors {
    pub step: u64,
    pub train: [f64; 2],
    pub held_out: [f64; 2],
}

/// What a localisation run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct LocaliseReport {
    pub train_frames: usize,
    pub held_out_frames: usize,
    pub height: usize,
    pub width: usize,
    /// Predicting the training frames' mean target on the held-out frames (for `Grasp`, each task's mean).
    pub mean_baseline: [f64; 2],
    pub curve: Vec<LocaliseErrors>,
}

/// First frames (normalised, `[N, 3, H, W]`, and as stored RGB bytes for augmentation), task one-hots `[N, 16]`
/// and targets `[N, 2k]` (x, y of k points) of a collection.
struct FirstFrames {
    frames: Tensor,
    rgb: Vec<Vec<u8>>,
    tasks: Tensor,
    targets: Tensor,
}

/// The x, y positions `target` names in trajectory `t` at its first frame.
fn target_positions(t: &Trajectory, target: LocaliseTarget) -> Vec<f32> {
    match target {
        LocaliseTarget::Grasp => t.grasp_and_drop()[..2].to_vec(),
        LocaliseTarget::Objects => t.object_poses[0].iter().flat_map(|pose| [pose[0], pose[1]]).collect(),
    }
}

fn first_frames(
    dir: &Path,
    target: LocaliseTarget,
    per_task: Option<usize>,
    pick: impl Fn(usize, &ManifestEntry) -> bool,
) -> Result<(FirstFrames, usize, usize)> {
    let manifest = Manifest::load(dir)?;
    let (mut frames, mut rgb, mut tasks, mut targets, mut size) = (vec![], vec![], vec![], vec![], (0, 0));
    let used = manifest.trajectories.iter().filter(|e| per_task.is_none_or(|n| e.index < n));
    for (_, entry) in used.enumerate().filter(|(i, e)| pick(*i, e)) {
        let t = Trajectory::from_bytes(&entry.read_verified(dir)?)?;
        let (h, w) = (t.meta.height, t.meta.width);
        size = (h, w);
        let first = t.frame_rgb(0)?;
        frames.push(normalised(&first, AugmentDraw::identity(h, w), h, w));
        rgb.push(first);
        let mut onehot = [0f32; NUM_TASKS];
        onehot[t.meta.task] = 1.0;
        tasks.push(Tensor::from_slice(&onehot));
        targets.push(Tensor::from_slice(&target_positions(&t, target)));
    }
    if frames.is_empty() {
        bail!("{} holds no trajectories for this split", dir.display());
    }
    let set = FirstFrames {
        frames: Tensor::stack(&frames, 0),
        rgb,
        tasks: Tensor::stack(&tasks, 0),
        targets: Tensor::stack(&targets, 0),
    };
    Ok((set, size.0, size.1))
}

/// `rgb` under `draw`, normalised, as a `[3, H, W]` tensor.
fn normalised(rgb: &[u8], draw: AugmentDraw, h: usize, w: usize) -> Tensor {
    let mut out = vec![0f32; 3 * h * w];
    draw.apply(rgb, h, w, &mut out);
    Tensor::from_slice(&out).view([3, h as i64, w as i64])
}

/// Mean absolute x and y errors over frames and points of predictions `[N, 2k]`.
fn errors(pred: &Tensor, truth: &Tensor) -> [f64; 2] {
    let e = (pred - truth).abs().view([-1, 2]).mean_dim([0i64].as_slice(), false, Kind::Double);
    [e.double_value(&[0]), e.double_value(&[1])]
}

/// Trains the check on the agent collection `dir` and reports its errors over training.
pub fn localise(dir: &Path, config: &LocaliseConfig, device: Device) -> Result<LocaliseReport> {
    if config.hold_out_every < 2 || config.batch < 1 || config.steps == 0 || config.report_every == 0 {
        bail!("localise: hold_out_every must be at least 2, batch, steps and report_every at least 1");
    }
    if config.object_attention && config.target != LocaliseTarget::Grasp {
        bail!("localise: object attention needs the grasp target, which tells the head the task");
    }
    let every = config.hold_out_every;
    // Held out by layout: a shared layout's trajectories under other tasks are held out with it.
    let held = |i: usize, e: &ManifestEntry| e.environment.unwrap_or(i as u64).is_multiple_of(every as u64);
    let (train, height, width) = first_frames(dir, config.target, config.per_task, |i, e| !held(i, e))?;
    let (held_out, _, _) = first_frames(dir, config.target, config.per_task, held)?;
    // The targets are standardised by the training frames' statistics, as a regression head would want.
    let mean = train.targets.mean_dim([0i64].as_slice(), true, Kind::Float);
    let scale = train.targets.std_dim([0i64].as_slice(), false, true).clamp_min(1e-3);
    let told_task = config.target == LocaliseTarget::Grasp;
    let mean_baseline = if told_task {
        // Per-task means: what a policy that knows the task but not the layout would predict.
        let counts = train.tasks.sum_dim_intlist([0i64].as_slice(), false, Kind::Float).clamp_min(1.0).unsqueeze(1);
        let task_means = train.tasks.transpose(0, 1).matmul(&train.targets) / counts;
        errors(&held_out.tasks.matmul(&task_means), &held_out.targets)
    } else {
        errors(&mean.expand_as(&held_out.targets), &held_out.targets)
    };

    tch::manual_seed(crate::seeds::derive_seed("localise", &[config.seed]) as i64);
    let mut vs = nn::VarStore::new(device);
    let root = vs.root();
    let trunk = ResNet18::new(&(&root / "backbone"), config.backbone_width, config.backbone_stages);
    let channels = trunk.out_channels();
    let attention = config.object_attention.then(|| {
        ObjectAttention::new(
            &(&root / "object_attention"),
            NUM_TASKS as i64,
            channels,
            config.attention_shape.0,
            config.attention_shape.1,
        )
    });
    let features = 2 * channels
        + if told_task { NUM_TASKS as i64 } else { 0 }
        + attention.as_ref().map_or(0, ObjectAttention::width);
    let hidden = nn::linear(&root / "hidden", features, 64, Default::default());
    let out = nn::linear(&root / "out", 64, train.targets.size()[1], Default::default());
    if let Some(path) = &config.init_trunk {
        crate::train::checkpoint::load_backbone(&mut vs, path)?;
    }
    let forward = |frames: &Tensor, tasks: &Tensor, train: bool| {
        let feats = trunk.forward_t(&frames.to_device(device), train);
        let tasks = tasks.to_device(device);
        let mut x = vec![spatial_softmax(&feats)];
        if told_task {
            x.push(tasks.shallow_clone());
        }
        if let Some(a) = &attention {
            x.push(a.forward(&tasks, &feats.unsqueeze(1)).squeeze_dim(1));
        }
        let x = Tensor::cat(&x, 1);
        out.forward(&hidden.forward(&x).relu()).to_device(Device::Cpu) * &scale + &mean
    };
    let score = |set: &FirstFrames| {
        let n = set.frames.size()[0].min(256);
        let pred = tch::no_grad(|| forward(&set.frames.narrow(0, 0, n), &set.tasks.narrow(0, 0, n), false));
        errors(&pred, &set.targets.narrow(0, 0, n))
    };
    let mut opt = nn::Adam::default().build(&vs, config.lr)?;
    let mut rng = ChaCha8Rng::seed_from_u64(crate::seeds::derive_seed("localise-augment", &[config.seed]));
    let n = train.frames.size()[0];
    let mut curve = vec![];
    for step in 0..=config.steps {
        if step % config.report_every == 0 || step == config.steps {
            curve.push(LocaliseErrors { step, train: score(&train), held_out: score(&held_out) });
            if let Some(path) = &config.curve_out {
                crate::fsio::write_json_lines(path, &curve)?;
            }
        }
        if step == config.steps {
            break;
        }
        let idx = Tensor::randint(n, [config.batch], (Kind::Int64, Device::Cpu));
        let frames = match &config.augmentation {
            None => train.frames.index_select(0, &idx),
            Some(ranges) => {
                let picked: Vec<Tensor> = Vec::<i64>::try_from(&idx)?
                    .into_iter()
                    .map(|i| {
                        normalised(
                            &train.rgb[i as usize],
                            AugmentDraw::sample(&mut rng, ranges, height, width),
                            height,
                            width,
                        )
                    })
                    .collect();
                Tensor::stack(&picked, 0)
            }
        };
        let pred = forward(&frames, &train.tasks.index_select(0, &idx), true);
        let target = train.targets.index_select(0, &idx);
        let loss = ((pred - target) / &scale).square().mean(Kind::Float);
        opt.backward_step(&loss);
    }
    if let Some(path) = &config.trunk_out {
        save_variables(&vs, "backbone.", false, path)?;
    }
    if let Some(path) = &config.attention_out {
        save_variables(&vs, "object_attention.", true, path)?;
    }
    Ok(LocaliseReport {
        train_frames: n as usize,
        held_out_frames: held_out.frames.size()[0] as usize,
        height,
        width,
        mean_baseline,
        curve,
    })
}

/// The curve a localisation run kept at `path` (`LocaliseConfig::curve_out`).
pub fn read_curve(path: &Path) -> Result<Vec<LocaliseErrors>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .map(|(i, line)| serde_json::from_str(line).with_context(|| format!("{}:{}", path.display(), i + 1)))
        .collect()
}

/// Writes the variables of `vs` whose names start with `prefix` to `path`, the prefix kept or dropped (the trunk's
/// are written under their torchvision names, `backbone.` dropped).
fn save_variables(vs: &nn::VarStore, prefix: &str, keep_prefix: bool, path: &Path) -> Result<()> {
    let strip = if keep_prefix { 0 } else { prefix.len() };
    let named: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .filter(|(name, _)| name.starts_with(prefix))
        .map(|(name, t)| (name[strip..].to_string(), t.to_device(Device::Cpu)))
        .collect();
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    crate::fsio::write_with(path, |tmp| Ok(Tensor::write_safetensors(&named, tmp)?))
}
