//! The report's "after the close" table: what the agent did while its gripper held the object on the table, from
//! the summaries of evaluations that kept traces (`eval.traces`), pooled over each row's seeds.
use super::data::ResultRow;
use crate::eval::holds::HoldSummary;
use crate::eval::run::SUMMARY_FILE;
use crate::pipeline::store::Store;
use anyhow::{Context, Result};
use serde::Deserialize;

/// The part of an evaluation's summary this table reads (its per-task rates, NaN for tasks without episodes, are
/// written as null and not read back).
#[derive(Deserialize)]
struct SummaryHolds {
    #[serde(default)]
    holds: Option<HoldSummary>,
}

/// A row's holds pooled over its finished evaluations; none where it has none or one of them kept no traces.
fn row_holds(store: &Store, row: &ResultRow) -> Result<Option<HoldSummary>> {
    let mut parts = Vec::with_capacity(row.eval_keys.len());
    for (_, artifact) in super::data::eval_artifacts(store, row)? {
        let path = artifact.join(SUMMARY_FILE);
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let summary: SummaryHolds =
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        match summary.holds {
            Some(h) => parts.push(h),
            None => return Ok(None),
        }
    }
    Ok(HoldSummary::pooled(&parts))
}

/// The Markdown table of the rows whose evaluations kept traces (a row with an evaluation summarised before
/// holds were recorded is left out); none where no row's did.
pub fn markdown(store: &Store, rows: &[ResultRow]) -> Result<Option<String>> {
    let mut lines = Vec::new();
    for row in rows {
        if let Some(h) = row_holds(store, row)? {
            lines.push(format!(
                "| {} | {}/{} | {} | {} | {} | {} / {} of {} |",
                row.label,
                row.seeds_done,
                row.seeds_total,
                h.episodes,
                h.steps,
                match h.steps {
                    0 => "-".to_string(),
                    _ => format!("{:.0}% / {:.0}%", 100.0 * h.opened, 100.0 * h.lifted),
                },
                h.let_go,
                h.slipped,
                h.lost
            ));
        }
    }
    if lines.is_empty() {
        return Ok(None);
    }
    let mut table = String::from(
        "| model | seeds | episodes holding the object on the table | holding steps | next command opens / lifts | \
         held, never picked: let go before rising / rose without it |\n| --- | --- | --- | --- | --- | --- |\n",
    );
    for l in lines {
        table += &l;
        table.push('\n');
    }
    Ok(Some(table))
}
