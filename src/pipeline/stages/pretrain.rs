//! The pretrain stage: the policy's image trunk trained to find objects in an agent collection's first frames
//! (the localisation check's regression), saved for the train stage to start from.
use super::{MetricName, RunContext, StageOutputs, Upstream};
use crate::config::CellConfig;
use crate::pipeline::graph::Plan;
use crate::pipeline::key::omit_when;
use crate::train::pretrain::{LocaliseConfig, PretrainConfig, localise};
use anyhow::Result;
use std::path::{Path, PathBuf};

/// Implementation version of trunk pretraining (part of every pretrain key).
pub const VERSION: u32 = 2;

/// The trunk's weights in a pretrain artifact (torchvision names, as `model.pretrained_backbone` reads them).
pub const TRUNK_FILE: &str = "trunk.safetensors";

/// The object attention's weights in a pretrain artifact whose `object_attention_steps` trained one.
pub const ATTENTION_FILE: &str = "object_attention.safetensors";

/// The trunk phase's held-out errors over its steps (JSON lines of `LocaliseErrors`), kept as they are measured.
pub const TRUNK_CURVE_FILE: &str = "trunk_curve.jsonl";

/// The object attention phase's held-out errors over its steps, where it has one.
pub const ATTENTION_CURVE_FILE: &str = "attention_curve.jsonl";

/// What a pretrain stage runs: its settings, the trunk's shape, the seed, the agent collection's key and how many
/// slots per task it uses of it (none: all; a smaller size of a nested grid uses only its own layouts).
#[derive(Debug, Clone, PartialEq)]
pub struct PretrainJob {
    pub pretrain: PretrainConfig,
    pub backbone_width: i64,
    pub backbone_stages: usize,
    /// The policy's object attention heads and inner width (what `object_attention_steps` trains).
    pub attention_shape: (i64, i64),
    pub seed: u64,
    /// Where it runs (not part of the key).
    pub device: String,
    pub agents: String,
    pub per_task: Option<usize>,
}

/// Adds the pretraining a cell's `[pretrain]` section asks for on the agent collection `agents` (its first
/// `per_task` slots of each task, if given: then the key says so), seeded by the cell's training seed, so each
/// seed of the grid is an independent replicate; returns its key, or none when the cell has no such section.
pub fn add(plan: &mut Plan, cell: &CellConfig, agents: &str, per_task: Option<usize>) -> Option<String> {
    let pretrain = cell.pretrain.clone()?;
    let job = PretrainJob {
        pretrain,
        backbone_width: cell.model.backbone_width,
        backbone_stages: cell.model.backbone_stages,
        attention_shape: (cell.model.attention_heads, cell.model.attention_inner),
        seed: cell.train.seed,
        device: cell.train.device.clone(),
        agents: agents.into(),
        per_task,
    };
    let mut inputs = serde_json::json!({
        "pretrain": job.pretrain,
        "backbone_width": job.backbone_width,
        "backbone_stages": job.backbone_stages,
        "seed": job.seed,
    });
    if job.pretrain.object_attention_steps > 0 {
        inputs["attention_shape"] = serde_json::json!([job.attention_shape.0, job.attention_shape.1]);
    }
    // Frames not augmented, no attention phase: the key as before the settings existed.
    omit_when(
        &mut inputs,
        &[("pretrain.augmentation", serde_json::Value::Null), ("pretrain.object_attention_steps", 0.into())],
    );
    if let Some(n) = per_task {
        inputs["per_task"] = n.into();
    }
    Some(plan.add(inputs, vec![agents.into()], super::Job::Pretrain(job)))
}

/// The trunk file of the finished pretrain stage `key`.
pub fn trunk_of(upstream: &Upstream, key: &str) -> Result<PathBuf> {
    Ok(upstream.get(key)?.join(TRUNK_FILE))
}

/// The object attention file of the finished pretrain stage `key`, if its `object_attention_steps` made one.
pub fn attention_of(upstream: &Upstream, key: &str) -> Result<Option<PathBuf>> {
    Ok(Some(upstream.get(key)?.join(ATTENTION_FILE)).filter(|p| p.is_file()))
}

/// Trains the trunk into `staging` (then, with `object_attention_steps`, the object attention with it), keeping
/// each phase's curve there as it goes; reports the held-out errors of each phase beside the mean's.
pub fn run(job: &PretrainJob, upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
    let trunk = (job.backbone_width, job.backbone_stages);
    let config = LocaliseConfig {
        curve_out: Some(staging.join(TRUNK_CURVE_FILE)),
        ..job.pretrain.localise(trunk, job.per_task, job.seed, Some(staging.join(TRUNK_FILE)))
    };
    let device = crate::device::parse_device(&ctx.device_or(&job.device))?;
    let agents = upstream.get(&job.agents)?;
    let report = localise(agents, &config, device)?;
    let last = report.curve.last().expect("the check measures at its last step");
    let mut metrics = vec![
        (MetricName::TrunkHeldOutErrorX, last.held_out[0]),
        (MetricName::TrunkHeldOutErrorY, last.held_out[1]),
        (MetricName::TrunkMeanErrorX, report.mean_baseline[0]),
        (MetricName::TrunkMeanErrorY, report.mean_baseline[1]),
    ];
    let attention = job.pretrain.attention_phase(
        &config,
        job.attention_shape,
        staging.join(TRUNK_FILE),
        staging.join(ATTENTION_FILE),
    );
    if let Some(config) = attention {
        let config = LocaliseConfig { curve_out: Some(staging.join(ATTENTION_CURVE_FILE)), ..config };
        let report = localise(agents, &config, device)?;
        let last = report.curve.last().expect("the check measures at its last step");
        metrics.extend([
            (MetricName::AttentionHeldOutErrorX, last.held_out[0]),
            (MetricName::AttentionHeldOutErrorY, last.held_out[1]),
            (MetricName::AttentionMeanErrorX, report.mean_baseline[0]),
            (MetricName::AttentionMeanErrorY, report.mean_baseline[1]),
        ]);
    }
    Ok(StageOutputs { metrics, ..StageOutputs::default() })
}
