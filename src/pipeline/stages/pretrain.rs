//! The pretrain stage: the policy's image trunk trained to find objects in an agent collection's first frames
//! (the localisation check's regression), saved for the train stage to start from.
use super::{MetricName, RunContext, StageOutputs, Upstream};
use crate::config::CellConfig;
use crate::pipeline::graph::Plan;
use crate::pipeline::key::omit_when;
use crate::train::pretrain::{PretrainConfig, localise};
use anyhow::Result;
use std::path::{Path, PathBuf};

/// Implementation version of trunk pretraining (part of every pretrain key).
pub const VERSION: u32 = 2;

/// The trunk's weights in a pretrain artifact (torchvision names, as `model.pretrained_backbone` reads them).
pub const TRUNK_FILE: &str = "trunk.safetensors";

/// What a pretrain stage runs: its settings, the trunk's shape, the seed, the agent collection's key and how many
/// slots per task it uses of it (none: all; a smaller size of a nested grid uses only its own layouts).
#[derive(Debug, Clone, PartialEq)]
pub struct PretrainJob {
    pub pretrain: PretrainConfig,
    pub backbone_width: i64,
    pub backbone_stages: usize,
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
    // Frames not augmented: the key as before the setting existed.
    omit_when(&mut inputs, &[("pretrain.augmentation", serde_json::Value::Null)]);
    if let Some(n) = per_task {
        inputs["per_task"] = n.into();
    }
    Some(plan.add(inputs, vec![agents.into()], super::Job::Pretrain(job)))
}

/// The trunk file of the finished pretrain stage `key`.
pub fn trunk_of(upstream: &Upstream, key: &str) -> Result<PathBuf> {
    Ok(upstream.get(key)?.join(TRUNK_FILE))
}

/// Trains the trunk into `staging`; reports its held-out errors beside the mean's.
pub fn run(job: &PretrainJob, upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
    let trunk = (job.backbone_width, job.backbone_stages);
    let config = job.pretrain.localise(trunk, job.per_task, job.seed, Some(staging.join(TRUNK_FILE)));
    let device = crate::device::parse_device(&ctx.device_or(&job.device))?;
    let report = localise(upstream.get(&job.agents)?, &config, device)?;
    let last = report.curve.last().expect("the check measures at its last step");
    Ok(StageOutputs {
        metrics: vec![
            (MetricName::TrunkHeldOutErrorX, last.held_out[0]),
            (MetricName::TrunkHeldOutErrorY, last.held_out[1]),
            (MetricName::TrunkMeanErrorX, report.mean_baseline[0]),
            (MetricName::TrunkMeanErrorY, report.mean_baseline[1]),
        ],
        ..StageOutputs::default()
    })
}
