//! Reading an experiment file: its include chain and profiles merged into one table, and errors located at the
//! file, line and key they are about.
use super::{CellConfig, Grid};
use anyhow::{Context, Result, bail};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

/// The top level of an experiment file after its include and profile are merged in: sections stay tables
/// (merged with variants before they are typed), the rest is typed here.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileShape {
    pub(super) name: Option<String>,
    pub(super) description: Option<String>,
    pub(super) world: Option<toml::Table>,
    pub(super) collect: Option<toml::Table>,
    pub(super) model: Option<toml::Table>,
    pub(super) pretrain: Option<toml::Table>,
    pub(super) train: Option<toml::Table>,
    pub(super) eval: Option<toml::Table>,
    #[serde(default)]
    pub(super) grid: Grid,
    #[serde(default)]
    pub(super) variants: BTreeMap<String, toml::Table>,
    #[serde(default)]
    pub(super) slurm: super::slurm::SlurmSection,
    /// Already merged in (the chosen one) when the shape is read.
    #[serde(default, rename = "profiles")]
    pub(super) _profiles: Option<toml::Table>,
}

impl FileShape {
    /// The sections as one table, the base every variant starts from.
    pub(super) fn sections(&self) -> toml::Table {
        let all = [
            ("world", &self.world),
            ("collect", &self.collect),
            ("model", &self.model),
            ("pretrain", &self.pretrain),
            ("train", &self.train),
            ("eval", &self.eval),
        ];
        all.into_iter().filter_map(|(k, v)| Some((k.to_string(), toml::Value::Table(v.clone()?)))).collect()
    }
}

/// Deep-merges `over` into `base` (tables merge key by key; anything else is replaced).
pub(super) fn merge(base: &mut toml::Table, over: &toml::Table) {
    for (k, v) in over {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// The 1-based line of the first occurrence of `key` as a TOML key in `text`.
pub(super) fn line_of(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.starts_with(key) || l.contains(&format!(".{key}")) || l.contains(&format!("{key} ="))
        })
        .map(|i| i + 1)
}

/// The most bytes an experiment or configuration file may hold: far above any real one.
const MAX_FILE_BYTES: u64 = 1 << 20;

/// The text of a configuration file: a regular file of at most [`MAX_FILE_BYTES`], in UTF-8.
pub(super) fn read_text(path: &Path) -> Result<String> {
    let meta = std::fs::metadata(path).with_context(|| format!("reading {}", path.display()))?;
    if !meta.is_file() {
        bail!("{} is not a regular file: an experiment or configuration file is a TOML file", path.display());
    }
    if meta.len() > MAX_FILE_BYTES {
        bail!(
            "{} holds {} bytes: an experiment or configuration file holds at most {MAX_FILE_BYTES}",
            path.display(),
            meta.len()
        );
    }
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

/// Reads one file (and, recursively, its include) into a merged table.
pub(super) fn read_table(path: &Path, depth: usize) -> Result<(toml::Table, String)> {
    if depth > 8 {
        bail!("{}: include chain deeper than 8 files", path.display());
    }
    let text = read_text(path)?;
    let mut table: toml::Table = toml::from_str(&text).with_context(|| format!("in {}", path.display()))?;
    let Some(include) = table.remove("include") else { return Ok((table, text)) };
    let include = include.as_str().with_context(|| format!("{}: include must be a string", path.display()))?;
    let base_path = path.parent().unwrap_or(Path::new(".")).join(include);
    let (mut merged, _) =
        read_table(&base_path, depth + 1).with_context(|| format!("included from {}", path.display()))?;
    merged.remove("name");
    merged.remove("description");
    merge(&mut merged, &table);
    Ok((merged, text))
}

/// A toml error as `FILE (line N): in WHAT: message`, the line from the error's position in `text` or else
/// from the key the message names.
pub(super) fn located(e: toml::de::Error, file: &str, what: &str, text: &str) -> anyhow::Error {
    let msg = e.message().to_string();
    let at_span = e.span().and_then(|s| text.get(..s.start)).map(|before| before.matches('\n').count() + 1);
    let line = at_span
        .or_else(|| msg.split('`').nth(1).and_then(|key| line_of(text, key)))
        .map(|l| format!(" (line {l})"))
        .unwrap_or_default();
    anyhow::anyhow!("{file}{line}: in {what}: {msg}")
}

/// An error typing the file's top level (an unknown table, a wrong type in `[grid]`): located by reading this
/// file's own text, which keeps positions, at the line and dotted key it is about; else as [`located`] can.
pub(super) fn shape_error(e: toml::de::Error, file: &str, what: &str, text: &str) -> anyhow::Error {
    let Some(span) = toml::from_str::<FileShape>(text).err().and_then(|own| own.span()) else {
        return located(e, file, what, text);
    };
    let line = text.get(..span.start).map_or(1, |before| before.matches('\n').count() + 1);
    let key = key_at(text, line).map(|k| format!(", key `{k}`")).unwrap_or_default();
    anyhow::anyhow!("{file} (line {line}{key}): in {what}: {}", e.message())
}

/// The dotted key written on 1-based `line` of `text`: a table header's name, or `table.key` of an assignment.
fn key_at(text: &str, line: usize) -> Option<String> {
    let lines: Vec<&str> = text.lines().collect();
    let here = lines.get(line.checked_sub(1)?)?.trim();
    let header = |l: &str| {
        l.strip_prefix('[').map(|h| h.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string())
    };
    if let Some(h) = header(here) {
        return Some(h);
    }
    let key = here.split('=').next()?.trim().trim_matches('"').to_string();
    let table = lines[..line - 1].iter().rev().find_map(|l| header(l.trim()));
    Some(match table {
        Some(t) if !t.is_empty() => format!("{t}.{key}"),
        _ => key,
    })
}

/// The first `section.key` of `table` that does not deserialise on its own (a merged table has no positions
/// left: this finds which key a type error is about).
pub(super) fn offending_key(table: &toml::Table) -> Option<String> {
    table.iter().find_map(|(section, body)| {
        let body = body.as_table()?;
        body.iter().find_map(|(key, value)| {
            let single = toml::Table::from_iter([(key.clone(), value.clone())]);
            let one = toml::Table::from_iter([(section.clone(), toml::Value::Table(single))]);
            toml::Value::Table(one).try_into::<CellConfig>().is_err().then(|| key.clone())
        })
    })
}
