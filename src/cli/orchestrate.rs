//! `run`, `run-stage`, `plan` and `cancel`: an experiment file against the results store.
use super::default_workers;
use super::options::{OutputFormat, StoreArgs};
use anyhow::{Context, Result, bail};
use oneshot_lab::config::{Experiment, Grid, overrides};
use oneshot_lab::pipeline::child::{StageSource, exit_with_parent, run_stage as run_one_stage};
use oneshot_lab::pipeline::events::{RunEvent, RunEvents};
use oneshot_lab::pipeline::graph::{Plan, short};
use oneshot_lab::pipeline::integrity;
use oneshot_lab::pipeline::load_plan;
use oneshot_lab::pipeline::scheduler::{RunOptions, RunReport, run as run_plan};
use oneshot_lab::pipeline::selection::{Pattern, display_name};
use oneshot_lab::pipeline::slurm::queue::shell_quote;
use oneshot_lab::pipeline::slurm::{SlurmOptions, detached};
use oneshot_lab::pipeline::stages::{self, collection_totals};
use oneshot_lab::pipeline::store::read::ExperimentRecord;
use oneshot_lab::pipeline::store::{StageState, Store};
use std::collections::BTreeSet;
use std::path::PathBuf;

/// Arguments of the `run` command.
#[derive(clap::Args)]
pub struct RunArgs {
    /// The experiment file.
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Stages executed at once; above 1, each in a process of its own (so it gives the result it gives alone).
    #[arg(long, value_parser = super::options::at_least_one, default_value_t = 1)]
    pub jobs: usize,
    /// Simulation threads per collection or evaluation stage (default: CPU cores).
    #[arg(long, value_parser = super::options::at_least_one)]
    pub workers: Option<usize>,
    /// Only cells whose `cell/kind` label matches (`*` wildcards), plus what they need.
    #[arg(long)]
    pub only: Option<String>,
    /// Re-run matching stages and everything below them.
    #[arg(long)]
    pub force: Option<String>,
    /// Re-run the cached stages of these kinds (collect, pretrain, train, eval; comma-separated) that other code
    /// built (their kind's source changed since: see `plan` and `why`), and everything below them.
    #[arg(long, value_delimiter = ',', value_parser = ["collect", "pretrain", "train", "eval"])]
    pub rerun_code_changed: Vec<String>,
    /// Show what would run.
    #[arg(long)]
    pub dry_run: bool,
    /// CUDA device indices, one per concurrent network stage (e.g. 0,1).
    #[arg(long, value_delimiter = ',')]
    pub gpus: Vec<usize>,
    /// Run each stage as a Slurm job (`sbatch --wait`); `--jobs` bounds jobs in flight.
    #[arg(long)]
    pub slurm: bool,
    /// With --slurm: submit every stage at once, each job waiting on its upstream jobs, and exit; `status` and the
    /// next `run` record what the jobs did, `cancel` stops them.
    #[arg(long, requires = "slurm")]
    pub detach: bool,
    /// Extra sbatch argument for every job (repeatable), e.g. --slurm-arg=--partition=cpu.
    #[arg(long = "slurm-arg", allow_hyphen_values = true)]
    pub slurm_args: Vec<String>,
    /// Extra sbatch argument for network stages (repeatable), e.g. --slurm-gpu-arg=--gres=gpu:1.
    #[arg(long = "slurm-gpu-arg", allow_hyphen_values = true)]
    pub slurm_gpu_args: Vec<String>,
}

/// Arguments of the `run-stage` command.
#[derive(clap::Args)]
pub struct RunStageArgs {
    /// The experiment file the stage belongs to.
    pub file: PathBuf,
    /// The stage's key.
    #[arg(long)]
    pub key: String,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Simulation threads (default: CPU cores).
    #[arg(long, value_parser = super::options::at_least_one)]
    pub workers: Option<usize>,
    /// Device of a network stage (`cuda:N`, as `run --gpus` hands them out); default: the stage's configuration.
    #[arg(long)]
    pub device: Option<String>,
    /// Stop when process PID, the run that started this stage, has gone.
    #[arg(long, value_name = "PID")]
    pub parent: Option<u32>,
}

/// Arguments of the `plan` command.
#[derive(clap::Args)]
pub struct PlanArgs {
    /// The experiment file.
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Text for people or JSON for scripts.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// Arguments of the `cancel` command.
#[derive(clap::Args)]
pub struct CancelArgs {
    /// The experiment file whose jobs are cancelled.
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Prints a run's events on standard error, as they happen.
struct PrintEvents;

impl RunEvents for PrintEvents {
    fn report(&self, event: RunEvent) {
        eprintln!("{event}");
    }
}

/// Runs what is missing, records the experiment's cells and (unless `--only` or a dry run) writes its report.
pub fn run(a: RunArgs) -> Result<()> {
    let (experiment, plan) = load_plan(&a.file, &a.store.resolution())?;
    let source = StageSource { file: a.file.clone(), resolution: a.store.resolution() };
    let slurm = a.slurm.then(|| SlurmOptions {
        source: source.clone(),
        args: a.slurm_args.clone(),
        gpu_args: a.slurm_gpu_args.clone(),
        per_kind: experiment.slurm.clone(),
    });
    let opts = RunOptions {
        slurm,
        jobs: a.jobs,
        only: a.only.as_deref().map(Pattern::new).transpose().context("--only")?,
        force: a.force.as_deref().map(Pattern::new).transpose().context("--force")?,
        rerun_code_changed: a.rerun_code_changed.iter().filter_map(|k| stages::Kind::named(k)).collect(),
        dry_run: a.dry_run,
        gpus: a.gpus.iter().map(|g| format!("cuda:{g}")).collect(),
        workers: a.workers.unwrap_or_else(default_workers),
        progress: true,
        detach: a.detach,
        source: Some(source),
    };
    let root = &a.store.dir.store;
    let report = run_plan(&plan, root, &opts, &PrintEvents)?;
    let labels = plan.labels();
    if opts.dry_run {
        println!("{} stages cached, {} to run:", report.cached.len(), report.would_run.len());
        for k in &report.would_run {
            let s = &plan.stages[k];
            println!("  {:<8} {}", s.kind().name(), display_name(s, &labels));
        }
        return Ok(());
    }
    let mut store = Store::open(root)?;
    let record = ExperimentRecord {
        file: a.file.display().to_string(),
        description: experiment.description.clone(),
        profile: a.store.file.profile.clone(),
        overrides: overrides::spelled(&experiment.resolution.overrides),
    };
    store.record_experiment(&record, &experiment.name, &plan.cells)?;
    if opts.detach {
        return detached_summary(&experiment.name, &a, &report, &plan);
    }
    println!(
        "{}: {} stages run, {} cached, {} failed, {} skipped",
        experiment.name,
        report.executed.len(),
        report.cached.len(),
        report.failed.len(),
        report.skipped.len()
    );
    for (k, e) in &report.failed {
        println!("  failed {}: {e}", display_name(&plan.stages[k], &labels));
    }
    if opts.only.is_none() {
        let out = oneshot_lab::report::report_dir(root, &experiment.name, &[]);
        oneshot_lab::report::write_report(&store, &experiment.name, &[], &out)?;
        super::print::print_table1(&out)?;
        println!("report: {}", out.join("index.md").display());
    }
    if !report.failed.is_empty() || !report.skipped.is_empty() {
        bail!("{} stages failed and {} were skipped; run again to retry", report.failed.len(), report.skipped.len());
    }
    Ok(())
}

/// What a detached run prints: the jobs it submitted and what to do next; an error if Slurm refused any.
fn detached_summary(name: &str, a: &RunArgs, report: &RunReport, plan: &Plan) -> Result<()> {
    let labels = plan.labels();
    let plan_stage = |k: &String| display_name(&plan.stages[k], &labels);
    println!(
        "{name}: {} Slurm jobs submitted, {} already queued, {} stages cached, {} refused, {} held back",
        report.submitted.len(),
        report.queued.len(),
        report.cached.len(),
        report.failed.len(),
        report.skipped.len()
    );
    for (k, job) in &report.submitted {
        println!("  job {job}: {}", plan_stage(k));
    }
    for (k, e) in &report.failed {
        println!("  refused {}: {e}", plan_stage(k));
    }
    let store = a.store.dir.store.display();
    let mut profile = a.store.file.profile.as_ref().map(|p| format!(" --profile {p}")).unwrap_or_default();
    for o in &a.store.file.set {
        profile += &format!(" --set {}", shell_quote(&o.to_string()));
    }
    println!(
        "follow with `oneshot-lab status --store {store}`; when the jobs are done, `oneshot-lab run {}{profile} \
         --store {store}` records them and writes the report (`oneshot-lab cancel` stops them)",
        a.file.display()
    );
    if !report.failed.is_empty() {
        bail!("Slurm refused {} jobs; fix the cause and run again to submit them", report.failed.len());
    }
    Ok(())
}

/// Cancels the queued and running Slurm jobs of an experiment's stages and fails those stages.
pub fn cancel(a: CancelArgs) -> Result<()> {
    let (experiment, plan) = load_plan(&a.file, &a.store.resolution())?;
    let mut store = Store::open_existing(&a.store.dir.store)?;
    let keys = plan.order.iter().cloned().collect();
    let cancelled = detached::cancel(&mut store, &a.store.dir.store, &keys)?;
    println!("{}: {} Slurm jobs cancelled", experiment.name, cancelled.len());
    for (k, job) in &cancelled {
        println!("  job {job}: {}", display_name(&plan.stages[k], &plan.labels()));
    }
    Ok(())
}

/// Runs one stage of an experiment in this process, as a Slurm job or a concurrent local stage does.
pub fn run_stage(a: RunStageArgs) -> Result<()> {
    if let Some(parent) = a.parent {
        exit_with_parent(parent);
    }
    let (_, plan) = load_plan(&a.file, &a.store.resolution())?;
    run_one_stage(&plan, &a.key, &a.store.dir.store, a.workers.unwrap_or_else(default_workers), a.device)
}

fn state_word(s: &StageState) -> &'static str {
    match s {
        StageState::Done => "cached",
        StageState::Missing | StageState::Planned => "to run",
        StageState::Failed(_) => "failed",
        StageState::Running(..) => "running",
    }
}

/// One stage of a cell in `plan`'s output.
#[derive(serde::Serialize)]
struct PlannedStage {
    kind: &'static str,
    key: String,
    state: &'static str,
    /// The training step of a checkpoint's evaluation.
    #[serde(skip_serializing_if = "Option::is_none")]
    step: Option<u64>,
    /// For a cached stage that code other than this binary's built: the commit it was built from.
    #[serde(skip_serializing_if = "Option::is_none")]
    built_by_other_code: Option<String>,
}

/// Prints the grid as cells x stages with their state and an estimate of the time left.
pub fn plan(a: PlanArgs) -> Result<()> {
    let (experiment, plan) = load_plan(&a.file, &a.store.resolution())?;
    let mut store = Store::open(&a.store.dir.store)?;
    store.register(&plan.order.iter().map(|k| &plan.stages[k]).collect::<Vec<_>>())?;
    // A stage is cached only with an intact artifact (a damaged one is marked failed, as `run` would).
    let mut stage = |kind: &'static str, key: &str, step: Option<u64>| -> Result<PlannedStage> {
        let (state, other) = match integrity::cached(&mut store, key)? {
            Some(Ok(_)) => ("cached", store.built_by_other_code(key, plan.stages[key].kind())?.map(|c| c.commit)),
            _ => (state_word(&store.state(key)?), None),
        };
        Ok(PlannedStage { kind, key: key.to_string(), state, step, built_by_other_code: other })
    };
    let mut cells = Vec::new();
    for c in &plan.cells {
        let mut stages = Vec::new();
        for (kind, key) in [
            ("collect sawyer", &c.collect_demo),
            ("collect panda", &c.collect_agent),
            ("pretrain", &c.pretrain),
            ("train", &c.train),
        ] {
            if let Some(k) = key {
                stages.push(stage(kind, k, None)?);
            }
        }
        stages.push(stage("eval", &c.eval, None)?);
        for (step, k) in &c.checkpoints {
            stages.push(stage("eval", k, Some(*step))?);
        }
        cells.push((c.name.clone(), stages));
    }
    let (mut estimate, mut unknown, mut todo) = (0.0, 0, 0);
    for s in plan.stages.values() {
        if matches!(integrity::cached(&mut store, &s.key)?, Some(Ok(_))) {
            continue;
        }
        todo += 1;
        // A training's time scales with its steps: past trainings give seconds per step.
        let steps = s.inputs.get("train").and_then(|t| t.get("steps")).and_then(|v| v.as_f64());
        let seconds = match (s.kind(), steps) {
            (stages::Kind::Train, Some(steps)) => store.mean_seconds_per_train_step()?.map(|t| t * steps),
            _ => store.mean_seconds(s.kind().name())?,
        };
        match seconds {
            Some(t) => estimate += t,
            None => unknown += 1,
        }
    }
    if a.format == OutputFormat::Json {
        let cells: Vec<_> =
            cells.iter().map(|(name, stages)| serde_json::json!({ "cell": name, "stages": stages })).collect();
        let out = serde_json::json!({
            "experiment": experiment.name,
            "distinct_stages": plan.stages.len(),
            "cells": cells,
            "to_run": todo,
            "estimated_seconds": (todo > unknown).then_some(estimate),
            "not_estimated": unknown,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{}: {} cells, {} distinct stages", experiment.name, plan.cells.len(), plan.stages.len());
    if experiment.grid.nested {
        let separate = Experiment { grid: Grid { nested: false, ..experiment.grid.clone() }, ..experiment.clone() };
        let (stages, trajectories) = collection_totals(&plan);
        let (separate_stages, separate_trajectories) = collection_totals(&stages::plan(&separate));
        if separate_trajectories > trajectories {
            println!(
                "nested dataset sizes: {stages} collections of {trajectories} trajectories in all, instead of \
                 {separate_stages} of {separate_trajectories} collected separately ({} fewer; grid.nested = false \
                 collects each size on its own)",
                separate_trajectories - trajectories
            );
        }
    }
    let columns = ["collect sawyer", "collect panda", "pretrain", "train"];
    let width = cells.iter().map(|(name, _)| name.len()).max().unwrap_or(0).max(28);
    println!("{:<width$} {:<20} {:<20} {:<20} {:<20} eval", "cell", columns[0], columns[1], columns[2], columns[3]);
    for (name, stages) in &cells {
        let shown = |s: &PlannedStage| {
            let mark = if s.built_by_other_code.is_some() { "*" } else { "" };
            format!("{}{mark} {}", s.state, short(&s.key))
        };
        let column = |kind: &str| stages.iter().find(|s| s.kind == kind).map_or("-".to_string(), shown);
        let evals: Vec<String> = stages.iter().filter(|s| s.kind == "eval").map(shown).collect();
        println!(
            "{name:<width$} {:<20} {:<20} {:<20} {:<20} {}",
            column(columns[0]),
            column(columns[1]),
            column(columns[2]),
            column(columns[3]),
            evals.join(", ")
        );
    }
    let mut other: Vec<(&str, &str)> = cells
        .iter()
        .flat_map(|(_, stages)| stages.iter())
        .filter_map(|s| Some((plan.stages[&s.key].kind().name(), s.built_by_other_code.as_deref()?)))
        .collect();
    other.sort();
    other.dedup();
    if !other.is_empty() {
        let mut kinds: Vec<&str> = other.iter().map(|(kind, _)| *kind).collect();
        kinds.dedup();
        let commits: BTreeSet<&str> = other.iter().map(|(_, commit)| *commit).collect();
        println!(
            "cached* : built by other code (commit {}; the source of its kind changed since): \
             `run --rerun-code-changed {}` re-runs them",
            commits.into_iter().collect::<Vec<_>>().join(", "),
            kinds.join(",")
        );
    }
    print!("{todo} stages to run");
    if todo > unknown {
        print!(", about {estimate:.0} s of work judging by past stages of the same kinds");
    }
    if unknown > 0 {
        print!(" ({unknown} of a kind never run in this store, so not estimated)");
    }
    println!();
    Ok(())
}
