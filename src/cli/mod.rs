//! The command-line layer, private to the binary: the command tree (`args`), the options commands share
//! (`options`), and per group of commands a module with their arguments and handlers, which call the library and
//! print.
pub mod args;
pub mod bench;
pub mod bench_world;
pub mod config;
pub mod diff;
pub mod eval;
pub mod inspect;
pub mod options;
pub mod orchestrate;
pub mod print;
pub mod reference;
pub mod stage_progress;
pub mod train;
pub mod world;

/// Worker threads when none are asked for: the machine's cores.
pub fn default_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
