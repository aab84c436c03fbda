//! `config`: the resolved configuration of an experiment file (its base, or one cell), with every value that
//! differs from the paper's defaults marked.
use super::options::ResolutionArgs;
use anyhow::{Result, bail};
use oneshot_lab::config::{CellConfig, Experiment};
use std::path::{Path, PathBuf};

/// Arguments of the `config` command.
#[derive(clap::Args)]
pub struct ConfigArgs {
    /// The experiment file.
    pub file: PathBuf,
    #[command(flatten)]
    pub file_resolution: ResolutionArgs,
    /// One cell of the grid (e.g. `n1600-full-s0`) instead of the base configuration.
    #[arg(long)]
    pub cell: Option<String>,
    /// How to print it.
    #[arg(long, value_enum, default_value = "toml")]
    pub format: ConfigFormat,
}

/// How `config` prints.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ConfigFormat {
    /// TOML, each value that differs from the default followed by `# default: ...`.
    Toml,
    /// `{"config": {...}, "changed": {"train.lr": {"value": ..., "default": ...}, ...}}`.
    Json,
}

/// `config`: prints the resolved configuration.
pub fn config(a: ConfigArgs) -> Result<()> {
    let resolution = a.file_resolution.resolution();
    let experiment = Experiment::load(&a.file, &resolution)?;
    let (what, config) = chosen_config(&experiment, &a.file, a.cell.as_deref())?;
    let value = toml::Value::try_from(config)?;
    let defaults = toml::Value::try_from(CellConfig::default())?;
    let (toml::Value::Table(value), toml::Value::Table(defaults)) = (value, defaults) else {
        bail!("a configuration serialises to a table");
    };
    match a.format {
        ConfigFormat::Toml => {
            println!("# {}: {what}", a.file.display());
            if let Some(p) = &resolution.profile {
                println!("# profile `{p}`");
            }
            for o in &resolution.overrides {
                println!("# --set {o}");
            }
            print!("{}", annotated(&value, &defaults, ""));
        }
        ConfigFormat::Json => {
            let mut changed = serde_json::Map::new();
            differences(&value, &defaults, "", &mut changed);
            let out = serde_json::json!({ "config": value, "changed": changed });
            println!("{}", serde_json::to_string_pretty(&out)?);
        }
    }
    Ok(())
}

/// The configuration of one cell of `experiment` (read from `file`), or its base without a cell, and how to name
/// it; an unknown cell is an error naming the file and listing the cells.
pub(super) fn chosen_config<'a>(
    experiment: &'a Experiment,
    file: &Path,
    cell: Option<&str>,
) -> Result<(String, &'a CellConfig)> {
    let Some(name) = cell else {
        return Ok(("the base configuration".to_string(), &experiment.base));
    };
    match experiment.cells.iter().find(|c| c.name == name) {
        Some(cell) => Ok((format!("cell {name}"), &cell.config)),
        None => {
            let names: Vec<&str> = experiment.cells.iter().map(|c| c.name.as_str()).collect();
            bail!("{}: no cell `{name}` (cells: {})", file.display(), names.join(", "))
        }
    }
}

/// `table` as TOML under the header `prefix`: its values first, then its tables, each value that differs from
/// `defaults` followed by its default.
fn annotated(table: &toml::Table, defaults: &toml::Table, prefix: &str) -> String {
    let mut out = String::new();
    if !prefix.is_empty() {
        out += &format!("\n[{prefix}]\n");
    }
    for (key, v) in table.iter().filter(|(_, v)| !v.is_table()) {
        let line = format!("{key} = {}", inline(v));
        match defaults.get(key) {
            Some(d) if d == v => out += &format!("{line}\n"),
            Some(d) => out += &format!("{line}  # default: {}\n", inline(d)),
            None => out += &format!("{line}  # default: none\n"),
        }
    }
    for (key, v) in table {
        if let toml::Value::Table(t) = v {
            let empty = toml::Table::new();
            let d = defaults.get(key).and_then(toml::Value::as_table).unwrap_or(&empty);
            let header = if prefix.is_empty() { key.clone() } else { format!("{prefix}.{key}") };
            out += &annotated(t, d, &header);
        }
    }
    if let Some(missing) = defaults.keys().find(|k| !table.contains_key(*k)) {
        out += &format!("# {missing}: none (default: {})\n", inline(&defaults[missing]));
    }
    out
}

/// A value on one line as TOML writes it (tables inline); also the reference pages' defaults.
pub(super) fn inline(v: &toml::Value) -> String {
    match v {
        toml::Value::Table(t) => {
            let parts: Vec<String> = t.iter().map(|(k, v)| format!("{k} = {}", inline(v))).collect();
            format!("{{ {} }}", parts.join(", "))
        }
        v => v.to_string(),
    }
}

/// Every dotted key whose value differs from its default, into `out` as `{"value": ..., "default": ...}`.
fn differences(
    table: &toml::Table,
    defaults: &toml::Table,
    prefix: &str,
    out: &mut serde_json::Map<String, serde_json::Value>,
) {
    let dotted = |k: &str| if prefix.is_empty() { k.to_string() } else { format!("{prefix}.{k}") };
    for (key, v) in table {
        match (v, defaults.get(key)) {
            (toml::Value::Table(t), Some(toml::Value::Table(d))) => differences(t, d, &dotted(key), out),
            (v, d) if d != Some(v) => {
                let default = d.map_or(serde_json::Value::Null, |d| serde_json::json!(d));
                out.insert(dotted(key), serde_json::json!({ "value": v, "default": default }));
            }
            _ => {}
        }
    }
    for (key, d) in defaults.iter().filter(|(k, _)| !table.contains_key(*k)) {
        out.insert(dotted(key), serde_json::json!({ "value": null, "default": d }));
    }
}
