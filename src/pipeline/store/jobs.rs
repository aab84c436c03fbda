//! Stages handed to Slurm by detached runs: their attempts name the job instead of a local process.
use super::{Store, now};
use anyhow::Result;
use rusqlite::params;

/// The `host` of an attempt that a Slurm job runs; its `pid` is the job id.
pub const SLURM_HOST: &str = "slurm";

/// A stage attempt running as a Slurm job.
#[derive(Debug, Clone, PartialEq)]
pub struct SubmittedJob {
    pub attempt: i64,
    pub key: String,
    pub kind: String,
    pub job: u64,
    /// Seconds since the Unix epoch.
    pub submitted_at: f64,
}

impl Store {
    /// Hands a claimed attempt to Slurm job `job`: from now on the job, not this process, holds the stage.
    pub fn hand_to_slurm(&mut self, attempt: i64, job: u64) -> Result<()> {
        self.conn.execute(
            "UPDATE attempts SET host = ?2, pid = ?3, started_at = ?4 WHERE id = ?1",
            params![attempt, SLURM_HOST, job as i64, now()],
        )?;
        Ok(())
    }

    /// Every attempt still held by a Slurm job, oldest first.
    pub fn slurm_jobs(&self) -> Result<Vec<SubmittedJob>> {
        let mut q = self.conn.prepare(
            "SELECT a.id, a.stage_key, s.kind, a.pid, a.started_at FROM attempts a JOIN stages s ON s.key = a.stage_key \
             WHERE a.status = 'running' AND a.host = ?1 ORDER BY a.id",
        )?;
        let rows = q.query_map([SLURM_HOST], |r| {
            Ok(SubmittedJob {
                attempt: r.get(0)?,
                key: r.get(1)?,
                kind: r.get(2)?,
                job: r.get::<_, i64>(3)? as u64,
                submitted_at: r.get(4)?,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }
}
