//! Training the policy: Adam on BC + inverse-dynamics + point losses, validation at fixed intervals,
//! checkpoints with resume, and a loss curve.
pub mod adam;
pub mod checkpoint;
pub mod config;
pub mod curve;
pub mod heartbeat;
pub mod pretrain;
pub mod stop;
pub mod tensorboard;
pub mod throughput;

use crate::data::loader::{AugmentAt, Batch, PrefetchSpec, Prefetcher, build_batch};
use crate::data::pairs::{PairDataset, Split};
use crate::model::architectures::transformer::SELECTION_TRUNK;
use crate::model::batch::DeviceBatch;
use crate::model::config::{ModelConfig, ObjectAttentionInput};
use crate::model::policy::{Losses, Policy};
use crate::seeds::derive_seed;
use crate::sim::env::{STATE_VERSION, WorldConfig};
use adam::Adam;
use anyhow::{Context, Result, bail};
use config::{LossWeights, TrainConfig};
use curve::CurvePoint;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use tch::nn;
use tch::{Kind, Tensor};

/// File names inside a training folder.
pub const FINAL_WEIGHTS: &str = "model.safetensors";
pub const FINAL_INFO: &str = "model.json";
pub const CURVE_FILE: &str = "curve.jsonl";
pub const CHECKPOINT_DIR: &str = "checkpoints";

/// What a finished training run reports (also written to `model.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainSummary {
    pub model: ModelConfig,
    pub train: TrainConfig,
    /// The world the training data was recorded in (frame size, camera, control, experts) and the JPEG quality
    /// of its frames: evaluation runs the policy in this world and encodes its frames alike.
    pub world: WorldConfig,
    pub jpeg_quality: u8,
    pub steps: u64,
    pub resumed_from: Option<u64>,
    pub first_val_bc: f64,
    pub final_val_bc: f64,
    pub seconds: f64,
    pub parameters: i64,
    /// How the robot's state was encoded ([`STATE_VERSION`]), for a network that reads it; absent in trainings
    /// written before it was recorded, which cannot be checked.
    #[serde(default)]
    pub state_version: Option<u32>,
}

impl TrainSummary {
    /// The summary of a network saved without training (benchmarks and tests of the inference path).
    pub fn untrained(model: ModelConfig, world: WorldConfig, jpeg_quality: u8) -> TrainSummary {
        TrainSummary {
            model,
            train: TrainConfig::default(),
            world,
            jpeg_quality,
            steps: 0,
            resumed_from: None,
            first_val_bc: 0.0,
            final_val_bc: 0.0,
            seconds: 0.0,
            parameters: 0,
            state_version: Some(STATE_VERSION),
        }
    }
}

/// Builds a policy with fresh weights (and the optional pretrained trunk) on `device`.
pub fn build_policy(model: &ModelConfig, device: tch::Device) -> Result<(nn::VarStore, Policy)> {
    model.validate()?;
    let mut vs = nn::VarStore::new(device);
    let policy = Policy::new(&vs.root(), model);
    if let Some(path) = &model.pretrained_backbone {
        checkpoint::load_backbone(&mut vs, Path::new(path)).context("model.pretrained_backbone")?;
        if model.object_attention && model.object_attention_input == ObjectAttentionInput::FrozenTrunk {
            checkpoint::load_under(&mut vs, Path::new(path), &format!("{SELECTION_TRUNK}."))?;
        }
    }
    if let Some(path) = &model.pretrained_object_attention
        && checkpoint::load_under(&mut vs, Path::new(path), "")? == 0
    {
        bail!("{path} holds no weight of this model's object attention (model.object_attention = true?)");
    }
    let frozen = |name: &str| {
        (model.freeze_backbone && name.starts_with("backbone.")) || name.starts_with(&format!("{SELECTION_TRUNK}."))
    };
    for (_, var) in vs.variables().into_iter().filter(|(name, _)| frozen(name)) {
        let _ = var.set_requires_grad(false);
    }
    Ok((vs, policy))
}

/// Checks that `model`'s network has the trunk a pretrain stage trains (a ResNet-18 of `model.backbone_width`
/// and `model.backbone_stages` under `backbone.`), so that every pretrained tensor finds its place.
pub fn check_pretrained_trunk(model: &ModelConfig) -> Result<()> {
    model.validate()?;
    let (policy_vars, _) = build_policy(model, tch::Device::Cpu)?;
    let trunk_vars = nn::VarStore::new(tch::Device::Cpu);
    crate::model::resnet::ResNet18::new(&(trunk_vars.root() / "backbone"), model.backbone_width, model.backbone_stages);
    let policy = policy_vars.variables();
    for (name, t) in trunk_vars.variables() {
        if policy.get(&name).map(|p| p.size()) != Some(t.size()) {
            bail!(
                "model.architecture = {:?} has no ResNet-18 trunk of width {} with {} stages to start from (`{name}`)",
                model.architecture.0,
                model.backbone_width,
                model.backbone_stages
            );
        }
    }
    Ok(())
}

/// A trained policy ready for inference.
pub struct TrainedPolicy {
    pub vars: nn::VarStore,
    pub policy: Policy,
    pub summary: TrainSummary,
}

/// Loads a finished training folder onto `device`: its final weights, or those of the checkpoint at `step`.
pub fn load_trained(dir: &Path, step: Option<u64>, device: tch::Device) -> Result<TrainedPolicy> {
    let info = dir.join(FINAL_INFO);
    let text = std::fs::read_to_string(&info)
        .with_context(|| format!("reading {} (is {} a finished training folder?)", info.display(), dir.display()))?;
    let summary: TrainSummary = serde_json::from_str(&text).with_context(|| {
        format!("parsing {} (a model trained by an older version records no world: train it again)", info.display())
    })?;
    if let Some(version) = summary.state_version
        && summary.model.concat_state
        && version != STATE_VERSION
    {
        bail!(
            "{} was trained on the robot's state encoded as version {version}, and this build encodes it as version \
             {STATE_VERSION}: the network would read other inputs than it learnt from; train it again",
            info.display()
        );
    }
    let model = ModelConfig { pretrained_backbone: None, ..summary.model.clone() };
    let (mut vars, policy) = build_policy(&model, device)?;
    let weights = match step {
        None => dir.join(FINAL_WEIGHTS),
        Some(s) => {
            let path = checkpoint::path_for(&dir.join(CHECKPOINT_DIR), s);
            if !path.exists() {
                bail!(
                    "{} has no checkpoint at step {s} (checkpoints every {} steps of {})",
                    dir.display(),
                    summary.train.checkpoint_interval,
                    summary.steps
                );
            }
            path
        }
    };
    checkpoint::load(&mut vars, &weights)?;
    Ok(TrainedPolicy { vars, policy, summary })
}

fn mean_losses(policy: &Policy, batches: &[DeviceBatch], w: &LossWeights, step: u64) -> CurvePoint {
    let n = batches.len() as f64;
    let (mut bc, mut inv, mut pnt, mut task, mut total) = (0.0, 0.0, 0.0, 0.0, 0.0);
    tch::no_grad(|| {
        for b in batches {
            let l = policy.losses(b, false);
            bc += l.bc.double_value(&[]) / n;
            inv += l.inverse.double_value(&[]) / n;
            pnt += l.point.double_value(&[]) / n;
            task += l.task.double_value(&[]) / n;
            total += w.total(&l).double_value(&[]) / n;
        }
    });
    CurvePoint { step, split: "val".into(), bc, inverse: inv, point: pnt, task, total }
}

/// Options of a training run that are not part of its identity.
pub struct TrainRun<'a> {
    pub demo_dir: &'a Path,
    pub agent_dir: &'a Path,
    /// Train on the first this many slots of each task of both collections (none: all of them).
    pub per_task: Option<usize>,
    pub out: &'a Path,
    pub progress: bool,
}

/// Trains into `run.out`, resuming from its latest checkpoint if there is one.
pub fn train(model: &ModelConfig, config: &TrainConfig, run: &TrainRun) -> Result<TrainSummary> {
    model.validate()?;
    config.validate()?;
    config::check_heads(model, config)?;
    config::check_precision(model, config)?;
    if model.freeze_backbone && model.pretrained_backbone.is_none() {
        bail!("model.freeze_backbone = true needs model.pretrained_backbone (a frozen random trunk learns nothing)");
    }
    if model.object_attention_input == ObjectAttentionInput::FrozenTrunk && model.pretrained_backbone.is_none() {
        bail!(
            "model.object_attention_input = \"frozen_trunk\" needs model.pretrained_backbone (a frozen random trunk \
             finds nothing)"
        );
    }
    let device = config.device()?;
    crate::device::autotune_convolutions(device);
    let data = Arc::new(PairDataset::open(run.demo_dir, run.agent_dir, config.val_fraction, run.per_task)?);
    data.check_fits(model)?;
    let ckpt_dir = run.out.join(CHECKPOINT_DIR);
    std::fs::create_dir_all(&ckpt_dir).with_context(|| format!("creating {}", ckpt_dir.display()))?;

    tch::manual_seed(derive_seed("init", &[config.seed]) as i64);
    let (mut vs, mut policy) = build_policy(model, device)?;
    policy.set_channels_last(config.memory_format == config::MemoryFormat::ChannelsLast);
    let mut opt = Adam::new(&vs, config.lr);
    let _stop = stop::StopGuard::new();
    let resumed = checkpoint::latest(&ckpt_dir)?;
    let start = match &resumed {
        Some((step, path)) => {
            checkpoint::load(&mut vs, path)?;
            opt.load(&checkpoint::optimizer_path(path))?;
            *step
        }
        None => 0,
    };
    let curve_path = run.out.join(CURVE_FILE);
    let mut curve = curve::resumed(&curve_path, start)?;
    let (h, w) = (data.height, data.width);
    let augment_at = match config.augment_on {
        config::AugmentOn::Host => AugmentAt::Host,
        config::AugmentOn::Device => AugmentAt::Device(device),
    };
    let val: Vec<DeviceBatch> = (0..config.val_batches)
        .map(|k| {
            build_batch(&data, Split::Val, model, config.batch_size, config.seed, k, config.windows(), None, augment_at)
                .map(|b| config.targets(b).to_device(model, h, w, device))
        })
        .collect::<Result<_>>()?;

    let clock = std::time::Instant::now();
    if start == 0 {
        curve.push(mean_losses(&policy, &val, &config.loss, 0));
        curve::write(&curve_path, &curve)?;
        tensorboard::write(&run.out.join(tensorboard::EVENTS_FILE), &curve)?;
    }
    let spec = PrefetchSpec {
        model: model.clone(),
        batch_size: config.batch_size,
        seed: config.seed,
        start,
        windows: config.windows(),
        augment: config.augment.then(|| config.augmentation.clone()),
        depth: config.prefetch,
        augment_at,
    };
    let mut loader = Prefetcher::start(data.clone(), spec);
    let bar = crate::progress::progress_bar(config.steps, run.progress, "train");
    bar.set_position(start);
    let heartbeat_path = run.out.join(heartbeat::HEARTBEAT_FILE);
    let mut beater = heartbeat::Beater::new(heartbeat::HEARTBEAT_EVERY);
    let mut window = TrainWindow::default();
    for step in start + 1..=config.steps {
        // Dropout draws depend on the step alone, so a resumed run repeats the uninterrupted one exactly.
        tch::manual_seed(derive_seed("dropout", &[config.seed, step]) as i64);
        opt.set_lr(config.lr_at(step));
        let batch: Batch = loader.next_batch()?;
        let batch = config.targets(batch).to_device(model, h, w, device);
        let l = {
            let _precision = config.precision.scope(device);
            policy.losses(&batch, true)
        };
        let total = config.loss.total(&l);
        let [bc, inverse, point, task, sum] = window.add(&l, &total);
        if ![bc, inverse, point, task, sum].iter().all(|v| v.is_finite()) {
            bail!(
                "training step {step}: the loss is not finite (total {sum}; bc {bc}, inverse {inverse}, point \
                 {point}, task {task}); stopped before its optimiser step"
            );
        }
        opt.backward_step(&total);
        if step % config.val_interval == 0 || step == config.steps {
            curve.push(window.take(step));
            let v = mean_losses(&policy, &val, &config.loss, step);
            bar.set_message(format!("train bc {:.3} val bc {:.3}", curve.last().map_or(0.0, |p| p.bc), v.bc));
            curve.push(v);
            curve::write(&curve_path, &curve)?;
            tensorboard::write(&run.out.join(tensorboard::EVENTS_FILE), &curve)?;
        }
        let stop = stop::requested();
        if step % config.checkpoint_interval == 0 || step == config.steps || stop.is_some() {
            let path = checkpoint::path_for(&ckpt_dir, step);
            opt.save(&checkpoint::optimizer_path(&path))?;
            checkpoint::save(&vs, &path)?;
        }
        if let Some(signal) = stop {
            bail!(
                "stopped by {signal} at step {step} of {}: checkpoint written, the next run resumes from it",
                config.steps
            );
        }
        beater.tick(&heartbeat_path, step);
        bar.inc(1);
    }
    bar.finish_and_clear();
    drop(loader);
    heartbeat::remove(&heartbeat_path)?;
    checkpoint::save(&vs, &run.out.join(FINAL_WEIGHTS))?;
    let vals: Vec<f64> = curve.iter().filter(|p| p.split == "val").map(|p| p.bc).collect();
    let summary = TrainSummary {
        model: model.clone(),
        train: config.clone(),
        world: data.world.clone(),
        jpeg_quality: data.jpeg_quality,
        steps: config.steps,
        resumed_from: resumed.map(|(s, _)| s),
        first_val_bc: vals.first().copied().unwrap_or(f64::NAN),
        final_val_bc: vals.last().copied().unwrap_or(f64::NAN),
        seconds: clock.elapsed().as_secs_f64(),
        parameters: vs.trainable_variables().iter().map(|t| t.numel() as i64).sum(),
        state_version: Some(STATE_VERSION),
    };
    let info = run.out.join(FINAL_INFO);
    std::fs::write(&info, serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("writing {}", info.display()))?;
    Ok(summary)
}

/// Training losses accumulated between curve points.
#[derive(Default)]
struct TrainWindow {
    n: f64,
    sums: [f64; 5],
}

impl TrainWindow {
    /// Adds one step's losses (bc, inverse, point, task, total) and returns them.
    fn add(&mut self, l: &Losses, total: &Tensor) -> [f64; 5] {
        let v =
            [&l.bc, &l.inverse, &l.point, &l.task, total].map(|t| t.detach().to_kind(Kind::Double).double_value(&[]));
        for (s, x) in self.sums.iter_mut().zip(v) {
            *s += x;
        }
        self.n += 1.0;
        v
    }

    fn take(&mut self, step: u64) -> CurvePoint {
        let n = self.n.max(1.0);
        let [bc, inverse, point, task, total] = self.sums.map(|s| s / n);
        *self = TrainWindow::default();
        CurvePoint { step, split: "train".into(), bc, inverse, point, task, total }
    }
}
