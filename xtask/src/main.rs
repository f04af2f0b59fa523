//! Project automation, run as `cargo xtask <command>`.
//!
//! - `reproduce-figures [--profile smoke|quick|paper] [--jigsaws-root DIR]`: regenerates the
//!   paper's figures by running `ntg reproduce` (crate `ntg-trainer`, release
//!   build); run folders go to `runs/figures/<profile>/` (finished runs are
//!   reused), figures, `results.json` and `REPORT.md` to `docs/figures/<profile>/`
//!   (the paper profile's to `docs/figures/`, with its run records).
//! - `ci`: runs exactly what CI runs (`.ci/run`).
//! - `check-gpu`: clippy and rustdoc with the GPU backends compiled in
//!   (`.ci/check-gpu`), then records the checked inputs in
//!   `.ci/gpu-checked`; CI checks them itself only when those inputs changed.
//! - `soak [--kills N]`: SIGKILLs a small training run N times, resumes it
//!   to the end and checks it ends exactly as an uninterrupted run
//!   (see `soak.rs`).
//! - `slurm-check`: the smoke profile as Slurm job arrays on a one-node
//!   cluster it starts on localhost, one task requeued mid-run, compared
//!   with a local run (see `slurm_check.rs`).
//! - `bench [--threads N] [--quick] [--repeats R] [--out FILE]`: runs the
//!   burn benchmarks and the PyTorch twin (`crates/ntg-model/benches/pytorch/twin.py`,
//!   with `NTG_PYTHON`, default `python3`) in one go, N threads on both sides
//!   (default 2: `RAYON_NUM_THREADS` for burn's `flex`, `torch.set_num_threads`),
//!   and prints one table of medians and burn/PyTorch ratios: the full
//!   model's state training step (batch 32), stage A's frame encoder step
//!   (64 frames), the demo interpreter's and the GCN's training steps, one
//!   policy step at rollout, and expert demos generated per second (no
//!   PyTorch counterpart). Also written as JSON (`target/bench/bench.json`).
//!   Without torch the PyTorch column says so and the command still
//!   succeeds; `--quick` is a smoke check (see `bench.rs`).
//!
//! xtask stays light (clap, anyhow, serde_json): it drives the `ntg` binary and cargo
//! as subprocesses instead of linking the networks, so it builds in seconds.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};

mod bench;
mod slurm_check;
mod soak;

#[derive(Debug, Parser)]
#[command(name = "cargo xtask", about = "ntg-rs project automation")]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Debug, Subcommand)]
enum Task {
    /// Regenerate the paper's figures, their numbers (results.json) and the
    /// report under `docs/figures/<profile>/` (paper: `docs/figures/`).
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
    /// Clippy and rustdoc with the GPU backends (features wgpu and cuda),
    /// then record what was checked in .ci/gpu-checked (commit it: CI
    /// skips these features while the lock file, the manifests and the
    /// code naming a backend are unchanged; see .ci/gpu-inputs).
    CheckGpu,
    /// Kill a small training run again and again (SIGKILL), resume it to
    /// the end, and check it ends bit for bit where an uninterrupted run
    /// ends, with no stray files.
    Soak {
        /// How many kills.
        #[arg(long, default_value_t = 50)]
        kills: usize,
        /// Seed of the delays before each kill.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Shortest delay before a kill, in seconds.
        #[arg(long, default_value_t = 0.3)]
        min_delay: f64,
        /// Longest delay before a kill, in seconds.
        #[arg(long, default_value_t = 0.9)]
        max_delay: f64,
        /// Soak the release build of ntg (default: the dev build).
        #[arg(long)]
        release: bool,
        /// Soak this ntg binary (a relative path is taken from the
        /// workspace root, as `--work` is) instead of building one. CI passes the one
        /// its test step built (`target/debug/ntg`): `cargo build -p
        /// ntg-trainer` resolves the dependencies' features without the
        /// workspace's dev-dependencies, so it rebuilds burn and everything
        /// above it (about 6 minutes of a CI run, measured).
        #[arg(long, conflicts_with = "release")]
        ntg: Option<PathBuf>,
        /// Working folder (replaced).
        #[arg(long, default_value = "target/soak")]
        work: PathBuf,
        /// Soak a job array task instead: `ntg reproduce --profile quick
        /// --array-index I` (the quick profile's NTG on object collection, `thor_all-ntg`),
        /// stopped with SIGTERM and SIGKILL in turn; about 10 kills at most.
        #[arg(long)]
        array: bool,
    },
    /// Run the smoke profile through a real Slurm: install it (apt), start
    /// a one-node cluster on localhost, submit `ntg cluster slurm`'s script,
    /// requeue a task mid-run, and check the report equals a local run's.
    SlurmCheck {
        /// Use this ntg binary (a relative path is taken from the workspace
        /// root) instead of building the release one.
        #[arg(long)]
        ntg: Option<PathBuf>,
        /// Working folder (replaced).
        #[arg(long, default_value = "target/slurm-check")]
        work: PathBuf,
        /// Seconds to wait for the jobs.
        #[arg(long, default_value_t = 900)]
        timeout: u64,
    },
    /// Time burn (flex) against the PyTorch twin, same batches and thread
    /// count, and print one table of medians and ratios.
    Bench {
        /// Threads on both sides (burn: RAYON_NUM_THREADS; PyTorch:
        /// torch.set_num_threads).
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..))]
        threads: u16,
        /// A smoke check: 3 repeats per row after 1 warm-up call.
        #[arg(long)]
        quick: bool,
        /// Timed repeats per training row (default 20, or 3 with --quick;
        /// the policy step runs max(10x, 100)).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
        repeats: Option<u32>,
        /// Where to write the table as JSON (default:
        /// target/bench/bench.json in the workspace).
        #[arg(long)]
        out: Option<PathBuf>,
    },
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
        .args(["--runs", "runs/figures"])
        .args(&extra)
        .current_dir(&root)
        .status()
        .context("could not start cargo")?;
    if !status.success() {
        bail!("ntg reproduce failed ({status})");
    }
    let out = if profile == "paper" {
        "docs/figures/".to_owned()
    } else {
        format!("docs/figures/{profile}/")
    };
    println!("figures, results.json and REPORT.md are in {out}");
    Ok(())
}

/// Runs the bash script `.ci/<name>` from the workspace root.
fn ci_script(name: &str) -> anyhow::Result<()> {
    let root = workspace_root();
    let script = Path::new(".ci").join(name);
    let status = Command::new("bash")
        .arg(&script)
        .current_dir(&root)
        .status()
        .with_context(|| format!("could not start bash {}", script.display()))?;
    if !status.success() {
        bail!("{} failed ({status})", script.display());
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
        Task::Ci => ci_script("run"),
        Task::CheckGpu => ci_script("check-gpu"),
        Task::Bench {
            threads,
            quick,
            repeats,
            out,
        } => {
            let root = workspace_root();
            let out = match out {
                // Relative to where the user ran the command.
                Some(p) => std::path::absolute(&p),
                None => Ok(root.join("target/bench/bench.json")),
            };
            out.context("resolving --out").and_then(|out| {
                bench::run(
                    &root,
                    &bench::Bench {
                        threads: usize::from(threads),
                        quick,
                        repeats: repeats.map_or(if quick { 3 } else { 20 }, |r| r as usize),
                        warmup: if quick { 1 } else { 3 },
                        out,
                    },
                )
            })
        }
        Task::SlurmCheck { ntg, work, timeout } => slurm_check::check(
            &workspace_root(),
            &slurm_check::SlurmCheck {
                ntg,
                work,
                timeout: std::time::Duration::from_secs(timeout),
            },
        ),
        Task::Soak {
            kills,
            seed,
            min_delay,
            max_delay,
            release,
            ntg,
            work,
            array,
        } => {
            if !(min_delay.is_finite()
                && max_delay.is_finite()
                && 0.0 <= min_delay
                && min_delay <= max_delay)
            {
                eprintln!("error: --min-delay and --max-delay: need 0 <= min <= max seconds");
                return std::process::ExitCode::FAILURE;
            }
            let root = workspace_root();
            soak::run(
                &root,
                &root.join(work),
                &soak::Soak {
                    kills,
                    seed,
                    min_delay: std::time::Duration::from_secs_f64(min_delay),
                    max_delay: std::time::Duration::from_secs_f64(max_delay),
                    release,
                    ntg: ntg.map(|path| root.join(path)),
                    array,
                },
            )
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
