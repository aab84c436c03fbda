//! Results tables as Markdown, LaTeX (booktabs) and CSV. Missing results appear as `missing`.
use super::data::{ResultRow, StepCurve};
use super::paper::paper_stages;
use crate::eval::grasps::{CloseOffsets, GraspSummary};
use crate::eval::stats::{Counts, Rate, wilson};
use crate::sim::object::Object;
use crate::sim::task::Task;
use anyhow::Result;

const STAGES: [&str; 3] = ["reach", "pick", "place"];

fn pct(r: &Rate) -> String {
    format!("{:.1} [{:.1}, {:.1}]", 100.0 * r.value, 100.0 * r.low, 100.0 * r.high)
}

fn seeds(r: &ResultRow) -> String {
    format!("{}/{}", r.seeds_done, r.seeds_total)
}

fn paper(r: &ResultRow, s: usize) -> String {
    match paper_stages(r).and_then(|p| p[s]) {
        Some((v, h)) => format!("{v:.1} ± {h:.1}"),
        None => String::new(),
    }
}

/// Markdown table: rows x stages (pooled %, 95% Wilson interval), seeds done, the paper's value where reported.
pub fn markdown(rows: &[ResultRow]) -> String {
    let mut s =
        String::from("| model | seeds | reach % [95% CI] | pick % [95% CI] | place % [95% CI] | paper place % |\n");
    s += "| --- | --- | --- | --- | --- | --- |\n";
    for r in rows {
        let cells: Vec<String> = match &r.pooled {
            Some(p) => p.iter().map(pct).collect(),
            None => vec!["missing".into(); 3],
        };
        s +=
            &format!("| {} | {} | {} | {} | {} | {} |\n", r.label, seeds(r), cells[0], cells[1], cells[2], paper(r, 2));
    }
    s
}

/// Markdown table of the multi-object rows: stages with intervals, the episodes that left the object in another
/// quadrant ("wrong bin", the failure the paper names), and the paper's pick and place on held-out objects.
pub fn multi_object_markdown(rows: &[&ResultRow]) -> String {
    let mut s = String::from(
        "| model | seeds | reach % [95% CI] | pick % [95% CI] | place % [95% CI] | wrong bin % [95% CI] | paper pick % | \
         paper place % |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    let paper = |v: Option<(f64, Option<f64>)>| match v {
        Some((v, Some(h))) => format!("{v:.1} ± {h:.1}"),
        Some((v, None)) => format!("about {v:.0}"),
        None => String::new(),
    };
    for r in rows {
        let cells: Vec<String> = match &r.pooled {
            Some(p) => p.iter().map(pct).collect(),
            None => vec!["missing".into(); 3],
        };
        let wrong = r.wrong_bin.as_ref().map(pct).unwrap_or_else(|| "missing".into());
        let reported = super::paper::paper_multi_object(r);
        s += &format!(
            "| {} | {} | {} | {} | {} | {wrong} | {} | {} |\n",
            r.label,
            seeds(r),
            cells[0],
            cells[1],
            cells[2],
            paper(reported.map(|p| p[0])),
            paper(reported.map(|p| p[1]))
        );
    }
    s
}

/// Markdown table of where the gripper first closed, per row pooled over its seeds: how often it closed, and the
/// medians of the task's object's offset in the gripper's frame (cm) for the episodes that picked it and those
/// that did not (`missing` without finished evaluations, `not recorded` where episodes were stored before the
/// store kept it).
pub fn grasps_markdown(rows: &[(&ResultRow, Option<GraspSummary>)]) -> String {
    let mut s = String::from(
        "| model | seeds | closed % [95% CI] | picked: closes, median abs x / abs y / z (cm) | not picked: closes, \
         median abs x / abs y / z (cm) |\n| --- | --- | --- | --- | --- |\n",
    );
    let offsets = |o: &Option<CloseOffsets>| match o {
        Some(o) => {
            format!("{}: {:.1} / {:.1} / {:+.1}", o.closes, 100.0 * o.across, 100.0 * o.sideways, 100.0 * o.along)
        }
        None => "none".into(),
    };
    for (r, g) in rows {
        match g {
            Some(g) => {
                s += &format!(
                    "| {} | {} | {} | {} | {} |\n",
                    r.label,
                    seeds(r),
                    pct(&g.closed),
                    offsets(&g.picked),
                    offsets(&g.not_picked)
                )
            }
            None if r.seeds_done == 0 => s += &format!("| {} | {} | missing | | |\n", r.label, seeds(r)),
            None => s += &format!("| {} | {} | not recorded | | |\n", r.label, seeds(r)),
        }
    }
    s
}

/// Per-task counts pooled into per-object counts (the base world's four objects, in task order).
fn per_object(tasks: &[(usize, Counts)]) -> Result<[Counts; 4]> {
    let mut objects = [Counts::default(); 4];
    for (id, c) in tasks {
        let o = &mut objects[Task::from_id(*id)?.object];
        *o = o.plus(c);
    }
    Ok(objects)
}

/// Markdown table of success per object of the base world, per row pooled over its seeds and the object's four
/// target quadrants: picked %, then placed % with its 95% Wilson interval, of the episodes whose task moved that
/// object (`missing` without finished evaluations).
pub fn objects_markdown(rows: &[(&ResultRow, Vec<(usize, Counts)>)]) -> Result<String> {
    let mut s = String::from("| model | seeds |");
    for o in Object::ALL {
        s += &format!(" {}: picked %, placed % [95% CI] (episodes) |", o.name());
    }
    s += "\n| --- | --- |";
    s += &" --- |".repeat(Object::ALL.len());
    s += "\n";
    for (r, tasks) in rows {
        s += &format!("| {} | {} |", r.label, seeds(r));
        if tasks.is_empty() {
            s += &" missing |".repeat(Object::ALL.len());
        } else {
            for c in per_object(tasks)? {
                s += &match c.episodes {
                    0 => " none |".to_string(),
                    n => format!(" {:.1}, {} ({n}) |", 100.0 * c.picked as f64 / n as f64, pct(&wilson(c.placed, n))),
                };
            }
        }
        s += "\n";
    }
    Ok(s)
}

/// CSV of the episodes' counts per row and task (pooled over the row's seeds): what per-task analyses start from.
pub fn tasks_csv(rows: &[(&ResultRow, Vec<(usize, Counts)>)]) -> Result<String> {
    let mut s = String::from("model,task,object,target_quadrant,episodes,reached,picked,placed\n");
    for (r, tasks) in rows {
        for (id, c) in tasks {
            let task = Task::from_id(*id)?;
            s += &format!(
                "{},{id},{},{},{},{},{},{}\n",
                r.label,
                Object::ALL[task.object].name(),
                task.target,
                c.episodes,
                c.reached,
                c.picked,
                c.placed
            );
        }
    }
    Ok(s)
}

/// Markdown table of success against training steps: one line per configuration and evaluated step.
pub fn steps_markdown(curves: &[StepCurve]) -> String {
    let mut s = String::from("| model | step | reach % [95% CI] | pick % [95% CI] | place % [95% CI] |\n");
    s += "| --- | --- | --- | --- | --- |\n";
    for c in curves {
        for (step, r) in &c.points {
            s += &format!("| {} | {step} | {} | {} | {} |\n", c.label, pct(&r[0]), pct(&r[1]), pct(&r[2]));
        }
    }
    s
}

/// CSV with pooled and mean-over-seeds figures (fractions) and the stage keys behind them.
pub fn csv(rows: &[ResultRow]) -> String {
    let mut s = String::from("model,policy,size,variant,context,seeds_done,seeds_total");
    for st in STAGES {
        s += &format!(",{st},{st}_low,{st}_high,{st}_seed_mean,{st}_seed_low,{st}_seed_high");
    }
    s += ",eval_keys\n";
    for r in rows {
        s += &format!(
            "{},{},{},{},{},{},{}",
            r.label,
            r.policy,
            r.size.map(|n| n.to_string()).unwrap_or_default(),
            r.variant.clone().unwrap_or_default(),
            r.context.clone().unwrap_or_default(),
            r.seeds_done,
            r.seeds_total
        );
        for st in 0..3 {
            match (&r.pooled, &r.mean) {
                (Some(p), Some(m)) => {
                    let (p, m) = (p[st], m[st]);
                    s += &format!(
                        ",{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
                        p.value, p.low, p.high, m.value, m.low, m.high
                    );
                }
                _ => s += ",missing,,,,,",
            }
        }
        s += &format!(",{}\n", r.eval_keys.join(" "));
    }
    s
}

/// LaTeX table body for the booktabs package.
pub fn latex(rows: &[ResultRow], caption: &str) -> String {
    let mut s = String::from("\\begin{table}[t]\n\\centering\n\\begin{tabular}{lcccc}\n\\toprule\n");
    s += "Model & Seeds & Reach (\\%) & Pick (\\%) & Place (\\%) \\\\\n\\midrule\n";
    for r in rows {
        let cells: Vec<String> = match &r.pooled {
            Some(p) => p
                .iter()
                .map(|x| {
                    format!("{:.1} {{\\scriptsize [{:.1}, {:.1}]}}", 100.0 * x.value, 100.0 * x.low, 100.0 * x.high)
                })
                .collect(),
            None => vec!["missing".into(); 3],
        };
        s += &format!(
            "{} & {} & {} & {} & {} \\\\\n",
            r.label.replace('_', "\\_"),
            seeds(r),
            cells[0],
            cells[1],
            cells[2]
        );
    }
    s += &format!("\\bottomrule\n\\end{{tabular}}\n\\caption{{{caption}}}\n\\end{{table}}\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counts(episodes: usize, picked: usize, placed: usize) -> Counts {
        Counts { episodes, reached: episodes, picked, placed, wrong_bin: Some(0) }
    }

    #[test]
    fn objects_pool_their_four_target_quadrants_and_rows_without_episodes_read_missing() {
        let full = ResultRow::model_for_test("full", 1600, "transformer", "spread");
        let ablation = ResultRow::model_for_test("final_frame", 1600, "transformer", "final");
        // Milk's tasks 0 and 3, the can's task 15; bread and cereal were not evaluated.
        let tasks = vec![(0, counts(10, 4, 2)), (3, counts(10, 6, 5)), (15, counts(10, 9, 8))];
        let rows = [(&full, tasks), (&ablation, Vec::new())];
        let table = objects_markdown(&rows).unwrap();
        let lines: Vec<&str> = table.lines().collect();
        assert!(
            lines[0].contains("| milk: picked %, placed % [95% CI]") && lines[0].contains("| can: picked"),
            "{table}"
        );
        assert_eq!(
            lines[2],
            format!(
                "| full @ 1600 | 0/1 | 50.0, {} (20) | none | none | 90.0, {} (10) |",
                pct(&wilson(7, 20)),
                pct(&wilson(8, 10))
            )
        );
        assert_eq!(lines[3], "| final_frame @ 1600 | 0/1 | missing | missing | missing | missing |");
        let csv = tasks_csv(&rows).unwrap();
        assert_eq!(
            csv.lines().collect::<Vec<_>>(),
            [
                "model,task,object,target_quadrant,episodes,reached,picked,placed",
                "full @ 1600,0,milk,0,10,10,4,2",
                "full @ 1600,3,milk,3,10,10,6,5",
                "full @ 1600,15,can,3,10,10,9,8",
            ]
        );
        assert!(objects_markdown(&[(&full, vec![(16, counts(1, 0, 0))])]).is_err(), "task 16 does not exist");
    }
}
