//! Datasets: the trajectory file format, collection, and (for training) pair sampling and augmentation.
pub mod augment;
pub mod collect;
pub mod collect_config;
pub mod device_augment;
pub mod frame_cache;
pub mod loader;
pub mod manifest;
pub mod pairs;
pub mod trajectory;
