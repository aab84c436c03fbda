//! Artifact folders that no stage of the given plans uses, and their removal.
use super::graph::{Plan, short};
use super::stages::Kind;
use super::store::Store;
use anyhow::{Context, Result};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Artifact and staging folders under store `root` whose stage belongs to none of `plans` and that no running
/// attempt holds (`held`: stage keys), sorted.
pub fn unused_artifacts(root: &Path, plans: &[Plan], held: &[String]) -> Result<Vec<PathBuf>> {
    let keep: HashSet<&str> =
        plans.iter().flat_map(|p| p.stages.keys().map(|k| short(k))).chain(held.iter().map(|k| short(k))).collect();
    let artifacts = root.join("artifacts");
    let mut unused = Vec::new();
    for dir in Kind::ALL.iter().map(|k| k.name()).chain([".staging"]).map(|d| artifacts.join(d)) {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries {
            let path = e?.path();
            if !path.file_name().and_then(|n| n.to_str()).is_some_and(|n| keep.contains(n)) {
                unused.push(path);
            }
        }
    }
    unused.sort();
    Ok(unused)
}

/// Bytes under `path` (files only, links not followed).
pub fn folder_size(path: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(path) else { return 0 };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => folder_size(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// Removes `folders` and marks their stages to be re-run.
pub fn remove_artifacts(store: &mut Store, folders: &[PathBuf]) -> Result<()> {
    for path in folders {
        std::fs::remove_dir_all(path).with_context(|| format!("removing {}", path.display()))?;
        store.forget_artifact(path)?;
    }
    Ok(())
}
