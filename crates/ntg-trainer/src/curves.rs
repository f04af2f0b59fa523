//! `ntg plot`: a run's training curves, read from its run folder (the
//! `metrics.jsonl` and `validation.jsonl` that [`crate::fit`] writes, the
//! run's own and each stage's), drawn as a figure of
//! [`crate::figure::Panel`]s.
//!
//! A row per folder that trained (the run, then its stages: a video run's
//! `stage_a`, NTP (Detector)'s `detector_stage`): the losses, the
//! accuracies the method logs (fields named `*accuracy` or `*f1`), and the
//! validation scores, against epochs counted from 1. The validation
//! scores are named as the training log named them (the event files'
//! `validation/...` tags, [`crate::events`]); a run from before event
//! files gets the record's field names.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use crate::figure::{Dash, Look, Marker, Panel, Point, Series};
use crate::fit::ValidationRecord;
use crate::run_dir::{RunDir, read_jsonl};

/// One folder's curves: per field, its values by epoch (from 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Curves {
    /// The folder's name in titles: `run` or the stage folder's name.
    pub label: String,
    /// `metrics.jsonl`'s numeric fields (not `epoch`, `seconds`,
    /// `cpu_seconds`), in name order.
    pub metrics: Vec<(String, Vec<(f64, f64)>)>,
    /// The validation scores' two series, named.
    pub validation: Vec<(String, Vec<(f64, f64)>)>,
}

/// The curves of `run` and of its stages (subfolders with a
/// `metrics.jsonl`, in name order), those with at least one epoch.
pub fn read_curves(run: &Path) -> anyhow::Result<Vec<Curves>> {
    let mut folders = vec![(String::from("run"), run.to_path_buf())];
    let mut stages: Vec<PathBuf> = std::fs::read_dir(run)
        .with_context(|| format!("reading {}", run.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("metrics.jsonl").is_file())
        .collect();
    stages.sort();
    for stage in stages {
        let name = stage
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        folders.push((name, stage));
    }
    let mut out = Vec::new();
    for (label, dir) in folders {
        let metrics_path = dir.join("metrics.jsonl");
        if !metrics_path.is_file() {
            continue;
        }
        let lines: Vec<serde_json::Value> = read_jsonl(&metrics_path)?;
        let mut metrics: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
        for (i, line) in lines.iter().enumerate() {
            let epoch = line
                .get("epoch")
                .and_then(|e| e.as_u64())
                .map(|e| e as f64 + 1.0)
                .unwrap_or(i as f64 + 1.0);
            let Some(fields) = line.as_object() else {
                bail!(
                    "{}: line {} is not an object",
                    metrics_path.display(),
                    i + 1
                );
            };
            for (name, value) in fields {
                if matches!(name.as_str(), "epoch" | "seconds" | "cpu_seconds") {
                    continue;
                }
                let Some(y) = value.as_f64() else { continue };
                match metrics.iter_mut().find(|(n, _)| n == name) {
                    Some((_, points)) => points.push((epoch, y)),
                    None => metrics.push((name.clone(), vec![(epoch, y)])),
                }
            }
        }
        metrics.sort_by(|a, b| a.0.cmp(&b.0));
        let validation_path = dir.join("validation.jsonl");
        let mut validation = Vec::new();
        if validation_path.is_file() {
            let records: Vec<ValidationRecord> = read_jsonl(&validation_path)?;
            let [first, second] = score_names(&dir)?;
            let at = |f: fn(&ValidationRecord) -> f64| -> Vec<(f64, f64)> {
                records
                    .iter()
                    .map(|r| (r.epoch as f64 + 1.0, f(r)))
                    .collect()
            };
            validation.push((first, at(|r| r.score.success)));
            validation.push((second, at(|r| r.score.goal_fraction)));
        }
        if !lines.is_empty() {
            out.push(Curves {
                label,
                metrics,
                validation,
            });
        }
    }
    Ok(out)
}

/// The names the training log gave the validation score's two numbers in
/// `dir` (its newest event file's `validation/` tags, in the order the
/// log wrote them); for a run from before event files, a stage's names by
/// its folder, else the rollouts' (every method's own validation).
fn score_names(dir: &Path) -> anyhow::Result<[String; 2]> {
    let fallback = || {
        let names = match dir.file_name().and_then(|n| n.to_str()) {
            Some(crate::video::STAGE_A_DIR) => crate::video::STAGE_A_SCORES,
            Some(crate::method::detector::DETECTOR_STAGE_DIR) => {
                crate::method::detector::DETECTOR_SCORES
            }
            _ => crate::fit::ROLLOUT_SCORES,
        };
        names.map(str::to_owned)
    };
    let files = crate::events::event_files(dir)?;
    let Some(newest) = files.last() else {
        return Ok(fallback());
    };
    for event in crate::events::read_events(newest)? {
        if let Some(crate::events::What::Summary(summary)) = event.what {
            let names: Vec<String> = summary
                .value
                .iter()
                .filter_map(|v| v.tag.strip_prefix("validation/"))
                .map(|t| t.replace('_', " "))
                .collect();
            if let [a, b] = names.as_slice() {
                return Ok([a.clone(), b.clone()]);
            }
        }
    }
    Ok(fallback())
}

/// Whether a metrics field is an accuracy-like number in [0, 1].
fn is_rate(name: &str) -> bool {
    name.ends_with("accuracy") || name.ends_with("f1")
}

fn series(list: &[(String, Vec<(f64, f64)>)]) -> Vec<Series> {
    list.iter()
        .enumerate()
        .map(|(i, (name, points))| Series {
            name: name.replace('_', " "),
            points: points.iter().map(|&(x, y)| Point::exact(x, y)).collect(),
            look: Some(Look {
                colour: i % 10,
                marker: [Marker::Circle, Marker::Triangle, Marker::Square][(i / 10) % 3],
                dash: Dash::Solid,
            }),
        })
        .collect()
}

/// The panels of `curves`: per folder, its losses, its rates, and its
/// validation scores (where it was validated).
pub fn panels(run_name: &str, curves: &[Curves]) -> Vec<Panel> {
    let mut panels = Vec::new();
    for c in curves {
        let title = |what: &str| {
            if c.label == "run" {
                format!("{run_name}: {what}")
            } else {
                format!("{run_name} / {}: {what}", c.label)
            }
        };
        let (rates, losses): (Vec<_>, Vec<_>) =
            c.metrics.iter().cloned().partition(|(n, _)| is_rate(n));
        let max_loss = losses
            .iter()
            .flat_map(|(_, p)| p.iter().map(|&(_, y)| y))
            .filter(|y| y.is_finite())
            .fold(0.0f64, f64::max);
        let epochs = c.metrics.iter().map(|(_, p)| p.len()).max().unwrap_or(0);
        let panel =
            |what: &str, y_label: &str, y_range, list: &[(String, Vec<(f64, f64)>)]| Panel {
                title: title(what),
                x_label: "epoch".into(),
                y_label: y_label.into(),
                x_log: false,
                // Whole epochs as ticks, while they are few enough to label.
                x_ticks_at_points: epochs <= 12,
                y_range,
                series: series(list),
            };
        if !losses.is_empty() {
            panels.push(panel(
                "training losses",
                "loss",
                (0.0, max_loss * 1.05 + 1e-9),
                &losses,
            ));
        }
        if !rates.is_empty() {
            panels.push(panel("training accuracies", "fraction", (0.0, 1.0), &rates));
        }
        if !c.validation.is_empty() {
            let (lo, hi) = c
                .validation
                .iter()
                .flat_map(|(_, p)| p.iter().map(|&(_, y)| y))
                .fold((0.0f64, 1.0f64), |(lo, hi), y| (lo.min(y), hi.max(y)));
            panels.push(panel("validation", "score", (lo, hi), &c.validation));
        }
    }
    panels
}

/// Writes the curves of the run folder `run` to `png` (and an SVG beside
/// it); the number of panels drawn.
pub fn plot_run(run: &Path, png: &Path) -> anyhow::Result<usize> {
    let root = RunDir::open(run)?;
    let curves = read_curves(root.root())?;
    if curves.is_empty() {
        bail!(
            "{}: no training epochs logged (metrics.jsonl is missing or empty); a committed zoo entry keeps only its weights and record",
            run.display()
        );
    }
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into());
    let panels = panels(&name, &curves);
    let stem = png.with_extension("");
    crate::figure::write_figure(&panels, &stem)?;
    Ok(panels.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_run_and_its_stage() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        std::fs::write(
            root.join("metrics.jsonl"),
            "{\"epoch\":0,\"loss\":2.0,\"token_accuracy\":0.5,\"seconds\":1.0}\n{\"epoch\":1,\"loss\":1.0,\"token_accuracy\":0.75,\"seconds\":1.0}\n",
        )
        .unwrap();
        std::fs::write(
            root.join("validation.jsonl"),
            "{\"epoch\":1,\"success\":0.5,\"goal_fraction\":0.8}\n",
        )
        .unwrap();
        std::fs::create_dir(root.join("stage_a")).unwrap();
        std::fs::write(
            root.join("stage_a/metrics.jsonl"),
            "{\"epoch\":0,\"loss\":3.0,\"seconds\":1.0}\n",
        )
        .unwrap();
        let curves = read_curves(root).unwrap();
        assert_eq!(curves.len(), 2);
        assert_eq!(curves[0].label, "run");
        assert_eq!(
            curves[0].metrics,
            [
                ("loss".to_owned(), vec![(1.0, 2.0), (2.0, 1.0)]),
                ("token_accuracy".to_owned(), vec![(1.0, 0.5), (2.0, 0.75)])
            ]
        );
        assert_eq!(
            curves[0].validation[0],
            ("success".to_owned(), vec![(2.0, 0.5)])
        );
        assert_eq!(curves[0].validation[1].0, "goals met");
        assert_eq!(curves[1].label, "stage_a");
        let panels = panels("r", &curves);
        let titles: Vec<&str> = panels.iter().map(|p| p.title.as_str()).collect();
        assert_eq!(
            titles,
            [
                "r: training losses",
                "r: training accuracies",
                "r: validation",
                "r / stage_a: training losses"
            ]
        );
        assert!(crate::figure::same_looks(&panels).is_none());
    }
}
