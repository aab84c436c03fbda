//! `run` and `plan`: an experiment file against the results store.
use crate::config::Experiment;
use crate::pipeline::graph::{Plan, short};
use crate::pipeline::scheduler::{RunOptions, RunReport, display_name, run};
use crate::pipeline::store::{StageState, Store};
use anyhow::{Result, bail};
use std::path::Path;

/// Loads an experiment and expands it.
pub fn load_plan(file: &Path, profile: Option<&str>) -> Result<(Experiment, Plan)> {
    let experiment = Experiment::load(file, profile)?;
    let plan = Plan::build(&experiment);
    Ok((experiment, plan))
}

/// Runs what is missing, records the experiment's cells and (unless `--only` or a dry run) writes its report.
pub fn run_experiment(file: &Path, profile: Option<&str>, root: &Path, opts: &RunOptions) -> Result<RunReport> {
    let (experiment, plan) = load_plan(file, profile)?;
    let report = run(&plan, root, opts)?;
    let labels = crate::pipeline::scheduler::labels(&plan);
    if opts.dry_run {
        println!("{} stages cached, {} to run:", report.cached.len(), report.would_run.len());
        for k in &report.would_run {
            let s = &plan.stages[k];
            println!("  {:<8} {}", s.kind.name(), display_name(s, &labels));
        }
        return Ok(report);
    }
    let mut store = Store::open(root)?;
    store.record_experiment(
        &experiment.name,
        &file.display().to_string(),
        &experiment.description,
        profile,
        &plan.cells,
    )?;
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
        let out = crate::report::report_dir(root, &experiment.name);
        crate::report::write_report(&store, &experiment.name, &out)?;
        println!("report: {}", out.join("index.md").display());
    }
    if !report.failed.is_empty() || !report.skipped.is_empty() {
        bail!("{} stages failed and {} were skipped; run again to retry", report.failed.len(), report.skipped.len());
    }
    Ok(report)
}

fn state_word(s: &StageState) -> &'static str {
    match s {
        StageState::Done => "cached",
        StageState::Missing | StageState::Planned => "to run",
        StageState::Failed(_) => "failed",
        StageState::Running(..) => "running",
    }
}

/// Prints the grid as cells x stages with their state and an estimate of the time left.
pub fn print_plan(file: &Path, profile: Option<&str>, root: &Path) -> Result<()> {
    let (experiment, plan) = load_plan(file, profile)?;
    let mut store = Store::open(root)?;
    store.register(&plan.order.iter().map(|k| &plan.stages[k]).collect::<Vec<_>>())?;
    println!("{}: {} cells, {} distinct stages", experiment.name, plan.cells.len(), plan.stages.len());
    println!("{:<28} {:<20} {:<20} {:<20} {:<20}", "cell", "collect sawyer", "collect panda", "train", "eval");
    let cell_state = |k: &Option<String>| -> Result<String> {
        Ok(match k {
            Some(k) => format!("{} {}", state_word(&store.state(k)?), short(k)),
            None => "-".into(),
        })
    };
    for c in &plan.cells {
        println!(
            "{:<28} {:<20} {:<20} {:<20} {:<20}",
            c.name,
            cell_state(&c.collect_demo)?,
            cell_state(&c.collect_agent)?,
            cell_state(&c.train)?,
            cell_state(&Some(c.eval.clone()))?
        );
    }
    let mut estimate = 0.0;
    let mut unknown = 0;
    let mut todo = 0;
    for s in plan.stages.values() {
        if store.state(&s.key)? == StageState::Done {
            continue;
        }
        todo += 1;
        match store.mean_seconds(s.kind.name())? {
            Some(t) => estimate += t,
            None => unknown += 1,
        }
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
