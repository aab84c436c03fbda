//! Tables the commands print: an evaluation's success rates, the open-loop probe's errors and a report's Table 1.
use anyhow::{Context, Result};
use oneshot_lab::eval::grip_probe::{GripProbe, GripRow};
use oneshot_lab::eval::probe::ProbeReport;
use oneshot_lab::eval::summary::{EvalSummary, percent};
use oneshot_lab::sim::action::{ACTION_DIM, ACTION_RANGES};
use std::path::Path;

/// Prints the summary as a table.
pub fn print_summary(s: &EvalSummary) {
    println!("{} policy, {} episodes (95% Wilson intervals)", s.policy, s.episodes);
    println!("{:>4}  {:<22} {:<22} {:<22}", "task", "reached", "picked", "placed");
    for (t, r) in s.per_task.iter().enumerate().filter(|(_, r)| r.reached.n > 0) {
        println!("{t:>4}  {:<22} {:<22} {:<22}", percent(&r.reached), percent(&r.picked), percent(&r.placed));
    }
    let o = &s.overall;
    println!("{:>4}  {:<22} {:<22} {:<22}", "all", percent(&o.reached), percent(&o.picked), percent(&o.placed));
    if let Some(w) = &s.wrong_bin {
        println!("wrong bin (the object at rest in another quadrant): {}", percent(w));
    }
    if let Some(g) = &s.grasps {
        println!("gripper closed (command above 0) at some step: {}", percent(&g.closed));
        println!(
            "the object in the gripper's frame at the first close, medians: |x| across the fingers, |y|, z along them"
        );
        for (which, offsets) in [("picked", &g.picked), ("not picked", &g.not_picked)] {
            if let Some(o) = offsets {
                let cm = |m: f64| 100.0 * m;
                println!(
                    "  {which:<11} {:>4} closes   {:5.1} / {:5.1} / {:5.1} cm",
                    o.closes,
                    cm(o.across),
                    cm(o.sideways),
                    cm(o.along)
                );
            }
        }
    }
    if let Some(h) = &s.holds {
        println!(
            "held the object on the table (closed, fingers stopped on it) in {} episodes, {} steps; the next command \
             opened the gripper after {:.0}% of them, lifted after {:.0}%",
            h.episodes,
            h.steps,
            100.0 * h.opened,
            100.0 * h.lifted
        );
        println!(
            "  of the {} that held it and did not pick it: let go before rising {}, rose closed without it {}",
            h.lost, h.let_go, h.slipped
        );
    }
}

/// Prints the grip probe's rows: by step around the expert's lift, then the lift and the rest by frames seen.
pub fn print_grip_probe(r: &GripProbe) {
    println!(
        "grip probe: {} agent trajectories from the close to one step past the lift ({} left out: no close, no lift or no demonstration of the task)",
        r.trajectories, r.skipped
    );
    println!(
        "the next command: expert's, and the head's (a sample's probability, whether the most likely action does)"
    );
    let header = |first: &str| {
        println!(
            "{first:<14} {:>7} {:>13} {:>10} {:>11} {:>10} {:>11}",
            "queries", "expert lifts", "P(lift)", "mode lifts", "P(open)", "mode opens"
        )
    };
    let line = |label: String, g: &GripRow| {
        let pct = |v: f64| format!("{:.1}%", 100.0 * v);
        println!(
            "{label:<14} {:>7} {:>13} {:>10} {:>11} {:>10} {:>11}",
            g.queries,
            pct(g.expert_lifts),
            pct(g.lift_probability),
            pct(g.mode_lifts),
            pct(g.open_probability),
            pct(g.mode_opens)
        )
    };
    header("step vs lift");
    for (offset, g) in &r.by_step {
        line(format!("{offset:+}"), g);
    }
    for (name, rows) in
        [("the lift step (0)", &r.lift_by_frames), ("resting steps (close < step < lift)", &r.rest_by_frames)]
    {
        println!("{name}, by frames in the window");
        header("frames");
        for (k, g) in rows.iter().enumerate().filter(|(_, g)| g.queries > 0) {
            line(format!("{}", k + 1), g);
        }
    }
    let [none, some, all] = r.bottom_mode_lifts;
    println!(
        "trajectories whose most likely action lifts at none / some / all of their steps from after the close \
         through the lift (every window length): {none} / {some} / {all}"
    );
}

/// Prints the report with absolute units beside the normalised ones.
pub fn print_probe(r: &ProbeReport) {
    const NAMES: [&str; ACTION_DIM] = ["x", "y", "z", "angle/pi", "axis x", "axis y", "axis z", "gripper"];
    println!("open-loop probe: {} windows, {} actions; mean absolute error (normalised units)", r.windows, r.actions);
    println!(
        "{:<9} {:>9} {:>9} {:>11} {:>16} {:>21}",
        "dimension", "mode", "sample", "mean-only", "mode (absolute)", "mean-only (absolute)"
    );
    for d in 0..ACTION_DIM {
        let half_range = (ACTION_RANGES[d][1] - ACTION_RANGES[d][0]) / 2.0;
        let unit = if d < 3 { " m" } else { "" };
        println!(
            "{:<9} {:>9.3} {:>9.3} {:>11.3} {:>14.4}{unit} {:>19.4}{unit}",
            NAMES[d],
            r.mode[d],
            r.sample[d],
            r.mean_baseline[d],
            r.mode[d] * half_range,
            r.mean_baseline[d] * half_range
        );
    }
    println!("by window position, mode / mean-only (absolute, m): position 0 sees one agent frame, so only there");
    println!("must the object be found in the picture rather than in the arm's motion");
    println!("{:<9} {:>17} {:>17} {:>17}", "position", "x", "y", "z");
    for (i, p) in r.by_position.iter().enumerate() {
        let cell = |d: usize| {
            let half_range = (ACTION_RANGES[d][1] - ACTION_RANGES[d][0]) / 2.0;
            format!("{:.4} / {:.4}", p.mode[d] * half_range, p.mean_baseline[d] * half_range)
        };
        println!("{:<9} {:>17} {:>17} {:>17}", i, cell(0), cell(1), cell(2));
    }
    if let Some((head, mean)) = r.poses_from_first_frame {
        for (name, at) in [("grasp", 0), ("drop", 3)] {
            println!(
                "pose head, {name} position from the first agent frame, mean absolute error x / y / z (m): \
                 {:.4} / {:.4} / {:.4} (mean {name} position: {:.4} / {:.4} / {:.4})",
                head[at],
                head[at + 1],
                head[at + 2],
                mean[at],
                mean[at + 1],
                mean[at + 2]
            );
        }
    }
    if let Some(f) = r.first_target {
        println!("first target (position 0): which object of its own scene it heads for, by bearing from the gripper");
        println!("{:<8} {:>13} {:>13} {:>8} {:>26}", "", "demonstrated", "another", "still", "nearer the demo's scene");
        for (who, c) in [("policy", f.policy), ("expert", f.expert)] {
            let pct = |k: usize| format!("{:.1}%", 100.0 * k as f64 / c.windows.max(1) as f64);
            println!(
                "{who:<8} {:>13} {:>13} {:>8} {:>26}",
                pct(c.demonstrated),
                pct(c.other),
                pct(c.still),
                pct(c.demonstration_scene)
            );
        }
        println!("(heading for one of four objects at random: 25% demonstrated)");
    }
    if let Some(w) = r.swap {
        println!("first target with the demonstration swapped ({} windows): mean move in the table plane", w.windows);
        println!(
            "  another demonstration of the same task:   {:.1} cm (reading the task: 0)",
            100.0 * w.moved_same_task
        );
        println!(
            "  a demonstration of the next object:        {:.1} cm (the two objects lie {:.1} cm apart); heads for \
             that object in {:.1}% of windows",
            100.0 * w.moved_other_object,
            100.0 * w.objects_apart,
            100.0 * w.other_object.demonstrated as f64 / w.other_object.windows.max(1) as f64
        );
    }
}

/// Prints the Table 1 of the report written to `report_dir`.
pub fn print_table1(report_dir: &Path) -> Result<()> {
    let file = report_dir.join("table1.md");
    let table = std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    println!("Table 1 ({}):\n{table}", file.display());
    Ok(())
}
