//! The report's "after the pick" table: what became of the episodes that picked the task's object, from the
//! episodes and traces of evaluations that kept traces (`eval.traces`), pooled over each row's seeds.
use super::data::ResultRow;
use crate::eval::carries::CarrySummary;
use crate::eval::run::{EPISODES_FILE, TRACES_FILE};
use crate::eval::{EpisodeResult, EpisodeTrace};
use crate::pipeline::store::Store;
use anyhow::Result;

/// A row's picked episodes pooled over its finished evaluations; none where it has none or one of them kept no
/// traces.
fn row_carries(store: &Store, row: &ResultRow) -> Result<Option<CarrySummary>> {
    let mut parts = Vec::with_capacity(row.eval_keys.len());
    for (_, artifact) in super::data::eval_artifacts(store, row)? {
        if !artifact.join(TRACES_FILE).is_file() {
            return Ok(None);
        }
        let results: Vec<EpisodeResult> = crate::fsio::read_json_lines(&artifact.join(EPISODES_FILE))?;
        let traces: Vec<EpisodeTrace> = crate::fsio::read_json_lines(&artifact.join(TRACES_FILE))?;
        match CarrySummary::of(&results, &traces) {
            Some(c) => parts.push(c),
            None => return Ok(None),
        }
    }
    Ok(CarrySummary::pooled(&parts))
}

/// `k` of `of` as a count and a percentage.
fn share(k: usize, of: usize) -> String {
    match of {
        0 => "0".into(),
        _ => format!("{k} ({:.0}%)", 100.0 * k as f64 / of as f64),
    }
}

/// The Markdown table of the rows whose evaluations all kept traces; none where no row's did.
pub fn markdown(store: &Store, rows: &[ResultRow]) -> Result<Option<String>> {
    let mut table = String::from(
        "| model | seeds | picked | placed | set down in another quadrant | let go, not placed | lost from the fingers \
         before they opened | still held at the end |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    let mut any = false;
    for row in rows {
        let Some(c) = row_carries(store, row)? else { continue };
        any = true;
        table += &format!(
            "| {} | {}/{} | {} | {} | {} | {} | {} | {} |\n",
            row.label,
            row.seeds_done,
            row.seeds_total,
            c.picked,
            share(c.placed, c.picked),
            share(c.other_quadrant, c.picked),
            share(c.let_go, c.picked),
            share(c.lost, c.picked),
            share(c.held_at_end, c.picked)
        );
    }
    Ok(any.then_some(table))
}
