//! The `oneshot-lab` command line.
use anyhow::Result;
use clap::{Parser, Subcommand};
use oneshot_lab::commands::{bench_world, contact_sheet, eval, expert_check};
use oneshot_lab::data::collect::{CollectConfig, collect};
use oneshot_lab::eval::EvalConfig;
use oneshot_lab::eval::summary::print_summary;
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::scene::Visuals;
use oneshot_lab::train::{TrainFile, TrainRun, train};
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
    /// Expert trajectories of one robot into a new dataset folder.
    Collect {
        #[arg(long, value_enum)]
        robot: Robot,
        /// Output folder (must not exist; it appears only when complete).
        #[arg(long)]
        out: PathBuf,
        /// Task ids, comma separated (default: all 16).
        #[arg(long, value_delimiter = ',')]
        tasks: Option<Vec<usize>>,
        /// Trajectories per task.
        #[arg(long, default_value_t = 100)]
        per_task: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Parallel workers (default: CPU cores).
        #[arg(long)]
        workers: Option<usize>,
        #[arg(long, default_value_t = 90)]
        jpeg_quality: u8,
        #[command(flatten)]
        frames: FrameArgs,
    },
    /// Trains a policy on a demonstrator and an agent collection (resumes from the latest checkpoint in OUT).
    Train {
        /// Demonstrator (Sawyer) collection folder.
        #[arg(long)]
        demos: PathBuf,
        /// Agent (Panda) collection folder.
        #[arg(long)]
        agents: PathBuf,
        /// Training folder: checkpoints, loss curve, final weights.
        #[arg(long)]
        out: PathBuf,
        /// TOML file with optional [model] and [train] tables (paper defaults otherwise).
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long)]
        steps: Option<u64>,
        #[arg(long)]
        batch_size: Option<usize>,
        #[arg(long)]
        device: Option<String>,
    },
    /// Closed-loop rollouts on unseen instances: staged success with 95% intervals.
    Eval {
        /// `expert`, `random`, or a finished training folder.
        #[arg(long)]
        policy: String,
        #[arg(long, default_value_t = 160)]
        episodes: usize,
        #[arg(long, default_value_t = 60)]
        horizon: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Episodes in lockstep (the network's batch).
        #[arg(long, default_value_t = 32)]
        batch: usize,
        /// Simulation threads (default: CPU cores).
        #[arg(long)]
        workers: Option<usize>,
        #[arg(long, default_value = "auto")]
        device: String,
        /// Collection folders whose layouts must not be evaluated on (the training data).
        #[arg(long, value_delimiter = ',')]
        exclude_from: Vec<PathBuf>,
        /// Episode indices to draw as PNG strips (needs --out).
        #[arg(long, value_delimiter = ',')]
        strips: Vec<usize>,
        /// Folder for episodes.jsonl, summary.json and strips.
        #[arg(long)]
        out: Option<PathBuf>,
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
        Command::Collect { robot, out, tasks, per_task, seed, workers, jpeg_quality, frames } => {
            let mut config =
                CollectConfig { per_task, seed, jpeg_quality, world: frames.world(), ..CollectConfig::paper(robot) };
            if let Some(tasks) = tasks {
                config.tasks = tasks;
            }
            let manifest = collect(&config, &out, workers.unwrap_or_else(default_workers), true)?;
            let retries: usize = manifest.trajectories.iter().map(|e| e.attempts - 1).sum();
            println!(
                "wrote {} trajectories ({} frames, {} expert retries) to {}",
                manifest.trajectories.len(),
                manifest.total_steps(),
                retries,
                out.display()
            );
        }
        Command::Train { demos, agents, out, config, steps, batch_size, device } => {
            let mut file = match config {
                Some(path) => TrainFile::load(&path)?,
                None => TrainFile::default(),
            };
            file.train.steps = steps.unwrap_or(file.train.steps);
            file.train.batch_size = batch_size.unwrap_or(file.train.batch_size);
            file.train.device = device.unwrap_or(file.train.device);
            let run = TrainRun { demo_dir: &demos, agent_dir: &agents, out: &out, progress: true };
            let s = train(&file.model, &file.train, &run)?;
            println!(
                "trained {} steps in {:.0} s ({} parameters): validation BC {:.3} -> {:.3}; weights in {}",
                s.steps,
                s.seconds,
                s.parameters,
                s.first_val_bc,
                s.final_val_bc,
                out.display()
            );
        }
        Command::Eval {
            policy,
            episodes,
            horizon,
            seed,
            batch,
            workers,
            device,
            exclude_from,
            strips,
            out,
            frames,
        } => {
            let config = EvalConfig { episodes, horizon, seed, batch, device, strips, ..EvalConfig::default() };
            let exclude = eval::training_seeds(&exclude_from)?;
            let workers = workers.unwrap_or_else(default_workers);
            let policy = eval::PolicyArg::parse(&policy);
            let (_, summary) = eval::run_eval(&policy, &frames.world(), &config, &exclude, workers, out.as_deref())?;
            print_summary(&summary);
        }
        Command::ContactSheet { out, instances, seed, frames } => {
            let world = frames.world();
            contact_sheet::contact_sheet(&out, instances, seed, &world)?;
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}

/// Worker threads when none are asked for: the machine's cores.
fn default_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
