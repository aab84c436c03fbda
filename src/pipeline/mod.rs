//! The experiment orchestrator: stage graph, content keys, the SQLite results store and execution.
pub mod execute;
pub mod graph;
pub mod key;
pub mod scheduler;
pub mod slurm;
pub mod store;
