//! Evaluation's entry point: load the policy, run its episodes, and write the episodes, the summary and any strips
//! and videos into an output folder.
use super::actor::{Actor, ActorFiles};
use super::config::EvalConfig;
use super::layouts::Layouts;
use super::rollout::rollouts;
use super::summary::{EvalSummary, summarize};
use super::{EpisodeResult, EvalOutput};
use crate::sim::env::WorldConfig;
use crate::train::{TrainedPolicy, load_trained};
use anyhow::{Context, Result, bail};
use std::path::Path;

/// File names of an evaluation folder.
pub const EPISODES_FILE: &str = "episodes.jsonl";
pub const SUMMARY_FILE: &str = "summary.json";
/// Every episode's steps, one episode per line, where asked for.
pub const TRACES_FILE: &str = "traces.jsonl";
/// The folder of an evaluation's rollout videos.
pub const VIDEOS_DIR: &str = "videos";

/// Runs the evaluation of `policy` and, with `out`, writes the episodes, the summary, strips, videos and (with
/// `eval.traces`) every episode's steps there. A trained policy runs in the world it was trained in; `world`, if
/// given, must be that world (reference policies run in `world` or the default world).
pub fn run_eval(
    policy: &ActorFiles,
    world: Option<&WorldConfig>,
    config: &EvalConfig,
    layouts: &Layouts,
    workers: usize,
    out: Option<&Path>,
) -> Result<(Vec<EpisodeResult>, EvalSummary)> {
    if config.traces && out.is_none() {
        bail!("traces of the episodes' steps need an output folder (--out)");
    }
    let device = crate::device::parse_device(&config.device)?;
    let trained: Actor<TrainedPolicy> = policy.as_ref().try_map(|w| load_trained(&w.at, w.step, device))?;
    let loaded = trained.as_ref();
    let world = match &trained {
        Actor::Network(t) => world.cloned().unwrap_or_else(|| t.summary.world.clone()),
        _ => world.cloned().unwrap_or_default(),
    };
    world.validate()?;
    let output = EvalOutput { strips_dir: out.map(|o| o.join("strips")), videos_dir: out.map(|o| o.join(VIDEOS_DIR)) };
    let (results, steps) =
        rollouts(&loaded, &world, config, &layouts.episodes(config, world.objects)?, workers, &output)?;
    let summary = summarize(loaded.name(), &results, &steps);
    if let Some(out) = out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let lines: Vec<String> = results.iter().map(serde_json::to_string).collect::<Result<_, _>>()?;
        crate::fsio::write_atomic(&out.join(EPISODES_FILE), lines.join("\n") + "\n")?;
        crate::fsio::write_atomic(&out.join(SUMMARY_FILE), serde_json::to_string_pretty(&summary)? + "\n")?;
        if config.traces {
            let lines: Vec<String> = steps.iter().map(serde_json::to_string).collect::<Result<_, _>>()?;
            crate::fsio::write_atomic(&out.join(TRACES_FILE), lines.join("\n") + "\n")?;
        }
    }
    Ok((results, summary))
}
