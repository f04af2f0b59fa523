//! `ntg reproduce`: every figure this build makes, from its experiment
//! file ([`crate::experiment`]), run through the same training and
//! evaluation code as `ntg train` / `ntg eval`, written as figures, one
//! `results.json` and one `REPORT.md`.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::experiment::Source;
use crate::experiment::ntp_exp::{self, NtpExpPoint};
use crate::experiment::thor_all::{self, ThorAllResult};
use crate::experiment::{ablation, qualitative};
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
    /// Fig. "jigsaws": cross-task NLL on Needle Passing (issue 7).
    pub jigsaws: crate::jigsaws::JigsawsResult,
    /// Fig. "thor_all" (b), NTG and the Flat Policy.
    pub thor_all: ThorAllResult,
    /// Figures not reproduced yet, with the reason.
    pub not_yet: Vec<(String, String)>,
    /// What each block-stacking figure's file changes in its recipe
    /// (`(figure, note)`; results written before it: none).
    #[serde(default)]
    pub recipe_notes: Vec<(String, String)>,
}

/// Runs every figure this build can make at `profile`, keeping run folders
/// under `runs` (finished runs are reused, interrupted ones resumed) and
/// writing figures, `results.json` and `REPORT.md` into `out`. The figures'
/// runs come from their experiment files in `experiments`. Fig. "jigsaws"
/// runs on the synthetic stand-in unless `jigsaws_root` names a JIGSAWS
/// copy. Up to `jobs` runs train at once (each on one thread).
pub fn reproduce(
    profile: Profile,
    runs: &Path,
    out: &Path,
    jigsaws_root: Option<&Path>,
    experiments: Source<'_>,
    jobs: usize,
) -> anyhow::Result<Results> {
    let started = Instant::now();
    // Read and check every experiment file first, so a bad edit fails
    // before the long runs.
    let ntp_exp_file = ntp_exp::NtpExpExperiment::load(experiments)?;
    ntp_exp_file.run_configs(profile)?;
    let ablation_file = ablation::load(experiments)?;
    ablation_file.run_configs(profile)?;
    let ablation_b_file = ablation::AblationBExperiment::load(experiments)?;
    for &variant in &ablation_b_file.ablations {
        ablation_b_file.run_config(profile, variant)?;
    }
    let thor_all_file = thor_all::ThorAllExperiment::load(experiments)?;
    for &method in &thor_all_file.methods {
        thor_all_file.run_config(profile, method)?;
    }
    // First, so a wrong --jigsaws-root fails before the long runs.
    let jigsaws = crate::jigsaws::reproduce(profile, jigsaws_root, runs, out, experiments)?;
    let points = ntp_exp::run(&ntp_exp_file, profile, runs, jobs)?;
    let ablation_points = ntp_exp::run(&ablation_file, profile, runs, jobs)?;
    let ablation_b = ablation::run_b(&ablation_b_file, profile, runs, jobs)?;
    let trace_sorting = match ablation_b.iter().find(|p| p.ablation.is_full()) {
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
        Some(p) => qualitative::blocks_trace(&p.run, p.success.trials, &out.join("trace_blocks"))?,
        None => None,
    };
    let thor_all = thor_all::run(&thor_all_file, profile, runs, jobs)?;
    let results = Results {
        profile,
        ntp_exp: points,
        ablation: ablation_points,
        ablation_b,
        trace_sorting,
        trace_blocks,
        jigsaws,
        thor_all,
        recipe_notes: vec![
            ("ntp_exp".into(), ntp_exp_file.recipe_note(profile)),
            ("ablation".into(), ablation_file.recipe_note(profile)),
        ],
        not_yet: vec![
            (
                "block stacking split by structure".into(),
                "test tasks whose structures no training task has (issue 17 item 7) are not built yet".into(),
            ),
            (
                "seeds".into(),
                "one seed per point; the paper profile's seeds (issue 17 item 5) are not run".into(),
            ),
        ],
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    ntp_exp::write_figure(&results.ntp_exp, &out.join("ntp_exp"))?;
    ablation::write_figure(
        &results.ablation,
        &results.ablation_b,
        &out.join("ablation"),
    )?;
    thor_all::write_figure(&results.thor_all, &out.join("thor_all"))?;
    RunDir::write_json(&out.join("results.json"), &results)?;
    std::fs::write(
        out.join("REPORT.md"),
        report(&results, started.elapsed().as_secs_f64()),
    )
    .with_context(|| format!("writing {}", out.join("REPORT.md").display()))?;
    Ok(results)
}

fn report(results: &Results, seconds: f64) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Reproduced figures\n");
    let _ = writeln!(
        s,
        "Profile `{:?}`, {:.0} s in the invocation that wrote this report (finished runs and their evaluations are reused; the training time column is each run's own). Measured on 2 CPU cores shared with other jobs. Seeds: model 0, shuffling 0, demos and rollouts as documented in `ntg_trainer::blocks`. Intervals are 95% Wilson intervals over test tasks (one seed per point).\n",
        results.profile, seconds
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
    let _ = writeln!(s, "{}", crate::jigsaws::report_section(&results.jigsaws));
    s.push_str(&thor_all::report_section(&results.thor_all));
    let _ = writeln!(s, "## Not reproduced yet\n");
    for (what, why) in &results.not_yet {
        let _ = writeln!(s, "- {what}: {why}");
    }
    s
}
