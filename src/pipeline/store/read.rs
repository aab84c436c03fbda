//! What commands and reports read from the store, as typed records; the SQL stays here.
use super::Store;
use crate::eval::grasps::GraspSummary;
use crate::eval::stats::Counts;
use anyhow::{Result, bail};
use rusqlite::types::ValueRef;
use rusqlite::{OptionalExtension, params};

/// An experiment as last run.
#[derive(Debug, Clone, PartialEq)]
pub struct ExperimentRecord {
    pub file: String,
    pub description: String,
    pub profile: Option<String>,
    /// The `--set` overrides it was run with, as the command line spells them (empty when none).
    pub overrides: String,
}

/// A cell of an experiment with what the report needs of its stages.
#[derive(Debug, Clone)]
pub struct CellRecord {
    pub cell: String,
    pub policy: String,
    pub size: Option<usize>,
    pub variant: Option<String>,
    pub seed: Option<u64>,
    pub train_key: Option<String>,
    pub eval_key: String,
    /// The evaluation's counts; none until it has finished.
    pub counts: Option<Counts>,
    /// The model's context mode and architecture and the training steps, from the train stage's inputs.
    pub context: Option<String>,
    pub architecture: Option<String>,
    pub train_steps: Option<u64>,
    /// Who moved the agent in the evaluation (`scripted_poses`; none for the network's own actions).
    pub control: Option<String>,
    /// The evaluation world's objects (`library` for the multi-object world; none for the base world).
    pub objects: Option<String>,
}

/// One point of a BC loss curve.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveRow {
    pub step: u64,
    pub split: String,
    pub bc: f64,
}

/// A stage as registered: key, kind, status, resolved inputs (JSON) and upstream keys.
#[derive(Debug, Clone)]
pub struct StageRecord {
    pub key: String,
    pub kind: String,
    pub status: String,
    pub inputs: serde_json::Value,
    pub upstream: Vec<String>,
}

/// An attempt that is running or failed.
#[derive(Debug, Clone)]
pub struct AttemptRecord {
    pub key: String,
    pub kind: String,
    pub host: String,
    pub pid: i64,
    pub started_at: f64,
    pub error: Option<String>,
}

/// Named summaries for `query`, runnable from the `sqlite3` shell too.
pub const NAMED_QUERIES: [(&str, &str); 4] = [
    (
        "cells",
        "SELECT c.experiment, c.cell, c.policy, c.size, c.variant, c.seed, s.status AS eval_status,
                COUNT(e.idx) AS episodes, ROUND(AVG(e.reached), 3) AS reached, ROUND(AVG(e.picked), 3) AS picked,
                ROUND(AVG(e.placed), 3) AS placed, substr(c.eval_key, 1, 12) AS eval_key
         FROM cells c LEFT JOIN stages s ON s.key = c.eval_key LEFT JOIN episodes e ON e.eval_key = c.eval_key
         GROUP BY c.experiment, c.cell ORDER BY c.experiment, c.rowid",
    ),
    (
        "stages",
        "SELECT substr(key, 1, 12) AS key, kind, status, ROUND(seconds, 1) AS seconds,
                datetime(finished_at, 'unixepoch') AS finished, artifact FROM stages ORDER BY created_at",
    ),
    (
        "failures",
        "SELECT substr(a.stage_key, 1, 12) AS key, s.kind, a.host, a.pid, datetime(a.started_at, 'unixepoch') AS started,
                a.error FROM attempts a JOIN stages s ON s.key = a.stage_key WHERE a.status = 'failed' ORDER BY a.id",
    ),
    (
        "curves",
        "SELECT substr(train_key, 1, 12) AS train_key, step, split, ROUND(bc, 4) AS bc, ROUND(inverse, 4) AS inverse,
                ROUND(point, 4) AS point FROM loss_curves ORDER BY train_key, split, step",
    ),
];

/// The rows of a read-only query: column names and values as JSON.
pub struct QueryRows {
    pub columns: Vec<String>,
    pub rows: Vec<Vec<serde_json::Value>>,
}

fn value_json(v: ValueRef) -> serde_json::Value {
    match v {
        ValueRef::Null => serde_json::Value::Null,
        ValueRef::Integer(i) => i.into(),
        ValueRef::Real(f) => f.into(),
        ValueRef::Text(t) => String::from_utf8_lossy(t).into_owned().into(),
        ValueRef::Blob(b) => format!("<{} bytes>", b.len()).into(),
    }
}

fn counts(r: &rusqlite::Row, first: usize) -> rusqlite::Result<Counts> {
    Ok(Counts {
        episodes: r.get::<_, i64>(first)? as usize,
        reached: r.get::<_, i64>(first + 1)? as usize,
        picked: r.get::<_, i64>(first + 2)? as usize,
        placed: r.get::<_, i64>(first + 3)? as usize,
        wrong_bin: r.get::<_, Option<i64>>(first + 4)?.map(|v| v as usize),
    })
}

impl Store {
    /// The experiment `name` as last run.
    pub fn experiment(&self, name: &str) -> Result<ExperimentRecord> {
        let row = self
            .conn
            .query_row("SELECT file, description, profile, overrides FROM experiments WHERE name = ?1", [name], |r| {
                Ok(ExperimentRecord {
                    file: r.get(0)?,
                    description: r.get(1)?,
                    profile: r.get(2)?,
                    overrides: r.get(3)?,
                })
            })
            .optional()?;
        match row {
            Some(e) => Ok(e),
            None => bail!("the store has no experiment `{name}` (run it first)"),
        }
    }

    /// The cells of `experiment`, in grid order, with their evaluations' counts.
    pub fn cells(&self, experiment: &str) -> Result<Vec<CellRecord>> {
        let mut stmt = self.conn.prepare(
            "SELECT c.cell, c.policy, c.size, c.variant, c.seed, c.train_key, c.eval_key, s.status,
                    json_extract(t.inputs, '$.model.context'), json_extract(t.inputs, '$.model.architecture'),
                    json_extract(t.inputs, '$.train.steps'), json_extract(s.inputs, '$.eval.control'),
                    json_extract(s.inputs, '$.world.objects')
             FROM cells c LEFT JOIN stages s ON s.key = c.eval_key LEFT JOIN stages t ON t.key = c.train_key
             WHERE c.experiment = ?1 ORDER BY c.rowid",
        )?;
        let rows = stmt
            .query_map([experiment], |r| {
                let record = CellRecord {
                    cell: r.get(0)?,
                    policy: r.get(1)?,
                    size: r.get::<_, Option<i64>>(2)?.map(|v| v as usize),
                    variant: r.get(3)?,
                    seed: r.get::<_, Option<i64>>(4)?.map(|v| v as u64),
                    train_key: r.get(5)?,
                    eval_key: r.get(6)?,
                    counts: None,
                    context: r.get(8)?,
                    architecture: r.get(9)?,
                    train_steps: r.get::<_, Option<i64>>(10)?.map(|v| v as u64),
                    control: r.get(11)?,
                    objects: r.get(12)?,
                };
                Ok((record, r.get::<_, Option<String>>(7)?))
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        if rows.is_empty() {
            bail!("the store has no cells of experiment `{experiment}` (run it first)");
        }
        let mut out = Vec::with_capacity(rows.len());
        for (mut cell, status) in rows {
            if status.as_deref() == Some("done") {
                cell.counts = Some(self.eval_counts(&cell.eval_key)?);
            }
            out.push(cell);
        }
        Ok(out)
    }

    /// Stage counts over the episodes of evaluation `eval_key`.
    pub fn eval_counts(&self, eval_key: &str) -> Result<Counts> {
        Ok(self.conn.query_row(
            "SELECT COUNT(*), COALESCE(SUM(reached), 0), COALESCE(SUM(picked), 0), COALESCE(SUM(placed), 0),
                    SUM(wrong_bin)
             FROM episodes WHERE eval_key = ?1",
            params![eval_key],
            |r| counts(r, 0),
        )?)
    }

    /// Stage counts per task over the episodes of the finished evaluations among `eval_keys`, pooled: (task id,
    /// counts) in task order, tasks without episodes left out.
    pub fn task_counts(&self, eval_keys: &[String]) -> Result<Vec<(usize, Counts)>> {
        let mut stmt = self.conn.prepare(
            "SELECT e.task, COUNT(*), SUM(e.reached), SUM(e.picked), SUM(e.placed), SUM(e.wrong_bin)
             FROM episodes e JOIN stages s ON s.key = e.eval_key AND s.status = 'done'
             WHERE e.eval_key = ?1 GROUP BY e.task",
        )?;
        let mut pooled = std::collections::BTreeMap::<usize, Counts>::new();
        for key in eval_keys {
            let rows = stmt.query_map([key], |r| Ok((r.get::<_, i64>(0)? as usize, counts(r, 1)?)))?;
            for row in rows {
                let (task, c) = row?;
                let total = pooled.entry(task).or_default();
                *total = total.plus(&c);
            }
        }
        Ok(pooled.into_iter().collect())
    }

    /// Where the gripper first closed over the episodes of the finished evaluations among `eval_keys`, pooled;
    /// none where they have no episodes or some were stored before the store kept it (version 4).
    pub fn grasps(&self, eval_keys: &[String]) -> Result<Option<GraspSummary>> {
        let mut stmt = self.conn.prepare(
            "SELECT e.picked, e.closed, e.close_x, e.close_y, e.close_z
             FROM episodes e JOIN stages s ON s.key = e.eval_key AND s.status = 'done'
             WHERE e.eval_key = ?1 ORDER BY e.idx",
        )?;
        let mut episodes = Vec::new();
        for key in eval_keys {
            let rows = stmt.query_map([key], |r| {
                let offset = match (r.get::<_, Option<f64>>(2)?, r.get(3)?, r.get(4)?) {
                    (Some(x), Some(y), Some(z)) => Some([x, y, z]),
                    _ => None,
                };
                Ok((r.get::<_, bool>(0)?, r.get::<_, Option<bool>>(1)?, offset))
            })?;
            for row in rows {
                let (picked, closed, offset) = row?;
                match closed {
                    None => return Ok(None),
                    Some(false) => episodes.push((picked, None)),
                    Some(true) => match offset {
                        Some(offset) => episodes.push((picked, Some(offset))),
                        None => bail!("an episode of evaluation `{key}` closed its gripper but has no offset stored"),
                    },
                }
            }
        }
        Ok((!episodes.is_empty()).then(|| GraspSummary::of_closes(episodes)))
    }

    /// Finished evaluations of intermediate checkpoints of `experiment`: (cell, step, counts).
    pub fn checkpoint_counts(&self, experiment: &str) -> Result<Vec<(String, u64, Counts)>> {
        let mut stmt = self.conn.prepare(
            "SELECT ce.cell, ce.step, COUNT(e.idx), COALESCE(SUM(e.reached), 0), COALESCE(SUM(e.picked), 0),
                    COALESCE(SUM(e.placed), 0), SUM(e.wrong_bin)
             FROM checkpoint_evals ce JOIN stages s ON s.key = ce.eval_key AND s.status = 'done'
             JOIN episodes e ON e.eval_key = ce.eval_key
             WHERE ce.experiment = ?1 GROUP BY ce.cell, ce.step",
        )?;
        let rows = stmt
            .query_map([experiment], |r| Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)? as u64, counts(r, 2)?)))?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// The BC loss curve of train stage `train_key`.
    pub fn curve(&self, train_key: &str) -> Result<Vec<CurveRow>> {
        let mut stmt =
            self.conn.prepare("SELECT step, split, bc FROM loss_curves WHERE train_key = ?1 ORDER BY split, step")?;
        let rows = stmt
            .query_map([train_key], |r| {
                Ok(CurveRow { step: r.get::<_, i64>(0)? as u64, split: r.get(1)?, bc: r.get(2)? })
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    fn stage_records(&self, filter: &str, arg: &str) -> Result<Vec<StageRecord>> {
        let sql = format!("SELECT key, kind, status, inputs, upstream FROM stages WHERE {filter} ORDER BY key");
        let mut stmt = self.conn.prepare(&sql)?;
        let rows = stmt
            .query_map([arg], |r| {
                Ok((r.get::<_, String>(0)?, r.get(1)?, r.get(2)?, r.get::<_, String>(3)?, r.get::<_, String>(4)?))
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        rows.into_iter()
            .map(|(key, kind, status, inputs, upstream)| {
                Ok(StageRecord {
                    key,
                    kind,
                    status,
                    inputs: serde_json::from_str(&inputs)?,
                    upstream: serde_json::from_str(&upstream)?,
                })
            })
            .collect()
    }

    /// Stages whose key starts with `prefix` (compared as text: `%` and `_` are plain characters).
    pub fn stages_with_prefix(&self, prefix: &str) -> Result<Vec<StageRecord>> {
        self.stage_records("substr(key, 1, length(?1)) = ?1", prefix)
    }

    /// The metrics a finished stage recorded, by name.
    pub fn metrics(&self, stage_key: &str) -> Result<Vec<(String, f64)>> {
        let mut stmt = self.conn.prepare("SELECT name, value FROM metrics WHERE stage_key = ?1 ORDER BY name")?;
        let rows = stmt.query_map([stage_key], |r| Ok((r.get(0)?, r.get(1)?)))?.collect::<rusqlite::Result<_>>()?;
        Ok(rows)
    }

    /// Recorded cells called `cell` (in any experiment, or in `experiment` only): (experiment, record).
    pub fn cells_named(&self, experiment: Option<&str>, cell: &str) -> Result<Vec<(String, CellRecord)>> {
        let mut stmt =
            self.conn.prepare("SELECT DISTINCT experiment FROM cells WHERE cell = ?1 ORDER BY experiment")?;
        let names: Vec<String> = stmt.query_map([cell], |r| r.get(0))?.collect::<rusqlite::Result<_>>()?;
        let mut out = Vec::new();
        for name in names.into_iter().filter(|n| experiment.is_none_or(|e| e == n)) {
            let found = self.cells(&name)?.into_iter().find(|c| c.cell == cell);
            out.extend(found.map(|c| (name.clone(), c)));
        }
        Ok(out)
    }

    /// Finished stages of `kind`.
    pub fn done_stages(&self, kind: &str) -> Result<Vec<StageRecord>> {
        self.stage_records("kind = ?1 AND status = 'done'", kind)
    }

    /// Stage counts by kind and status.
    pub fn stage_counts(&self) -> Result<Vec<(String, String, i64)>> {
        let mut stmt = self
            .conn
            .prepare("SELECT kind, status, COUNT(*) FROM stages GROUP BY kind, status ORDER BY kind, status")?;
        let rows = stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?.collect::<rusqlite::Result<_>>()?;
        Ok(rows)
    }

    fn attempts(&self, status: &str, order_limit: &str) -> Result<Vec<AttemptRecord>> {
        let sql = format!(
            "SELECT a.stage_key, s.kind, a.host, a.pid, a.started_at, a.error FROM attempts a
             JOIN stages s ON s.key = a.stage_key WHERE a.status = ?1 {order_limit}"
        );
        let mut stmt = self.conn.prepare(&sql)?;
        let rows = stmt
            .query_map([status], |r| {
                Ok(AttemptRecord {
                    key: r.get(0)?,
                    kind: r.get(1)?,
                    host: r.get(2)?,
                    pid: r.get(3)?,
                    started_at: r.get(4)?,
                    error: r.get(5)?,
                })
            })?
            .collect::<rusqlite::Result<_>>()?;
        Ok(rows)
    }

    /// Attempts marked running, oldest first.
    pub fn running_attempts(&self) -> Result<Vec<AttemptRecord>> {
        self.attempts("running", "ORDER BY a.id")
    }

    /// The latest `n` failures that still stand, newest first: attempts that failed and are their stage's latest,
    /// so a stage that was run again since (finished or running) no longer shows its old failure.
    pub fn recent_failures(&self, n: usize) -> Result<Vec<AttemptRecord>> {
        self.attempts(
            "failed",
            &format!(
                "AND a.id = (SELECT MAX(b.id) FROM attempts b WHERE b.stage_key = a.stage_key)
                 ORDER BY a.id DESC LIMIT {n}"
            ),
        )
    }

    /// Runs a named query (see [`NAMED_QUERIES`]) or raw SQL on a read-only connection.
    pub fn query_read_only(root: &std::path::Path, what: &str) -> Result<QueryRows> {
        use anyhow::Context;
        let path = root.join(super::DATABASE);
        if !path.is_file() {
            bail!("no results store at {} (run an experiment there first, or pass --store)", path.display());
        }
        let mut conn = super::read_only_connection(&path)?;
        super::schema_version(&conn, &path)?;
        // A read-only connection still lets `ATTACH` create a file and `VACUUM INTO` write one: the authorizer
        // lets a statement only read, and a statement SQLite does not call read-only is refused too.
        conn.authorizer(Some(reads_only)).context("installing the read-only authorizer")?;
        if what.trim().is_empty() {
            let names: Vec<&str> = NAMED_QUERIES.iter().map(|(n, _)| *n).collect();
            bail!("the query is empty: give a named summary ({}) or one SQL statement", names.join(", "));
        }
        let sql = NAMED_QUERIES.iter().find(|(n, _)| *n == what).map_or(what, |(_, q)| *q);
        let mut stmt = conn.prepare(sql).with_context(|| {
            let names: Vec<&str> = NAMED_QUERIES.iter().map(|(n, _)| *n).collect();
            format!("`{what}` is neither a named query ({}) nor SQL that only reads", names.join(", "))
        })?;
        if !stmt.readonly() {
            bail!("`{what}` would change the store or another file: query runs only statements that read");
        }
        let columns: Vec<String> = stmt.column_names().map(|c| c.to_string()).collect();
        let mut rows = stmt.query([])?;
        let mut out = Vec::new();
        while let Some(row) = rows.next()? {
            out.push((0..columns.len()).map(|i| row.get_ref(i).map(value_json)).collect::<rusqlite::Result<_>>()?);
        }
        Ok(QueryRows { columns, rows: out })
    }
}

/// The authorizer of `query`'s connection: reading tables and calling functions, nothing else.
fn reads_only(ctx: rusqlite::hooks::AuthContext<'_>) -> rusqlite::hooks::Authorization {
    use rusqlite::hooks::{AuthAction, Authorization};
    match ctx.action {
        AuthAction::Select | AuthAction::Read { .. } | AuthAction::Function { .. } | AuthAction::Recursive => {
            Authorization::Allow
        }
        _ => Authorization::Deny,
    }
}
