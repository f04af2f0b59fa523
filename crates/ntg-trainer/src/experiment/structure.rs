//! Block stacking on tasks of new structures (not in the paper; a
//! structure is a task with its cube names ignored).
//!
//! The structure benchmark (issue 66): runs of `experiments/structure.toml`
//! trained on the benchmark's own task set (training, validation and test
//! structures disjoint; `env_blocks::structure`), each scored on new
//! structures of trained heights and on taller towers, with two-level
//! bootstrap intervals over structures and tasks ([`run_benchmark`],
//! [`benchmark_section`]).
//!
//! The earlier protocol (issue 17 item 7; its test structures were
//! examined by diagnostics, so they are not clean): each curve of fig.
//! "ntp_exp" at its largest number of training tasks, scored again on
//! tasks whose structure no training-pool task has (`ntg eval --split
//! structure`: towers of five cubes or more), beside its score on the
//! standard test tasks ([`run`], [`report_section`]).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

use crate::blocks::Recipe;
use crate::domain::EvalSplit;
use crate::experiment::Plan;
use crate::experiment::ntp_exp::{NtpExpExperiment, NtpExpPoint, curve_name};
use crate::experiment::template::STRUCTURE;
use crate::method::MethodId;
use crate::spec::{ObsKind, Profile};
use crate::stats::SuccessRate;

/// One run scored on both splits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StructurePoint {
    /// The method.
    pub method: MethodId,
    /// Its recipe.
    pub recipe: Recipe,
    /// Observation kind.
    pub obs: ObsKind,
    /// Seed of the run (results written before seeds: 0).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub seed: u64,
    /// Training tasks.
    pub train_tasks: usize,
    /// Success on the standard test tasks (fig. ntp_exp).
    pub standard: SuccessRate,
    /// Success on as many tasks of the structure split.
    pub success: SuccessRate,
    /// What the run adds to the paper's recipe, named from its whole
    /// configuration (the fig. ntp_exp point's `additions`; results written
    /// before it: empty).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub additions: Vec<String>,
    /// Video runs: the side of the camera's frames (the point's `camera`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<u32>,
    /// Mean fraction of goals met there.
    pub goal_fraction: f64,
    /// Run folder.
    pub run: PathBuf,
}

fn is_zero(seed: &u64) -> bool {
    *seed == 0
}

/// Scores, for every curve of `points` (method, recipe, input) and each of
/// its seeds, its point with the most training tasks on as many structure-split tasks as it
/// had test tasks (cached in the run's `eval/structure-*.json`, the file
/// `ntg eval --split structure` writes).
///
/// A run restored from its record (no weights) is scored only if its
/// record holds that evaluation; the evaluations made here are added to
/// the runs' records (`plan`).
pub fn run(points: &[NtpExpPoint], plan: &Plan<'_>) -> anyhow::Result<Vec<StructurePoint>> {
    let largest = crate::experiment::ntp_exp::largest_of_each_curve(points);
    let mut scored = Vec::new();
    for p in largest.into_iter().map(|i| &points[i]) {
        let n = p.success.trials;
        let Some(result) =
            crate::experiment::ntp_exp::evaluate_point(p, EvalSplit::Structure, n, plan)?
        else {
            continue;
        };
        eprintln!(
            "structure split [{}]: success {:.3} ({:.3}-{:.3}) on {n} tasks (standard test tasks: {:.3})",
            p.run.display(),
            result.success.rate,
            result.success.ci_low,
            result.success.ci_high,
            p.success.rate
        );
        scored.push(StructurePoint {
            method: p.method,
            recipe: p.recipe,
            obs: p.obs,
            seed: p.seed,
            train_tasks: p.train_tasks,
            standard: p.success,
            additions: p.additions.clone(),
            camera: p.camera,
            success: result.success,
            goal_fraction: result.mean_goal_fraction,
            run: p.run.clone(),
        });
    }
    Ok(scored)
}

/// The report section (Markdown).
pub fn report_section(points: &[StructurePoint]) -> String {
    let mut s = match super::open_section(&STRUCTURE.text("head"), !points.is_empty()) {
        Ok(head) => head,
        Err(whole) => return whole,
    };
    let _ = writeln!(s, "{}", STRUCTURE.text("table_head"));
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.3} | {:.3} ({:.3}–{:.3}) | {:.3} |",
            curve_name(p.method, p.recipe, crate::method::ntg::Variant::Full),
            crate::experiment::ntp_exp::input_cell(p.obs, p.camera),
            p.train_tasks,
            p.seed,
            match p.additions.is_empty() {
                true => "none".to_owned(),
                false => p.additions.join("; "),
            },
            p.standard.rate,
            p.success.rate,
            p.success.ci_low,
            p.success.ci_high,
            p.goal_fraction
        );
    }
    let _ = writeln!(s);
    s
}

// The structure benchmark (issue 66): runs trained on its task set.

/// The structure benchmark's experiment file (`experiments/structure.toml`):
/// block-stacking runs in fig. ntp_exp's form, every one trained on the
/// benchmark's task set (`structure_benchmark = true`; checked).
pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<NtpExpExperiment> {
    NtpExpExperiment::load_named(BENCHMARK_FILE, source)
}

/// The benchmark's experiment file's name, and the prefix of its run
/// folders (`structure-state-...`).
pub const BENCHMARK_FILE: &str = "structure";

/// Checks that every run of `experiment` at `profile` trains on the
/// structure benchmark's task set: a run of the standard set would be
/// scored on sets it was not split for.
pub fn check_benchmark(experiment: &NtpExpExperiment, profile: Profile) -> anyhow::Result<()> {
    for (name, config) in experiment.named_run_configs(profile)? {
        anyhow::ensure!(
            config.structure_benchmark && config.tasks.is_none(),
            "{}: run {name} does not train on the structure benchmark's task set: set `structure_benchmark = true` in the file's [overrides] (and no `tasks` file)",
            experiment.origin
        );
    }
    Ok(())
}

/// One structure's tasks on one test set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StructureOutcomes {
    /// Its towers' heights, e.g. `2+3`.
    pub towers: String,
    /// Its tasks' outcomes in evaluation order: `1` success, `0` failure.
    pub outcomes: String,
}

impl StructureOutcomes {
    fn successes(&self) -> Vec<bool> {
        self.outcomes.chars().map(|c| c == '1').collect()
    }

    /// The height of its tallest tower.
    fn tallest(&self) -> usize {
        self.towers
            .split('+')
            .filter_map(|h| h.parse().ok())
            .max()
            .unwrap_or(0)
    }
}

/// A run's score on one of the benchmark's test sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetScore {
    /// Success over its tasks, with the Wilson interval over tasks.
    pub success: SuccessRate,
    /// Mean fraction of goals met.
    pub goal_fraction: f64,
    /// Fraction of demos the interpreter transcribed exactly (NTG).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transcribed: Option<f64>,
    /// The outcomes structure by structure (key order).
    pub structures: Vec<StructureOutcomes>,
}

impl SetScore {
    /// The score of `result`, an evaluation on the benchmark's `set`.
    fn of(
        set: env_blocks::structure::StructureSet,
        result: &crate::blocks::EvalResult,
    ) -> anyhow::Result<SetScore> {
        let structures = crate::blocks::outcomes_by_structure(set, &result.tasks)?
            .into_iter()
            .map(|(towers, outcomes)| StructureOutcomes {
                towers,
                outcomes: outcomes
                    .iter()
                    .map(|&s| if s { '1' } else { '0' })
                    .collect(),
            })
            .collect();
        Ok(SetScore {
            success: result.success,
            goal_fraction: result.mean_goal_fraction,
            transcribed: crate::domain::transcription_exact_rate(&result.tasks).map(|r| r.rate),
            structures,
        })
    }

    fn outcomes(&self) -> Vec<Vec<bool>> {
        self.structures
            .iter()
            .map(StructureOutcomes::successes)
            .collect()
    }
}

/// One run of the structure benchmark: its point in fig. ntp_exp's form
/// (`point.success`: the test structures) and its scores on both test
/// sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchPoint {
    /// The run as fig. ntp_exp's code trained and scored it.
    pub point: NtpExpPoint,
    /// New structures of heights seen in training.
    pub test: SetScore,
    /// Towers taller than any in training.
    pub taller: SetScore,
}

/// Scores every point of the benchmark's runs on its two test sets: the
/// test structures from the evaluation the point was trained for (its
/// `eval/` file), the taller towers on as many tasks (`ntg eval --split
/// taller`, cached in `eval/taller-*.json` and added to the run's
/// record). A run restored from its record without the taller evaluation
/// is left out, saying so.
pub fn run_benchmark(points: &[NtpExpPoint], plan: &Plan<'_>) -> anyhow::Result<Vec<BenchPoint>> {
    use env_blocks::structure::StructureSet;
    let mut scored = Vec::new();
    for p in points {
        let n = p.success.trials;
        let test_file = crate::run_dir::RunDir::open(&p.run)?
            .eval_dir()
            .join(crate::experiment::ntp_exp::test_eval_file(p.method, n));
        let test: crate::blocks::EvalResult = crate::run_dir::RunDir::read_json(&test_file)
            .with_context(|| format!("the test structures' evaluation of {}", p.run.display()))?;
        let Some(taller) =
            crate::experiment::ntp_exp::evaluate_point(p, EvalSplit::Taller, n, plan)?
        else {
            continue;
        };
        let point = BenchPoint {
            point: p.clone(),
            test: SetScore::of(StructureSet::Test, &test)
                .with_context(|| test_file.display().to_string())?,
            taller: SetScore::of(StructureSet::Taller, &taller)
                .with_context(|| format!("the taller towers' evaluation of {}", p.run.display()))?,
        };
        eprintln!(
            "structure benchmark [{}]: test structures {:.3}, taller towers {:.3} ({n} tasks each)",
            p.run.display(),
            point.test.success.rate,
            point.taller.success.rate,
        );
        scored.push(point);
    }
    Ok(scored)
}

/// One row of the benchmark: a run's seeds (its folder name without the
/// seed names the row, so every panel of the file is a row of its own).
struct BenchRow<'a> {
    seeds: Vec<&'a BenchPoint>,
}

impl BenchRow<'_> {
    fn first(&self) -> &NtpExpPoint {
        &self.seeds[0].point
    }

    /// The mean over seeds on one set, with the two-level bootstrap
    /// interval over structures and tasks within them.
    fn clustered(
        &self,
        set: impl Fn(&BenchPoint) -> &SetScore,
    ) -> anyhow::Result<crate::stats::ClusteredRate> {
        let outcomes: Vec<Vec<Vec<bool>>> = self.seeds.iter().map(|p| set(p).outcomes()).collect();
        crate::stats::clustered_bootstrap(&outcomes, BOOTSTRAP_RESAMPLES, 0)
            .map_err(|e| anyhow::anyhow!("{}: {e}", self.first().run.display()))
    }

    /// Mean success over seeds and tasks by the tallest tower of a
    /// structure: `(height, rate)` in height order.
    fn by_height(&self, set: impl Fn(&BenchPoint) -> &SetScore) -> Vec<(usize, f64)> {
        let mut heights: std::collections::BTreeMap<usize, (usize, usize)> = Default::default();
        for p in &self.seeds {
            for s in &set(p).structures {
                let e = heights.entry(s.tallest()).or_default();
                e.0 += s.outcomes.chars().filter(|&c| c == '1').count();
                e.1 += s.outcomes.len();
            }
        }
        heights
            .into_iter()
            .map(|(h, (ok, n))| (h, ok as f64 / n.max(1) as f64))
            .collect()
    }

    /// The row's name: the method and recipe with their core and node
    /// source ([`CurveId::method_name`](crate::experiment::ntp_exp::CurveId::method_name)),
    /// and the panel's tag where it has one (two panels of one recipe
    /// that differ in an override: the additions say how).
    fn name(&self) -> String {
        let name = self.first().curve_id().method_name();
        match &self.first().tag {
            Some(tag) => format!("{name} ({tag})"),
            None => name,
        }
    }

    /// What the run adds to the paper's recipe, the task set (every row's)
    /// left out.
    fn additions(&self) -> String {
        let additions: Vec<&String> = self
            .first()
            .additions
            .iter()
            .filter(|a| *a != BENCHMARK_ADDITION)
            .collect();
        match additions.is_empty() {
            true => "none".into(),
            false => additions
                .iter()
                .map(|a| a.as_str())
                .collect::<Vec<_>>()
                .join("; "),
        }
    }
}

/// How [`crate::blocks::additions`] names the benchmark's task set.
const BENCHMARK_ADDITION: &str = "structure benchmark's task set";

/// Resamples of the two-level bootstrap.
const BOOTSTRAP_RESAMPLES: usize = 10_000;

/// `points` grouped into rows: by run folder without its seed, in order
/// of first appearance.
fn bench_rows(points: &[BenchPoint]) -> Vec<BenchRow<'_>> {
    let mut rows: Vec<(String, BenchRow<'_>)> = Vec::new();
    for p in points {
        let key = unseeded(&p.point.run);
        match rows.iter_mut().find(|(k, _)| *k == key) {
            Some((_, row)) => row.seeds.push(p),
            None => rows.push((key, BenchRow { seeds: vec![p] })),
        }
    }
    rows.into_iter().map(|(_, row)| row).collect()
}

/// A run folder's name without its `-seedS` suffix.
fn unseeded(run: &std::path::Path) -> String {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    match name.rsplit_once("-seed") {
        Some((base, seed)) if !seed.is_empty() && seed.chars().all(|c| c.is_ascii_digit()) => {
            base.to_owned()
        }
        _ => name,
    }
}

/// The benchmark's report section (Markdown): one row per run of the file
/// (its seeds together), success on each test set with the two-level
/// bootstrap interval, then success by the tallest tower.
pub fn benchmark_section(points: &[BenchPoint]) -> String {
    let mut s = match super::open_section(&STRUCTURE.text("bench_head"), !points.is_empty()) {
        Ok(head) => head,
        Err(whole) => return whole,
    };
    let _ = writeln!(s, "{}", STRUCTURE.text("bench_table_head"));
    let rows = bench_rows(points);
    let mut heights = Vec::new();
    for row in &rows {
        let p = row.first();
        // Seeds of one row scored on different tasks cannot be averaged
        // task by task: the row says so instead of a number.
        let (test, taller) = match (row.clustered(|b| &b.test), row.clustered(|b| &b.taller)) {
            (Ok(test), Ok(taller)) => (test, taller),
            (Err(e), _) | (_, Err(e)) => {
                let _ = writeln!(s, "| {} | {e:#} |", row.name());
                continue;
            }
        };
        let per_seed = |set: &dyn Fn(&BenchPoint) -> &SetScore| {
            row.seeds
                .iter()
                .map(|b| format!("{:.3}", set(b).success.rate))
                .collect::<Vec<_>>()
                .join(" / ")
        };
        let transcribed = |set: &dyn Fn(&BenchPoint) -> &SetScore| {
            let rates: Vec<f64> = row
                .seeds
                .iter()
                .filter_map(|b| set(b).transcribed)
                .collect();
            match rates.is_empty() {
                true => "–".to_owned(),
                false => format!("{:.3}", rates.iter().sum::<f64>() / rates.len() as f64),
            }
        };
        let seeds: Vec<String> = row.seeds.iter().map(|b| b.point.seed.to_string()).collect();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | **{:.3}** ({:.3}–{:.3}) | **{:.3}** ({:.3}–{:.3}) | {} | {} | {} / {} |",
            row.name(),
            crate::experiment::ntp_exp::scale_cells(p),
            seeds.join(", "),
            row.additions(),
            test.rate,
            test.ci_low,
            test.ci_high,
            taller.rate,
            taller.ci_low,
            taller.ci_high,
            per_seed(&|b| &b.test),
            per_seed(&|b| &b.taller),
            transcribed(&|b| &b.test),
            transcribed(&|b| &b.taller),
        );
        let cells: Vec<String> = row
            .by_height(|b| &b.taller)
            .into_iter()
            .map(|(h, rate)| format!("{h}: {rate:.3}"))
            .collect();
        heights.push(STRUCTURE.fill(
            "bench_height_line",
            &[
                ("row", &row.name()),
                (
                    "input",
                    &crate::experiment::ntp_exp::input_cell(p.obs, p.camera),
                ),
                ("heights", &cells.join(", ")),
            ],
        ));
    }
    let _ = writeln!(s);
    if rows.iter().any(|r| r.first().tag.is_some()) {
        let _ = writeln!(s, "{}\n", STRUCTURE.text("bench_choice"));
    }
    crate::experiment::ntp_exp::bullet_list(&mut s, &STRUCTURE.text("bench_heights"), heights);
    s
}

/// Writes the benchmark's figure as `stem.svg` and `stem.png`: a panel per
/// input, a group of bars per row of the report (its seeds' mean with the
/// two-level bootstrap interval) on the test structures and the taller
/// towers. Nothing is written without points.
pub fn write_benchmark_figure(points: &[BenchPoint], stem: &std::path::Path) -> anyhow::Result<()> {
    use crate::figure::{Bar, GroupedBars};
    let rows = bench_rows(points);
    let mut inputs: Vec<String> = Vec::new();
    for row in &rows {
        let p = row.first();
        let input = crate::experiment::ntp_exp::input_cell(p.obs, p.camera);
        if !inputs.contains(&input) {
            inputs.push(input);
        }
    }
    let mut charts = Vec::new();
    for (i, input) in inputs.iter().enumerate() {
        let of_input: Vec<&BenchRow<'_>> = rows
            .iter()
            .filter(|r| {
                let p = r.first();
                &crate::experiment::ntp_exp::input_cell(p.obs, p.camera) == input
            })
            .collect();
        let mut labels: Vec<String> = Vec::new();
        for row in &of_input {
            let mut label = short_label(row.first());
            if labels.contains(&label) {
                label = format!("{label} ({})", labels.len() + 1);
            }
            labels.push(label);
        }
        let mut series = Vec::new();
        for (name, set) in [
            (
                "new structures, trained heights",
                (|b: &BenchPoint| &b.test) as fn(&BenchPoint) -> &SetScore,
            ),
            ("taller towers", |b: &BenchPoint| &b.taller),
        ] {
            let mut bars = Vec::new();
            for (row, label) in of_input.iter().zip(&labels) {
                let rate = row.clustered(set)?;
                bars.push(Bar {
                    label: label.clone(),
                    value: rate.rate,
                    lo: rate.ci_low,
                    hi: rate.ci_high,
                });
            }
            series.push((name.to_owned(), bars));
        }
        charts.push(GroupedBars {
            title: format!(
                "({}) structure benchmark, {input}",
                char::from(b'a' + i as u8)
            ),
            y_label: "success (mean of seeds, 95% two-level bootstrap)".into(),
            categories: labels,
            series,
        });
    }
    if charts.is_empty() {
        return Ok(());
    }
    crate::figure::write_grouped_bars(&charts, stem)
}

/// A bar group's label: the method, `rec.` for the recommended recipe
/// (`rec., localizer` on video where the localizer chooses the node, as the
/// recipe's executed node does not), and its core where recurrent.
fn short_label(p: &NtpExpPoint) -> String {
    let mut label = match p.method {
        MethodId::Ntg => "NTG".to_owned(),
        MethodId::Ntp => "NTP".to_owned(),
        MethodId::NtpFlat => "NTP Flat".to_owned(),
        MethodId::NtpDetector => "NTP (Det.)".to_owned(),
        MethodId::Flat => "Flat".to_owned(),
    };
    if p.recipe == Recipe::Recommended {
        label.push_str(" rec.");
        if p.method == MethodId::Ntg && p.obs == ObsKind::Vid && !p.executed_node {
            label.push_str(", localizer");
        }
    }
    if !p.ntp_core.is_reactive() {
        label.push_str(" GRU");
    }
    if let Some(tag) = &p.tag {
        label = format!("{label} ({tag})");
    }
    label
}

/// Two seeds of one row and one seed of another, from `point` (a fig.
/// ntp_exp point of the paper results), for tests of the report.
#[cfg(test)]
pub(crate) fn example_bench_points(point: &NtpExpPoint) -> Vec<BenchPoint> {
    let set = |outcomes: [&str; 2]| SetScore {
        success: SuccessRate::new(
            outcomes.iter().map(|o| o.matches('1').count()).sum(),
            outcomes.iter().map(|o| o.len()).sum(),
        ),
        goal_fraction: 0.5,
        transcribed: Some(0.9),
        structures: ["2+2", "5"]
            .iter()
            .zip(outcomes)
            .map(|(towers, outcomes)| StructureOutcomes {
                towers: (*towers).into(),
                outcomes: outcomes.into(),
            })
            .collect(),
    };
    let mut points = Vec::new();
    for (seed, run) in [
        (0, "structure-state-1000"),
        (1, "structure-state-1000-seed1"),
    ] {
        let mut p = point.clone();
        p.seed = seed;
        p.run = PathBuf::from("runs").join(run);
        p.additions = vec![BENCHMARK_ADDITION.into(), "cube renaming".into()];
        points.push(BenchPoint {
            point: p,
            test: set(["1101", "1111"]),
            taller: set(["1100", "1000"]),
        });
    }
    let mut ntp = points[0].clone();
    ntp.point.method = MethodId::Ntp;
    ntp.point.run = PathBuf::from("runs/structure-state-ntp-1000");
    points.push(ntp);
    points
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_benchmark_section_gives_each_row_its_seeds_together() {
        let results: crate::reproduce::Results = crate::run_dir::RunDir::read_json(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../docs/figures/results.json"),
        )
        .unwrap();
        let points = example_bench_points(&results.ntp_exp[0]);
        let section = benchmark_section(&points);
        // Two rows: NTG's two seeds, NTP's one.
        let rows: Vec<&str> = section
            .lines()
            .filter(|l| l.starts_with("| NTG") || l.starts_with("| NTP"))
            .collect();
        assert_eq!(rows.len(), 2, "{section}");
        assert!(rows[0].contains("| 0, 1 |"), "{}", rows[0]);
        // 7 of 8 tasks on each seed; 3 of 8 on the taller towers.
        assert!(rows[0].contains("**0.875**"), "{}", rows[0]);
        assert!(rows[0].contains("**0.375**"), "{}", rows[0]);
        // The task set is every row's: not named as an addition.
        assert!(!rows[0].contains(BENCHMARK_ADDITION), "{}", rows[0]);
        assert!(rows[0].contains("cube renaming"), "{}", rows[0]);
        // Taller towers by height: 2+2 is 2 cubes tall, 5 is 5.
        assert!(section.contains("2: 0.500, 5: 0.250"), "{section}");
        let dir = tempfile::tempdir().unwrap();
        write_benchmark_figure(&points, &dir.path().join("structure")).unwrap();
        assert!(dir.path().join("structure.svg").is_file());
        // Nothing to draw: no file.
        write_benchmark_figure(&[], &dir.path().join("none")).unwrap();
        assert!(!dir.path().join("none.svg").exists());
        assert!(benchmark_section(&[]).contains("No run of it trained"));
        // A panel's tag tells two rows of one recipe apart.
        let mut tagged = points[2].clone();
        tagged.point.tag = Some("nodetach".into());
        tagged.point.run = PathBuf::from("runs/structure-state-nodetach-ntp-1000");
        let section = benchmark_section(&[points[2].clone(), tagged]);
        assert!(section.contains("| NTP (nodetach) |"), "{section}");
        // The recommended recipe on video says where its node comes from
        // when the localizer chooses it (the recipe's default on video is
        // the executed node).
        let mut ntg = results.ntp_exp[0].clone();
        (ntg.method, ntg.recipe, ntg.obs, ntg.tag) =
            (MethodId::Ntg, Recipe::Recommended, ObsKind::Vid, None);
        ntg.executed_node = false;
        assert_eq!(short_label(&ntg), "NTG rec., localizer");
        ntg.executed_node = true;
        assert_eq!(short_label(&ntg), "NTG rec.");
        ntg.obs = ObsKind::State;
        ntg.executed_node = false;
        assert_eq!(short_label(&ntg), "NTG rec.");
    }

    #[test]
    fn every_run_of_the_benchmark_file_trains_on_its_task_set() {
        let file = load(crate::experiment::Source::BuiltIn).unwrap();
        for profile in [Profile::Smoke, Profile::Quick, Profile::Paper] {
            check_benchmark(&file, profile).unwrap();
        }
        let mut without = file.clone();
        without.overrides.remove("structure_benchmark");
        let e = check_benchmark(&without, Profile::Smoke).unwrap_err();
        assert!(
            format!("{e:#}").contains("structure_benchmark = true"),
            "{e:#}"
        );
    }

    #[test]
    fn a_seed_suffix_is_dropped_from_the_row_key() {
        assert_eq!(
            unseeded(std::path::Path::new("r/structure-state-1000-seed2")),
            "structure-state-1000"
        );
        assert_eq!(
            unseeded(std::path::Path::new("r/structure-state-1000")),
            "structure-state-1000"
        );
        assert_eq!(unseeded(std::path::Path::new("r/a-seedx")), "a-seedx");
    }
}
