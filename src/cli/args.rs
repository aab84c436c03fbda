//! The command tree: every command and the module of its handler, where its arguments are defined. Options that
//! have a configuration counterpart default to the configuration's default (they are `Option`s, filled in from the
//! configuration structs), so no default is written twice.
use super::bench::{BenchEvalArgs, BenchLoaderArgs, BenchPlanArgs, BenchTrainArgs};
use super::bench_world::BenchWorldArgs;
use super::config::ConfigArgs;
use super::diff::DiffArgs;
use super::eval::{EvalArgs, LocaliseArgs, ProbeArgs};
use super::inspect::{GcArgs, QueryArgs, ReportArgs, StatusArgs, WhyArgs};
use super::orchestrate::{CancelArgs, PlanArgs, RunArgs, RunStageArgs};
use super::reference::{CompletionsArgs, ReferenceArgs};
use super::train::TrainArgs;
use super::world::{CollectArgs, ContactSheetArgs, ExpertCheckArgs};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "oneshot-lab", version, about = "Transformers for One-Shot Visual Imitation, reproduced")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The commands.
#[derive(Subcommand)]
pub enum Command {
    /// Scripted-expert success per task and stage.
    ExpertCheck(ExpertCheckArgs),
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
    /// The resolved configuration of an experiment file or of one of its cells, with the values that differ
    /// from the paper's defaults marked.
    Config(ConfigArgs),
    /// Why a stage would run: its inputs against the nearest cached stage of its kind.
    Why(WhyArgs),
    /// Two stages or two cells side by side: the inputs that differ and the metrics each recorded.
    Diff(DiffArgs),
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
    /// Benchmarks: the world, training, evaluation, the orchestrator and the data loader.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// A PNG of first frames of several instances for both robots.
    ContactSheet(ContactSheetArgs),
    /// Prints a reference page generated from the code (`config`: every experiment-file key; `cli`: every
    /// command and option), as kept under docs/reference/.
    Reference(ReferenceArgs),
    /// Prints a shell completion script (commands, options and their fixed values), e.g. `oneshot-lab
    /// completions bash > ~/.local/share/bash-completion/completions/oneshot-lab`.
    Completions(CompletionsArgs),
}

/// The benchmarks of `bench <what>`.
#[derive(Subcommand)]
pub enum BenchCommand {
    /// Throughput of expert episodes beside a bare MuJoCo step + render loop.
    World(BenchWorldArgs),
    /// Training steps/s and peak memory of a configuration, beside its ResNet-18 trunk alone.
    Train(BenchTrainArgs),
    /// Evaluation rollouts/s on CPU for the small network and the random policy.
    Eval(BenchEvalArgs),
    /// Time of `plan` and of a fully cached `run` over a large grid.
    Plan(BenchPlanArgs),
    /// Training samples/s the data path builds from two collections and copies to the device.
    Loader(BenchLoaderArgs),
}
