//! `contact-sheet`: one PNG of the first frame of several instances, for both robots.
use crate::sim::env::{Env, WorldConfig};
use crate::sim::robot::Robot;
use crate::sim::task::{Instance, NUM_TASKS, Task};
use anyhow::{Context, Result, bail};
use std::path::Path;

/// Renders `instances` first frames per robot (rows: robots, columns: instances) into `out`.
pub fn contact_sheet(out: &Path, instances: usize, seed: u64, world: &WorldConfig) -> Result<()> {
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
