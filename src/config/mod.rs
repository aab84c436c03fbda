//! Experiment files: TOML with defaults for every stage, named variants (overrides), a grid of dataset sizes,
//! variants and seeds, an optional `include` of a base file and named scale `profiles`.
//!
//! Resolution order (later wins): included file, this file, the chosen profile, then a cell's variant.
use crate::eval::EvalConfig;
use crate::model::config::ModelConfig;
use crate::sim::env::WorldConfig;
use crate::sim::task::NUM_TASKS;
use crate::train::config::TrainConfig;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Collection settings shared by the grid (the trajectories per task come from the dataset size).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CollectSettings {
    pub seed: u64,
    pub tasks: Vec<usize>,
    pub max_actions: usize,
    pub max_attempts: usize,
    pub jpeg_quality: u8,
}

impl Default for CollectSettings {
    fn default() -> Self {
        CollectSettings {
            seed: 0,
            tasks: (0..NUM_TASKS).collect(),
            max_actions: 100,
            max_attempts: 10,
            jpeg_quality: 90,
        }
    }
}

/// Reference policies that are evaluated once per experiment through the same path as the models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reference {
    Expert,
    Random,
}

impl Reference {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Reference::Expert => "expert",
            Reference::Random => "random",
        }
    }
}

/// The grid of cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Grid {
    /// Training trajectories per robot (a multiple of the number of tasks).
    pub sizes: Vec<usize>,
    /// Variant names; `full` is the unmodified configuration.
    pub variants: Vec<String>,
    /// Training seeds.
    pub seeds: Vec<u64>,
    pub references: Vec<Reference>,
}

impl Default for Grid {
    fn default() -> Self {
        Grid { sizes: vec![1600], variants: vec![FULL.into()], seeds: vec![0], references: Vec::new() }
    }
}

/// The variant without overrides.
pub const FULL: &str = "full";

/// Everything one cell's stages need.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CellConfig {
    pub world: WorldConfig,
    pub collect: CollectSettings,
    pub model: ModelConfig,
    pub train: TrainConfig,
    pub eval: EvalConfig,
}

/// The shape of one file, checked on its own so errors carry the file's line numbers.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)] // Fields are read through the merged table; this type only validates.
struct FileShape {
    name: Option<String>,
    description: Option<String>,
    include: Option<String>,
    world: Option<WorldConfig>,
    collect: Option<CollectSettings>,
    model: Option<ModelConfig>,
    train: Option<TrainConfig>,
    eval: Option<EvalConfig>,
    grid: Option<Grid>,
    variants: Option<BTreeMap<String, toml::Table>>,
    profiles: Option<BTreeMap<String, toml::Table>>,
}

/// A cell of the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// `size-variant-seed`, e.g. `n480-no_inverse-s1`.
    pub name: String,
    pub size: usize,
    pub variant: String,
    pub seed: u64,
    pub config: CellConfig,
}

/// A loaded, validated experiment.
#[derive(Debug, Clone)]
pub struct Experiment {
    pub name: String,
    pub description: String,
    pub path: PathBuf,
    pub profile: Option<String>,
    pub grid: Grid,
    pub base: CellConfig,
    pub cells: Vec<Cell>,
}

/// Deep-merges `over` into `base` (tables merge key by key; anything else is replaced).
fn merge(base: &mut toml::Table, over: &toml::Table) {
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
fn line_of(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.starts_with(key) || l.contains(&format!(".{key}")) || l.contains(&format!("{key} ="))
        })
        .map(|i| i + 1)
}

/// Reads one file (and, recursively, its include) into a merged table.
fn read_table(path: &Path, depth: usize) -> Result<(toml::Table, String)> {
    if depth > 8 {
        bail!("{}: include chain deeper than 8 files", path.display());
    }
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    toml::from_str::<FileShape>(&text).with_context(|| format!("in {}", path.display()))?;
    let table: toml::Table = toml::from_str(&text).with_context(|| format!("in {}", path.display()))?;
    let Some(include) = table.get("include") else { return Ok((table, text)) };
    let include = include.as_str().context("include must be a string")?;
    let base_path = path.parent().unwrap_or(Path::new(".")).join(include);
    let (mut merged, _) =
        read_table(&base_path, depth + 1).with_context(|| format!("included from {}", path.display()))?;
    merged.remove("name");
    merged.remove("description");
    merge(&mut merged, &table);
    merged.remove("include");
    Ok((merged, text))
}

const SECTIONS: [&str; 5] = ["world", "collect", "model", "train", "eval"];

impl Experiment {
    /// Loads `path` with an optional scale profile; every error names the file and the key (and a line).
    pub fn load(path: &Path, profile: Option<&str>) -> Result<Experiment> {
        let (mut table, text) = read_table(path, 0)?;
        let file = path.display().to_string();
        if let Some(p) = profile {
            let profiles = table.get("profiles").and_then(|v| v.as_table());
            let Some(over) = profiles.and_then(|t| t.get(p)).and_then(|v| v.as_table()).cloned() else {
                let known: Vec<String> = profiles.map(|t| t.keys().cloned().collect()).unwrap_or_default();
                bail!(
                    "{file}: no profile `{p}` (profiles: {})",
                    if known.is_empty() { "none".into() } else { known.join(", ") }
                );
            };
            merge(&mut table, &over);
            toml::Value::Table(table.clone())
                .try_into::<FileShape>()
                .with_context(|| format!("{file}: in profiles.{p}"))?;
        }
        let name = match table.get("name") {
            Some(v) => v.as_str().with_context(|| format!("{file}: name must be a string"))?.to_string(),
            None => path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
        };
        let description = table.get("description").and_then(|v| v.as_str()).unwrap_or("").to_string();
        let grid: Grid = match table.get("grid") {
            Some(v) => v.clone().try_into().with_context(|| format!("{file}: in [grid]"))?,
            None => Grid::default(),
        };
        let mut base_table = toml::Table::new();
        for s in SECTIONS {
            if let Some(v) = table.get(s) {
                base_table.insert(s.into(), v.clone());
            }
        }
        let variants: BTreeMap<String, toml::Table> = match table.get("variants") {
            Some(v) => v.clone().try_into().with_context(|| format!("{file}: in [variants]"))?,
            None => BTreeMap::new(),
        };
        reject_train_seed(&base_table, &file, "the base configuration", &text)?;
        for (name, over) in &variants {
            reject_train_seed(over, &file, &format!("variant `{name}`"), &text)?;
        }
        let base = resolve(&base_table, &file, "the base configuration", &text)?;
        validate_grid(&grid, &variants, &file, &text)?;

        let mut cells = Vec::new();
        for variant in &grid.variants {
            let mut t = base_table.clone();
            if variant != FULL {
                merge(&mut t, &variants[variant]);
            }
            let resolved = resolve(&t, &file, &format!("variant `{variant}`"), &text)?;
            for &size in &grid.sizes {
                for &seed in &grid.seeds {
                    let mut config = resolved.clone();
                    config.train.seed = seed;
                    cells.push(Cell {
                        name: format!("n{size}-{variant}-s{seed}"),
                        size,
                        variant: variant.clone(),
                        seed,
                        config,
                    });
                }
            }
        }
        Ok(Experiment {
            name,
            description,
            path: path.to_path_buf(),
            profile: profile.map(str::to_string),
            grid,
            base,
            cells,
        })
    }
}

/// A cell's training seed comes from `grid.seeds`: a `train.seed` in the file would be silently overwritten.
fn reject_train_seed(table: &toml::Table, file: &str, what: &str, text: &str) -> Result<()> {
    let nested = table.get("train").and_then(|t| t.as_table()).is_some_and(|t| t.contains_key("seed"));
    if nested || table.contains_key("train.seed") {
        let line = line_of(text, "seed").map(|l| format!(" (line {l})")).unwrap_or_default();
        bail!("{file}{line}: in {what}: train.seed is set per cell by grid.seeds; remove it and list the seeds there");
    }
    Ok(())
}

/// Turns merged sections into a validated cell configuration.
fn resolve(table: &toml::Table, file: &str, what: &str, text: &str) -> Result<CellConfig> {
    let mut config: CellConfig = toml::Value::Table(table.clone()).try_into().map_err(|e: toml::de::Error| {
        let msg = e.message().to_string();
        let line = msg
            .split('`')
            .nth(1)
            .and_then(|key| line_of(text, key))
            .map(|l| format!(" (line {l})"))
            .unwrap_or_default();
        anyhow::anyhow!("{file}{line}: in {what}: {msg}")
    })?;
    let check = |r: Result<()>| r.with_context(|| format!("{file}: in {what}"));
    check(config.world.validate())?;
    check(config.model.validate())?;
    check(config.train.validate())?;
    check(config.eval.validate())?;
    check(crate::train::config::check_heads(&config.model, &config.train))?;
    if config.collect.tasks.is_empty() || config.collect.tasks.iter().any(|&t| t >= NUM_TASKS) {
        bail!("{file}: in {what}: collect.tasks must list task ids 0..{}", NUM_TASKS - 1);
    }
    // Evaluation covers the collected tasks unless it names its own (which must have training data).
    let eval_tasks_given = table.get("eval").and_then(|t| t.as_table()).is_some_and(|t| t.contains_key("tasks"));
    if !eval_tasks_given {
        config.eval.tasks = config.collect.tasks.clone();
    } else if let Some(t) = config.eval.tasks.iter().find(|t| !config.collect.tasks.contains(t)) {
        bail!("{file}: in {what}: eval.tasks contains task {t}, which collect.tasks does not collect");
    }
    check(config.eval.check_policy(&config.model, &config.world))?;
    let t = &config.train;
    for &step in &config.eval.checkpoints {
        if step == 0 || step >= t.steps || (step % t.checkpoint_interval != 0) {
            bail!(
                "{file}: in {what}: eval.checkpoints contains {step}: checkpoints to evaluate must be multiples of \
                 train.checkpoint_interval = {} below train.steps = {} (the final weights are always evaluated)",
                t.checkpoint_interval,
                t.steps
            );
        }
    }
    Ok(config)
}

fn validate_grid(grid: &Grid, variants: &BTreeMap<String, toml::Table>, file: &str, text: &str) -> Result<()> {
    let at = |key: &str| line_of(text, key).map(|l| format!(" (line {l})")).unwrap_or_default();
    for v in &grid.variants {
        if v != FULL && !variants.contains_key(v) {
            let known: Vec<&str> = std::iter::once(FULL).chain(variants.keys().map(String::as_str)).collect();
            bail!(
                "{file}{}: grid.variants names `{v}`, which is not defined (defined: {})",
                at("variants"),
                known.join(", ")
            );
        }
    }
    for &n in &grid.sizes {
        if n == 0 || n % NUM_TASKS != 0 {
            bail!("{file}{}: grid.sizes contains {n}: sizes must be positive multiples of {NUM_TASKS}", at("sizes"));
        }
    }
    if grid.sizes.is_empty() && grid.references.is_empty() {
        bail!("{file}: the grid has no sizes and no references: nothing to run");
    }
    if !grid.sizes.is_empty() && (grid.variants.is_empty() || grid.seeds.is_empty()) {
        bail!("{file}{}: grid.variants and grid.seeds must not be empty", at("grid"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> Result<Experiment> {
        let dir = std::env::temp_dir().join(format!(
            "oneshot-config-{}-{}",
            std::process::id(),
            blake3::hash(text.as_bytes())
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("e.toml");
        std::fs::write(&path, text).unwrap();
        let e = Experiment::load(&path, None);
        std::fs::remove_dir_all(&dir).unwrap();
        e
    }

    #[test]
    fn evaluation_covers_the_collected_tasks_and_the_grid_sets_training_seeds() {
        let e = load("[collect]\ntasks = [0, 5]\n[grid]\nsizes = [32]\nseeds = [4, 7]\n").unwrap();
        assert!(e.cells.iter().all(|c| c.config.eval.tasks == [0, 5]));
        assert_eq!(e.cells.iter().map(|c| c.config.train.seed).collect::<Vec<_>>(), [4, 7]);
        let own = load("[collect]\ntasks = [0, 5]\n[eval]\ntasks = [5]\n[grid]\nsizes = [32]\n").unwrap();
        assert_eq!(own.cells[0].config.eval.tasks, [5]);
    }

    #[test]
    fn merge_is_deep_and_later_wins() {
        let mut a: toml::Table = toml::from_str("[train]\nlr = 1.0\nsteps = 5\n[train.loss]\nbc = 1.0\n").unwrap();
        let b: toml::Table = toml::from_str("[train]\nlr = 2.0\n[train.loss]\npoint = 0.0\n").unwrap();
        merge(&mut a, &b);
        let t = a["train"].as_table().unwrap();
        assert_eq!((t["lr"].as_float(), t["steps"].as_integer()), (Some(2.0), Some(5)));
        let loss = t["loss"].as_table().unwrap();
        assert_eq!((loss["bc"].as_float(), loss["point"].as_float()), (Some(1.0), Some(0.0)));
    }
}
