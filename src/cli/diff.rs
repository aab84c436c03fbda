//! `diff A B`: two stages, or two cells, side by side: the inputs that differ and the metrics each recorded.
use super::inspect::{differences, one_stage};
use super::options::{OutputFormat, ReadStoreDir};
use anyhow::{Result, bail};
use oneshot_lab::pipeline::graph::short;
use oneshot_lab::pipeline::store::Store;
use oneshot_lab::pipeline::store::read::StageRecord;
use std::collections::BTreeMap;

/// Arguments of the `diff` command.
#[derive(clap::Args)]
pub struct DiffArgs {
    /// A stage key (or its first characters), a cell (`n1600-full-s0`) or an experiment's cell
    /// (`learn_cpu16/n1600-full-s0`).
    pub a: String,
    /// The other stage or cell.
    pub b: String,
    #[command(flatten)]
    pub store: ReadStoreDir,
    /// Text for people or JSON for scripts.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// The stages one side of a diff names: a cell's train and eval stages, or one stage.
fn stages_of(store: &Store, dir: &ReadStoreDir, what: &str) -> Result<Vec<StageRecord>> {
    let (experiment, cell) = match what.split_once('/') {
        Some((e, c)) => (Some(e), c),
        None => (None, what),
    };
    let cells = store.cells_named(experiment, cell)?;
    match cells.as_slice() {
        [] if experiment.is_some() => bail!("no cell `{cell}` recorded for experiment `{}`", experiment.unwrap_or("")),
        [] => Ok(vec![one_stage(store, dir, what)?]),
        [(_, c)] => {
            let keys = c.train_key.iter().chain([&c.eval_key]);
            keys.map(|k| one_stage(store, dir, k)).collect()
        }
        many => {
            let names: Vec<String> = many.iter().map(|(e, _)| format!("{e}/{cell}")).collect();
            bail!("cell `{cell}` is recorded by several experiments: name one of {}", names.join(", "))
        }
    }
}

/// `diff`: pairs the stages of A and B by kind and prints, for each pair, the inputs that differ and the metrics.
pub fn diff(a: DiffArgs) -> Result<()> {
    let store = a.store.open()?;
    let (left, right) = (stages_of(&store, &a.store, &a.a)?, stages_of(&store, &a.store, &a.b)?);
    let mut pairs = Vec::new();
    for l in &left {
        let Some(r) = right.iter().find(|r| r.kind == l.kind) else {
            bail!("`{}` has a {} stage and `{}` has none to compare it with", a.a, l.kind, a.b);
        };
        let metrics = |s: &StageRecord| store.metrics(&s.key).map(|m| m.into_iter().collect::<BTreeMap<_, _>>());
        let (ml, mr) = (metrics(l)?, metrics(r)?);
        let names: Vec<&String> = ml.keys().chain(mr.keys().filter(|k| !ml.contains_key(*k))).collect();
        let side_by_side: Vec<(String, Option<f64>, Option<f64>)> =
            names.into_iter().map(|n| (n.clone(), ml.get(n).copied(), mr.get(n).copied())).collect();
        pairs.push((l, r, differences(l, r), side_by_side));
    }
    if a.format == OutputFormat::Json {
        let out: Vec<_> = pairs
            .iter()
            .map(|(l, r, d, m)| {
                serde_json::json!({
                    "kind": l.kind, "a": l.key, "b": r.key, "differences": d,
                    "metrics": m.iter().map(|(n, x, y)| serde_json::json!({ "name": n, "a": x, "b": y }))
                        .collect::<Vec<_>>(),
                })
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let shown = |v: &Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    for (l, r, d, m) in &pairs {
        println!("{} {} ({}) vs {} ({})", l.kind, short(&l.key), l.status, short(&r.key), r.status);
        if d.is_empty() {
            println!("  same inputs");
        }
        for d in d {
            println!("  {}: {} -> {}", d.input, d.a, d.b);
        }
        if !m.is_empty() {
            println!("  {:<32} {:>12} {:>12}", "metric", short(&l.key), short(&r.key));
        }
        for (name, x, y) in m {
            println!("  {name:<32} {:>12} {:>12}", shown(x), shown(y));
        }
    }
    Ok(())
}
