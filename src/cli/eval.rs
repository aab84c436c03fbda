//! `eval`, `probe` and `localise`: a policy in closed loop, a trained one open loop on held-out expert windows,
//! and the localisation check of an image trunk.
use super::default_workers;
use super::options::{FrameArgs, parse_named};
use super::print::{print_grip_probe, print_probe, print_summary};
use anyhow::{Result, bail};
use oneshot_lab::data::augment::Augmentation;
use oneshot_lab::data::pairs::{PairDataset, Split, Windows};
use oneshot_lab::device::parse_device;
use oneshot_lab::eval::config::Control;
use oneshot_lab::eval::grip_probe::grip_probe;
use oneshot_lab::eval::history::HistoryMode;
use oneshot_lab::eval::layouts::{Layouts, training_seeds};
use oneshot_lab::eval::probe::open_loop;
use oneshot_lab::eval::run::run_eval;
use oneshot_lab::eval::{ActionChoice, Actor, ActorFiles, EvalConfig, Weights};
use oneshot_lab::train::load_trained;
use oneshot_lab::train::pretrain::{LocaliseTarget, PretrainConfig};
use std::path::PathBuf;

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
    /// Which action the network's distribution yields (default: eval.action).
    #[arg(long, value_enum)]
    pub action: Option<ActionArg>,
    /// How the agent's window of frames is kept (default: eval.history).
    #[arg(long, value_enum)]
    pub history: Option<HistoryArg>,
    /// Episodes in lockstep, the network's batch (default: eval.batch).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Simulation threads (default: CPU cores).
    #[arg(long, value_parser = super::options::at_least_one)]
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
    /// Write every episode's steps to traces.jsonl: the command, the gripper and its fingers, the object in the
    /// gripper's frame (needs --out).
    #[arg(long, requires = "out")]
    pub traces: bool,
    /// Who moves the agent (default: eval.control).
    #[arg(long, value_enum)]
    pub control: Option<ControlArg>,
    /// Folder for episodes.jsonl, summary.json, traces.jsonl, strips and videos.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Frames of the reference policies' world (a trained policy runs in its own).
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// Which action the network's distribution yields at each step (`eval.action`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ActionArg {
    /// A sample (the authors').
    Sample,
    /// The mean of the most probable mixture component: no sampling noise.
    Mode,
    /// The mean of a sampled mixture component: no spread within the component.
    Component,
}

/// How the agent's window of frames is kept (`eval.history`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum HistoryArg {
    /// Cleared once it holds `eval.history_frames` frames (the authors').
    Reset,
    /// The latest `eval.history_frames` frames.
    Sliding,
}

/// Who moves the agent during an evaluation of a network (`eval.control`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ControlArg {
    /// The network's actions, step by step.
    Policy,
    /// The scripted expert executes the grasp and drop positions the network predicts (DAML-Auxiliary).
    #[value(name = "scripted_poses")]
    ScriptedPoses,
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
    /// Windows to probe (with `--at-grip`, agent trajectories).
    #[arg(long, default_value_t = 64)]
    pub windows: usize,
    /// Probe training windows instead of validation ones.
    #[arg(long)]
    pub train_split: bool,
    /// Probe windows at the start of each trajectory (the approach to the object) instead of training's draws.
    #[arg(long)]
    pub from_start: bool,
    /// Probe the steps around each expert's lift instead: what the head gives the next command once the fingers
    /// have closed on the object, seen with 1 to `eval.history_frames` (the authors' 5) frames.
    #[arg(long, conflicts_with = "from_start")]
    pub at_grip: bool,
    /// Seed of the windows drawn.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N`.
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
    /// Training steps (default: the `[pretrain]` section's, 2,000).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Batch size (default: the `[pretrain]` section's, 32).
    #[arg(long)]
    pub batch: Option<i64>,
    /// Learning rate (default: the `[pretrain]` section's, 1e-3).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Errors are printed every this many steps (default: ten times over the run).
    #[arg(long)]
    pub report_every: Option<u64>,
    /// Seed of the trunk's initial weights and batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N`.
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// `grasp`: the task's grasp position, told the task; `objects`: all four objects' positions, not told it
    /// (default: the `[pretrain]` section's, `objects`).
    #[arg(long, value_parser = parse_localise_target)]
    pub target: Option<LocaliseTarget>,
    /// Augmentation of the training frames.
    #[arg(long, value_enum, default_value_t = AugmentArg::None)]
    pub augment: AugmentArg,
    /// Write the trained trunk here (safetensors with torchvision names), for `model.pretrained_backbone`.
    #[arg(long)]
    pub save_trunk: Option<PathBuf>,
    /// With `--target grasp`: the head also reads where attention from the task over the trunk's feature map
    /// lands (the policy's `model.object_attention`).
    #[arg(long)]
    pub object_attention: bool,
    /// Start the trunk from these weights (a `--save-trunk` file, or a pretrain stage's `trunk.safetensors`)
    /// rather than from scratch.
    #[arg(long)]
    pub init_trunk: Option<PathBuf>,
}

/// Augmentation of the localisation check's training frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AugmentArg {
    /// The frames as collected.
    None,
    /// The policy's default colour jitter, crops and shifts.
    Authors,
    /// The colour jitter alone.
    Colour,
}

fn parse_localise_target(s: &str) -> Result<LocaliseTarget, String> {
    parse_named(s)
}

/// Evaluates `expert`, `random` or a training folder and prints success per task and stage.
pub fn eval(a: EvalArgs) -> Result<()> {
    let mut config = EvalConfig::default();
    config.episodes = a.episodes.unwrap_or(config.episodes);
    config.horizon = a.horizon.unwrap_or(config.horizon);
    config.seed = a.seed.unwrap_or(config.seed);
    config.batch = a.batch.unwrap_or(config.batch);
    config.device = a.device.unwrap_or(config.device);
    config.tasks = a.tasks.unwrap_or(config.tasks);
    config.strips = a.strips;
    config.videos = a.videos;
    config.traces = a.traces;
    if let Some(control) = a.control {
        config.control = match control {
            ControlArg::Policy => Control::Policy,
            ControlArg::ScriptedPoses => Control::ScriptedPoses,
        };
    }
    if let Some(history) = a.history {
        config.history = match history {
            HistoryArg::Reset => HistoryMode::Reset,
            HistoryArg::Sliding => HistoryMode::Sliding,
        };
    }
    if let Some(action) = a.action {
        config.action = match action {
            ActionArg::Sample => ActionChoice::Sample,
            ActionArg::Mode => ActionChoice::Mode,
            ActionArg::Component => ActionChoice::Component,
        };
    }
    let layouts = match a.training_layouts.as_deref() {
        Some([demos, agents]) => Layouts::Training { demos: demos.clone(), agents: agents.clone() },
        Some(other) => bail!("--training-layouts takes DEMOS,AGENTS: two folders, not {}", other.len()),
        None => Layouts::Fresh(training_seeds(&a.exclude_from)?),
    };
    let policy: ActorFiles = Actor::parse(&a.policy, |dir| Weights { at: dir.into(), step: a.checkpoint });
    if let (Some(step), false) = (a.checkpoint, matches!(policy, Actor::Network(_))) {
        bail!("--checkpoint {step} picks a trained policy's weights; the `{}` policy has none", a.policy);
    }
    let world = match (&policy, a.frames.given()) {
        (_, false) => None,
        (Actor::Network(_), true) => {
            bail!("a trained policy is evaluated in the world it was trained in: drop --height, --width and --visuals")
        }
        (_, true) => Some(a.frames.world()),
    };
    let workers = a.workers.unwrap_or_else(default_workers);
    let (_, summary) = run_eval(&policy, world.as_ref(), &config, &layouts, workers, a.out.as_deref())?;
    print_summary(&summary);
    Ok(())
}

/// Prints the open-loop errors of a trained policy per action dimension.
pub fn probe(a: ProbeArgs) -> Result<()> {
    if a.windows == 0 {
        bail!("--windows (0) must be at least 1");
    }
    let trained = load_trained(&a.policy, a.checkpoint, parse_device(&a.device)?)?;
    let data = PairDataset::open(&a.demos, &a.agents, trained.summary.train.val_fraction, None)?;
    let split = if a.train_split { Split::Train } else { Split::Val };
    if a.at_grip {
        let history = EvalConfig::default().history_frames;
        print_grip_probe(&grip_probe(&trained, &data, split, a.windows, history, 16, a.seed)?);
        return Ok(());
    }
    let placement = if a.from_start { Windows::FromStart } else { trained.summary.train.windows() };
    print_probe(&open_loop(&trained, &data, split, placement, a.windows, 16, a.seed)?);
    Ok(())
}

/// `localise`: the localisation check's errors over training, in centimetres.
pub fn localise(a: LocaliseArgs) -> Result<()> {
    let defaults = PretrainConfig::default();
    let pretrain = PretrainConfig {
        target: a.target.unwrap_or(defaults.target),
        steps: a.steps.unwrap_or(defaults.steps),
        batch: a.batch.unwrap_or(defaults.batch),
        lr: a.lr.unwrap_or(defaults.lr),
        augmentation: match a.augment {
            AugmentArg::None => None,
            AugmentArg::Authors => Some(Augmentation::default()),
            AugmentArg::Colour => Some(Augmentation { crop: [0.0; 2], shift: [0.0; 2], ..Augmentation::default() }),
        },
        ..defaults
    };
    pretrain.validate()?;
    let mut config = pretrain.localise((a.backbone_width, a.backbone_stages), None, a.seed, a.save_trunk.clone());
    config.report_every = a.report_every.unwrap_or(config.report_every);
    config.object_attention = a.object_attention;
    config.init_trunk = a.init_trunk.clone();
    let r = oneshot_lab::train::pretrain::localise(&a.agents, &config, parse_device(&a.device)?)?;
    let cm = |e: [f64; 2]| format!("{:5.2} / {:5.2}", 100.0 * e[0], 100.0 * e[1]);
    let (what, baseline) = match pretrain.target {
        LocaliseTarget::Grasp => ("the task's grasp position", "per-task mean position"),
        LocaliseTarget::Objects => ("the four objects' positions", "mean position of each object"),
    };
    println!(
        "{what} from the first frame ({}x{}; {} training, {} held-out layouts), mean absolute error x / y (cm)",
        r.height, r.width, r.train_frames, r.held_out_frames
    );
    println!("{baseline}, held out: {}", cm(r.mean_baseline));
    println!("{:>6}  {:>13}  {:>13}", "step", "training", "held out");
    for e in &r.curve {
        println!("{:>6}  {:>13}  {:>13}", e.step, cm(e.train), cm(e.held_out));
    }
    Ok(())
}
