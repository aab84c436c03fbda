//! Executes the missing stages of a plan: in dependency order, up to `jobs` at once, claiming each in the store so
//! that concurrent runs never execute a stage twice; a failure stops only the stages below it.
use super::child::{Processes, StageSource};
use super::events::{RunEvent, RunEvents};
use super::executor::{Executor, Local};
use super::graph::{Plan, short};
use super::selection::{Labels, Pattern, built_by_other_code, display_name, forced, selected};
use super::slurm::{Slurm, SlurmOptions, detached};
use super::stages::{Kind, StageOutputs};
use super::store::{Claim, Store};
use anyhow::{Context, Result};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::{Duration, Instant};

/// How to run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Stages executed at once.
    pub jobs: usize,
    /// Only cells whose `cell/kind` label matches (plus what they need).
    pub only: Option<Pattern>,
    /// Re-run matching stages (and everything below them) even if cached.
    pub force: Option<Pattern>,
    /// Re-run cached stages of these kinds that code other than this binary's built (and everything below them).
    pub rerun_code_changed: Vec<Kind>,
    pub dry_run: bool,
    /// CUDA devices handed out one per network stage (`cuda:0`, ...); empty: the configuration decides.
    pub gpus: Vec<String>,
    /// Simulation threads per collection or evaluation stage.
    pub workers: usize,
    /// Show the stage's own progress bar when one runs at a time.
    pub progress: bool,
    /// Submit stages to Slurm instead of running them here.
    pub slurm: Option<SlurmOptions>,
    /// Where a stage process rebuilds its stage from: with `jobs` above 1 every local stage runs in a process of
    /// its own ([`Processes`]), which needs it.
    pub source: Option<StageSource>,
    /// With `slurm`: submit every stage at once, chained by dependencies, and return without waiting.
    pub detach: bool,
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
    /// Stages a detached run submitted, with their Slurm job ids.
    pub submitted: Vec<(String, u64)>,
    /// Stages already held by a Slurm job of an earlier detached run.
    pub queued: Vec<(String, u64)>,
}

#[derive(Debug, Clone, PartialEq)]
enum Status {
    Pending,
    Running,
    Done(PathBuf),
    Failed,
}

/// A finished execution: stage key, store attempt, the GPU it held, and the outcome.
type Finished = (String, i64, Option<String>, Result<(PathBuf, StageOutputs)>);

/// The state of one run.
struct Scheduler<'a> {
    plan: &'a Plan,
    store: Store,
    events: &'a dyn RunEvents,
    labels: Labels,
    keys: Vec<String>,
    forced: HashSet<String>,
    status: HashMap<String, Status>,
    report: RunReport,
    executor: Arc<dyn Executor>,
    jobs: usize,
    free_gpus: Vec<String>,
    use_gpus: bool,
    running: usize,
    started: usize,
    total: usize,
    clock: Instant,
    tx: Sender<Finished>,
    rx: Receiver<Finished>,
    /// Stages held by another process whose wait was already announced.
    announced_waits: HashSet<String>,
}

impl Scheduler<'_> {
    /// Whether stage `key` needs to run (not cached, or forced).
    fn initial_status(&mut self, key: &str) -> Result<Status> {
        if self.forced.contains(key) {
            return Ok(Status::Pending);
        }
        Ok(match super::integrity::cached(&mut self.store, key)? {
            Some(Ok(artifact)) => Status::Done(artifact),
            Some(Err(reason)) => {
                let kind = self.plan.stages[key].kind().name();
                self.events.report(RunEvent::Warning(format!("{kind} stage {}: {reason}", short(key))));
                Status::Pending
            }
            None => Status::Pending,
        })
    }

    /// Starts every ready stage while job slots (and GPUs, where needed) are free; returns whether a stage is
    /// held by another process.
    fn start_ready(&mut self) -> Result<bool> {
        let mut waiting_on_others = false;
        if crate::train::stop::requested().is_some() {
            // Asked to stop (a cluster's warning): the running stages wind down, no new one starts.
            return Ok(false);
        }
        for k in self.keys.clone() {
            if self.status[&k] != Status::Pending || self.running >= self.jobs {
                continue;
            }
            let stage = &self.plan.stages[&k];
            let ups: Vec<&Status> =
                stage.upstream.iter().map(|u| self.status.get(u).unwrap_or(&Status::Failed)).collect();
            if ups.contains(&&Status::Failed) {
                self.status.insert(k.clone(), Status::Failed);
                self.report.skipped.push(k);
                continue;
            }
            if !ups.iter().all(|s| matches!(s, Status::Done(_))) {
                continue;
            }
            let gpu = if stage.job.needs_gpu() && self.use_gpus {
                match self.free_gpus.pop() {
                    Some(g) => Some(g),
                    None => continue,
                }
            } else {
                None
            };
            match self.store.claim(&k, self.forced.contains(&k))? {
                Claim::AlreadyDone => {
                    let a = self.store.artifact(&k)?.unwrap_or_default();
                    self.status.insert(k.clone(), Status::Done(a));
                    self.report.cached.push(k);
                    self.free_gpus.extend(gpu);
                }
                Claim::Busy(holder) => {
                    waiting_on_others = true;
                    self.free_gpus.extend(gpu);
                    if self.announced_waits.insert(k.clone()) {
                        self.events.report(RunEvent::Waiting { stage: display_name(stage, &self.labels), holder });
                    }
                }
                Claim::Acquired(attempt) => self.launch(&k, attempt, gpu),
            }
        }
        Ok(waiting_on_others)
    }

    /// Runs stage `key` on a thread of its own.
    fn launch(&mut self, key: &str, attempt: i64, gpu: Option<String>) {
        let stage = self.plan.stages[key].clone();
        self.started += 1;
        self.events.report(RunEvent::Started {
            number: self.started,
            total: self.total,
            kind: stage.kind().name(),
            stage: display_name(&stage, &self.labels),
        });
        let upstream: HashMap<String, PathBuf> = stage
            .upstream
            .iter()
            .filter_map(|u| match &self.status[u] {
                Status::Done(a) => Some((u.clone(), a.clone())),
                _ => None,
            })
            .collect();
        self.status.insert(key.to_string(), Status::Running);
        let (tx, executor, key) = (self.tx.clone(), self.executor.clone(), key.to_string());
        std::thread::spawn(move || {
            let result = executor.execute(&stage, &upstream, gpu.clone());
            let _ = tx.send((key, attempt, gpu, result));
        });
        self.running += 1;
    }

    /// Records a finished execution in the store.
    fn finish(&mut self, (key, attempt, gpu, result): Finished) -> Result<()> {
        self.running -= 1;
        self.free_gpus.extend(gpu);
        let name = display_name(&self.plan.stages[&key], &self.labels);
        match result {
            Ok((artifact, outputs)) => {
                self.store.complete(&key, attempt, &artifact, &outputs)?;
                self.events.report(RunEvent::Done { stage: name, seconds: self.clock.elapsed().as_secs_f64() });
                self.status.insert(key.clone(), Status::Done(artifact));
                self.report.executed.push(key);
            }
            Err(e) => {
                let msg = format!("{e:#}");
                self.store.fail(&key, attempt, &msg)?;
                self.events.report(RunEvent::Failed { stage: name, message: msg.clone() });
                self.status.insert(key.clone(), Status::Failed);
                self.report.failed.push((key, msg));
            }
        }
        Ok(())
    }
}

/// How often a run waiting on Slurm jobs asks the queue about them.
const SLURM_POLL: Duration = Duration::from_secs(15);

/// Records what Slurm jobs of earlier detached runs did; without a reachable Slurm it says so and goes on (their
/// stages stay held until a run that can see the queue catches up).
fn catch_up_with_slurm(store: &mut Store, root: &Path, events: &dyn RunEvents) {
    match detached::catch_up(store, root) {
        Ok(c) => {
            for (key, why) in c.failed {
                events.report(RunEvent::SlurmJobFailed { key, why });
            }
        }
        Err(e) => events.report(RunEvent::Warning(format!("could not catch up with Slurm jobs: {e:#}"))),
    }
}

/// Runs what is missing of `plan` against the store at `root`, telling `events` what happens.
pub fn run(plan: &Plan, root: &Path, opts: &RunOptions, events: &dyn RunEvents) -> Result<RunReport> {
    let mut store = Store::open(root)?;
    let labels = plan.labels();
    let keys = selected(plan, opts.only.as_ref(), &labels)?;
    let mut forced = forced(plan, &keys, opts.force.as_ref(), &labels)?;
    if !opts.rerun_code_changed.is_empty() {
        let changed = built_by_other_code(plan, &keys, &opts.rerun_code_changed, &store)?;
        let kinds: Vec<&str> = opts.rerun_code_changed.iter().map(|k| k.name()).collect();
        events.report(RunEvent::CodeChanged { kinds: kinds.join(","), stages: changed.len() });
        forced.extend(changed);
    }
    store.register(&keys.iter().map(|k| &plan.stages[k]).collect::<Vec<_>>())?;
    if let (Some(slurm), true, false) = (&opts.slurm, opts.detach, opts.dry_run) {
        let s = detached::submit(plan, &mut store, root, slurm, opts.workers.max(1), &keys, &forced)?;
        return Ok(RunReport {
            cached: s.cached,
            failed: s.refused,
            skipped: s.held_back,
            submitted: s.submitted,
            queued: s.queued,
            ..RunReport::default()
        });
    }
    catch_up_with_slurm(&mut store, root, events);
    let jobs = opts.jobs.max(1);
    let executor: Arc<dyn Executor> = match &opts.slurm {
        Some(s) => Arc::new(Slurm { options: s.clone(), root: root.to_path_buf(), workers: opts.workers.max(1) }),
        None if jobs > 1 => Arc::new(Processes {
            source: opts.source.clone().context("concurrent local stages need the experiment they come from")?,
            root: root.to_path_buf(),
            workers: opts.workers.max(1),
        }),
        None => Arc::new(Local { root: root.to_path_buf(), workers: opts.workers.max(1), progress: opts.progress }),
    };
    let (tx, rx) = channel();
    let mut s = Scheduler {
        plan,
        store,
        events,
        labels,
        keys,
        forced,
        status: HashMap::new(),
        report: RunReport::default(),
        executor,
        jobs,
        free_gpus: opts.gpus.iter().rev().cloned().collect(),
        use_gpus: !opts.gpus.is_empty(),
        running: 0,
        started: 0,
        total: 0,
        clock: Instant::now(),
        tx,
        rx,
        announced_waits: HashSet::new(),
    };
    for k in s.keys.clone() {
        let status = s.initial_status(&k)?;
        if let Status::Done(_) = status {
            s.report.cached.push(k.clone());
        }
        s.status.insert(k, status);
    }
    let pending: Vec<String> = s.keys.iter().filter(|k| s.status[*k] == Status::Pending).cloned().collect();
    if opts.dry_run {
        s.report.would_run = pending;
        return Ok(s.report);
    }
    s.total = pending.len();
    let mut last_catch_up = Instant::now();
    loop {
        let waiting_on_others = s.start_ready()?;
        if s.running == 0 && !waiting_on_others {
            break;
        }
        // Wait for a stage of ours to finish, or poll stages that another process or a Slurm job is running.
        if let Ok(finished) = s.rx.recv_timeout(Duration::from_secs(2)) {
            s.finish(finished)?;
        }
        if waiting_on_others && last_catch_up.elapsed() > SLURM_POLL {
            catch_up_with_slurm(&mut s.store, root, events);
            last_catch_up = Instant::now();
        }
    }
    Ok(s.report)
}
