//! The eval stage: closed-loop rollouts of a trained policy (its final weights or a checkpoint) or a reference
//! policy.
use super::{MetricName, RunContext, StageOutputs, Upstream};
use crate::config::{CellConfig, Reference};
use crate::eval::layouts::{Layouts, training_seeds};
use crate::eval::run::run_eval;
use crate::eval::{Actor, EvalConfig, Weights};
use crate::pipeline::graph::Plan;
use crate::pipeline::key::omit_when;
use crate::sim::env::WorldConfig;
use anyhow::Result;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Implementation version of evaluation (part of every eval key).
pub const VERSION: u32 = 4;

/// What an eval stage runs: the policy (a network by its train stage key), the world and settings, and the
/// collections whose layouts it must avoid.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalJob {
    pub policy: Actor<Weights<String>>,
    pub world: WorldConfig,
    pub eval: EvalConfig,
    pub exclude: Vec<String>,
}

impl EvalJob {
    /// Whether a network is evaluated.
    pub fn runs_network(&self) -> bool {
        matches!(self.policy, Actor::Network(_))
    }
}

/// Evaluation settings that do not change one evaluation's results are left out of keys: the device, and which
/// checkpoints the experiment evaluates (each checkpoint evaluation is a stage keyed by its step).
fn identity(e: &EvalConfig) -> EvalConfig {
    EvalConfig { device: "auto".into(), checkpoints: Vec::new(), ..e.clone() }
}

/// What an evaluation's key is made of besides its upstream stages: the world, the evaluation settings that
/// change results and who acts, less the settings added after keys existed at their earlier value.
fn key_inputs(world: &WorldConfig, eval: &EvalConfig, policy: &str) -> Value {
    let mut inputs = json!({ "world": world, "eval": identity(eval), "policy": policy });
    let [close, rise, objects] = super::neutral_world();
    omit_when(
        &mut inputs,
        &[
            close,
            rise,
            objects,
            ("eval.videos", json!([])),
            ("eval.control", json!("policy")),
            ("eval.video_width", json!(320)),
            ("eval.traces", json!(false)),
        ],
    );
    inputs
}

/// Adds the evaluation of training `train`'s final weights (`step` none) or checkpoint at `step`, avoiding the
/// layouts of the collections `data`; returns its key.
pub fn add_trained(plan: &mut Plan, cell: &CellConfig, train: &str, step: Option<u64>, data: &[String]) -> String {
    let mut inputs = key_inputs(&cell.world, &cell.eval, "trained");
    if let Some(s) = step {
        inputs["checkpoint"] = s.into();
    }
    let job = EvalJob {
        policy: Actor::Network(Weights { at: train.to_string(), step }),
        world: cell.world.clone(),
        eval: cell.eval.clone(),
        exclude: data.to_vec(),
    };
    let upstream = std::iter::once(train.to_string()).chain(data.iter().cloned()).collect();
    plan.add(inputs, upstream, super::Job::Eval(job))
}

/// Adds the evaluation of reference policy `r` in the experiment's base configuration; returns its key.
pub fn add_reference(plan: &mut Plan, base: &CellConfig, r: Reference) -> String {
    let inputs = key_inputs(&base.world, &base.eval, r.name());
    let job = EvalJob { policy: r.into(), world: base.world.clone(), eval: base.eval.clone(), exclude: Vec::new() };
    plan.add(inputs, Vec::new(), super::Job::Eval(job))
}

/// Evaluates into `staging` (episodes, summary, strips).
pub fn run(job: &EvalJob, upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
    let eval = EvalConfig { device: ctx.device_or(&job.eval.device), ..job.eval.clone() };
    let policy = job
        .policy
        .as_ref()
        .try_map(|w| -> Result<_> { Ok(Weights { at: upstream.get(&w.at)?.to_path_buf(), step: w.step }) })?;
    let data: Vec<PathBuf> =
        job.exclude.iter().map(|k| upstream.get(k).map(Path::to_path_buf)).collect::<Result<_>>()?;
    let layouts = Layouts::Fresh(training_seeds(&data)?);
    let (episodes, summary) = run_eval(&policy, Some(&job.world), &eval, &layouts, ctx.workers, Some(staging))?;
    let o = &summary.overall;
    Ok(StageOutputs {
        metrics: vec![
            (MetricName::Reached, o.reached.value),
            (MetricName::Picked, o.picked.value),
            (MetricName::Placed, o.placed.value),
        ],
        episodes,
        ..StageOutputs::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_added_later_stay_out_of_keys_at_their_first_value() {
        let world = WorldConfig::default();
        let plain = key_inputs(&world, &EvalConfig::default(), "trained");
        for later in ["videos", "control", "video_width", "traces"] {
            assert!(plain["eval"].get(later).is_none(), "eval.{later} at its default is not in the key");
        }
        let traced = key_inputs(&world, &EvalConfig { traces: true, ..EvalConfig::default() }, "trained");
        assert_eq!(traced["eval"]["traces"], json!(true), "an evaluation that keeps traces is another stage");
    }
}
