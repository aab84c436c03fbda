//! The train stage: a policy trained on a demonstrator and an agent collection.
use super::{MetricName, RunContext, StageOutputs, Upstream};
use crate::config::CellConfig;
use crate::model::config::ModelConfig;
use crate::pipeline::graph::Plan;
use crate::pipeline::key::omit_when;
use crate::sim::env::STATE_VERSION;
use crate::train::config::{AUTHORS_WINDOW_START, TrainConfig};
use crate::train::{CURVE_FILE, TrainRun, curve, train};
use anyhow::Result;
use serde_json::{Value, json};
use std::path::Path;

/// Implementation version of training (part of every train key).
pub const VERSION: u32 = 4;

/// What a train stage runs: the network and training settings, the keys of the two collections, how many
/// slots per task it uses of them (none: all), and the pretrain stage whose trunk it starts from (if any).
#[derive(Debug, Clone, PartialEq)]
pub struct TrainJob {
    pub model: ModelConfig,
    pub train: TrainConfig,
    pub demos: String,
    pub agents: String,
    pub per_task: Option<usize>,
    pub trunk: Option<String>,
}

/// Training settings that do not change results (where it runs, how far ahead batches are made, the tensor
/// layout, where frames are augmented) are left out of keys, so that moving a run to another machine reuses the
/// cache.
fn identity(t: &TrainConfig) -> TrainConfig {
    TrainConfig {
        device: "auto".into(),
        prefetch: 0,
        memory_format: Default::default(),
        augment_on: Default::default(),
        ..t.clone()
    }
}

/// Settings added after train keys existed, left out of them at their earlier value.
fn neutral() -> [(&'static str, Value); 16] {
    [
        ("model.freeze_backbone", json!(false)),
        ("model.concat_state", json!(false)),
        ("model.finger_motion", json!(false)),
        ("model.pose_head", json!(false)),
        ("model.task_head", json!(false)),
        ("model.object_attention", json!(false)),
        ("model.object_attention_input", json!("mixed")),
        ("model.object_attention_query", json!("embedding")),
        ("model.pose_head_input", json!("joint")),
        ("train.loss.pose", json!(1.0)),
        ("train.loss.task", json!(1.0)),
        ("train.augment_on", json!("host")),
        ("train.precision", json!("fp32")),
        ("train.window_start", json!(AUTHORS_WINDOW_START)),
        ("train.action_resolution", json!(0)),
        ("train.pose_frames", json!("window")),
    ]
}

/// What a training's key is made of besides its upstream stages: the model and the training settings that
/// change results, and how the robot's state is encoded where the network reads it.
fn key_inputs(cell: &CellConfig) -> Value {
    let mut inputs = json!({ "model": cell.model, "train": identity(&cell.train) });
    omit_when(&mut inputs, &neutral());
    if cell.model.concat_state {
        inputs["state_version"] = STATE_VERSION.into();
    }
    inputs
}

/// Adds a cell's training on the collections `demos` and `agents` (their first `per_task` slots of each task, if
/// given: then the key says so), starting from the trunk of pretrain stage `trunk` if given (an upstream of the
/// key); returns its key.
pub fn add(
    plan: &mut Plan,
    cell: &CellConfig,
    demos: &str,
    agents: &str,
    per_task: Option<usize>,
    trunk: Option<&str>,
) -> String {
    let mut inputs = key_inputs(cell);
    if let Some(n) = per_task {
        inputs["per_task"] = n.into();
    }
    // The weights file is an input by its content, not its name or where it lies: replacing it retrains, moving
    // it (or the experiment file that names it) does not.
    if let Some(path) = &cell.model.pretrained_backbone {
        inputs["pretrained_backbone_blake3"] = file_digest(Path::new(path)).into();
        if let Some(model) = inputs["model"].as_object_mut() {
            model.remove("pretrained_backbone");
        }
    }
    let job = TrainJob {
        model: cell.model.clone(),
        train: cell.train.clone(),
        demos: demos.into(),
        agents: agents.into(),
        per_task,
        trunk: trunk.map(str::to_string),
    };
    let upstream = [demos, agents].into_iter().chain(trunk).map(str::to_string).collect();
    plan.add(inputs, upstream, super::Job::Train(Box::new(job)))
}

/// The blake3 digest of a file's bytes in hex (`unreadable` when it cannot be read: configuration checks refuse a
/// missing file before planning).
fn file_digest(path: &Path) -> String {
    std::fs::read(path).map_or_else(|_| "unreadable".into(), |bytes| blake3::hash(&bytes).to_hex().to_string())
}

/// Trains into `staging`, resuming from the checkpoints an interrupted attempt left there.
pub fn run(job: &TrainJob, upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
    let config = TrainConfig { device: ctx.device_or(&job.train.device), ..job.train.clone() };
    let model = match &job.trunk {
        Some(key) => ModelConfig {
            pretrained_backbone: Some(super::pretrain::trunk_of(upstream, key)?.to_string_lossy().into_owned()),
            pretrained_object_attention: super::pretrain::attention_of(upstream, key)?
                .map(|p| p.to_string_lossy().into_owned()),
            ..job.model.clone()
        },
        None => job.model.clone(),
    };
    let run = TrainRun {
        demo_dir: upstream.get(&job.demos)?,
        agent_dir: upstream.get(&job.agents)?,
        per_task: job.per_task,
        out: staging,
        progress: ctx.progress,
    };
    let summary = train(&model, &config, &run)?;
    Ok(StageOutputs {
        metrics: vec![
            (MetricName::FirstValBc, summary.first_val_bc),
            (MetricName::FinalValBc, summary.final_val_bc),
            (MetricName::TrainSeconds, summary.seconds),
            (MetricName::Parameters, summary.parameters as f64),
        ],
        curve: curve::read(&staging.join(CURVE_FILE), summary.steps)?,
        ..StageOutputs::default()
    })
}
