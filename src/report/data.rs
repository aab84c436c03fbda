//! What a report makes of the store's records: the experiment's cells grouped into rows (one configuration over
//! its seeds) with pooled and mean-over-seeds rates, and success against training steps.
use crate::eval::stats::{Counts, Rate, StageRates, wilson};
use crate::pipeline::graph::short;
use crate::pipeline::store::Store;
use crate::pipeline::store::read::CellRecord;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// A row of a results table: one policy configuration over its seeds.
#[derive(Debug, Clone)]
pub struct ResultRow {
    /// `full @ 480`, `expert`, ...
    pub label: String,
    pub policy: String,
    pub size: Option<usize>,
    pub variant: Option<String>,
    pub context: Option<String>,
    pub architecture: Option<String>,
    /// Who moved the agent in the evaluation (`scripted_poses` for DAML-Auxiliary; none for the network).
    pub control: Option<String>,
    /// Seeds with finished evaluations, and seeds in the grid.
    pub seeds_done: usize,
    pub seeds_total: usize,
    /// [reached, picked, placed] pooled over seeds (Wilson); none when no seed finished.
    pub pooled: Option<[Rate; 3]>,
    /// The same as a mean over seeds (t interval).
    pub mean: Option<[Rate; 3]>,
    /// The evaluation world's objects (`library`: the multi-object world's held-out objects).
    pub objects: Option<String>,
    /// Episodes that left the object in another quadrant, pooled (Wilson); none where a seed's episodes were
    /// stored before this was recorded.
    pub wrong_bin: Option<Rate>,
    /// Keys of the train and eval stages behind the numbers.
    pub train_keys: Vec<String>,
    pub eval_keys: Vec<String>,
}

impl ResultRow {
    /// Whether it was evaluated in the multi-object world's environments (its object slots then hold other objects
    /// than the base world's).
    pub fn in_library_world(&self) -> bool {
        self.objects.as_deref() == Some("library")
    }
}

/// The artifact folders of a row's finished evaluations with their keys, each verified against its manifest.
pub(super) fn eval_artifacts<'a>(store: &Store, row: &'a ResultRow) -> Result<Vec<(&'a str, PathBuf)>> {
    let mut folders = Vec::with_capacity(row.eval_keys.len());
    for key in &row.eval_keys {
        let Some(artifact) = store.artifact(key)? else { continue };
        crate::pipeline::integrity::verify(&artifact)
            .with_context(|| format!("eval stage {}: run the experiment again to recompute it", short(key)))?;
        folders.push((key.as_str(), artifact));
    }
    Ok(folders)
}

#[cfg(test)]
impl ResultRow {
    /// A trained model's row without results, for tests: `variant @ size` with its architecture and context.
    pub fn model_for_test(variant: &str, size: usize, architecture: &str, context: &str) -> ResultRow {
        ResultRow {
            label: format!("{variant} @ {size}"),
            policy: "model".into(),
            size: Some(size),
            variant: Some(variant.into()),
            context: Some(context.into()),
            architecture: Some(architecture.into()),
            control: None,
            seeds_done: 0,
            seeds_total: 1,
            pooled: None,
            mean: None,
            objects: None,
            wrong_bin: None,
            train_keys: Vec::new(),
            eval_keys: Vec::new(),
        }
    }
}

/// The row label of a cell: `variant @ size` for a trained model, else the reference policy's name.
fn label_of(c: &CellRecord) -> String {
    match (&c.variant, c.size) {
        (Some(v), Some(n)) => format!("{v} @ {n}"),
        _ => c.policy.clone(),
    }
}

/// Groups cells into rows (same policy, size and variant), in first-appearance order.
pub fn rows(cells: &[CellRecord]) -> Vec<ResultRow> {
    let mut out: Vec<ResultRow> = Vec::new();
    for c in cells {
        let label = label_of(c);
        let i = match out.iter().position(|r| r.label == label) {
            Some(i) => i,
            None => {
                out.push(ResultRow {
                    label,
                    policy: c.policy.clone(),
                    size: c.size,
                    variant: c.variant.clone(),
                    context: c.context.clone(),
                    architecture: c.architecture.clone(),
                    control: c.control.clone(),
                    seeds_done: 0,
                    seeds_total: 0,
                    pooled: None,
                    mean: None,
                    objects: c.objects.clone(),
                    wrong_bin: None,
                    train_keys: Vec::new(),
                    eval_keys: Vec::new(),
                });
                out.len() - 1
            }
        };
        let r = &mut out[i];
        r.seeds_total += 1;
        r.train_keys.extend(c.train_key.clone());
        r.eval_keys.push(c.eval_key.clone());
    }
    for r in &mut out {
        let done: Vec<Counts> =
            cells.iter().filter(|c| r.eval_keys.contains(&c.eval_key)).filter_map(|c| c.counts).collect();
        r.seeds_done = done.len();
        if done.is_empty() {
            continue;
        }
        let total = done.iter().fold(Counts::default(), |a, c| a.plus(c));
        r.pooled = Some(StageRates::of(&total).rates());
        r.wrong_bin = total.wrong_bin.map(|w| wilson(w, total.episodes));
        let per_seed: Vec<StageRates> = done.iter().map(StageRates::of).collect();
        r.mean = Some(StageRates::mean_over(&per_seed).rates());
    }
    out
}

/// Success against training steps of one row: per evaluated step (intermediate checkpoints and the final
/// weights), the stage rates pooled over the row's seeds.
#[derive(Debug, Clone)]
pub struct StepCurve {
    pub label: String,
    pub points: Vec<(u64, [Rate; 3])>,
}

/// Success against training steps for every row whose cells evaluated intermediate checkpoints.
pub fn step_curves(store: &Store, experiment: &str, cells: &[CellRecord]) -> Result<Vec<StepCurve>> {
    // (label, step) -> counts pooled over the row's seeds; a cell's final evaluation sits at its last step.
    let mut pooled: Vec<(String, u64, Counts)> = Vec::new();
    let add = |pooled: &mut Vec<(String, u64, Counts)>, label: String, step: u64, c: Counts| match pooled
        .iter_mut()
        .find(|p| p.0 == label && p.1 == step)
    {
        Some(p) => p.2 = p.2.plus(&c),
        None => pooled.push((label, step, c)),
    };
    for (cell, step, counts) in store.checkpoint_counts(experiment)? {
        let Some(c) = cells.iter().find(|c| c.cell == cell) else { continue };
        add(&mut pooled, label_of(c), step, counts);
    }
    let with_checkpoints: Vec<String> = pooled.iter().map(|p| p.0.clone()).collect();
    for c in cells.iter().filter(|c| with_checkpoints.contains(&label_of(c))) {
        if let (Some(counts), Some(steps)) = (c.counts, c.train_steps) {
            add(&mut pooled, label_of(c), steps, counts);
        }
    }
    let mut curves: Vec<StepCurve> = Vec::new();
    for (label, step, counts) in pooled {
        let point = (step, StageRates::of(&counts).rates());
        match curves.iter_mut().find(|c| c.label == label) {
            Some(c) => c.points.push(point),
            None => curves.push(StepCurve { label, points: vec![point] }),
        }
    }
    for c in &mut curves {
        c.points.sort_by_key(|p| p.0);
    }
    Ok(curves)
}
