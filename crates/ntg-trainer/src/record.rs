//! Run records: what `ntg reproduce --profile paper` commits of each
//! finished run, so that a profile of many hours can be completed across
//! sittings and checked point by point from a fresh clone.
//!
//! A record is one small JSON file, `<out>/records/<run>.json`: the run
//! folder's configuration, training metrics (with each epoch's seconds),
//! validation scores, model selection and evaluations (each episode's
//! outcome, without the per-step traces), plus the commit and machine that
//! produced it. It holds no weights and no dataset. Restored into a run
//! folder it makes that run count as finished and evaluated: the figures
//! and the report read it as they read a run trained here; only what needs
//! the weights (a qualitative trace, an evaluation not recorded) is
//! skipped, and says so.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::run_dir::RunDir;

/// The record format written by this build.
pub const FORMAT: u32 = 1;

pub use ntg_train::provenance::{Session, commit, machine, mixed_float_mode_warning, note_session};
pub use ntg_train::run_dir::{RESTORED_MARKER, is_restored};

/// Folders of a run whose files are not recorded (caches regenerated from
/// seeds: demos, frame embeddings, NTP's encoded episodes
/// ([`crate::method::ntp::NTP_FRAMES_DIR`]); or figures), besides any
/// `*.partial` folder (a cache or copy being written).
const SKIPPED_DIRS: [&str; 4] = ["dataset", "embeddings", "ntp_frames", "qualitative"];

/// Per-episode fields dropped from recorded evaluations (long; the
/// qualitative figures, which need them, need the weights too).
const DROPPED_FIELDS: [&str; 3] = ["trace", "transcription", "demo_actions"];

/// One finished run, as committed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// [`FORMAT`] when written.
    pub format: u32,
    /// The run folder's name.
    pub run: String,
    /// The commit the writing binary was built from (`-dirty` with
    /// uncommitted changes to the code then; `unknown` when built outside
    /// a git checkout). Older records hold the checkout's commit when
    /// written instead. Where and with what each stretch of training ran
    /// is the run's `sessions.jsonl` ([`note_session`]).
    pub commit: String,
    /// The CPU and thread count of the machine that wrote it.
    pub machine: String,
    /// The run folder's small files by relative path (`/`-separated):
    /// `.json` files as JSON, `.jsonl` files as arrays of their lines.
    pub files: BTreeMap<String, Value>,
}

/// How a new record of a run stands to the one kept ([`RunRecord::compare`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Comparison {
    /// The same configuration and evaluations, episode for episode.
    Same,
    /// Every evaluation of the kept one, equal, and more (or the same ones
    /// with the per-episode verdict the kept one predates): worth keeping
    /// instead.
    Extends,
    /// Every evaluation both hold is equal, but the new one lacks some of
    /// the kept one's (`missing`; e.g. `ntg reproduce --only` reruns a
    /// point's main evaluation, not the checks its record also holds), or
    /// the per-episode verdict in some: the kept one stays, with the new
    /// one's other evaluations (`adds`) worth adding to it.
    Within {
        /// The kept record's evaluations the new one lacks.
        missing: Vec<String>,
        /// The new one's evaluations the kept one lacks.
        adds: Vec<String>,
        /// How many evaluations both hold (0: nothing was compared).
        common: usize,
    },
    /// Another configuration, or an evaluation both hold differs.
    Differs,
}

/// `path` with `.SUFFIX` appended to its file name (not replacing an
/// extension: run names may hold dots).
fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".");
    name.push(suffix);
    path.with_file_name(name)
}

/// An evaluation without what records written before it lack.
fn normalised(value: &Value) -> Value {
    let mut value = value.clone();
    without_key(&mut value, TRANSCRIBED_EXACTLY);
    value
}

impl RunRecord {
    /// The record of the run folder `dir`.
    pub fn of_run(dir: &Path) -> anyhow::Result<Self> {
        let mut files = BTreeMap::new();
        collect(dir, dir, &mut files)?;
        if !files.contains_key("config.json") {
            bail!("{} is not a run folder: no config.json", dir.display());
        }
        Ok(RunRecord {
            format: FORMAT,
            run: dir
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            commit: commit(),
            machine: machine(),
            files,
        })
    }

    /// Reads a record, checking its format.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let record: RunRecord = RunDir::read_json(path)?;
        if record.format != FORMAT {
            bail!(
                "{}: record format {} (this build reads {FORMAT})",
                path.display(),
                record.format
            );
        }
        Ok(record)
    }

    /// Writes it compactly (records of 1000 episodes stay near 100 kB).
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        let text = serde_json::to_string(self)?;
        // Through a temporary file renamed into place: a kill leaves the
        // old record or the new one, never half of one.
        let tmp = sibling(path, "tmp");
        std::fs::write(&tmp, text + "\n").with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, path)
            .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
    }

    /// The run configuration it was trained with.
    pub fn config(&self) -> Option<&Value> {
        self.files.get("config.json")
    }

    /// Writes its files into the new folder `dir` (which must not exist),
    /// checkpoint progress before evaluations so that these count as
    /// belonging to the final weights, and marks it restored. Through a
    /// sibling `NAME.restoring` folder renamed into place: a kill leaves no
    /// `dir` (a folder with the record's progress but not its marker would
    /// pass for a finished training with weights).
    pub fn restore(&self, dir: &Path, from: &Path) -> anyhow::Result<()> {
        if dir.exists() {
            bail!(
                "{} exists: a record is only restored into a new folder",
                dir.display()
            );
        }
        let staging = sibling(dir, "restoring");
        if staging.exists() {
            std::fs::remove_dir_all(&staging)
                .with_context(|| format!("removing the unfinished {}", staging.display()))?;
        }
        self.write_files(&staging, from)?;
        std::fs::rename(&staging, dir)
            .with_context(|| format!("renaming {} to {}", staging.display(), dir.display()))
    }

    /// [`RunRecord::restore`]'s writing of the files and marker into `dir`.
    fn write_files(&self, dir: &Path, from: &Path) -> anyhow::Result<()> {
        let mut paths: Vec<&String> = self.files.keys().collect();
        paths.sort_by_key(|p| (p.starts_with("eval/"), p.as_str()));
        for relative in paths {
            if relative
                .split('/')
                .any(|part| part == ".." || part.is_empty())
            {
                bail!("{}: bad file name {relative:?}", from.display());
            }
            let path = dir.join(relative);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent)
                    .with_context(|| format!("creating {}", parent.display()))?;
            }
            let value = &self.files[relative];
            let text = if relative.ends_with(".jsonl") {
                let lines = value.as_array().with_context(|| {
                    format!("{}: {relative} is not an array of lines", from.display())
                })?;
                lines.iter().map(|l| l.to_string() + "\n").collect()
            } else {
                serde_json::to_string_pretty(value)?
            };
            std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        }
        std::fs::write(dir.join(RESTORED_MARKER), from.display().to_string())
            .with_context(|| format!("writing {}", dir.join(RESTORED_MARKER).display()))
    }

    /// How the record `new` of the same run stands to this one: their
    /// configurations and the evaluations both hold (every episode),
    /// whatever the commit, machine or timings. See [`Comparison`].
    pub fn compare(&self, new: &RunRecord) -> Comparison {
        if self.config() != new.config() {
            return Comparison::Differs;
        }
        let (ours, theirs) = (self.evaluations(), new.evaluations());
        if ours.iter().any(|(path, v)| {
            theirs
                .get(path)
                .is_some_and(|w| normalised(v) != normalised(w))
        }) {
            return Comparison::Differs;
        }
        let only_in = |a: &BTreeMap<&str, &Value>, b: &BTreeMap<&str, &Value>| -> Vec<String> {
            a.keys()
                .filter(|p| !b.contains_key(*p))
                .map(|p| (*p).to_owned())
                .collect()
        };
        let (missing, adds) = (only_in(&ours, &theirs), only_in(&theirs, &ours));
        if !missing.is_empty() {
            let common = ours.len() - missing.len();
            return Comparison::Within {
                missing,
                adds,
                common,
            };
        }
        // `new` holds every evaluation of this one, equal: it extends this
        // one if it has more, or adds the per-episode verdict a record
        // written before it lacks, and drops that verdict from none.
        let lacks_verdict = |v: &Value| normalised(v) == *v;
        let drops = ours
            .iter()
            .any(|(path, v)| !lacks_verdict(v) && lacks_verdict(theirs[path]));
        let gains = ours
            .iter()
            .any(|(path, v)| lacks_verdict(v) && !lacks_verdict(theirs[path]));
        if drops && !adds.is_empty() {
            // Worth merging, not replacing: its new evaluations into this.
            Comparison::Within {
                missing,
                adds,
                common: ours.len(),
            }
        } else if (!adds.is_empty() || gains) && !drops {
            Comparison::Extends
        } else {
            Comparison::Same
        }
    }

    /// This record with the evaluations `paths` of `new` added (a record
    /// that holds evaluations `new` lacks, `new` ones it lacks:
    /// [`Comparison::Within`] with `adds`).
    pub fn with_evaluations_of(&self, new: &RunRecord, paths: &[String]) -> RunRecord {
        let mut merged = self.clone();
        for path in paths {
            if let Some(v) = new.files.get(path) {
                merged.files.insert(path.clone(), v.clone());
            }
        }
        merged
    }

    /// Whether `other` records the same run with the same outcomes: the
    /// same configuration and evaluations (every episode), whatever the
    /// commit, machine or timings ([`RunRecord::compare`] is `Same` or
    /// `Extends` either way round).
    pub fn same_outcomes(&self, other: &RunRecord) -> bool {
        matches!(
            (self.compare(other), other.compare(self)),
            (
                Comparison::Same | Comparison::Extends,
                Comparison::Same | Comparison::Extends
            )
        )
    }

    /// Its evaluations (`eval/...`) by path.
    fn evaluations(&self) -> BTreeMap<&str, &Value> {
        self.files
            .iter()
            .filter(|(p, _)| p.starts_with("eval/"))
            .map(|(p, v)| (p.as_str(), v))
            .collect()
    }

    /// The stretches of training its `sessions.jsonl` lists (lines that do
    /// not parse are left out).
    pub fn sessions(&self) -> Vec<Session> {
        self.files
            .get("sessions.jsonl")
            .and_then(Value::as_array)
            .map(|lines| {
                lines
                    .iter()
                    .filter_map(|l| serde_json::from_value(l.clone()).ok())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Why a rerun in this process might not repeat the record although
    /// the code is the same: its training ran with another float mode than
    /// this process's (`ntg_model::float_mode`). `None` when every
    /// stretch ran in this process's mode.
    pub fn float_mode_note(&self) -> Option<String> {
        let now = ntg_model::flushes_subnormals();
        let sessions = self.sessions();
        let other = sessions
            .iter()
            .filter(|s| s.flushed_subnormals() != now)
            .count();
        (other > 0).then(|| {
            let (then, value) = if now { ("kept", "0") } else { ("flushed", "1") };
            format!(
                "{other} of its {} training stretches {then} subnormal floats, which this \
                 process does not (NTG_FLUSH_SUBNORMALS={value} reruns it in that mode)",
                sessions.len()
            )
        })
    }

    /// A short summary of its evaluations ("eval/full-1000.json: 921/1000").
    pub fn summary(&self) -> String {
        self.files
            .iter()
            .filter(|(p, _)| p.starts_with("eval/"))
            .map(|(p, v)| {
                let mut rates = Vec::new();
                successes(v, &mut rates);
                format!("{p}: {}", rates.join(", "))
            })
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// Where a paper-profile run in progress, carried between machines, is
/// kept: `in-progress/NAME/` beside the `records` folder (its README says
/// how a run folder is saved there); `ntg reproduce` resumes from a copy
/// of it when the run has neither a folder nor a record.
pub fn in_progress_dir(records: &Path, name: &str) -> PathBuf {
    records
        .parent()
        .unwrap_or(Path::new("."))
        .join("in-progress")
        .join(name)
}

/// The record file of run `name` in `records`.
pub fn path(records: &Path, name: &str) -> PathBuf {
    records.join(format!("{name}.json"))
}

fn successes(value: &Value, out: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            if let Some(s) = map.get("success")
                && let (Some(k), Some(n)) = (s["successes"].as_u64(), s["trials"].as_u64())
            {
                out.push(format!("{k}/{n}"));
                return;
            }
            for (key, v) in map {
                if key != "tasks" && key != "episodes" {
                    successes(v, out);
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| successes(v, out)),
        _ => {}
    }
}

fn collect(root: &Path, dir: &Path, files: &mut BTreeMap<String, Value>) -> anyhow::Result<()> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    entries.sort();
    for path in entries {
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        if path.is_dir() {
            if !SKIPPED_DIRS.contains(&name.as_ref()) && !name.ends_with(".partial") {
                collect(root, &path, files)?;
            }
            continue;
        }
        let relative = path
            .strip_prefix(root)
            .unwrap_or(&path)
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect::<Vec<_>>()
            .join("/");
        let value = if name.ends_with(".jsonl") {
            Value::Array(crate::run_dir::read_jsonl(&path)?)
        } else if name.ends_with(".json") {
            let mut value: Value = RunDir::read_json(&path)?;
            if relative.starts_with("eval/") {
                drop_fields(&mut value);
            }
            value
        } else {
            continue;
        };
        files.insert(relative, value);
    }
    Ok(())
}

/// The per-episode verdict kept of the dropped sequences (see
/// `EpisodeRecord::transcribed_exactly`): derived here for evaluations
/// saved before it, and left out of [`RunRecord::compare`], since
/// records written before it lack it.
const TRANSCRIBED_EXACTLY: &str = "transcribed_exactly";

fn drop_fields(value: &mut Value) {
    match value {
        Value::Object(map) => {
            if !map.contains_key(TRANSCRIBED_EXACTLY)
                && let (Some(Value::Array(said)), Some(Value::Array(done))) =
                    (map.get("transcription"), map.get("demo_actions"))
                && !said.is_empty()
            {
                let exact = said == done;
                map.insert(TRANSCRIBED_EXACTLY.into(), Value::Bool(exact));
            }
            for field in DROPPED_FIELDS {
                if map.get(field).is_some_and(Value::is_array) {
                    map.remove(field);
                }
            }
            map.values_mut().for_each(drop_fields);
        }
        Value::Array(items) => items.iter_mut().for_each(drop_fields),
        _ => {}
    }
}

/// Removes `key` from every object in `value`.
fn without_key(value: &mut Value, key: &str) {
    match value {
        Value::Object(map) => {
            map.remove(key);
            map.values_mut().for_each(|v| without_key(v, key));
        }
        Value::Array(items) => items.iter_mut().for_each(|v| without_key(v, key)),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_restores_the_small_files_and_drops_traces() {
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("ntp_exp-state-5");
        let write = |p: &str, text: &str| {
            let path = run.join(p);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        };
        write("config.json", r#"{"train_tasks": 5}"#);
        write(
            "metrics.jsonl",
            "{\"epoch\":0,\"seconds\":1.5}\n{\"epoch\":1,\"seconds\":2.0}\n",
        );
        write("checkpoint/progress.json", r#"{"epochs_done": 2}"#);
        write("checkpoint/model.bpk", "weights");
        write("dataset/index.json", "{}");
        write(
            &format!("{}/episodes.json", crate::method::ntp::NTP_FRAMES_DIR),
            "{}",
        );
        write("embeddings.partial/index.json", "{}");
        write(
            "eval/full-2.json",
            concat!(
                r#"{"success": {"successes": 1, "trials": 2}, "tasks": ["#,
                r#"{"task": "a", "success": true, "trace": ["pick(A)"], "transcription": ["pick(A)"], "demo_actions": ["pick(A)"]}, "#,
                r#"{"task": "b", "success": false, "trace": [], "transcription": ["pick(B)"], "demo_actions": ["pick(C)"]}]}"#
            ),
        );
        let record = RunRecord::of_run(&run).unwrap();
        assert_eq!(record.run, "ntp_exp-state-5");
        assert_eq!(
            record.files.keys().cloned().collect::<Vec<_>>(),
            [
                "checkpoint/progress.json",
                "config.json",
                "eval/full-2.json",
                "metrics.jsonl"
            ]
        );
        let tasks = &record.files["eval/full-2.json"]["tasks"];
        for field in DROPPED_FIELDS {
            assert!(tasks[0].get(field).is_none(), "{field} kept");
        }
        // What is kept of the dropped sequences: whether they agreed.
        assert_eq!(tasks[0][TRANSCRIBED_EXACTLY], true);
        assert_eq!(tasks[1][TRANSCRIBED_EXACTLY], false);
        assert_eq!(record.summary(), "eval/full-2.json: 1/2");
        let file = tmp.path().join("records").join("r.json");
        record.write(&file).unwrap();
        let back = RunRecord::read(&file).unwrap();
        assert_eq!(back, record);
        let restored = tmp.path().join("again");
        back.restore(&restored, &file).unwrap();
        assert!(is_restored(&restored));
        // Its training is recorded as done, but there are no weights to
        // reuse: neither the run nor a stage folder of it is finished.
        assert!(crate::fit::training_finished(&run, 2).unwrap());
        assert!(!crate::fit::training_finished(&restored, 2).unwrap());
        let stage = restored.join("stage_a");
        std::fs::create_dir_all(stage.join("checkpoint")).unwrap();
        std::fs::write(
            stage.join("checkpoint/progress.json"),
            r#"{"epochs_done": 2}"#,
        )
        .unwrap();
        assert!(!crate::fit::training_finished(&stage, 2).unwrap());
        let run_dir = RunDir::open(&restored).unwrap();
        assert_eq!(run_dir.epoch_seconds().unwrap(), 3.5);
        // The evaluation counts as made after the last checkpoint.
        let eval: Value = run_dir
            .cached_eval("full-2.json", || bail!("re-evaluated"))
            .unwrap();
        assert_eq!(eval["success"]["successes"], 1);
        assert!(back.same_outcomes(&RunRecord::of_run(&restored).unwrap()));
        assert!(back.restore(&restored, &file).is_err());
        // A record written before the verdict was kept still matches.
        let mut older = back.clone();
        without_key(
            older.files.get_mut("eval/full-2.json").unwrap(),
            TRANSCRIBED_EXACTLY,
        );
        assert!(back.same_outcomes(&older));
        let mut other = back.clone();
        other.files.get_mut("eval/full-2.json").unwrap()["tasks"][1]["success"] = true.into();
        assert!(!back.same_outcomes(&other));
    }

    #[test]
    fn records_compare_by_the_evaluations_both_hold() {
        let record = |evals: &[(&str, Value)]| RunRecord {
            format: FORMAT,
            run: "x-0.5".into(),
            commit: "c".into(),
            machine: "m".into(),
            files: std::iter::once(("config.json".to_owned(), serde_json::json!({"seed": 1})))
                .chain(evals.iter().map(|(p, v)| (format!("eval/{p}"), v.clone())))
                .collect(),
        };
        let won = serde_json::json!({"tasks": [{"success": true, TRANSCRIBED_EXACTLY: true}]});
        let won_before_verdict = serde_json::json!({"tasks": [{"success": true}]});
        let lost = serde_json::json!({"tasks": [{"success": false}]});
        let main = record(&[("full-1.json", won.clone())]);
        let both = record(&[("full-1.json", won.clone()), ("seen-1.json", lost.clone())]);
        assert_eq!(main.compare(&main), Comparison::Same);
        assert_eq!(main.compare(&both), Comparison::Extends);
        assert_eq!(
            both.compare(&main),
            Comparison::Within {
                missing: vec!["eval/seen-1.json".into()],
                adds: vec![],
                common: 1,
            }
        );
        // Each with an evaluation the other lacks; nothing in common.
        let other = record(&[
            ("full-1.json", won.clone()),
            ("structure-1.json", won.clone()),
        ]);
        assert_eq!(
            both.compare(&other),
            Comparison::Within {
                missing: vec!["eval/seen-1.json".into()],
                adds: vec!["eval/structure-1.json".into()],
                common: 1,
            }
        );
        let merged = both.with_evaluations_of(&other, &["eval/structure-1.json".into()]);
        assert_eq!(merged.files.len(), 4);
        assert_eq!(both.compare(&merged), Comparison::Extends);
        assert!(matches!(
            main.compare(&record(&[("seen-1.json", won.clone())])),
            Comparison::Within { common: 0, .. }
        ));
        assert!(main.same_outcomes(&main) && !main.same_outcomes(&both));
        // A record from before the per-episode verdict: the same outcomes,
        // which a record with the verdict extends.
        let older = record(&[("full-1.json", won_before_verdict.clone())]);
        assert_eq!(older.compare(&main), Comparison::Extends);
        assert_eq!(main.compare(&older), Comparison::Same);
        // More evaluations, but one without the verdict the kept one has.
        let fewer_verdicts = record(&[
            ("full-1.json", won_before_verdict),
            ("seen-1.json", won.clone()),
        ]);
        assert_eq!(
            main.compare(&fewer_verdicts),
            Comparison::Within {
                missing: vec![],
                adds: vec!["eval/seen-1.json".into()],
                common: 1,
            }
        );
        assert!(older.same_outcomes(&main));
        assert_eq!(
            main.compare(&record(&[("full-1.json", lost)])),
            Comparison::Differs
        );
        let mut other_config = main.clone();
        other_config
            .files
            .insert("config.json".into(), serde_json::json!({"seed": 2}));
        assert_eq!(main.compare(&other_config), Comparison::Differs);

        // Written through a temporary file, restored through a staging
        // folder (a dotted run name keeps its whole name in both), an
        // unfinished staging folder of a killed restore cleared first.
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp.path().join("x-0.5.json");
        main.write(&file).unwrap();
        assert_eq!(RunRecord::read(&file).unwrap(), main);
        let dir = tmp.path().join("x-0.5");
        std::fs::create_dir_all(tmp.path().join("x-0.5.restoring/checkpoint")).unwrap();
        main.restore(&dir, &file).unwrap();
        assert!(is_restored(&dir));
        let mut names: Vec<String> = std::fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["x-0.5", "x-0.5.json"]);
    }

    #[test]
    fn a_record_names_training_stretches_of_another_float_mode() {
        // Tests run without `init_float_mode`: subnormals kept.
        assert!(!ntg_model::flushes_subnormals());
        let record = |lines: &str| RunRecord {
            format: FORMAT,
            run: "r".into(),
            commit: String::new(),
            machine: String::new(),
            files: BTreeMap::from([(
                "sessions.jsonl".to_string(),
                serde_json::from_str(lines).unwrap(),
            )]),
        };
        // Lines from before the mode existed kept subnormals.
        let old = r#"[{"from_epoch": 0, "commit": "a", "machine": "m"}]"#;
        assert_eq!(record(old).float_mode_note(), None);
        let mixed = r#"[{"from_epoch": 0, "commit": "a", "machine": "m"},
            {"from_epoch": 3, "commit": "b", "machine": "m", "flush_subnormals": true}]"#;
        let note = record(mixed).float_mode_note().unwrap();
        assert!(
            note.starts_with("1 of its 2 training stretches flushed"),
            "{note}"
        );
        assert!(note.contains("NTG_FLUSH_SUBNORMALS=1"), "{note}");
        // A new line says which mode it ran in.
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(&tmp.path().join("r")).unwrap();
        note_session(&run, 0).unwrap();
        let text = std::fs::read_to_string(tmp.path().join("r/sessions.jsonl")).unwrap();
        let line: Session = serde_json::from_str(text.trim()).unwrap();
        assert_eq!(line.flush_subnormals, Some(false));
        // And on how many threads.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        pool.install(|| note_session(&run, 1)).unwrap();
        let text = std::fs::read_to_string(tmp.path().join("r/sessions.jsonl")).unwrap();
        let line: Session = serde_json::from_str(text.lines().last().unwrap()).unwrap();
        assert_eq!(line.compute_threads, Some(3));
        // Resuming it in the other mode is warned about, in its own not.
        assert_eq!(mixed_float_mode_warning(&run, false).unwrap(), None);
        let warning = mixed_float_mode_warning(&run, true).unwrap().unwrap();
        assert!(warning.contains("NTG_FLUSH_SUBNORMALS=0"), "{warning}");
        // A folder without sessions has nothing to mix.
        let fresh = RunDir::create(&tmp.path().join("fresh")).unwrap();
        assert_eq!(mixed_float_mode_warning(&fresh, true).unwrap(), None);
    }

    #[test]
    fn bad_records_are_errors_that_name_the_file() {
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp.path().join("x.json");
        std::fs::write(&file, "{ not json").unwrap();
        let err = format!("{:#}", RunRecord::read(&file).unwrap_err());
        assert!(err.contains("x.json"), "{err}");
        std::fs::write(
            &file,
            r#"{"format": 99, "run": "x", "commit": "", "machine": "", "files": {}}"#,
        )
        .unwrap();
        let err = format!("{:#}", RunRecord::read(&file).unwrap_err());
        assert!(err.contains("format 99"), "{err}");
        let mut record = RunRecord::read(&file).unwrap_or_else(|_| RunRecord {
            format: FORMAT,
            run: "x".into(),
            commit: String::new(),
            machine: String::new(),
            files: BTreeMap::from([("../escape.json".to_owned(), Value::Null)]),
        });
        record.format = FORMAT;
        let err = record.restore(&tmp.path().join("r"), &file).unwrap_err();
        assert!(err.to_string().contains("bad file name"), "{err}");
    }
}
