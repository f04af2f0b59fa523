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
            // Usage errors on one line: clap's first paragraph (with the
            // missing flags after "not provided:", or the possible values).
            eprintln!("{}", one_line(&err.render().to_string()));
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

/// Clap's first paragraph of an error message on one line.
fn one_line(rendered: &str) -> String {
    let words: Vec<&str> = rendered
        .lines()
        .take_while(|l| !l.trim().is_empty())
        .map(str::trim)
        .collect();
    if words.is_empty() {
        "error: invalid arguments".to_owned()
    } else {
        words.join(" ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn usage_errors_keep_their_first_paragraph_on_one_line() {
        let err = Cli::try_parse_from(["ntg", "train"]).unwrap_err();
        let line = one_line(&err.render().to_string());
        assert!(
            line.starts_with("error: the following required arguments were not provided:")
                && line.contains("--out"),
            "{line}"
        );
        assert!(!line.contains('\n'));
        let err = Cli::try_parse_from(["ntg", "train", "--out", "r", "--epochs", "x"]).unwrap_err();
        let line = one_line(&err.render().to_string());
        assert!(
            line.contains("--epochs") && !line.contains("Usage"),
            "{line}"
        );
    }
}
