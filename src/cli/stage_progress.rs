//! Where a running stage stands, read from what it keeps in its staging folder as it runs (readable from another
//! machine on a shared filesystem too): a training's loss curve, checkpoints and heartbeat, a pretraining's curves
//! of held-out error. `status` prints them.
use oneshot_lab::pipeline::stages::pretrain::{ATTENTION_CURVE_FILE, TRUNK_CURVE_FILE};
use oneshot_lab::train::heartbeat::{self, HEARTBEAT_FILE};
use oneshot_lab::train::pretrain::read_curve;
use oneshot_lab::train::{CHECKPOINT_DIR, CURVE_FILE, checkpoint, curve};
use std::path::Path;
use std::time::UNIX_EPOCH;

/// A running training: its latest curve point, checkpoint or heartbeat against its total steps, and its pace in
/// this attempt.
#[derive(Debug, serde::Serialize)]
pub struct TrainingProgress {
    /// The latest step its curve, checkpoints or heartbeat show.
    pub step: u64,
    /// The steps it trains in all.
    pub steps: u64,
    /// The checkpoint this attempt resumed from (0: it started afresh).
    pub resumed_from: u64,
    /// The latest training and validation BC on its curve.
    pub train_bc: Option<f64>,
    pub val_bc: Option<f64>,
    /// This attempt's pace, from its heartbeat where it has one (none before the heartbeat's second write), else
    /// up to its latest record (none before its first); and the time the steps left would take at it.
    pub steps_per_second: Option<f64>,
    pub seconds_left: Option<f64>,
}

/// A running pretraining: the phase it is in, its latest measured step and held-out error.
#[derive(Debug, serde::Serialize)]
pub struct PretrainingProgress {
    /// `trunk`, or `object attention` (the second phase, where `object_attention_steps` asks for one).
    pub phase: &'static str,
    /// The phase's latest measured step.
    pub step: u64,
    /// The phase's steps.
    pub steps: u64,
    /// Held-out error x / y at `step`, in metres.
    pub held_out: [f64; 2],
    /// Steps of both phases done and in all.
    pub done: u64,
    pub total: u64,
    /// The pace up to the latest measurement, and the time the steps left would take at it.
    pub steps_per_second: Option<f64>,
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

/// Steps per second over `seconds` and the seconds the `left` steps would take at that pace; neither before the
/// first step.
fn pace(steps: u64, seconds: f64, left: u64) -> (Option<f64>, Option<f64>) {
    let rate = (steps > 0).then(|| steps as f64 / seconds.max(1.0));
    (rate, rate.map(|rate| left as f64 / rate))
}

/// The pace and the time left, as `status` prints them.
fn pace_text(steps_per_second: Option<f64>, seconds_left: Option<f64>) -> String {
    match (steps_per_second, seconds_left) {
        (Some(rate), Some(left)) => format!("{rate:.2} steps/s, about {:.0} min left", left / 60.0),
        _ => "pace not yet measured".to_string(),
    }
}

impl std::fmt::Display for TrainingProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let bc = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        let resumed =
            if self.resumed_from > 0 { format!(" (resumed at {})", self.resumed_from) } else { String::new() };
        write!(
            f,
            "step {} of {}{resumed}: train bc {}, val bc {}, {}",
            self.step,
            self.steps,
            bc(self.train_bc),
            bc(self.val_bc),
            pace_text(self.steps_per_second, self.seconds_left)
        )
    }
}

impl std::fmt::Display for PretrainingProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let all =
            if self.total > self.steps { format!(" ({} of {} in all)", self.done, self.total) } else { String::new() };
        write!(
            f,
            "{} step {} of {}{all}: held-out error {:.2} / {:.2} cm, {}",
            self.phase,
            self.step,
            self.steps,
            100.0 * self.held_out[0],
            100.0 * self.held_out[1],
            pace_text(self.steps_per_second, self.seconds_left)
        )
    }
}

/// The time `path` was last written, in seconds since the epoch.
fn written_at(path: &Path) -> Option<f64> {
    let modified = std::fs::metadata(path).and_then(|m| m.modified()).ok()?;
    Some(modified.duration_since(UNIX_EPOCH).ok()?.as_secs_f64())
}

/// The latest checkpoint in `dir` written before `started_at` (seconds since the epoch): where an attempt that
/// began then resumed from (0: none).
fn resumed_step(dir: &Path, started_at: f64) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| written_at(p).is_some_and(|t| t <= started_at))
        .filter_map(|p| checkpoint::step_of(&p))
        .max()
        .unwrap_or(0)
}

/// A training of `steps` running in `staging` since `started_at` (seconds since the epoch); its pace runs to its
/// latest record.
pub fn training(staging: &Path, steps: u64, started_at: f64) -> Option<TrainingProgress> {
    let curve_file = staging.join(CURVE_FILE);
    let mut points = curve::read(&curve_file, u64::MAX).ok()?;
    let checkpoints = staging.join(CHECKPOINT_DIR);
    let resumed_from = resumed_step(&checkpoints, started_at);
    // Until this attempt first rewrites the curve, points past its checkpoint are a killed attempt's.
    let curve_written = written_at(&curve_file).filter(|t| *t > started_at);
    if curve_written.is_none() {
        points.retain(|p| p.step <= resumed_from);
    }
    // A checkpoint may be later than the last curve point (checkpoints may come more often, and a training stopped
    // by signal checkpoints where it stopped): the later of the two.
    let checkpointed = checkpoint::latest(&checkpoints).ok().flatten();
    let checkpoint_written = checkpointed.as_ref().and_then(|(_, path)| written_at(path));
    let checkpointed = checkpointed.map_or(0, |(step, _)| step);
    let step = points.iter().map(|p| p.step).max().unwrap_or(0).max(checkpointed).max(resumed_from);
    let latest = |split: &str| points.iter().filter(|p| p.split == split).max_by_key(|p| p.step).map(|p| p.bc);
    // The heartbeat comes every few seconds, and its pace leaves out the start-up; one first written before this
    // attempt began is a stopped attempt's.
    let (step, (steps_per_second, seconds_left)) =
        match heartbeat::read(&staging.join(HEARTBEAT_FILE)).filter(|b| b.first_at > started_at) {
            Some(beat) => {
                let step = step.max(beat.step);
                let rate = beat.steps_per_second();
                (step, (rate, rate.map(|rate| steps.saturating_sub(step) as f64 / rate)))
            }
            None => {
                let recorded_at = [curve_written, checkpoint_written].into_iter().flatten().fold(started_at, f64::max);
                (step, pace(step - resumed_from, recorded_at - started_at, steps.saturating_sub(step)))
            }
        };
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
/// `started_at`; none before its first measurement. Its pace runs to that measurement.
pub fn pretraining(
    staging: &Path,
    (trunk_steps, attention_steps): (u64, u64),
    started_at: f64,
) -> Option<PretrainingProgress> {
    let latest = |file: &str| {
        let path = staging.join(file);
        Some((read_curve(&path).ok()?.last().copied()?, written_at(&path)?))
    };
    let (phase, steps, before, (point, measured_at)) = match latest(ATTENTION_CURVE_FILE) {
        Some(last) => ("object attention", attention_steps, trunk_steps, last),
        None => ("trunk", trunk_steps, 0, latest(TRUNK_CURVE_FILE)?),
    };
    let (done, total) = (before + point.step, trunk_steps + attention_steps);
    let (steps_per_second, seconds_left) = pace(done, measured_at - started_at, total.saturating_sub(done));
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
        let dir = scratch("resumed");
        for (step, written) in [(1000, 100.0), (2000, 200.0), (3000, 400.0)] {
            std::fs::write(checkpoint::path_for(&dir, step), b"").unwrap();
            set_written(&checkpoint::path_for(&dir, step), written);
        }
        assert_eq!(resumed_step(&dir, 300.0), 2000, "step 3000 was written by the attempt itself");
        assert_eq!(resumed_step(&dir, 50.0), 0, "no checkpoint before it: a fresh start");
        assert_eq!(resumed_step(&dir.join("absent"), 300.0), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// An empty scratch folder for test `name`.
    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("oneshot-progress-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn set_written(path: &Path, secs: f64) {
        let file = std::fs::File::options().append(true).open(path).unwrap();
        file.set_modified(UNIX_EPOCH + std::time::Duration::from_secs_f64(secs)).unwrap();
    }

    #[test]
    fn a_resumed_training_shows_its_checkpoint_until_it_rewrites_a_killed_attempts_curve() {
        let dir = scratch("training");
        let checkpoints = dir.join(CHECKPOINT_DIR);
        std::fs::create_dir_all(&checkpoints).unwrap();
        let started = 1_000_000.0;
        for (step, written) in [(1000, started - 100.0), (1500, started + 50.0)] {
            let path = checkpoint::path_for(&checkpoints, step);
            std::fs::write(&path, b"").unwrap();
            set_written(&path, written);
        }
        let point = |step, split: &str, bc| curve::CurvePoint {
            step,
            split: split.into(),
            bc,
            inverse: 0.0,
            point: 0.0,
            task: 0.0,
            total: bc,
        };
        // The killed attempt had measured step 2000 after its last checkpoint at 1000.
        let killed = [point(0, "val", 5.0), point(2000, "train", 2.0), point(2000, "val", 1.9)];
        curve::write(&dir.join(CURVE_FILE), &killed).unwrap();
        set_written(&dir.join(CURVE_FILE), started - 50.0);
        let p = training(&dir, 4000, started).unwrap();
        assert_eq!((p.step, p.resumed_from, p.train_bc, p.val_bc), (1500, 1000, None, Some(5.0)));
        assert_eq!(
            (p.steps_per_second, p.seconds_left),
            (Some(10.0), Some(250.0)),
            "500 steps by the checkpoint at 50 s"
        );
        // Once this attempt writes its own curve, its points count.
        curve::write(&dir.join(CURVE_FILE), &[point(0, "val", 5.0), point(2000, "train", 1.5)]).unwrap();
        set_written(&dir.join(CURVE_FILE), started + 100.0);
        let p = training(&dir, 4000, started).unwrap();
        assert_eq!(
            (p.step, p.train_bc, p.steps_per_second, p.seconds_left),
            (2000, Some(1.5), Some(10.0), Some(200.0))
        );
        // A heartbeat written by this attempt gives the step between curve points; a killed attempt's does not.
        // Its pace runs from the heartbeat's first write, leaving out the start-up.
        let beat = |step, at, first_step, first_at| {
            let text = serde_json::to_vec(&heartbeat::Heartbeat { step, at, first_step, first_at }).unwrap();
            std::fs::write(dir.join(HEARTBEAT_FILE), text).unwrap();
        };
        beat(1001, started + 40.0, 1001, started + 40.0);
        let p = training(&dir, 4000, started).unwrap();
        assert_eq!((p.step, p.steps_per_second), (2000, None), "one heartbeat: no pace yet");
        beat(2600, started + 160.0, 1001, started + 40.0);
        let p = training(&dir, 4000, started).unwrap();
        assert_eq!((p.step, p.steps_per_second.map(|r| (r * 1e6).round() / 1e6)), (2600, Some(13.325)));
        assert_eq!(p.seconds_left.map(|s| s.round()), Some(105.0), "1,400 steps left at 1,599 steps in 120 s");
        beat(2900, started + 10.0, 2000, started - 1.0);
        assert_eq!(training(&dir, 4000, started).unwrap().step, 2000, "a heartbeat from before this attempt");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_pretraining_shows_the_phase_of_its_latest_curve_and_its_pace_to_that_measurement() {
        let dir = scratch("pretraining");
        let started = 1_000_000.0;
        assert!(pretraining(&dir, (100, 200), started).is_none(), "nothing measured yet");
        let errors = |step, e| oneshot_lab::train::pretrain::LocaliseErrors { step, train: [e, e], held_out: [e, e] };
        let write = |file: &str, curve: &[oneshot_lab::train::pretrain::LocaliseErrors], written: f64| {
            oneshot_lab::fsio::write_json_lines(&dir.join(file), curve).unwrap();
            set_written(&dir.join(file), written);
        };
        write(TRUNK_CURVE_FILE, &[errors(0, 0.05), errors(100, 0.02)], started + 50.0);
        let p = pretraining(&dir, (100, 200), started).unwrap();
        assert_eq!((p.phase, p.step, p.steps, p.done, p.total, p.held_out), ("trunk", 100, 100, 100, 300, [0.02; 2]));
        assert_eq!((p.steps_per_second, p.seconds_left), (Some(2.0), Some(100.0)));
        write(ATTENTION_CURVE_FILE, &[errors(0, 0.02), errors(50, 0.015)], started + 75.0);
        let p = pretraining(&dir, (100, 200), started).unwrap();
        assert_eq!((p.phase, p.step, p.steps, p.done, p.held_out), ("object attention", 50, 200, 150, [0.015; 2]));
        assert_eq!((p.steps_per_second, p.seconds_left), (Some(2.0), Some(75.0)));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_pace_counts_only_this_attempts_steps() {
        let (rate, left) = pace(500, 250.0, 1000);
        assert_eq!((rate, left), (Some(2.0), Some(500.0)));
        assert_eq!(pace(0, 0.0, 10), (None, None), "no steps yet: no estimate");
        assert_eq!(pace_text(None, None), "pace not yet measured");
        assert_eq!(pace_text(Some(0.5), Some(600.0)), "0.50 steps/s, about 10 min left");
    }
}
