//! `train`: a policy on a demonstrator and an agent collection.
use anyhow::Result;
use oneshot_lab::config::CellConfig;
use oneshot_lab::train::{TrainRun, train as run};
use std::path::PathBuf;

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
    /// Training steps (default: the configuration's train.steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Samples per step (default: train.batch_size).
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N` (default: train.device).
    #[arg(long)]
    pub device: Option<String>,
}

/// Trains into the output folder (resuming from its latest checkpoint) and prints the summary.
pub fn train(a: TrainArgs) -> Result<()> {
    let mut c = match &a.config {
        Some(path) => CellConfig::load(path)?,
        None => CellConfig::default(),
    };
    if c.pretrain.is_some() {
        anyhow::bail!(
            "{}: [pretrain] is a stage of experiment files (`run`); for `train`, make the trunk with `localise \
             --save-trunk` and name it in model.pretrained_backbone",
            a.config.as_ref().map_or_else(String::new, |p| p.display().to_string())
        );
    }
    c.train.steps = a.steps.unwrap_or(c.train.steps);
    c.train.batch_size = a.batch_size.unwrap_or(c.train.batch_size);
    c.train.device = a.device.unwrap_or(c.train.device);
    let paths = TrainRun { demo_dir: &a.demos, agent_dir: &a.agents, per_task: None, out: &a.out, progress: true };
    let s = run(&c.model, &c.train, &paths)?;
    println!(
        "trained {} steps in {:.0} s ({} parameters): validation BC {:.3} -> {:.3}; weights in {}",
        s.steps,
        s.seconds,
        s.parameters,
        s.first_val_bc,
        s.final_val_bc,
        a.out.display()
    );
    Ok(())
}
