//! The `oneshot-lab` command line.
use anyhow::Result;
use clap::{Parser, Subcommand};
use oneshot_lab::commands::{bench, bench_world, contact_sheet, eval, expert_check, inspect, orchestrate};
use oneshot_lab::data::collect::{CollectConfig, collect};
use oneshot_lab::data::pairs::{PairDataset, Split};
use oneshot_lab::eval::EvalConfig;
use oneshot_lab::eval::probe;
use oneshot_lab::eval::summary::print_summary;
use oneshot_lab::pipeline::scheduler::RunOptions;
use oneshot_lab::pipeline::slurm::SlurmOptions;
use oneshot_lab::pipeline::store::Store;
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
        /// The expert's gripper yaw rule: fixed, heading or object_yaw (default: the robot's in the default world).
        #[arg(long)]
        gripper_yaw: Option<String>,
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
        /// `expert`, `random`, or a finished training folder (evaluated in the world it was trained in).
        #[arg(long)]
        policy: String,
        /// Evaluate the training folder's checkpoint at this step instead of its final weights.
        #[arg(long)]
        checkpoint: Option<u64>,
        #[arg(long, default_value_t = 160)]
        episodes: usize,
        #[arg(long, default_value_t = 60)]
        horizon: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Task ids the episodes cycle through, comma separated (default: all 16).
        #[arg(long, value_delimiter = ',')]
        tasks: Option<Vec<usize>>,
        /// `sample` the network's action distribution (the authors') or take its `mode`.
        #[arg(long, default_value = "sample")]
        action: String,
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
        /// Evaluate on the training layouts of these collections instead (DEMOS,AGENTS): each agent trajectory's
        /// layout with the same slot's demonstration; --episodes is then their number.
        #[arg(long, value_delimiter = ',', conflicts_with = "exclude_from")]
        training_layouts: Option<Vec<PathBuf>>,
        /// Episode indices to draw as PNG strips (needs --out).
        #[arg(long, value_delimiter = ',')]
        strips: Vec<usize>,
        /// Folder for episodes.jsonl, summary.json and strips.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Frame height of the reference policies' world (a trained policy uses its own).
        #[arg(long)]
        height: Option<usize>,
        /// Frame width of the reference policies' world.
        #[arg(long)]
        width: Option<usize>,
        /// Visual meshes, or collision geometry only (reference policies).
        #[arg(long, value_enum)]
        visuals: Option<Visuals>,
    },
    /// Open-loop probe: a trained policy's most likely and sampled actions on held-out expert windows against the
    /// expert's, per action dimension (mean absolute error).
    Probe {
        /// A finished training folder.
        #[arg(long)]
        policy: PathBuf,
        /// Probe the checkpoint at this step instead of the final weights.
        #[arg(long)]
        checkpoint: Option<u64>,
        /// Demonstrator (Sawyer) collection folder.
        #[arg(long)]
        demos: PathBuf,
        /// Agent (Panda) collection folder.
        #[arg(long)]
        agents: PathBuf,
        /// Windows to probe.
        #[arg(long, default_value_t = 64)]
        windows: usize,
        /// Probe training windows instead of validation ones.
        #[arg(long)]
        train_split: bool,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value = "auto")]
        device: String,
    },
    /// Runs an experiment file: what is not cached executes, then the report is written.
    Run {
        file: PathBuf,
        #[command(flatten)]
        store: StoreArgs,
        /// Stages executed at once.
        #[arg(long, default_value_t = 1)]
        jobs: usize,
        /// Simulation threads per collection or evaluation stage (default: CPU cores).
        #[arg(long)]
        workers: Option<usize>,
        /// Only cells whose `cell/kind` label matches (`*` wildcards), plus what they need.
        #[arg(long)]
        only: Option<String>,
        /// Re-run matching stages and everything below them.
        #[arg(long)]
        force: Option<String>,
        /// Show what would run.
        #[arg(long)]
        dry_run: bool,
        /// CUDA device indices, one per concurrent network stage (e.g. 0,1).
        #[arg(long, value_delimiter = ',')]
        gpus: Vec<usize>,
        /// Run each stage as a Slurm job (`sbatch --wait`); `--jobs` bounds jobs in flight.
        #[arg(long)]
        slurm: bool,
        /// Extra sbatch argument for every job (repeatable), e.g. --slurm-arg=--partition=cpu.
        #[arg(long = "slurm-arg", allow_hyphen_values = true)]
        slurm_args: Vec<String>,
        /// Extra sbatch argument for network stages (repeatable), e.g. --slurm-gpu-arg=--gres=gpu:1.
        #[arg(long = "slurm-gpu-arg", allow_hyphen_values = true)]
        slurm_gpu_args: Vec<String>,
    },
    /// Runs one stage of an experiment (what a Slurm job executes); records nothing in the store.
    #[command(hide = true)]
    RunStage {
        file: PathBuf,
        #[arg(long)]
        key: String,
        #[command(flatten)]
        store: StoreArgs,
        #[arg(long)]
        workers: Option<usize>,
    },
    /// The grid as cells x stages: cached, to run or failed, with an estimate of the time left.
    Plan {
        file: PathBuf,
        #[command(flatten)]
        store: StoreArgs,
    },
    /// Why a stage would run: its inputs against the nearest cached stage of its kind.
    Why {
        /// Stage key or its first characters.
        stage: String,
        #[arg(long, default_value = "runs")]
        store: PathBuf,
    },
    /// Stages by kind and status, running attempts and recent failures.
    Status {
        #[arg(long, default_value = "runs")]
        store: PathBuf,
    },
    /// A named summary (cells, stages, failures, curves) or raw SQL, read-only.
    Query {
        query: String,
        #[arg(long, value_enum, default_value = "table")]
        format: inspect::Format,
        #[arg(long, default_value = "runs")]
        store: PathBuf,
    },
    /// Artifacts no given experiment file references (listed; removed with --delete).
    Gc {
        files: Vec<PathBuf>,
        #[arg(long)]
        profile: Option<String>,
        #[arg(long, default_value = "runs")]
        store: PathBuf,
        #[arg(long)]
        delete: bool,
    },
    /// Rebuilds an experiment's tables and figures from the results store.
    Report {
        file: PathBuf,
        #[command(flatten)]
        store: StoreArgs,
        /// Output folder (default: STORE/reports/NAME).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Training steps/s and peak memory of a configuration, beside its ResNet-18 trunk alone.
    BenchTrain {
        /// `paper` (240x320, batch 30) or `small` (the smoke network at 64x80, batch 8).
        #[arg(long, default_value = "small")]
        config: String,
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Override the configuration's batch size.
        #[arg(long)]
        batch: Option<usize>,
        #[arg(long, default_value = "auto")]
        device: String,
    },
    /// Evaluation rollouts/s on CPU for the small network and the random policy.
    BenchEval {
        #[arg(long, default_value_t = 16)]
        episodes: usize,
        #[arg(long, default_value_t = 40)]
        horizon: usize,
        #[arg(long)]
        workers: Option<usize>,
    },
    /// Time of `plan` and of a fully cached `run` over a large grid.
    BenchPlan {
        /// Cells in the grid (stages are about twice as many).
        #[arg(long, default_value_t = 200)]
        cells: usize,
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

/// The results store and the experiment's scale profile.
#[derive(clap::Args)]
struct StoreArgs {
    /// Store folder (database and artifacts).
    #[arg(long, default_value = "runs")]
    store: PathBuf,
    /// Scale profile defined in the experiment file (e.g. `cpu`).
    #[arg(long)]
    profile: Option<String>,
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
    // Exit quietly when stdout is closed early (e.g. `oneshot-lab query cells | head`).
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::ExpertCheck { robot, per_task, seed, max_actions, gripper_yaw } => {
            let mut world = WorldConfig::default();
            if let Some(rule) = gripper_yaw {
                let rule = serde_json::from_value(serde_json::Value::String(rule.clone()))
                    .map_err(|_| anyhow::anyhow!("--gripper-yaw {rule}: expected fixed, heading or object_yaw"))?;
                match robot {
                    Robot::Sawyer => world.demo_yaw = rule,
                    Robot::Panda => world.agent_yaw = rule,
                }
            }
            let report = expert_check::expert_check(robot, &world, per_task, seed, max_actions)?;
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
            checkpoint,
            episodes,
            horizon,
            seed,
            tasks,
            action,
            batch,
            workers,
            device,
            exclude_from,
            training_layouts,
            strips,
            out,
            height,
            width,
            visuals,
        } => {
            let mut config = EvalConfig { episodes, horizon, seed, batch, device, strips, ..EvalConfig::default() };
            if let Some(tasks) = tasks {
                config.tasks = tasks;
            }
            config.action = serde_json::from_value(serde_json::Value::String(action.clone()))
                .map_err(|_| anyhow::anyhow!("--action {action}: expected sample or mode"))?;
            let layouts = match training_layouts.as_deref() {
                Some([demos, agents]) => eval::Layouts::Training { demos: demos.clone(), agents: agents.clone() },
                Some(other) => anyhow::bail!("--training-layouts takes DEMOS,AGENTS: two folders, not {}", other.len()),
                None => eval::Layouts::Fresh(eval::training_seeds(&exclude_from)?),
            };
            let workers = workers.unwrap_or_else(default_workers);
            let policy = eval::PolicyArg::parse(&policy, checkpoint);
            let world = match (height, width, visuals, &policy) {
                (None, None, None, _) => None,
                (_, _, _, eval::PolicyArg::Trained { .. }) => {
                    anyhow::bail!(
                        "a trained policy is evaluated in the world it was trained in: drop --height, --width and --visuals"
                    )
                }
                _ => {
                    let d = WorldConfig::default();
                    let image =
                        ImageSize { height: height.unwrap_or(d.image.height), width: width.unwrap_or(d.image.width) };
                    Some(WorldConfig { image, visuals: visuals.unwrap_or(d.visuals), ..d })
                }
            };
            let (_, summary) = eval::run_eval(&policy, world.as_ref(), &config, &layouts, workers, out.as_deref())?;
            print_summary(&summary);
        }
        Command::Probe { policy, checkpoint, demos, agents, windows, train_split, seed, device } => {
            let trained = oneshot_lab::train::load_trained(
                &policy,
                checkpoint,
                oneshot_lab::train::config::parse_device(&device)?,
            )?;
            let data = PairDataset::open(&demos, &agents, trained.summary.train.val_fraction)?;
            let split = if train_split { Split::Train } else { Split::Val };
            let report = probe::open_loop(&trained, &data, split, windows, 16, seed)?;
            probe::print_probe(&report);
        }
        Command::Run { file, store, jobs, workers, only, force, dry_run, gpus, slurm, slurm_args, slurm_gpu_args } => {
            let slurm = slurm.then(|| SlurmOptions {
                file: file.clone(),
                profile: store.profile.clone(),
                args: slurm_args,
                gpu_args: slurm_gpu_args,
            });
            let opts = RunOptions {
                slurm,
                jobs,
                only,
                force,
                dry_run,
                gpus: gpus.iter().map(|g| format!("cuda:{g}")).collect(),
                workers: workers.unwrap_or_else(default_workers),
                progress: true,
            };
            orchestrate::run_experiment(&file, store.profile.as_deref(), &store.store, &opts)?;
        }
        Command::RunStage { file, key, store, workers } => {
            let (_, plan) = orchestrate::load_plan(&file, store.profile.as_deref())?;
            oneshot_lab::pipeline::slurm::run_stage(
                &plan,
                &key,
                &store.store,
                workers.unwrap_or_else(default_workers),
            )?;
        }
        Command::Plan { file, store } => orchestrate::print_plan(&file, store.profile.as_deref(), &store.store)?,
        Command::Why { stage, store } => inspect::why(&store, &stage)?,
        Command::Status { store } => inspect::status(&store)?,
        Command::Query { query, format, store } => inspect::query(&store, &query, format)?,
        Command::Gc { files, profile, store, delete } => {
            let unused = inspect::gc(&store, &files, profile.as_deref(), delete)?;
            for p in &unused {
                println!("{}{}", if delete { "removed " } else { "" }, p.display());
            }
            if !delete && !unused.is_empty() {
                println!("{} unused artifact folders; run again with --delete to remove them", unused.len());
            }
        }
        Command::Report { file, store, out } => {
            let experiment = oneshot_lab::config::Experiment::load(&file, store.profile.as_deref())?;
            let out = out.unwrap_or_else(|| oneshot_lab::report::report_dir(&store.store, &experiment.name));
            let db = Store::open(&store.store)?;
            oneshot_lab::report::write_report(&db, &experiment.name, &out)?;
            println!("wrote {}", out.join("index.md").display());
        }
        Command::BenchTrain { config, steps, batch, device } => {
            let mut c = bench::bench_config(&config)?;
            c.batch = batch.unwrap_or(c.batch);
            bench::bench_train(&c, steps.max(1), &device)?;
        }
        Command::BenchEval { episodes, horizon, workers } => {
            bench::bench_eval(episodes.max(1), horizon.max(1), workers.unwrap_or_else(default_workers))?
        }
        Command::BenchPlan { cells } => bench::bench_plan(cells.max(1))?,
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
