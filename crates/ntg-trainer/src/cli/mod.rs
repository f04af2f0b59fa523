//! The `ntg` command line: argument parsing (clap) and one module per
//! subcommand family.
//!
//! Every subcommand returns `anyhow::Result`; [`main`] prints an error as one
//! line (`error: ...`, causes joined with `: `) and exits with status 1.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod blocks;
pub mod collect;
pub mod graph;
pub mod jigsaws;
pub mod trace;
pub mod train;

/// Neural Task Graphs: one-shot visual imitation from a single demonstration.
#[derive(Debug, Parser)]
#[command(name = "ntg", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands of `ntg`.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build the conjugate task graph (union of paths) of demonstrated action
    /// sequences and print it.
    Graph(graph::GraphArgs),
    /// Train NTG on seen tasks into a run folder.
    Train(train::TrainArgs),
    /// Evaluate a trained run on unseen tasks.
    Eval(train::EvalArgs),
    /// Execute one unseen test task with a trained run and write the trace:
    /// frames, the CTG (DOT and SVG), and per step the localised node and
    /// chosen edge.
    Trace(trace::TraceArgs),
    /// Reproduce the paper's figures (what `cargo xtask reproduce-figures` runs).
    Reproduce(train::ReproduceArgs),
    /// Block stacking and object sorting: task sets and demonstrations.
    #[command(subcommand)]
    Blocks(blocks::BlocksCommand),
    /// Object collection: demonstrations.
    #[command(subcommand)]
    Collect(collect::CollectCommand),
    /// The JIGSAWS surgical dataset: synthetic data and statistics.
    #[command(subcommand)]
    Jigsaws(jigsaws::JigsawsCommand),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Graph(args) => graph::run(&args, &mut std::io::stdout().lock()),
        Command::Train(args) => train::run_train(&args),
        Command::Eval(args) => train::run_eval(&args),
        Command::Trace(args) => trace::run(&args),
        Command::Reproduce(args) => train::run_reproduce(&args),
        Command::Blocks(cmd) => blocks::run(cmd),
        Command::Collect(cmd) => collect::run(cmd),
        Command::Jigsaws(cmd) => jigsaws::run(cmd),
    }
}

/// Entry point of the `ntg` binary: parse, run, and report errors on one line.
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) if !err.use_stderr() => {
            // --help / --version: print as clap formats it.
            let _ = err.print();
            return ExitCode::SUCCESS;
        }
        Err(err) => {
            // Usage errors on one line (clap's first line), then a hint.
            let rendered = err.render().to_string();
            let first = rendered
                .lines()
                .next()
                .unwrap_or("error: invalid arguments");
            let hint = rendered
                .lines()
                .find(|l| l.trim_start().starts_with("[possible values"))
                .map(|l| format!(" {}", l.trim()))
                .unwrap_or_default();
            eprintln!("{first}{hint}");
            return ExitCode::from(2);
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
