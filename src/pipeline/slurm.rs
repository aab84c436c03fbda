//! Running stages as Slurm jobs: each claimed stage becomes `sbatch --wait` of this binary's `run-stage` command
//! for the same experiment file. The job writes only artifacts (a shared filesystem is assumed); the submitting
//! process keeps the SQLite store on its local disk and records the job's results when it ends.
use super::execute::{ExecContext, artifact_dir, execute};
use super::graph::{EvalTarget, Job, Plan, Stage, short};
use super::store::StageResults;
use anyhow::{Context, Result, bail};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// File in a stage's artifact folder holding what the job measured.
pub const RESULTS_FILE: &str = "stage-results.json";

/// How to submit jobs.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// The experiment file and profile the jobs rebuild their stage from.
    pub file: PathBuf,
    pub profile: Option<String>,
    /// Extra `sbatch` arguments for every job (e.g. `--partition=cpu`).
    pub args: Vec<String>,
    /// Extra `sbatch` arguments for training and network evaluation jobs (e.g. `--gres=gpu:1`).
    pub gpu_args: Vec<String>,
}

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).with_context(|| format!("resolving {}", p.display()))
}

/// Submits `stage` and waits for its job; returns the artifact folder and the results the job wrote.
pub fn run_job(stage: &Stage, ctx: &ExecContext, opts: &SlurmOptions) -> Result<(PathBuf, StageResults)> {
    let exe = std::env::current_exe().context("locating this binary")?;
    let root = absolute(&ctx.root)?;
    let logs = root.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let log = logs.join(format!("{}-{}.log", stage.kind.name(), short(&stage.key)));
    let mut inner = vec![
        exe.to_string_lossy().into_owned(),
        "run-stage".into(),
        absolute(&opts.file)?.to_string_lossy().into_owned(),
        "--key".into(),
        stage.key.clone(),
        "--store".into(),
        root.to_string_lossy().into_owned(),
        "--workers".into(),
        ctx.workers.to_string(),
    ];
    if let Some(p) = &opts.profile {
        inner.extend(["--profile".into(), p.clone()]);
    }
    let wrap = inner.iter().map(|a| shell_quote(a)).collect::<Vec<_>>().join(" ");
    let mut cmd = Command::new("sbatch");
    cmd.args(["--parsable", "--wait", "--job-name"])
        .arg(format!("oneshot-{}-{}", stage.kind.name(), short(&stage.key)))
        .arg("--output")
        .arg(&log)
        .args(&opts.args);
    if matches!(stage.job, Job::Train { .. } | Job::Eval { target: EvalTarget::Trained { .. }, .. }) {
        cmd.args(&opts.gpu_args);
    }
    let out = cmd.arg("--wrap").arg(&wrap).output().context("running sbatch (is Slurm installed and up?)")?;
    if !out.status.success() {
        let tail: Vec<String> =
            std::fs::read_to_string(&log).unwrap_or_default().lines().rev().take(5).map(String::from).collect();
        bail!(
            "Slurm job for stage {} failed ({}): {} (log: {})",
            short(&stage.key),
            String::from_utf8_lossy(&out.stderr).trim(),
            tail.into_iter().rev().collect::<Vec<_>>().join(" | "),
            log.display()
        );
    }
    let artifact = artifact_dir(&root, stage.kind, &stage.key);
    let path = artifact.join(RESULTS_FILE);
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {} written by the job", path.display()))?;
    Ok((artifact, serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?))
}

/// The job side: runs stage `key` of `plan` (its upstream artifacts found by key) and writes its results file.
pub fn run_stage(plan: &Plan, key: &str, root: &Path, workers: usize) -> Result<()> {
    let stage = plan.stages.get(key).with_context(|| format!("stage {key} is not part of this experiment"))?;
    let artifacts: HashMap<String, PathBuf> =
        stage.upstream.iter().map(|u| (u.clone(), artifact_dir(root, plan.stages[u].kind, u))).collect();
    let ctx = ExecContext { root: root.to_path_buf(), artifacts, workers, device: None, progress: false };
    let (artifact, results) = execute(stage, &ctx)?;
    let path = artifact.join(RESULTS_FILE);
    let tmp = artifact.join(format!("{RESULTS_FILE}.partial"));
    std::fs::write(&tmp, serde_json::to_string(&results)?).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))
}

/// Single-quotes `s` for the shell that runs `--wrap`.
fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}
