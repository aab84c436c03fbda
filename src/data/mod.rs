//! Datasets: the trajectory file format, collection, and (for training) pair sampling and augmentation.
pub mod collect;
pub mod manifest;
pub mod trajectory;
