//! Paper-profile runs carried between machines.
//!
//! A run that takes longer than one sitting is saved, half-trained, into
//! `in-progress/RUN/` beside the run records (`docs/figures/in-progress/`),
//! committed, and resumed from a copy of it on the next machine
//! ([`crate::experiment::Plan`] does that). This module saves one
//! ([`carry_run`], `ntg carry`) and drops it once the run's record has
//! landed ([`discard_carried`]). A carried folder holds what training
//! cannot rebuild (configuration, logs, weights and optimizer state of the
//! last checkpoint and of finished stages, the selected weights); it
//! leaves out what a resumed run rebuilds from its seeds and carried
//! weights ([`rebuildable`]).

use std::fs;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use anyhow::{Context, bail};

use crate::record;
use crate::run_dir::{RunDir, replace_dir};

/// Whether a run-folder entry named `name` is left out of a carried copy:
/// caches a resumed run rebuilds (rendered frames `dataset/`, encoded
/// episodes `ntp_frames*/` and `embeddings*/`, parts of either
/// `*.parts`), the writer's lock, the half-written files of an atomic
/// write (`*.tmp`, `*.next`, `*.old`, `*.partial`), and the starting
/// weights `initial/` (read only by the reduced profiles' untrained
/// scores; a carried paper-profile run does without them).
pub fn rebuildable(name: &str) -> bool {
    name == "dataset"
        || name == "initial"
        || name == "train.lock"
        || name.starts_with("ntp_frames")
        || name.starts_with("embeddings")
        || [".parts", ".tmp", ".next", ".old", ".partial"]
            .iter()
            .any(|suffix| name.ends_with(suffix))
}

/// What one carried file was when it was read: path relative to the run
/// folder, length, modification time.
type Listing = Vec<(PathBuf, u64, SystemTime)>;

/// The files of `root` a carried copy holds, sorted by path.
fn listing(root: &Path) -> anyhow::Result<Listing> {
    fn walk(root: &Path, rel: &Path, out: &mut Listing) -> anyhow::Result<()> {
        let dir = root.join(rel);
        for entry in fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))? {
            let entry = entry?;
            let name = entry.file_name();
            if rebuildable(&name.to_string_lossy()) {
                continue;
            }
            let rel = rel.join(&name);
            let meta = entry.metadata()?;
            if meta.is_dir() {
                walk(root, &rel, out)?;
            } else {
                out.push((rel, meta.len(), meta.modified()?));
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(root, Path::new(""), &mut out)?;
    out.sort();
    Ok(out)
}

/// What [`carry_run`] saved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Carried {
    /// The folder written.
    pub to: PathBuf,
    /// Files in it.
    pub files: usize,
    /// Their total size in bytes.
    pub bytes: u64,
    /// Per checkpoint carried (`checkpoint/progress.json` of the run and
    /// of each stage folder): the folder relative to the run (empty for
    /// the run itself) and its epochs done.
    pub checkpoints: Vec<(PathBuf, usize)>,
}

/// Copies the files of `from` a carried copy holds into `to` (a fresh,
/// empty folder) as one consistent snapshot, also while a training
/// process writes `from`: the files are listed before and after the copy
/// and the copy is redone (after a pause) until nothing changed between
/// the two, so a checkpoint replaced during a copy is never mixed with
/// the one before it.
fn snapshot(from: &Path, to: &Path) -> anyhow::Result<Listing> {
    const ATTEMPTS: usize = 30;
    for _ in 0..ATTEMPTS {
        let before = listing(from)?;
        if to.exists() {
            fs::remove_dir_all(to).with_context(|| format!("removing {}", to.display()))?;
        }
        let copied = before
            .iter()
            .try_for_each(|(rel, _, _)| -> anyhow::Result<()> {
                let target = to.join(rel);
                if let Some(parent) = target.parent() {
                    fs::create_dir_all(parent)?;
                }
                fs::copy(from.join(rel), &target)?;
                Ok(())
            });
        // A file replaced or removed under the copy shows as a failed copy
        // or a changed listing: both are retried.
        if copied.is_ok() && listing(from)? == before {
            return Ok(before);
        }
        std::thread::sleep(Duration::from_secs(2));
    }
    bail!(
        "{} kept changing while it was copied ({ATTEMPTS} attempts): stop its training \
         after a checkpoint, then carry it",
        from.display()
    )
}

/// Saves the paper-profile run `name` (its folder in `runs`) into
/// `in-progress/NAME/` beside `records`, replacing an earlier copy of the
/// same run; refuses a run that is recorded already (finished), a folder
/// restored from a record, and an earlier copy of another configuration
/// (it is not overwritten). The run may be training meanwhile (the
/// copy is redone until no file changed under it).
pub fn carry_run(runs: &Path, records: &Path, name: &str) -> anyhow::Result<Carried> {
    // One plain folder name (a trailing `/` from tab completion would name
    // the record `records/NAME/.json` and pass the check below).
    let name = name.trim_end_matches(['/', std::path::MAIN_SEPARATOR]);
    if name.is_empty()
        || name == "."
        || name == ".."
        || name.contains(['/', std::path::MAIN_SEPARATOR])
    {
        bail!(
            "{name:?} is not a run name: name a run folder of {}",
            runs.display()
        );
    }
    let from = runs.join(name);
    let config_path = from.join("config.json");
    if !config_path.is_file() {
        bail!(
            "{} is not a run folder (no config.json): name a paper-profile run of this runs folder",
            from.display()
        );
    }
    if record::is_restored(&from) {
        bail!(
            "{} was restored from its record: it is finished, nothing to carry",
            from.display()
        );
    }
    let record_path = record::path(records, name);
    if record_path.is_file() {
        bail!(
            "{name} is finished and recorded in {}: nothing to carry",
            record_path.display()
        );
    }
    let to = record::in_progress_dir(records, name);
    let config: serde_json::Value = RunDir::read_json(&config_path)?;
    prepare_copy(&to, &config, || {
        format!(
            "{} holds a run of another configuration than {}: delete it to carry this one",
            to.display(),
            from.display()
        )
    })?;
    let mut copied = Listing::new();
    replace_dir(&to, |next| {
        copied = snapshot(&from, next)?;
        Ok(())
    })?;
    let mut checkpoints = Vec::new();
    for (rel, _, _) in &copied {
        if rel.ends_with("checkpoint/progress.json") {
            let stage = rel
                .parent()
                .and_then(Path::parent)
                .unwrap_or(Path::new(""))
                .to_path_buf();
            let progress: serde_json::Value = RunDir::read_json(&to.join(rel))?;
            let epochs = progress["epochs_done"].as_u64().unwrap_or(0) as usize;
            checkpoints.push((stage, epochs));
        }
    }
    Ok(Carried {
        files: copied.len(),
        bytes: copied.iter().map(|(_, len, _)| len).sum(),
        checkpoints,
        to,
    })
}

/// After the record of run `name` (of configuration `config`) is in
/// `records`: removes its carried copy, if one of that configuration is
/// kept beside them (the record supersedes it). Returns the folder
/// removed.
pub fn discard_carried(
    records: &Path,
    name: &str,
    config: Option<&serde_json::Value>,
) -> anyhow::Result<Option<PathBuf>> {
    let carried = record::in_progress_dir(records, name);
    // A carry killed while it swapped copies is put back in order first.
    crate::run_dir::recover_dir(&carried)?;
    let carried_config = carried.join("config.json");
    if !carried_config.is_file() {
        return Ok(None);
    }
    let theirs: serde_json::Value = RunDir::read_json(&carried_config)?;
    if config != Some(&theirs) {
        return Ok(None);
    }
    fs::remove_dir_all(&carried).with_context(|| format!("removing {}", carried.display()))?;
    Ok(Some(carried))
}

/// Runs of at least this many training tasks keep their selected weights
/// beside their records ([`keep_selected_weights`]): the paper profile's
/// 1000-task runs, whose weights take hours to train again on 2 cores.
pub const KEEP_WEIGHTS_FROM_TASKS: u64 = 1000;

/// Where the selected weights of recorded run `name` are kept:
/// `weights/NAME/` beside the `records` folder.
pub fn weights_dir(records: &Path, name: &str) -> PathBuf {
    records
        .parent()
        .unwrap_or(Path::new("."))
        .join("weights")
        .join(name)
}

/// What [`keep_selected_weights`] kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeptWeights {
    /// The folder written.
    pub to: PathBuf,
    /// Files in it.
    pub files: usize,
    /// Their total size in bytes.
    pub bytes: u64,
}

/// Readies `to` for a copy of a run of `config`: an earlier copy killed
/// while it swapped folders is put back in place (or its new one kept), so
/// that the check sees it, and `to`'s parent is made. A copy of another
/// configuration already in `to` is never overwritten: the error says
/// `conflict()`.
fn prepare_copy(
    to: &Path,
    config: &serde_json::Value,
    conflict: impl FnOnce() -> String,
) -> anyhow::Result<()> {
    crate::run_dir::recover_dir(to)?;
    let earlier = to.join("config.json");
    if earlier.is_file() && RunDir::read_json::<serde_json::Value>(&earlier)? != *config {
        bail!(conflict());
    }
    if let Some(parent) = to.parent() {
        fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    Ok(())
}

/// After run folder `run` (named `name`) is recorded in `records`: when its
/// `config.json` says it trained on at least [`KEEP_WEIGHTS_FROM_TASKS`]
/// tasks (`train_tasks`) and validation selected an epoch (`best/`), has
/// `write(run, folder)` fill a new folder with its selected weights
/// ([`crate::export::keep_in_zoo`] in the paper profile) and puts it in
/// place as [`weights_dir`], replacing an earlier copy of the same
/// configuration (one of another configuration is kept, and this one is
/// not). Otherwise keeps nothing (`None`).
pub fn keep_selected_weights(
    records: &Path,
    name: &str,
    run: &Path,
    write: &dyn Fn(&Path, &Path) -> anyhow::Result<()>,
) -> anyhow::Result<Option<KeptWeights>> {
    let config_path = run.join("config.json");
    let config: serde_json::Value = RunDir::read_json(&config_path)?;
    let tasks = config["train_tasks"].as_u64().unwrap_or(0);
    if tasks < KEEP_WEIGHTS_FROM_TASKS || !run.join("best").is_dir() {
        return Ok(None);
    }
    let to = weights_dir(records, name);
    prepare_copy(&to, &config, || {
        format!(
            "{} holds the weights of another configuration than {}: delete it to keep this run's",
            to.display(),
            run.display()
        )
    })?;
    replace_dir(&to, |next| {
        fs::create_dir_all(next)?;
        write(run, next)?;
        let written: serde_json::Value = RunDir::read_json(&next.join("config.json"))
            .context("the kept weights' folder needs the run's config.json")?;
        anyhow::ensure!(written == config, "the kept config.json is not the run's");
        Ok(())
    })?;
    let kept = listing(&to)?;
    Ok(Some(KeptWeights {
        files: kept.len(),
        bytes: kept.iter().map(|(_, len, _)| len).sum(),
        to,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, text: &str) {
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(path, text).unwrap();
    }

    /// A run folder with a stage, caches and a lock.
    fn run_folder(runs: &Path, name: &str, config: &str) -> PathBuf {
        let run = runs.join(name);
        write(&run.join("config.json"), config);
        write(&run.join("metrics.jsonl"), "{}\n");
        write(
            &run.join("checkpoint/progress.json"),
            r#"{"epochs_done": 3}"#,
        );
        write(&run.join("checkpoint/model.bpk"), "weights");
        write(&run.join("stage_a/config.json"), "{}");
        write(
            &run.join("stage_a/checkpoint/progress.json"),
            r#"{"epochs_done": 2}"#,
        );
        write(&run.join("stage_a/dataset/frames.bin"), "frames");
        write(&run.join("ntp_frames/rows.bin"), "rows");
        write(&run.join("embeddings.parts/0.bin"), "part");
        write(&run.join("checkpoint.next/model.bpk"), "half-written");
        write(&run.join("train.lock"), "123");
        run
    }

    #[test]
    fn a_carried_run_holds_what_training_cannot_rebuild() {
        let tmp = tempfile::tempdir().unwrap();
        let (runs, records) = (tmp.path().join("runs"), tmp.path().join("figures/records"));
        run_folder(&runs, "r", r#"{"seed": 0}"#);
        let carried = carry_run(&runs, &records, "r").unwrap();
        assert_eq!(carried.to, record::in_progress_dir(&records, "r"));
        let files: Vec<PathBuf> = listing(&carried.to)
            .unwrap()
            .into_iter()
            .map(|(p, _, _)| p)
            .collect();
        let expected = [
            "checkpoint/model.bpk",
            "checkpoint/progress.json",
            "config.json",
            "metrics.jsonl",
            "stage_a/checkpoint/progress.json",
            "stage_a/config.json",
        ];
        assert_eq!(files, expected.map(PathBuf::from));
        for entry in [
            "stage_a/dataset",
            "ntp_frames",
            "embeddings.parts",
            "checkpoint.next",
            "train.lock",
        ] {
            assert!(!carried.to.join(entry).exists(), "{entry} carried");
        }
        assert_eq!(carried.files, 6);
        let mut checkpoints = carried.checkpoints.clone();
        checkpoints.sort();
        assert_eq!(
            checkpoints,
            vec![(PathBuf::new(), 3), (PathBuf::from("stage_a"), 2)]
        );
        // Carried again (a later checkpoint): the copy is replaced.
        write(
            &runs.join("r/checkpoint/progress.json"),
            r#"{"epochs_done": 4}"#,
        );
        let again = carry_run(&runs, &records, "r").unwrap();
        assert!(again.checkpoints.contains(&(PathBuf::new(), 4)));
    }

    #[test]
    fn carrying_refuses_finished_runs_and_other_configurations() {
        let tmp = tempfile::tempdir().unwrap();
        let (runs, records) = (tmp.path().join("runs"), tmp.path().join("figures/records"));
        let err = carry_run(&runs, &records, "absent")
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a run folder"), "{err}");
        run_folder(&runs, "r", r#"{"seed": 0}"#);
        carry_run(&runs, &records, "r").unwrap();
        // Another run of the same name: the copy there is not overwritten.
        fs::remove_dir_all(runs.join("r")).unwrap();
        run_folder(&runs, "r", r#"{"seed": 1}"#);
        let err = carry_run(&runs, &records, "r").unwrap_err().to_string();
        assert!(err.contains("another configuration"), "{err}");
        let kept: serde_json::Value =
            RunDir::read_json(&record::in_progress_dir(&records, "r").join("config.json")).unwrap();
        assert_eq!(kept["seed"], 0);
        // Also after a carry killed while it swapped copies, its copy
        // parked as `r.old`: put back, then seen.
        let copy = record::in_progress_dir(&records, "r");
        let parked = copy.with_file_name("r.old");
        fs::rename(&copy, &parked).unwrap();
        let err = carry_run(&runs, &records, "r").unwrap_err().to_string();
        assert!(err.contains("another configuration"), "{err}");
        assert!(copy.join("config.json").is_file() && !parked.exists());
        // Recorded: finished.
        write(&record::path(&records, "r"), "{}");
        let err = carry_run(&runs, &records, "r").unwrap_err().to_string();
        assert!(err.contains("finished and recorded"), "{err}");
        // Also when named with a trailing slash (tab completion); a path
        // is not a run name.
        let err = carry_run(&runs, &records, "r/").unwrap_err().to_string();
        assert!(err.contains("finished and recorded"), "{err}");
        for bad in ["../r", "a/r", "", "/r", "r/.", ".", ".."] {
            let err = carry_run(&runs, &records, bad).unwrap_err().to_string();
            assert!(err.contains("not a run name"), "{bad}: {err}");
        }
    }

    #[test]
    fn a_carried_copy_is_discarded_only_for_its_own_configuration() {
        let tmp = tempfile::tempdir().unwrap();
        let (runs, records) = (tmp.path().join("runs"), tmp.path().join("figures/records"));
        run_folder(&runs, "r", r#"{"seed": 0}"#);
        carry_run(&runs, &records, "r").unwrap();
        let other = serde_json::json!({"seed": 1});
        assert_eq!(discard_carried(&records, "r", Some(&other)).unwrap(), None);
        assert_eq!(discard_carried(&records, "r", None).unwrap(), None);
        let own = serde_json::json!({"seed": 0});
        let removed = discard_carried(&records, "r", Some(&own)).unwrap();
        assert_eq!(removed, Some(record::in_progress_dir(&records, "r")));
        assert!(!record::in_progress_dir(&records, "r").exists());
        assert_eq!(discard_carried(&records, "r", Some(&own)).unwrap(), None);
    }

    /// Stands in for `export::keep_in_zoo`: the run's config.json and its
    /// `best/model.bpk` as `best/model.safetensors`.
    fn fake_zoo(run: &Path, next: &Path) -> anyhow::Result<()> {
        fs::copy(run.join("config.json"), next.join("config.json"))?;
        fs::create_dir_all(next.join("best"))?;
        fs::copy(
            run.join("best/model.bpk"),
            next.join("best/model.safetensors"),
        )?;
        Ok(())
    }

    #[test]
    fn a_recorded_thousand_task_run_keeps_its_selected_weights_only() {
        let tmp = tempfile::tempdir().unwrap();
        let (runs, records) = (tmp.path().join("runs"), tmp.path().join("figures/records"));
        let run = run_folder(&runs, "big", r#"{"train_tasks": 1000}"#);
        write(&run.join("best/model.bpk"), "selected");
        write(&run.join("best/frame_encoder/model.bpk"), "encoder");
        write(&run.join("stage_a/best/model.bpk"), "stage a");
        let kept = keep_selected_weights(&records, "big", &run, &fake_zoo)
            .unwrap()
            .unwrap();
        assert_eq!(kept.to, weights_dir(&records, "big"));
        assert!(kept.to.ends_with("figures/weights/big"));
        let files: Vec<PathBuf> = listing(&kept.to)
            .unwrap()
            .into_iter()
            .map(|(p, _, _)| p)
            .collect();
        let expected = ["best/model.safetensors", "config.json"];
        assert_eq!(files, expected.map(PathBuf::from));
        assert_eq!(kept.files, 2);
        // Kept again (the record extended): replaced, same files.
        write(&run.join("best/model.bpk"), "selected again");
        keep_selected_weights(&records, "big", &run, &fake_zoo)
            .unwrap()
            .unwrap();
        assert_eq!(
            fs::read_to_string(kept.to.join("best/model.safetensors")).unwrap(),
            "selected again"
        );
        // Another configuration of the same name: refused, the copy kept.
        write(
            &run.join("config.json"),
            r#"{"train_tasks": 1000, "seed": 1}"#,
        );
        let err = keep_selected_weights(&records, "big", &run, &fake_zoo)
            .unwrap_err()
            .to_string();
        assert!(err.contains("another configuration"), "{err}");
        assert_eq!(
            fs::read_to_string(kept.to.join("best/model.safetensors")).unwrap(),
            "selected again"
        );
    }

    #[test]
    fn a_smaller_run_or_one_without_selected_weights_keeps_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let (runs, records) = (tmp.path().join("runs"), tmp.path().join("figures/records"));
        let small = run_folder(&runs, "small", r#"{"train_tasks": 500}"#);
        write(&small.join("best/model.bpk"), "selected");
        assert_eq!(
            keep_selected_weights(&records, "small", &small, &fake_zoo).unwrap(),
            None
        );
        let unselected = run_folder(&runs, "none", r#"{"train_tasks": 1000}"#);
        assert_eq!(
            keep_selected_weights(&records, "none", &unselected, &fake_zoo).unwrap(),
            None
        );
        assert!(!records.parent().unwrap().join("weights").exists());
    }
}
