//! The model zoo in a reduced profile's report: the paper profile's kept
//! 1000-task models (`docs/figures/weights/RUN/`) evaluated again on the
//! first test tasks of the profile, beside their records' scores on the
//! same tasks episode by episode, so the main job shows paper-scale
//! numbers, reproduced, next to its own reduced-scale training.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::domain::{EvalFlags, EvalSplit};
use crate::experiment::template::ZOO;
use crate::run_dir::RunDir;
use crate::stats::SuccessRate;

/// Where the zoo and the paper profile's records are, from the
/// repository's root (where `cargo xtask reproduce-figures` runs `ntg`).
pub const ZOO_DIR: &str = "docs/figures/weights";
/// The paper profile's run records.
pub const RECORDS_DIR: &str = "docs/figures/records";

/// One zoo entry evaluated again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZooPoint {
    /// The entry's (and its record's) run name.
    pub name: String,
    /// Its method as the figures name it.
    pub legend: String,
    /// What it adds to the paper's recipe, named from its whole
    /// configuration ([`crate::blocks::additions`]).
    pub additions: Vec<String>,
    /// Its input cell (`Vid (128×128)`).
    pub input: String,
    /// The record's test success (its whole evaluation, 1000 tasks).
    pub recorded: SuccessRate,
    /// The record's success on the first `success.trials` test tasks.
    pub recorded_first: SuccessRate,
    /// Its success now on those tasks.
    pub success: SuccessRate,
    /// Whether every one of those episodes ended as in the record
    /// (success, steps, goals met, transcription).
    pub same_episodes: bool,
}

/// The episode fields compared with the record's.
const EPISODE_FIELDS: [&str; 7] = [
    "task",
    "index",
    "success",
    "steps",
    "goals",
    "goals_met",
    "transcribed_exactly",
];

fn episode_key(episode: &serde_json::Value) -> Vec<serde_json::Value> {
    EPISODE_FIELDS
        .iter()
        .map(|f| episode.get(*f).cloned().unwrap_or(serde_json::Value::Null))
        .collect()
}

fn rate(episodes: &[serde_json::Value]) -> SuccessRate {
    let successes = episodes
        .iter()
        .filter(|e| e.get("success").and_then(serde_json::Value::as_bool) == Some(true))
        .count();
    SuccessRate::new(successes, episodes.len())
}

/// The record's test evaluation: the `eval/*.json` of the test set with
/// the most tasks (no split prefix; a structure-benchmark run's new
/// structures, not its taller towers).
fn recorded_episodes(record: &Path) -> anyhow::Result<Vec<serde_json::Value>> {
    let record = crate::record::RunRecord::read(record)?;
    let splits = [
        "validation-",
        "seen-",
        "structure-",
        "taller-",
        "tasks-",
        "decisions",
    ];
    let best = record
        .files
        .iter()
        .filter(|(path, _)| {
            path.strip_prefix("eval/")
                .is_some_and(|f| !splits.iter().any(|s| f.contains(s)))
        })
        .filter_map(|(_, value)| value.get("tasks")?.as_array().cloned())
        .max_by_key(Vec::len)
        .context("the record holds no evaluation on the test tasks")?;
    Ok(best)
}

/// Evaluates every entry of `zoo` on the first `tasks` test tasks, in a
/// copy under `runs/zoo/` (the checkout is never written), and compares
/// each with its record in `records`. No zoo folder: no points. Entries
/// are evaluated on rayon's pool (each evaluation on one thread; a video
/// model's 100 episodes take about 10 CPU seconds, and the zoo grows with
/// every kept model), and listed in name order.
pub fn run(zoo: &Path, records: &Path, runs: &Path, tasks: usize) -> anyhow::Result<Vec<ZooPoint>> {
    use rayon::prelude::*;
    let Ok(entries) = std::fs::read_dir(zoo) else {
        return Ok(Vec::new());
    };
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("config.json").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
        .into_par_iter()
        .map(|name| evaluate_entry(zoo, records, runs, tasks, name))
        .collect()
}

/// One entry of [`run`]: evaluated in its copy, compared with its record.
fn evaluate_entry(
    zoo: &Path,
    records: &Path,
    runs: &Path,
    tasks: usize,
    name: String,
) -> anyhow::Result<ZooPoint> {
    let copy = runs.join("zoo").join(&name);
    if copy.exists() {
        std::fs::remove_dir_all(&copy).with_context(|| format!("replacing {}", copy.display()))?;
    }
    crate::run_dir::link_or_copy_tree(&zoo.join(&name), &copy)?;
    let run = RunDir::open(&copy)?;
    let config: crate::blocks::BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let flags = EvalFlags::of_run(&copy, tasks, EvalSplit::Test);
    let (_, result) = crate::blocks::evaluate_run(&run, &flags)
        .with_context(|| format!("evaluating the zoo's {name}"))?;
    let now: Vec<serde_json::Value> = serde_json::to_value(&result)?
        .get("tasks")
        .and_then(|t| t.as_array().cloned())
        .unwrap_or_default();
    let recorded = recorded_episodes(&crate::record::path(records, &name))
        .with_context(|| format!("the record of the zoo's {name}"))?;
    let first: Vec<serde_json::Value> = recorded.iter().take(now.len()).cloned().collect();
    let same_episodes = first.len() == now.len()
        && first
            .iter()
            .zip(&now)
            .all(|(a, b)| episode_key(a) == episode_key(b));
    eprintln!(
        "model zoo [{name}]: {}/{} now, {}/{} in its record on the same tasks{}",
        result.success.successes,
        result.success.trials,
        rate(&first).successes,
        first.len(),
        if same_episodes {
            ", every episode the same"
        } else {
            ", episodes differ"
        }
    );
    let video = config.obs == crate::spec::ObsKind::Vid;
    Ok(ZooPoint {
        legend: config.method.legend().to_owned(),
        additions: crate::blocks::additions(&config),
        input: crate::experiment::ntp_exp::input_cell(
            config.obs,
            video.then_some(config.camera().size),
        ),
        recorded: rate(&recorded),
        recorded_first: rate(&first),
        success: result.success,
        same_episodes,
        name,
    })
}

/// The report section (Markdown); nothing without a zoo.
pub fn report_section(points: &[ZooPoint]) -> String {
    if points.is_empty() {
        return String::new();
    }
    let mut s = format!("{}\n\n{}\n", ZOO.text("head"), ZOO.text("table_head"));
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.3} ({}/{}) | {:.3} ({}/{}) | {:.3} ({}/{}) | {} |",
            p.name,
            p.legend,
            p.input,
            match p.additions.is_empty() {
                true => "none".to_owned(),
                false => p.additions.join("; "),
            },
            p.recorded.rate,
            p.recorded.successes,
            p.recorded.trials,
            p.recorded_first.rate,
            p.recorded_first.successes,
            p.recorded_first.trials,
            p.success.rate,
            p.success.successes,
            p.success.trials,
            if p.same_episodes { "yes" } else { "**no**" }
        );
    }
    let _ = writeln!(s);
    s
}

/// The zoo folder and records as seen from the working folder.
pub fn default_dirs() -> (PathBuf, PathBuf) {
    (PathBuf::from(ZOO_DIR), PathBuf::from(RECORDS_DIR))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed zoo entries, evaluated again on their first test
    /// tasks, end every episode as their records say. Five tasks each: the
    /// zoo grows with every kept model (19 now, 13 of them on video), and
    /// the quick profile checks 100 tasks of each.
    #[test]
    fn every_zoo_entry_reproduces_its_record_on_its_first_test_tasks() {
        const TASKS: usize = 5;
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let runs = tempfile::tempdir().unwrap();
        let points = run(
            &root.join(ZOO_DIR),
            &root.join(RECORDS_DIR),
            runs.path(),
            TASKS,
        )
        .unwrap();
        assert!(!points.is_empty(), "the zoo is empty");
        let names: Vec<&str> = points.iter().map(|p| p.name.as_str()).collect();
        assert!(names.is_sorted(), "{names:?}");
        for p in &points {
            assert_eq!(p.success.trials, TASKS, "{}", p.name);
            assert!(
                p.same_episodes,
                "{}: {:?} against {:?}",
                p.name, p.success, p.recorded_first
            );
            assert_eq!(p.success, p.recorded_first, "{}", p.name);
        }
        // The checkout's zoo is not written to.
        assert!(
            !root
                .join(ZOO_DIR)
                .join(&points[0].name)
                .join("eval")
                .exists()
        );
        let section = report_section(&points);
        assert!(section.contains("| yes |"), "{section}");
    }
}
