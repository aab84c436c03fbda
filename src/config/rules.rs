//! The rules that span sections or cells: a cell's configuration typed and checked as a whole, the grid's
//! consistency, and what a file may not set.
use super::file::{line_of, located, offending_key};
use super::{CellConfig, FULL, Grid};
use anyhow::{Context, Result, bail};
use std::collections::BTreeMap;
use std::path::Path;

/// A cell's training seed comes from `grid.seeds`: a `train.seed` in the file would be silently overwritten.
pub(super) fn reject_train_seed(table: &toml::Table, file: &str, what: &str, text: &str) -> Result<()> {
    let nested = table.get("train").and_then(|t| t.as_table()).is_some_and(|t| t.contains_key("seed"));
    if nested || table.contains_key("train.seed") {
        let line = line_of(text, "seed").map(|l| format!(" (line {l})")).unwrap_or_default();
        bail!("{file}{line}: in {what}: train.seed is set per cell by grid.seeds; remove it and list the seeds there");
    }
    Ok(())
}

/// `path` as written in experiment file `file`: a relative path is read from the file's folder, so an experiment
/// means the same weights from whatever folder it is run.
fn beside(file: &str, path: &str) -> String {
    match Path::new(file).parent().filter(|d| !d.as_os_str().is_empty() && Path::new(path).is_relative()) {
        Some(dir) => dir.join(path).to_string_lossy().into_owned(),
        None => path.to_string(),
    }
}

/// Turns merged sections into a validated cell configuration.
pub(super) fn resolve(table: &toml::Table, file: &str, what: &str, text: &str) -> Result<CellConfig> {
    let mut config: CellConfig = toml::Value::Table(table.clone()).try_into().map_err(|e| {
        let msg = e.message().to_string();
        match offending_key(table) {
            Some(key) => {
                let line = line_of(text, &key).map(|l| format!(" (line {l})")).unwrap_or_default();
                anyhow::anyhow!("{file}{line}: in {what}: `{key}`: {msg}")
            }
            None => located(e, file, what, text),
        }
    })?;
    let check = |r: Result<()>| r.with_context(|| format!("{file}: in {what}"));
    check(config.validate())?;
    // Evaluation covers the collected tasks unless it names its own (which must have training data).
    let eval_tasks_given = table.get("eval").and_then(|t| t.as_table()).is_some_and(|t| t.contains_key("tasks"));
    if !eval_tasks_given {
        config.eval.tasks = config.collect.tasks.clone();
    } else if let Some(t) = config.eval.tasks.iter().find(|t| !config.collect.tasks.contains(t)) {
        bail!("{file}: in {what}: eval.tasks contains task {t}, which collect.tasks does not collect");
    }
    check(config.eval.check_policy(&config.model, &config.world))?;
    if let Some(path) = config.model.pretrained_backbone.as_mut() {
        *path = beside(file, path);
    }
    if let Some(path) = config.model.pretrained_backbone.as_ref().filter(|p| !Path::new(p).is_file()) {
        bail!("{file}: in {what}: model.pretrained_backbone = {path:?}: no such file");
    }
    if config.pretrain.is_some() {
        if config.model.pretrained_backbone.is_some() {
            bail!(
                "{file}: in {what}: [pretrain] and model.pretrained_backbone both give the trunk's starting weights; \
                 keep one"
            );
        }
        check(crate::train::check_pretrained_trunk(&config.model).context("[pretrain]"))?;
        let m = &config.model;
        let queries_with_tasks = m.object_attention
            && m.object_attention_input.reads_trunk()
            && m.object_attention_query == crate::model::config::ObjectAttentionQuery::TaskHead;
        if config.pretrain.as_ref().is_some_and(|p| p.object_attention_steps > 0) && !queries_with_tasks {
            bail!(
                "{file}: in {what}: pretrain.object_attention_steps trains an object attention over the trunk queried \
                 by task: set model.object_attention = true, model.object_attention_input = \"trunk\" (or \
                 \"frozen_trunk\") and \
                 model.object_attention_query = \"task_head\""
            );
        }
    }
    crate::data::collect_config::check_layouts_in(&config.world, &config.collect)
        .map_err(|e| anyhow::anyhow!("{file}: in {what}: {e}"))?;
    if config.model.freeze_backbone && config.model.pretrained_backbone.is_none() && config.pretrain.is_none() {
        bail!("{file}: in {what}: model.freeze_backbone = true needs model.pretrained_backbone or [pretrain]");
    }
    if config.model.object_attention_input == crate::model::config::ObjectAttentionInput::FrozenTrunk
        && config.model.pretrained_backbone.is_none()
        && config.pretrain.is_none()
    {
        bail!(
            "{file}: in {what}: model.object_attention_input = \"frozen_trunk\" freezes a copy of the pretrained \
             trunk: it needs model.pretrained_backbone or [pretrain]"
        );
    }
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

/// The largest dataset size accepted: 100,000 trajectories per robot, about 60 times the paper's largest.
const MAX_SIZE: usize = 100_000;

pub(super) fn validate_grid(
    grid: &Grid,
    variants: &BTreeMap<String, toml::Table>,
    file: &str,
    text: &str,
) -> Result<()> {
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
    if variants.contains_key(FULL) {
        bail!(
            "{file}{}: [variants.{FULL}] is the base configuration itself: set its keys in the sections instead",
            at(&format!("variants.{FULL}"))
        );
    }
    repeated("grid.variants", &grid.variants).map_err(|e| anyhow::anyhow!("{file}{}: {e}", at("variants")))?;
    repeated("grid.sizes", &grid.sizes).map_err(|e| anyhow::anyhow!("{file}{}: {e}", at("sizes")))?;
    repeated("grid.seeds", &grid.seeds).map_err(|e| anyhow::anyhow!("{file}{}: {e}", at("seeds")))?;
    repeated("grid.references", &grid.references).map_err(|e| anyhow::anyhow!("{file}{}: {e}", at("references")))?;
    for &n in &grid.sizes {
        if n == 0 {
            bail!("{file}{}: grid.sizes contains 0: sizes must be positive", at("sizes"));
        }
        if n > MAX_SIZE {
            bail!(
                "{file}{}: grid.sizes contains {n}: at most {MAX_SIZE} trajectories per robot (the paper's largest is \
                 1600; a collection of {n} would not fit a disk)",
                at("sizes")
            );
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

/// An error naming the first value `list` holds twice (two cells would share one name).
fn repeated<T: PartialEq + std::fmt::Debug>(key: &str, list: &[T]) -> Result<()> {
    match list.iter().enumerate().find(|(i, v)| list[..*i].contains(v)) {
        Some((_, v)) => bail!("{key} lists {v:?} twice: each cell would run twice under one name"),
        None => Ok(()),
    }
}

impl CellConfig {
    /// Checks every section's ranges and that the training losses fit the architecture; errors name the key.
    pub fn validate(&self) -> Result<()> {
        self.world.validate()?;
        self.collect.validate()?;
        self.model.validate()?;
        if let Some(p) = &self.pretrain {
            p.validate()?;
        }
        self.train.validate()?;
        self.eval.validate()?;
        crate::train::config::check_heads(&self.model, &self.train)?;
        crate::train::config::check_precision(&self.model, &self.train)
    }
}
