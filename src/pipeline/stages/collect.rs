//! The collect stage: expert trajectories of one robot.
use super::{MetricName, RunContext, StageOutputs, Upstream};
use crate::config::CellConfig;
use crate::data::collect::collect_into;
use crate::data::collect_config::CollectConfig;
use crate::pipeline::graph::Plan;
use crate::pipeline::key::omit_when;
use crate::sim::robot::Robot;
use anyhow::Result;
use std::path::Path;

/// Implementation version of collection (part of every collect key).
pub const VERSION: u32 = 4;

/// What a collect stage runs.
pub type CollectJob = CollectConfig;

/// Adds the collection of `per_task` trajectories per task by `robot` for a cell; returns its key.
pub fn add(plan: &mut Plan, robot: Robot, per_task: usize, cell: &CellConfig) -> String {
    let job = CollectConfig { robot, per_task, world: cell.world.clone(), settings: cell.collect.clone() };
    plan.add(key_inputs(&job), Vec::new(), super::Job::Collect(job))
}

/// What a collection's key is made of: the whole configuration, less the world's neutral settings and, outside
/// the multi-object world, the environments' size (which only groups library objects).
fn key_inputs(job: &CollectJob) -> serde_json::Value {
    let mut inputs = serde_json::to_value(job).expect("configurations serialise");
    omit_when(&mut inputs, &super::neutral_world());
    if !job.library() {
        inputs["settings"].as_object_mut().expect("settings serialise to an object").remove("environment_instances");
    }
    inputs
}

/// Collects into `staging`.
pub fn run(job: &CollectJob, _upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
    let manifest = collect_into(job, staging, ctx.workers, ctx.progress)?;
    let retries: usize = manifest.trajectories.iter().map(|e| e.attempts - 1).sum();
    Ok(StageOutputs {
        metrics: vec![
            (MetricName::Trajectories, manifest.trajectories.len() as f64),
            (MetricName::Frames, manifest.total_steps() as f64),
            (MetricName::ExpertRetries, retries as f64),
        ],
        ..StageOutputs::default()
    })
}
