//! `ntg cluster slurm`: a profile as Slurm job arrays (see
//! [`crate::slurm`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};

/// Subcommands of `ntg cluster`.
#[derive(Debug, Subcommand)]
pub enum ClusterCommand {
    /// Write a Slurm submit script that runs a profile as job arrays (one
    /// task a run, requeued on preemption) and then writes its report.
    Slurm(SlurmArgs),
}

/// Arguments of `ntg cluster slurm`.
#[derive(Debug, Args)]
pub struct SlurmArgs {
    /// The profile to run.
    #[arg(long, value_enum, default_value_t = crate::spec::Profile::Paper)]
    pub profile: crate::spec::Profile,
    /// The runs folder every task trains into (on a file system all nodes
    /// share), as `ntg reproduce --runs`.
    #[arg(long, value_name = "DIR")]
    pub runs: PathBuf,
    /// Where the report job writes figures, results.json and REPORT.md, as
    /// `ntg reproduce --out` (default: its default for the profile).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Experiment files instead of the built-in ones, as `ntg reproduce
    /// --experiments`.
    #[arg(long, value_name = "DIR")]
    pub experiments: Option<PathBuf>,
    /// The ntg binary the tasks run (default: this one).
    #[arg(long, value_name = "PATH")]
    pub ntg: Option<PathBuf>,
    /// Write the script to FILE instead of stdout (refused if FILE exists,
    /// unless --force).
    #[arg(long, value_name = "FILE")]
    pub script: Option<PathBuf>,
    /// Replace an existing --script FILE.
    #[arg(long, requires = "script")]
    pub force: bool,
}

/// Runs an `ntg cluster` subcommand.
pub fn run(command: ClusterCommand) -> anyhow::Result<()> {
    match command {
        ClusterCommand::Slurm(args) => run_slurm(&args),
    }
}

fn absolute(path: &Path, flag: &str) -> anyhow::Result<String> {
    let path = std::path::absolute(path).with_context(|| format!("{flag} {}", path.display()))?;
    path.to_str()
        .map(str::to_owned)
        .with_context(|| format!("{flag} {}: not valid UTF-8", path.display()))
}

fn run_slurm(args: &SlurmArgs) -> anyhow::Result<()> {
    let experiments = match &args.experiments {
        Some(dir) => crate::experiment::Source::Dir(dir),
        None => crate::experiment::Source::BuiltIn,
    };
    let list = crate::reproduce::run_list(args.profile, experiments)?;
    let profile = args.profile.name().to_owned();
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| crate::reproduce::default_out(args.profile));
    let ntg = match &args.ntg {
        Some(path) => path.clone(),
        None => std::env::current_exe().context("finding this ntg binary (give --ntg)")?,
    };
    let settings = crate::slurm::ScriptSettings {
        profile,
        ntg: absolute(&ntg, "--ntg")?,
        runs: absolute(&args.runs, "--runs")?,
        out: absolute(&out, "--out")?,
        experiments: args
            .experiments
            .as_deref()
            .map(|dir| absolute(dir, "--experiments"))
            .transpose()?,
    };
    let script = crate::slurm::submit_script(&list, &settings);
    match &args.script {
        None => print!("{script}"),
        Some(path) => {
            if path.exists() && !args.force {
                anyhow::bail!(
                    "--script {}: exists; pass --force to replace it, or choose another file",
                    path.display()
                );
            }
            std::fs::write(path, &script).with_context(|| format!("writing {}", path.display()))?;
            let arrays = crate::slurm::arrays(&list).len();
            println!(
                "wrote {}: {} runs in {arrays} arrays and a report job; submit with `bash {}`",
                path.display(),
                list.len(),
                path.display()
            );
        }
    }
    Ok(())
}
