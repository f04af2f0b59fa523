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
use crate::run_dir::RunDir;

pub use crate::spec::Profile;

/// Everything `reproduce` measured (`results.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Results {
    /// Profile used.
    pub profile: Profile,
    /// Fig. "ntp_exp", NTG.
    pub ntp_exp: Vec<NtpExpPoint>,
    /// Fig. "jigsaws": cross-task NLL on Needle Passing (issue 7).
    pub jigsaws: crate::jigsaws::JigsawsResult,
    /// Fig. "thor_all" (b), NTG and the Flat Policy.
    pub thor_all: ThorAllResult,
    /// Figures not reproduced yet, with the reason.
    pub not_yet: Vec<(String, String)>,
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
    let thor_all_file = thor_all::ThorAllExperiment::load(experiments)?;
    for &method in &thor_all_file.methods {
        thor_all_file.run_config(profile, method)?;
    }
    // First, so a wrong --jigsaws-root fails before the long runs.
    let jigsaws = crate::jigsaws::reproduce(profile, jigsaws_root, runs, out, experiments)?;
    let points = ntp_exp::run(&ntp_exp_file, profile, runs, jobs)?;
    let thor_all = thor_all::run(&thor_all_file, profile, runs, jobs)?;
    let results = Results {
        profile,
        ntp_exp: points,
        jigsaws,
        thor_all,
        not_yet: vec![(
            "ablation".into(),
            "ablation configs not wired into reproduce yet (ntg eval --variant exists)".into(),
        )],
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    ntp_exp::write_figure(&results.ntp_exp, &out.join("ntp_exp"))?;
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
    s.push_str(&ntp_exp::report_section(&results.ntp_exp));
    let _ = writeln!(s, "{}", crate::jigsaws::report_section(&results.jigsaws));
    s.push_str(&thor_all::report_section(&results.thor_all));
    let _ = writeln!(s, "## Not reproduced yet\n");
    for (what, why) in &results.not_yet {
        let _ = writeln!(s, "- {what}: {why}");
    }
    s
}
