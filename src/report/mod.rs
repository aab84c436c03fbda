//! Reports: the paper's tables and figures for one experiment, rebuilt from the results store alone.
pub mod carries;
pub mod data;
pub mod holds;
pub mod html;
pub mod paper;
pub mod plots;
pub mod tables;
pub mod videos;

use crate::config::FULL;
use crate::pipeline::graph::short;
use crate::pipeline::store::Store;
use crate::pipeline::store::read::{CellRecord, ExperimentRecord};
use anyhow::{Context, Result, bail};
use data::ResultRow;
use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The code version stamped on reports: crate version and the git commit it was built from.
pub const CODE_VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), "+", env!("ONESHOT_GIT_COMMIT"));

/// Where the report of `experiment` goes in the store folder: `reports/NAME`, or `reports/NAME@seed-0-1` for a
/// report of some training seeds only (`@` is not allowed in a name, so no experiment's own report is hit).
pub fn report_dir(root: &Path, experiment: &str, seeds: &[u64]) -> PathBuf {
    let folder = match seeds {
        [] => experiment.to_string(),
        _ => format!("{experiment}@seed-{}", seeds.iter().map(u64::to_string).collect::<Vec<_>>().join("-")),
    };
    root.join("reports").join(folder)
}

/// The cells a report of `seeds` shows (every cell where `seeds` is empty): the trained cells of those seeds and
/// every reference, which has no seed. A seed no trained cell has is an error naming it and the seeds there are.
pub fn cells_of_seeds(cells: Vec<CellRecord>, experiment: &str, seeds: &[u64]) -> Result<Vec<CellRecord>> {
    let present: BTreeSet<u64> = cells.iter().filter_map(|c| c.seed).collect();
    if let Some(missing) = seeds.iter().find(|s| !present.contains(s)) {
        let there = match present.is_empty() {
            true => "it has no trained cells".to_string(),
            false => format!("its seeds: {}", present.iter().map(u64::to_string).collect::<Vec<_>>().join(", ")),
        };
        bail!(
            "--seed {missing}: experiment `{experiment}`, as last run, has no trained cell of training seed {missing} \
             ({there})"
        );
    }
    Ok(cells.into_iter().filter(|c| seeds.is_empty() || c.seed.is_none_or(|s| seeds.contains(&s))).collect())
}

fn context_table(rows: &[&ResultRow]) -> String {
    let mut s = String::from("| context | model | seeds | place % [95% CI] |\n| --- | --- | --- | --- |\n");
    for r in rows {
        let place = match &r.pooled {
            Some(p) => format!("{:.1} [{:.1}, {:.1}]", 100.0 * p[2].value, 100.0 * p[2].low, 100.0 * p[2].high),
            None => "missing".into(),
        };
        let context = match r.context.as_deref() {
            Some("spread") => "4 frames (first, last, 2 between)".to_string(),
            Some("first_last") => "first + last frame".into(),
            Some("final") => "final frame only".into(),
            other => other.unwrap_or("-").to_string(),
        };
        let _ = writeln!(s, "| {context} | {} | {}/{} | {place} |", r.label, r.seeds_done, r.seeds_total);
    }
    s
}

/// The rows of the architecture figure: the full model and every configuration that changes the architecture,
/// with the default context.
fn architecture_rows<'a>(rows: &[&'a ResultRow]) -> Vec<&'a ResultRow> {
    rows.iter()
        .copied()
        .filter(|r| r.context.as_deref() == Some("spread"))
        .filter(|r| r.variant.as_deref() == Some(FULL) || r.architecture.as_deref().is_some_and(|a| a != "transformer"))
        .collect()
}

/// Writes every table and figure of `experiment` into `out` (replacing it as a whole once complete), over the
/// training seeds `seeds` (all where empty; [`cells_of_seeds`]).
pub fn write_report(store: &Store, experiment: &str, seeds: &[u64], out: &Path) -> Result<()> {
    let cells = cells_of_seeds(store.cells(experiment)?, experiment, seeds)?;
    let rows = data::rows(&cells);
    let ExperimentRecord { file, description, profile, overrides } = store.experiment(experiment)?;
    let staging = crate::fsio::staging_sibling(out)?;
    crate::fsio::remove_dir_if_present(&staging)?;
    std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
    let write = |name: &str, text: &str| -> Result<()> {
        std::fs::write(staging.join(name), text).with_context(|| format!("writing {name}"))
    };

    let listed = seeds.iter().map(u64::to_string).collect::<Vec<_>>().join(", ");
    let named = format!("training seed{} {listed}", if seeds.len() > 1 { "s" } else { "" });
    let pooled_over = match seeds.len() {
        0 => "pooled over seeds".to_string(),
        1 => named.clone(),
        _ => format!("pooled over {named}"),
    };
    let caption = format!("Success rates of experiment {experiment} ({pooled_over}; 95\\% Wilson intervals).");
    write("table1.md", &tables::markdown(&rows))?;
    write("table1.csv", &tables::csv(&rows))?;
    write("table1.tex", &tables::latex(&rows, &caption))?;
    let largest = rows.iter().filter_map(|r| r.size).max();
    let at_largest: Vec<&ResultRow> = rows.iter().filter(|r| r.size.is_some() && r.size == largest).collect();
    write("context.md", &context_table(&at_largest))?;

    let all = plots::Bars {
        name: "success_by_configuration",
        caption: "Task success (placed) per configuration, 95% CI",
        rows: rows.iter().collect(),
    };
    plots::success_bars(&staging, &all)?;
    let architectures = architecture_rows(&at_largest);
    if architectures.len() > 1 {
        let bars = plots::Bars {
            name: "success_by_architecture",
            caption: "Task success (placed) per architecture, 95% CI (paper Fig. 3)",
            rows: architectures.clone(),
        };
        plots::success_bars(&staging, &bars)?;
    }
    plots::success_vs_size(&staging, &rows)?;
    let mut curves = Vec::new();
    for r in &at_largest {
        if let Some(k) = r.train_keys.first() {
            let c = store.curve(k)?;
            if !c.is_empty() {
                curves.push((r.label.clone(), c));
            }
        }
    }
    plots::loss_curves(&staging, &curves)?;
    let step_curves = data::step_curves(store, experiment, &cells)?;
    if !step_curves.is_empty() {
        plots::success_vs_steps(&staging, &step_curves)?;
    }

    let mut index = format!("# {experiment}\n\n");
    if !description.is_empty() {
        let _ = writeln!(index, "{description}\n");
    }
    let _ = writeln!(
        index,
        "Experiment file `{file}`{}{}; code version `{CODE_VERSION}`.\n",
        match &profile {
            Some(p) => format!(", profile `{p}`"),
            None => String::new(),
        },
        if overrides.is_empty() { String::new() } else { format!(", overrides `{overrides}`") }
    );
    index += &match seeds.len() {
        0 => "Every number below is recomputed from the results store (`oneshot.sqlite`); rates are pooled over \
              training seeds with 95% Wilson score intervals (`table1.csv` also has the mean over seeds with a \
              Student-t interval). A configuration without finished evaluations shows as `missing`.\n\n"
            .to_string(),
        n => format!(
            "Every number below is recomputed from the results store (`oneshot.sqlite`) **from the cells of {named} \
             only** (`report --seed`; the references, which have no seed, are all here), with 95% Wilson score \
             intervals{}. A configuration without finished evaluations shows as `missing`.\n\n",
            if n > 1 {
                " (rates pooled over those seeds; `table1.csv` also has the mean over seeds with a Student-t interval)"
            } else {
                ""
            }
        ),
    };
    index += "## Table 1: success per stage\n\n";
    index += &tables::markdown(&rows);
    index += "\nAlso as [CSV](table1.csv) and [LaTeX](table1.tex).\n\n## Context ablation (largest training set)\n\n";
    index += &context_table(&at_largest);
    if !step_curves.is_empty() {
        index += "\n## Success against training steps\n\n";
        index += &tables::steps_markdown(&step_curves);
        index += "\n![success against training steps](success_vs_steps.png)\n";
    }
    let multi_object: Vec<&ResultRow> = rows.iter().filter(|r| r.in_library_world()).collect();
    if !multi_object.is_empty() {
        let table = tables::multi_object_markdown(&multi_object);
        write("multi_object.md", &table)?;
        index += "\n## Multi-object environments: held-out objects\n\nEvaluated in environments of the library's four \
                  held-out objects; \"wrong bin\" counts the episodes that left the object in another quadrant of \
                  the target bin (latched, so an episode can count there and as placed).\n\n";
        index += &table;
    }
    let mut grasps = Vec::with_capacity(rows.len());
    for r in &rows {
        grasps.push((r, store.grasps(&r.eval_keys)?));
    }
    if grasps.iter().any(|(_, g)| g.is_some()) {
        let table = tables::grasps_markdown(&grasps);
        write("grasps.md", &table)?;
        index += "\n## Where the gripper first closed\n\nWhere the task's object's centre lay in the gripper's frame \
                  after the step that first commanded the gripper closed (from the end-effector point: x across the \
                  fingers, y along their faces, z along them), medians over the episodes that picked it and those \
                  that did not: what a failed grasp missed by.\n\n";
        index += &table;
    }
    if let Some(table) = holds::markdown(store, &rows)? {
        write("holds.md", &table)?;
        index += "\n## After the close\n\nFrom the traces of evaluations that kept them (`eval.traces`): the steps at \
                  which the gripper held the task's object on the table (closed, fingers stopped on it, the object \
                  between them), the share after which the next command opened the gripper or lifted, and of the \
                  episodes that held the object and never picked it, how many let go before the gripper rose and \
                  how many rose without it.\n\n";
        index += &table;
    }
    if let Some(table) = carries::markdown(store, &rows)? {
        write("carries.md", &table)?;
        index += "\n## After the pick\n\nFrom the traces of evaluations that kept them (`eval.traces`): what became of \
                  the episodes that picked the task's object. Placed first, then set down in another quadrant of the \
                  target bin (at rest there at some step); the rest by the last step that ran with the gripper closed: the object still \
                  between the fingers when the gripper opened (let go, not placed), no longer between them (lost \
                  from the fingers: a pick that held it by an edge, or dropped it), or still held at the end (the \
                  episode's last command, which the authors' protocol opens, not counted).\n\n";
        index += &table;
    }
    let mut per_task = Vec::with_capacity(rows.len());
    for r in rows.iter().filter(|r| !r.in_library_world()) {
        per_task.push((r, store.task_counts(&r.eval_keys)?));
    }
    if per_task.iter().any(|(_, tasks)| !tasks.is_empty()) {
        let table = tables::objects_markdown(&per_task)?;
        write("objects.md", &table)?;
        write("tasks.csv", &tables::tasks_csv(&per_task)?)?;
        index += "\n## Success per object\n\nThe base world's episodes grouped by the object their task moves (its \
                  four target quadrants pooled), picked and placed; counts per task in [tasks.csv](tasks.csv).\n\n";
        index += &table;
    }
    index += &videos::copy_and_list(store, &rows, &staging)?;
    index += "\n## Figures\n\n![success per configuration](success_by_configuration.png)\n\n";
    if architectures.len() > 1 {
        index += "![success per architecture](success_by_architecture.png)\n\n";
    }
    index += "![success vs training data](success_vs_size.png)\n\n![BC loss curves](loss_curves.png)\n\n";
    index += "SVG versions sit beside the PNGs.\n\n## Sources\n\n| model | train stages | eval stages |\n| --- | --- | --- |\n";
    for r in &rows {
        let keys = |ks: &[String]| ks.iter().map(|k| format!("`{}`", short(k))).collect::<Vec<_>>().join(" ");
        let _ = writeln!(index, "| {} | {} | {} |", r.label, keys(&r.train_keys), keys(&r.eval_keys));
    }
    index += "\nStage keys are blake3 hashes of each stage's resolved configuration, its implementation version and \
              its upstream keys; `oneshot-lab why KEY` shows a stage's inputs.\n";
    write("index.md", &index)?;
    write("index.html", &html::page(&index, &staging, experiment)?)?;

    write(MARKER, "This folder was written by `oneshot-lab report`; the next report replaces it as a whole.\n")?;
    if let Err(e) = check_replaceable(out, &staging) {
        crate::fsio::remove_dir_if_present(&staging)?;
        return Err(e);
    }
    crate::fsio::publish_dir(&staging, out)?;
    Ok(())
}

/// The file every report folder carries, so that a report replaces only a folder a report wrote.
pub const MARKER: &str = ".oneshot-lab-report";

/// What a report writes only when it has rows for it: a report folder from before the marker may hold them.
const OPTIONAL_OUTPUTS: [&str; 11] = [
    "grasps.md",
    "holds.md",
    "carries.md",
    "objects.md",
    "tasks.csv",
    "multi_object.md",
    "videos",
    "success_by_architecture.png",
    "success_by_architecture.svg",
    "success_vs_steps.png",
    "success_vs_steps.svg",
];

/// Whether the existing folder `out` may be replaced by the new report in `staging`: it carries the marker, or
/// (a report written before the marker) holds an `index.md` and nothing but what a report writes.
fn check_replaceable(out: &Path, staging: &Path) -> Result<()> {
    if !out.exists() || out.join(MARKER).is_file() {
        return Ok(());
    }
    if !out.join("index.md").is_file() {
        bail!("{} exists and is not a report (no index.md): refusing to replace it", out.display());
    }
    let entries = std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))?;
    for entry in entries {
        let name = entry?.file_name();
        let optional = name.to_str().is_some_and(|n| OPTIONAL_OUTPUTS.contains(&n));
        if !optional && !staging.join(&name).exists() {
            bail!(
                "{} holds {:?}, which a report does not write: refusing to replace the folder (move that file \
                 away or pick another --out)",
                out.display(),
                name
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(variant: &str, architecture: &str, context: &str) -> ResultRow {
        ResultRow::model_for_test(variant, 480, architecture, context)
    }

    #[test]
    fn the_architecture_figure_shows_the_full_model_and_each_other_architecture() {
        let rows = [
            row("full", "transformer", "spread"),
            row("no_inverse", "transformer", "spread"),
            row("conv_lstm", "conv_lstm", "spread"),
            row("final_frame", "transformer", "final"),
            row("no_attention", "temporal_conv", "spread"),
        ];
        let refs: Vec<&ResultRow> = rows.iter().collect();
        let shown: Vec<&str> = architecture_rows(&refs).iter().filter_map(|r| r.variant.as_deref()).collect();
        assert_eq!(shown, ["full", "conv_lstm", "no_attention"]);
    }

    fn cell(name: &str, seed: Option<u64>) -> CellRecord {
        CellRecord {
            cell: name.into(),
            policy: if seed.is_some() { "model" } else { name }.into(),
            size: seed.map(|_| 1600),
            variant: seed.map(|_| "full".into()),
            seed,
            train_key: None,
            eval_key: format!("eval-{name}"),
            counts: None,
            context: None,
            architecture: None,
            train_steps: None,
            control: None,
            objects: None,
        }
    }

    #[test]
    fn a_report_of_some_seeds_keeps_their_cells_and_every_reference() {
        let cells = || vec![cell("n1600-full-s0", Some(0)), cell("n1600-full-s1", Some(1)), cell("expert", None)];
        let names = |seeds: &[u64]| -> Vec<String> {
            cells_of_seeds(cells(), "exp", seeds).unwrap().into_iter().map(|c| c.cell).collect()
        };
        assert_eq!(names(&[]), ["n1600-full-s0", "n1600-full-s1", "expert"]);
        assert_eq!(names(&[1]), ["n1600-full-s1", "expert"]);
        assert_eq!(names(&[0, 1]), names(&[]));
        let err = cells_of_seeds(cells(), "exp", &[1, 3]).unwrap_err().to_string();
        assert!(err.contains("--seed 3") && err.contains("`exp`") && err.contains("its seeds: 0, 1"), "{err}");
        let err = cells_of_seeds(vec![cell("random", None)], "refs", &[0]).unwrap_err().to_string();
        assert!(err.contains("no trained cells"), "{err}");
        let root = Path::new("/store");
        assert_eq!(report_dir(root, "exp", &[]), Path::new("/store/reports/exp"));
        assert_eq!(report_dir(root, "exp", &[0, 1]), Path::new("/store/reports/exp@seed-0-1"));
    }

    #[test]
    fn a_report_replaces_only_a_folder_a_report_wrote() {
        let dir = std::env::temp_dir().join(format!("oneshot-report-replace-{}", std::process::id()));
        let (out, staging) = (dir.join("out"), dir.join("staging"));
        std::fs::create_dir_all(&staging).unwrap();
        for name in ["index.md", "table1.md", MARKER] {
            std::fs::write(staging.join(name), "x").unwrap();
        }
        assert!(check_replaceable(&out, &staging).is_ok(), "nothing there yet");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("thesis.tex"), "mine").unwrap();
        let err = check_replaceable(&out, &staging).unwrap_err().to_string();
        assert!(err.contains("not a report"), "{err}");
        std::fs::write(out.join("index.md"), "mine").unwrap();
        let err = check_replaceable(&out, &staging).unwrap_err().to_string();
        assert!(err.contains("thesis.tex") && err.contains("refusing"), "{err}");
        std::fs::remove_file(out.join("thesis.tex")).unwrap();
        std::fs::write(out.join("table1.md"), "old").unwrap();
        std::fs::write(out.join("holds.md"), "old").unwrap();
        assert!(check_replaceable(&out, &staging).is_ok(), "a report from before the marker, a table since dropped");
        std::fs::write(out.join("notes.txt"), "x").unwrap();
        assert!(check_replaceable(&out, &staging).is_err());
        std::fs::write(out.join(MARKER), "").unwrap();
        assert!(check_replaceable(&out, &staging).is_ok(), "the marker: the whole folder is the report's");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
