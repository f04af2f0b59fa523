//! `ntg reproduce`: the paper's figures as experiment configs, run through
//! the same training and evaluation code as `ntg train` / `ntg eval`.
//!
//! Built so far: fig. "ntp_exp" (block stacking, success on unseen tasks vs
//! number of training tasks, (a) state and (b) video) for NTG. Baselines
//! (NTP, NTP Flat, NTP Detector) are legend entries waiting for their issue.
//! Fig. "thor_all" (b) (object collection, NTG and the Flat Policy, success
//! vs number of objects) runs through [`crate::collect::thor_all`].

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::blocks::{self, BlocksRunConfig, ObsKind, Variant};
use crate::figure::{Panel, Point, Series, write_figure};
use crate::fit::OptimConfig;
use crate::run_dir::RunDir;
use crate::stats::SuccessRate;

pub use crate::spec::Profile;

/// The scale of one panel of fig. "ntp_exp".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PanelScale {
    /// x values: numbers of training tasks.
    pub train_tasks: Vec<usize>,
    /// Demonstrations per training task.
    pub demos_per_task: usize,
    /// Training epochs (at least).
    pub epochs: usize,
    /// At least this many optimisation steps (batches of 32 demos): small
    /// training sets get more epochs so that every point is trained, not
    /// just the large ones. 0 = exactly `epochs`.
    pub min_steps: usize,
    /// Unseen test tasks evaluated per point.
    pub test_tasks: usize,
}

impl PanelScale {
    /// Epochs for `train_tasks` tasks: `epochs`, or more to reach `min_steps`.
    pub fn epochs_for(&self, train_tasks: usize, batch_size: usize) -> usize {
        let demos = train_tasks * self.demos_per_task;
        let steps_per_epoch = demos.div_ceil(batch_size.max(1)).max(1);
        self.epochs.max(self.min_steps.div_ceil(steps_per_epoch))
    }
}

/// Batch size of every reproduced run.
pub const BATCH_SIZE: usize = 32;

/// Hidden layers of the localizer's and edge classifier's state encoders in
/// reproduced runs.
pub const STATE_HIDDEN_LAYERS: usize = 3;

/// Whether reproduced runs' state encoders read pairwise cube-position
/// differences.
pub const PAIRWISE: bool = true;

/// Validation tasks of reproduced runs at `profile`: the model is scored
/// on them about [`VALIDATIONS_PER_RUN`] times per run and the best
/// scoring epoch is kept (see `train::train_with`).
pub fn validation_tasks(profile: Profile) -> usize {
    match profile {
        Profile::Smoke => 0,
        Profile::Quick => 50,
        Profile::Paper => 100,
    }
}

/// How often a reproduced run is scored on its validation tasks.
pub const VALIDATIONS_PER_RUN: usize = 16;

/// The scales of both panels under `profile`.
pub fn ntp_exp_scale(profile: Profile) -> [(ObsKind, PanelScale); 2] {
    let tasks = |v: &[usize]| v.to_vec();
    match profile {
        Profile::Smoke => [
            (
                ObsKind::State,
                PanelScale {
                    train_tasks: tasks(&[5, 10]),
                    demos_per_task: 2,
                    epochs: 2,
                    min_steps: 0,
                    test_tasks: 5,
                },
            ),
            (
                ObsKind::Vid,
                PanelScale {
                    train_tasks: tasks(&[5, 10]),
                    demos_per_task: 1,
                    epochs: 1,
                    min_steps: 0,
                    test_tasks: 3,
                },
            ),
        ],
        Profile::Quick => [
            (
                ObsKind::State,
                PanelScale {
                    train_tasks: tasks(&[50, 100, 500, 1000]),
                    demos_per_task: 10,
                    epochs: 6,
                    // With the build, the quick profile must fit 15 minutes
                    // on 2 cores (measured: 1000 steps per point took it
                    // to 17 min 20 s).
                    min_steps: 700,
                    test_tasks: 100,
                },
            ),
            (
                ObsKind::Vid,
                // A frame-input training step costs ~2 s on 2 cores (the demo
                // interpreter runs the CNN on every demo frame), so the quick
                // video panel is one pass over one demo per task: it shows the
                // pipeline, not the paper's numbers.
                PanelScale {
                    train_tasks: tasks(&[50, 100, 500, 1000]),
                    demos_per_task: 1,
                    epochs: 1,
                    min_steps: 0,
                    test_tasks: 20,
                },
            ),
        ],
        Profile::Paper => [
            (
                ObsKind::State,
                PanelScale {
                    train_tasks: tasks(&[50, 100, 500, 1000]),
                    demos_per_task: 100,
                    epochs: 30,
                    min_steps: 0,
                    test_tasks: 1000,
                },
            ),
            (
                ObsKind::Vid,
                PanelScale {
                    train_tasks: tasks(&[50, 100, 500, 1000]),
                    demos_per_task: 100,
                    epochs: 30,
                    min_steps: 0,
                    test_tasks: 1000,
                },
            ),
        ],
    }
}

/// One measured point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NtpExpPoint {
    /// Observation kind of the panel.
    pub obs: ObsKind,
    /// Training tasks.
    pub train_tasks: usize,
    /// Demonstrations per task.
    pub demos_per_task: usize,
    /// Epochs.
    pub epochs: usize,
    /// The epoch (from 0) that scored best on the validation tasks and was
    /// evaluated; `None` = the last.
    #[serde(default)]
    pub selected_epoch: Option<usize>,
    /// Whether training renamed cubes at random (not in the paper).
    #[serde(default)]
    pub permute_objects: bool,
    /// Success on unseen tasks.
    pub success: SuccessRate,
    /// Mean fraction of each unseen task's goal constraints met at the end.
    #[serde(default)]
    pub goal_fraction: f64,
    /// Seconds spent in training epochs (summed from the run's
    /// `metrics.jsonl`, so reused runs report their original cost).
    pub train_seconds: f64,
    /// Run folder.
    pub run: PathBuf,
}

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
    pub thor_all: crate::collect::ThorAllResult,
    /// Figures not reproduced yet, with the reason.
    pub not_yet: Vec<(String, String)>,
}

/// Runs every figure this build can make at `profile`, keeping run folders
/// under `runs` (finished runs are reused, interrupted ones resumed) and
/// writing figures, `results.json` and `REPORT.md` into `out`. Fig.
/// "jigsaws" runs on the synthetic stand-in unless `jigsaws_root` names a
/// JIGSAWS copy.
pub fn reproduce(
    profile: Profile,
    runs: &Path,
    out: &Path,
    jigsaws_root: Option<&Path>,
) -> anyhow::Result<Results> {
    let started = Instant::now();
    // First, so a wrong --jigsaws-root fails before the long runs.
    let jigsaws = crate::jigsaws::reproduce(profile, jigsaws_root, runs, out)?;
    let mut points = Vec::new();
    for (obs, scale) in ntp_exp_scale(profile) {
        for &n in &scale.train_tasks {
            let epochs = scale.epochs_for(n, BATCH_SIZE);
            let config = BlocksRunConfig {
                obs,
                train_tasks: n,
                demos_per_task: scale.demos_per_task,
                failures: true,
                model_seed: 0,
                state_hidden_layers: STATE_HIDDEN_LAYERS,
                pairwise: PAIRWISE,
                validation_tasks: validation_tasks(profile),
                validate_every: epochs.div_ceil(VALIDATIONS_PER_RUN),
                // The figure reproduces the paper's method; cube renaming
                // (`--permute-objects`) is an extension measured apart.
                permute_objects: false,
                exclude_held_out_renamings: false,
                edge_fusion_hidden: 0,
                retry_weight: 0.0,
                detach_gcn_from_edges: false,
                soft_edges: false,
                optim: OptimConfig {
                    epochs,
                    batch_size: BATCH_SIZE,
                    learning_rate: 3e-3,
                    seed: 0,
                    token_dropout: 0.0,
                    cosine_decay: profile.cosine_decay(),
                    gcn_from_other_demo: false,
                },
            };
            let dir = runs.join(format!("ntp_exp-{}-{n}", obs.name()));
            let run = RunDir::open_or_create(&dir, &config)?;
            eprintln!(
                "ntp_exp ({obs:?}, {n} tasks x {} demos, {epochs} epochs): training -> {}",
                scale.demos_per_task,
                dir.display()
            );
            let device = ntg_model::cpu_device().autodiff();
            let model = blocks::train_run(&run, &config, &device, |m| {
                eprintln!(
                    "  epoch {:>3}: loss {:.3}, tokens {:.3}, steps {:.3}",
                    m.epoch, m.loss, m.token_accuracy, m.step_accuracy
                )
            })?;
            let train_seconds = run.epoch_seconds()?;
            let result = run.cached_eval(&format!("full-{}.json", scale.test_tasks), || {
                blocks::evaluate(&model, obs, true, scale.test_tasks, Variant::Full)
            })?;
            eprintln!(
                "  success on {} unseen tasks: {:.3} ({:.3}-{:.3}); goals met {:.3}",
                scale.test_tasks,
                result.success.rate,
                result.success.ci_low,
                result.success.ci_high,
                result.mean_goal_fraction
            );
            points.push(NtpExpPoint {
                obs,
                train_tasks: n,
                demos_per_task: scale.demos_per_task,
                epochs,
                selected_epoch: crate::fit::selected_epoch(&run)?.map(|r| r.epoch),
                permute_objects: config.permute_objects,
                success: result.success,
                goal_fraction: result.mean_goal_fraction,
                train_seconds,
                run: dir,
            });
        }
    }
    let thor_all = crate::collect::thor_all(profile, runs)?;
    let results = Results {
        profile,
        ntp_exp: points,
        jigsaws,
        thor_all,
        not_yet: vec![
            (
                "ntp_exp baselines (NTP, NTP Flat, NTP Detector)".into(),
                "the baselines issue is not built".into(),
            ),
            (
                "ablation".into(),
                "ablation configs not wired into reproduce yet (ntg eval --variant exists)".into(),
            ),
        ],
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_ntp_exp_figure(&results, &out.join("ntp_exp"))?;
    crate::collect::write_thor_all_figure(&results.thor_all, &out.join("thor_all"))?;
    RunDir::write_json(&out.join("results.json"), &results)?;
    std::fs::write(
        out.join("REPORT.md"),
        report(&results, started.elapsed().as_secs_f64()),
    )
    .with_context(|| format!("writing {}", out.join("REPORT.md").display()))?;
    Ok(results)
}

fn write_ntp_exp_figure(results: &Results, stem: &Path) -> anyhow::Result<()> {
    let panel = |obs: ObsKind, title: &str| Panel {
        title: title.into(),
        x_label: "seen training tasks".into(),
        y_label: "unseen tasks: success, goals met".into(),
        x_log: true,
        x_ticks_at_points: false,
        y_range: (0.0, 1.0),
        series: vec![
            Series {
                name: "NTG (ours): success".into(),
                points: results
                    .ntp_exp
                    .iter()
                    .filter(|p| p.obs == obs)
                    .map(|p| Point {
                        x: p.train_tasks as f64,
                        y: p.success.rate,
                        lo: p.success.ci_low,
                        hi: p.success.ci_high,
                    })
                    .collect(),
            },
            // Partial progress, so that reduced profiles, where whole tasks
            // rarely succeed, still show what the model learned.
            Series {
                name: "NTG (ours): goals met".into(),
                points: results
                    .ntp_exp
                    .iter()
                    .filter(|p| p.obs == obs)
                    .map(|p| Point {
                        x: p.train_tasks as f64,
                        y: p.goal_fraction,
                        lo: p.goal_fraction,
                        hi: p.goal_fraction,
                    })
                    .collect(),
            },
        ],
    };
    write_figure(
        &[
            panel(ObsKind::State, "(a) state input"),
            panel(ObsKind::Vid, "(b) video input"),
        ],
        stem,
    )
}

fn report(results: &Results, seconds: f64) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Reproduced figures\n");
    let _ = writeln!(
        s,
        "Profile `{:?}`, {:.0} s in the invocation that wrote this report (finished runs and their evaluations are reused; the training time column is each run's own). Measured on 2 CPU cores shared with other jobs. Seeds: model 0, shuffling 0, demos and rollouts as documented in `ntg_trainer::blocks`. Intervals are 95% Wilson intervals over test tasks (one seed per point).\n",
        results.profile, seconds
    );
    let _ = writeln!(
        s,
        "## Fig. ntp_exp: block stacking, unseen target configurations\n\n![ntp_exp](ntp_exp.png)\n"
    );
    let _ = writeln!(
        s,
        "| input | training tasks | demos/task | epochs (selected) | cube renaming | training time | test tasks | NTG success (95% CI) | goals met | paper (known in text) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for p in &results.ntp_exp {
        let paper = match (p.obs, p.train_tasks) {
            (ObsKind::State, 50) | (ObsKind::Vid, 50) => "≈ 0.1 (NTG, 50 tasks)",
            (_, 1000) => "≈ 0.9 (NTG, 1000 tasks, 100 demos/task)",
            _ => "rising with tasks",
        };
        let _ = writeln!(
            s,
            "| {:?} | {} | {} | {} ({}) | {} | {:.0} s | {} | {:.3} ({:.3}–{:.3}) | {:.3} | {paper} |",
            p.obs,
            p.train_tasks,
            p.demos_per_task,
            p.epochs,
            p.selected_epoch
                .map_or_else(|| "last".to_owned(), |e| (e + 1).to_string()),
            if p.permute_objects { "yes" } else { "no" },
            p.train_seconds,
            p.success.trials,
            p.success.rate,
            p.success.ci_low,
            p.success.ci_high,
            p.goal_fraction
        );
    }
    let _ = writeln!(
        s,
        "\nThe paper trains with 100 demos per task; the reduced profiles use far fewer demos and optimisation steps, so lower values are expected there. Every point gets at least the profile's minimum number of steps (small training sets get more epochs). \"Goals met\" is the mean fraction of a task's `on_top` constraints that hold at the end: partial progress where whole tasks rarely succeed.\n\n**Model selection (not in the paper).** Each run is scored on held-out validation tasks (end configurations in neither the training pool nor the test set) several times during training, and the best-scoring epoch (\"selected\", counted from 1) is the one evaluated on the test tasks. **The recommended recipe (not used in this figure).** `ntg train` by default (`--recipe recommended`) adds five things to the paper's method: cube renaming (every training demo shown with its cubes renamed by a fresh random permutation: state columns, actions and task graph together; never into a held-out task), a fusion layer in the edge classifier, the GCN reading another demo of the task than the one the edge classifier imitates, the edge loss kept out of the GCN, and soft edges. At 1000 tasks x 20 demos x 20 epochs it reaches 0.960 (seed 0) on 200 unseen tasks (README). Its curve over training tasks does not rise either, for the opposite reason: renaming makes each task stand for all its renamings, so 50 tasks are already enough. With 10 demos per task and the same number of steps per point (first 100 test tasks, seed 0, measured outside this profile and before renamings onto held-out tasks were excluded; README), it scored 0.22 / 0.11 / 0.07 / 0.23 at 50 / 100 / 500 / 1000 tasks with about 1250 steps (undertrained, small sets fitting first) and 0.91 / 0.88 / 0.92 / 0.80 with about 3750 steps (882 s of training epochs for the four points on 2 cores shared with other jobs, more than this profile's whole budget). So the figure keeps the paper's method, whose demo interpreter memorises the training sequences at 50 and 100 tasks.\n"
    );
    let _ = writeln!(s, "{}", crate::jigsaws::report_section(&results.jigsaws));
    s.push_str(&crate::collect::report_section(&results.thor_all));
    let _ = writeln!(s, "## Not reproduced yet\n");
    for (what, why) in &results.not_yet {
        let _ = writeln!(s, "- {what}: {why}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_training_sets_get_epochs_up_to_the_minimum_steps() {
        let scale = PanelScale {
            train_tasks: vec![50, 1000],
            demos_per_task: 10,
            epochs: 6,
            min_steps: 1000,
            test_tasks: 10,
        };
        // 500 demos = 16 steps per epoch -> 63 epochs to reach 1000 steps.
        assert_eq!(scale.epochs_for(50, 32), 63);
        // 10000 demos = 313 steps per epoch: 6 epochs already exceed it.
        assert_eq!(scale.epochs_for(1000, 32), 6);
        let exact = PanelScale {
            min_steps: 0,
            ..scale
        };
        assert_eq!(exact.epochs_for(50, 32), 6);
    }
}
