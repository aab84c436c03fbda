//! The policy network in libtorch: trunk, attention, embeddings and heads.
pub mod attention;
pub mod config;
pub mod heads;
pub mod lstm;
pub mod mixture;
pub mod policy;
pub mod resnet;
pub mod transformer;
