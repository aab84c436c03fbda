//! Stages as Slurm jobs. Each job runs this binary's `run-stage` command for the same experiment file and writes
//! only artifacts (a shared filesystem is assumed): its published artifact folder and a results file that marks
//! it complete. The submitting side keeps the SQLite store on its own disk and records a job's results when it
//! learns that the job ended: at once with `sbatch --wait` ([`Slurm`]), or on a later `run`, `status` or
//! `cancel` for detached submissions ([`detached`]).
pub mod detached;
pub mod queue;

use super::executor::{Executor, Local, artifact_dir};
use super::graph::{Plan, Stage, short};
use super::stages::{Kind, StageOutputs};
use crate::config::Resolution;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// File in a stage's artifact folder holding what the job measured; its presence marks the job complete.
pub const RESULTS_FILE: &str = "stage-results.json";

/// How to submit jobs.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// The experiment file, profile and overrides the jobs rebuild their stage from.
    pub file: PathBuf,
    pub resolution: Resolution,
    /// Extra `sbatch` arguments for every job (e.g. `--partition=cpu`).
    pub args: Vec<String>,
    /// Extra `sbatch` arguments for jobs that run a network (e.g. `--gres=gpu:1`).
    pub gpu_args: Vec<String>,
    /// The experiment file's `[slurm.KIND]` resources, given after the arguments above (so they win where both
    /// set an option).
    pub per_kind: crate::config::slurm::SlurmSection,
}

/// What a job leaves in its artifact folder: which job it was (so that a later attempt's job is never mistaken for
/// an earlier one's) and the stage's outputs.
#[derive(Debug, Serialize, Deserialize)]
struct JobResults {
    job: Option<u64>,
    outputs: StageOutputs,
}

/// Reads the results a job left for `stage_key`, if job `job` wrote them.
fn results_of(root: &Path, kind: Kind, stage_key: &str, job: u64) -> Result<Option<StageOutputs>> {
    let path = artifact_dir(root, kind, stage_key).join(RESULTS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let results: JobResults = serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    Ok((results.job == Some(job)).then_some(results.outputs))
}

/// Runs stages as Slurm jobs, waiting for each (`sbatch --wait`).
pub struct Slurm {
    pub options: SlurmOptions,
    /// The store folder, which the compute nodes must see.
    pub root: PathBuf,
    /// Simulation threads per job.
    pub workers: usize,
}

impl Executor for Slurm {
    /// Submits `stage` and waits for its job; `device` is left to Slurm's GPU allocation.
    fn execute(
        &self,
        stage: &Stage,
        _upstream: &HashMap<String, PathBuf>,
        _device: Option<String>,
    ) -> Result<(PathBuf, StageOutputs)> {
        let job = queue::submit(stage, &self.options, &self.root, self.workers, &[], true)?;
        let artifact = artifact_dir(&self.root, stage.kind(), &stage.key);
        match results_of(&self.root, stage.kind(), &stage.key, job)? {
            Some(outputs) => Ok((artifact, outputs)),
            None => bail!(
                "Slurm job {job} for stage {} ended without writing {} (log: {})",
                short(&stage.key),
                artifact.join(RESULTS_FILE).display(),
                queue::log_path(&self.root, stage.kind(), &stage.key, job).display()
            ),
        }
    }
}

/// The job side: runs stage `key` of `plan` locally (its upstream artifacts found by key) and writes its results
/// file, naming the Slurm job it ran in, into the published artifact folder.
pub fn run_stage(plan: &Plan, key: &str, root: &Path, workers: usize) -> Result<()> {
    let stage = plan.stages.get(key).with_context(|| format!("stage {key} is not part of this experiment"))?;
    let upstream: HashMap<String, PathBuf> =
        stage.upstream.iter().map(|u| (u.clone(), artifact_dir(root, plan.stages[u].kind(), u))).collect();
    let local = Local { root: root.to_path_buf(), workers, progress: false };
    let (artifact, outputs) = local.execute(stage, &upstream, None)?;
    let job = std::env::var("SLURM_JOB_ID").ok().and_then(|j| j.parse().ok());
    let results = JobResults { job, outputs };
    crate::fsio::write_atomic(&artifact.join(RESULTS_FILE), serde_json::to_string(&results)?)
}
