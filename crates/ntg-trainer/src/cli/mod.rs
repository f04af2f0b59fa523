//! The `ntg` command line: argument parsing (clap) and one module per
//! subcommand family.
//!
//! Every subcommand returns `anyhow::Result`; [`main`] prints an error as one
//! line (`error: ...`, causes joined with `: `) and exits with status 1. A
//! usage error is clap's (the error, a "did you mean" tip, the usage line)
//! with status 2; bare `ntg` prints the help with the command list.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod blocks;
pub mod carry;
pub mod cluster;
pub mod collect;
pub mod export;
pub mod graph;
pub mod jigsaws;
pub mod plot;
pub mod trace;
pub mod train;

/// Neural Task Graphs: one-shot visual imitation from a single demonstration.
#[derive(Debug, Parser)]
#[command(name = "ntg", version, long_about = None)]
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
    Train(Box<train::TrainArgs>),
    /// Evaluate a trained run on unseen tasks.
    Eval(train::EvalArgs),
    /// Execute one unseen test task with a trained run and write the trace:
    /// frames, the CTG (DOT and SVG), and per step the localised node and
    /// chosen edge.
    Trace(trace::TraceArgs),
    /// Write a trained run's weights as safetensors files that PyTorch
    /// loads, with their name map (`names.json`) and configurations.
    Export(export::ExportArgs),
    /// Draw a run's training curves (losses, accuracies, validation
    /// scores, its stages' too) as a PNG; `tensorboard --logdir` reads the
    /// same log from the run's event files.
    Plot(plot::PlotArgs),
    /// Reproduce the paper's figures (what `cargo xtask reproduce-figures` runs).
    Reproduce(train::ReproduceArgs),
    /// Save unfinished paper-profile runs into docs/figures/in-progress/
    /// (without their rebuildable caches), to commit them and resume them
    /// on another machine; safe while they train.
    Carry(carry::CarryArgs),
    /// Run a profile on a cluster: a Slurm submit script of job arrays.
    #[command(subcommand)]
    Cluster(cluster::ClusterCommand),
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
    let device = match &cli.command {
        Command::Train(args) => Some(args.flags.device),
        Command::Eval(args) => Some(args.device),
        Command::Reproduce(args) => Some(args.device),
        _ => None,
    };
    if let Some(device) = device {
        crate::spec::select_device(device)?;
    }
    match cli.command {
        Command::Graph(args) => graph::run(&args, &mut std::io::stdout().lock()),
        Command::Train(args) => train::run_train(&args),
        Command::Eval(args) => train::run_eval(&args),
        Command::Trace(args) => trace::run(&args),
        Command::Export(args) => export::run(&args),
        Command::Plot(args) => plot::run(&args),
        Command::Reproduce(args) => train::run_reproduce(&args),
        Command::Carry(args) => carry::run(&args),
        Command::Cluster(cmd) => cluster::run(cmd),
        Command::Blocks(cmd) => blocks::run(cmd),
        Command::Collect(cmd) => collect::run(cmd),
        Command::Jigsaws(cmd) => jigsaws::run(cmd),
    }
}

/// Parses a command line: clap's parsing, then the checks it cannot
/// express (flags of another domain than `--domain`'s are refused, not
/// ignored).
pub fn parse_from<I, T>(args: I) -> Result<Cli, clap::Error>
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    use clap::{CommandFactory, FromArgMatches};
    let mut command = Cli::command();
    let matches = command.try_get_matches_from_mut(args)?;
    let cli = Cli::from_arg_matches(&matches)?;
    if let (Command::Train(train), Some(("train", sub))) = (&cli.command, matches.subcommand())
        && let Some(message) = foreign_domain_flag(&command, sub, train.domain)
    {
        return Err(command.error(clap::error::ErrorKind::ArgumentConflict, message));
    }
    Ok(cli)
}

/// The message for the first `ntg train` flag given on the command line
/// that belongs to another domain than `domain`, if any.
fn foreign_domain_flag(
    command: &clap::Command,
    sub: &clap::ArgMatches,
    domain: crate::domain::DomainId,
) -> Option<String> {
    let train = command.find_subcommand("train")?;
    crate::domain::DomainId::ALL
        .iter()
        .filter(|&&other| other != domain)
        .find_map(|&other| {
            let id = other.flags_group()?;
            let group = train.get_groups().find(|g| g.get_id() == &id)?;
            let arg = group.get_args().find(|a| {
                sub.value_source(a.as_str()) == Some(clap::parser::ValueSource::CommandLine)
            })?;
            let flag = train
                .get_arguments()
                .find(|x| x.get_id() == arg)
                .and_then(|x| x.get_long())
                .unwrap_or(arg.as_str());
            Some(format!(
                "--{flag} is a flag of --domain {}; this run is --domain {}",
                other.name(),
                domain.name()
            ))
        })
}

/// Entry point of the `ntg` binary: parse, run, and report errors on one line.
pub fn main() -> ExitCode {
    let cli = match parse_from(std::env::args_os()) {
        Ok(cli) => cli,
        Err(err) if !err.use_stderr() => {
            // --help / --version: print as clap formats it.
            let _ = err.print();
            return ExitCode::SUCCESS;
        }
        Err(err) => {
            // Usage errors as clap writes them: the error, a "did you
            // mean" tip where one fits, the usage line and where to find
            // more; bare `ntg` (or a family without its subcommand) gets
            // the help with the command list.
            eprint!("{}", usage_error(&err));
            return ExitCode::from(2);
        }
    };
    if let Some(hint) = resume_hint(&cli.command) {
        // Training survives a kill at any moment (checkpoints and records
        // are replaced whole), so Ctrl-C, SIGTERM (Slurm's preemption and
        // time-limit signal) and SIGHUP end the process at once, saying how
        // to go on: a requeued job array task resumes exactly.
        let installed = ctrlc::set_handler(move || {
            eprintln!("\ninterrupted: {hint}");
            std::process::exit(130);
        });
        if let Err(e) = installed {
            eprintln!("warning: Ctrl-C will not print how to resume ({e})");
        }
    }
    // rayon's global pool, its threads pinned to cores when it takes the
    // whole machine (see `ntg_model::init_thread_pool`).
    ntg_model::init_thread_pool();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", error_chain(&err));
            ExitCode::FAILURE
        }
    }
}

/// What to tell a user who stops `command` with Ctrl-C: how to resume a
/// training command (`None` for the others, which redo their work).
fn resume_hint(command: &Command) -> Option<String> {
    match command {
        Command::Train(args) => {
            let mut words: Vec<String> = std::env::args().skip(1).collect();
            if !args.flags.resume {
                words.insert(1, "--resume".into());
            }
            let quoted: Vec<String> = words.iter().map(|w| shell_word(w)).collect();
            Some(format!(
                "{} keeps every finished epoch; `ntg {}` continues from the last one",
                args.flags.out.display(),
                quoted.join(" ")
            ))
        }
        Command::Reproduce(_) => Some(
            "finished runs are kept; the same command again reuses them and resumes the others where they stopped".into(),
        ),
        _ => None,
    }
}

/// `word` as a shell reads it back: quoted when it holds anything but
/// letters, digits and `-_./=,:`.
fn shell_word(word: &str) -> String {
    let plain = !word.is_empty()
        && word
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=,:".contains(c));
    if plain {
        word.to_owned()
    } else {
        format!("'{}'", word.replace('\'', "'\\''"))
    }
}

/// The error and its causes joined by ": ", leaving out a cause that the
/// message before it already shows (errors that print their source, such
/// as `"{path}: {source}"`, would otherwise show it twice).
pub fn error_chain(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let cause = cause.to_string();
        if text.is_empty() {
            text = cause;
        } else if !text.ends_with(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}

/// What `ntg` prints for a usage error: clap's rendering (error, tip,
/// usage line), ending in one newline.
fn usage_error(err: &clap::Error) -> String {
    let text = err.render().to_string();
    format!("{}\n", text.trim_end())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_the_message_already_shows_is_printed_once() {
        let io = std::io::Error::new(std::io::ErrorKind::IsADirectory, "Is a directory");
        let err = anyhow::Error::new(env_blocks::BlocksError::Io {
            path: "/tmp".into(),
            source: io,
        });
        assert_eq!(error_chain(&err), "/tmp: Is a directory");
        let err = anyhow::anyhow!("inner").context("outer");
        assert_eq!(error_chain(&err), "outer: inner");
    }

    #[test]
    fn usage_errors_suggest_the_flag_meant_and_show_the_usage_line() {
        let err = parse_from(["ntg", "train", "--out", "r", "--train-task", "5"]).unwrap_err();
        let text = usage_error(&err);
        assert!(
            text.starts_with("error: unexpected argument '--train-task'"),
            "{text}"
        );
        assert!(
            text.contains("--train-tasks") && text.contains("Usage: ntg train"),
            "{text}"
        );
        let err = parse_from(["ntg", "eval", "--runs", "r"]).unwrap_err();
        let text = usage_error(&err);
        assert!(
            text.contains("'--run'") && text.contains("Usage: ntg eval"),
            "{text}"
        );
        let err = parse_from(["ntg", "train"]).unwrap_err();
        let text = usage_error(&err);
        assert!(
            text.starts_with("error: the following required arguments were not provided:")
                && text.contains("--out"),
            "{text}"
        );
        // Bare `ntg`: the help, with every command.
        let err = parse_from(["ntg"]).unwrap_err();
        let text = usage_error(&err);
        for command in ["train", "eval", "export", "trace", "reproduce"] {
            assert!(text.contains(&format!("  {command}")), "{text}");
        }
    }

    #[test]
    fn flags_of_another_domain_are_refused_not_ignored() {
        let err = parse_from(["ntg", "train", "--out", "r", "--learn-end"]).unwrap_err();
        let line = usage_error(&err);
        assert!(
            line.contains("--learn-end is a flag of --domain collect; this run is --domain blocks"),
            "{line}"
        );
        let err = parse_from([
            "ntg",
            "train",
            "--domain",
            "collect",
            "--out",
            "r",
            "--pairwise",
        ])
        .unwrap_err()
        .render()
        .to_string();
        assert!(
            err.contains("--pairwise is a flag of --domain blocks"),
            "{err}"
        );
        // A domain's own flags, and flags left at their defaults, pass.
        parse_from([
            "ntg",
            "train",
            "--domain",
            "collect",
            "--out",
            "r",
            "--learn-end",
        ])
        .unwrap();
        parse_from(["ntg", "train", "--out", "r", "--pairwise"]).unwrap();
        parse_from(["ntg", "eval", "--run", "r"]).unwrap();
    }
}
