//! Stages in processes of their own. This binary's `run-stage` command rebuilds one stage from the experiment file,
//! runs it against the store's artifacts and leaves its outputs in a results file in the published artifact
//! folder; the side that started it records them in the store. Slurm jobs run it ([`super::slurm`]), and so do
//! concurrent local stages ([`Processes`]): libtorch's random generator is one per process, so stages sharing a
//! process draw from each other's streams, and a stage's result would hang on what ran beside it.
use super::executor::{Executor, Local, artifact_dir};
use super::graph::{Plan, Stage, short};
use super::stages::{Kind, StageOutputs};
use crate::config::Resolution;
use crate::train::stop;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// File in a stage's artifact folder holding what its process measured; its presence marks the process complete.
pub const RESULTS_FILE: &str = "stage-results.json";

/// What a stage process leaves in its artifact folder: the Slurm job it ran in, if any (so that a later attempt's
/// job is never mistaken for an earlier one's; a local process's results are read only once it exited
/// successfully, after it published them), and the stage's outputs.
#[derive(Debug, Serialize, Deserialize)]
struct JobResults {
    job: Option<u64>,
    outputs: StageOutputs,
}

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).with_context(|| format!("resolving {}", p.display()))
}

/// The experiment a stage process rebuilds its stage from: the file, its profile and its `--set` overrides.
#[derive(Debug, Clone)]
pub struct StageSource {
    pub file: PathBuf,
    pub resolution: Resolution,
}

impl StageSource {
    /// The arguments of `run-stage` (after the program) that run stage `key` against the store at `root` with
    /// `workers` simulation threads.
    pub fn arguments(&self, key: &str, root: &Path, workers: usize) -> Result<Vec<String>> {
        let mut line = vec![
            "run-stage".into(),
            absolute(&self.file)?.to_string_lossy().into_owned(),
            "--key".into(),
            key.to_string(),
            "--store".into(),
            absolute(root)?.to_string_lossy().into_owned(),
            "--workers".into(),
            workers.to_string(),
        ];
        if let Some(p) = &self.resolution.profile {
            line.extend(["--profile".into(), p.clone()]);
        }
        for o in &self.resolution.overrides {
            line.extend(["--set".into(), o.to_string()]);
        }
        Ok(line)
    }
}

/// Reads the results a stage process left for `stage_key`, if the process that wrote them ran as Slurm job `job`
/// (none: outside Slurm).
pub fn results_of(root: &Path, kind: Kind, stage_key: &str, job: Option<u64>) -> Result<Option<StageOutputs>> {
    let path = artifact_dir(root, kind, stage_key).join(RESULTS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let results: JobResults = serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    Ok((results.job == job).then_some(results.outputs))
}

/// The process side: runs stage `key` of `plan` in this process (its upstream artifacts found by key, its network
/// on `device` if given) and writes its results file, naming the Slurm job it ran in, into the published artifact
/// folder.
pub fn run_stage(plan: &Plan, key: &str, root: &Path, workers: usize, device: Option<String>) -> Result<()> {
    let stage = plan.stages.get(key).with_context(|| format!("stage {key} is not part of this experiment"))?;
    let upstream: HashMap<String, PathBuf> =
        stage.upstream.iter().map(|u| (u.clone(), artifact_dir(root, plan.stages[u].kind(), u))).collect();
    let local = Local { root: root.to_path_buf(), workers, progress: false };
    let (artifact, outputs) = local.execute(stage, &upstream, device)?;
    let job = std::env::var("SLURM_JOB_ID").ok().and_then(|j| j.parse().ok());
    let results = JobResults { job, outputs };
    crate::fsio::write_atomic(&artifact.join(RESULTS_FILE), serde_json::to_string(&results)?)
}

/// Ends this process once process `parent` is no longer its parent (it died and this one was handed to another):
/// a stage process must not outlive the run that started it, or the next run would reclaim the stage while it
/// still writes.
pub fn exit_with_parent(parent: u32) {
    std::thread::spawn(move || {
        loop {
            if std::os::unix::process::parent_id() != parent {
                eprintln!("error: the run that started this stage (pid {parent}) has gone: stopping");
                // At once, without running exit handlers or destructors while the stage's thread still works.
                unsafe { libc::_exit(1) };
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    });
}

/// Runs each stage in a child process of this binary's `run-stage` command, so that concurrent stages share no
/// libtorch state and every stage gives the result it gives alone. A stage's output goes to
/// `STORE/logs/KIND-KEY-local.log`; SIGTERM or SIGUSR1 to the run is relayed to its stage processes, so that
/// trainings checkpoint and stop as they do in one process.
pub struct Processes {
    pub source: StageSource,
    /// The store folder; artifacts live under `artifacts/`.
    pub root: PathBuf,
    /// Simulation threads per stage.
    pub workers: usize,
}

/// The log of stage `key`'s latest local process.
pub fn log_path(root: &Path, kind: Kind, key: &str) -> PathBuf {
    root.join("logs").join(format!("{}-{}-local.log", kind.name(), short(key)))
}

/// What a failed stage process said: its last `error:` line (or its last line), and how it ended.
fn failure(log: &Path, status: std::process::ExitStatus) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let said = lines.iter().rev().find(|l| l.starts_with("error: ")).or(lines.last()).copied().unwrap_or("");
    let said: String = said.strip_prefix("error: ").unwrap_or(said).chars().take(600).collect();
    let ended = match status.signal() {
        Some(s) => format!("killed by signal {s}"),
        None => format!("exit status {}", status.code().unwrap_or(-1)),
    };
    format!("{said} (stage process {ended}; log: {})", log.display())
}

impl Executor for Processes {
    fn execute(
        &self,
        stage: &Stage,
        _upstream: &HashMap<String, PathBuf>,
        device: Option<String>,
    ) -> Result<(PathBuf, StageOutputs)> {
        let log = log_path(&self.root, stage.kind(), &stage.key);
        let logs = log.parent().expect("a log lies in the logs folder");
        std::fs::create_dir_all(logs).with_context(|| format!("creating {}", logs.display()))?;
        let out = std::fs::File::create(&log).with_context(|| format!("creating {}", log.display()))?;
        // This binary's own file, even if a build has replaced it since the run began: the stage runs the code
        // the run records for it.
        let mut cmd = Command::new("/proc/self/exe");
        cmd.args(self.source.arguments(&stage.key, &self.root, self.workers)?);
        cmd.args(["--parent", &std::process::id().to_string()]);
        if let Some(d) = &device {
            cmd.args(["--device", d]);
        }
        // Inside a Slurm allocation the child would otherwise name the allocation's job in its results.
        cmd.env_remove("SLURM_JOB_ID").stdin(Stdio::null()).stdout(out.try_clone()?).stderr(out);
        // While the stage runs, SIGTERM and SIGUSR1 are this run's to relay rather than its end.
        let _relay = stop::StopGuard::new();
        let mut child = cmd.spawn().context("starting a stage process")?;
        let mut relayed = false;
        let status = loop {
            if let Some(status) = child.try_wait()? {
                break status;
            }
            if !relayed && stop::requested().is_some() {
                unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
                relayed = true;
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        if !status.success() {
            bail!("{}", failure(&log, status));
        }
        let artifact = artifact_dir(&self.root, stage.kind(), &stage.key);
        match results_of(&self.root, stage.kind(), &stage.key, None)? {
            Some(outputs) => Ok((artifact, outputs)),
            None => bail!(
                "the process of stage {} ended without writing {} (log: {})",
                short(&stage.key),
                artifact.join(RESULTS_FILE).display(),
                log.display()
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::stages::MetricName;

    #[test]
    fn results_read_back_every_bit_of_a_float() {
        // Without serde_json's exact float parsing this value came back one unit in the last place off, so an
        // evaluation run in its own process recorded other numbers than the same evaluation run in the run's.
        let root = std::env::temp_dir().join(format!("oneshot-child-results-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let value = 0.13709402414392421_f64;
        let outputs = StageOutputs { metrics: vec![(MetricName::Reached, value)], ..StageOutputs::default() };
        let dir = artifact_dir(&root, Kind::Eval, "k");
        std::fs::create_dir_all(&dir).unwrap();
        let text = serde_json::to_string(&JobResults { job: None, outputs }).unwrap();
        std::fs::write(dir.join(RESULTS_FILE), text).unwrap();
        let read = results_of(&root, Kind::Eval, "k", None).unwrap().expect("results of a local process");
        assert_eq!(read.metrics[0].1.to_bits(), value.to_bits());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
