//! Running one stage for real: collection, training or evaluation, into a staging folder that is renamed into
//! place before the store records the stage as done.
use super::graph::{EvalTarget, Job, Kind, Stage, short};
use super::store::StageResults;
use crate::commands::eval::{Layouts, PolicyArg, run_eval, training_seeds};
use crate::data::collect::collect;
use crate::train::{CURVE_FILE, TrainRun, curve, train};
use anyhow::{Context, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Where and how stages run.
pub struct ExecContext {
    /// The store folder; artifacts live under `artifacts/`.
    pub root: PathBuf,
    /// Artifact folders of finished stages, by key.
    pub artifacts: HashMap<String, PathBuf>,
    /// Simulation threads for collection and evaluation.
    pub workers: usize,
    /// Device for training and evaluation networks, overriding the configuration (from `--gpus`).
    pub device: Option<String>,
    pub progress: bool,
}

/// The final artifact folder of a stage.
pub fn artifact_dir(root: &Path, kind: Kind, key: &str) -> PathBuf {
    root.join("artifacts").join(kind.name()).join(short(key))
}

/// The staging folder of a stage: stable across attempts, so training resumes from its checkpoints.
pub fn staging_dir(root: &Path, key: &str) -> PathBuf {
    root.join("artifacts").join(".staging").join(short(key))
}

fn upstream<'a>(ctx: &'a ExecContext, key: &str) -> Result<&'a PathBuf> {
    ctx.artifacts.get(key).with_context(|| format!("upstream stage {} has no artifact", short(key)))
}

/// Moves `from` to `to`, replacing a stale `to` left by an attempt the store never recorded as done.
fn publish(from: &Path, to: &Path) -> Result<()> {
    if to.exists() {
        std::fs::remove_dir_all(to).with_context(|| format!("removing stale {}", to.display()))?;
    }
    std::fs::create_dir_all(to.parent().expect("artifact folders have parents"))?;
    std::fs::rename(from, to).with_context(|| format!("moving {} to {}", from.display(), to.display()))
}

/// Runs `stage`; returns its artifact folder and results.
pub fn execute(stage: &Stage, ctx: &ExecContext) -> Result<(PathBuf, StageResults)> {
    let out = artifact_dir(&ctx.root, stage.kind, &stage.key);
    let staging = staging_dir(&ctx.root, &stage.key);
    let mut results = StageResults::default();
    match &stage.job {
        Job::Collect(config) => {
            if out.exists() {
                std::fs::remove_dir_all(&out).with_context(|| format!("removing stale {}", out.display()))?;
            }
            let manifest = collect(config, &out, ctx.workers, ctx.progress)?;
            let retries: usize = manifest.trajectories.iter().map(|e| e.attempts - 1).sum();
            results.metrics = vec![
                ("trajectories".into(), manifest.trajectories.len() as f64),
                ("frames".into(), manifest.total_steps() as f64),
                ("expert_retries".into(), retries as f64),
            ];
        }
        Job::Train { model, train: config, demos, agents } => {
            let mut config = config.clone();
            if let Some(d) = &ctx.device {
                config.device = d.clone();
            }
            std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
            let run = TrainRun {
                demo_dir: upstream(ctx, demos)?,
                agent_dir: upstream(ctx, agents)?,
                out: &staging,
                progress: ctx.progress,
            };
            let summary = train(model, &config, &run)?;
            results.curve = curve::read(&staging.join(CURVE_FILE), summary.steps)?;
            results.metrics = vec![
                ("first_val_bc".into(), summary.first_val_bc),
                ("final_val_bc".into(), summary.final_val_bc),
                ("train_seconds".into(), summary.seconds),
                ("parameters".into(), summary.parameters as f64),
            ];
            publish(&staging, &out)?;
        }
        Job::Eval { target, world, eval, exclude } => {
            let mut eval = eval.clone();
            if let Some(d) = &ctx.device {
                eval.device = d.clone();
            }
            if staging.exists() {
                std::fs::remove_dir_all(&staging).with_context(|| format!("removing {}", staging.display()))?;
            }
            let policy = match target {
                EvalTarget::Trained { train, step } => {
                    PolicyArg::Trained { dir: upstream(ctx, train)?.clone(), step: *step }
                }
                EvalTarget::Reference(crate::config::Reference::Expert) => PolicyArg::Expert,
                EvalTarget::Reference(crate::config::Reference::Random) => PolicyArg::Random,
            };
            let dirs: Vec<PathBuf> = exclude.iter().map(|k| upstream(ctx, k).cloned()).collect::<Result<_>>()?;
            let layouts = Layouts::Fresh(training_seeds(&dirs)?);
            let (episodes, summary) = run_eval(&policy, Some(world), &eval, &layouts, ctx.workers, Some(&staging))?;
            let o = &summary.overall;
            results.metrics = vec![
                ("reached".into(), o.reached.value),
                ("picked".into(), o.picked.value),
                ("placed".into(), o.placed.value),
            ];
            results.episodes = episodes;
            publish(&staging, &out)?;
        }
    }
    Ok((out, results))
}
