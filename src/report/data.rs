//! What a report reads from the results store: the experiment's cells, grouped into rows, with their episodes'
//! stage counts and training curves.
use crate::eval::stats::{Rate, mean_over_seeds, wilson};
use crate::pipeline::store::Store;
use anyhow::{Result, bail};
use rusqlite::params;

/// Stage counts of one evaluation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Counts {
    pub episodes: usize,
    pub reached: usize,
    pub picked: usize,
    pub placed: usize,
}

impl Counts {
    /// The counts of both evaluations together.
    pub fn plus(&self, o: &Counts) -> Counts {
        Counts {
            episodes: self.episodes + o.episodes,
            reached: self.reached + o.reached,
            picked: self.picked + o.picked,
            placed: self.placed + o.placed,
        }
    }
}

/// One cell as stored.
#[derive(Debug, Clone)]
pub struct CellRow {
    pub cell: String,
    pub policy: String,
    pub size: Option<usize>,
    pub variant: Option<String>,
    pub seed: Option<u64>,
    pub train_key: Option<String>,
    pub eval_key: String,
    /// None when the evaluation has not finished.
    pub counts: Option<Counts>,
    /// The model's context mode and architecture, and the training steps, from the train stage's inputs.
    pub context: Option<String>,
    pub architecture: Option<String>,
    pub train_steps: Option<u64>,
}

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
    /// Seeds with finished evaluations, and seeds in the grid.
    pub seeds_done: usize,
    pub seeds_total: usize,
    /// Pooled over seeds (Wilson); None when no seed finished.
    pub pooled: Option<[Rate; 3]>,
    /// Mean over seeds (t interval).
    pub mean: Option<[Rate; 3]>,
    /// Keys of the train and eval stages behind the numbers.
    pub train_keys: Vec<String>,
    pub eval_keys: Vec<String>,
}

/// Loads the cells of `experiment`.
pub fn cells(store: &Store, experiment: &str) -> Result<Vec<CellRow>> {
    let conn = store.conn();
    let mut stmt = conn.prepare(
        "SELECT c.cell, c.policy, c.size, c.variant, c.seed, c.train_key, c.eval_key, s.status,
                json_extract(t.inputs, '$.model.context'), json_extract(t.inputs, '$.model.architecture'),
                json_extract(t.inputs, '$.train.steps')
         FROM cells c LEFT JOIN stages s ON s.key = c.eval_key LEFT JOIN stages t ON t.key = c.train_key
         WHERE c.experiment = ?1 ORDER BY c.rowid",
    )?;
    let rows = stmt
        .query_map([experiment], |r| {
            Ok((
                CellRow {
                    cell: r.get(0)?,
                    policy: r.get(1)?,
                    size: r.get::<_, Option<i64>>(2)?.map(|v| v as usize),
                    variant: r.get(3)?,
                    seed: r.get::<_, Option<i64>>(4)?.map(|v| v as u64),
                    train_key: r.get(5)?,
                    eval_key: r.get(6)?,
                    counts: None,
                    context: r.get(8)?,
                    architecture: r.get(9)?,
                    train_steps: r.get::<_, Option<i64>>(10)?.map(|v| v as u64),
                },
                r.get::<_, Option<String>>(7)?,
            ))
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    if rows.is_empty() {
        bail!("the store has no cells of experiment `{experiment}` (run it first)");
    }
    let mut out = Vec::with_capacity(rows.len());
    for (mut row, status) in rows {
        if status.as_deref() == Some("done") {
            let c = conn.query_row(
                "SELECT COUNT(*), COALESCE(SUM(reached), 0), COALESCE(SUM(picked), 0), COALESCE(SUM(placed), 0)
                 FROM episodes WHERE eval_key = ?1",
                params![row.eval_key],
                |r| {
                    Ok(Counts {
                        episodes: r.get::<_, i64>(0)? as usize,
                        reached: r.get::<_, i64>(1)? as usize,
                        picked: r.get::<_, i64>(2)? as usize,
                        placed: r.get::<_, i64>(3)? as usize,
                    })
                },
            )?;
            row.counts = Some(c);
        }
        out.push(row);
    }
    Ok(out)
}

fn rates(c: &Counts) -> [Rate; 3] {
    [wilson(c.reached, c.episodes), wilson(c.picked, c.episodes), wilson(c.placed, c.episodes)]
}

/// The row label of a cell: `variant @ size` for a trained model, else the reference policy's name.
fn label_of(c: &CellRow) -> String {
    match (&c.variant, c.size) {
        (Some(v), Some(n)) => format!("{v} @ {n}"),
        _ => c.policy.clone(),
    }
}

/// Groups cells into rows (same policy, size and variant), in first-appearance order.
pub fn rows(cells: &[CellRow]) -> Vec<ResultRow> {
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
                    seeds_done: 0,
                    seeds_total: 0,
                    pooled: None,
                    mean: None,
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
        r.pooled = Some(rates(&total));
        let per_seed: Vec<[Rate; 3]> = done.iter().map(rates).collect();
        r.mean =
            Some(std::array::from_fn(|s| mean_over_seeds(&per_seed.iter().map(|p| p[s].value).collect::<Vec<_>>())));
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
pub fn step_curves(store: &Store, experiment: &str, cells: &[CellRow]) -> Result<Vec<StepCurve>> {
    let mut stmt = store.conn().prepare(
        "SELECT ce.cell, ce.step, COUNT(e.idx), COALESCE(SUM(e.reached), 0), COALESCE(SUM(e.picked), 0),
                COALESCE(SUM(e.placed), 0)
         FROM checkpoint_evals ce JOIN stages s ON s.key = ce.eval_key AND s.status = 'done'
         JOIN episodes e ON e.eval_key = ce.eval_key
         WHERE ce.experiment = ?1 GROUP BY ce.cell, ce.step",
    )?;
    let checkpoint_counts = stmt
        .query_map([experiment], |r| {
            let counts = Counts {
                episodes: r.get::<_, i64>(2)? as usize,
                reached: r.get::<_, i64>(3)? as usize,
                picked: r.get::<_, i64>(4)? as usize,
                placed: r.get::<_, i64>(5)? as usize,
            };
            Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)? as u64, counts))
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    // (label, step) -> counts pooled over the row's seeds; a cell's final evaluation sits at its last step.
    let mut pooled: Vec<(String, u64, Counts)> = Vec::new();
    let add = |pooled: &mut Vec<(String, u64, Counts)>, label: String, step: u64, c: Counts| match pooled
        .iter_mut()
        .find(|p| p.0 == label && p.1 == step)
    {
        Some(p) => p.2 = p.2.plus(&c),
        None => pooled.push((label, step, c)),
    };
    for (cell, step, counts) in checkpoint_counts {
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
        let point = (step, rates(&counts));
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

/// One point of a loss curve.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveRow {
    pub step: u64,
    pub split: String,
    pub bc: f64,
}

/// The BC loss curve of a train stage.
pub fn curve(store: &Store, train_key: &str) -> Result<Vec<CurveRow>> {
    let mut stmt =
        store.conn().prepare("SELECT step, split, bc FROM loss_curves WHERE train_key = ?1 ORDER BY split, step")?;
    let rows = stmt
        .query_map([train_key], |r| Ok(CurveRow { step: r.get::<_, i64>(0)? as u64, split: r.get(1)?, bc: r.get(2)? }))?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    Ok(rows)
}
