//! Expansion of an experiment into stages: collect (per robot, size, settings) -> train (per cell) -> eval (per
//! cell, plus the reference policies). Identical stages share one key, within and across experiment files.
use super::key::{canonical_json, stage_key};
use crate::config::{CellConfig, Experiment, Reference};
use crate::data::collect::CollectConfig;
use crate::eval::EvalConfig;
use crate::model::config::ModelConfig;
use crate::sim::env::WorldConfig;
use crate::sim::robot::Robot;
use crate::train::config::TrainConfig;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Implementation versions: bump one when its stage's results would change for the same inputs.
pub const COLLECT_VERSION: u32 = 2;
pub const TRAIN_VERSION: u32 = 2;
pub const EVAL_VERSION: u32 = 3;

/// The kinds of cached stages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Collect,
    Train,
    Eval,
}

impl Kind {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Collect => "collect",
            Kind::Train => "train",
            Kind::Eval => "eval",
        }
    }

    /// The implementation version that goes into keys.
    pub fn version(self) -> u32 {
        match self {
            Kind::Collect => COLLECT_VERSION,
            Kind::Train => TRAIN_VERSION,
            Kind::Eval => EVAL_VERSION,
        }
    }
}

/// The policy an evaluation stage measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EvalTarget {
    /// The trained policy of this train stage key: its final weights, or its checkpoint at `step`.
    Trained {
        train: String,
        step: Option<u64>,
    },
    Reference(Reference),
}

/// What a stage runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Job {
    Collect(CollectConfig),
    Train { model: ModelConfig, train: TrainConfig, demos: String, agents: String },
    Eval { target: EvalTarget, world: WorldConfig, eval: EvalConfig, exclude: Vec<String> },
}

/// A stage: its key, kind, resolved inputs and upstream keys.
#[derive(Debug, Clone)]
pub struct Stage {
    pub key: String,
    pub kind: Kind,
    /// The resolved inputs that went into the key (without the upstream keys).
    pub inputs: serde_json::Value,
    pub upstream: Vec<String>,
    pub job: Job,
}

/// A cell of the experiment with the stages that produce its numbers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlannedCell {
    pub name: String,
    /// `model` for a trained cell, otherwise the reference policy's name.
    pub policy: String,
    pub size: Option<usize>,
    pub variant: Option<String>,
    pub seed: Option<u64>,
    pub collect_demo: Option<String>,
    pub collect_agent: Option<String>,
    pub train: Option<String>,
    pub eval: String,
    /// Evaluations of intermediate checkpoints: (training step, eval stage key).
    pub checkpoints: Vec<(u64, String)>,
}

/// The stage graph of an experiment.
#[derive(Debug, Clone, Default)]
pub struct Plan {
    /// Stages by key.
    pub stages: BTreeMap<String, Stage>,
    /// Keys in an order where every stage follows its upstream.
    pub order: Vec<String>,
    pub cells: Vec<PlannedCell>,
}

/// Training settings that do not change results (where it runs, how far ahead batches are made) are left out of
/// keys so that moving a run to another machine reuses the cache.
fn train_identity(t: &TrainConfig) -> TrainConfig {
    TrainConfig { device: "auto".into(), prefetch: 0, memory_format: Default::default(), ..t.clone() }
}

/// Evaluation settings that do not change one evaluation's results are left out of keys: the device, and which
/// checkpoints the experiment evaluates (each checkpoint evaluation is a stage keyed by its step).
fn eval_identity(e: &EvalConfig) -> EvalConfig {
    EvalConfig { device: "auto".into(), checkpoints: Vec::new(), ..e.clone() }
}

impl Plan {
    fn add(&mut self, kind: Kind, inputs: serde_json::Value, upstream: Vec<String>, job: Job) -> String {
        let key = stage_key(kind.name(), kind.version(), &canonical_json(&inputs), &upstream);
        if !self.stages.contains_key(&key) {
            self.order.push(key.clone());
            self.stages.insert(key.clone(), Stage { key: key.clone(), kind, inputs, upstream, job });
        }
        key
    }

    fn collect(&mut self, robot: Robot, size: usize, c: &CellConfig) -> String {
        let tasks = c.collect.tasks.clone();
        let config = CollectConfig {
            robot,
            per_task: size / crate::sim::task::NUM_TASKS,
            tasks,
            seed: c.collect.seed,
            world: c.world.clone(),
            max_actions: c.collect.max_actions,
            max_attempts: c.collect.max_attempts,
            jpeg_quality: c.collect.jpeg_quality,
        };
        let inputs = serde_json::to_value(&config).expect("serialisable");
        self.add(Kind::Collect, inputs, Vec::new(), Job::Collect(config))
    }

    /// Expands `experiment` into its stages and cells.
    pub fn build(experiment: &Experiment) -> Plan {
        let mut plan = Plan::default();
        for cell in &experiment.cells {
            let c = &cell.config;
            let demos = plan.collect(Robot::Sawyer, cell.size, c);
            let agents = plan.collect(Robot::Panda, cell.size, c);
            let train = train_identity(&c.train);
            let inputs = serde_json::json!({ "model": c.model, "train": train });
            let job = Job::Train {
                model: c.model.clone(),
                train: c.train.clone(),
                demos: demos.clone(),
                agents: agents.clone(),
            };
            let train_key = plan.add(Kind::Train, inputs, vec![demos.clone(), agents.clone()], job);
            let upstream = vec![train_key.clone(), demos.clone(), agents.clone()];
            let mut eval_stage = |step: Option<u64>| {
                let eval = eval_identity(&c.eval);
                let mut inputs = serde_json::json!({ "world": c.world, "eval": eval, "policy": "trained" });
                if let Some(s) = step {
                    inputs["checkpoint"] = s.into();
                }
                let job = Job::Eval {
                    target: EvalTarget::Trained { train: train_key.clone(), step },
                    world: c.world.clone(),
                    eval: c.eval.clone(),
                    exclude: vec![demos.clone(), agents.clone()],
                };
                plan.add(Kind::Eval, inputs, upstream.clone(), job)
            };
            let checkpoints = c.eval.checkpoints.iter().map(|&s| (s, eval_stage(Some(s)))).collect();
            let eval_key = eval_stage(None);
            plan.cells.push(PlannedCell {
                name: cell.name.clone(),
                policy: "model".into(),
                size: Some(cell.size),
                variant: Some(cell.variant.clone()),
                seed: Some(cell.seed),
                collect_demo: Some(demos),
                collect_agent: Some(agents),
                train: Some(train_key),
                eval: eval_key,
                checkpoints,
            });
        }
        for &r in &experiment.grid.references {
            let b = &experiment.base;
            let inputs = serde_json::json!({ "world": b.world, "eval": eval_identity(&b.eval), "policy": r.name() });
            let job = Job::Eval {
                target: EvalTarget::Reference(r),
                world: b.world.clone(),
                eval: b.eval.clone(),
                exclude: vec![],
            };
            let eval_key = plan.add(Kind::Eval, inputs, Vec::new(), job);
            plan.cells.push(PlannedCell {
                name: r.name().into(),
                policy: r.name().into(),
                size: None,
                variant: None,
                seed: None,
                collect_demo: None,
                collect_agent: None,
                train: None,
                eval: eval_key,
                checkpoints: Vec::new(),
            });
        }
        plan
    }

    /// Keys of `key` and every stage downstream of it.
    pub fn downstream(&self, key: &str) -> Vec<String> {
        let mut out = vec![key.to_string()];
        for k in &self.order {
            if self.stages[k].upstream.iter().any(|u| out.contains(u)) && !out.contains(k) {
                out.push(k.clone());
            }
        }
        out
    }
}

/// A short form of a key for folder names and tables.
pub fn short(key: &str) -> &str {
    &key[..key.len().min(12)]
}
