//! `why`, `status`, `query`, `gc` and `report`: looking into (and tidying) the results store.
use super::options::{StoreArgs, StoreDir};
use anyhow::{Result, bail};
use oneshot_lab::config::Experiment;
use oneshot_lab::pipeline::gc::{folder_size, remove_artifacts, unused_artifacts};
use oneshot_lab::pipeline::graph::short;
use oneshot_lab::pipeline::load_plan;
use oneshot_lab::pipeline::slurm::detached;
use oneshot_lab::pipeline::store::jobs::SLURM_HOST;
use oneshot_lab::pipeline::store::read::StageRecord;
use oneshot_lab::pipeline::store::{DATABASE, Store, now};
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

/// Arguments of the `why` command.
#[derive(clap::Args)]
pub struct WhyArgs {
    /// Stage key or its first characters.
    pub stage: String,
    #[command(flatten)]
    pub store: StoreDir,
}

/// Arguments of the `status` command.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    pub store: StoreDir,
}

/// Arguments of the `query` command.
#[derive(clap::Args)]
pub struct QueryArgs {
    /// A named summary (`cells`, `stages`, `failures`, `curves`) or an SQL statement that only reads.
    pub query: String,
    /// How rows are printed.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
    #[command(flatten)]
    pub store: StoreDir,
}

/// Output formats of `query`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Aligned columns (cells cut at 60 characters).
    Table,
    /// Comma-separated values under a header line.
    Csv,
    /// An array of objects, one per row.
    Json,
}

/// Arguments of the `gc` command.
#[derive(clap::Args)]
pub struct GcArgs {
    /// The experiment files whose stages are kept.
    pub files: Vec<PathBuf>,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Remove the unreferenced artifacts (after printing them and their size); without it they are only listed.
    #[arg(long)]
    pub delete: bool,
}

/// Arguments of the `report` command.
#[derive(clap::Args)]
pub struct ReportArgs {
    /// The experiment file whose report is rebuilt.
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Output folder (default: STORE/reports/NAME).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

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

/// The lines that tell `other`'s inputs (a cached stage) from `stage`'s.
fn differences(stage: &StageRecord, other: &StageRecord) -> Vec<String> {
    let (mut mine, mut theirs) = (BTreeMap::new(), BTreeMap::new());
    flatten("", &stage.inputs, &mut mine);
    flatten("", &other.inputs, &mut theirs);
    let keys: BTreeSet<&String> = mine.keys().chain(theirs.keys()).collect();
    let show = |v: Option<&String>| v.cloned().unwrap_or_else(|| "(absent)".into());
    let mut d: Vec<String> = keys
        .into_iter()
        .filter(|k| mine.get(*k) != theirs.get(*k))
        .map(|k| format!("  {k}: {} (cached) -> {} (this stage)", show(theirs.get(k)), show(mine.get(k))))
        .collect();
    if other.upstream != stage.upstream {
        let keys = |ks: &[String]| ks.iter().map(|k| short(k)).collect::<Vec<_>>().join(",");
        d.push(format!(
            "  upstream stages: {} (cached) -> {} (this stage)",
            keys(&other.upstream),
            keys(&stage.upstream)
        ));
    }
    d
}

/// Explains a stage (a key or its start): its state, and which inputs differ from the nearest cached stage of
/// the same kind.
pub fn why(a: WhyArgs) -> Result<()> {
    let store = Store::open_existing(&a.store.store)?;
    let found = store.stages_with_prefix(&a.stage)?;
    let stage = match found.as_slice() {
        [one] => one,
        [] => bail!(
            "no stage key starts with `{}` in {} (run `plan` or `run` first)",
            a.stage,
            a.store.store.join(DATABASE).display()
        ),
        many => bail!("`{}` matches {} stages; give more of the key", a.stage, many.len()),
    };
    println!("{} stage {} is {}", stage.kind, stage.key, stage.status);
    let done = store.done_stages(&stage.kind)?;
    let nearest =
        done.iter().filter(|o| o.key != stage.key).map(|o| (differences(stage, o), o)).min_by_key(|(d, _)| d.len());
    match (stage.status.as_str(), nearest) {
        ("done", _) => println!("it is cached; a run reuses it"),
        (_, None) => println!("no {} stage is cached yet, so every input is new", stage.kind),
        (_, Some((d, o))) if d.is_empty() => {
            println!("same inputs as cached stage {} but a different implementation version", short(&o.key))
        }
        (_, Some((d, o))) => {
            println!("nearest cached {} stage {} differs in {} field(s):", stage.kind, short(&o.key), d.len());
            for line in d {
                println!("{line}");
            }
        }
    }
    Ok(())
}

/// Prints stage counts by kind and status, running attempts and recent failures.
pub fn status(a: StatusArgs) -> Result<()> {
    let mut store = Store::open_existing(&a.store.store)?;
    println!("store {}", a.store.store.join(DATABASE).display());
    let slurm = detached::catch_up(&mut store, &a.store.store).unwrap_or_else(|e| {
        println!("  warning: Slurm jobs not checked: {e:#}");
        Default::default()
    });
    if !slurm.completed.is_empty() || !slurm.failed.is_empty() {
        println!(
            "  caught up with Slurm: {} jobs finished, {} ended without results",
            slurm.completed.len(),
            slurm.failed.len()
        );
    }
    for (kind, status, n) in store.stage_counts()? {
        println!("  {kind:<8} {status:<8} {n}");
    }
    for (job, entry) in &slurm.live {
        println!("  slurm: {}", detached::describe(job, entry));
    }
    for r in store.running_attempts()?.into_iter().filter(|r| r.host != SLURM_HOST) {
        println!(
            "  running: {} {} on {} pid {} for {:.0} s",
            r.kind,
            short(&r.key),
            r.host,
            r.pid,
            now() - r.started_at
        );
    }
    for f in store.recent_failures(5)? {
        println!("  failed: {} {}: {}", f.kind, short(&f.key), f.error.unwrap_or_default());
    }
    Ok(())
}

fn text(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Null => String::new(),
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Runs a named query or raw SQL against the store, read-only, and prints the rows.
pub fn query(a: QueryArgs) -> Result<()> {
    let q = Store::query_read_only(&a.store.store, &a.query)?;
    match a.format {
        Format::Json => {
            let rows: Vec<serde_json::Value> = q
                .rows
                .into_iter()
                .map(|r| serde_json::Value::Object(q.columns.iter().cloned().zip(r).collect()))
                .collect();
            println!("{}", serde_json::to_string_pretty(&rows)?);
        }
        Format::Csv => {
            let esc = |s: String| {
                if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s }
            };
            println!("{}", q.columns.iter().cloned().map(esc).collect::<Vec<_>>().join(","));
            for r in &q.rows {
                println!("{}", r.iter().map(|v| esc(text(v))).collect::<Vec<_>>().join(","));
            }
        }
        Format::Table => {
            let table: Vec<Vec<String>> = q.rows.iter().map(|r| r.iter().map(text).collect()).collect();
            let widths: Vec<usize> = (0..q.columns.len())
                .map(|i| {
                    table.iter().map(|r| r[i].chars().count()).chain([q.columns[i].len()]).max().unwrap_or(0).min(60)
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
            println!("{}", line(&q.columns));
            for r in &table {
                println!("{}", line(r));
            }
            println!("({} rows)", table.len());
        }
    }
    Ok(())
}

/// Lists (or with `--delete` removes) artifact folders that no stage of the given experiment files uses.
pub fn gc(a: GcArgs) -> Result<()> {
    if a.delete && a.files.is_empty() {
        bail!("gc --delete needs the experiment files whose stages it keeps; with none it would remove every artifact");
    }
    let plans =
        a.files.iter().map(|f| load_plan(f, &a.store.resolution()).map(|(_, p)| p)).collect::<Result<Vec<_>>>()?;
    let mut store = Store::open_existing(&a.store.dir.store)?;
    let unused = unused_artifacts(&a.store.dir.store, &plans, &store.held_stages()?)?;
    for p in &unused {
        println!("{}", p.display());
    }
    let (n, mb) = (unused.len(), unused.iter().map(|p| folder_size(p)).sum::<u64>() as f64 / 1e6);
    if a.delete {
        println!("removing {n} unused artifact folders ({mb:.1} MB)");
        remove_artifacts(&mut store, &unused)?;
    } else if !unused.is_empty() {
        println!("{n} unused artifact folders ({mb:.1} MB); run again with --delete to remove them");
    }
    Ok(())
}

/// Rebuilds an experiment's tables and figures from the store alone.
pub fn report(a: ReportArgs) -> Result<()> {
    let experiment = Experiment::load(&a.file, &a.store.resolution())?;
    let out = a.out.unwrap_or_else(|| oneshot_lab::report::report_dir(&a.store.dir.store, &experiment.name));
    let store = Store::open_existing(&a.store.dir.store)?;
    oneshot_lab::report::write_report(&store, &experiment.name, &out)?;
    println!("wrote {}", out.join("index.md").display());
    Ok(())
}
