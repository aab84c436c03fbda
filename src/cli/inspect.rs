//! `why`, `status`, `query`, `gc` and `report`: looking into (and tidying) the results store.
use super::options::{OutputFormat, ReadStoreDir, StoreArgs};
use super::stage_progress::{self, Progress};
use anyhow::{Result, bail};
use oneshot_lab::config::{Experiment, overrides};
use oneshot_lab::pipeline::code;
use oneshot_lab::pipeline::executor::staging_dir;
use oneshot_lab::pipeline::gc::{folder_size, remove_artifacts, unused_artifacts};
use oneshot_lab::pipeline::graph::short;
use oneshot_lab::pipeline::load_plan;
use oneshot_lab::pipeline::slurm::detached;
use oneshot_lab::pipeline::slurm::queue::shell_quote;
use oneshot_lab::pipeline::stages::Kind;
use oneshot_lab::pipeline::store::jobs::SLURM_HOST;
use oneshot_lab::pipeline::store::read::StageRecord;
use oneshot_lab::pipeline::store::{DATABASE, Store, alive, host, now};
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

/// Arguments of the `why` command.
#[derive(clap::Args)]
pub struct WhyArgs {
    /// Stage key or its first characters.
    pub stage: String,
    #[command(flatten)]
    pub store: ReadStoreDir,
    /// Text for people or JSON for scripts.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// Arguments of the `status` command.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    pub store: ReadStoreDir,
    /// Text for people or JSON for scripts.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
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
    pub store: ReadStoreDir,
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
    /// Output folder (default: STORE/reports/NAME, or STORE/reports/NAME@seed-N with --seed).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Only the trained cells of this training seed (repeatable; the references, which have no seed, stay): a
    /// per-seed report beside the pooled one.
    #[arg(long = "seed", value_name = "N")]
    pub seeds: Vec<u64>,
    /// Open the store without writing anything to it (automatic where this process cannot write its folder);
    /// the report then goes to `--out`, outside the store.
    #[arg(long)]
    pub read_only: bool,
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

/// One input in which two stages differ: its dotted name and each stage's value (`(absent)` where it has none).
#[derive(serde::Serialize)]
pub struct Difference {
    pub input: String,
    pub a: String,
    pub b: String,
}

/// The inputs (and upstream stages, as `upstream`) in which stage `a` differs from stage `b`.
pub fn differences(a: &StageRecord, b: &StageRecord) -> Vec<Difference> {
    let (mut left, mut right) = (BTreeMap::new(), BTreeMap::new());
    flatten("", &a.inputs, &mut left);
    flatten("", &b.inputs, &mut right);
    let keys: BTreeSet<&String> = left.keys().chain(right.keys()).collect();
    let show = |v: Option<&String>| v.cloned().unwrap_or_else(|| "(absent)".into());
    let mut d: Vec<Difference> = keys
        .into_iter()
        .filter(|k| left.get(*k) != right.get(*k))
        .map(|k| Difference { input: k.clone(), a: show(left.get(k)), b: show(right.get(k)) })
        .collect();
    if a.upstream != b.upstream {
        let keys = |ks: &[String]| ks.iter().map(|k| short(k)).collect::<Vec<_>>().join(",");
        d.push(Difference { input: "upstream".into(), a: keys(&a.upstream), b: keys(&b.upstream) });
    }
    d
}

/// Explains a stage (a key or its start): its state, and which inputs differ from the nearest cached stage of
/// the same kind.
pub fn why(a: WhyArgs) -> Result<()> {
    let store = a.store.open()?;
    let stage = one_stage(&store, &a.store, &a.stage)?;
    let done = store.done_stages(&stage.kind)?;
    let nearest =
        done.iter().filter(|o| o.key != stage.key).map(|o| (differences(&stage, o), o)).min_by_key(|(d, _)| d.len());
    if a.format == OutputFormat::Json {
        let out = serde_json::json!({
            "kind": stage.kind,
            "key": stage.key,
            "status": stage.status,
            "built_by": store.built_by(&stage.key)?.map(|c| serde_json::json!({
                "commit": c.commit,
                "digest": c.digest,
                "same_code_as_this_binary": Kind::named(&stage.kind).map(|k| code::current(k).digest == c.digest),
            })),
            "nearest_cached": nearest.as_ref().map(|(d, o)| serde_json::json!({
                "key": o.key,
                "differences": d.iter().map(|d| serde_json::json!({ "input": d.input, "cached": d.b, "this": d.a }))
                    .collect::<Vec<_>>(),
            })),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{} stage {} is {}", stage.kind, stage.key, stage.status);
    match (stage.status.as_str(), nearest) {
        ("done", _) => {
            println!("it is cached; a run reuses it");
            println!("{}", built_by(&store, &stage)?);
        }
        (_, None) => println!("no {} stage is cached yet, so every input is new", stage.kind),
        (_, Some((d, o))) if d.is_empty() => {
            println!("same inputs as cached stage {} but a different implementation version", short(&o.key))
        }
        (_, Some((d, o))) => {
            println!("nearest cached {} stage {} differs in {} field(s):", stage.kind, short(&o.key), d.len());
            for d in d {
                println!("  {}: {} (cached) -> {} (this stage)", d.input, d.b, d.a);
            }
        }
    }
    Ok(())
}

/// Which code built finished stage `stage`, against this binary's.
fn built_by(store: &Store, stage: &StageRecord) -> Result<String> {
    let Some(kind) = Kind::named(&stage.kind) else { return Ok(format!("its kind `{}` is unknown", stage.kind)) };
    let now = code::current(kind);
    Ok(match store.built_by(&stage.key)? {
        None => "built before oneshot-lab recorded which code builds a stage".into(),
        Some(built) if built.digest == now.digest => {
            format!("built from commit {} by the same {} code as this binary's", built.commit, stage.kind)
        }
        Some(built) => format!(
            "built from commit {} by other code: the source of the {kind} stage's modules changed since (digest {} \
             then, {} in this binary, commit {}); `run FILE --rerun-code-changed {kind}` re-runs it",
            built.commit,
            built.digest,
            now.digest,
            now.commit,
            kind = stage.kind
        ),
    })
}

/// The one stage whose key starts with `prefix`.
pub fn one_stage(store: &Store, dir: &ReadStoreDir, prefix: &str) -> Result<StageRecord> {
    let mut found = store.stages_with_prefix(prefix)?;
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => bail!(
            "no stage key starts with `{prefix}` in {} (run `plan` or `run` first)",
            dir.store.join(DATABASE).display()
        ),
        n => bail!("`{prefix}` matches {n} stages; give more of the key"),
    }
}

/// Prints stage counts by kind and status, running attempts (and whether their process is still alive) and
/// recent failures.
pub fn status(a: StatusArgs) -> Result<()> {
    let mut store = a.store.open()?;
    let mut warnings = Vec::new();
    let slurm = if store.is_read_only() {
        warnings.push("Slurm jobs not checked: the store is open read-only".into());
        Default::default()
    } else {
        detached::catch_up(&mut store, &a.store.store).unwrap_or_else(|e| {
            warnings.push(format!("Slurm jobs not checked: {e:#}"));
            Default::default()
        })
    };
    let this_host = host();
    let running: Vec<_> = store
        .running_attempts()?
        .into_iter()
        .filter(|r| r.host != SLURM_HOST)
        .map(|r| {
            // A holder on this machine whose process is gone died without recording it: the next run takes over.
            let live = if r.host == this_host { Some(alive(r.pid)) } else { None };
            let progress = running_progress(&store, &a.store, &r.key, &r.kind, r.started_at);
            (r, live, progress)
        })
        .collect();
    let failures = store.recent_failures(5)?;
    if a.format == OutputFormat::Json {
        let out = serde_json::json!({
            "store": a.store.store.join(DATABASE),
            "warnings": warnings,
            "slurm_caught_up": { "finished": slurm.completed.len(), "without_results": slurm.failed.len() },
            "stages": store.stage_counts()?.into_iter()
                .map(|(kind, status, n)| serde_json::json!({ "kind": kind, "status": status, "count": n }))
                .collect::<Vec<_>>(),
            "slurm_jobs": slurm.live.iter().map(|(job, entry)| detached::describe(job, entry)).collect::<Vec<_>>(),
            "running": running.iter().map(|(r, live, progress)| serde_json::json!({
                "kind": r.kind, "key": r.key, "host": r.host, "pid": r.pid,
                "seconds": now() - r.started_at, "process_alive": live,
                "training": progress.as_ref().and_then(Progress::training),
                "pretraining": progress.as_ref().and_then(Progress::pretraining),
            })).collect::<Vec<_>>(),
            "recent_failures": failures.iter()
                .map(|f| serde_json::json!({ "kind": f.kind, "key": f.key, "error": f.error }))
                .collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("store {}", a.store.store.join(DATABASE).display());
    for w in &warnings {
        println!("  warning: {w}");
    }
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
    for (r, live, progress) in &running {
        let what =
            if *live == Some(false) { "stale (its process is gone; the next run takes it over)" } else { "running" };
        println!(
            "  {what}: {} {} on {} pid {} for {:.0} s",
            r.kind,
            short(&r.key),
            r.host,
            r.pid,
            now() - r.started_at
        );
        if let Some(p) = progress {
            println!("    {p}");
        }
    }
    for f in failures {
        println!("  failed: {} {}: {}", f.kind, short(&f.key), f.error.unwrap_or_default());
    }
    Ok(())
}

/// Where the running stage `key` of `kind` stands, from its staging folder: none for kinds that keep no record
/// there as they run, or before their first.
fn running_progress(store: &Store, dir: &ReadStoreDir, key: &str, kind: &str, started_at: f64) -> Option<Progress> {
    if kind != "train" && kind != "pretrain" {
        return None;
    }
    let inputs = one_stage(store, dir, key).ok()?.inputs;
    let staging = staging_dir(&dir.store, key);
    let steps = |section: &str, name: &str| inputs.get(section)?.get(name)?.as_u64();
    if kind == "train" {
        stage_progress::training(&staging, steps("train", "steps")?, started_at).map(Progress::Training)
    } else {
        let phases = (steps("pretrain", "steps")?, steps("pretrain", "object_attention_steps").unwrap_or(0));
        stage_progress::pretraining(&staging, phases, started_at).map(Progress::Pretraining)
    }
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

/// A report shows an experiment as its last `run` recorded it (cells, profile, overrides). A report asked for with
/// another profile or other overrides is refused, naming both; one asked for plainly, of a run made with some,
/// says so on stderr, since its cells may not be the file's as written.
fn check_as_last_run(store: &Store, experiment: &Experiment, a: &ReportArgs) -> Result<()> {
    let recorded = store.experiment(&experiment.name)?;
    let describe = |profile: &Option<String>, overrides: &str| {
        let parts: Vec<String> = profile
            .iter()
            .map(|p| format!("--profile {p}"))
            .chain((!overrides.is_empty()).then(|| overrides.into()))
            .collect();
        if parts.is_empty() { "no profile or overrides".to_string() } else { parts.join(" ") }
    };
    let last = describe(&recorded.profile, &recorded.overrides);
    let asked_overrides = overrides::spelled(&experiment.resolution.overrides);
    let asked = describe(&a.store.file.profile, &asked_overrides);
    let file = a.file.display();
    if a.store.file.profile.is_some() || !asked_overrides.is_empty() {
        if (&recorded.profile, &recorded.overrides) != (&a.store.file.profile, &asked_overrides) {
            let command: Vec<String> = a
                .store
                .file
                .profile
                .iter()
                .map(|p| format!("--profile {}", shell_quote(p)))
                .chain(experiment.resolution.overrides.iter().map(|o| format!("--set {}", shell_quote(&o.to_string()))))
                .collect();
            bail!(
                "the store holds experiment `{}` as last run with {last}, not with {asked}: a report shows an \
                 experiment as its last run recorded it, so run `oneshot-lab run {file} {}` first (finished \
                 stages are cached), then report",
                experiment.name,
                command.join(" ")
            );
        }
    } else if last != asked {
        eprintln!(
            "note: reporting `{}` as last run, with {last}; `oneshot-lab run {file}` records the file as written \
             (finished stages are cached)",
            experiment.name
        );
    }
    Ok(())
}

/// Rebuilds an experiment's tables and figures from the store alone.
pub fn report(mut a: ReportArgs) -> Result<()> {
    a.seeds.sort_unstable();
    a.seeds.dedup();
    let experiment = Experiment::load(&a.file, &a.store.resolution())?;
    let store = Store::open_for_reading(&a.store.dir.store, a.read_only)?;
    let in_store = |out: &PathBuf| {
        let absolute = |p: &std::path::Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        absolute(out).starts_with(absolute(&a.store.dir.store))
    };
    if store.is_read_only() && a.out.as_ref().is_none_or(in_store) {
        bail!(
            "the store {} is open read-only, so its report cannot go in it: pass --out FOLDER outside it",
            a.store.dir.store.display()
        );
    }
    check_as_last_run(&store, &experiment, &a)?;
    let out = a.out.unwrap_or_else(|| oneshot_lab::report::report_dir(&a.store.dir.store, &experiment.name, &a.seeds));
    oneshot_lab::report::write_report(&store, &experiment.name, &a.seeds, &out)?;
    super::print::print_table1(&out)?;
    println!("wrote {}", out.join("index.md").display());
    Ok(())
}
