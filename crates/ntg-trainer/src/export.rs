//! A trained run's weights as safetensors files in PyTorch's layout, with
//! their name map (`names.json`): `ntg export` writes them flat into a
//! folder of the user's ([`Layout::Flat`]); the model zoo
//! (`docs/figures/weights/`, [`crate::carry::keep_selected_weights`]) keeps
//! them in a run folder's own layout ([`Layout::RunFolder`]), so that the
//! entry is a run that `ntg eval` and `ntg trace` read. docs/EXPORT.md
//! documents both.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use crate::domain::TrainedRun;
use crate::method::ExportedFile;
use crate::run_dir::RunDir;

/// The `format` of `names.json`.
pub const EXPORT_FORMAT: &str = "ntg-export/1";
/// The name map's file name.
pub const NAMES_FILE: &str = "names.json";

/// Where the files go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// `ntg export`: `model.safetensors`, `frame_encoder.safetensors`, ...,
    /// each network's configuration as `NAME.config.json`, the run's as
    /// `run.json`.
    Flat,
    /// A model zoo entry: the run's `config.json`, and its model folder
    /// (`best/`, or `checkpoint/` for a run without validation) as the run
    /// keeps it (`selection.json`, each network's `config.json`) with
    /// `model.safetensors` in place of `model.bpk`.
    RunFolder,
}

/// `names.json`: what the folder holds.
#[derive(Debug, Serialize)]
struct NameMap<'a> {
    format: &'static str,
    /// The run folder the weights come from, as given.
    run: String,
    domain: &'static str,
    method: &'static str,
    /// The run's model folder they come from (`best` or `checkpoint`).
    source: String,
    /// The epoch validation selected (from 1), if it selected one.
    #[serde(skip_serializing_if = "Option::is_none")]
    epoch: Option<usize>,
    layout: &'static str,
    /// The run configuration's file.
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

/// Writes the weights of `trained` (the trained model of `run`, whose path
/// the name map gives as `label`) into the new, empty folder `dir` in
/// `layout`, with the configurations and `names.json`. Returns the files
/// written (`file`: their paths in `dir`).
pub fn write_export(
    dir: &Path,
    run: &RunDir,
    trained: &TrainedRun,
    layout: Layout,
    label: &str,
) -> anyhow::Result<Vec<ExportedFile>> {
    let (run_config, staging) = match layout {
        Layout::Flat => ("run.json", dir.to_path_buf()),
        Layout::RunFolder => ("config.json", dir.join(".export")),
    };
    std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
    let mut files = trained.model.export_safetensors(&staging)?;
    let source_folder = trained
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut configs = Vec::new();
    for file in &mut files {
        let from = trained.dir.join(&file.folder);
        let config = match layout {
            Layout::Flat => {
                let stem = file.file.trim_end_matches(".safetensors");
                format!("{stem}.config.json")
            }
            Layout::RunFolder => {
                // The run's own model folder: `best` (with its
                // selection.json) or, for a run that did not validate,
                // `checkpoint`.
                let to = Path::new(&source_folder).join(&file.folder);
                std::fs::create_dir_all(dir.join(&to))?;
                let weights = to.join(ntg_model::export::SAFETENSORS_WEIGHTS_FILE);
                let (written, kept) = (staging.join(&file.file), dir.join(&weights));
                std::fs::rename(&written, &kept)
                    .with_context(|| format!("moving {}", written.display()))?;
                std::fs::rename(sidecar(&written), sidecar(&kept))
                    .with_context(|| format!("moving {}", written.display()))?;
                file.file = slash(&weights);
                // The configuration's checksum travels with it.
                let side = sidecar(&from.join(ntg_model::CONFIG_FILE));
                if side.is_file() {
                    std::fs::copy(&side, sidecar(&dir.join(&to).join(ntg_model::CONFIG_FILE)))
                        .with_context(|| format!("copying {}", side.display()))?;
                }
                slash(&to.join(ntg_model::CONFIG_FILE))
            }
        };
        let source = from.join(ntg_model::CONFIG_FILE);
        std::fs::copy(&source, dir.join(&config))
            .with_context(|| format!("copying {}", source.display()))?;
        configs.push(config);
    }
    if layout == Layout::RunFolder {
        std::fs::remove_dir_all(&staging)?;
        let selection = trained.dir.join("selection.json");
        if selection.is_file() {
            std::fs::copy(&selection, dir.join("best/selection.json"))
                .with_context(|| format!("copying {}", selection.display()))?;
        }
    }
    std::fs::copy(run.config_path(), dir.join(run_config))
        .with_context(|| format!("copying {}", run.config_path().display()))?;
    let map = NameMap {
        format: EXPORT_FORMAT,
        run: label.to_owned(),
        domain: crate::domain::DomainId::of_run(&RunDir::read_json(&run.config_path())?)
            .map_or("", |d| d.name()),
        method: trained.method,
        source: source_folder,
        // Counted from 1, as the training log prints epochs.
        epoch: crate::fit::selected_epoch(run)?.map(|s| s.epoch + 1),
        layout: LAYOUT,
        run_config,
        files: files
            .iter()
            .zip(configs)
            .map(|(exported, config)| FileEntry { exported, config })
            .collect(),
    };
    let path = dir.join(NAMES_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(&map)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(files)
}

/// Writes the selected weights of the paper-profile run folder `run` into
/// the new folder `next` as a model zoo entry ([`Layout::RunFolder`]);
/// what [`crate::carry::keep_selected_weights`] keeps.
pub fn keep_in_zoo(run: &Path, next: &Path) -> anyhow::Result<()> {
    let (dir, domain) = crate::domain::open_run(run)?;
    let trained = domain.runs().trained(&dir)?;
    anyhow::ensure!(
        trained.dir == dir.best_dir(),
        "{}: validation selected no epoch; the model zoo keeps selected weights only",
        run.display()
    );
    let label = run
        .file_name()
        .map(|n| format!("paper-profile run {}", n.to_string_lossy()))
        .unwrap_or_default();
    write_export(next, &dir, &trained, Layout::RunFolder, &label)?;
    Ok(())
}

/// `path` with `.sha256` added (a checksum's sidecar).
fn sidecar(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".sha256");
    name.into()
}

/// A relative path with `/` between its parts, whatever the platform.
fn slash(path: &Path) -> String {
    path.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}
