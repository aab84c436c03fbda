//! `bench-world`: physics and rendering throughput of an expert episode loop (IK, control, frames) beside a
//! bare MuJoCo step + render loop of the same scene, in the same run.
use crate::sim::env::{Env, WorldConfig};
use crate::sim::robot::Robot;
use crate::sim::rollout::run_expert;
use crate::sim::task::{Instance, NUM_TASKS, Task};
use anyhow::Result;
use std::time::Instant;

/// Throughput figures of one run.
pub struct WorldBench {
    pub episode_physics_steps_per_s: f64,
    pub episode_frames_per_s: f64,
    pub bare_physics_steps_per_s: f64,
    pub bare_frames_per_s: f64,
}

/// Runs `episodes` rendered expert episodes, then a bare loop with the same number of physics steps and frames.
pub fn bench_world(robot: Robot, world: &WorldConfig, episodes: usize) -> Result<WorldBench> {
    let mut env = Env::new(robot, world, true)?;
    let per_action = env.physics_steps_per_action();
    let (mut frames, mut actions) = (0usize, 0usize);
    let start = Instant::now();
    for e in 0..episodes {
        let ep = run_expert(&mut env, &Instance::sample(Task::from_id(e % NUM_TASKS)?, e as u64), 100, true)?;
        frames += ep.steps.len();
        actions += ep.steps.len() - 1;
    }
    let episode_s = start.elapsed().as_secs_f64();
    let physics = actions * per_action;

    // Bare loop: the same scene, zero controls, the same numbers of physics steps and frames.
    env.reset(&Instance::sample(Task::from_id(0)?, 0));
    let start = Instant::now();
    for _ in 0..frames {
        env.step_physics_only(per_action);
        env.render()?;
    }
    let bare_s = start.elapsed().as_secs_f64();
    Ok(WorldBench {
        episode_physics_steps_per_s: physics as f64 / episode_s,
        episode_frames_per_s: frames as f64 / episode_s,
        bare_physics_steps_per_s: (frames * per_action) as f64 / bare_s,
        bare_frames_per_s: frames as f64 / bare_s,
    })
}

/// Prints the figures and the episode loop's share of the bare loop's speed.
pub fn print_bench(robot: Robot, world: &WorldConfig, b: &WorldBench) {
    println!(
        "world benchmark: {robot}, {}x{} frames, {:?} visuals",
        world.image.height, world.image.width, world.visuals
    );
    println!(
        "  expert episodes : {:>9.0} physics steps/s {:>7.1} frames/s",
        b.episode_physics_steps_per_s, b.episode_frames_per_s
    );
    println!(
        "  bare step+render: {:>9.0} physics steps/s {:>7.1} frames/s",
        b.bare_physics_steps_per_s, b.bare_frames_per_s
    );
    println!(
        "  episodes run at {:.0}% of the bare loop's frame rate",
        100.0 * b.episode_frames_per_s / b.bare_frames_per_s
    );
}
