//! Where a running stage stands, read from what it keeps in its staging folder as it runs (readable from another
//! machine on a shared filesystem too): a training's loss curve and checkpoints, a pretraining's curves of
//! held-out error. `status` prints them.
use oneshot_lab::pipeline::stages::pretrain::{ATTENTION_CURVE_FILE, TRUNK_CURVE_FILE};
use oneshot_lab::train::pretrain::read_curve;
use oneshot_lab::train::{CHECKPOINT_DIR, CURVE_FILE, checkpoint, curve};
use std::path::Path;
use std::time::{Duration, UNIX_EPOCH};

/// A running training: its latest curve point or checkpoint against its total steps, and its pace since this
/// attempt began.
#[derive(Debug, serde::Serialize)]
pub struct TrainingProgress {
    pub step: u64,
    pub steps: u64,
    /// The checkpoint this attempt resumed from (0: it started afresh).
    pub resumed_from: u64,
    pub train_bc: Option<f64>,
    pub val_bc: Option<f64>,
    pub steps_per_second: f64,
    pub seconds_left: Option<f64>,
}

/// A running pretraining: the phase it is in, its latest measured step and held-out error.
#[derive(Debug, serde::Serialize)]
pub struct PretrainingProgress {
    /// `trunk`, or `object attention` (the second phase, where `object_attention_steps` asks for one).
    pub phase: &'static str,
    pub step: u64,
    /// The phase's steps.
    pub steps: u64,
    /// Held-out error x / y at `step`, in metres.
    pub held_out: [f64; 2],
    /// Steps of both phases done and in all.
    pub done: u64,
    pub total: u64,
    pub steps_per_second: f64,
    pub seconds_left: Option<f64>,
}

/// How far a running stage is, for the kinds that keep a record as they run.
pub enum Progress {
    Training(TrainingProgress),
    Pretraining(PretrainingProgress),
}

impl Progress {
    /// The training's progress, if this is one.
    pub fn training(&self) -> Option<&TrainingProgress> {
        match self {
            Progress::Training(p) => Some(p),
            Progress::Pretraining(_) => None,
        }
    }

    /// The pretraining's progress, if this is one.
    pub fn pretraining(&self) -> Option<&PretrainingProgress> {
        match self {
            Progress::Pretraining(p) => Some(p),
            Progress::Training(_) => None,
        }
    }
}

impl std::fmt::Display for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Progress::Training(p) => p.fmt(f),
            Progress::Pretraining(p) => p.fmt(f),
        }
    }
}

/// Steps per second over `seconds` and the seconds the `left` steps would take at that pace.
fn pace(steps: u64, seconds: f64, left: u64) -> (f64, Option<f64>) {
    let rate = steps as f64 / seconds.max(1.0);
    (rate, (rate > 0.0).then(|| left as f64 / rate))
}

fn minutes_left(seconds: Option<f64>) -> String {
    seconds.map_or(String::new(), |s| format!(", about {:.0} min left", s / 60.0))
}

impl std::fmt::Display for TrainingProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let bc = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        let resumed =
            if self.resumed_from > 0 { format!(" (resumed at {})", self.resumed_from) } else { String::new() };
        write!(
            f,
            "step {} of {}{resumed}: train bc {}, val bc {}, {:.2} steps/s{}",
            self.step,
            self.steps,
            bc(self.train_bc),
            bc(self.val_bc),
            self.steps_per_second,
            minutes_left(self.seconds_left)
        )
    }
}

impl std::fmt::Display for PretrainingProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} step {} of {} (of {} in all): held-out error {:.2} / {:.2} cm, {:.2} steps/s{}",
            self.phase,
            self.step,
            self.steps,
            self.total,
            100.0 * self.held_out[0],
            100.0 * self.held_out[1],
            self.steps_per_second,
            minutes_left(self.seconds_left)
        )
    }
}

/// The latest checkpoint in `dir` written before `started_at` (seconds since the epoch): where an attempt that
/// began then resumed from (0: none).
pub fn resumed_step(dir: &Path, started_at: f64) -> u64 {
    let began = UNIX_EPOCH + Duration::from_secs_f64(started_at.max(0.0));
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| std::fs::metadata(p).and_then(|m| m.modified()).is_ok_and(|t| t <= began))
        .filter_map(|p| checkpoint::step_of(&p))
        .max()
        .unwrap_or(0)
}

/// A training of `steps` running in `staging` since `started_at` (seconds since the epoch), at `now`.
pub fn training(staging: &Path, steps: u64, started_at: f64, now: f64) -> Option<TrainingProgress> {
    let points = curve::read(&staging.join(CURVE_FILE), u64::MAX).ok()?;
    let checkpoints = staging.join(CHECKPOINT_DIR);
    // Checkpoints come more often than curve points: the later of the two.
    let checkpointed = checkpoint::latest(&checkpoints).ok().flatten().map_or(0, |(s, _)| s);
    let step = points.iter().map(|p| p.step).max().unwrap_or(0).max(checkpointed);
    let latest = |split: &str| points.iter().filter(|p| p.split == split).max_by_key(|p| p.step).map(|p| p.bc);
    let resumed_from = resumed_step(&checkpoints, started_at).min(step);
    let (steps_per_second, seconds_left) = pace(step - resumed_from, now - started_at, steps.saturating_sub(step));
    Some(TrainingProgress {
        step,
        steps,
        resumed_from,
        train_bc: latest("train"),
        val_bc: latest("val"),
        steps_per_second,
        seconds_left,
    })
}

/// A pretraining of `trunk_steps` (then `attention_steps` of object attention) running in `staging` since
/// `started_at`, at `now`; none before its first measurement.
pub fn pretraining(
    staging: &Path,
    (trunk_steps, attention_steps): (u64, u64),
    started_at: f64,
    now: f64,
) -> Option<PretrainingProgress> {
    let latest = |file: &str| read_curve(&staging.join(file)).ok().and_then(|c| c.last().copied());
    let (phase, steps, before, point) = match latest(ATTENTION_CURVE_FILE) {
        Some(point) => ("object attention", attention_steps, trunk_steps, point),
        None => ("trunk", trunk_steps, 0, latest(TRUNK_CURVE_FILE)?),
    };
    let (done, total) = (before + point.step, trunk_steps + attention_steps);
    let (steps_per_second, seconds_left) = pace(done, now - started_at, total.saturating_sub(done));
    Some(PretrainingProgress {
        phase,
        step: point.step,
        steps,
        held_out: point.held_out,
        done,
        total,
        steps_per_second,
        seconds_left,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_attempt_resumed_from_the_checkpoint_written_before_it_began() {
        let dir = std::env::temp_dir().join(format!("oneshot-resumed-step-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let at = |secs: u64| UNIX_EPOCH + Duration::from_secs(secs);
        for (step, written) in [(1000, 100), (2000, 200), (3000, 400)] {
            let file = std::fs::File::create(checkpoint::path_for(&dir, step)).unwrap();
            file.set_modified(at(written)).unwrap();
        }
        assert_eq!(resumed_step(&dir, 300.0), 2000, "step 3000 was written by the attempt itself");
        assert_eq!(resumed_step(&dir, 50.0), 0, "no checkpoint before it: a fresh start");
        assert_eq!(resumed_step(&dir.join("absent"), 300.0), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_pace_counts_only_this_attempts_steps() {
        let (rate, left) = pace(500, 250.0, 1000);
        assert_eq!((rate, left), (2.0, Some(500.0)));
        assert_eq!(pace(0, 0.0, 10), (0.0, None), "no steps yet: no estimate");
    }
}
