//! The Slurm commands: `sbatch` to submit a stage, `squeue` to read jobs' states, `scancel` to stop them.
use super::SlurmOptions;
use crate::pipeline::graph::{Stage, short};
use crate::pipeline::stages::Kind;
use anyhow::{Context, Result, bail};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).with_context(|| format!("resolving {}", p.display()))
}

/// The job name of a stage of `kind` (`oneshot-` prefixed in the queue) and the stem of its log files.
fn job_name(kind: Kind, key: &str) -> String {
    format!("{}-{}", kind.name(), short(key))
}

/// The log of job `job` running stage `key`: `STORE/logs/KIND-KEY-JOB.log`.
pub fn log_path(root: &Path, kind: Kind, key: &str, job: u64) -> PathBuf {
    root.join("logs").join(format!("{}-{job}.log", job_name(kind, key)))
}

/// The last `n` lines of a job's log, joined with ` | ` (empty when there is no log).
pub fn log_tail(path: &Path, n: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut lines: Vec<&str> = text.lines().rev().take(n).collect();
    lines.reverse();
    lines.join(" | ")
}

/// Submits `stage` as a job of this binary's `run-stage` command, starting once every job in `after` has
/// succeeded; with `wait`, returns only when the job has ended (an error if it failed). Returns the job id.
pub fn submit(
    stage: &Stage,
    opts: &SlurmOptions,
    root: &Path,
    workers: usize,
    after: &[u64],
    wait: bool,
) -> Result<u64> {
    let root = absolute(root)?;
    let logs = root.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let name = job_name(stage.kind(), &stage.key);
    let exe = std::env::current_exe().context("locating this binary")?;
    let mut inner = vec![exe.to_string_lossy().into_owned()];
    inner.extend(opts.source.arguments(&stage.key, &root, workers)?);
    // `exec`: the job's shell becomes this binary, so the signals Slurm sends before preemption or the time
    // limit reach the training itself rather than a shell that would die of them first.
    let wrap = format!("exec {}", inner.iter().map(|a| shell_quote(a)).collect::<Vec<_>>().join(" "));
    let mut cmd = Command::new("sbatch");
    cmd.args(["--parsable", "--job-name"]).arg(format!("oneshot-{name}"));
    cmd.arg("--output").arg(logs.join(format!("{name}-%j.log")));
    if wait {
        cmd.arg("--wait");
    }
    if !after.is_empty() {
        let ids: Vec<String> = after.iter().map(u64::to_string).collect();
        cmd.arg(format!("--dependency=afterok:{}", ids.join(":")));
    }
    cmd.args(&opts.args);
    if stage.job.needs_gpu() {
        cmd.args(&opts.gpu_args);
    }
    if let Some(resources) = opts.per_kind.of(stage.kind().name()) {
        cmd.args(resources.sbatch_args());
    }
    let out = cmd.arg("--wrap").arg(&wrap).output().context("running sbatch (is Slurm installed and up?)")?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let job = stdout.lines().next().and_then(|l| l.split(';').next()).and_then(|id| id.trim().parse::<u64>().ok());
    let stderr = String::from_utf8_lossy(&out.stderr);
    match job {
        None => bail!("Slurm refused the job for stage {}: {}", short(&stage.key), stderr.trim()),
        Some(job) if !out.status.success() => bail!(
            "Slurm job {job} for stage {} failed ({}): {} (log: {})",
            short(&stage.key),
            stderr.trim(),
            log_tail(&log_path(&root, stage.kind(), &stage.key, job), 5),
            log_path(&root, stage.kind(), &stage.key, job).display()
        ),
        Some(job) => Ok(job),
    }
}

/// A job as the queue reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QueueEntry {
    /// `PENDING`, `RUNNING`, `COMPLETED`, `FAILED`, `CANCELLED`, ...
    pub state: String,
    /// Why it waits (`Resources`, `Dependency`, `DependencyNeverSatisfied`, ...).
    pub reason: String,
}

impl QueueEntry {
    /// Whether the job may still run to completion.
    pub fn live(&self) -> bool {
        let waiting = ["PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "SUSPENDED", "REQUEUED", "RESIZING"];
        waiting.contains(&self.state.as_str()) && self.reason != "DependencyNeverSatisfied"
    }
}

/// The queue's view of `jobs`; a job Slurm no longer knows is absent from the map.
pub fn states(jobs: &[u64]) -> Result<HashMap<u64, QueueEntry>> {
    if jobs.is_empty() {
        return Ok(HashMap::new());
    }
    let ids: Vec<String> = jobs.iter().map(u64::to_string).collect();
    let out = Command::new("squeue")
        .args(["--noheader", "--states=all", "--format=%i|%T|%r", "--jobs"])
        .arg(ids.join(","))
        .output()
        .context("running squeue (is Slurm installed and up?)")?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        // Asked only about jobs it has forgotten, squeue fails with this; that is an answer, not an error.
        if stderr.contains("Invalid job id") {
            return Ok(HashMap::new());
        }
        bail!("squeue failed: {}", stderr.trim());
    }
    Ok(parse_states(&String::from_utf8_lossy(&out.stdout)))
}

/// Parses `squeue --format=%i|%T|%r` lines.
fn parse_states(text: &str) -> HashMap<u64, QueueEntry> {
    text.lines()
        .filter_map(|line| {
            let mut parts = line.trim().split('|');
            let id = parts.next()?.parse().ok()?;
            let state = parts.next()?.to_string();
            let reason = parts.next().unwrap_or_default().to_string();
            Some((id, QueueEntry { state, reason }))
        })
        .collect()
}

/// Cancels `jobs`.
pub fn cancel(jobs: &[u64]) -> Result<()> {
    if jobs.is_empty() {
        return Ok(());
    }
    let out = Command::new("scancel")
        .args(jobs.iter().map(u64::to_string))
        .output()
        .context("running scancel (is Slurm installed and up?)")?;
    if !out.status.success() {
        bail!("scancel failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    Ok(())
}

/// `s` single-quoted for a POSIX shell (the one that runs `--wrap`, or a command printed for the user).
pub fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queue_lines_parse_and_an_unsatisfiable_dependency_is_not_live() {
        let states = parse_states("17|CANCELLED|BeginTime\n18|PENDING|DependencyNeverSatisfied\n19|RUNNING|None\n");
        assert_eq!(states.len(), 3);
        assert!(!states[&17].live());
        assert!(!states[&18].live(), "a job whose upstream failed never runs");
        assert!(states[&19].live());
        assert!(QueueEntry { state: "PENDING".into(), reason: "Dependency".into() }.live());
    }
}
