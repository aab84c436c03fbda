//! The command-line layer, private to the binary: arguments, and one handler per command that calls the library
//! and prints.
pub mod args;
pub mod bench;
pub mod bench_world;
pub mod eval;
pub mod inspect;
pub mod orchestrate;
pub mod train;
pub mod world;

/// Worker threads when none are asked for: the machine's cores.
pub fn default_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
