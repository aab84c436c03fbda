//! The policy networks in libtorch: shared parts (trunk, attention, embeddings, heads) and the architectures
//! built from them.
pub mod architectures;
pub mod attention;
pub mod batch;
pub mod config;
pub mod heads;
pub mod mixture;
pub mod output;
pub mod policy;
pub mod resnet;
