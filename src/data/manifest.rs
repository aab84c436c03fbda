//! `manifest.json`: what a collection holds, how it was made, and a blake3 digest of every file.
use super::collect_config::CollectConfig;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// File name of the manifest inside a collection folder.
pub const MANIFEST_FILE: &str = "manifest.json";
/// Sub-folder of the trajectory files.
pub const TRAJECTORY_DIR: &str = "trajectories";

/// One trajectory file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ManifestEntry {
    /// Path relative to the collection folder.
    pub file: String,
    pub task: usize,
    /// Slot within the task.
    pub index: usize,
    pub instance_seed: u64,
    /// The pool environment the slot drew, when layouts are shared: its first attempt used that environment's
    /// layout (a retry, a layout of the slot's own); the train/validation split goes by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<u64>,
    /// In the multi-object world, the names of the environment's four objects by slot (the task's object is
    /// `objects[task / 4]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub objects: Option<Vec<String>>,
    /// Expert attempts this slot took (failed layouts are redrawn).
    pub attempts: usize,
    pub steps: usize,
    pub bytes: u64,
    pub blake3: String,
}

impl ManifestEntry {
    /// The file's bytes, checked against its recorded size and blake3 digest.
    pub fn read_verified(&self, dir: &Path) -> Result<Vec<u8>> {
        let path = dir.join(&self.file);
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        if bytes.len() as u64 != self.bytes || blake3::hash(&bytes).to_hex().as_str() != self.blake3 {
            bail!("{} does not match its manifest digest", path.display());
        }
        Ok(bytes)
    }
}

/// The manifest of a collection folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub config: CollectConfig,
    pub trajectories: Vec<ManifestEntry>,
}

impl Manifest {
    /// A manifest for `config` with `trajectories` in slot order.
    pub fn new(config: CollectConfig, trajectories: Vec<ManifestEntry>) -> Manifest {
        Manifest {
            format: format!("oneshot-lab trajectories v{}", super::trajectory::FORMAT_VERSION),
            config,
            trajectories,
        }
    }

    /// Writes `manifest.json` into `dir`.
    pub fn save(&self, dir: &Path) -> Result<()> {
        let path = dir.join(MANIFEST_FILE);
        std::fs::write(&path, serde_json::to_string_pretty(self)? + "\n")
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Reads `manifest.json` from the collection folder `dir`.
    pub fn load(dir: &Path) -> Result<Manifest> {
        let path = dir.join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {} (is {} a collection folder?)", path.display(), dir.display()))?;
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// Checks every file's size and blake3 digest against the manifest.
    pub fn verify(&self, dir: &Path) -> Result<()> {
        for e in &self.trajectories {
            e.read_verified(dir)?;
        }
        Ok(())
    }

    /// Total frames over all trajectories.
    pub fn total_steps(&self) -> usize {
        self.trajectories.iter().map(|e| e.steps).sum()
    }
}
