//! Executes the missing stages of a plan: in dependency order, up to `jobs` at once, claiming each in the store so
//! that concurrent runs never execute a stage twice; a failure stops only the stages below it.
use super::execute::{ExecContext, execute};
use super::graph::{EvalTarget, Job, Plan, Stage, short};
use super::slurm::{SlurmOptions, run_job};
use super::store::{Claim, StageResults, StageState, Store};
use anyhow::Result;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::mpsc::channel;
use std::time::{Duration, Instant};

/// How to run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Stages executed at once.
    pub jobs: usize,
    /// Only cells whose `cell/kind` label matches (plus what they need).
    pub only: Option<String>,
    /// Re-run matching stages (and everything below them) even if cached.
    pub force: Option<String>,
    pub dry_run: bool,
    /// CUDA devices handed out one per network stage (`cuda:0`, ...); empty: the configuration decides.
    pub gpus: Vec<String>,
    /// Simulation threads per collection or evaluation stage.
    pub workers: usize,
    /// Show each stage's own progress bar (only sensible with one job).
    pub progress: bool,
    /// Submit stages to Slurm instead of running them in this process.
    pub slurm: Option<SlurmOptions>,
}

/// What a run did.
#[derive(Debug, Default)]
pub struct RunReport {
    pub executed: Vec<String>,
    pub cached: Vec<String>,
    pub failed: Vec<(String, String)>,
    /// Not run because an upstream stage failed.
    pub skipped: Vec<String>,
    /// What a dry run would execute.
    pub would_run: Vec<String>,
}

/// `*` matches any run of characters; a pattern without `*` matches any label containing it.
pub fn matches(pattern: &str, label: &str) -> bool {
    if !pattern.contains('*') {
        return label.contains(pattern);
    }
    let parts: Vec<&str> = pattern.split('*').collect();
    let mut rest = label;
    for (i, part) in parts.iter().enumerate() {
        if i == 0 {
            let Some(r) = rest.strip_prefix(part) else { return false };
            rest = r;
        } else if i == parts.len() - 1 {
            return rest.ends_with(part);
        } else {
            let Some(pos) = rest.find(part) else { return false };
            rest = &rest[pos + part.len()..];
        }
    }
    rest.is_empty()
}

/// `cell/kind` labels of every stage (a shared stage has several).
pub fn labels(plan: &Plan) -> HashMap<String, Vec<String>> {
    let mut out: HashMap<String, Vec<String>> = HashMap::new();
    for c in &plan.cells {
        let keys = [(&c.collect_demo, "collect"), (&c.collect_agent, "collect"), (&c.train, "train")];
        for (k, kind) in keys {
            if let Some(k) = k {
                out.entry(k.clone()).or_default().push(format!("{}/{kind}", c.name));
            }
        }
        out.entry(c.eval.clone()).or_default().push(format!("{}/eval", c.name));
        for (step, k) in &c.checkpoints {
            out.entry(k.clone()).or_default().push(format!("{}/eval@{step}", c.name));
        }
    }
    out
}

/// A readable name of a stage: its first label and short key.
pub fn display_name(stage: &Stage, labels: &HashMap<String, Vec<String>>) -> String {
    let label = labels.get(&stage.key).and_then(|l| l.first()).cloned().unwrap_or_else(|| stage.kind.name().into());
    let robot = match &stage.job {
        Job::Collect(c) => format!(" {}", c.robot),
        _ => String::new(),
    };
    format!("{label}{robot} [{}]", short(&stage.key))
}

/// The keys to consider: the matching cells' stages and all they depend on, in plan order.
fn selected(plan: &Plan, only: Option<&str>, labels: &HashMap<String, Vec<String>>) -> Vec<String> {
    let Some(p) = only else { return plan.order.clone() };
    let mut want: HashSet<String> = plan
        .order
        .iter()
        .filter(|k| labels.get(*k).is_some_and(|ls| ls.iter().any(|l| matches(p, l))))
        .cloned()
        .collect();
    for k in plan.order.iter().rev() {
        if want.contains(k) {
            want.extend(plan.stages[k].upstream.iter().cloned());
        }
    }
    plan.order.iter().filter(|k| want.contains(*k)).cloned().collect()
}

fn needs_gpu(stage: &Stage) -> bool {
    matches!(stage.job, Job::Train { .. } | Job::Eval { target: EvalTarget::Trained { .. }, .. })
}

#[derive(Debug, Clone, PartialEq)]
enum Status {
    Pending,
    Running,
    Done(PathBuf),
    Failed,
}

/// Runs what is missing of `plan` against the store at `root`.
pub fn run(plan: &Plan, root: &Path, opts: &RunOptions) -> Result<RunReport> {
    let mut store = Store::open(root)?;
    let labels = labels(plan);
    let keys = selected(plan, opts.only.as_deref(), &labels);
    let mut forced: HashSet<String> = HashSet::new();
    if let Some(p) = &opts.force {
        for k in &keys {
            if labels.get(k).is_some_and(|ls| ls.iter().any(|l| matches(p, l))) {
                forced.extend(plan.downstream(k));
            }
        }
    }
    store.register(&keys.iter().map(|k| &plan.stages[k]).collect::<Vec<_>>())?;

    let mut report = RunReport::default();
    let mut status: HashMap<String, Status> = HashMap::new();
    for k in &keys {
        let s = match (store.state(k)?, forced.contains(k)) {
            (StageState::Done, false) => match store.artifact(k)? {
                Some(a) if a.exists() => Status::Done(a),
                _ => Status::Pending,
            },
            _ => Status::Pending,
        };
        if let Status::Done(_) = s {
            report.cached.push(k.clone());
        }
        status.insert(k.clone(), s);
    }
    if opts.dry_run {
        report.would_run = keys.iter().filter(|k| status[*k] == Status::Pending).cloned().collect();
        return Ok(report);
    }

    let total = keys.iter().filter(|k| status[*k] == Status::Pending).count();
    let mut started = 0;
    let mut free_gpus: Vec<String> = opts.gpus.iter().rev().cloned().collect();
    let (tx, rx) = channel::<(String, i64, Option<String>, Result<(PathBuf, StageResults)>)>();
    let mut running = 0usize;
    let jobs = opts.jobs.max(1);
    let clock = Instant::now();
    loop {
        // Start whatever is ready.
        let mut waiting_on_others = false;
        for k in &keys {
            if status[k] != Status::Pending || running >= jobs {
                continue;
            }
            let stage = &plan.stages[k];
            let ups: Vec<&Status> = stage.upstream.iter().map(|u| status.get(u).unwrap_or(&Status::Failed)).collect();
            if ups.iter().any(|s| **s == Status::Failed) {
                status.insert(k.clone(), Status::Failed);
                report.skipped.push(k.clone());
                continue;
            }
            if !ups.iter().all(|s| matches!(s, Status::Done(_))) {
                continue;
            }
            let gpu = if needs_gpu(stage) && !opts.gpus.is_empty() {
                match free_gpus.pop() {
                    Some(g) => Some(g),
                    None => continue,
                }
            } else {
                None
            };
            match store.claim(k, forced.contains(k))? {
                Claim::AlreadyDone => {
                    let a = store.artifact(k)?.unwrap_or_default();
                    status.insert(k.clone(), Status::Done(a));
                    report.cached.push(k.clone());
                    free_gpus.extend(gpu);
                }
                Claim::Busy => {
                    waiting_on_others = true;
                    free_gpus.extend(gpu);
                }
                Claim::Acquired(attempt) => {
                    started += 1;
                    eprintln!("[{started}/{total}] {} {} ...", stage.kind.name(), display_name(stage, &labels));
                    let artifacts = status
                        .iter()
                        .filter_map(|(k, s)| match s {
                            Status::Done(a) => Some((k.clone(), a.clone())),
                            _ => None,
                        })
                        .collect();
                    let ctx = ExecContext {
                        root: root.to_path_buf(),
                        artifacts,
                        workers: opts.workers.max(1),
                        device: gpu.clone(),
                        progress: opts.progress && jobs == 1 && opts.slurm.is_none(),
                    };
                    let (tx, stage, key, slurm) = (tx.clone(), stage.clone(), k.clone(), opts.slurm.clone());
                    std::thread::spawn(move || {
                        let result = match &slurm {
                            Some(s) => run_job(&stage, &ctx, s),
                            None => execute(&stage, &ctx),
                        };
                        let _ = tx.send((key, attempt, gpu, result));
                    });
                    status.insert(k.clone(), Status::Running);
                    running += 1;
                }
            }
        }
        if running == 0 && !waiting_on_others {
            break;
        }
        // Wait for a stage of ours to finish, or poll stages that another process is running.
        let Ok((key, attempt, gpu, result)) = rx.recv_timeout(Duration::from_secs(2)) else { continue };
        running -= 1;
        free_gpus.extend(gpu);
        let stage = &plan.stages[&key];
        match result {
            Ok((artifact, results)) => {
                store.complete(&key, attempt, &artifact, &results)?;
                eprintln!(
                    "    done: {} ({:.0} s into the run)",
                    display_name(stage, &labels),
                    clock.elapsed().as_secs_f64()
                );
                status.insert(key.clone(), Status::Done(artifact));
                report.executed.push(key);
            }
            Err(e) => {
                let msg = format!("{e:#}");
                store.fail(&key, attempt, &msg)?;
                eprintln!("    FAILED: {}: {msg}", display_name(stage, &labels));
                status.insert(key.clone(), Status::Failed);
                report.failed.push((key, msg));
            }
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::matches;

    #[test]
    fn patterns_match_substrings_and_globs() {
        assert!(matches("n480", "n480-full-s0/train"));
        assert!(matches("n480-*-s1/eval", "n480-no_point-s1/eval"));
        assert!(!matches("n480-*-s1/eval", "n480-no_point-s0/eval"));
        assert!(matches("*/eval", "expert/eval"));
        assert!(!matches("*/train", "expert/eval"));
    }
}
