//! Executing a stage: the local executor runs it in this process; the process executor ([`super::child`]) runs it
//! in a child process (concurrent local stages), the Slurm executor ([`super::slurm`]) as a cluster job, both
//! through the local executor there. Every stage's artifact folder is published the same way: built in a staging
//! folder, then renamed into place, before the store records the stage as done.
use super::graph::{Stage, short};
use super::stages::{Kind, RunContext, StageOutputs, Upstream};
use anyhow::{Context, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Runs stages to completion.
pub trait Executor: Send + Sync {
    /// Runs `stage`, whose upstream artifact folders are `upstream`, with the network on `device` if given;
    /// returns the published artifact folder and the stage's outputs.
    fn execute(
        &self,
        stage: &Stage,
        upstream: &HashMap<String, PathBuf>,
        device: Option<String>,
    ) -> Result<(PathBuf, StageOutputs)>;
}

/// The final artifact folder of a stage.
pub fn artifact_dir(root: &Path, kind: Kind, key: &str) -> PathBuf {
    root.join("artifacts").join(kind.name()).join(short(key))
}

/// The staging folder of a stage: stable across attempts, so that a resuming kind picks up where it stopped.
pub fn staging_dir(root: &Path, key: &str) -> PathBuf {
    root.join("artifacts").join(".staging").join(short(key))
}

/// Runs stages in this process.
pub struct Local {
    /// The store folder; artifacts live under `artifacts/`.
    pub root: PathBuf,
    /// Simulation threads for collection and evaluation.
    pub workers: usize,
    /// Show each stage's own progress bar.
    pub progress: bool,
}

impl Executor for Local {
    fn execute(
        &self,
        stage: &Stage,
        upstream: &HashMap<String, PathBuf>,
        device: Option<String>,
    ) -> Result<(PathBuf, StageOutputs)> {
        let kind = stage.kind();
        let staging = staging_dir(&self.root, &stage.key);
        if !kind.resumes() {
            crate::fsio::remove_dir_if_present(&staging)?;
        }
        std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
        let ctx = RunContext { workers: self.workers, device, progress: self.progress };
        let outputs = stage.job.run(&Upstream(upstream), &staging, &ctx)?;
        let out = artifact_dir(&self.root, kind, &stage.key);
        super::integrity::seal(&staging)?;
        crate::fsio::publish_dir(&staging, &out)?;
        Ok((out, outputs))
    }
}
