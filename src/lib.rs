//! oneshot-lab: a reproduction of "Transformers for One-Shot Visual Imitation" (Dasari & Gupta, CoRL 2020).
pub mod commands;
pub mod sim;
