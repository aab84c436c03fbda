//! `why`, `status`, `query` and `gc`: looking into (and tidying) the results store.
use crate::commands::orchestrate::load_plan;
use crate::pipeline::store::{DATABASE, Store};
use anyhow::{Context, Result, bail};
use rusqlite::types::ValueRef;
use rusqlite::{Connection, OpenFlags};
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

/// Flattens JSON into `dotted.path -> value text`.
fn flatten(prefix: &str, v: &serde_json::Value, out: &mut BTreeMap<String, String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                let p = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                flatten(&p, x, out);
            }
        }
        other => {
            out.insert(prefix.to_string(), other.to_string());
        }
    }
}

struct StageRow {
    key: String,
    kind: String,
    status: String,
    inputs: BTreeMap<String, String>,
    upstream: Vec<String>,
}

fn stage_rows(store: &Store, filter: &str, arg: &str) -> Result<Vec<StageRow>> {
    let mut stmt = store
        .conn()
        .prepare(&format!("SELECT key, kind, status, inputs, upstream FROM stages WHERE {filter} ORDER BY key"))?;
    let rows = stmt.query_map([arg], |r| {
        Ok((
            r.get::<_, String>(0)?,
            r.get::<_, String>(1)?,
            r.get::<_, String>(2)?,
            r.get::<_, String>(3)?,
            r.get::<_, String>(4)?,
        ))
    })?;
    let mut out = Vec::new();
    for row in rows {
        let (key, kind, status, inputs, upstream) = row?;
        let mut flat = BTreeMap::new();
        flatten("", &serde_json::from_str(&inputs)?, &mut flat);
        out.push(StageRow { key, kind, status, inputs: flat, upstream: serde_json::from_str(&upstream)? });
    }
    Ok(out)
}

/// Explains stage `prefix` (a key or its start): its state, and which inputs differ from the nearest cached
/// stage of the same kind.
pub fn why(root: &Path, prefix: &str) -> Result<()> {
    let store = Store::open(root)?;
    let found = stage_rows(&store, "key LIKE ?1 || '%'", prefix)?;
    let stage = match found.as_slice() {
        [one] => one,
        [] => bail!(
            "no stage key starts with `{prefix}` in {} (run `plan` or `run` first)",
            root.join(DATABASE).display()
        ),
        many => bail!("`{prefix}` matches {} stages; give more of the key", many.len()),
    };
    println!("{} stage {} is {}", stage.kind, stage.key, stage.status);
    let done = stage_rows(&store, "kind = ?1 AND status = 'done'", &stage.kind)?;
    let diff = |other: &StageRow| -> Vec<String> {
        let mut d = Vec::new();
        let keys: HashSet<&String> = stage.inputs.keys().chain(other.inputs.keys()).collect();
        let mut keys: Vec<&String> = keys.into_iter().collect();
        keys.sort();
        for k in keys {
            let (a, b) = (other.inputs.get(k), stage.inputs.get(k));
            if a != b {
                let show = |v: Option<&String>| v.cloned().unwrap_or_else(|| "(absent)".into());
                d.push(format!("  {k}: {} (cached) -> {} (this stage)", show(a), show(b)));
            }
        }
        if other.upstream != stage.upstream {
            d.push(format!(
                "  upstream stages: {} (cached) -> {} (this stage)",
                other.upstream.iter().map(|k| &k[..12]).collect::<Vec<_>>().join(","),
                stage.upstream.iter().map(|k| &k[..12]).collect::<Vec<_>>().join(",")
            ));
        }
        d
    };
    let nearest = done.iter().filter(|o| o.key != stage.key).map(|o| (diff(o), o)).min_by_key(|(d, _)| d.len());
    match (stage.status.as_str(), nearest) {
        ("done", _) => println!("it is cached; a run reuses it"),
        (_, None) => println!("no {} stage is cached yet, so every input is new", stage.kind),
        (_, Some((d, o))) if d.is_empty() => {
            println!("same inputs as cached stage {} but a different implementation version", &o.key[..12])
        }
        (_, Some((d, o))) => {
            println!("nearest cached {} stage {} differs in {} field(s):", stage.kind, &o.key[..12], d.len());
            for line in d {
                println!("{line}");
            }
        }
    }
    Ok(())
}

/// Prints stage counts by kind and status, running attempts and recent failures.
pub fn status(root: &Path) -> Result<()> {
    let store = Store::open(root)?;
    let conn = store.conn();
    println!("store {}", root.join(DATABASE).display());
    let mut stmt =
        conn.prepare("SELECT kind, status, COUNT(*) FROM stages GROUP BY kind, status ORDER BY kind, status")?;
    let rows = stmt.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?, r.get::<_, i64>(2)?)))?;
    for row in rows {
        let (kind, status, n) = row?;
        println!("  {kind:<8} {status:<8} {n}");
    }
    let mut stmt = conn.prepare(
        "SELECT a.stage_key, s.kind, a.host, a.pid, a.started_at FROM attempts a JOIN stages s ON s.key = a.stage_key
         WHERE a.status = 'running' ORDER BY a.id",
    )?;
    let running = stmt.query_map([], |r| {
        Ok((
            r.get::<_, String>(0)?,
            r.get::<_, String>(1)?,
            r.get::<_, String>(2)?,
            r.get::<_, i64>(3)?,
            r.get::<_, f64>(4)?,
        ))
    })?;
    for r in running {
        let (key, kind, host, pid, started) = r?;
        let age = crate::pipeline::store::now() - started;
        println!("  running: {kind} {} on {host} pid {pid} for {age:.0} s", &key[..12]);
    }
    let mut stmt = conn.prepare(
        "SELECT a.stage_key, s.kind, a.error FROM attempts a JOIN stages s ON s.key = a.stage_key
         WHERE a.status = 'failed' ORDER BY a.id DESC LIMIT 5",
    )?;
    let failed =
        stmt.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?, r.get::<_, Option<String>>(2)?)))?;
    for f in failed {
        let (key, kind, error) = f?;
        println!("  failed: {kind} {}: {}", &key[..12], error.unwrap_or_default());
    }
    Ok(())
}

/// Named queries of `query`.
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

/// Output formats of `query`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Table,
    Csv,
    Json,
}

fn value_text(v: ValueRef) -> String {
    match v {
        ValueRef::Null => String::new(),
        ValueRef::Integer(i) => i.to_string(),
        ValueRef::Real(f) => f.to_string(),
        ValueRef::Text(t) => String::from_utf8_lossy(t).into_owned(),
        ValueRef::Blob(b) => format!("<{} bytes>", b.len()),
    }
}

fn value_json(v: ValueRef) -> serde_json::Value {
    match v {
        ValueRef::Null => serde_json::Value::Null,
        ValueRef::Integer(i) => i.into(),
        ValueRef::Real(f) => f.into(),
        other => value_text(other).into(),
    }
}

/// Runs a named query or raw SQL against the store, read-only, and prints the rows.
pub fn query(root: &Path, what: &str, format: Format) -> Result<()> {
    let path = root.join(DATABASE);
    if !path.exists() {
        bail!("no results store at {}", path.display());
    }
    let conn = Connection::open_with_flags(&path, OpenFlags::SQLITE_OPEN_READ_ONLY)
        .with_context(|| format!("opening {}", path.display()))?;
    let sql = NAMED_QUERIES.iter().find(|(n, _)| *n == what).map_or(what, |(_, q)| *q);
    let mut stmt = conn.prepare(sql).with_context(|| {
        let names: Vec<&str> = NAMED_QUERIES.iter().map(|(n, _)| *n).collect();
        format!("`{what}` is neither a named query ({}) nor valid SQL", names.join(", "))
    })?;
    let columns: Vec<String> = stmt.column_names().map(|c| c.to_string()).collect();
    let mut rows = stmt.query([])?;
    let mut table: Vec<Vec<String>> = Vec::new();
    let mut json = Vec::new();
    while let Some(row) = rows.next()? {
        let values: Vec<ValueRef> = (0..columns.len()).map(|i| row.get_ref(i)).collect::<rusqlite::Result<_>>()?;
        match format {
            Format::Json => {
                let obj: serde_json::Map<String, serde_json::Value> =
                    columns.iter().cloned().zip(values.into_iter().map(value_json)).collect();
                json.push(serde_json::Value::Object(obj));
            }
            _ => table.push(values.into_iter().map(value_text).collect()),
        }
    }
    match format {
        Format::Json => println!("{}", serde_json::to_string_pretty(&json)?),
        Format::Csv => {
            let esc = |s: &String| {
                if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.clone() }
            };
            println!("{}", columns.iter().map(esc).collect::<Vec<_>>().join(","));
            for r in &table {
                println!("{}", r.iter().map(esc).collect::<Vec<_>>().join(","));
            }
        }
        Format::Table => {
            let widths: Vec<usize> = (0..columns.len())
                .map(|i| {
                    table.iter().map(|r| r[i].chars().count()).chain([columns[i].len()]).max().unwrap_or(0).min(60)
                })
                .collect();
            let line = |cells: &[String]| {
                cells
                    .iter()
                    .zip(&widths)
                    .map(|(c, w)| format!("{:<w$}", c.chars().take(60).collect::<String>()))
                    .collect::<Vec<_>>()
                    .join("  ")
            };
            println!("{}", line(&columns));
            for r in &table {
                println!("{}", line(r));
            }
            println!("({} rows)", table.len());
        }
    }
    Ok(())
}

/// Artifact folders that no stage of the given experiment files uses; removed (and their stages marked to be
/// re-run) only with `delete`.
pub fn gc(root: &Path, files: &[PathBuf], profile: Option<&str>, delete: bool) -> Result<Vec<PathBuf>> {
    let mut keep: HashSet<String> = HashSet::new();
    for f in files {
        let (_, plan) = load_plan(f, profile)?;
        keep.extend(plan.stages.keys().map(|k| crate::pipeline::graph::short(k).to_string()));
    }
    let mut unused = Vec::new();
    let artifacts = root.join("artifacts");
    for kind in ["collect", "train", "eval", ".staging"] {
        let dir = artifacts.join(kind);
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries {
            let path = e?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("").to_string();
            if !keep.contains(&name) {
                unused.push(path);
            }
        }
    }
    unused.sort();
    let mut store = Store::open(root)?;
    for path in &unused {
        if delete {
            std::fs::remove_dir_all(path).with_context(|| format!("removing {}", path.display()))?;
            store.forget_artifact(&path.to_string_lossy())?;
        }
    }
    Ok(unused)
}
