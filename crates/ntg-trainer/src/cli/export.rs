//! `ntg export`: a trained run's weights as safetensors files that PyTorch
//! loads, with a name map (`names.json`) and the configurations they were
//! built from. The layout is documented in `docs/EXPORT.md`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use serde::Serialize;

use crate::method::ExportedFile;

/// The `format` of `names.json`.
pub const EXPORT_FORMAT: &str = "ntg-export/1";
/// The name map's file name in an export folder.
pub const NAMES_FILE: &str = "names.json";
/// The run configuration's copy in an export folder.
pub const RUN_CONFIG_FILE: &str = "run.json";

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
}

/// `names.json`: what an export folder holds.
#[derive(Debug, Serialize)]
struct NameMap<'a> {
    format: &'static str,
    /// The run folder, as given on the command line.
    run: String,
    domain: &'static str,
    method: &'static str,
    /// The model folder of the run the weights come from (`best` or
    /// `checkpoint`).
    source: String,
    /// The epoch validation selected (from 1), if it selected one.
    #[serde(skip_serializing_if = "Option::is_none")]
    epoch: Option<usize>,
    layout: &'static str,
    /// The run configuration's copy.
    run_config: &'static str,
    files: Vec<FileEntry<'a>>,
}

#[derive(Debug, Serialize)]
struct FileEntry<'a> {
    #[serde(flatten)]
    exported: &'a ExportedFile,
    /// The network's configuration, as saved beside its weights.
    config: String,
}

/// What `layout` says in every name map.
const LAYOUT: &str = "PyTorch's: each Linear weight is [out, in] (burn keeps [in, out]; \
    \"transposed\": true marks them); every other tensor as burn keeps it (convolutions \
    [out, in, kh, kw], biases, embedding tables [N, E]). Names are the parameters' paths \
    in the burn module, without enum variant names";

/// Runs `ntg export`.
pub fn run(args: &ExportArgs) -> anyhow::Result<()> {
    let (run, domain) = super::train::open_run(&args.run)?;
    check_out(&args.out, args.force)?;
    let trained = domain.runs().trained(&run)?;
    // Counted from 1, as the training log prints epochs.
    let epoch = crate::fit::selected_epoch(&run)?.map(|s| s.epoch + 1);

    // Written into a sibling folder, then moved into place: a failure
    // leaves no half-written export at --out.
    let staging = staging_dir(&args.out)?;
    let written = write_export(
        &staging,
        &trained,
        &run.config_path(),
        NameMapHead {
            run: args.run.display().to_string(),
            domain: domain.name(),
            epoch,
        },
    );
    let files = match written {
        Ok(files) => files,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    if args.out.exists() {
        // check_out allowed it: empty, or an earlier export with --force.
        std::fs::remove_dir_all(&args.out)
            .with_context(|| format!("replacing {}", args.out.display()))?;
    }
    std::fs::rename(&staging, &args.out)
        .with_context(|| format!("moving the export into {}", args.out.display()))?;

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

/// What the name map says of the run.
struct NameMapHead {
    run: String,
    domain: &'static str,
    epoch: Option<usize>,
}

/// Writes the safetensors files, the configurations and `names.json`
/// into the new folder `dir`.
fn write_export(
    dir: &Path,
    trained: &crate::domain::TrainedRun,
    run_config: &Path,
    head: NameMapHead,
) -> anyhow::Result<Vec<ExportedFile>> {
    let files = trained.model.export_safetensors(dir)?;
    let mut entries = Vec::new();
    for file in &files {
        let stem = file.file.trim_end_matches(".safetensors");
        let config = format!("{stem}.config.json");
        let source = trained.dir.join(&file.folder).join(ntg_model::CONFIG_FILE);
        std::fs::copy(&source, dir.join(&config))
            .with_context(|| format!("copying {}", source.display()))?;
        entries.push(FileEntry {
            exported: file,
            config,
        });
    }
    std::fs::copy(run_config, dir.join(RUN_CONFIG_FILE))
        .with_context(|| format!("copying {}", run_config.display()))?;
    let map = NameMap {
        format: EXPORT_FORMAT,
        run: head.run,
        domain: head.domain,
        method: trained.method,
        source: trained
            .dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        epoch: head.epoch,
        layout: LAYOUT,
        run_config: RUN_CONFIG_FILE,
        files: entries,
    };
    let path = dir.join(NAMES_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(&map)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(files)
}

/// Refuses an `--out` that holds anything but an earlier export replaced
/// with `--force`.
fn check_out(out: &Path, force: bool) -> anyhow::Result<()> {
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
    let earlier_export = out.join(NAMES_FILE).is_file();
    match (earlier_export, force) {
        (true, true) => Ok(()),
        (true, false) => anyhow::bail!(
            "--out {}: holds an earlier export; pass --force to replace it, or choose another folder",
            out.display()
        ),
        (false, _) => anyhow::bail!(
            "--out {}: exists and is not empty (and holds no export that --force could replace); choose another folder",
            out.display()
        ),
    }
}

/// A new folder beside `out` to write the export into.
fn staging_dir(out: &Path) -> anyhow::Result<PathBuf> {
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
