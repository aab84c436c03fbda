//! The experiment orchestrator: the stage graph and its content keys, the stage kinds, the SQLite results store,
//! and execution (locally or on Slurm) by the scheduler.
pub mod child;
pub mod code;
pub mod events;
pub mod executor;
pub mod gc;
pub mod graph;
pub mod integrity;
pub mod key;
pub mod scheduler;
pub mod selection;
pub mod slurm;
pub mod stages;
pub mod store;

use crate::config::{Experiment, Resolution};
use anyhow::Result;
use graph::Plan;
use std::path::Path;

/// Loads an experiment file (with an optional scale profile and overrides) and expands it into its plan.
pub fn load_plan(file: &Path, resolution: &Resolution) -> Result<(Experiment, Plan)> {
    let experiment = Experiment::load(file, resolution)?;
    let plan = stages::plan(&experiment);
    Ok((experiment, plan))
}
