//! The Slurm executor: each stage becomes `sbatch --wait` of this binary's `run-stage` command for the same
//! experiment file. The job writes only artifacts (a shared filesystem is assumed); the submitting process keeps
//! the SQLite store on its local disk and records the job's results when it ends.
use super::executor::{Executor, Local, artifact_dir};
use super::graph::{Plan, Stage, short};
use super::stages::StageOutputs;
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
    /// Extra `sbatch` arguments for jobs that run a network (e.g. `--gres=gpu:1`).
    pub gpu_args: Vec<String>,
}

/// Runs stages as Slurm jobs.
pub struct Slurm {
    pub options: SlurmOptions,
    /// The store folder, which the compute nodes must see.
    pub root: PathBuf,
    /// Simulation threads per job.
    pub workers: usize,
}

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).with_context(|| format!("resolving {}", p.display()))
}

impl Executor for Slurm {
    /// Submits `stage` and waits for its job; `device` is left to Slurm's GPU allocation.
    fn execute(
        &self,
        stage: &Stage,
        _upstream: &HashMap<String, PathBuf>,
        _device: Option<String>,
    ) -> Result<(PathBuf, StageOutputs)> {
        let opts = &self.options;
        let exe = std::env::current_exe().context("locating this binary")?;
        let root = absolute(&self.root)?;
        let logs = root.join("logs");
        std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
        let name = format!("{}-{}", stage.kind().name(), short(&stage.key));
        let log = logs.join(format!("{name}.log"));
        let mut inner = vec![
            exe.to_string_lossy().into_owned(),
            "run-stage".into(),
            absolute(&opts.file)?.to_string_lossy().into_owned(),
            "--key".into(),
            stage.key.clone(),
            "--store".into(),
            root.to_string_lossy().into_owned(),
            "--workers".into(),
            self.workers.to_string(),
        ];
        if let Some(p) = &opts.profile {
            inner.extend(["--profile".into(), p.clone()]);
        }
        let wrap = inner.iter().map(|a| shell_quote(a)).collect::<Vec<_>>().join(" ");
        let mut cmd = Command::new("sbatch");
        cmd.args(["--parsable", "--wait", "--job-name"]).arg(format!("oneshot-{name}")).arg("--output").arg(&log);
        cmd.args(&opts.args);
        if stage.job.needs_gpu() {
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
        let artifact = artifact_dir(&root, stage.kind(), &stage.key);
        let path = artifact.join(RESULTS_FILE);
        let text =
            std::fs::read_to_string(&path).with_context(|| format!("reading {} written by the job", path.display()))?;
        Ok((artifact, serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?))
    }
}

/// The job side: runs stage `key` of `plan` locally (its upstream artifacts found by key) and writes its results
/// file into the published artifact folder.
pub fn run_stage(plan: &Plan, key: &str, root: &Path, workers: usize) -> Result<()> {
    let stage = plan.stages.get(key).with_context(|| format!("stage {key} is not part of this experiment"))?;
    let upstream: HashMap<String, PathBuf> =
        stage.upstream.iter().map(|u| (u.clone(), artifact_dir(root, plan.stages[u].kind(), u))).collect();
    let local = Local { root: root.to_path_buf(), workers, progress: false };
    let (artifact, outputs) = local.execute(stage, &upstream, None)?;
    crate::fsio::write_atomic(&artifact.join(RESULTS_FILE), serde_json::to_string(&outputs)?)
}

/// Single-quotes `s` for the shell that runs `--wrap`.
fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}
