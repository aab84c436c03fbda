//! Animated GIFs of evaluation episodes: the demonstration (left) beside the agent's rollout (right), played at
//! the policy's rate, with a bar under the agent's frame whose three squares light up as the episode reaches,
//! picks and places.
use super::EpisodeResult;
use crate::sim::action::Action;
use crate::sim::camera::ImageSize;
use crate::sim::env::{Env, WorldConfig};
use crate::sim::milestones::Milestones;
use crate::sim::object::Object;
use crate::sim::robot::Robot;
use crate::sim::rollout::run_expert;
use crate::sim::task::{Instance, NUM_OBJECTS, Task};
use anyhow::{Context, Result, bail};
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgba, RgbaImage};
use std::path::{Path, PathBuf};

/// Height of the stage bar under the frames, in pixels.
const BAR: u32 = 12;
/// Colour of a stage square once the stage holds: reached, picked, placed.
const LIT: [[u8; 3]; 3] = [[240, 200, 40], [240, 130, 30], [40, 190, 70]];
/// Colour of a square whose stage does not hold yet.
const DARK: [u8; 3] = [70, 70, 70];

/// The file name of an episode's video: its index, task and the last stage it achieved.
pub fn file_name(result: &EpisodeResult) -> String {
    let outcome = match (result.placed, result.picked, result.reached) {
        (true, _, _) => "placed",
        (_, true, _) => "picked",
        (_, _, true) => "reached",
        _ => "failed",
    };
    format!("episode_{:04}_task{:02}_{outcome}.gif", result.index, result.task)
}

/// The frames of a video of `size`, beside the policy's: where the policy sees frames narrower than `width`, the
/// same view `width` pixels wide (the height keeps the policy frame's proportions); otherwise the policy's frames.
pub fn video_size(policy: ImageSize, width: usize) -> ImageSize {
    if policy.width >= width {
        return policy;
    }
    let height = (policy.height as f64 * width as f64 / policy.width as f64).round() as usize;
    ImageSize { height, width }
}

/// A replayed episode: the demonstration's frames, and the agent's with the stages after each.
pub type Replayed = (Vec<Vec<u8>>, Vec<(Vec<u8>, Milestones)>);

/// An episode rendered again at `size`: the demonstrator's expert replayed from the layout its demonstration
/// succeeded on, and the agent's commands replayed from its layout, each in a scene whose camera renders at
/// `size` (the physics is the same scene's, so the replay takes the same path). Returns the demonstration's
/// frames and the agent's with the stages after each; an agent replay that ends in other stages than
/// `result` is an error rather than a misleading video.
pub fn replay(
    world: &WorldConfig,
    size: ImageSize,
    result: &EpisodeResult,
    objects: [Object; NUM_OBJECTS],
    commands: &[Action],
    demo_max_actions: usize,
) -> Result<Replayed> {
    let world = WorldConfig { image: size, ..world.clone() };
    let task = Task::from_id(result.task)?;
    let mut demo_env = Env::new(Robot::Sawyer, &world, true)?;
    let demo =
        run_expert(&mut demo_env, &Instance::sample_with(task, result.demo_seed, objects), demo_max_actions, true)?;
    let demo: Vec<Vec<u8>> = demo.steps.into_iter().filter_map(|s| s.frame).collect();
    let mut env = Env::new(Robot::Panda, &world, true)?;
    env.reset(&Instance::sample_with(task, result.agent_seed, objects))?;
    let mut agent = vec![(env.render()?, Milestones::default())];
    for action in commands {
        env.step(action);
        agent.push((env.render()?, env.milestones()));
    }
    let m = env.milestones();
    if (m.reached, m.picked, m.placed) != (result.reached, result.picked, result.placed) {
        bail!(
            "the replay of episode {} at {}x{} ended reached/picked/placed {}/{}/{}, the episode {}/{}/{}",
            result.index,
            size.height,
            size.width,
            m.reached,
            m.picked,
            m.placed,
            result.reached,
            result.picked,
            result.placed
        );
    }
    Ok((demo, agent))
}

/// Writes `dir/<file_name>` from the demonstrator's frames and the agent's frames with the stages after each (the
/// first agent frame has none). Frames play at `hz`; the shorter video holds its last frame.
pub fn write_video(
    dir: &Path,
    demo: &[Vec<u8>],
    agent: &[(Vec<u8>, Milestones)],
    size: ImageSize,
    hz: f64,
    result: &EpisodeResult,
) -> Result<PathBuf> {
    let (h, w) = (size.height as u32, size.width as u32);
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(file_name(result));
    let file = std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
    let mut encoder = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    encoder.set_repeat(Repeat::Infinite)?;
    let delay = Delay::from_numer_denom_ms((1000.0 / hz).round() as u32, 1);
    let frames = demo.len().max(agent.len());
    for k in 0..frames {
        let mut canvas = RgbaImage::from_pixel(2 * w, h + BAR, Rgba([20, 20, 20, 255]));
        if let Some(d) = demo.get(k.min(demo.len().saturating_sub(1))) {
            paste(&mut canvas, d, w, h, 0)?;
        }
        if let Some((a, stages)) = agent.get(k.min(agent.len().saturating_sub(1))) {
            paste(&mut canvas, a, w, h, w)?;
            let lit = [stages.reached, stages.picked, stages.placed];
            for (i, on) in lit.iter().enumerate() {
                let [r, g, b] = if *on { LIT[i] } else { DARK };
                let x0 = w + 2 + i as u32 * (BAR + 2);
                for y in h + 2..h + BAR - 2 {
                    for x in x0..(x0 + BAR).min(2 * w) {
                        canvas.put_pixel(x, y, Rgba([r, g, b, 255]));
                    }
                }
            }
        }
        encoder.encode_frame(Frame::from_parts(canvas, 0, 0, delay)).with_context(|| format!("{}", path.display()))?;
    }
    Ok(path)
}

/// Copies an RGB frame `w x h` into `canvas` at column `x`.
fn paste(canvas: &mut RgbaImage, rgb: &[u8], w: u32, h: u32, x: u32) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, rgb.to_vec()).context("frame size")?;
    let rgba = image::DynamicImage::ImageRgb8(img).to_rgba8();
    image::imageops::overlay(canvas, &rgba, i64::from(x), 0);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::AnimationDecoder;
    use image::codecs::gif::GifDecoder;

    #[test]
    fn a_video_has_one_frame_per_step_and_lights_the_stages_it_reached() {
        let size = ImageSize { height: 8, width: 48 };
        let frame = |v: u8| vec![v; 3 * 8 * 48];
        let none = Milestones::default();
        let reached = Milestones { reached: true, ..none };
        let demo = vec![frame(200); 3];
        let agent = vec![(frame(50), none), (frame(60), reached), (frame(70), reached), (frame(80), reached)];
        let result = EpisodeResult {
            index: 3,
            task: 5,
            agent_seed: 0,
            demo_seed: 0,
            reached: true,
            picked: false,
            placed: false,
            wrong_bin: false,
            steps: 3,
            first_reached: Some(1),
            first_picked: None,
            first_placed: None,
            first_close: None,
        };
        let dir = std::env::temp_dir().join(format!("oneshot-video-{}", std::process::id()));
        let path = write_video(&dir, &demo, &agent, size, 10.0, &result).unwrap();
        assert!(path.ends_with("episode_0003_task05_reached.gif"), "{}", path.display());
        let decoder = GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap())).unwrap();
        let frames: Vec<_> = decoder.into_frames().collect::<Result<_, _>>().unwrap();
        assert_eq!(frames.len(), 4, "the longer video sets the length");
        let (first, last) = (frames[0].buffer(), frames[3].buffer());
        assert_eq!(first.dimensions(), (96, 8 + BAR));
        let square = |img: &RgbaImage, i: u32| img.get_pixel(48 + 2 + i * (BAR + 2) + 3, 8 + BAR / 2).0;
        let near = |p: [u8; 4], c: [u8; 3]| p.iter().zip(c).all(|(a, b)| a.abs_diff(b) < 24);
        assert!(near(square(first, 0), DARK) && near(square(last, 0), LIT[0]), "reached lights up");
        assert!(near(square(last, 2), DARK), "placed stays dark");
        assert!(near(first.get_pixel(2, 2).0, [200, 200, 200]) && near(last.get_pixel(50, 2).0, [80, 80, 80]));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
