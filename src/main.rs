//! The `oneshot-lab` command line.
use anyhow::Result;
use clap::{Parser, Subcommand};
use oneshot_lab::commands::{bench_world, contact_sheet, expert_check};
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::scene::Visuals;
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "oneshot-lab", version, about = "Transformers for One-Shot Visual Imitation, reproduced")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Scripted-expert success per task and stage.
    ExpertCheck {
        #[arg(long, value_enum)]
        robot: Robot,
        /// Instances of each of the 16 tasks.
        #[arg(long, default_value_t = 10)]
        per_task: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Action budget per episode.
        #[arg(long, default_value_t = 100)]
        max_actions: usize,
    },
    /// Throughput of expert episodes beside a bare MuJoCo step + render loop.
    BenchWorld {
        #[arg(long, value_enum, default_value = "sawyer")]
        robot: Robot,
        #[arg(long, default_value_t = 4)]
        episodes: usize,
        #[command(flatten)]
        frames: FrameArgs,
    },
    /// A PNG of first frames of several instances for both robots.
    ContactSheet {
        #[arg(long, default_value = "contact_sheet.png")]
        out: PathBuf,
        #[arg(long, default_value_t = 4)]
        instances: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[command(flatten)]
        frames: FrameArgs,
    },
}

/// Frame size and visuals of rendered scenes.
#[derive(clap::Args)]
struct FrameArgs {
    /// Frame height (pixels).
    #[arg(long, default_value_t = 240)]
    height: usize,
    /// Frame width (pixels).
    #[arg(long, default_value_t = 320)]
    width: usize,
    /// Visual meshes, or collision geometry only.
    #[arg(long, value_enum, default_value = "full")]
    visuals: Visuals,
}

impl FrameArgs {
    fn world(&self) -> WorldConfig {
        let image = ImageSize { height: self.height, width: self.width };
        WorldConfig { image, visuals: self.visuals, ..WorldConfig::default() }
    }
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::ExpertCheck { robot, per_task, seed, max_actions } => {
            let report = expert_check::expert_check(robot, per_task, seed, max_actions)?;
            expert_check::print_report(&report);
        }
        Command::BenchWorld { robot, episodes, frames } => {
            let world = frames.world();
            let bench = bench_world::bench_world(robot, &world, episodes)?;
            bench_world::print_bench(robot, &world, &bench);
        }
        Command::ContactSheet { out, instances, seed, frames } => {
            let world = frames.world();
            contact_sheet::contact_sheet(&out, instances, seed, &world)?;
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}
