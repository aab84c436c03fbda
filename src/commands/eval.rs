//! `eval`: closed-loop rollouts of a trained policy, the scripted expert or the random policy.
use crate::data::manifest::Manifest;
use crate::eval::summary::{EvalSummary, summarize};
use crate::eval::{EpisodeResult, EvalConfig, EvalOutput, EvalPolicy, evaluate, evaluate_episodes, training_layouts};
use crate::sim::env::WorldConfig;
use crate::train::{TrainedPolicy, load_trained};
use anyhow::{Context, Result};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// File names of an evaluation folder.
pub const EPISODES_FILE: &str = "episodes.jsonl";
pub const SUMMARY_FILE: &str = "summary.json";

/// What to evaluate: `expert`, `random`, or a finished training folder (its final weights or a checkpoint).
pub enum PolicyArg {
    Expert,
    Random,
    Trained { dir: PathBuf, step: Option<u64> },
}

impl PolicyArg {
    /// Parses the `--policy` value; `step` picks a checkpoint of a training folder.
    pub fn parse(s: &str, step: Option<u64>) -> PolicyArg {
        match s {
            "expert" => PolicyArg::Expert,
            "random" => PolicyArg::Random,
            path => PolicyArg::Trained { dir: PathBuf::from(path), step },
        }
    }
}

/// Where the episodes are laid out.
pub enum Layouts {
    /// Fresh layouts, none with these instance seeds (the training data's).
    Fresh(HashSet<u64>),
    /// The training layouts of a demonstrator and an agent collection (see [`training_layouts`]).
    Training { demos: PathBuf, agents: PathBuf },
}

/// Instance seeds of the given collections (training layouts the evaluation must avoid).
pub fn training_seeds(collections: &[PathBuf]) -> Result<HashSet<u64>> {
    let mut seeds = HashSet::new();
    for dir in collections {
        seeds.extend(Manifest::load(dir)?.trajectories.iter().map(|e| e.instance_seed));
    }
    Ok(seeds)
}

/// Runs the evaluation and, with `out`, writes the episodes, the summary and any strips there. A trained policy
/// runs in the world it was trained in; `world`, if given, must be that world.
pub fn run_eval(
    policy: &PolicyArg,
    world: Option<&WorldConfig>,
    config: &EvalConfig,
    layouts: &Layouts,
    workers: usize,
    out: Option<&Path>,
) -> Result<(Vec<EpisodeResult>, EvalSummary)> {
    let trained: Option<TrainedPolicy> = match policy {
        PolicyArg::Trained { dir, step } => {
            Some(load_trained(dir, *step, crate::train::config::parse_device(&config.device)?)?)
        }
        _ => None,
    };
    let (policy, world) = match (&trained, policy) {
        (Some(t), _) => (EvalPolicy::Network(t), world.cloned().unwrap_or_else(|| t.summary.world.clone())),
        (None, PolicyArg::Expert) => (EvalPolicy::Expert, world.cloned().unwrap_or_default()),
        (None, _) => (EvalPolicy::Random, world.cloned().unwrap_or_default()),
    };
    let output = EvalOutput { strips_dir: out.map(|o| o.join("strips")) };
    let results = match layouts {
        Layouts::Fresh(exclude) => evaluate(&policy, &world, config, exclude, workers, &output)?,
        Layouts::Training { demos, agents } => {
            let specs = training_layouts(&Manifest::load(demos)?, &Manifest::load(agents)?);
            evaluate_episodes(&policy, &world, config, &specs, workers, &output)?
        }
    };
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
