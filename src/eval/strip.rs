//! PNG strips of evaluation episodes: the demonstrator's context frames on top, the agent's frames below.
use super::EpisodeResult;
use crate::sim::camera::ImageSize;
use anyhow::{Context, Result};
use std::path::Path;

/// Frames per row of the agent part.
const COLUMNS: usize = 8;

/// Writes a strip: row 0 holds `COLUMNS` frames spread over the demonstration, the rows below every
/// `ceil(len / (2 * COLUMNS))`-th agent frame (at most two rows), with the episode's stages in the file name's
/// companion text file.
pub fn write_strip(
    path: &Path,
    demo: &[Vec<u8>],
    agent: &[Vec<u8>],
    size: ImageSize,
    result: &EpisodeResult,
) -> Result<()> {
    let (h, w) = (size.height as u32, size.width as u32);
    let pick = |frames: &[Vec<u8>], k: usize| -> Vec<usize> {
        if frames.len() <= k {
            return (0..frames.len()).collect();
        }
        (0..k).map(|i| i * (frames.len() - 1) / (k - 1)).collect()
    };
    let demo_idx = pick(demo, COLUMNS);
    let agent_idx = pick(agent, 2 * COLUMNS);
    let rows = 1 + agent_idx.len().div_ceil(COLUMNS) as u32;
    let mut sheet = image::RgbImage::new(w * COLUMNS as u32, h * rows);
    let mut put = |frame: &[u8], slot: usize| -> Result<()> {
        let img = image::RgbImage::from_raw(w, h, frame.to_vec()).context("frame size")?;
        let (row, col) = ((slot / COLUMNS) as u32, (slot % COLUMNS) as u32);
        image::imageops::overlay(&mut sheet, &img, i64::from(col * w), i64::from(row * h));
        Ok(())
    };
    for (k, &t) in demo_idx.iter().enumerate() {
        put(&demo[t], k)?;
    }
    for (k, &t) in agent_idx.iter().enumerate() {
        put(&agent[t], COLUMNS + k)?;
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    sheet.save(path)?;
    let note = format!(
        "task {} agent seed {} demo seed {}: reached {} picked {} placed {} after {} steps\ntop row: demonstration; below: agent frames\n",
        result.task, result.agent_seed, result.demo_seed, result.reached, result.picked, result.placed, result.steps
    );
    std::fs::write(path.with_extension("txt"), note)?;
    Ok(())
}
