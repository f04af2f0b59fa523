//! Fig. "ablation": (a) NTG trained whole and trained without each of its
//! parts (demo interpreter, node localizer, edge classifier, GCN), block
//! stacking, scored on the same unseen tasks; (b) object sorting whole,
//! without the GCN and without the edge classifier, on scenes that need
//! another order than the demo's. Panel (a)'s runs are listed in
//! `experiments/ablation.toml`, in the form of fig. "ntp_exp" (a panel's
//! `ablations`), and are trained and evaluated by [`ntp_exp::run`]; panel
//! (b)'s in `experiments/ablation_b.toml` ([`AblationBExperiment`], run by
//! [`run_b`]). This module draws both and checks the paper's trends.

use std::fmt::Write as _;
use std::path::Path;

use std::path::PathBuf;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

use crate::domain::DomainId;
use crate::domain::sorting::{self, SortingRunConfig};
use crate::experiment::ntp_exp::{self, NtpExpExperiment, NtpExpPoint};
use crate::experiment::template::ABLATION;
use crate::figure::{Bar, GroupedBars, Point};
use crate::method::ntg::Variant;
use crate::run_dir::RunDir;
use crate::spec::Profile;
use crate::stats::SuccessRate;

/// Reads `ablation.toml` from `source`.
pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<NtpExpExperiment> {
    NtpExpExperiment::load_named("ablation", source)
}

/// Writes the figure as `stem.svg` and `stem.png`, grouped bars: panel
/// (a), success (with its interval: over seeds, from the lowest seed's end
/// to the highest's) and goals met per block-stacking variant, and panel
/// (b), success and objects sorted per sorting variant.
pub fn write_figure(
    points: &[NtpExpPoint],
    sorting: &[SortingPoint],
    stem: &Path,
) -> anyhow::Result<()> {
    // (variant, success point, partial progress)
    let panel = |title: &str, rows: Vec<(Variant, Point, f64)>, partial: &str| GroupedBars {
        title: title.into(),
        y_label: format!("unseen tasks: success, {partial}"),
        categories: rows.iter().map(|r| short_name(r.0).to_owned()).collect(),
        series: vec![
            (
                "success (95% interval)".into(),
                rows.iter()
                    .map(|r| Bar {
                        label: short_name(r.0).into(),
                        value: r.1.y,
                        lo: r.1.lo,
                        hi: r.1.hi,
                    })
                    .collect(),
            ),
            (
                partial.into(),
                rows.iter()
                    .map(|r| Bar {
                        label: short_name(r.0).into(),
                        value: r.2,
                        lo: r.2,
                        hi: r.2,
                    })
                    .collect(),
            ),
        ],
    };
    // Panel (a): one point per variant, the mean over its seeds.
    let mut variants: Vec<Variant> = Vec::new();
    for p in points {
        if !variants.contains(&p.ablation) {
            variants.push(p.ablation);
        }
    }
    let a = variants
        .into_iter()
        .flat_map(|v| {
            ntp_exp::by_point(points.iter().filter(move |p| p.ablation == v))
                .into_iter()
                .map(move |g| (v, g.success_point(), g.mean(|p| p.goal_fraction)))
        })
        .collect();
    // Panel (b): one point per variant, the mean over its seeds with a bar
    // over their intervals (one seed: its interval).
    let mut sorted: Vec<Variant> = Vec::new();
    for p in sorting {
        if !sorted.contains(&p.ablation) {
            sorted.push(p.ablation);
        }
    }
    let b = sorted
        .into_iter()
        .map(|v| {
            let seeds: Vec<&SortingPoint> = sorting.iter().filter(|p| p.ablation == v).collect();
            let n = seeds.len() as f64;
            let point = match seeds.as_slice() {
                [one] => Point::success(0.0, &one.success),
                many => Point {
                    x: 0.0,
                    y: many.iter().map(|p| p.success.rate).sum::<f64>() / n,
                    lo: many.iter().map(|p| p.success.ci_low).fold(1.0, f64::min),
                    hi: many.iter().map(|p| p.success.ci_high).fold(0.0, f64::max),
                },
            };
            (
                v,
                point,
                seeds.iter().map(|p| p.goal_fraction).sum::<f64>() / n,
            )
        })
        .collect();
    // Panel (a)'s title names the recipe its runs share when it is not the
    // paper's (the quick profile's, whose paper-recipe runs score 0).
    let title_a = match points.first().map(|p| p.recipe) {
        Some(recipe)
            if recipe != crate::blocks::Recipe::Paper
                && points.iter().all(|p| p.recipe == recipe) =>
        {
            format!(
                "(a) block stacking: NTG without each part, {} recipe",
                recipe.name()
            )
        }
        _ => "(a) block stacking: NTG without each part".to_owned(),
    };
    crate::figure::write_grouped_bars(
        &[
            panel(&title_a, a, "goals met"),
            panel(
                "(b) object sorting, another order than the demo's",
                b,
                "objects sorted",
            ),
        ],
        stem,
    )
}

/// A variant's name on the figure's axis.
fn short_name(ablation: Variant) -> &'static str {
    match ablation {
        Variant::NoDemoInterpreter => "no demo int.",
        Variant::NoNodeLocalizer => "no node loc.",
        Variant::NoEdgeClassifier => "no edge cls.",
        Variant::NoGcn => "no GCN",
        _ => "full",
    }
}

/// The paper's trend, each part checked on `points` (Markdown lines):
/// holds / does not hold, with the numbers. A variant with several seeds
/// counts as their mean success; a part is "near zero" when every seed's
/// interval ends below a tenth, and the whole model is "best" when its
/// mean success is at least every variant's.
pub fn trend_checks(points: &[NtpExpPoint]) -> Vec<String> {
    let of = |v: Variant| {
        let seeds: Vec<&NtpExpPoint> = points.iter().filter(|p| p.ablation == v).collect();
        (!seeds.is_empty()).then_some(seeds)
    };
    let mean = |seeds: &[&NtpExpPoint]| crate::stats::mean_rate(&ntp_exp::seed_rates(seeds));
    let Some(full) = of(Variant::Full) else {
        return vec![ABLATION.text("whole_model_not_run")];
    };
    let rate = |seeds: &[&NtpExpPoint]| match seeds {
        [p] => format!(
            "{:.3} ({:.3}–{:.3})",
            p.success.rate, p.success.ci_low, p.success.ci_high
        ),
        _ => crate::stats::seeds_text(&ntp_exp::seed_rates(seeds)),
    };
    let holds = |ok: bool| if ok { "holds" } else { "does not hold" };
    let mut lines = Vec::new();
    for v in [Variant::NoDemoInterpreter, Variant::NoNodeLocalizer] {
        if let Some(p) = of(v) {
            lines.push(ABLATION.fill(
                "near_zero",
                &[
                    ("part", &ntp_exp::ablation_part(v)),
                    ("verdict", &holds(p.iter().all(|p| p.success.ci_high < 0.1))),
                    ("rate", &rate(&p)),
                ],
            ));
        }
    }
    for v in [Variant::NoEdgeClassifier, Variant::NoGcn] {
        if let (Some(p), Some(drop_to_zero)) = (
            of(v),
            [Variant::NoDemoInterpreter, Variant::NoNodeLocalizer]
                .iter()
                .filter_map(|&z| of(z))
                .map(|z| mean(&z))
                .reduce(f64::max),
        ) {
            let smaller = mean(&p) <= mean(&full) && mean(&p) > drop_to_zero;
            lines.push(ABLATION.fill(
                "smaller_drop",
                &[
                    ("part", &ntp_exp::ablation_part(v)),
                    ("verdict", &holds(smaller)),
                    ("rate", &rate(&p)),
                    ("full", &rate(&full)),
                    ("near_zero", &format!("{drop_to_zero:.3}")),
                ],
            ));
        }
    }
    let variants: Vec<Variant> = points
        .iter()
        .map(|p| p.ablation)
        .fold(Vec::new(), |mut v, a| {
            if !v.contains(&a) {
                v.push(a);
            }
            v
        });
    lines.push(whole_model_best(variants.len(), rate(&full), || {
        variants
            .iter()
            .filter_map(|&v| of(v))
            .all(|seeds| mean(&seeds) <= mean(&full))
    }));
    lines
}

/// The line "the whole model is best": checked only against at least one
/// other trained variant (`variants` counts the whole model too).
fn whole_model_best(variants: usize, full: String, best: impl FnOnce() -> bool) -> String {
    if variants < 2 {
        ABLATION.fill("best_not_checked", &[("full", &full)])
    } else {
        let verdict = if best() { "holds" } else { "does not hold" };
        ABLATION.fill("best", &[("verdict", &verdict), ("full", &full)])
    }
}

/// The report section of fig. "ablation" (Markdown); `recipe_note` says
/// what the file changes in the recipe.
pub fn report_section(points: &[NtpExpPoint], recipe_note: &str) -> String {
    let mut s = match super::open_section(&ABLATION.text("head"), !points.is_empty()) {
        Ok(head) => head,
        Err(whole) => return whole,
    };
    let _ = writeln!(s, "{}", ABLATION.text("table_head"));
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} |",
            ntp_exp::row_name(p),
            ntp_exp::scale_cells(p),
            ntp_exp::additions_cell(p),
            ntp_exp::outcome_cells(p)
        );
    }
    let notes = ABLATION.fill("notes", &[("recipe_note", &recipe_note)]);
    let _ = writeln!(s, "\n{notes}\n");
    for line in trend_checks(points) {
        let _ = writeln!(s, "- {line}");
    }
    let _ = writeln!(s);
    ntp_exp::bullet_list(
        &mut s,
        &crate::experiment::template::NTP_EXP.text("transcription_title"),
        ntp_exp::transcription_lines(points),
    );
    ntp_exp::bullet_list(
        &mut s,
        &crate::experiment::template::NTP_EXP.text("learning_title"),
        ntp_exp::learning_lines(points),
    );
    s
}

/// Panel (b)'s experiment file (`experiments/ablation_b.toml`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AblationBExperiment {
    /// Always object sorting.
    pub domain: DomainId,
    /// Seed of every run's weights and shuffling.
    pub seed: u64,
    /// The variants trained, in the figure's order.
    pub ablations: Vec<Variant>,
    /// The scale of each profile.
    pub profiles: crate::experiment::Profiles<AblationBScale>,
    /// Where the file was read from (for messages).
    #[serde(skip)]
    pub origin: String,
}

/// Panel (b)'s scale under a profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AblationBScale {
    /// Training maps (a prefix of the sorting pool).
    pub train_tasks: usize,
    /// Demonstrations per map.
    pub demos_per_task: usize,
    /// Training epochs.
    pub epochs: usize,
    /// Validation episodes (presorted scenes of the validation maps).
    pub validation_episodes: usize,
    /// Test episodes (presorted scenes of the unseen test maps).
    pub test_episodes: usize,
    /// Seeds trained besides the experiment's `seed` (each variant once
    /// per seed, in folders `ablation_b-VARIANT-seedS`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extra_seeds: Vec<u64>,
}

impl AblationBExperiment {
    /// Reads `ablation_b.toml` from `source`.
    pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<Self> {
        let (mut experiment, origin): (Self, String) =
            crate::experiment::load("ablation_b", source)?;
        experiment.origin = origin;
        Ok(experiment)
    }

    /// The seeds of `profile`'s runs: the experiment's, then the extra.
    pub fn seeds(&self, profile: Profile) -> Vec<u64> {
        std::iter::once(self.seed)
            .chain(self.profiles.get(profile).extra_seeds.iter().copied())
            .collect()
    }

    /// The run folder name of `ablation` with `seed`.
    pub fn run_name(&self, ablation: Variant, seed: u64) -> String {
        let base = format!("ablation_b-{}", ablation.name());
        crate::experiment::seeded_name(base, seed, self.seed)
    }

    /// The run configuration of `ablation` with `seed` at `profile`,
    /// checked.
    pub fn run_config(
        &self,
        profile: Profile,
        ablation: Variant,
        seed: u64,
    ) -> anyhow::Result<SortingRunConfig> {
        anyhow::ensure!(
            self.domain == DomainId::Sorting,
            "{}: fig. ablation (b) is an object-sorting figure (domain = \"sorting\")",
            self.origin
        );
        let scale = self.profiles.get(profile);
        let config = SortingRunConfig {
            domain: "sorting".into(),
            train_tasks: scale.train_tasks,
            demos_per_task: scale.demos_per_task,
            failures: true,
            model_seed: seed,
            state_hidden_layers: 3,
            pairwise: true,
            validation_episodes: scale.validation_episodes,
            validate_every: 1,
            ablation,
            step_limit: sorting::STEP_LIMIT,
            optim: crate::fit::OptimConfig {
                cosine_decay: false,
                ..crate::fit::OptimConfig::stage(scale.epochs, 32, 3e-3, seed, 1)
            },
        };
        config
            .validate()
            .map_err(|e| anyhow::anyhow!("{}: {e}", self.origin))?;
        Ok(config)
    }
}

/// One variant's point of panel (b).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SortingPoint {
    /// The part NTG was trained without (`full`: none).
    pub ablation: Variant,
    /// Seed of the run's weights and shuffling (results written before
    /// seeds: 0).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub seed: u64,
    /// Training maps, demos per map, epochs.
    pub train_tasks: usize,
    /// Demonstrations per map.
    pub demos_per_task: usize,
    /// Epochs trained.
    pub epochs: usize,
    /// The epoch (from 0) selected on validation; `None` = the last.
    pub selected_epoch: Option<usize>,
    /// Success on the test episodes.
    pub success: SuccessRate,
    /// Mean fraction of objects in their bins at the end.
    pub goal_fraction: f64,
    /// A reduced profile: the same test scenes with the run's initial
    /// weights (see [`ntp_exp::NtpExpPoint::untrained`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub untrained: Option<ntp_exp::Untrained>,
    /// Core-seconds of training epochs
    /// ([`crate::run_dir::RunDir::epoch_compute_seconds`]: CPU time where
    /// recorded, else wall time; from the run's metrics, so a reused run
    /// reports its original cost).
    pub train_seconds: f64,
    /// Run folder.
    pub run: PathBuf,
}

/// Trains (or reuses) and evaluates every variant of panel (b) at
/// `profile` (or those whose folders `only` names), `jobs` at a time, in
/// folders `ablation_b-VARIANT` under `runs`.
pub fn run_b(
    experiment: &AblationBExperiment,
    profile: Profile,
    plan: &crate::experiment::Plan<'_>,
) -> anyhow::Result<Vec<SortingPoint>> {
    let scale = experiment.profiles.get(profile);
    let wave: Vec<crate::experiment::Job<'_, Option<SortingPoint>>> = experiment
        .seeds(profile)
        .into_iter()
        .flat_map(|seed| experiment.ablations.iter().map(move |&a| (a, seed)))
        .filter(|&(ablation, seed)| plan.selected(&experiment.run_name(ablation, seed)))
        .map(|(ablation, seed)| {
            Box::new(move || {
                let config = experiment.run_config(profile, ablation, seed)?;
                let name = experiment.run_name(ablation, seed);
                let eval_file = format!("full-{}.json", scale.test_episodes);
                let Some(dir) = plan.prepare(&name, &config, &eval_file)? else {
                    return Ok(None);
                };
                let run = RunDir::open_or_create(&dir, &config)?;
                // One writer for training, evaluation and the record.
                let _writer = run.lock()?;
                eprintln!(
                    "ablation (b) ({}, {} maps x {} demos, {} epochs): training -> {}",
                    ablation.name(),
                    config.train_tasks,
                    config.demos_per_task,
                    config.optim.epochs,
                    dir.display()
                );
                let device = crate::spec::device().autodiff();
                let (_, _, test) = sorting::split()?;
                let episodes = sorting::episodes(&test, scale.test_episodes, sorting::TEST_SEEDS);
                let result = run.cached_eval(&eval_file, || {
                    let model =
                        sorting::train_run(&run, &config, &device, |r| eprintln!("  [{name}] {r}"))?;
                    sorting::evaluate(&model, &config, &episodes, Variant::Full)
                })?;
                // A reduced profile shows that each variant's training
                // moved it: the same scenes at its initial weights.
                let untrained = super::untrained_eval(&run, profile, &eval_file, || {
                    let model = ntg_model::NtgModel::load(run.initial_dir(), &device)
                        .with_context(|| {
                            format!("loading the untrained model of {}", dir.display())
                        })?;
                    sorting::evaluate(&model, &config, &episodes, Variant::Full)
                })?
                .map(|u| ntp_exp::Untrained {
                    success: u.success,
                    goal_fraction: u.goal_fraction,
                });
                plan.finish(&dir)?;
                eprintln!(
                    "  [{name}] success on {} part-sorted test scenes: {:.3} ({:.3}-{:.3}); objects sorted {:.3}",
                    result.success.trials,
                    result.success.rate,
                    result.success.ci_low,
                    result.success.ci_high,
                    result.goal_fraction
                );
                Ok(Some(SortingPoint {
                    ablation,
                    seed,
                    train_tasks: config.train_tasks,
                    demos_per_task: config.demos_per_task,
                    epochs: config.optim.epochs,
                    selected_epoch: crate::fit::selected_epoch(&run)?.map(|r| r.epoch),
                    success: result.success,
                    goal_fraction: result.goal_fraction,
                    untrained,
                    train_seconds: run.epoch_compute_seconds()?,
                    run: dir,
                }))
            }) as crate::experiment::Job<'_, _>
        })
        .collect();
    Ok(
        crate::experiment::in_parallel("ablation (b)", &plan.slots, wave)?
            .into_iter()
            .flatten()
            .collect(),
    )
}

fn is_zero(seed: &u64) -> bool {
    *seed == 0
}

/// Panel (b)'s trend (Markdown lines), each variant over its seeds: no
/// task completed by any seed without the edge classifier; every seed's
/// interval without the GCN below every seed's of the whole model; the
/// whole model's mean success at least every variant's.
pub fn trend_checks_b(points: &[SortingPoint]) -> Vec<String> {
    let of = |v: Variant| {
        let rates: Vec<SuccessRate> = points
            .iter()
            .filter(|p| p.ablation == v)
            .map(|p| p.success)
            .collect();
        (!rates.is_empty()).then_some(rates)
    };
    let rate = |rates: &[SuccessRate]| match rates {
        [r] => format!("{:.3} ({:.3}–{:.3})", r.rate, r.ci_low, r.ci_high),
        _ => crate::stats::seeds_text(rates),
    };
    let holds = |ok: bool| if ok { "holds" } else { "does not hold" };
    let mut lines = Vec::new();
    if let Some(p) = of(Variant::NoEdgeClassifier) {
        lines.push(ABLATION.fill(
            "b_no_edge_classifier",
            &[
                ("verdict", &holds(p.iter().all(|r| r.successes == 0))),
                ("rate", &rate(&p)),
            ],
        ));
    }
    if let (Some(full), Some(p)) = (of(Variant::Full), of(Variant::NoGcn)) {
        let full_low = crate::stats::interval_span(&full).0;
        lines.push(ABLATION.fill(
            "b_no_gcn",
            &[
                ("verdict", &holds(p.iter().all(|r| r.ci_high < full_low))),
                ("rate", &rate(&p)),
                ("full", &rate(&full)),
            ],
        ));
    }
    if let Some(full) = of(Variant::Full) {
        let mut variants: Vec<Variant> = points.iter().map(|p| p.ablation).collect();
        variants.sort_by_key(|v| v.name());
        variants.dedup();
        let whole = crate::stats::mean_rate(&full);
        lines.push(whole_model_best(variants.len(), rate(&full), || {
            variants
                .iter()
                .filter_map(|&v| of(v))
                .all(|r| crate::stats::mean_rate(&r) <= whole)
        }));
    }
    lines
}

/// Panel (b)'s report section (Markdown).
pub fn report_section_b(points: &[SortingPoint]) -> String {
    let mut s = match super::open_section(&ABLATION.text("b_head"), !points.is_empty()) {
        Ok(head) => head,
        Err(whole) => return whole,
    };
    let _ = writeln!(s, "{}", ABLATION.text("b_table_head"));
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} ({}) | {:.0} s | {} | {:.3} ({:.3}–{:.3}) | {:.3} |",
            b_row_name(p),
            p.train_tasks,
            p.demos_per_task,
            p.epochs,
            p.selected_epoch
                .map_or_else(|| "last".to_owned(), |e| (e + 1).to_string()),
            p.train_seconds,
            p.success.trials,
            p.success.rate,
            p.success.ci_low,
            p.success.ci_high,
            p.goal_fraction
        );
    }
    let notes = ABLATION.fill(
        "b_notes",
        &[
            ("train", &sorting::TRAIN_POOL),
            ("validation", &sorting::VALIDATION_TASKS),
            ("test", &sorting::TEST_TASKS),
            ("step_limit", &sorting::STEP_LIMIT),
        ],
    );
    let _ = writeln!(s, "\n{notes}\n");
    for line in trend_checks_b(points) {
        let _ = writeln!(s, "- {line}");
    }
    let _ = writeln!(s);
    ntp_exp::bullet_list(
        &mut s,
        &ABLATION.text("b_learning_title"),
        learning_lines_b(points),
    );
    s
}

/// One line per panel (b) point whose untrained model was scored: its
/// success and objects sorted beside the untrained model's.
fn learning_lines_b(points: &[SortingPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let u = p.untrained.as_ref()?;
            let verdict = super::learning_verdict(&p.success, &u.success);
            Some(ABLATION.fill(
                "b_learning_line",
                &[
                    ("variant", &b_row_name(p)),
                    ("success", &format!("{:.3}", p.success.rate)),
                    ("low", &format!("{:.3}", p.success.ci_low)),
                    ("high", &format!("{:.3}", p.success.ci_high)),
                    ("untrained", &format!("{:.3}", u.success.rate)),
                    ("sorted", &format!("{:.3}", p.goal_fraction)),
                    ("untrained_sorted", &format!("{:.3}", u.goal_fraction)),
                    ("verdict", &verdict),
                ],
            ))
        })
        .collect()
}

/// A panel (b) point's row name: its variant, and its seed if not 0.
fn b_row_name(p: &SortingPoint) -> String {
    let name = ntp_exp::curve_name(
        crate::method::MethodId::Ntg,
        crate::blocks::Recipe::Paper,
        p.ablation,
    );
    match p.seed {
        0 => name,
        seed => format!("{name}, seed {seed}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::Plan;
    use crate::spec::Profile;

    #[test]
    fn the_built_in_file_trains_every_part_away_from_the_same_run() {
        let experiment = load(crate::experiment::Source::BuiltIn).unwrap();
        let ntp_exp = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let panel = &experiment.profiles.get(Profile::Quick).panels[0];
        let runs = experiment.runs_of(panel);
        assert_eq!(runs.len(), 5);
        // The whole model is fig. ntp_exp's quick state point of the
        // recommended recipe at 1000 tasks (the run is shared), in a folder
        // of its own.
        let state = &ntp_exp.profiles.get(Profile::Quick).panels[1];
        let whole = (crate::method::MethodId::Ntg, Variant::Full);
        assert_eq!(
            experiment
                .run_config(Profile::Quick, panel, whole, 1000)
                .unwrap(),
            ntp_exp
                .run_config(Profile::Quick, state, whole, 1000)
                .unwrap()
        );
        assert_eq!(
            experiment.run_name(panel, whole, 1000),
            "ablation-state-recommended-1000"
        );
        for &(method, ablation) in &runs[1..] {
            let c = experiment
                .run_config(Profile::Quick, panel, (method, ablation), 1000)
                .unwrap();
            assert_eq!(c.ablation, ablation);
            assert_eq!(
                experiment.run_name(panel, (method, ablation), 1000),
                format!("ablation-state-{}-recommended-1000", ablation.name())
            );
        }
        // An evaluation setting is not a trained variant.
        let err = experiment
            .run_config(
                Profile::Quick,
                panel,
                (crate::method::MethodId::Ntg, Variant::ExecutedNode),
                1000,
            )
            .unwrap_err();
        assert!(format!("{err:#}").contains("ablations are NTG"), "{err:#}");
    }

    #[test]
    fn the_smoke_profile_trains_each_variant_and_the_report_checks_the_trend() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = load(crate::experiment::Source::BuiltIn).unwrap();
        let panel = &mut experiment.profiles.smoke.panels[0];
        panel.train_tasks = vec![2];
        panel.epochs = 1;
        panel.test_tasks = 2;
        panel.ablations = Some(vec![Variant::Full, Variant::NoGcn]);
        let runs = dir.path().join("runs");
        let points = ntp_exp::run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 2)).unwrap();
        assert_eq!(
            points.iter().map(|p| p.ablation).collect::<Vec<_>>(),
            vec![Variant::Full, Variant::NoGcn]
        );
        let no_gcn = &points[1];
        assert!(no_gcn.run.ends_with("ablation-state-no-gcn-2"));
        let saved: ntg_model::NtgConfig =
            crate::run_dir::RunDir::read_json(&no_gcn.run.join("checkpoint").join("config.json"))
                .unwrap();
        assert!(!saved.ablation.gcn, "the switch is saved with the model");
        let report = report_section(&points, "RECIPE");
        assert!(report.contains("NTG (ours) without the GCN"), "{report}");
        assert!(report.contains("The whole model is best: **"), "{report}");
        write_figure(&points, &[], &dir.path().join("ablation")).unwrap();
        assert!(dir.path().join("ablation.svg").is_file());
    }

    #[test]
    fn the_trend_counts_each_variant_over_its_seeds() {
        let point = |ablation, seed, successes: usize| NtpExpPoint {
            method: crate::method::MethodId::Ntg,
            ablation,
            recipe: crate::blocks::Recipe::Paper,
            obs: crate::spec::ObsKind::State,
            seed,
            train_tasks: 1000,
            demos_per_task: 100,
            epochs: 30,
            selected_epoch: None,
            permute_objects: false,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ntp_core: crate::method::ntp::NtpCoreKind::Reactive,
            executed_node: false,
            success: crate::stats::SuccessRate::from_outcomes((0..1000).map(|i| i < successes)),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            stage_times: None,
            transcription: None,
            seen: None,
            detector: None,
            decisions: None,
            curve: None,
            run: std::path::PathBuf::new(),
        };
        let points = [
            point(Variant::Full, 0, 600),
            point(Variant::Full, 1, 800),
            point(Variant::NoGcn, 0, 650),
            point(Variant::NoDemoInterpreter, 0, 10),
            point(Variant::NoDemoInterpreter, 1, 150),
        ];
        let lines = trend_checks(&points);
        // One seed of two far from zero: not near zero.
        assert!(
            lines[0].starts_with("Without the demo interpreter almost no task is completed: **does not hold** (0.080 (mean of 2 seeds: 0.010, 0.150))"),
            "{lines:?}"
        );
        // 0.65 is below the whole model's mean 0.7, though above seed 0.
        assert!(lines[1].contains("**holds**"), "{lines:?}");
        assert!(
            lines[2].contains(
                "The whole model is best: **holds** (0.700 (mean of 2 seeds: 0.600, 0.800))"
            ),
            "{lines:?}"
        );
    }

    #[test]
    fn the_whole_model_is_best_only_against_another_variant() {
        let line = |n, best| whole_model_best(n, "0.6".into(), || best);
        assert!(
            line(1, true).contains("**not checked**"),
            "{}",
            line(1, true)
        );
        assert!(line(2, true).contains("**holds**"));
        assert!(line(3, false).contains("**does not hold**"));
    }

    #[test]
    fn panel_b_trend_counts_each_variant_over_its_seeds() {
        let point = |ablation: Variant, seed: u64, successes: usize| SortingPoint {
            ablation,
            seed,
            train_tasks: 10,
            demos_per_task: 2,
            epochs: 1,
            selected_epoch: None,
            success: SuccessRate::new(successes, 100),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            run: PathBuf::new(),
        };
        // A second seed of the whole model is not "another variant": the
        // whole model is best by its mean over both seeds.
        let points = [
            point(Variant::Full, 1, 80),
            point(Variant::Full, 0, 60),
            point(Variant::NoGcn, 0, 30),
            point(Variant::NoEdgeClassifier, 0, 0),
        ];
        let lines = trend_checks_b(&points).join("\n");
        assert!(
            lines.contains(
                "The whole model is best: **holds** (0.700 (mean of 2 seeds: 0.800, 0.600))"
            ),
            "{lines}"
        );
        assert!(
            lines.contains(
                "stuck on the unseen order, well below the whole model (intervals apart): **holds**"
            ),
            "{lines}"
        );
        // A variant above the whole model's mean breaks it.
        let points = [
            point(Variant::Full, 0, 30),
            point(Variant::Full, 1, 50),
            point(Variant::NoGcn, 0, 45),
        ];
        let lines = trend_checks_b(&points).join("\n");
        assert!(
            lines.contains("The whole model is best: **does not hold**"),
            "{lines}"
        );
        // Within one seed a variant above the whole model breaks it.
        let points = [point(Variant::Full, 0, 30), point(Variant::NoGcn, 0, 60)];
        let lines = trend_checks_b(&points).join("\n");
        assert!(
            lines.contains("The whole model is best: **does not hold**"),
            "{lines}"
        );
    }

    #[test]
    fn panel_b_trains_each_sorting_variant_and_checks_the_trend() {
        let dir = tempfile::tempdir().unwrap();
        let experiment = AblationBExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let quick = experiment
            .run_config(Profile::Quick, Variant::NoGcn, 0)
            .unwrap();
        assert_eq!((quick.train_tasks, quick.optim.epochs), (150, 20));
        assert_eq!(experiment.seeds(Profile::Quick), vec![0]);
        assert_eq!(experiment.seeds(Profile::Paper), vec![0, 1, 2]);
        assert_eq!(
            experiment.run_name(Variant::NoGcn, 1),
            "ablation_b-no-gcn-seed1"
        );
        let seeded = experiment
            .run_config(Profile::Paper, Variant::NoGcn, 1)
            .unwrap();
        assert_eq!((seeded.model_seed, seeded.optim.seed), (1, 1));
        assert!(
            experiment
                .run_config(Profile::Quick, Variant::ExecutedNode, 0)
                .is_err()
        );
        let runs = dir.path().join("runs");
        let points = run_b(&experiment, Profile::Smoke, &Plan::train_all(&runs, 2)).unwrap();
        assert_eq!(
            points.iter().map(|p| p.ablation).collect::<Vec<_>>(),
            experiment.ablations
        );
        assert!(points.iter().all(|p| p.success.trials == 3));
        assert!(points[1].run.ends_with("ablation_b-no-gcn"));
        // Reused, not trained again.
        assert_eq!(
            run_b(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap(),
            points
        );
        let report = report_section_b(&points);
        assert!(
            report.contains("Without the edge classifier no task completes: **"),
            "{report}"
        );
        write_figure(&[], &points, &dir.path().join("ablation")).unwrap();
    }
}
