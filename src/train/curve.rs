//! The loss curve: one record per (step, split), kept as JSON lines beside the checkpoints.
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Losses at one step of one split (mean over the batches it covers).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    pub step: u64,
    /// `train` or `val`.
    pub split: String,
    pub bc: f64,
    pub inverse: f64,
    pub point: f64,
    /// Weighted sum as optimised.
    pub total: f64,
}

/// Reads the curve at `path`, keeping points up to `max_step` (what a resumed run has already done).
pub fn read(path: &Path, max_step: u64) -> Result<Vec<CurvePoint>> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut points = Vec::new();
    for (i, line) in text.lines().enumerate() {
        // A torn last line from an interrupted write is dropped; anything else must parse.
        match serde_json::from_str::<CurvePoint>(line) {
            Ok(p) if p.step <= max_step => points.push(p),
            Ok(_) => {}
            Err(e) if i + 1 == text.lines().count() => drop(e),
            Err(e) => return Err(e).with_context(|| format!("{}:{}", path.display(), i + 1)),
        }
    }
    Ok(points)
}

/// Rewrites the curve at `path` atomically.
pub fn write(path: &Path, points: &[CurvePoint]) -> Result<()> {
    let mut text = String::new();
    for p in points {
        text += &serde_json::to_string(p)?;
        text.push('\n');
    }
    crate::fsio::write_atomic(path, text)
}
