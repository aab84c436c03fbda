//! A running training's latest step, rewritten every few seconds in its folder, so that `status` can give the
//! step and pace between the curve points and checkpoints (which may come only every thousand steps). Removed when
//! the training finishes; it never enters the stored artifact.
use crate::fsio;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The file inside a training folder.
pub const HEARTBEAT_FILE: &str = "heartbeat.json";

/// How often a training rewrites it.
pub const HEARTBEAT_EVERY: Duration = Duration::from_secs(15);

/// A training's step when last written, and when (seconds since the epoch).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Heartbeat {
    pub step: u64,
    pub at: f64,
}

/// The heartbeat in `path`, if there is one that reads.
pub fn read(path: &Path) -> Option<Heartbeat> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// Writes `step` to `path` at most once every `every`.
pub struct Beater {
    every: Duration,
    last: Option<Instant>,
}

impl Beater {
    /// A beater that writes at its first tick, then once every `every`.
    pub fn new(every: Duration) -> Beater {
        Beater { every, last: None }
    }

    /// Writes `step` (atomically) if `every` has passed since the last write.
    pub fn tick(&mut self, path: &Path, step: u64) -> Result<()> {
        if self.last.is_some_and(|last| last.elapsed() < self.every) {
            return Ok(());
        }
        let at = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
        fsio::write_atomic(path, serde_json::to_vec(&Heartbeat { step, at })?)?;
        self.last = Some(Instant::now());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_beater_writes_at_once_then_waits_its_interval() {
        let dir = std::env::temp_dir().join(format!("oneshot-heartbeat-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(HEARTBEAT_FILE);
        let mut beater = Beater::new(Duration::from_secs(3600));
        beater.tick(&path, 7).unwrap();
        let first = read(&path).unwrap();
        assert_eq!(first.step, 7);
        assert!(first.at > 1.7e9, "the time is seconds since the epoch: {}", first.at);
        beater.tick(&path, 8).unwrap();
        assert_eq!(read(&path).unwrap().step, 7, "written again before its interval");
        let mut eager = Beater::new(Duration::ZERO);
        eager.tick(&path, 9).unwrap();
        eager.tick(&path, 10).unwrap();
        assert_eq!(read(&path).unwrap().step, 10);
        std::fs::write(&path, "{\"step\": ").unwrap();
        assert_eq!(read(&path), None, "a damaged heartbeat reads as none");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
