//! The results store: one SQLite database (WAL mode) beside the artifacts under the store folder.
//!
//! Schema (query it with `sqlite3 runs/oneshot.sqlite`):
//! - `stages(key, kind, version, inputs, upstream, status, artifact, created_at, finished_at, seconds)`:
//!   one row per stage ever planned; `status` is `planned`, `running`, `done` or `failed`; `inputs` is the resolved
//!   configuration (JSON) that went into the key, `upstream` a JSON array of upstream keys.
//! - `attempts(id, stage_key, status, host, pid, started_at, finished_at, error, code_commit, code_digest)`: every
//!   execution of a stage; a detached Slurm job's attempt has `host = 'slurm'` and its job id as `pid`;
//!   `code_commit` and `code_digest` say which code ran it (`pipeline::code`; empty before version 2).
//! - `experiments(name, file, description, profile, updated_at, overrides)` and
//!   `cells(experiment, cell, policy, size, variant, seed, collect_demo, collect_agent, train_key, eval_key)`;
//!   `checkpoint_evals(experiment, cell, step, eval_key)`: a cell's evaluations of intermediate checkpoints.
//! - `episodes(eval_key, idx, task, agent_seed, demo_seed, reached, picked, placed, steps, first_reached,
//!   first_picked, first_placed, wrong_bin, closed, close_step, close_x, close_y, close_z)`: every evaluation
//!   episode (`wrong_bin` null before version 3); `closed` says whether the agent ever commanded its gripper
//!   closed, and `close_*` the step and the task's object in the gripper's frame (metres) then (all null before
//!   version 4; the `close_*` null where it never closed).
//! - `metrics(stage_key, name, value)`: scalar results (e.g. `placed`, `final_val_bc`, `trajectories`).
//! - `loss_curves(train_key, step, split, bc, inverse, point, total)`.
//!
//! Timestamps are Unix seconds.
pub mod jobs;
pub mod read;

use super::code::{self, CodeVersion};
use super::graph::{PlannedCell, Stage, short};
use super::stages::{Kind, StageOutputs};
use anyhow::{Context, Result, bail};
use read::ExperimentRecord;
use rusqlite::{Connection, OptionalExtension, TransactionBehavior, params};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// File name of the database inside the store folder.
pub const DATABASE: &str = "oneshot.sqlite";

/// Version of the database layout this binary reads and writes (SQLite's `user_version`). Stores from before it
/// was recorded read 0 and are migrated on their first writable opening ([`migrate`]); a store newer than the
/// binary is refused rather than misread.
pub const SCHEMA_VERSION: i64 = 4;

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS stages (
    key TEXT PRIMARY KEY, kind TEXT NOT NULL, version INTEGER NOT NULL, inputs TEXT NOT NULL,
    upstream TEXT NOT NULL, status TEXT NOT NULL DEFAULT 'planned', artifact TEXT,
    created_at REAL NOT NULL, finished_at REAL, seconds REAL);
CREATE TABLE IF NOT EXISTS attempts (
    id INTEGER PRIMARY KEY, stage_key TEXT NOT NULL REFERENCES stages(key), status TEXT NOT NULL,
    host TEXT NOT NULL, pid INTEGER NOT NULL, started_at REAL NOT NULL, finished_at REAL, error TEXT,
    code_commit TEXT, code_digest TEXT);
CREATE TABLE IF NOT EXISTS experiments (
    name TEXT PRIMARY KEY, file TEXT NOT NULL, description TEXT NOT NULL, profile TEXT, updated_at REAL NOT NULL,
    overrides TEXT NOT NULL DEFAULT '');
CREATE TABLE IF NOT EXISTS cells (
    experiment TEXT NOT NULL, cell TEXT NOT NULL, policy TEXT NOT NULL, size INTEGER, variant TEXT, seed INTEGER,
    collect_demo TEXT, collect_agent TEXT, train_key TEXT, eval_key TEXT NOT NULL,
    PRIMARY KEY (experiment, cell));
CREATE TABLE IF NOT EXISTS checkpoint_evals (
    experiment TEXT NOT NULL, cell TEXT NOT NULL, step INTEGER NOT NULL, eval_key TEXT NOT NULL,
    PRIMARY KEY (experiment, cell, step));
CREATE TABLE IF NOT EXISTS episodes (
    eval_key TEXT NOT NULL, idx INTEGER NOT NULL, task INTEGER NOT NULL, agent_seed TEXT NOT NULL,
    demo_seed TEXT NOT NULL, reached INTEGER NOT NULL, picked INTEGER NOT NULL, placed INTEGER NOT NULL,
    steps INTEGER NOT NULL, first_reached INTEGER, first_picked INTEGER, first_placed INTEGER,
    wrong_bin INTEGER, closed INTEGER, close_step INTEGER, close_x REAL, close_y REAL, close_z REAL,
    PRIMARY KEY (eval_key, idx));
CREATE TABLE IF NOT EXISTS metrics (
    stage_key TEXT NOT NULL, name TEXT NOT NULL, value REAL NOT NULL, PRIMARY KEY (stage_key, name));
CREATE TABLE IF NOT EXISTS loss_curves (
    train_key TEXT NOT NULL, step INTEGER NOT NULL, split TEXT NOT NULL, bc REAL NOT NULL, inverse REAL NOT NULL,
    point REAL NOT NULL, total REAL NOT NULL, PRIMARY KEY (train_key, step, split));
CREATE INDEX IF NOT EXISTS attempts_by_stage ON attempts(stage_key);
";

/// Stores written before artifact paths were relative recorded them as the path `run` was given
/// (`runs/artifacts/train/KEY`, relative to the directory it ran in): keeps their last three parts,
/// `artifacts/KIND/KEY`, which is where every artifact lies in its store folder.
fn relative_artifact_paths(conn: &Connection) -> Result<()> {
    let mut stmt = conn
        .prepare("SELECT key, artifact FROM stages WHERE artifact IS NOT NULL AND artifact NOT LIKE 'artifacts/%'")?;
    let old: Vec<(String, String)> =
        stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?.collect::<rusqlite::Result<_>>()?;
    for (key, artifact) in old {
        let parts: Vec<&str> = Path::new(&artifact).iter().filter_map(|p| p.to_str()).collect();
        if let [.., "artifacts", kind, short] = parts.as_slice() {
            conn.execute(
                "UPDATE stages SET artifact = ?2 WHERE key = ?1",
                params![key, format!("artifacts/{kind}/{short}")],
            )?;
        }
    }
    Ok(())
}

/// Brings a store of an older layout to [`SCHEMA_VERSION`]: each step is idempotent, so an interrupted migration
/// reruns safely.
fn migrate(conn: &mut Connection, path: &Path) -> Result<()> {
    // One writer at a time: a second process opening the same old store waits, then finds it migrated.
    let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
    if schema_version(&tx, path)? < SCHEMA_VERSION {
        tx.execute_batch(SCHEMA).with_context(|| format!("creating the schema in {}", path.display()))?;
        // Version 0 -> 1: artifact paths relative to the store, and the experiments' `--set` overrides.
        relative_artifact_paths(&tx).with_context(|| format!("updating artifact paths in {}", path.display()))?;
        add_column(&tx, "experiments", "overrides TEXT NOT NULL DEFAULT ''", path)?;
        // Version 1 -> 2: the code that ran each attempt.
        add_column(&tx, "attempts", "code_commit TEXT", path)?;
        add_column(&tx, "attempts", "code_digest TEXT", path)?;
        // Version 2 -> 3: whether an episode left the object in another quadrant (unknown before).
        add_column(&tx, "episodes", "wrong_bin INTEGER", path)?;
        // Version 3 -> 4: where the gripper first closed (unknown before).
        for column in ["closed INTEGER", "close_step INTEGER", "close_x REAL", "close_y REAL", "close_z REAL"] {
            add_column(&tx, "episodes", column, path)?;
        }
        tx.pragma_update(None, "user_version", SCHEMA_VERSION)?;
    }
    tx.commit()?;
    Ok(())
}

/// Adds column `definition` (its name, then its type) to `table` unless it is there already.
fn add_column(conn: &Connection, table: &str, definition: &str, path: &Path) -> Result<()> {
    let name = definition.split_whitespace().next().expect("a column definition starts with its name");
    let present =
        conn.prepare(&format!("SELECT 1 FROM pragma_table_info('{table}') WHERE name = ?1"))?.exists([name])?;
    if !present {
        conn.execute_batch(&format!("ALTER TABLE {table} ADD COLUMN {definition}"))
            .with_context(|| format!("adding {table}.{name} to {}", path.display()))?;
    }
    Ok(())
}

/// The layout version of the database at `path`, refused when newer than this binary's.
pub(crate) fn schema_version(conn: &Connection, path: &Path) -> Result<i64> {
    let version: i64 = conn
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .with_context(|| format!("reading {}", path.display()))?;
    if version > SCHEMA_VERSION {
        bail!(
            "{} has store schema version {version}, newer than this oneshot-lab's {SCHEMA_VERSION}: it was written by a \
             newer release; use that release (or a newer one) to read it",
            path.display()
        );
    }
    Ok(version)
}

/// A connection that cannot write the database at `path`, nor create files beside it. Without a write-ahead log
/// beside it (no writer has it open: the last one to close folds the log into the database) the database is
/// opened as immutable, read as it is on disk, since even a read-only WAL connection would create the log's index
/// files. With a log (a writer at work, or one that died) it is opened read-only through the log, which SQLite
/// needs to read the latest state; an unwritable folder then falls back to the immutable view.
pub(crate) fn read_only_connection(path: &Path) -> Result<Connection> {
    use rusqlite::OpenFlags;
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_URI | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let readable = |c: &Connection| c.query_row("SELECT count(*) FROM sqlite_master", [], |r| r.get::<_, i64>(0));
    let mut wal = path.as_os_str().to_owned();
    wal.push("-wal");
    if Path::new(&wal).exists() {
        let conn = Connection::open_with_flags(path, flags).with_context(|| format!("opening {}", path.display()))?;
        if readable(&conn).is_ok() {
            return Ok(conn);
        }
    }
    let escaped = path.display().to_string().replace('%', "%25").replace('?', "%3f").replace('#', "%23");
    let uri = format!("file:{escaped}?immutable=1");
    let conn = Connection::open_with_flags(&uri, flags).with_context(|| format!("opening {}", path.display()))?;
    readable(&conn).with_context(|| format!("reading {}", path.display()))?;
    Ok(conn)
}

/// Whether this process may write both the store folder and its database (`access(2)`, which sees read-only
/// mounts and permissions as the kernel will apply them).
fn writable(root: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let ok = |p: &Path| {
        std::ffi::CString::new(p.as_os_str().as_bytes())
            .is_ok_and(|c| unsafe { libc::access(c.as_ptr(), libc::W_OK) } == 0)
    };
    ok(root) && ok(&root.join(DATABASE))
}

/// Seconds since the Unix epoch.
pub fn now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// This machine's name.
pub fn host() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "unknown".into())
}

/// Whether process `pid` is alive on this machine.
pub fn alive(pid: i64) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

/// The status of a stage as the store knows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StageState {
    Missing,
    Planned,
    Done,
    Failed(String),
    /// Running in a live process (host, pid).
    Running(String, i64),
}

/// Outcome of trying to claim a stage.
#[derive(Debug, PartialEq)]
pub enum Claim {
    /// This process now runs it; the attempt id.
    Acquired(i64),
    AlreadyDone,
    /// A live process runs it.
    Busy(Holder),
}

/// The process running a stage: where, which, and since when.
#[derive(Debug, Clone, PartialEq)]
pub struct Holder {
    pub host: String,
    pub pid: i64,
    /// Seconds since the Unix epoch.
    pub started_at: f64,
}

/// An open results store.
pub struct Store {
    conn: Connection,
    /// The store folder: artifact paths are recorded relative to it, so a copied or moved store still finds its
    /// own artifacts.
    root: PathBuf,
    /// Opened without the right to write (`--read-only`, or a folder this process cannot write).
    read_only: bool,
}

impl Store {
    /// Opens (creating if needed) the store in folder `root`.
    pub fn open(root: &Path) -> Result<Store> {
        std::fs::create_dir_all(root).with_context(|| format!("creating store folder {}", root.display()))?;
        Store::open_database(root)
    }

    /// Opens the store in folder `root`, which must already hold one (commands that change it, such as `gc`).
    pub fn open_existing(root: &Path) -> Result<Store> {
        Store::existing_database(root)?;
        Store::open_database(root)
    }

    /// Opens the store in folder `root`, which must already hold one, for a command that only reads it: without
    /// writing anything where `read_only` is set or this process cannot write the folder, otherwise as
    /// [`Store::open_existing`] (which migrates an older layout).
    pub fn open_for_reading(root: &Path, read_only: bool) -> Result<Store> {
        let path = Store::existing_database(root)?;
        if !read_only && writable(root) {
            return Store::open_database(root);
        }
        let conn = read_only_connection(&path)?;
        let version = schema_version(&conn, &path)?;
        if version < SCHEMA_VERSION {
            bail!(
                "{} has store schema version {version}, older than this oneshot-lab's {SCHEMA_VERSION}, and is opened \
                 read-only: open it once where it can be written (any `status` without --read-only) to migrate it",
                path.display()
            );
        }
        Ok(Store { conn, root: root.to_path_buf(), read_only: true })
    }

    /// Whether the store was opened without the right to write.
    pub fn is_read_only(&self) -> bool {
        self.read_only
    }

    /// The database file of an existing store in `root`.
    fn existing_database(root: &Path) -> Result<PathBuf> {
        let path = root.join(DATABASE);
        if !path.is_file() {
            bail!("no results store at {} (run an experiment there first, or pass --store)", path.display());
        }
        Ok(path)
    }

    fn open_database(root: &Path) -> Result<Store> {
        let path = root.join(DATABASE);
        let mut conn = Connection::open(&path).with_context(|| format!("opening {}", path.display()))?;
        conn.busy_timeout(Duration::from_secs(60))?;
        if schema_version(&conn, &path)? < SCHEMA_VERSION {
            migrate(&mut conn, &path)?;
        }
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "NORMAL")?;
        Ok(Store { conn, root: root.to_path_buf(), read_only: false })
    }

    /// Records the stages (inputs and upstream) of a plan, keeping what is already known.
    pub fn register(&mut self, stages: &[&Stage]) -> Result<()> {
        let tx = self.conn.transaction()?;
        for s in stages {
            tx.execute(
                "INSERT OR IGNORE INTO stages (key, kind, version, inputs, upstream, created_at) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![
                    s.key,
                    s.kind().name(),
                    s.kind().version(),
                    serde_json::to_string(&s.inputs)?,
                    serde_json::to_string(&s.upstream)?,
                    now()
                ],
            )?;
        }
        tx.commit()?;
        Ok(())
    }

    /// Records an experiment (its file, description, profile and `--set` overrides as spelled) and its cells
    /// (replacing its previous cells).
    pub fn record_experiment(&mut self, record: &ExperimentRecord, name: &str, cells: &[PlannedCell]) -> Result<()> {
        let tx = self.conn.transaction()?;
        let ExperimentRecord { file, description, profile, overrides } = record;
        tx.execute(
            "INSERT INTO experiments (name, file, description, profile, updated_at, overrides)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6)
             ON CONFLICT(name) DO UPDATE SET file = ?2, description = ?3, profile = ?4, updated_at = ?5, overrides = ?6",
            params![name, file, description, profile, now(), overrides],
        )?;
        tx.execute("DELETE FROM cells WHERE experiment = ?1", [name])?;
        tx.execute("DELETE FROM checkpoint_evals WHERE experiment = ?1", [name])?;
        for c in cells {
            tx.execute(
                "INSERT INTO cells (experiment, cell, policy, size, variant, seed, collect_demo, collect_agent, train_key, eval_key)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![name, c.name, c.policy, c.size.map(|n| n as i64), c.variant, c.seed.map(|s| s as i64), c.collect_demo, c.collect_agent, c.train, c.eval],
            )?;
            for (step, key) in &c.checkpoints {
                tx.execute(
                    "INSERT INTO checkpoint_evals (experiment, cell, step, eval_key) VALUES (?1, ?2, ?3, ?4)",
                    params![name, c.name, *step as i64, key],
                )?;
            }
        }
        tx.commit()?;
        Ok(())
    }

    /// The state of stage `key`.
    pub fn state(&self, key: &str) -> Result<StageState> {
        let row: Option<String> =
            self.conn.query_row("SELECT status FROM stages WHERE key = ?1", [key], |r| r.get(0)).optional()?;
        Ok(match row.as_deref() {
            None => StageState::Missing,
            Some("done") => StageState::Done,
            Some("running") => match self.live_attempt(key)? {
                Some((host, pid)) => StageState::Running(host, pid),
                None => StageState::Failed("interrupted".into()),
            },
            Some("failed") => StageState::Failed(self.last_error(key)?.unwrap_or_default()),
            _ => StageState::Planned,
        })
    }

    /// Keys of the stages an attempt holds now: a live process on this host, or any holder elsewhere (a Slurm job
    /// or another machine, which this one cannot check).
    pub fn held_stages(&self) -> Result<Vec<String>> {
        let mut stmt = self.conn.prepare("SELECT DISTINCT stage_key FROM attempts WHERE status = 'running'")?;
        let keys = stmt.query_map([], |r| r.get::<_, String>(0))?.collect::<rusqlite::Result<Vec<_>>>()?;
        let mut held = Vec::new();
        for key in keys {
            if self.live_attempt(&key)?.is_some() {
                held.push(key);
            }
        }
        Ok(held)
    }

    fn live_attempt(&self, key: &str) -> Result<Option<(String, i64)>> {
        let row: Option<(String, i64)> = self
            .conn
            .query_row(
                "SELECT host, pid FROM attempts WHERE stage_key = ?1 AND status = 'running' ORDER BY id DESC LIMIT 1",
                [key],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()?;
        Ok(row.filter(|(h, pid)| *h != host() || alive(*pid)))
    }

    fn last_error(&self, key: &str) -> Result<Option<String>> {
        Ok(self
            .conn
            .query_row("SELECT error FROM attempts WHERE stage_key = ?1 ORDER BY id DESC LIMIT 1", [key], |r| r.get(0))
            .optional()?
            .flatten())
    }

    /// Claims stage `key` for this process, atomically with respect to other processes on the store; the attempt
    /// records this binary's code for the stage's kind.
    pub fn claim(&mut self, key: &str, force: bool) -> Result<Claim> {
        let (h, pid) = (host(), std::process::id() as i64);
        let tx = self.conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
        let (status, kind): (String, String) =
            tx.query_row("SELECT status, kind FROM stages WHERE key = ?1", [key], |r| Ok((r.get(0)?, r.get(1)?)))?;
        let kind = Kind::named(&kind).with_context(|| format!("stage {key} has unknown kind `{kind}`"))?;
        if status == "done" && !force {
            return Ok(Claim::AlreadyDone);
        }
        let running: Option<(i64, String, i64, f64)> = tx
            .query_row(
                "SELECT id, host, pid, started_at FROM attempts WHERE stage_key = ?1 AND status = 'running' \
                 ORDER BY id DESC LIMIT 1",
                [key],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
            )
            .optional()?;
        if let Some((id, rh, rpid, started_at)) = running {
            if rh != h || alive(rpid) && rpid != pid {
                return Ok(Claim::Busy(Holder { host: rh, pid: rpid, started_at }));
            }
            tx.execute(
                "UPDATE attempts SET status = 'failed', finished_at = ?2, error = 'interrupted (process gone)' WHERE id = ?1",
                params![id, now()],
            )?;
        }
        tx.execute("UPDATE stages SET status = 'running', finished_at = NULL WHERE key = ?1", [key])?;
        let code = code::current(kind);
        tx.execute(
            "INSERT INTO attempts (stage_key, status, host, pid, started_at, code_commit, code_digest)
             VALUES (?1, 'running', ?2, ?3, ?4, ?5, ?6)",
            params![key, h, pid, now(), code.commit, code.digest],
        )?;
        let id = tx.last_insert_rowid();
        tx.commit()?;
        Ok(Claim::Acquired(id))
    }

    /// The code that built finished stage `key` (its last successful attempt), where that was recorded.
    pub fn built_by(&self, key: &str) -> Result<Option<CodeVersion>> {
        let row: Option<(Option<String>, Option<String>)> = self
            .conn
            .query_row(
                "SELECT code_commit, code_digest FROM attempts WHERE stage_key = ?1 AND status = 'done'
                 ORDER BY id DESC LIMIT 1",
                [key],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()?;
        Ok(row.and_then(|(commit, digest)| Some(CodeVersion { commit: commit?, digest: digest? })))
    }

    /// The code that built finished stage `key` of `kind` where it differs from this binary's (none where it is
    /// the same, or was never recorded).
    pub fn built_by_other_code(&self, key: &str, kind: Kind) -> Result<Option<CodeVersion>> {
        Ok(self.built_by(key)?.filter(|built| built.digest != code::current(kind).digest))
    }

    /// Marks a claimed stage failed.
    pub fn fail(&mut self, key: &str, attempt: i64, error: &str) -> Result<()> {
        let tx = self.conn.transaction()?;
        tx.execute("UPDATE stages SET status = 'failed', finished_at = ?2 WHERE key = ?1", params![key, now()])?;
        tx.execute(
            "UPDATE attempts SET status = 'failed', finished_at = ?2, error = ?3 WHERE id = ?1",
            params![attempt, now(), error],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Marks a claimed stage done with its artifact folder and results, in one transaction.
    pub fn complete(&mut self, key: &str, attempt: i64, artifact: &Path, results: &StageOutputs) -> Result<()> {
        let recorded = self.relative(artifact);
        let tx = self.conn.transaction()?;
        let started: f64 = tx.query_row("SELECT started_at FROM attempts WHERE id = ?1", [attempt], |r| r.get(0))?;
        let t = now();
        for table in ["episodes WHERE eval_key", "metrics WHERE stage_key", "loss_curves WHERE train_key"] {
            tx.execute(&format!("DELETE FROM {table} = ?1"), [key])?;
        }
        for e in &results.episodes {
            tx.execute(
                "INSERT INTO episodes (eval_key, idx, task, agent_seed, demo_seed, reached, picked, placed, steps,
                     first_reached, first_picked, first_placed, wrong_bin, closed, close_step, close_x, close_y,
                     close_z)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18)",
                params![
                    key,
                    e.index as i64,
                    e.task as i64,
                    e.agent_seed.to_string(),
                    e.demo_seed.to_string(),
                    e.reached,
                    e.picked,
                    e.placed,
                    e.steps as i64,
                    e.first_reached.map(|v| v as i64),
                    e.first_picked.map(|v| v as i64),
                    e.first_placed.map(|v| v as i64),
                    e.wrong_bin,
                    e.first_close.is_some(),
                    e.first_close.map(|c| c.step as i64),
                    e.first_close.map(|c| c.object_in_gripper[0]),
                    e.first_close.map(|c| c.object_in_gripper[1]),
                    e.first_close.map(|c| c.object_in_gripper[2])
                ],
            )?;
        }
        for (name, value) in &results.metrics {
            tx.execute("INSERT INTO metrics VALUES (?1, ?2, ?3)", params![key, name.as_str(), value])?;
        }
        for p in &results.curve {
            tx.execute(
                "INSERT INTO loss_curves VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![key, p.step as i64, p.split, p.bc, p.inverse, p.point, p.total],
            )?;
        }
        tx.execute(
            "UPDATE stages SET status = 'done', artifact = ?2, finished_at = ?3, seconds = ?4 WHERE key = ?1",
            params![key, recorded.to_string_lossy(), t, t - started],
        )?;
        tx.execute("UPDATE attempts SET status = 'done', finished_at = ?2 WHERE id = ?1", params![attempt, t])?;
        tx.commit()?;
        Ok(())
    }

    /// The artifact folder of a finished stage.
    pub fn artifact(&self, key: &str) -> Result<Option<PathBuf>> {
        self.conn
            .query_row("SELECT artifact FROM stages WHERE key = ?1 AND status = 'done'", [key], |r| {
                r.get::<_, Option<String>>(0)
            })
            .optional()?
            .flatten()
            .map(|a| self.inside(key, &a))
            .transpose()
    }

    /// The recorded artifact path `recorded` of stage `key` in the store folder, refused unless it has the
    /// shape every artifact has, `artifacts/KIND/KEY` of plain names, so that no path in the database reaches
    /// outside the store.
    fn inside(&self, key: &str, recorded: &str) -> Result<PathBuf> {
        let parts: Vec<&str> = recorded.split('/').collect();
        let plain = parts.iter().all(|p| crate::fsio::check_plain_name("artifact", p).is_ok());
        if parts.len() != 3 || parts[0] != "artifacts" || !plain {
            bail!(
                "stage {} records its artifact at {recorded:?}, not a folder artifacts/KIND/KEY of this store: the \
                 store's database is damaged",
                short(key)
            );
        }
        Ok(self.root.join(recorded))
    }

    /// `artifact` relative to the store folder (as recorded), where it lies inside it.
    fn relative(&self, artifact: &Path) -> PathBuf {
        artifact.strip_prefix(&self.root).map_or_else(|_| artifact.to_path_buf(), Path::to_path_buf)
    }

    /// Marks done stage `key` failed because its artifact is missing or damaged (`reason`), recorded as an attempt
    /// of this process, so the next run recomputes it.
    pub fn mark_damaged(&mut self, key: &str, reason: &str) -> Result<()> {
        let tx = self.conn.transaction()?;
        tx.execute("UPDATE stages SET status = 'failed', finished_at = ?2 WHERE key = ?1", params![key, now()])?;
        tx.execute(
            "INSERT INTO attempts (stage_key, status, host, pid, started_at, finished_at, error)
             VALUES (?1, 'failed', ?2, ?3, ?4, ?4, ?5)",
            params![key, host(), std::process::id() as i64, now(), reason],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Marks the stage whose artifact folder was `artifact` as to be re-run (its folder was removed).
    pub fn forget_artifact(&mut self, artifact: &Path) -> Result<()> {
        let recorded = self.relative(artifact).to_string_lossy().into_owned();
        self.conn.execute("UPDATE stages SET status = 'planned', artifact = NULL WHERE artifact = ?1", [recorded])?;
        Ok(())
    }

    /// Mean seconds per step of finished trainings, for estimates.
    pub fn mean_seconds_per_train_step(&self) -> Result<Option<f64>> {
        Ok(self.conn.query_row(
            "SELECT AVG(seconds / json_extract(inputs, '$.train.steps')) FROM stages
             WHERE kind = 'train' AND status = 'done' AND json_extract(inputs, '$.train.steps') > 0",
            [],
            |r| r.get(0),
        )?)
    }

    /// Mean seconds of finished stages of `kind`, for estimates.
    pub fn mean_seconds(&self, kind: &str) -> Result<Option<f64>> {
        Ok(self
            .conn
            .query_row("SELECT AVG(seconds) FROM stages WHERE kind = ?1 AND status = 'done'", [kind], |r| r.get(0))?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh store in a scratch folder named after `test`, and the smoke experiment's plan to register from.
    fn scratch_store(test: &str) -> (PathBuf, crate::pipeline::graph::Plan, Store) {
        let root = std::env::temp_dir().join(format!("oneshot-store-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let (_, plan) = crate::pipeline::load_plan(Path::new("experiments/smoke.toml"), &Default::default()).unwrap();
        let store = Store::open(&root).unwrap();
        (root, plan, store)
    }

    #[test]
    fn a_stage_another_host_runs_is_busy_and_names_its_holder() {
        let (root, plan, mut store) = scratch_store("claim");
        let stage = &plan.stages[&plan.order[0]];
        store.register(&[stage]).unwrap();
        store
            .conn
            .execute(
                "INSERT INTO attempts (stage_key, status, host, pid, started_at) VALUES (?1, 'running', 'node7', 4242, 100.5)",
                [&stage.key],
            )
            .unwrap();
        let holder = Holder { host: "node7".into(), pid: 4242, started_at: 100.5 };
        assert_eq!(store.claim(&stage.key, false).unwrap(), Claim::Busy(holder));
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn where_each_episode_first_closed_the_gripper_round_trips_through_the_store() {
        use crate::eval::grasps::GraspSummary;
        use crate::eval::{EpisodeResult, GripperClose};
        let (root, plan, mut store) = scratch_store("grasps");
        let stage = &plan.stages[&plan.order[0]];
        store.register(&[stage]).unwrap();
        let Claim::Acquired(attempt) = store.claim(&stage.key, false).unwrap() else { panic!("not claimed") };
        let episode = |index: usize, picked: bool, close: Option<[f64; 3]>| EpisodeResult {
            index,
            task: 0,
            agent_seed: 1,
            demo_seed: 2,
            reached: true,
            picked,
            placed: false,
            wrong_bin: false,
            steps: 10,
            first_reached: Some(4),
            first_picked: None,
            first_placed: None,
            first_close: close.map(|object_in_gripper| GripperClose { step: 5, object_in_gripper }),
        };
        let episodes = vec![
            episode(0, true, Some([0.002, -0.001, 0.004])),
            episode(1, false, Some([-0.025, 0.01, 0.03])),
            episode(2, false, None),
        ];
        let outputs = StageOutputs { metrics: Vec::new(), episodes: episodes.clone(), curve: Vec::new() };
        store.complete(&stage.key, attempt, &root.join("artifacts/x"), &outputs).unwrap();
        let keys = [stage.key.clone()];
        assert_eq!(store.grasps(&keys).unwrap(), Some(GraspSummary::of(&episodes)));
        // A stage being run again keeps its old episodes until it finishes; they are not read meanwhile.
        store.conn.execute("UPDATE stages SET status = 'running'", []).unwrap();
        assert_eq!(store.grasps(&keys).unwrap(), None);
        store.conn.execute("UPDATE stages SET status = 'done'", []).unwrap();
        let steps: Vec<Option<i64>> = {
            let mut q = store.conn.prepare("SELECT close_step FROM episodes ORDER BY idx").unwrap();
            q.query_map([], |r| r.get(0)).unwrap().collect::<rusqlite::Result<_>>().unwrap()
        };
        assert_eq!(steps, [Some(5), Some(5), None]);
        // Episodes stored before the store kept it (version 3) leave it unknown rather than "never closed".
        store.conn.execute("UPDATE episodes SET closed = NULL WHERE idx = 2", []).unwrap();
        assert_eq!(store.grasps(&keys).unwrap(), None);
        assert_eq!(store.grasps(&[]).unwrap(), None, "no episodes, no summary");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn a_failure_stops_showing_once_its_stage_is_run_again() {
        let (root, plan, mut store) = scratch_store("failures");
        let (first, second) = (&plan.stages[&plan.order[0]], &plan.stages[&plan.order[1]]);
        store.register(&[first, second]).unwrap();
        for (stage, why) in [(first, "first broke"), (second, "second broke")] {
            let Claim::Acquired(attempt) = store.claim(&stage.key, false).unwrap() else { panic!("not claimed") };
            store.fail(&stage.key, attempt, why).unwrap();
        }
        let standing = |store: &Store| -> Vec<String> {
            store.recent_failures(5).unwrap().into_iter().map(|f| f.error.unwrap_or_default()).collect()
        };
        assert_eq!(standing(&store), ["second broke", "first broke"]);
        // Running the first stage again hides its old failure, whether the new attempt runs or has finished.
        let Claim::Acquired(attempt) = store.claim(&first.key, false).unwrap() else { panic!("not claimed") };
        assert_eq!(standing(&store), ["second broke"]);
        let outputs = StageOutputs::default();
        store.complete(&first.key, attempt, &root.join("artifacts/x"), &outputs).unwrap();
        assert_eq!(standing(&store), ["second broke"]);
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn an_artifact_path_in_the_database_never_leads_outside_the_store() {
        let (root, plan, mut store) = scratch_store("artifact");
        let stage = &plan.stages[&plan.order[0]];
        store.register(&[stage]).unwrap();
        let Claim::Acquired(attempt) = store.claim(&stage.key, false).unwrap() else { panic!("not claimed") };
        let outputs = StageOutputs::default();
        store.complete(&stage.key, attempt, &root.join("artifacts/collect/abc"), &outputs).unwrap();
        assert_eq!(store.artifact(&stage.key).unwrap(), Some(root.join("artifacts/collect/abc")));
        for damaged in ["/tmp/elsewhere", "artifacts/../../elsewhere", "artifacts/collect", "other/collect/abc"] {
            store.conn.execute("UPDATE stages SET artifact = ?2 WHERE key = ?1", params![stage.key, damaged]).unwrap();
            let err = store.artifact(&stage.key).unwrap_err().to_string();
            assert!(err.contains("database is damaged") && err.contains(damaged), "{damaged}: {err}");
        }
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn a_store_whose_path_holds_uri_characters_opens_read_only() {
        // `%41` would read as `A`, `?` end the path and `#` start a fragment in an unescaped SQLite URI.
        let root = std::env::temp_dir().join(format!("oneshot-store-%41?#-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        drop(Store::open(&root).unwrap());
        let store = Store::open_for_reading(&root, true).unwrap();
        assert!(store.is_read_only());
        assert_eq!(store.stage_counts().unwrap(), vec![]);
        std::fs::remove_dir_all(&root).unwrap();
    }
}
