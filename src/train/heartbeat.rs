//! A running training's latest step, rewritten every few seconds in its folder, so that `status` can give the
//! step and pace between the curve points and checkpoints (which may come only every thousand steps). Removed when
//! the training finishes; a stopped attempt leaves its own, which the next attempt overwrites and `status` ignores.
use crate::fsio;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The file inside a training folder.
pub const HEARTBEAT_FILE: &str = "heartbeat.json";

/// How often a training rewrites it.
pub const HEARTBEAT_EVERY: Duration = Duration::from_secs(15);

/// A training's step when last written and when (seconds since the epoch), and the same at this attempt's first
/// write, so that its pace leaves out the start-up before its first step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Heartbeat {
    pub step: u64,
    pub at: f64,
    pub first_step: u64,
    pub first_at: f64,
}

impl Heartbeat {
    /// Steps per second between this attempt's first write and its latest (none until a later write).
    pub fn steps_per_second(&self) -> Option<f64> {
        (self.at > self.first_at && self.step > self.first_step)
            .then(|| (self.step - self.first_step) as f64 / (self.at - self.first_at))
    }
}

/// The heartbeat in `path`, if there is one that reads.
pub fn read(path: &Path) -> Option<Heartbeat> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// Removes the heartbeat at `path` and any half-written copy of it.
pub fn remove(path: &Path) -> Result<()> {
    fsio::remove_file_if_present(&fsio::temporary_path(path))?;
    fsio::remove_file_if_present(path)
}

/// Writes a training's step to its heartbeat file at most once every `every`.
pub struct Beater {
    every: Duration,
    last: Option<Instant>,
    first: Option<(u64, f64)>,
    warned: bool,
}

impl Beater {
    /// A beater that writes at its first tick, then once every `every`.
    pub fn new(every: Duration) -> Beater {
        Beater { every, last: None, first: None, warned: false }
    }

    /// Writes `step` to `path` (atomically) if `every` has passed since the last write. The heartbeat only informs
    /// `status`, so a failed write warns once on stderr and the training goes on.
    pub fn tick(&mut self, path: &Path, step: u64) {
        if self.last.is_some_and(|last| last.elapsed() < self.every) {
            return;
        }
        let at = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
        let (first_step, first_at) = *self.first.get_or_insert((step, at));
        let beat = Heartbeat { step, at, first_step, first_at };
        let written = serde_json::to_vec(&beat).map_err(anyhow::Error::from).and_then(|b| fsio::write_atomic(path, b));
        if let Err(e) = written
            && !self.warned
        {
            eprintln!("warning: the training's heartbeat (what `status` reads) could not be written: {e:#}");
            self.warned = true;
        }
        self.last = Some(Instant::now());
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
        beater.tick(&path, 7);
        let first = read(&path).unwrap();
        assert_eq!((first.step, first.first_step), (7, 7));
        assert!(first.at > 1.7e9 && first.at == first.first_at, "seconds since the epoch: {first:?}");
        assert_eq!(first.steps_per_second(), None, "one write measures no pace");
        beater.tick(&path, 8);
        assert_eq!(read(&path).unwrap().step, 7, "written again before its interval");
        let mut eager = Beater::new(Duration::ZERO);
        eager.tick(&path, 9);
        std::thread::sleep(Duration::from_millis(20));
        eager.tick(&path, 10);
        let latest = read(&path).unwrap();
        assert_eq!((latest.step, latest.first_step), (10, 9), "the attempt's first write is kept");
        assert!(latest.steps_per_second().is_some_and(|r| r > 0.0 && r < 100.0), "{latest:?}");
        std::fs::write(&path, "{\"step\": ").unwrap();
        assert_eq!(read(&path), None, "a damaged heartbeat reads as none");
        std::fs::write(fsio::temporary_path(&path), "{").unwrap();
        remove(&path).unwrap();
        assert!(!path.exists() && !fsio::temporary_path(&path).exists(), "removed with its half-written copy");
        let mut blocked = Beater::new(Duration::ZERO);
        blocked.tick(&dir.join("absent").join(HEARTBEAT_FILE), 1);
        assert!(blocked.warned, "a write that fails warns and does not stop the training");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_pace_runs_from_the_first_write() {
        let beat = Heartbeat { step: 1300, at: 1_000_060.0, first_step: 1001, first_at: 1_000_000.0 };
        assert_eq!(beat.steps_per_second(), Some(299.0 / 60.0));
    }
}
