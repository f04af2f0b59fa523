//! Project automation, run as `cargo xtask <command>`.
//!
//! - `reproduce-figures [--profile smoke|quick|paper] [--jigsaws-root DIR]`: regenerates the
//!   paper's figures by running `ntg reproduce` (crate `ntg-trainer`, release
//!   build); run folders go to `runs/figures/<profile>/` (finished runs are
//!   reused), figures, `results.json` and `REPORT.md` to `docs/figures/`.
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
        /// Run fig. "jigsaws" on a real JIGSAWS copy instead of the
        /// synthetic stand-in.
        #[arg(long)]
        jigsaws_root: Option<PathBuf>,
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

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}

fn reproduce_figures(profile: Profile, jigsaws_root: Option<PathBuf>) -> anyhow::Result<()> {
    let root = workspace_root();
    let profile = match profile {
        Profile::Smoke => "smoke",
        Profile::Quick => "quick",
        Profile::Paper => "paper",
    };
    println!("reproduce-figures (profile: {profile}): building the ntg binary (release)");
    let mut extra = Vec::new();
    if let Some(dir) = jigsaws_root {
        // Relative to where the user ran the command, not the workspace.
        let dir =
            std::path::absolute(&dir).with_context(|| format!("resolving {}", dir.display()))?;
        extra.push("--jigsaws-root".into());
        extra.push(dir.into_os_string());
    }
    let status = Command::new(env!("CARGO"))
        .args([
            "run",
            "--release",
            "--quiet",
            "-p",
            "ntg-trainer",
            "--bin",
            "ntg",
            "--",
        ])
        .args(["reproduce", "--profile", profile])
        .args(["--runs", "runs/figures", "--out", "docs/figures"])
        .args(&extra)
        .current_dir(&root)
        .status()
        .context("could not start cargo")?;
    if !status.success() {
        bail!("ntg reproduce failed ({status})");
    }
    println!("figures, results.json and REPORT.md are in docs/figures/");
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
        Task::ReproduceFigures {
            profile,
            jigsaws_root,
        } => reproduce_figures(profile, jigsaws_root),
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
