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
    /// Cross-entropy of the demonstrated task (`model.task_head`; 0 without the head, and in curves written
    /// before it existed). Chance over sixteen tasks is ln 16 = 2.77.
    #[serde(default)]
    pub task: f64,
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

/// The curve a run starting after step `start` continues: the points up to `start` (its validation at `start`
/// included), or none when it starts afresh, whose step-0 validation is measured again. A staging folder may hold
/// the curve of an earlier attempt that stopped before its first checkpoint.
pub fn resumed(path: &Path, start: u64) -> Result<Vec<CurvePoint>> {
    if start == 0 { Ok(Vec::new()) } else { read(path, start) }
}

/// Rewrites the curve at `path` atomically.
pub fn write(path: &Path, points: &[CurvePoint]) -> Result<()> {
    crate::fsio::write_json_lines(path, points)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(step: u64, split: &str) -> CurvePoint {
        CurvePoint { step, split: split.into(), bc: 1.0, inverse: 0.0, point: 0.0, task: 0.0, total: 1.0 }
    }

    #[test]
    fn a_fresh_start_drops_an_earlier_attempts_points_and_a_resume_keeps_those_up_to_its_step() {
        let path = std::env::temp_dir().join(format!("oneshot-curve-{}.jsonl", std::process::id()));
        write(&path, &[point(0, "val"), point(10, "train"), point(10, "val"), point(20, "train")]).unwrap();
        assert!(resumed(&path, 0).unwrap().is_empty(), "step 0's validation is measured again");
        let kept: Vec<(u64, String)> = resumed(&path, 10).unwrap().into_iter().map(|p| (p.step, p.split)).collect();
        assert_eq!(kept, [(0, "val".into()), (10, "train".into()), (10, "val".into())]);
        std::fs::remove_file(&path).unwrap();
    }
}
