//! oneshot-lab: a reproduction of "Transformers for One-Shot Visual Imitation" (Dasari & Gupta, CoRL 2020).
//! The library holds the domain (world, data, model, training, evaluation), the orchestrator and the reports;
//! the command line (`src/cli`) is private to the binary. ARCHITECTURE.md walks through the layers.
pub mod autocast;
pub mod config;
pub mod data;
pub mod device;
pub mod eval;
pub mod fsio;
pub mod model;
pub mod pipeline;
pub mod progress;
pub mod report;
pub mod seeds;
pub mod sim;
pub mod train;
