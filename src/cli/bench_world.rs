//! `bench world`: physics and rendering throughput of the collection path (expert episodes with IK, control,
//! frames, JPEG encoding and file writing) beside a bare MuJoCo step + render loop of the same scene, in one run.
use super::options::{FrameArgs, parse_robot};
use super::world::Objects;
use anyhow::{Context, Result};
use oneshot_lab::data::collect::collect;
use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings};
use oneshot_lab::sim::env::{Env, WorldConfig};
use oneshot_lab::sim::robot::Robot;
use std::time::Instant;

/// Arguments of the `bench world` command.
#[derive(clap::Args)]
pub struct BenchWorldArgs {
    /// `sawyer` (the demonstrator) or `panda` (the agent).
    #[arg(long, value_parser = parse_robot, default_value = "sawyer")]
    pub robot: Robot,
    /// Expert episodes timed.
    #[arg(long, default_value_t = 4)]
    pub episodes: usize,
    /// `base` (the four base objects) or `library` (the multi-object world: 30 objects in the scene, four of an
    /// environment laid out, the others parked).
    #[arg(long, value_enum, default_value = "base")]
    pub objects: Objects,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// `bench world`: runs the benchmark and prints its figures.
pub fn bench_world(a: BenchWorldArgs) -> Result<()> {
    let world = WorldConfig { objects: a.objects.set(), ..a.frames.world() };
    let bench = measure(a.robot, &world, a.episodes)?;
    print_bench(a.robot, &world, &bench);
    Ok(())
}

/// Throughput figures of one run.
struct WorldBench {
    collect_physics_steps_per_s: f64,
    collect_frames_per_s: f64,
    bare_physics_steps_per_s: f64,
    bare_frames_per_s: f64,
}

/// Collects `episodes` trajectories with one worker (stored frames only are counted), then runs a bare loop
/// with the same numbers of physics steps and frames.
fn measure(robot: Robot, world: &WorldConfig, episodes: usize) -> Result<WorldBench> {
    let tmp = std::env::temp_dir().join(format!("oneshot-bench-world-{}", std::process::id()));
    let tasks = (0..episodes).map(|e| (e * 5) % 16).collect();
    let settings = CollectSettings { tasks, ..CollectSettings::default() };
    let config = CollectConfig { per_task: 1, world: world.clone(), settings, ..CollectConfig::paper(robot) };
    let start = Instant::now();
    let manifest = collect(&config, &tmp, 1, false).context("benchmark collection")?;
    let collect_s = start.elapsed().as_secs_f64();
    std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    let frames = manifest.total_steps();
    let actions = frames - manifest.trajectories.len();

    let mut env = Env::new(robot, world, true)?;
    let per_action = env.physics_steps_per_action();
    env.reset(&config.instance(0, 0, 0)?)?;
    let start = Instant::now();
    for _ in 0..frames {
        env.step_physics_only(per_action);
        env.render()?;
    }
    let bare_s = start.elapsed().as_secs_f64();
    Ok(WorldBench {
        collect_physics_steps_per_s: (actions * per_action) as f64 / collect_s,
        collect_frames_per_s: frames as f64 / collect_s,
        bare_physics_steps_per_s: (frames * per_action) as f64 / bare_s,
        bare_frames_per_s: frames as f64 / bare_s,
    })
}

/// Prints the figures and the collection path's share of the bare loop's speed.
fn print_bench(robot: Robot, world: &WorldConfig, b: &WorldBench) {
    println!(
        "world benchmark: {robot}, {}x{} frames, {:?} visuals, {:?} objects, one worker",
        world.image.height, world.image.width, world.visuals, world.objects
    );
    println!(
        "  collection      : {:>9.0} physics steps/s {:>7.1} frames/s",
        b.collect_physics_steps_per_s, b.collect_frames_per_s
    );
    println!(
        "  bare step+render: {:>9.0} physics steps/s {:>7.1} frames/s",
        b.bare_physics_steps_per_s, b.bare_frames_per_s
    );
    println!(
        "  collection runs at {:.0}% of the bare loop's frame rate",
        100.0 * b.collect_frames_per_s / b.bare_frames_per_s
    );
}
