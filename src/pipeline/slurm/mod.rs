//! Stages as Slurm jobs. Each job runs this binary's `run-stage` command ([`super::child`]) for the same experiment
//! file and writes only artifacts (a shared filesystem is assumed): its published artifact folder and a results
//! file that marks it complete. The submitting side keeps the SQLite store on its own disk and records a job's
//! results when it learns that the job ended: at once with `sbatch --wait` ([`Slurm`]), or on a later `run`, `status` or
//! `cancel` for detached submissions ([`detached`]).
pub mod detached;
pub mod queue;

use super::child::{RESULTS_FILE, StageSource, results_of};
use super::executor::{Executor, artifact_dir};
use super::graph::{Stage, short};
use super::stages::StageOutputs;
use anyhow::{Result, bail};
use std::collections::HashMap;
use std::path::PathBuf;

/// How to submit jobs.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// The experiment file, profile and overrides the jobs rebuild their stage from.
    pub source: StageSource,
    /// Extra `sbatch` arguments for every job (e.g. `--partition=cpu`).
    pub args: Vec<String>,
    /// Extra `sbatch` arguments for jobs that run a network (e.g. `--gres=gpu:1`).
    pub gpu_args: Vec<String>,
    /// The experiment file's `[slurm.KIND]` resources, given after the arguments above (so they win where both
    /// set an option).
    pub per_kind: crate::config::slurm::SlurmSection,
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
        match results_of(&self.root, stage.kind(), &stage.key, Some(job))? {
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
