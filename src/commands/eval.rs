//! `eval`: closed-loop rollouts of a trained policy, the scripted expert or the random policy.
use crate::data::manifest::Manifest;
use crate::eval::summary::{EvalSummary, summarize};
use crate::eval::{EpisodeResult, EvalConfig, EvalOutput, EvalPolicy, evaluate};
use crate::sim::env::WorldConfig;
use crate::train::{TrainedPolicy, load_trained};
use anyhow::{Context, Result};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// File names of an evaluation folder.
pub const EPISODES_FILE: &str = "episodes.jsonl";
pub const SUMMARY_FILE: &str = "summary.json";

/// What to evaluate: `expert`, `random`, or a finished training folder.
pub enum PolicyArg {
    Expert,
    Random,
    Trained(PathBuf),
}

impl PolicyArg {
    /// Parses the `--policy` value.
    pub fn parse(s: &str) -> PolicyArg {
        match s {
            "expert" => PolicyArg::Expert,
            "random" => PolicyArg::Random,
            path => PolicyArg::Trained(PathBuf::from(path)),
        }
    }
}

/// Instance seeds of the given collections (training layouts the evaluation must avoid).
pub fn training_seeds(collections: &[PathBuf]) -> Result<HashSet<u64>> {
    let mut seeds = HashSet::new();
    for dir in collections {
        seeds.extend(Manifest::load(dir)?.trajectories.iter().map(|e| e.instance_seed));
    }
    Ok(seeds)
}

/// Runs the evaluation and, with `out`, writes the episodes, the summary and any strips there.
pub fn run_eval(
    policy: &PolicyArg,
    world: &WorldConfig,
    config: &EvalConfig,
    exclude: &HashSet<u64>,
    workers: usize,
    out: Option<&Path>,
) -> Result<(Vec<EpisodeResult>, EvalSummary)> {
    let trained: Option<TrainedPolicy> = match policy {
        PolicyArg::Trained(dir) => Some(load_trained(dir, crate::train::config::parse_device(&config.device)?)?),
        _ => None,
    };
    let (policy, world) = match (&trained, policy) {
        (Some(t), _) => (EvalPolicy::Network(t), WorldConfig { image: t.summary.image, ..world.clone() }),
        (None, PolicyArg::Expert) => (EvalPolicy::Expert, world.clone()),
        (None, _) => (EvalPolicy::Random, world.clone()),
    };
    let output = EvalOutput { strips_dir: out.map(|o| o.join("strips")) };
    let results = evaluate(&policy, &world, config, exclude, workers, &output)?;
    let summary = summarize(policy.name(), &results);
    if let Some(out) = out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let lines: Vec<String> = results.iter().map(serde_json::to_string).collect::<Result<_, _>>()?;
        write_atomically(&out.join(EPISODES_FILE), &(lines.join("\n") + "\n"))?;
        write_atomically(&out.join(SUMMARY_FILE), &(serde_json::to_string_pretty(&summary)? + "\n"))?;
    }
    Ok((results, summary))
}

/// Writes `text` to a temporary name beside `path`, then renames it: a killed run never leaves a half file.
fn write_atomically(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("partial");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}
