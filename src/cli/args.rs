//! The command line's arguments. Options that have a configuration counterpart default to the configuration's
//! default (they are `Option`s here, filled in from the configuration structs), so no default is written twice.
use clap::{Parser, Subcommand};
use oneshot_lab::eval::localise::LocaliseTarget;
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::scene::Visuals;
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "oneshot-lab", version, about = "Transformers for One-Shot Visual Imitation, reproduced")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Scripted-expert success per task and stage.
    ExpertCheck(ExpertCheckArgs),
    /// Throughput of expert episodes beside a bare MuJoCo step + render loop.
    BenchWorld(BenchWorldArgs),
    /// Expert trajectories of one robot into a new dataset folder.
    Collect(CollectArgs),
    /// Trains a policy on a demonstrator and an agent collection (resumes from the latest checkpoint in OUT).
    Train(TrainArgs),
    /// Closed-loop rollouts on unseen instances: staged success with 95% intervals.
    Eval(EvalArgs),
    /// Open-loop probe: a trained policy's most likely and sampled actions on held-out expert windows against the
    /// expert's, per action dimension (mean absolute error).
    Probe(ProbeArgs),
    /// Localisation check: trains the policy's image trunk to regress the grasp position from each agent
    /// trajectory's first frame, scored on held-out layouts against the per-task mean (can this frame size show
    /// where the object is?).
    Localise(LocaliseArgs),
    /// Runs an experiment file: what is not cached executes, then the report is written.
    Run(RunArgs),
    /// Runs one stage of an experiment (what a Slurm job executes); records nothing in the store.
    #[command(hide = true)]
    RunStage(RunStageArgs),
    /// The grid as cells x stages: cached, to run or failed, with an estimate of the time left.
    Plan(PlanArgs),
    /// Why a stage would run: its inputs against the nearest cached stage of its kind.
    Why(WhyArgs),
    /// Stages by kind and status, running attempts and Slurm jobs, and recent failures (records what finished
    /// Slurm jobs did).
    Status(StatusArgs),
    /// Cancels the queued and running Slurm jobs of an experiment's stages.
    Cancel(CancelArgs),
    /// A named summary (cells, stages, failures, curves) or raw SQL, read-only.
    Query(QueryArgs),
    /// Artifacts no given experiment file references (listed; removed with --delete).
    Gc(GcArgs),
    /// Rebuilds an experiment's tables and figures from the results store.
    Report(ReportArgs),
    /// Training steps/s and peak memory of a configuration, beside its ResNet-18 trunk alone.
    BenchTrain(BenchTrainArgs),
    /// Evaluation rollouts/s on CPU for the small network and the random policy.
    BenchEval(BenchEvalArgs),
    /// Time of `plan` and of a fully cached `run` over a large grid.
    BenchPlan(BenchPlanArgs),
    /// Training samples/s the data path builds from two collections and copies to the device.
    BenchLoader(BenchLoaderArgs),
    /// A PNG of first frames of several instances for both robots.
    ContactSheet(ContactSheetArgs),
}

/// The results store and the experiment's scale profile.
#[derive(clap::Args)]
pub struct StoreArgs {
    /// Store folder (database and artifacts).
    #[arg(long, default_value = "runs")]
    pub store: PathBuf,
    /// Scale profile defined in the experiment file (e.g. `cpu`).
    #[arg(long)]
    pub profile: Option<String>,
}

/// Frame size and visuals of rendered scenes (each defaults to the `[world]` default).
#[derive(clap::Args)]
pub struct FrameArgs {
    /// Frame height (pixels).
    #[arg(long)]
    pub height: Option<usize>,
    /// Frame width (pixels).
    #[arg(long)]
    pub width: Option<usize>,
    /// `full` visual meshes, or `collision` geometry only.
    #[arg(long, value_parser = parse_visuals)]
    pub visuals: Option<Visuals>,
}

impl FrameArgs {
    /// The default world with these frames.
    pub fn world(&self) -> WorldConfig {
        let d = WorldConfig::default();
        let image =
            ImageSize { height: self.height.unwrap_or(d.image.height), width: self.width.unwrap_or(d.image.width) };
        WorldConfig { image, visuals: self.visuals.unwrap_or(d.visuals), ..d }
    }

    /// Whether any frame option was given.
    pub fn given(&self) -> bool {
        self.height.is_some() || self.width.is_some() || self.visuals.is_some()
    }
}

/// Output formats of `query`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Table,
    Csv,
    Json,
}

/// A lower-case name in the configuration's spelling, parsed as its type (a robot, visuals, a yaw rule).
pub fn parse_named<T: serde::de::DeserializeOwned>(s: &str) -> Result<T, String> {
    serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|e| format!("`{s}`: {e}"))
}

fn parse_robot(s: &str) -> Result<Robot, String> {
    parse_named(s)
}

fn parse_visuals(s: &str) -> Result<Visuals, String> {
    parse_named(s)
}

/// Arguments of the `expert-check` command.
#[derive(clap::Args)]
pub struct ExpertCheckArgs {
    #[arg(long, value_parser = parse_robot)]
    pub robot: Robot,
    /// Instances of each of the 16 tasks.
    #[arg(long, default_value_t = 10)]
    pub per_task: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Action budget per episode (default: collect.max_actions).
    #[arg(long)]
    pub max_actions: Option<usize>,
    /// The expert's gripper yaw rule: fixed, heading or object_yaw (default: the robot's in the default world).
    #[arg(long)]
    pub gripper_yaw: Option<String>,
    /// The expert closes the gripper on reaching the grasp point (world.close_on_arrival).
    #[arg(long)]
    pub close_on_arrival: bool,
}

/// Arguments of the `bench-world` command.
#[derive(clap::Args)]
pub struct BenchWorldArgs {
    #[arg(long, value_parser = parse_robot, default_value = "sawyer")]
    pub robot: Robot,
    #[arg(long, default_value_t = 4)]
    pub episodes: usize,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// Arguments of the `collect` command.
#[derive(clap::Args)]
pub struct CollectArgs {
    #[arg(long, value_parser = parse_robot)]
    pub robot: Robot,
    /// Output folder (must not exist; it appears only when complete).
    #[arg(long)]
    pub out: PathBuf,
    /// Task ids, comma separated (default: all 16).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Option<Vec<usize>>,
    /// Trajectories per task (default: the paper's 100).
    #[arg(long)]
    pub per_task: Option<usize>,
    /// Root seed of the layouts (default: collect.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Parallel workers (default: CPU cores).
    #[arg(long)]
    pub workers: Option<usize>,
    /// JPEG quality of stored frames (default: collect.jpeg_quality).
    #[arg(long)]
    pub jpeg_quality: Option<u8>,
    /// Noise (m) on the executed position targets; the expert's own actions are recorded (default:
    /// collect.action_noise).
    #[arg(long)]
    pub action_noise: Option<f64>,
    /// The expert closes the gripper on reaching the grasp point (world.close_on_arrival).
    #[arg(long)]
    pub close_on_arrival: bool,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// Arguments of the `train` command.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Demonstrator (Sawyer) collection folder.
    #[arg(long)]
    pub demos: PathBuf,
    /// Agent (Panda) collection folder.
    #[arg(long)]
    pub agents: PathBuf,
    /// Training folder: checkpoints, loss curve, final weights.
    #[arg(long)]
    pub out: PathBuf,
    /// TOML file with optional [model] and [train] tables (paper defaults otherwise).
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[arg(long)]
    pub steps: Option<u64>,
    #[arg(long)]
    pub batch_size: Option<usize>,
    #[arg(long)]
    pub device: Option<String>,
}

/// Arguments of the `eval` command.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// `expert`, `random`, or a finished training folder (evaluated in the world it was trained in).
    #[arg(long)]
    pub policy: String,
    /// Evaluate the training folder's checkpoint at this step instead of its final weights.
    #[arg(long)]
    pub checkpoint: Option<u64>,
    /// Episodes (default: eval.episodes).
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Actions per episode (default: eval.horizon).
    #[arg(long)]
    pub horizon: Option<usize>,
    /// Root of the layouts and the sampling (default: eval.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Task ids the episodes cycle through, comma separated (default: all 16).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Option<Vec<usize>>,
    /// `sample` the network's action distribution (the authors') or take its `mode` (default: eval.action).
    #[arg(long)]
    pub action: Option<String>,
    /// `reset` the agent's frames once 5 are held (the authors') or keep a `sliding` window of the latest 5
    /// (default: eval.history).
    #[arg(long)]
    pub history: Option<String>,
    /// Episodes in lockstep, the network's batch (default: eval.batch).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Simulation threads (default: CPU cores).
    #[arg(long)]
    pub workers: Option<usize>,
    /// `auto`, `cpu`, `cuda` or `cuda:N` (default: eval.device).
    #[arg(long)]
    pub device: Option<String>,
    /// Collection folders whose layouts must not be evaluated on (the training data).
    #[arg(long, value_delimiter = ',')]
    pub exclude_from: Vec<PathBuf>,
    /// Evaluate on the training layouts of these collections instead (DEMOS,AGENTS): each agent trajectory's
    /// layout with the same slot's demonstration; --episodes is then their number.
    #[arg(long, value_delimiter = ',', conflicts_with = "exclude_from")]
    pub training_layouts: Option<Vec<PathBuf>>,
    /// Episode indices to draw as PNG strips (needs --out).
    #[arg(long, value_delimiter = ',')]
    pub strips: Vec<usize>,
    /// Episode indices to record as GIFs, the demonstration beside the rollout (needs --out).
    #[arg(long, value_delimiter = ',')]
    pub videos: Vec<usize>,
    /// Who moves the agent: `policy` (the network's actions) or `scripted_poses` (DAML-Auxiliary: the scripted
    /// expert executes the grasp and drop positions the network predicts).
    #[arg(long)]
    pub control: Option<String>,
    /// Folder for episodes.jsonl, summary.json, strips and videos.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Frames of the reference policies' world (a trained policy runs in its own).
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// Arguments of the `probe` command.
#[derive(clap::Args)]
pub struct ProbeArgs {
    /// A finished training folder.
    #[arg(long)]
    pub policy: PathBuf,
    /// Probe the checkpoint at this step instead of the final weights.
    #[arg(long)]
    pub checkpoint: Option<u64>,
    /// Demonstrator (Sawyer) collection folder.
    #[arg(long)]
    pub demos: PathBuf,
    /// Agent (Panda) collection folder.
    #[arg(long)]
    pub agents: PathBuf,
    /// Windows to probe.
    #[arg(long, default_value_t = 64)]
    pub windows: usize,
    /// Probe training windows instead of validation ones.
    #[arg(long)]
    pub train_split: bool,
    /// Probe windows at the start of each trajectory (the approach to the object) instead of training's draws.
    #[arg(long)]
    pub from_start: bool,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value = "auto")]
    pub device: String,
}

/// Arguments of the `localise` command.
#[derive(clap::Args)]
pub struct LocaliseArgs {
    /// Agent (Panda) collection folder.
    #[arg(long)]
    pub agents: PathBuf,
    /// ResNet-18 base width (the CPU network's 16; the paper's 64).
    #[arg(long, default_value_t = 16)]
    pub backbone_width: i64,
    /// Residual stages kept (the CPU network's 3; the paper's 4).
    #[arg(long, default_value_t = 3)]
    pub backbone_stages: usize,
    #[arg(long, default_value_t = 1000)]
    pub steps: u64,
    #[arg(long, default_value_t = 32)]
    pub batch: i64,
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Errors are printed every this many steps.
    #[arg(long, default_value_t = 200)]
    pub report_every: u64,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// `grasp`: the task's grasp position, told the task; `objects`: all four objects' positions, not told it.
    #[arg(long, default_value = "grasp", value_parser = parse_localise_target)]
    pub target: LocaliseTarget,
    /// Augmentation of the training frames: `none`, `authors` (the policy's default colour jitter, crops and
    /// shifts) or `colour` (the colour jitter alone).
    #[arg(long, default_value = "none", value_parser = ["none", "authors", "colour"])]
    pub augment: String,
    /// Write the trained trunk here (safetensors with torchvision names), for `model.pretrained_backbone`.
    #[arg(long)]
    pub save_trunk: Option<PathBuf>,
}

fn parse_localise_target(s: &str) -> Result<LocaliseTarget, String> {
    parse_named(s)
}

/// Arguments of the `run` command.
#[derive(clap::Args)]
pub struct RunArgs {
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Stages executed at once.
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// Simulation threads per collection or evaluation stage (default: CPU cores).
    #[arg(long)]
    pub workers: Option<usize>,
    /// Only cells whose `cell/kind` label matches (`*` wildcards), plus what they need.
    #[arg(long)]
    pub only: Option<String>,
    /// Re-run matching stages and everything below them.
    #[arg(long)]
    pub force: Option<String>,
    /// Show what would run.
    #[arg(long)]
    pub dry_run: bool,
    /// CUDA device indices, one per concurrent network stage (e.g. 0,1).
    #[arg(long, value_delimiter = ',')]
    pub gpus: Vec<usize>,
    /// Run each stage as a Slurm job (`sbatch --wait`); `--jobs` bounds jobs in flight.
    #[arg(long)]
    pub slurm: bool,
    /// With --slurm: submit every stage at once, each job waiting on its upstream jobs, and exit; `status` and the
    /// next `run` record what the jobs did, `cancel` stops them.
    #[arg(long, requires = "slurm")]
    pub detach: bool,
    /// Extra sbatch argument for every job (repeatable), e.g. --slurm-arg=--partition=cpu.
    #[arg(long = "slurm-arg", allow_hyphen_values = true)]
    pub slurm_args: Vec<String>,
    /// Extra sbatch argument for network stages (repeatable), e.g. --slurm-gpu-arg=--gres=gpu:1.
    #[arg(long = "slurm-gpu-arg", allow_hyphen_values = true)]
    pub slurm_gpu_args: Vec<String>,
}

/// Arguments of the `run-stage` command.
#[derive(clap::Args)]
pub struct RunStageArgs {
    pub file: PathBuf,
    #[arg(long)]
    pub key: String,
    #[command(flatten)]
    pub store: StoreArgs,
    #[arg(long)]
    pub workers: Option<usize>,
}

/// Arguments of the `plan` command.
#[derive(clap::Args)]
pub struct PlanArgs {
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Arguments of the `why` command.
#[derive(clap::Args)]
pub struct WhyArgs {
    /// Stage key or its first characters.
    pub stage: String,
    #[arg(long, default_value = "runs")]
    pub store: PathBuf,
}

/// Arguments of the `status` command.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[arg(long, default_value = "runs")]
    pub store: PathBuf,
}

/// Arguments of the `cancel` command.
#[derive(clap::Args)]
pub struct CancelArgs {
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Arguments of the `query` command.
#[derive(clap::Args)]
pub struct QueryArgs {
    pub query: String,
    #[arg(long, value_enum, default_value = "table")]
    pub format: Format,
    #[arg(long, default_value = "runs")]
    pub store: PathBuf,
}

/// Arguments of the `gc` command.
#[derive(clap::Args)]
pub struct GcArgs {
    pub files: Vec<PathBuf>,
    #[arg(long)]
    pub profile: Option<String>,
    #[arg(long, default_value = "runs")]
    pub store: PathBuf,
    #[arg(long)]
    pub delete: bool,
}

/// Arguments of the `report` command.
#[derive(clap::Args)]
pub struct ReportArgs {
    pub file: PathBuf,
    #[command(flatten)]
    pub store: StoreArgs,
    /// Output folder (default: STORE/reports/NAME).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Arguments of the `bench-train` command.
#[derive(clap::Args)]
pub struct BenchTrainArgs {
    /// `paper` (240x320, batch 30) or `small` (the smoke network at 64x80, batch 8).
    #[arg(long, default_value = "small")]
    pub config: String,
    #[arg(long, default_value_t = 5)]
    pub steps: usize,
    /// Override the configuration's batch size.
    #[arg(long)]
    pub batch: Option<usize>,
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// Architectures to time, comma separated, or `all` (default: the configuration's, the transformer).
    #[arg(long)]
    pub architectures: Option<String>,
    /// Number type of the forward pass: `fp32` or `bf16` (autocast), as `train.precision`.
    #[arg(long, default_value = "fp32")]
    pub precision: String,
    /// Layout of the trunk's images: `contiguous` or `channels_last`, as `train.memory_format`.
    #[arg(long, default_value = "contiguous")]
    pub memory_format: String,
}

/// Arguments of the `bench-eval` command.
#[derive(clap::Args)]
pub struct BenchEvalArgs {
    #[arg(long, default_value_t = 16)]
    pub episodes: usize,
    #[arg(long, default_value_t = 40)]
    pub horizon: usize,
    #[arg(long)]
    pub workers: Option<usize>,
}

/// Arguments of the `bench-loader` command.
#[derive(clap::Args)]
pub struct BenchLoaderArgs {
    /// Demonstrator collection folder.
    #[arg(long)]
    pub demos: PathBuf,
    /// Agent collection folder.
    #[arg(long)]
    pub agents: PathBuf,
    #[arg(long, default_value_t = 30)]
    pub batch: usize,
    /// Batches timed (after one warm-up batch).
    #[arg(long, default_value_t = 20)]
    pub batches: usize,
    /// Threads building each batch (default: CPU cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Build batches without augmentation.
    #[arg(long)]
    pub no_augment: bool,
    /// Decode each frame's JPEG when it is used, as a dataset too large to hold decoded does.
    #[arg(long)]
    pub decode_on_use: bool,
    /// Where batches are copied: `auto`, `cpu`, `cuda` or `cuda:N`.
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// Where frames are augmented: `host` (by the threads building the batch) or `device` (after the copy),
    /// as `train.augment_on`.
    #[arg(long, default_value = "host")]
    pub augment_on: String,
}

/// Arguments of the `bench-plan` command.
#[derive(clap::Args)]
pub struct BenchPlanArgs {
    /// Cells in the grid (stages are about twice as many).
    #[arg(long, default_value_t = 200)]
    pub cells: usize,
}

/// Arguments of the `contact-sheet` command.
#[derive(clap::Args)]
pub struct ContactSheetArgs {
    #[arg(long, default_value = "contact_sheet.png")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 4)]
    pub instances: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub frames: FrameArgs,
}
