//! Block stacking split by structure (not in the paper; issue 17 item 7):
//! each curve of fig. "ntp_exp" at its largest number of training tasks,
//! scored again on tasks whose structure no training-pool task has
//! (`ntg eval --split structure`: towers of five cubes or more), beside its
//! score on the standard test tasks.

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::blocks::Recipe;
use crate::domain::EvalSplit;
use crate::experiment::Plan;
use crate::experiment::ntp_exp::{NtpExpPoint, curve_name};
use crate::experiment::template::STRUCTURE;
use crate::method::MethodId;
use crate::spec::ObsKind;
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
