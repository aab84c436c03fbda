//! The integration tests, in one binary so that libtorch and MuJoCo are linked once: one module per area, and
//! the helpers they share.
mod cli;
mod daml;
mod data;
mod eval;
mod experiments;
mod helpers;
mod layers;
mod learning;
mod model;
mod pipeline;
mod precision;
mod protocol;
mod slurm;
mod smoke;
mod train;
mod world;
