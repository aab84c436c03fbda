//! `expert-check`, `collect` and `contact-sheet`: the world and its scripted expert.
use super::args::{CollectArgs, ContactSheetArgs, ExpertCheckArgs, parse_named};
use super::default_workers;
use anyhow::{Context, Result, bail};
use oneshot_lab::data::collect::{self, CollectConfig};
use oneshot_lab::sim::env::{Env, WorldConfig};
use oneshot_lab::sim::expert_check::{ExpertReport, expert_check as check};
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::task::{Instance, NUM_TASKS, Task};
use std::path::Path;

/// `expert-check`: the expert's staged success per task.
pub fn expert_check(a: ExpertCheckArgs) -> Result<()> {
    let mut world = WorldConfig { close_on_arrival: a.close_on_arrival, ..WorldConfig::default() };
    if let Some(rule) = &a.gripper_yaw {
        let rule =
            parse_named(rule).map_err(|e| anyhow::anyhow!("--gripper-yaw {e} (fixed, heading or object_yaw)"))?;
        match a.robot {
            Robot::Sawyer => world.demo_yaw = rule,
            Robot::Panda => world.agent_yaw = rule,
        }
    }
    let max_actions = a.max_actions.unwrap_or(CollectConfig::paper(a.robot).settings.max_actions);
    let report = check(a.robot, &world, a.per_task, a.seed, max_actions)?;
    print_report(&report);
    Ok(())
}

/// `collect`: expert trajectories into a new dataset folder.
pub fn collect(a: CollectArgs) -> Result<()> {
    let world = WorldConfig { close_on_arrival: a.close_on_arrival, ..a.frames.world() };
    let mut config = CollectConfig { world, ..CollectConfig::paper(a.robot) };
    config.per_task = a.per_task.unwrap_or(config.per_task);
    let s = &mut config.settings;
    s.seed = a.seed.unwrap_or(s.seed);
    s.tasks = a.tasks.unwrap_or(s.tasks.clone());
    s.jpeg_quality = a.jpeg_quality.unwrap_or(s.jpeg_quality);
    s.action_noise = a.action_noise.unwrap_or(s.action_noise);
    let manifest = collect::collect(&config, &a.out, a.workers.unwrap_or_else(default_workers), true)?;
    let retries: usize = manifest.trajectories.iter().map(|e| e.attempts - 1).sum();
    println!(
        "wrote {} trajectories ({} frames, {} expert retries) to {}",
        manifest.trajectories.len(),
        manifest.total_steps(),
        retries,
        a.out.display()
    );
    Ok(())
}

/// `contact-sheet`: first frames of several instances for both robots in one PNG.
pub fn contact_sheet(a: ContactSheetArgs) -> Result<()> {
    render_sheet(&a.out, a.instances, a.seed, &a.frames.world())?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// Prints the report as a table.
fn print_report(r: &ExpertReport) {
    let n = r.instances_per_task;
    println!("expert on {} ({} instances per task)", r.robot, n);
    println!("{:>4} {:>8} {:>8} {:>8}", "task", "reached", "picked", "placed");
    for (t, c) in r.per_task.iter().enumerate() {
        println!("{t:>4} {:>8} {:>8} {:>8}", format!("{}/{n}", c[0]), format!("{}/{n}", c[1]), format!("{}/{n}", c[2]));
    }
    let o = r.overall();
    println!("all  {:>7.1}% {:>7.1}% {:>7.1}%", o[0] * 100.0, o[1] * 100.0, o[2] * 100.0);
}

/// Renders `instances` first frames per robot (rows: robots, columns: instances) into `out`.
fn render_sheet(out: &Path, instances: usize, seed: u64, world: &WorldConfig) -> Result<()> {
    if instances == 0 {
        bail!("--instances must be at least 1");
    }
    let (h, w) = (world.image.height, world.image.width);
    let mut sheet = image::RgbImage::new((w * instances) as u32, (h * Robot::ALL.len()) as u32);
    for (row, robot) in Robot::ALL.iter().enumerate() {
        let mut env = Env::new(*robot, world, true)?;
        for col in 0..instances {
            let task = Task::from_id((col * 5) % NUM_TASKS)?;
            env.reset(&Instance::sample(task, seed + col as u64));
            let frame = env.render()?;
            let img = image::RgbImage::from_raw(w as u32, h as u32, frame).context("frame size")?;
            image::imageops::overlay(&mut sheet, &img, (col * w) as i64, (row * h) as i64);
        }
    }
    sheet.save(out).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}
