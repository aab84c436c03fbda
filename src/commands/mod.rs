//! The command-line tools, one module each.
pub mod bench;
pub mod bench_world;
pub mod contact_sheet;
pub mod eval;
pub mod expert_check;
pub mod inspect;
pub mod orchestrate;
