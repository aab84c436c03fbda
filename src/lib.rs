//! oneshot-lab: a reproduction of "Transformers for One-Shot Visual Imitation" (Dasari & Gupta, CoRL 2020).
pub mod commands;
pub mod config;
pub mod data;
pub mod eval;
pub mod model;
pub mod pipeline;
pub mod report;
pub mod seeds;
pub mod sim;
pub mod train;
