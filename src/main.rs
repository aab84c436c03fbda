//! The `oneshot-lab` command line: parses the arguments and hands each command to its handler in `cli`.
mod cli;

use clap::{CommandFactory, Parser};
use cli::args::{BenchCommand, Cli, Command};

fn main() {
    // Exit quietly when stdout is closed early (e.g. `oneshot-lab query cells | head`).
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    if let Err(e) = dispatch(Cli::parse().command) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::ExpertCheck(a) => cli::world::expert_check(a),
        Command::Collect(a) => cli::world::collect(a),
        Command::Train(a) => cli::train::train(a),
        Command::Eval(a) => cli::eval::eval(a),
        Command::Probe(a) => cli::eval::probe(a),
        Command::Localise(a) => cli::eval::localise(a),
        Command::Run(a) => cli::orchestrate::run(a),
        Command::RunStage(a) => cli::orchestrate::run_stage(a),
        Command::Plan(a) => cli::orchestrate::plan(a),
        Command::Config(a) => cli::config::config(a),
        Command::Reference(a) => cli::reference::reference(a, Cli::command()),
        Command::Completions(a) => cli::reference::completions(a, Cli::command()),
        Command::Why(a) => cli::inspect::why(a),
        Command::Diff(a) => cli::diff::diff(a),
        Command::Status(a) => cli::inspect::status(a),
        Command::Cancel(a) => cli::orchestrate::cancel(a),
        Command::Query(a) => cli::inspect::query(a),
        Command::Gc(a) => cli::inspect::gc(a),
        Command::Report(a) => cli::inspect::report(a),
        Command::Bench(BenchCommand::World(a)) => cli::bench_world::bench_world(a),
        Command::Bench(BenchCommand::Train(a)) => cli::bench::train(a),
        Command::Bench(BenchCommand::Eval(a)) => cli::bench::eval(a),
        Command::Bench(BenchCommand::Plan(a)) => cli::bench::plan(a),
        Command::Bench(BenchCommand::Loader(a)) => cli::bench::loader(a),
        Command::ContactSheet(a) => cli::world::contact_sheet(a),
    }
}
