//! The stage kinds: the one place in the pipeline that names them. Each kind is a module with a job type and a
//! `run` of one shape, `run(job, upstream artifacts, staging folder, context) -> StageOutputs`; this registry says
//! which kind a job is, its implementation version, whether it needs a GPU, and how an experiment's cells expand
//! into stages.
pub mod collect;
pub mod eval;
pub mod pretrain;
pub mod train;

use super::graph::{Plan, PlannedCell};
use crate::config::Experiment;
use crate::eval::EpisodeResult;
use crate::sim::robot::Robot;
use crate::train::curve::CurvePoint;
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The world's settings that keys leave out at their first value (added after keys existed).
fn neutral_world() -> [(&'static str, serde_json::Value); 3] {
    [
        ("world.close_on_arrival", serde_json::Value::Bool(false)),
        ("world.rise_on_grip", serde_json::Value::Bool(false)),
        ("world.objects", serde_json::Value::String("base".into())),
    ]
}

/// The kinds of cached stages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Collect,
    Pretrain,
    Train,
    Eval,
}

impl Kind {
    /// Every kind, in pipeline order.
    pub const ALL: [Kind; 4] = [Kind::Collect, Kind::Pretrain, Kind::Train, Kind::Eval];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Collect => "collect",
            Kind::Pretrain => "pretrain",
            Kind::Train => "train",
            Kind::Eval => "eval",
        }
    }

    /// The kind called `name` (as [`Kind::name`] spells it).
    pub fn named(name: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The implementation version that goes into keys: bumped when a kind's results change for the same inputs.
    pub fn version(self) -> u32 {
        match self {
            Kind::Collect => collect::VERSION,
            Kind::Pretrain => pretrain::VERSION,
            Kind::Train => train::VERSION,
            Kind::Eval => eval::VERSION,
        }
    }

    /// The source files (prefixes of paths under `src/`) whose code decides this kind's results: their digest is
    /// recorded with every attempt (`pipeline::code`). A kind that comes to use another module lists it here.
    pub fn sources(self) -> &'static [&'static str] {
        match self {
            Kind::Collect => &["pipeline/stages/collect.rs", "sim/", "data/", "seeds.rs", "fsio.rs"],
            Kind::Pretrain => &["pipeline/stages/pretrain.rs", "train/", "model/", "data/", "seeds.rs", "device.rs"],
            Kind::Train => {
                &["pipeline/stages/train.rs", "train/", "model/", "data/", "seeds.rs", "device.rs", "autocast.rs"]
            }
            Kind::Eval => {
                &["pipeline/stages/eval.rs", "eval/", "sim/", "model/", "data/", "seeds.rs", "device.rs", "autocast.rs"]
            }
        }
    }

    /// Whether an interrupted attempt's staging folder is kept for the next one (training resumes from its
    /// checkpoints); otherwise it is cleared.
    pub fn resumes(self) -> bool {
        self == Kind::Train
    }
}

/// What a stage runs.
#[derive(Debug, Clone, PartialEq)]
pub enum Job {
    Collect(collect::CollectJob),
    Pretrain(pretrain::PretrainJob),
    Train(Box<train::TrainJob>),
    Eval(eval::EvalJob),
}

impl Job {
    /// The job's kind.
    pub fn kind(&self) -> Kind {
        match self {
            Job::Collect(_) => Kind::Collect,
            Job::Pretrain(_) => Kind::Pretrain,
            Job::Train(_) => Kind::Train,
            Job::Eval(_) => Kind::Eval,
        }
    }

    /// Whether the job runs a network (and takes a GPU when the run hands them out).
    pub fn needs_gpu(&self) -> bool {
        match self {
            Job::Collect(_) => false,
            Job::Pretrain(_) | Job::Train(_) => true,
            Job::Eval(e) => e.runs_network(),
        }
    }

    /// A few words that tell stages of one cell apart (the collection's robot), or nothing.
    pub fn detail(&self) -> String {
        match self {
            Job::Collect(c) => c.robot.to_string(),
            _ => String::new(),
        }
    }

    /// Runs the job into the empty (or, for a resuming kind, partly filled) folder `staging`.
    pub fn run(&self, upstream: &Upstream, staging: &Path, ctx: &RunContext) -> Result<StageOutputs> {
        match self {
            Job::Collect(j) => collect::run(j, upstream, staging, ctx),
            Job::Pretrain(j) => pretrain::run(j, upstream, staging, ctx),
            Job::Train(j) => train::run(j, upstream, staging, ctx),
            Job::Eval(j) => eval::run(j, upstream, staging, ctx),
        }
    }
}

/// Artifact folders of finished upstream stages, by key.
pub struct Upstream<'a>(pub &'a HashMap<String, PathBuf>);

impl Upstream<'_> {
    /// The artifact folder of upstream stage `key`.
    pub fn get(&self, key: &str) -> Result<&Path> {
        self.0.get(key).map(PathBuf::as_path).with_context(|| format!("upstream stage {key} has no artifact"))
    }
}

/// How a stage runs on this machine: none of it is part of the stage's key.
#[derive(Debug, Clone)]
pub struct RunContext {
    /// Simulation threads for collection and evaluation.
    pub workers: usize,
    /// Device for networks, overriding the configuration's (`run --gpus`).
    pub device: Option<String>,
    /// Show the stage's own progress bar.
    pub progress: bool,
}

impl RunContext {
    /// The device to run on: the override, else the configured one.
    pub fn device_or(&self, configured: &str) -> String {
        self.device.clone().unwrap_or_else(|| configured.to_string())
    }
}

/// Names of the scalar results stages report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MetricName {
    Trajectories,
    Frames,
    ExpertRetries,
    FirstValBc,
    FinalValBc,
    TrainSeconds,
    Parameters,
    Reached,
    Picked,
    Placed,
    /// The pretrained trunk's mean absolute x and y errors on held-out layouts (metres).
    TrunkHeldOutErrorX,
    TrunkHeldOutErrorY,
    /// Predicting the training layouts' mean there instead (metres).
    TrunkMeanErrorX,
    TrunkMeanErrorY,
    /// With `pretrain.object_attention_steps`: the grasp position through the object attention on held-out
    /// layouts, and each task's mean there (metres).
    AttentionHeldOutErrorX,
    AttentionHeldOutErrorY,
    AttentionMeanErrorX,
    AttentionMeanErrorY,
}

impl MetricName {
    /// The name as stored in the `metrics` table.
    pub fn as_str(self) -> &'static str {
        match self {
            MetricName::Trajectories => "trajectories",
            MetricName::Frames => "frames",
            MetricName::ExpertRetries => "expert_retries",
            MetricName::FirstValBc => "first_val_bc",
            MetricName::FinalValBc => "final_val_bc",
            MetricName::TrainSeconds => "train_seconds",
            MetricName::Parameters => "parameters",
            MetricName::Reached => "reached",
            MetricName::Picked => "picked",
            MetricName::Placed => "placed",
            MetricName::TrunkHeldOutErrorX => "trunk_held_out_error_x",
            MetricName::TrunkHeldOutErrorY => "trunk_held_out_error_y",
            MetricName::TrunkMeanErrorX => "trunk_mean_error_x",
            MetricName::TrunkMeanErrorY => "trunk_mean_error_y",
            MetricName::AttentionHeldOutErrorX => "attention_held_out_error_x",
            MetricName::AttentionHeldOutErrorY => "attention_held_out_error_y",
            MetricName::AttentionMeanErrorX => "attention_mean_error_x",
            MetricName::AttentionMeanErrorY => "attention_mean_error_y",
        }
    }
}

/// What a finished stage adds to the results store.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct StageOutputs {
    pub metrics: Vec<(MetricName, f64)>,
    pub episodes: Vec<EpisodeResult>,
    pub curve: Vec<CurvePoint>,
}

/// The collect stages of `plan` and the trajectories they gather in all (both robots).
pub fn collection_totals(plan: &Plan) -> (usize, usize) {
    let jobs: Vec<&collect::CollectJob> = plan
        .stages
        .values()
        .filter_map(|s| match &s.job {
            Job::Collect(c) => Some(c),
            _ => None,
        })
        .collect();
    (jobs.len(), jobs.iter().map(|c| c.per_task * c.settings.tasks.len()).sum())
}

/// Expands `experiment` into its stages and cells: per cell, a collection per robot, the trunk's pretraining
/// where the cell asks for it, training, and an evaluation of the final weights and of each chosen checkpoint;
/// then one evaluation per reference policy.
pub fn plan(experiment: &Experiment) -> Plan {
    let mut plan = Plan::default();
    // With nested sizes, each collection (world and collection settings) is made once, at its largest size.
    let collection_of = |c: &crate::config::CellConfig| serde_json::json!([c.world, c.collect]).to_string();
    let mut largest: HashMap<String, usize> = HashMap::new();
    for cell in &experiment.cells {
        let per_task = cell.per_task();
        let entry = largest.entry(collection_of(&cell.config)).or_insert(per_task);
        *entry = (*entry).max(per_task);
    }
    for cell in &experiment.cells {
        let c = &cell.config;
        let per_task = cell.per_task();
        let collected = if experiment.grid.nested { largest[&collection_of(c)] } else { per_task };
        let demos = collect::add(&mut plan, Robot::Sawyer, collected, c);
        let agents = collect::add(&mut plan, Robot::Panda, collected, c);
        let subset = (per_task < collected).then_some(per_task);
        let pretrain = pretrain::add(&mut plan, c, &agents, subset);
        let train = train::add(&mut plan, c, &demos, &agents, subset, pretrain.as_deref());
        let data = [demos.clone(), agents.clone()];
        let checkpoints =
            c.eval.checkpoints.iter().map(|&s| (s, eval::add_trained(&mut plan, c, &train, Some(s), &data))).collect();
        let eval = eval::add_trained(&mut plan, c, &train, None, &data);
        plan.cells.push(PlannedCell {
            name: cell.name.clone(),
            policy: "model".into(),
            size: Some(cell.size),
            variant: Some(cell.variant.clone()),
            seed: Some(cell.seed),
            collect_demo: Some(demos),
            collect_agent: Some(agents),
            pretrain,
            train: Some(train),
            eval,
            checkpoints,
        });
    }
    for &r in &experiment.grid.references {
        let eval = eval::add_reference(&mut plan, &experiment.base, r);
        plan.cells.push(PlannedCell {
            name: r.name().into(),
            policy: r.name().into(),
            size: None,
            variant: None,
            seed: None,
            collect_demo: None,
            collect_agent: None,
            pretrain: None,
            train: None,
            eval,
            checkpoints: Vec::new(),
        });
    }
    plan
}
