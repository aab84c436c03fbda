//! Where evaluation episodes are laid out: fresh layouts that avoid the training data's, or the training layouts
//! themselves (what an overfitted policy reproduces).
use super::config::EvalConfig;
use super::workers::EpisodeSpec;
use crate::data::manifest::Manifest;
use crate::sim::env::ObjectSet;
use anyhow::Result;
use std::collections::HashSet;
use std::path::PathBuf;

/// Where the episodes are laid out.
#[derive(Debug, Clone)]
pub enum Layouts {
    /// Fresh layouts from the `eval` seed domain, none with these instance seeds (the training data's).
    Fresh(HashSet<u64>),
    /// The layouts of a demonstrator and an agent collection (see [`training_layouts`]).
    Training { demos: PathBuf, agents: PathBuf },
}

impl Layouts {
    /// The episodes to run in a world of `objects`.
    pub fn episodes(&self, config: &EvalConfig, objects: ObjectSet) -> Result<Vec<EpisodeSpec>> {
        Ok(match self {
            Layouts::Fresh(exclude) => config.episode_specs(objects, exclude),
            Layouts::Training { demos, agents } => training_layouts(&Manifest::load(demos)?, &Manifest::load(agents)?),
        })
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

/// Episodes on the layouts of a demonstrator and an agent collection: each agent trajectory's own layout, with
/// its environment's objects, demonstrated on the layout of the demonstrator trajectory of the same task and slot
/// (the training pairs an overfitted policy reproduces).
pub fn training_layouts(demos: &Manifest, agents: &Manifest) -> Vec<EpisodeSpec> {
    agents
        .trajectories
        .iter()
        .filter_map(|a| {
            let d = demos.trajectories.iter().find(|d| d.task == a.task && d.index == a.index)?;
            Some((a, d.instance_seed))
        })
        .enumerate()
        .map(|(index, (a, demo_seed))| EpisodeSpec {
            index,
            task: a.task,
            agent_seed: a.instance_seed,
            demo_seed,
            objects: agents.config.objects(a.environment),
        })
        .collect()
}
