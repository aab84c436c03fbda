//! What a run reports while it goes: stages starting, finishing and failing, waits on stages that another
//! process or a Slurm job holds. The scheduler sends each event to a [`RunEvents`] (the command line prints
//! them); an event's `Display` is how it reads.
use super::graph::short;
use super::store::jobs::SLURM_HOST;
use super::store::{Holder, now};
use std::fmt;

/// One thing that happened during a run.
#[derive(Debug, Clone, PartialEq)]
pub enum RunEvent {
    /// The `number`-th of `total` stages to execute started.
    Started {
        number: usize,
        total: usize,
        kind: &'static str,
        stage: String,
    },
    /// A stage finished, `seconds` into the run.
    Done {
        stage: String,
        seconds: f64,
    },
    Failed {
        stage: String,
        message: String,
    },
    /// A stage this run needs is held by another process or a Slurm job.
    Waiting {
        stage: String,
        holder: Holder,
    },
    /// A Slurm job of an earlier detached run failed.
    SlurmJobFailed {
        key: String,
        why: String,
    },
    /// `--rerun-code-changed`: how many stages (of `kinds`, with those below them) it re-runs.
    CodeChanged {
        kinds: String,
        stages: usize,
    },
    /// Something went wrong that does not stop the run.
    Warning(String),
}

/// Where a run's events go.
pub trait RunEvents: Sync {
    fn report(&self, event: RunEvent);
}

impl fmt::Display for RunEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RunEvent::Started { number, total, kind, stage } => write!(f, "[{number}/{total}] {kind} {stage} ..."),
            RunEvent::Done { stage, seconds } => write!(f, "    done: {stage} ({seconds:.0} s into the run)"),
            RunEvent::Failed { stage, message } => write!(f, "    FAILED: {stage}: {message}"),
            RunEvent::Waiting { stage, holder } => {
                let since = (now() - holder.started_at).max(0.0);
                if holder.host == SLURM_HOST {
                    write!(
                        f,
                        "waiting: {stage} is Slurm job {} (submitted {since:.0} s ago); this run goes on when it ends",
                        holder.pid
                    )
                } else {
                    write!(
                        f,
                        "waiting: {stage} is being run by pid {} on {} (started {since:.0} s ago); this run goes on \
                         when it ends",
                        holder.pid, holder.host
                    )
                }
            }
            RunEvent::SlurmJobFailed { key, why } => write!(f, "Slurm job of stage {} failed: {why}", short(key)),
            RunEvent::CodeChanged { kinds, stages: 0 } => {
                write!(f, "--rerun-code-changed {kinds}: no cached stage of this plan was built by other code")
            }
            RunEvent::CodeChanged { kinds, stages } => write!(
                f,
                "--rerun-code-changed {kinds}: {stages} stages re-run (built by other code, or below one that was)"
            ),
            RunEvent::Warning(message) => write!(f, "warning: {message}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_waiting_message_names_the_stage_the_process_and_how_long() {
        let holder = Holder { host: "node7".into(), pid: 4242, started_at: now() - 90.0 };
        let m = RunEvent::Waiting { stage: "n32-full-s0/train".into(), holder }.to_string();
        assert!(m.starts_with("waiting: n32-full-s0/train is being run by pid 4242 on node7"), "{m}");
        assert!(m.contains("(started 90 s ago)") || m.contains("(started 91 s ago)"), "{m}");
    }

    #[test]
    fn the_waiting_message_names_a_slurm_job_by_its_id() {
        let holder = Holder { host: SLURM_HOST.into(), pid: 812, started_at: now() - 30.0 };
        let m = RunEvent::Waiting { stage: "n32-full-s0/eval".into(), holder }.to_string();
        assert!(m.starts_with("waiting: n32-full-s0/eval is Slurm job 812 (submitted 3"), "{m}");
    }
}
