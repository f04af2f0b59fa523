//! `ntg reproduce`: every figure this build makes, from its experiment
//! file ([`crate::experiment`]), run through the same training and
//! evaluation code as `ntg train` / `ntg eval`, written as figures, one
//! `results.json` and one `REPORT.md`.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::experiment::ntp_exp::{self, NtpExpPoint};
use crate::experiment::template::REPORT;
use crate::experiment::thor_all::{self, ThorAllResult};
use crate::experiment::{Plan, Source};
use crate::experiment::{ablation, qualitative, structure};
use crate::run_dir::RunDir;

pub use crate::spec::Profile;

/// Everything `reproduce` measured (`results.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Results {
    /// Profile used.
    pub profile: Profile,
    /// Fig. "ntp_exp", NTG.
    pub ntp_exp: Vec<NtpExpPoint>,
    /// Fig. "ablation" (a): NTG whole and without each part (results
    /// written before it: none).
    #[serde(default)]
    pub ablation: Vec<NtpExpPoint>,
    /// Fig. "ablation" (b): object sorting whole and without parts, on
    /// scenes that need another order (results written before it: none).
    #[serde(default)]
    pub ablation_b: Vec<ablation::SortingPoint>,
    /// The qualitative block-stacking trace (results written before it, or
    /// no qualifying rollout: none).
    #[serde(default)]
    pub trace_blocks: Option<qualitative::BlocksTraceFigure>,
    /// The qualitative sorting trace (results written before it, or no
    /// qualifying episode: none).
    #[serde(default)]
    pub trace_sorting: Option<qualitative::SortingTraceFigure>,
    /// The block-stacking split by structure (results written before it:
    /// none).
    #[serde(default)]
    pub structure: Vec<crate::experiment::structure::StructurePoint>,
    /// The structure benchmark: runs on its task set, scored on new
    /// structures and taller towers (results written before it: none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub structure_benchmark: Vec<crate::experiment::structure::BenchPoint>,
    /// A reduced profile: the model zoo's paper-scale models evaluated
    /// on its test tasks beside their records (the paper profile, results
    /// written before it, or no zoo: none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub zoo: Vec<crate::experiment::zoo::ZooPoint>,
    /// Fig. "jigsaws": cross-task NLL on Needle Passing (issue 7).
    pub jigsaws: crate::jigsaws::JigsawsResult,
    /// Fig. "thor_all" (b), NTG and the Flat Policy.
    pub thor_all: ThorAllResult,
    /// Figures not reproduced yet, with the reason.
    pub not_yet: Vec<(String, String)>,
    /// Runs of the profile's rollout figures not trained yet (listed in
    /// `not_yet`; results written before it: 0).
    #[serde(default)]
    pub runs_missing: usize,
    /// What each block-stacking figure's file changes in its recipe
    /// (`(figure, note)`; results written before it: none).
    #[serde(default)]
    pub recipe_notes: Vec<(String, String)>,
}

/// Runs every figure this build can make at `profile`, keeping run folders
/// under `plan.runs` (finished runs are reused, interrupted ones resumed,
/// recorded ones restored: [`Plan`]) and writing figures, `results.json`
/// and `REPORT.md` into `out`. The figures' runs come from their experiment
/// files in `experiments`. Fig. "jigsaws" runs on the synthetic stand-in
/// unless `jigsaws_root` names a JIGSAWS copy; with `plan.train` off it is
/// read from `out/jigsaws.json`. The report shows each run beside the
/// same run in `paper` (the committed paper-profile results), if given.
pub fn reproduce(
    profile: Profile,
    plan: &Plan<'_>,
    out: &Path,
    jigsaws_root: Option<&Path>,
    experiments: Source<'_>,
    paper: Option<&Results>,
) -> anyhow::Result<Results> {
    let started = Instant::now();
    // Read and check every experiment file first, so a bad edit fails
    // before the long runs.
    let ntp_exp_file = ntp_exp::NtpExpExperiment::load(experiments)?;
    ntp_exp_file.run_configs(profile)?;
    let ablation_file = ablation::load(experiments)?;
    ablation_file.run_configs(profile)?;
    let structure_file = structure::load(experiments)?;
    structure::check_benchmark(&structure_file, profile)?;
    let ablation_b_file = ablation::AblationBExperiment::load(experiments)?;
    for seed in ablation_b_file.seeds(profile) {
        for &variant in &ablation_b_file.ablations {
            ablation_b_file.run_config(profile, variant, seed)?;
        }
    }
    let thor_all_file = thor_all::ThorAllExperiment::load(experiments)?;
    for run in thor_all_file.runs(profile) {
        thor_all_file.run_config(profile, run)?;
    }
    // First, so a wrong --jigsaws-root fails before the long runs.
    let jigsaws_saved = out.join("jigsaws.json");
    let jigsaws = if plan.train {
        crate::jigsaws::reproduce(profile, jigsaws_root, plan.runs, out, experiments)?
    } else {
        RunDir::read_json(&jigsaws_saved).context(
            "fig. jigsaws is read from its saved result when nothing is trained (--no-train)",
        )?
    };
    // What needs a run's weights, of a run restored from its record, is
    // taken from the results written before (if of the same run).
    let before: Option<Results> = RunDir::read_json(&out.join("results.json"))
        .ok()
        .filter(|r: &Results| r.profile == profile);
    let mut not_yet = Vec::new();
    // Figs. ntp_exp then ablation (whose whole model is ntp_exp's run at
    // 1000 tasks), and beside them figs. ablation (b) then thor_all, which
    // need no run of the others: all share `plan.slots`, so neither core
    // idles while one figure waits for its longest run. ntp_exp's first
    // run (its longest) takes its place first.
    let (front, side) = std::thread::scope(|scope| {
        let side = scope.spawn(|| {
            ntg_model::apply_float_mode();
            plan.slots.wait_for_a_start();
            let ablation_b = ablation::run_b(&ablation_b_file, profile, plan)?;
            let thor_all = thor_all::run(&thor_all_file, profile, plan)?;
            anyhow::Ok((ablation_b, thor_all))
        });
        let front = ntp_exp::run(&ntp_exp_file, profile, plan).and_then(|points| {
            Ok((
                points,
                ntp_exp::run(&ablation_file, profile, plan)?,
                ntp_exp::run(&structure_file, profile, plan)?,
            ))
        });
        plan.slots.open();
        if front.is_err() {
            plan.slots.fail();
        }
        let side = side
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("figs. ablation (b) and thor_all panicked")));
        (front, side)
    });
    let (mut points, ablation_points, benchmark_points) = front?;
    let (ablation_b, thor_all) = side?;
    ntp_exp::check_baselines(&mut points, plan, ntp_exp::SEEN_CHECK_TRAIN_TASKS)?;
    let structure = structure::run(&points, plan)?;
    let structure_benchmark = structure::run_benchmark(&benchmark_points, plan)?;
    let trace_sorting = match ablation_b.iter().find(|p| p.ablation.is_full()) {
        Some(p) if crate::record::is_restored(&p.run) => {
            let kept = before.as_ref().and_then(|b| b.trace_sorting.clone());
            if kept.is_none() {
                not_yet.push(weights_needed("trace_sorting", &p.run));
            }
            kept
        }
        Some(p) => {
            qualitative::sorting_trace(&p.run, p.success.trials, &out.join("trace_sorting"))?
        }
        None => None,
    };
    // The qualitative trace: from the state-input NTG run that scored best
    // (the most training tasks among equals).
    let traced = points
        .iter()
        .filter(|p| p.obs == crate::spec::ObsKind::State && p.method.is_ntg())
        .max_by(|a, b| {
            (a.success.rate, a.train_tasks)
                .partial_cmp(&(b.success.rate, b.train_tasks))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
    let trace_blocks = match traced {
        Some(p) if crate::record::is_restored(&p.run) => {
            let kept = before.as_ref().and_then(|b| b.trace_blocks.clone());
            if kept.is_none() {
                not_yet.push(weights_needed("trace_blocks", &p.run));
            }
            kept
        }
        Some(p) => qualitative::blocks_trace(&p.run, p.success.trials, &out.join("trace_blocks"))?,
        None => None,
    };
    let mut missing = plan
        .missing
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    // Noted as runs finish, two at a time: sorted, so the report is the
    // same from one invocation to the next.
    missing.sort();
    let runs_missing = missing.len();
    not_yet.extend(missing_runs_lines(&missing));
    if profile != Profile::Paper {
        not_yet.push(seeds_line());
    }
    if structure_file.run_names(profile).is_empty() {
        not_yet.push(structure_not_in_profile_line());
    }
    // A reduced profile evaluates the paper profile's kept models on its
    // test tasks (as many as its largest point's); without training, it
    // keeps what was measured before.
    let zoo = if profile == Profile::Paper {
        Vec::new()
    } else if plan.train {
        let tasks = points.iter().map(|p| p.success.trials).max().unwrap_or(100);
        let (zoo_dir, records) = crate::experiment::zoo::default_dirs();
        crate::experiment::zoo::run(&zoo_dir, &records, plan.runs, tasks)?
    } else {
        before.as_ref().map(|b| b.zoo.clone()).unwrap_or_default()
    };
    let results = Results {
        profile,
        zoo,
        ntp_exp: points,
        ablation: ablation_points,
        ablation_b,
        trace_sorting,
        structure,
        structure_benchmark,
        trace_blocks,
        jigsaws,
        thor_all,
        recipe_notes: vec![
            ("ntp_exp".into(), ntp_exp_file.recipe_note(profile)),
            ("ablation".into(), ablation_file.recipe_note(profile)),
            (
                structure::BENCHMARK_FILE.into(),
                structure_file.recipe_note(profile),
            ),
        ],
        not_yet,
        runs_missing,
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_figures(&results, out)?;
    RunDir::write_json(&out.join("results.json"), &results)?;
    std::fs::write(
        out.join("REPORT.md"),
        report(&results, paper, started.elapsed().as_secs_f64()),
    )
    .with_context(|| format!("writing {}", out.join("REPORT.md").display()))?;
    // The headline table the README shows (the paper profile's), where
    // there are 1000-task points.
    if results
        .ntp_exp
        .iter()
        .any(|p| p.train_tasks == HEADLINE_TASKS)
    {
        let table = out.join(HEADLINE_TABLE);
        std::fs::write(
            &table,
            ntp_exp::headline_table(&results.ntp_exp, HEADLINE_TASKS),
        )
        .with_context(|| format!("writing {}", table.display()))?;
    }
    Ok(results)
}

/// The training tasks of the headline table ([`ntp_exp::headline_table`]).
pub const HEADLINE_TASKS: usize = 1000;
/// Its file beside `REPORT.md`; README.md shows the paper profile's
/// between `<!-- results-table -->` markers (a test keeps them equal).
pub const HEADLINE_TABLE: &str = "results-table.md";

/// Writes the rollout figures of `results` into `out` (fig. jigsaws is
/// written with its report).
fn write_figures(results: &Results, out: &Path) -> anyhow::Result<()> {
    ntp_exp::write_figure(&results.ntp_exp, &out.join("ntp_exp"))?;
    ablation::write_figure(
        &results.ablation,
        &results.ablation_b,
        &out.join("ablation"),
    )?;
    structure::write_benchmark_figure(&results.structure_benchmark, &out.join("structure"))?;
    thor_all::write_figure(&results.thor_all, &out.join("thor_all"))
}

/// The `not_yet` lines of the runs `missing` (sorted): one per figure, by
/// the run name's prefix (`ntp_exp-...`, `ablation_b-...`).
fn missing_runs_lines(missing: &[String]) -> Vec<(String, String)> {
    let mut by_figure: Vec<(&str, Vec<&str>)> = Vec::new();
    for name in missing {
        let figure = name.split('-').next().unwrap_or(name);
        match by_figure.iter_mut().find(|(f, _)| *f == figure) {
            Some((_, names)) => names.push(name),
            None => by_figure.push((figure, vec![name])),
        }
    }
    by_figure
        .into_iter()
        .map(|(figure, names)| {
            let what = match names.len() {
                1 => REPORT.fill("not_yet_runs_one", &[("figure", &figure)]),
                n => REPORT.fill("not_yet_runs", &[("figure", &figure), ("runs", &n)]),
            };
            (what, format!("{MISSING_RUNS_PREFIX}{}", names.join(", ")))
        })
        .collect()
}

/// The `not_yet` line of a profile other than the paper's: its seeds.
fn seeds_line() -> (String, String) {
    ("seeds".into(), REPORT.text("not_yet_seeds"))
}

/// The `not_yet` line of a profile whose structure benchmark has no run.
fn structure_not_in_profile_line() -> (String, String) {
    (
        "the structure benchmark".into(),
        REPORT.text("not_yet_structure_profile"),
    )
}

/// A `not_yet` line: `what` needs the weights of `run`, which was restored
/// from its record.
fn weights_needed(what: &str, run: &Path) -> (String, String) {
    (
        what.into(),
        REPORT.fill("not_yet_weights", &[("run", &run.display())]),
    )
}

/// The rollout figures' training compute: how many runs, their summed
/// core-seconds of training epochs (`train_seconds`:
/// `RunDir::epoch_compute_seconds`), and over the epochs that recorded
/// their CPU time (`RunDir::recorded_cpu_seconds`): in how many runs, their
/// CPU seconds and their wall seconds. A run reused by two figures (its
/// folder linked for the other) counts once: runs are told apart by their
/// configuration and seconds together (seconds alone collide: CPU time is
/// counted in ticks of 10 ms, and small runs take a few).
struct TrainingCompute {
    runs: usize,
    core_seconds: f64,
    with_cpu: usize,
    cpu: f64,
    wall_of_cpu_epochs: f64,
    /// Runs (or a stage of a run, "RUN's STAGE") that trained some stretch
    /// on more than one thread, with the most threads of a stretch
    /// ([`compute_threads`]).
    multi_threaded: Vec<(String, usize)>,
}

fn training_compute(results: &Results) -> TrainingCompute {
    let runs = results
        .ntp_exp
        .iter()
        .chain(&results.ablation)
        .chain(results.structure_benchmark.iter().map(|b| &b.point))
        .map(|p| (p.train_seconds, &p.run))
        .chain(results.ablation_b.iter().map(|p| (p.train_seconds, &p.run)))
        .chain(
            results
                .thor_all
                .lines
                .iter()
                .map(|l| (l.train_seconds, &l.run)),
        );
    let mut unique: Vec<(u64, Vec<u8>, &std::path::PathBuf)> = runs
        .map(|(seconds, run)| {
            let config = std::fs::read(run.join("config.json")).unwrap_or_default();
            (seconds.to_bits(), config, run)
        })
        .collect();
    unique.sort_by(|a, b| (a.0, &a.1).cmp(&(b.0, &b.1)));
    unique.dedup_by(|a, b| a.0 == b.0 && a.1 == b.1);
    let unique: Vec<(u64, &std::path::PathBuf)> = unique
        .into_iter()
        .map(|(bits, _, run)| (bits, run))
        .collect();
    let mut compute = TrainingCompute {
        runs: unique.len(),
        core_seconds: 0.0,
        with_cpu: 0,
        cpu: 0.0,
        wall_of_cpu_epochs: 0.0,
        multi_threaded: Vec::new(),
    };
    for (bits, run) in unique {
        compute.core_seconds += f64::from_bits(bits);
        let name = run.file_name().unwrap_or_default().to_string_lossy();
        for (part, threads) in compute_threads(run) {
            let name = match part {
                None => name.clone().into_owned(),
                Some(stage) => format!("{name}'s {stage}"),
            };
            compute.multi_threaded.push((name, threads));
        }
        let recorded = RunDir::open(run)
            .ok()
            .and_then(|dir| dir.recorded_cpu_seconds().ok().flatten());
        if let Some((cpu, wall)) = recorded {
            compute.with_cpu += 1;
            compute.cpu += cpu;
            compute.wall_of_cpu_epochs += wall;
        }
    }
    compute
}

/// The most threads a stretch of `run`'s training computed on
/// (`compute_threads` in `sessions.jsonl`), where more than one: the run's
/// own stretches (`None`) and each stage folder's (`stage_a/`,
/// `detector_stage/`: trained in stretches of their own, noted in their
/// own `sessions.jsonl`), in that order.
fn compute_threads(run: &std::path::Path) -> Vec<(Option<String>, usize)> {
    let most = |folder: &std::path::Path| {
        crate::run_dir::read_jsonl::<crate::record::Session>(&folder.join("sessions.jsonl"))
            .ok()
            .and_then(|sessions| sessions.iter().filter_map(|s| s.compute_threads).max())
            .filter(|&threads| threads > 1)
    };
    let mut stages: Vec<String> = std::fs::read_dir(run)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|entry| entry.path().join("sessions.jsonl").is_file())
        .map(|entry| entry.file_name().to_string_lossy().into_owned())
        .collect();
    stages.sort();
    let own = most(run).map(|threads| (None, threads));
    own.into_iter()
        .chain(
            stages
                .into_iter()
                .filter_map(|stage| most(&run.join(&stage)).map(|threads| (Some(stage), threads))),
        )
        .collect()
}

/// The names of the runs `results` lists as not trained yet (its
/// `not_yet` lines of missing runs).
fn missing_runs(results: &Results) -> Vec<&str> {
    results
        .not_yet
        .iter()
        .filter_map(|(_, why)| why.strip_prefix(MISSING_RUNS_PREFIX))
        .flat_map(|names| names.split(", "))
        .collect()
}

/// How a `not_yet` line of missing runs starts, before their names. Not a
/// template's: it is also how [`missing_runs`] finds them in the results
/// files written before, so it cannot change with the prose.
const MISSING_RUNS_PREFIX: &str = "left out of the figure and tables above: ";

/// The report section that puts each run's outcome beside the same run's
/// at the paper profile (the committed `docs/figures/results.json`).
fn beside_paper(results: &Results, paper: &Results) -> String {
    let mut s = String::new();
    let profile = format!("{:?}", results.profile);
    let _ = writeln!(
        s,
        "{}",
        REPORT.fill("beside_paper", &[("profile", &profile)])
    );
    let committed = outcomes(paper);
    let missing = missing_runs(paper);
    for outcome in outcomes(results) {
        let there = match committed.iter().find(|c| c.name == outcome.name) {
            Some(c) => c.text(),
            None if missing.contains(&outcome.name.as_str()) => {
                REPORT.text("beside_paper_not_trained")
            }
            None => REPORT.text("beside_paper_not_a_run"),
        };
        let _ = writeln!(s, "| {} | {} | {there} |", outcome.name, outcome.text());
    }
    s.push('\n');
    s
}

/// `REPORT.md` of `results` (beside `paper`'s, if given), written by an
/// invocation of `seconds`.
fn report(results: &Results, paper: Option<&Results>, seconds: f64) -> String {
    report_of(results, paper, seconds, &training_compute(results))
}

/// [`report`], with the runs' `compute` given.
fn report_of(
    results: &Results,
    paper: Option<&Results>,
    seconds: f64,
    compute: &TrainingCompute,
) -> String {
    let mut s = String::new();
    let where_it_ran = if results.profile == Profile::Paper {
        // A count here; the runs themselves in a list at the end.
        let exceptions = match compute.multi_threaded.len() {
            0 => String::new(),
            count => format!(
                " {}",
                REPORT.fill("threads_exceptions", &[("count", &count)])
            ),
        };
        REPORT.fill("threads", &[("exceptions", &exceptions)])
    } else {
        REPORT.fill("measured_on", &[("machine", &crate::record::machine())])
    };
    let _ = writeln!(s, "{}\n", REPORT.text("title"));
    let _ = writeln!(
        s,
        "{}\n",
        REPORT.fill(
            "intro",
            &[
                ("profile", &format!("{:?}", results.profile)),
                ("seconds", &format!("{seconds:.0}")),
                ("where_it_ran", &where_it_ran),
            ]
        )
    );
    let cpu = match compute.with_cpu {
        0 => String::new(),
        n => {
            let cpu_hours = format!("{:.1}", compute.cpu / 3600.0);
            let wall_hours = format!("{:.1}", compute.wall_of_cpu_epochs / 3600.0);
            let values: [(&str, &dyn std::fmt::Display); 3] = [
                ("runs", &n),
                ("cpu_hours", &cpu_hours),
                ("wall_hours", &wall_hours),
            ];
            format!(" {}", REPORT.fill("compute_cpu", &values))
        }
    };
    let missing = match results.runs_missing {
        0 => String::new(),
        1 => format!(" {}", REPORT.text("compute_missing_one")),
        n => format!(" {}", REPORT.fill("compute_missing", &[("runs", &n)])),
    };
    let core_hours = format!("{:.1}", compute.core_seconds / 3600.0);
    let _ = writeln!(
        s,
        "{}\n",
        REPORT.fill(
            "compute",
            &[
                ("runs", &compute.runs),
                ("core_hours", &core_hours),
                ("cpu", &cpu),
                ("missing", &missing),
            ]
        )
    );
    let note = |figure: &str| {
        results
            .recipe_notes
            .iter()
            .find(|(f, _)| f == figure)
            .map_or("", |(_, note)| note.as_str())
    };
    s.push_str(&ntp_exp::report_section(&results.ntp_exp, note("ntp_exp")));
    s.push_str(&ablation::report_section(
        &results.ablation,
        note("ablation"),
    ));
    s.push_str(&ablation::report_section_b(&results.ablation_b));
    s.push_str(&qualitative::report_section(
        results.trace_blocks.as_ref(),
        "trace_blocks",
    ));
    s.push_str(&qualitative::sorting_report_section(
        results.trace_sorting.as_ref(),
        "trace_sorting",
    ));
    s.push_str(&structure::benchmark_section(&results.structure_benchmark));
    s.push_str(&structure::report_section(&results.structure));
    s.push_str(&crate::experiment::zoo::report_section(&results.zoo));
    let _ = writeln!(s, "{}", crate::jigsaws::report_section(&results.jigsaws));
    s.push_str(&thor_all::report_section(&results.thor_all));
    if let Some(paper) = paper {
        s.push_str(&beside_paper(results, paper));
    }
    let _ = writeln!(s, "{}\n", REPORT.text("not_yet"));
    if results.not_yet.is_empty() {
        let _ = writeln!(s, "{}", REPORT.text("not_yet_nothing"));
    }
    for (what, why) in &results.not_yet {
        let _ = writeln!(s, "- {what}: {why}");
    }
    if results.profile == Profile::Paper && !compute.multi_threaded.is_empty() {
        let runs: Vec<String> = compute
            .multi_threaded
            .iter()
            .map(|(run, threads)| {
                REPORT.fill("threads_exception", &[("run", run), ("threads", threads)])
            })
            .collect();
        let _ = writeln!(
            s,
            "\n{}",
            REPORT.fill("threads_list", &[("runs", &runs.join(", "))])
        );
    }
    s
}

/// One run's measured result, as `ntg reproduce --only` compares it.
#[derive(Debug, Clone, PartialEq)]
struct Outcome {
    /// The run folder's name.
    name: String,
    /// `(label, success, partial progress)`: one per evaluated group (fig.
    /// thor_all: per number of objects).
    measures: Vec<(String, crate::stats::SuccessRate, Option<f64>)>,
}

impl Outcome {
    fn new(run: &Path, measures: Vec<(String, crate::stats::SuccessRate, Option<f64>)>) -> Self {
        Outcome {
            name: run
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            measures,
        }
    }

    fn text(&self) -> String {
        self.measures
            .iter()
            .map(|(label, s, partial)| {
                let mut t = format!("{label}{}/{} = {:.3}", s.successes, s.trials, s.rate);
                if let Some(p) = partial {
                    t.push_str(&format!(" (partial {p:.3})"));
                }
                t
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// Same counts, and partial progress equal to 1e-9.
    fn matches(&self, other: &Outcome) -> bool {
        self.measures.len() == other.measures.len()
            && self.measures.iter().zip(&other.measures).all(|(a, b)| {
                a.0 == b.0
                    && (a.1.successes, a.1.trials) == (b.1.successes, b.1.trials)
                    && match (a.2, b.2) {
                        (Some(x), Some(y)) => (x - y).abs() < 1e-9,
                        (x, y) => x.is_none() && y.is_none(),
                    }
            })
    }
}

fn point_outcome(p: &NtpExpPoint) -> Outcome {
    Outcome::new(
        &p.run,
        vec![(String::new(), p.success, Some(p.goal_fraction))],
    )
}

/// A structure-benchmark run: its success on the test structures and on
/// the taller towers.
fn bench_outcome(b: &structure::BenchPoint) -> Outcome {
    Outcome::new(
        &b.point.run,
        vec![
            (
                "new structures: ".into(),
                b.test.success,
                Some(b.test.goal_fraction),
            ),
            (
                "taller: ".into(),
                b.taller.success,
                Some(b.taller.goal_fraction),
            ),
        ],
    )
}

fn sorting_outcome(p: &ablation::SortingPoint) -> Outcome {
    Outcome::new(
        &p.run,
        vec![(String::new(), p.success, Some(p.goal_fraction))],
    )
}

fn thor_all_outcome(line: &thor_all::ThorAllLine) -> Outcome {
    Outcome::new(
        &line.run,
        line.points
            .iter()
            .map(|p| (format!("N = {}: ", p.objects), p.success, None))
            .collect(),
    )
}

/// Every rollout run's outcome in `results`.
fn outcomes(results: &Results) -> Vec<Outcome> {
    let mut all: Vec<Outcome> = results.ntp_exp.iter().map(point_outcome).collect();
    all.extend(results.ablation.iter().map(point_outcome));
    all.extend(results.structure_benchmark.iter().map(bench_outcome));
    all.extend(results.ablation_b.iter().map(sorting_outcome));
    all.extend(results.thor_all.lines.iter().map(thor_all_outcome));
    all
}

/// Where `ntg reproduce` writes a profile's figures and report unless told
/// (`--out`): `docs/figures` for the paper profile, `docs/figures/PROFILE`
/// for the others.
pub fn default_out(profile: Profile) -> std::path::PathBuf {
    let figures = std::path::PathBuf::from("docs/figures");
    if profile == Profile::Paper {
        figures
    } else {
        figures.join(profile.name())
    }
}

/// One run of a profile, as `ntg reproduce --list` prints it and a job
/// array schedules it ([`run_list`]).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ListedRun {
    /// Its place in the list (`--array-index`).
    pub index: usize,
    /// Its figure's experiment file (`ntp_exp`, `ablation`, `ablation_b`,
    /// `thor_all`).
    pub figure: String,
    /// The run folder's name (`--only`).
    pub name: String,
    /// Its wave: every run of a wave may start once the earlier waves are
    /// done; a run of a later wave links the finished stages of the runs
    /// it lists in `after` instead of training them again.
    pub wave: usize,
    /// Runs of earlier waves whose finished stages it reuses (frame
    /// encoder, encoded episodes); without them it trains its own, to the
    /// same result.
    pub after: Vec<String>,
    /// `"video"` (trains on demo videos: more memory, a frame encoder) or
    /// `"state"`.
    pub kind: &'static str,
}

/// Every run of the rollout figures at `profile`, in an order a scheduler
/// can follow: wave by wave (ntp_exp's and ablation's video baselines
/// after the runs whose frame encoders they reuse), within a wave in the
/// order `ntg reproduce` starts them. The report (fig. jigsaws, the
/// seen-task and structure evaluations, figures) needs every run, and is
/// written by `ntg reproduce` once they are done.
pub fn run_list(profile: Profile, experiments: Source<'_>) -> anyhow::Result<Vec<ListedRun>> {
    let ntp_exp_file = ntp_exp::NtpExpExperiment::load(experiments)?;
    let ablation_file = ablation::load(experiments)?;
    let structure_file = structure::load(experiments)?;
    let ablation_b_file = ablation::AblationBExperiment::load(experiments)?;
    let thor_all_file = thor_all::ThorAllExperiment::load(experiments)?;
    let kind = |video: bool| if video { "video" } else { "state" };
    let mut runs: Vec<(String, ntp_exp::ScheduledRun)> = Vec::new();
    for file in [&ntp_exp_file, &ablation_file, &structure_file] {
        runs.extend(
            ntp_exp::schedule(file, profile)
                .into_iter()
                .map(|run| (file.name.clone(), run)),
        );
    }
    let alone = |name: String| ntp_exp::ScheduledRun {
        name,
        wave: 0,
        after: Vec::new(),
        video: false,
    };
    for seed in ablation_b_file.seeds(profile) {
        for &variant in &ablation_b_file.ablations {
            runs.push((
                "ablation_b".into(),
                alone(ablation_b_file.run_name(variant, seed)),
            ));
        }
    }
    // Fig. thor_all on video: the first run of each seed (and protocol)
    // trains the frame encoder and encodes the videos; the others of that
    // seed link them once finished, so they come after it
    // (`thor_all::run` starts them in that order too).
    let thor_all_runs = thor_all_file.runs(profile);
    for (k, &run) in thor_all_runs.iter().enumerate() {
        let video = thor_all_file.scale(profile, run.earlier)?.obs == crate::spec::ObsKind::Vid;
        let first = thor_all_runs[..k]
            .iter()
            .find(|r| (r.seed, r.earlier) == (run.seed, run.earlier));
        runs.push((
            "thor_all".into(),
            ntp_exp::ScheduledRun {
                name: thor_all_file.run_name(profile, run),
                wave: 0,
                after: match first {
                    Some(&first) if video => vec![thor_all_file.run_name(profile, first)],
                    _ => Vec::new(),
                },
                video,
            },
        ));
    }
    // A run of exactly another's configuration (fig. ablation's whole
    // model and fig. ntp_exp's point of the same scale) links that one's
    // folder once it is finished: it comes after it.
    let mut configs: Vec<(String, crate::blocks::BlocksRunConfig)> =
        ntp_exp_file.named_run_configs(profile)?;
    configs.extend(ablation_file.named_run_configs(profile)?);
    configs.extend(structure_file.named_run_configs(profile)?);
    for (k, (name, config)) in configs.iter().enumerate() {
        if let Some((twin, _)) = configs[..k].iter().find(|(_, c)| c == config)
            && let Some((_, run)) = runs.iter_mut().find(|(_, r)| &r.name == name)
            && !run.after.contains(twin)
        {
            run.after.insert(0, twin.clone());
        }
    }
    // Each run's wave is after every wave of the runs it waits for (a
    // longest path: at most one pass per run, unless they wait in a cycle).
    for pass in 0.. {
        anyhow::ensure!(
            pass <= runs.len(),
            "the runs of profile {profile:?} wait for each other in a cycle"
        );
        let waves: std::collections::BTreeMap<String, usize> =
            runs.iter().map(|(_, r)| (r.name.clone(), r.wave)).collect();
        let mut changed = false;
        for (_, run) in &mut runs {
            let wave = run
                .after
                .iter()
                .filter_map(|a| waves.get(a))
                .map(|w| w + 1)
                .fold(run.wave, usize::max);
            changed |= wave != run.wave;
            run.wave = wave;
        }
        if !changed {
            break;
        }
    }
    // Stable: within a wave, the figures' order.
    runs.sort_by_key(|(_, run)| run.wave);
    let mut seen = std::collections::BTreeSet::new();
    for (_, run) in &runs {
        anyhow::ensure!(
            seen.insert(run.name.clone()),
            "two runs of profile {profile:?} share the folder name {}",
            run.name
        );
    }
    Ok(runs
        .into_iter()
        .enumerate()
        .map(|(index, (figure, run))| ListedRun {
            index,
            figure,
            name: run.name,
            wave: run.wave,
            after: run.after,
            kind: kind(run.video),
        })
        .collect())
}

/// One line of `ntg reproduce --list`: index, name, wave, kind, and the
/// runs it comes after.
pub fn list_line(run: &ListedRun) -> String {
    let mut line = format!(
        "{:>3}  {}  (wave {}, {}",
        run.index, run.name, run.wave, run.kind
    );
    if !run.after.is_empty() {
        line.push_str(&format!("; after {}", run.after.join(", ")));
    }
    line.push(')');
    line
}

/// `ntg reproduce --only NAME...`: trains (or reuses) and evaluates only
/// the run folders `plan.only` names of the rollout figures (ntp_exp,
/// ablation (a) and (b), thor_all) at `profile`, and says of each whether
/// it matches what is committed: its run record where `plan.records` is
/// set (every episode's outcome; a record is written where none was), else
/// its result in `out/results.json` (success and partial progress). Writes
/// no figure or report. Returns one line per run.
pub fn reproduce_only(
    profile: Profile,
    plan: &Plan<'_>,
    out: &Path,
    experiments: Source<'_>,
) -> anyhow::Result<Vec<String>> {
    let only = plan.only.unwrap_or_default();
    let ntp_exp_file = ntp_exp::NtpExpExperiment::load(experiments)?;
    let ablation_file = ablation::load(experiments)?;
    let structure_file = structure::load(experiments)?;
    structure::check_benchmark(&structure_file, profile)?;
    let ablation_b_file = ablation::AblationBExperiment::load(experiments)?;
    let thor_all_file = thor_all::ThorAllExperiment::load(experiments)?;
    let known: Vec<String> = run_list(profile, experiments)?
        .into_iter()
        .map(|run| run.name)
        .collect();
    if let Some(unknown) = only.iter().find(|name| !known.contains(name)) {
        anyhow::bail!(
            "--only {unknown}: no run of that name at profile {profile:?}; its runs are {}",
            known.join(", ")
        );
    }
    // The committed records, read before a run writes its own.
    let mut recorded = std::collections::BTreeMap::new();
    if let Some(records) = plan.records {
        for name in only {
            let path = crate::record::path(records, name);
            if path.is_file() {
                recorded.insert(name.clone(), crate::record::RunRecord::read(&path)?);
            }
        }
    }
    let committed_path = out.join("results.json");
    let committed: Option<Results> = if committed_path.is_file() {
        Some(RunDir::read_json(&committed_path)?)
    } else {
        None
    };
    let mut measured: Vec<Outcome> = ntp_exp::run(&ntp_exp_file, profile, plan)?
        .iter()
        .map(point_outcome)
        .collect();
    measured.extend(
        ntp_exp::run(&ablation_file, profile, plan)?
            .iter()
            .map(point_outcome),
    );
    // The benchmark's runs with their taller towers' evaluation, so that
    // their records hold both test sets.
    let benchmark_points = ntp_exp::run(&structure_file, profile, plan)?;
    measured.extend(
        structure::run_benchmark(&benchmark_points, plan)?
            .iter()
            .map(bench_outcome),
    );
    measured.extend(
        ablation::run_b(&ablation_b_file, profile, plan)?
            .iter()
            .map(sorting_outcome),
    );
    measured.extend(
        thor_all::run(&thor_all_file, profile, plan)?
            .lines
            .iter()
            .map(thor_all_outcome),
    );
    let committed_outcomes = match &committed {
        Some(results) if results.profile == profile => outcomes(results),
        _ => Vec::new(),
    };
    measured
        .iter()
        .map(|m| {
            let verdict = match plan.records {
                Some(records) => {
                    let path = crate::record::path(records, &m.name);
                    let dir = plan.runs.join(&m.name);
                    match recorded.get(&m.name) {
                        Some(_) if crate::record::is_restored(&dir) => format!(
                            "restored from {} earlier, not retrained: move {} away to retrain it",
                            path.display(),
                            dir.display()
                        ),
                        Some(record) => {
                            use crate::record::Comparison;
                            let now = crate::record::RunRecord::of_run(&dir)?;
                            match record.compare(&now) {
                                Comparison::Same | Comparison::Extends => {
                                    format!("matches {} (every episode)", path.display())
                                }
                                Comparison::Within { common: 0, .. } => format!(
                                    "no evaluation in common with {}: nothing to compare",
                                    path.display()
                                ),
                                Comparison::Within { missing, .. } if missing.is_empty() => {
                                    format!("matches {} (every episode)", path.display())
                                }
                                Comparison::Within { missing, .. } => format!(
                                    "matches {} (every episode of the evaluations rerun; not rerun here: {})",
                                    path.display(),
                                    missing.join(", ")
                                ),
                                Comparison::Differs => {
                                    let why = record
                                        .float_mode_note()
                                        .map_or_else(String::new, |n| format!(" ({n})"));
                                    format!(
                                        "DIFFERS from {}: {}{why}",
                                        path.display(),
                                        record.summary()
                                    )
                                }
                            }
                        }
                        None => format!("no record before: written to {}", path.display()),
                    }
                }
                None => match committed_outcomes.iter().find(|c| c.name == m.name) {
                    Some(c) if c.matches(m) => format!("matches {}", committed_path.display()),
                    Some(c) => {
                        format!("DIFFERS from {}: {}", committed_path.display(), c.text())
                    }
                    None => format!(
                        "no result of this run at profile {profile:?} in {}",
                        committed_path.display()
                    ),
                },
            };
            Ok(format!("{}: {} -- {verdict}", m.name, m.text()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// README's results table is the headline table of the committed
    /// paper-profile results.
    #[test]
    fn the_readme_table_is_drawn_from_the_committed_results() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let results: Results = RunDir::read_json(&root.join("docs/figures/results.json")).unwrap();
        let table = ntp_exp::headline_table(&results.ntp_exp, HEADLINE_TASKS);
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
        let start = readme
            .find("<!-- results-table -->\n")
            .expect("the README's start marker")
            + "<!-- results-table -->\n".len();
        let end = readme
            .find("<!-- /results-table -->")
            .expect("the README's end marker");
        assert_eq!(
            &readme[start..end],
            table,
            "README.md's results table differs from docs/figures/results.json's (copy docs/figures/{HEADLINE_TABLE})"
        );
        let file = std::fs::read_to_string(root.join("docs/figures").join(HEADLINE_TABLE)).unwrap();
        assert_eq!(file, table);
        assert!(table.lines().count() > 8, "{table}");
    }

    /// `--list` (and so the Slurm script) holds every run of the paper
    /// profile once, and a run comes after every run whose finished stages
    /// it reuses.
    #[test]
    fn the_paper_list_holds_every_run_after_what_it_reuses() {
        let profile = Profile::Paper;
        let list = run_list(profile, Source::BuiltIn).unwrap();
        let mut expected = ntp_exp::NtpExpExperiment::load(Source::BuiltIn)
            .unwrap()
            .run_names(profile);
        expected.extend(ablation::load(Source::BuiltIn).unwrap().run_names(profile));
        expected.extend(structure::load(Source::BuiltIn).unwrap().run_names(profile));
        let b = ablation::AblationBExperiment::load(Source::BuiltIn).unwrap();
        for seed in b.seeds(profile) {
            expected.extend(b.ablations.iter().map(|&v| b.run_name(v, seed)));
        }
        let t = thor_all::ThorAllExperiment::load(Source::BuiltIn).unwrap();
        expected.extend(t.runs(profile).into_iter().map(|r| t.run_name(profile, r)));
        let mut names: Vec<String> = list.iter().map(|r| r.name.clone()).collect();
        names.sort();
        expected.sort();
        assert_eq!(names, expected);
        let wave_of = |name: &str| list.iter().find(|r| r.name == name).map(|r| r.wave);
        for (i, run) in list.iter().enumerate() {
            assert_eq!(run.index, i);
            assert!(
                i == 0 || list[i - 1].wave <= run.wave,
                "waves in order at {i}"
            );
            for a in &run.after {
                let w = wave_of(a).unwrap_or_else(|| panic!("{}: after {a}, not listed", run.name));
                assert!(
                    w < run.wave,
                    "{} (wave {}) after {a} (wave {w})",
                    run.name,
                    run.wave
                );
            }
        }
        let after = |name: &str| &list.iter().find(|r| r.name == name).unwrap().after;
        // A video baseline after NTG's run of its point (whose frame
        // encoder it may link), the GRU core after the reactive core's run.
        assert_eq!(after("ntp_exp-vid-ntp-1000"), &["ntp_exp-vid-1000"]);
        assert_eq!(
            after("ntp_exp-vid-cam128-ntp-gru-1000"),
            &["ntp_exp-vid-cam128-1000", "ntp_exp-vid-cam128-ntp-1000"]
        );
        // Fig. ablation's whole model links fig. ntp_exp's run of its
        // configuration; the localizer variant the executed-node run's
        // stage A.
        assert_eq!(after("ablation-state-1000"), &["ntp_exp-state-1000"]);
        assert_eq!(
            after("ntp_exp-vid-cam128-recommended-localizer-1000"),
            &["ntp_exp-vid-cam128-recommended-1000"]
        );
        assert!(after("ntp_exp-state-1000").is_empty());

        // The script: each run in exactly one array, every array after all
        // arrays of earlier waves, the report after all.
        let arrays = crate::slurm::arrays(&list);
        let mut covered: Vec<usize> = arrays.iter().flat_map(|a| a.indices.clone()).collect();
        covered.sort();
        assert_eq!(covered, (0..list.len()).collect::<Vec<_>>());
        let script = crate::slurm::submit_script(
            &list,
            &crate::slurm::ScriptSettings {
                profile: "paper".into(),
                ntg: "/opt/ntg".into(),
                runs: "/shared/runs".into(),
                out: "/shared/out".into(),
                experiments: None,
            },
        );
        for (k, a) in arrays.iter().enumerate() {
            let line = script
                .lines()
                .find(|l| l.starts_with(&format!("ids[{k}]=")))
                .unwrap();
            assert!(line.contains(&format!("\"{}\"", a.spec())), "{line}");
            let waits: Vec<String> = arrays
                .iter()
                .enumerate()
                .filter(|(_, b)| b.wave < a.wave)
                .map(|(j, _)| format!("${{ids[{j}]}}"))
                .collect();
            assert!(line.contains(&format!("\"{}\"", waits.join(":"))), "{line}");
        }
        let all: Vec<String> = (0..arrays.len())
            .map(|j| format!("${{ids[{j}]}}"))
            .collect();
        assert!(script.contains(&format!("--dependency=\"afterany:{}\"", all.join(":"))));
    }

    /// Every figure drawn from a committed results file tells its series
    /// apart: no two series of one panel share colour, marker and dash
    /// (writing a figure refuses such a pair).
    #[test]
    fn every_committed_figure_draws_each_series_of_a_panel_its_own_way() {
        let figures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
        let mut checked = 0;
        for dir in [figures.clone(), figures.join("quick")] {
            let file = dir.join("results.json");
            if !file.is_file() {
                continue;
            }
            let results: Results = RunDir::read_json(&file).unwrap();
            let out = tempfile::tempdir().unwrap();
            write_figures(&results, out.path())
                .unwrap_or_else(|e| panic!("{}: {e:#}", file.display()));
            checked += 1;
        }
        if figures.is_dir() {
            assert!(checked > 0, "no results.json in {}", figures.display());
        } else {
            eprintln!(
                "skipped: no {} (not a checkout of the repository)",
                figures.display()
            );
        }
    }

    /// A run's stage trained in stretches of its own: its threads are
    /// found in its own `sessions.jsonl`, not only the run's.
    #[test]
    fn compute_threads_names_a_stage_that_ran_on_more_threads_than_its_run() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("r");
        let line = |threads: usize| {
            format!(
                "{{\"from_epoch\":0,\"commit\":\"c\",\"machine\":\"m\",\"compute_threads\":{threads}}}\n"
            )
        };
        for stage in ["stage_a", "detector_stage", "embeddings"] {
            std::fs::create_dir_all(run.join(stage)).unwrap();
        }
        std::fs::write(run.join("sessions.jsonl"), line(1)).unwrap();
        std::fs::write(run.join("stage_a/sessions.jsonl"), line(1) + &line(2)).unwrap();
        std::fs::write(run.join("detector_stage/sessions.jsonl"), line(1)).unwrap();
        assert_eq!(compute_threads(&run), vec![(Some("stage_a".to_owned()), 2)]);
        std::fs::write(run.join("sessions.jsonl"), line(1) + &line(3)).unwrap();
        assert_eq!(
            compute_threads(&run),
            vec![(None, 3), (Some("stage_a".to_owned()), 2)]
        );
        // Lines written before threads were noted count as one thread.
        std::fs::write(
            run.join("stage_a/sessions.jsonl"),
            "{\"from_epoch\":0,\"commit\":\"c\",\"machine\":\"m\"}\n",
        )
        .unwrap();
        assert_eq!(compute_threads(&run), vec![(None, 3)]);
    }

    /// The committed paper- and quick-profile results, and variants of
    /// them that reach the report's other branches, fill every part of
    /// every template file (and none has a placeholder without a value).
    #[test]
    fn every_part_of_every_template_is_filled() {
        use crate::experiment::template::{ALL, FILLED};
        use crate::method::ntg::Variant;
        let read = |file: &str| -> Results {
            let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
            RunDir::read_json(&root.join(file)).unwrap()
        };
        let (paper, quick) = (read("results.json"), read("quick/results.json"));
        let compute = TrainingCompute {
            runs: 3,
            core_seconds: 7200.0,
            with_cpu: 2,
            cpu: 3600.0,
            wall_of_cpu_epochs: 4000.0,
            multi_threaded: vec![("ntp_exp-vid-1000".into(), 2)],
        };
        let mut paper_missing = paper.clone();
        // Two runs of the quick report that the paper results do not hold
        // (one figure), and one of another figure.
        let missing = [
            "ablation-state-recommended-1000",
            "ablation-state-no-gcn-recommended-1000",
            "ablation_b-full",
        ]
        .map(String::from);
        paper_missing.not_yet.extend(missing_runs_lines(&missing));
        // The runs the committed results already lack, then these.
        let mut expected = missing_runs(&paper);
        expected.extend(missing.iter().map(String::as_str));
        assert_eq!(missing_runs(&paper_missing), expected);
        let beside = report_of(&quick, Some(&paper_missing), 1.0, &compute);
        assert!(beside.contains(" | not trained yet |"), "{beside}");
        report_of(&paper, None, 1.0, &compute);
        let mut empty = quick.clone();
        empty.ntp_exp.clear();
        empty.ablation.clear();
        empty.ablation_b.clear();
        empty.trace_blocks = None;
        empty.trace_sorting = None;
        empty.structure.clear();
        empty.thor_all.lines.clear();
        empty.not_yet.clear();
        for runs_missing in [0, 1, 2] {
            empty.runs_missing = runs_missing;
            report(&empty, None, 1.0);
        }
        weights_needed("trace_blocks", Path::new("runs/r"));
        seeds_line();
        structure_not_in_profile_line();
        structure::benchmark_section(&structure::example_bench_points(&paper.ntp_exp[0]));
        // A video run's stage times, with and without its encoding noted.
        let mut timed = paper.ntp_exp[0].clone();
        for encoding in [
            None,
            Some(ntp_exp::EncodingTime {
                videos: 10,
                seconds: 1.0,
            }),
        ] {
            timed.stage_times = Some(ntp_exp::StageTimes {
                stages: vec![ntp_exp::StageTime {
                    stage: "stage B".into(),
                    epochs: 2,
                    seconds: 3.0,
                }],
                encoding,
            });
            ntp_exp::report_section(std::slice::from_ref(&timed), "");
        }
        let rate = crate::stats::SuccessRate::new(3, 4);
        crate::experiment::zoo::report_section(&[crate::experiment::zoo::ZooPoint {
            name: "r".into(),
            legend: "NTG (ours)".into(),
            additions: Vec::new(),
            input: "State".into(),
            recorded: rate,
            recorded_first: rate,
            success: rate,
            same_episodes: true,
        }]);
        ntp_exp::NtpExpExperiment::load(Source::BuiltIn)
            .unwrap()
            .recipe_note(Profile::Paper);
        let part = |v: Variant| {
            paper
                .ablation
                .iter()
                .filter(move |p| p.ablation == v)
                .cloned()
        };
        ablation::report_section(&part(Variant::Full).collect::<Vec<_>>(), "");
        ablation::report_section(&part(Variant::NoGcn).collect::<Vec<_>>(), "");
        // The committed lines, as the current protocol's (whichever
        // protocol they belong to in the committed results).
        let mut current = paper.thor_all.clone();
        current.scale.earlier = None;
        for line in &mut current.lines {
            line.earlier = 0;
        }
        for (learn_end, memory) in [(true, false), (false, true)] {
            let mut thor_all = current.clone();
            (thor_all.scale.learn_end, thor_all.scale.memory) = (learn_end, memory);
            thor_all::report_section(&thor_all);
        }
        // A protocol for longer demos beside an earlier one it keeps (the
        // paper's interpreter).
        let mut thor_all = current.clone();
        let mut earlier = thor_all.scale.clone();
        earlier.interpreter = Some(crate::collect::InterpreterKind::Luong);
        thor_all.scale.earlier = Some(Box::new(earlier));
        thor_all.scale.interpreter = Some(crate::collect::InterpreterKind::SteppingVideo);
        thor_all.scale.validation_objects = vec![6];
        let mut old = thor_all.lines[0].clone();
        old.earlier = 1;
        thor_all.lines.push(old);
        thor_all::report_section(&thor_all);
        // None of the current protocol's runs trained yet.
        thor_all.lines.retain(|l| l.earlier > 0);
        thor_all::report_section(&thor_all);
        let mut jigsaws = paper.jigsaws.clone();
        jigsaws.methods.reverse();
        for (m, other) in jigsaws.methods.iter_mut().zip(&paper.jigsaws.methods) {
            m.method = other.method;
        }
        jigsaws.graph.added_edges.clear();
        crate::jigsaws::report_section(&jigsaws);
        let mut points = paper.ntp_exp.clone();
        for t in points.iter_mut().filter_map(|p| p.transcription.as_mut()) {
            t.success_otherwise.trials = 0;
        }
        ntp_exp::report_section(&points, "");
        let filled = FILLED.with(|f| f.borrow().clone());
        let never: Vec<String> = ALL
            .iter()
            .flat_map(|t| t.parts().into_iter().map(|(part, _)| (t.file, part)))
            .filter(|&(file, part)| !filled.contains(&(file, part.to_owned())))
            .map(|(file, part)| format!("{file}: {part}"))
            .collect();
        assert!(never.is_empty(), "parts never filled: {never:?}");
    }

    /// The whole smoke profile end to end, then one run again with
    /// `--only`, compared with the committed results.
    #[test]
    fn the_smoke_profile_writes_every_figure_and_only_reruns_one_run() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, out) = (dir.path().join("runs"), dir.path().join("out"));
        let records = dir.path().join("records");
        let plan = Plan {
            records: Some(&records),
            restore: true,
            ..Plan::train_all(&runs, 2)
        };
        let results = reproduce(Profile::Smoke, &plan, &out, None, Source::BuiltIn, None).unwrap();
        for file in [
            "REPORT.md",
            "results.json",
            "ntp_exp.png",
            "ablation.png",
            "thor_all.png",
            "structure.png",
        ] {
            assert!(out.join(file).is_file(), "{file}");
        }
        assert_eq!(results.ablation.len(), 5);
        // The structure benchmark: its smoke runs (states, then video),
        // each scored on both test sets (8 tasks each, spread over their
        // structures).
        assert_eq!(results.structure_benchmark.len(), 2);
        for bench in &results.structure_benchmark {
            assert_eq!(bench.test.success.trials, 8);
            assert_eq!(bench.taller.success.trials, 8);
            let scored: usize = bench
                .taller
                .structures
                .iter()
                .map(|s| s.outcomes.len())
                .sum();
            assert_eq!(scored, 8);
        }
        assert_eq!(
            results.structure_benchmark[1].point.obs,
            crate::spec::ObsKind::Vid
        );
        assert_eq!(results.ablation_b.len(), 3);
        // The structure split: each curve's largest point (smoke: NTG, NTP
        // and NTP Flat on states at 10 tasks, four methods on video).
        assert_eq!(results.structure.len(), 7);
        assert!(results.structure.iter().all(|p| p.train_tasks == 10));
        let report = std::fs::read_to_string(out.join("REPORT.md")).unwrap();
        assert!(report.contains("split by structure"));
        assert!(report.contains("the structure benchmark"));
        // NTP (Detector)'s points carry their detector's held-out score,
        // and only they.
        for p in &results.ntp_exp {
            assert_eq!(
                p.detector.is_some(),
                p.method == crate::method::MethodId::NtpDetector,
                "{}",
                p.run.display()
            );
        }
        assert!(report.contains("**The detector of NTP (Detector).**"));
        // One record per rollout run.
        let outcomes = outcomes(&results);
        assert_eq!(std::fs::read_dir(&records).unwrap().count(), outcomes.len());

        // From the records alone, training nothing, in a fresh folder: the
        // same outcomes, the structure split and the traces included.
        let fresh = dir.path().join("from-records");
        let again = Plan {
            records: Some(&records),
            restore: true,
            train: false,
            ..Plan::train_all(&fresh, 2)
        };
        let restored =
            reproduce(Profile::Smoke, &again, &out, None, Source::BuiltIn, None).unwrap();
        assert!(
            again.missing.lock().unwrap().is_empty(),
            "{:?}",
            again.missing
        );
        let restored_outcomes = super::outcomes(&restored);
        assert_eq!(restored_outcomes.len(), outcomes.len());
        for (a, b) in outcomes.iter().zip(&restored_outcomes) {
            assert!(a.matches(b), "{} / {}", a.text(), b.text());
        }
        assert_eq!(restored.structure.len(), 7);
        assert_eq!(
            restored
                .ntp_exp
                .iter()
                .map(|p| &p.detector)
                .collect::<Vec<_>>(),
            results
                .ntp_exp
                .iter()
                .map(|p| &p.detector)
                .collect::<Vec<_>>(),
            "the detector's score comes back from the records"
        );
        assert_eq!(restored.trace_blocks, results.trace_blocks);
        // Nothing finished and nothing recorded: every run is listed as
        // missing, and nothing is trained.
        let empty_runs = dir.path().join("empty");
        let none = Plan {
            train: false,
            ..Plan::train_all(&empty_runs, 2)
        };
        let out_empty = dir.path().join("out-empty");
        std::fs::create_dir_all(&out_empty).unwrap();
        std::fs::copy(out.join("jigsaws.json"), out_empty.join("jigsaws.json")).unwrap();
        let empty = reproduce(
            Profile::Smoke,
            &none,
            &out_empty,
            None,
            Source::BuiltIn,
            Some(&results),
        )
        .unwrap();
        assert!(empty.ntp_exp.is_empty() && empty.thor_all.lines.is_empty());
        assert_eq!(none.missing.lock().unwrap().len(), outcomes.len());
        assert!(
            empty.not_yet[0].0.contains("not trained yet"),
            "{:?}",
            empty.not_yet
        );
        assert_eq!(empty.runs_missing, outcomes.len());
        let mut missing = missing_runs(&empty);
        missing.sort_unstable();
        let mut names: Vec<&str> = outcomes.iter().map(|o| o.name.as_str()).collect();
        names.sort_unstable();
        assert_eq!(missing, names, "the missing runs' names read back");
        assert_eq!(restored.runs_missing, 0);
        let report = std::fs::read_to_string(out_empty.join("REPORT.md")).unwrap();
        assert!(report.contains("## Beside the paper profile"), "{report}");
        assert!(
            report.contains(&format!(
                "{} more runs of this profile are not trained yet",
                outcomes.len()
            )),
            "{report}"
        );

        let only = ["ablation_b-no-gcn".to_owned()];
        let lines = reproduce_only(
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                ..Plan::train_all(&runs, 1)
            },
            &out,
            Source::BuiltIn,
        )
        .unwrap();
        assert_eq!(lines.len(), 1);
        assert!(lines[0].starts_with("ablation_b-no-gcn: "), "{}", lines[0]);
        assert!(lines[0].contains("-- matches"), "{}", lines[0]);
        // A rerun in a fresh runs folder trains it again, to the same result
        // (the committed results.json; then its record, episode by episode).
        let only = ["ntp_exp-state-ntp-5".to_owned()];
        let lines = reproduce_only(
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                ..Plan::train_all(&dir.path().join("fresh"), 1)
            },
            &out,
            Source::BuiltIn,
        )
        .unwrap();
        assert!(lines[0].contains("-- matches"), "{}", lines[0]);
        let lines = reproduce_only(
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                records: Some(&records),
                ..Plan::train_all(&dir.path().join("fresh-2"), 1)
            },
            &out,
            Source::BuiltIn,
        )
        .unwrap();
        assert!(lines[0].contains("(every episode)"), "{}", lines[0]);
        // A point whose record also holds the checks of a curve's largest
        // point (the structure split): rerun alone, it matches on its main
        // evaluation, says what it did not rerun, and the record is kept.
        let only = ["ntp_exp-state-ntp-10".to_owned()];
        let record_file = crate::record::path(&records, &only[0]);
        let before = std::fs::read(&record_file).unwrap();
        let lines = reproduce_only(
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                records: Some(&records),
                ..Plan::train_all(&dir.path().join("fresh-3"), 1)
            },
            &out,
            Source::BuiltIn,
        )
        .unwrap();
        assert!(
            lines[0].contains(
                "(every episode of the evaluations rerun; not rerun here: eval/structure-"
            ),
            "{}",
            lines[0]
        );
        assert_eq!(std::fs::read(&record_file).unwrap(), before);
        let only = ["nope".to_owned()];
        let err = reproduce_only(
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                ..Plan::train_all(&runs, 1)
            },
            &out,
            Source::BuiltIn,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("--only nope") && err.contains("ntp_exp-state-5"),
            "{err}"
        );
    }
}
