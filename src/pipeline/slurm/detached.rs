//! Detached Slurm runs: every stage a run needs is submitted at once, each job starting after the jobs of its
//! upstream stages succeed (`--dependency=afterok`), and the submitting process exits. The store records each
//! stage as held by its job; a later `run`, `status` or `cancel` catches up ([`catch_up`]): a job that left its
//! results file completes its stage, a job that ended without one (failed, killed, timed out, or waiting on an
//! upstream job that failed) fails it, so the next detached run submits it again.
use super::SlurmOptions;
use super::queue::{self, QueueEntry};
use crate::pipeline::child::results_of;
use crate::pipeline::executor::artifact_dir;
use crate::pipeline::graph::{Plan, short};
use crate::pipeline::stages::Kind;
use crate::pipeline::store::jobs::{SLURM_HOST, SubmittedJob};
use crate::pipeline::store::{Claim, StageState, Store};
use anyhow::{Context, Result};
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// What a detached submission did.
#[derive(Debug, Default)]
pub struct Submission {
    /// Stages submitted now, with their job ids.
    pub submitted: Vec<(String, u64)>,
    /// Stages already held by a queued or running job from an earlier submission.
    pub queued: Vec<(String, u64)>,
    /// Stages Slurm refused, with the reason.
    pub refused: Vec<(String, String)>,
    /// Stages not submitted: an upstream stage failed to submit, or a local process is running one.
    pub held_back: Vec<String>,
    /// Stages already done.
    pub cached: Vec<String>,
}

/// Submits every stage of `keys` (plan order) that is not done, or is in `forced`, unless a live job already
/// holds it.
pub fn submit(
    plan: &Plan,
    store: &mut Store,
    root: &Path,
    options: &SlurmOptions,
    workers: usize,
    keys: &[String],
    forced: &HashSet<String>,
) -> Result<Submission> {
    catch_up(store, root)?;
    let mut jobs: HashMap<String, u64> = store.slurm_jobs()?.into_iter().map(|j| (j.key, j.job)).collect();
    let mut out = Submission::default();
    for key in keys {
        if let Some(&job) = jobs.get(key) {
            out.queued.push((key.clone(), job));
            continue;
        }
        let force = forced.contains(key);
        if !force && store.state(key)? == StageState::Done {
            out.cached.push(key.clone());
            continue;
        }
        let stage = &plan.stages[key];
        let mut after = Vec::new();
        let mut ready = true;
        for up in &stage.upstream {
            match jobs.get(up) {
                Some(&job) => after.push(job),
                None => ready &= !forced.contains(up) && store.state(up)? == StageState::Done,
            }
        }
        if !ready {
            out.held_back.push(key.clone());
            continue;
        }
        match store.claim(key, force)? {
            Claim::AlreadyDone => out.cached.push(key.clone()),
            Claim::Busy(holder) if holder.host == SLURM_HOST => {
                jobs.insert(key.clone(), holder.pid as u64);
                out.queued.push((key.clone(), holder.pid as u64));
            }
            Claim::Busy(_) => out.held_back.push(key.clone()),
            Claim::Acquired(attempt) => match queue::submit(stage, options, root, workers, &after, false) {
                Ok(job) => {
                    store.hand_to_slurm(attempt, job)?;
                    jobs.insert(key.clone(), job);
                    out.submitted.push((key.clone(), job));
                }
                Err(e) => {
                    let message = format!("{e:#}");
                    store.fail(key, attempt, &message)?;
                    out.refused.push((key.clone(), message));
                }
            },
        }
    }
    Ok(out)
}

/// What catching up with the queue found.
#[derive(Debug, Default)]
pub struct CatchUp {
    /// Stages whose job finished and left its results, now done.
    pub completed: Vec<String>,
    /// Stages whose job ended without results, now failed, with why.
    pub failed: Vec<(String, String)>,
    /// Jobs still queued or running, with the queue's view of them.
    pub live: Vec<(SubmittedJob, QueueEntry)>,
}

/// Records the outcome of every Slurm job the store is waiting on.
pub fn catch_up(store: &mut Store, root: &Path) -> Result<CatchUp> {
    let jobs = store.slurm_jobs()?;
    let mut out = CatchUp::default();
    if jobs.is_empty() {
        return Ok(out);
    }
    // The queue first, results second: a job that has left the queue wrote its results file before it left.
    let queue = queue::states(&jobs.iter().map(|j| j.job).collect::<Vec<_>>())?;
    for j in jobs {
        let kind = Kind::named(&j.kind).with_context(|| format!("stage {} has unknown kind {}", j.key, j.kind))?;
        if let Some(outputs) = results_of(root, kind, &j.key, Some(j.job))? {
            store.complete(&j.key, j.attempt, &artifact_dir(root, kind, &j.key), &outputs)?;
            out.completed.push(j.key);
            continue;
        }
        let entry = queue.get(&j.job).cloned();
        if let Some(e) = entry.as_ref().filter(|e| e.live()) {
            out.live.push((j, e.clone()));
            continue;
        }
        let log = queue::log_path(root, kind, &j.key, j.job);
        let message = match entry {
            Some(e) if e.reason == "DependencyNeverSatisfied" => {
                queue::cancel(&[j.job])?;
                format!("Slurm job {} cancelled: a job it depended on failed", j.job)
            }
            Some(e) => format!("Slurm job {} ended {} without results{}", j.job, e.state, log_summary(&log)),
            None => format!("Slurm job {} left the queue without results{}", j.job, log_summary(&log)),
        };
        store.fail(&j.key, j.attempt, &message)?;
        out.failed.push((j.key, message));
    }
    Ok(out)
}

/// The end of a job's log for an error message, or that it wrote none.
fn log_summary(log: &Path) -> String {
    match queue::log_tail(log, 5) {
        tail if tail.is_empty() => format!(" and no log ({} is empty or absent)", log.display()),
        tail => format!(": {tail} (log: {})", log.display()),
    }
}

/// Cancels the live jobs of `keys` and fails their stages; returns the stages and jobs cancelled.
pub fn cancel(store: &mut Store, root: &Path, keys: &HashSet<String>) -> Result<Vec<(String, u64)>> {
    let live = catch_up(store, root)?.live;
    let mine: Vec<&SubmittedJob> = live.iter().map(|(j, _)| j).filter(|j| keys.contains(&j.key)).collect();
    queue::cancel(&mine.iter().map(|j| j.job).collect::<Vec<_>>())?;
    for j in &mine {
        store.fail(&j.key, j.attempt, &format!("Slurm job {} cancelled by `oneshot-lab cancel`", j.job))?;
    }
    Ok(mine.iter().map(|j| (j.key.clone(), j.job)).collect())
}

/// A one-line account of a job for `status`: stage kind and key, job id and the queue's state.
pub fn describe(job: &SubmittedJob, entry: &QueueEntry) -> String {
    let why =
        if entry.reason.is_empty() || entry.reason == "None" { String::new() } else { format!(", {}", entry.reason) };
    format!("{} {} is Slurm job {} ({}{why})", job.kind, short(&job.key), job.job, entry.state)
}
