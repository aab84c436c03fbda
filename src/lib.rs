//! oneshot-lab: a reproduction of "Transformers for One-Shot Visual Imitation" (Dasari & Gupta, CoRL 2020).
pub mod commands;
pub mod data;
pub mod eval;
pub mod model;
pub mod seeds;
pub mod sim;
pub mod train;
