//! Project automation, run as `cargo xtask <command>`.
//!
//! - `reproduce-figures [--profile smoke|quick|paper]`: regenerates the
//!   paper's figures through the `ntg` binary (crate `ntg-trainer`).
//! - `ci`: runs exactly what CI runs (`.ci/run`).
//!
//! xtask stays light (clap + anyhow): it drives the `ntg` binary and cargo
//! as subprocesses instead of linking the networks, so it builds in seconds.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Debug, Parser)]
#[command(name = "cargo xtask", about = "ntg-rs project automation")]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Debug, Subcommand)]
enum Task {
    /// Regenerate the paper's figures, their numbers (results.json) and the
    /// report under docs/figures/.
    ReproduceFigures {
        /// How much compute to spend.
        #[arg(long, value_enum, default_value_t = Profile::Quick)]
        profile: Profile,
    },
    /// Run what CI runs: formatting, clippy, the test suite (see .ci/run).
    Ci,
}

/// Experiment scale (see docs/ARCHITECTURE.md and the design's EXPERIMENTS.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Profile {
    /// Seconds per figure: for tests and CI.
    Smoke,
    /// Every figure at reduced scale, minutes on 2 CPU cores (the default).
    Quick,
    /// The paper's scale: hours; faster on a GPU backend.
    Paper,
}

/// The paper's figures and whether this checkout can make them yet.
const FIGURES: &[(&str, &str, Option<&str>)] = &[
    (
        "ntp_exp",
        "block stacking: success vs. number of training tasks (state, video)",
        Some("needs the trainer (ntg train/eval), env-blocks and ntg-model"),
    ),
    (
        "ablation",
        "block stacking / object sorting ablations",
        Some("needs the trainer and the ablation configs"),
    ),
    (
        "thor_all",
        "object collection: success vs. number of objects, NTG vs. Flat Policy",
        Some("needs env-collect, the Flat Policy baseline and the trainer"),
    ),
    (
        "jigsaws",
        "JIGSAWS Needle Passing NLL: uniform vs. no graph vs. NTG",
        Some("needs env-jigsaws and the trainer"),
    ),
];

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}

fn reproduce_figures(profile: Profile) -> anyhow::Result<()> {
    println!("reproduce-figures (profile: {profile:?})");
    let mut made = 0;
    for (name, what, missing) in FIGURES {
        match missing {
            None => made += 1,
            Some(reason) => println!("  - {name}: {what}\n      not reproducible yet: {reason}"),
        }
    }
    if made == 0 {
        println!(
            "\nThis checkout cannot make any of the paper's figures yet; nothing was written.\n\
             What works today: the ctg-graph core and `ntg graph` (try\n  \
             cargo run -p ntg-trainer --bin ntg -- graph --demo \"pick place\" --demo \"pick pick place\")."
        );
    }
    Ok(())
}

fn ci() -> anyhow::Result<()> {
    let root = workspace_root();
    let status = Command::new("bash")
        .arg(root.join(".ci/run"))
        .current_dir(&root)
        .status()
        .context("could not start bash .ci/run")?;
    if !status.success() {
        bail!(".ci/run failed ({status})");
    }
    Ok(())
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Task::ReproduceFigures { profile } => reproduce_figures(profile),
        Task::Ci => ci(),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
