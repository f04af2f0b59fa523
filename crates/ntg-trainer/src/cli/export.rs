//! `ntg export`: a trained run's weights as safetensors files that PyTorch
//! loads, with a name map (`names.json`) and the configurations they were
//! built from. The layout is documented in `docs/EXPORT.md`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;

use crate::export::{Layout, NAMES_FILE};

/// Arguments of `ntg export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// The run folder: one `ntg train` wrote, a paper-profile run, or an
    /// entry of the committed weights (`docs/figures/weights/RUN`).
    #[arg(value_name = "RUN")]
    pub run: PathBuf,
    /// The folder to write (must not exist, or be empty): one safetensors
    /// file per network, their configurations, the run's configuration
    /// (`run.json`) and the name map (`names.json`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Replace an earlier export in --out (a folder holding `names.json`);
    /// any other folder is never replaced.
    #[arg(long)]
    pub force: bool,
    /// Write a run folder instead (the model zoo's layout: the run's
    /// `config.json`, `best/` with `model.safetensors` in place of
    /// `model.bpk`), which `ntg eval --run` and `ntg trace` read.
    #[arg(long)]
    pub run_folder: bool,
}

/// Runs `ntg export`.
pub fn run(args: &ExportArgs) -> anyhow::Result<()> {
    let (run, domain) = crate::domain::open_run(&args.run)?;
    check_out(&args.out, args.force, NAMES_FILE, "an earlier export")?;
    let trained = domain.runs().trained(&run)?;
    let epoch = crate::fit::selected_epoch(&run)?.map(|s| s.epoch + 1);

    // Written into a sibling folder, then moved into place: a failure
    // leaves no half-written export at --out.
    let staging = staging_dir(&args.out)?;
    let written = crate::export::write_export(
        &staging,
        &run,
        &trained,
        if args.run_folder {
            Layout::RunFolder
        } else {
            Layout::Flat
        },
        &args.run.display().to_string(),
    );
    let files = match written {
        Ok(files) => files,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    move_into_place(&staging, &args.out)?;

    let tensors: usize = files.iter().map(|f| f.tensors.len()).sum();
    let values: usize = files
        .iter()
        .flat_map(|f| &f.tensors)
        .map(|t| t.shape.iter().product::<usize>())
        .sum();
    let names: Vec<&str> = files.iter().map(|f| f.file.as_str()).collect();
    let from = match epoch {
        Some(e) => format!("epoch {e}, selected on validation tasks"),
        None => "the last checkpoint".to_owned(),
    };
    println!(
        "exported {} ({}, {from}): {tensors} tensors, {values} values, in {} of {}; name map {}",
        run.root().display(),
        trained.method,
        names.join(", "),
        args.out.display(),
        args.out.join(NAMES_FILE).display()
    );
    Ok(())
}

/// Refuses an `--out` that holds anything but an earlier output of the
/// same command (`what`, recognised by its file `marker`) replaced with
/// `--force`.
pub(crate) fn check_out(out: &Path, force: bool, marker: &str, what: &str) -> anyhow::Result<()> {
    if out.exists() && !out.is_dir() {
        anyhow::bail!("--out {}: exists and is not a folder", out.display());
    }
    if !out.is_dir() {
        return Ok(());
    }
    let empty = std::fs::read_dir(out)
        .with_context(|| format!("--out {}", out.display()))?
        .next()
        .is_none();
    if empty {
        return Ok(());
    }
    let earlier = out.join(marker).is_file();
    match (earlier, force) {
        (true, true) => Ok(()),
        (true, false) => anyhow::bail!(
            "--out {}: holds {what}; pass --force to replace it, or choose another folder",
            out.display()
        ),
        (false, _) => anyhow::bail!(
            "--out {}: exists and is not empty (and holds no {} that --force could replace); choose another folder",
            out.display(),
            what.trim_start_matches("an earlier ")
        ),
    }
}

/// Moves the finished `staging` folder to `out`, replacing what
/// [`check_out`] allowed there (nothing, an empty folder, or an earlier
/// output with `--force`).
pub(crate) fn move_into_place(staging: &Path, out: &Path) -> anyhow::Result<()> {
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("replacing {}", out.display()))?;
    }
    std::fs::rename(staging, out)
        .with_context(|| format!("moving the output into {}", out.display()))
}

/// A new folder beside `out` to write the output into.
pub(crate) fn staging_dir(out: &Path) -> anyhow::Result<PathBuf> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).with_context(|| format!("creating {}", parent.display()))?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "export".to_owned());
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    if staging.exists() {
        std::fs::remove_dir_all(&staging)
            .with_context(|| format!("removing {}", staging.display()))?;
    }
    std::fs::create_dir(&staging).with_context(|| format!("creating {}", staging.display()))?;
    Ok(staging)
}
