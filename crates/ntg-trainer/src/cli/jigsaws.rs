//! `ntg jigsaws ...`: the env-jigsaws commands.
//!
//! - `ntg jigsaws synth --out DIR --seed S` writes the synthetic stand-in
//!   dataset in the real JIGSAWS layout;
//! - `ntg jigsaws stats --root DIR [--json]` reads a JIGSAWS copy (real or
//!   synthetic; task folders are searched for, nested ones included) and
//!   prints trials, gestures, frames and transition counts per task;
//! - `ntg jigsaws nll [--jigsaws-root DIR] --out DIR [--profile P]
//!   [--synth-seed S] [--model-seed S] [--seed-table]` runs the
//!   cross-task NLL experiment ([`crate::jigsaws`]): on the synthetic
//!   stand-in by default, on a JIGSAWS copy with `--jigsaws-root`.
//!
//! Warnings of the reader (skipped trials, stray files) go to stderr.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use env_jigsaws::{Dataset, SynthConfig, TaskStats, write_synthetic};

/// Subcommands of `ntg jigsaws`.
#[derive(Debug, Subcommand)]
pub enum JigsawsCommand {
    /// Write a synthetic stand-in for JIGSAWS (seeded; same layout, trial
    /// inventory and file formats as the real dataset, but generated data).
    Synth(SynthArgs),
    /// Trials, gestures, frames and gesture transitions per task of a JIGSAWS
    /// copy (real or synthetic).
    Stats(StatsArgs),
    /// The cross-task experiment: train NTG on Suturing + Knot Tying, build a
    /// policy from each Needle Passing demo and score the NLL of the others
    /// (uniform, NTG without graph, full NTG).
    Nll(NllArgs),
}

/// Arguments of `ntg jigsaws synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Folder to write into (created if needed; must not already hold a task
    /// folder).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Seed of the generator; the same seed writes the same files.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub seed: u64,
    /// Multiply every duration by this (smaller files; 1 is realistic).
    #[arg(long, value_name = "X", default_value_t = 1.0)]
    pub duration_scale: f64,
}

/// Arguments of `ntg jigsaws stats`.
#[derive(Debug, Args)]
pub struct StatsArgs {
    /// The dataset root (task folders are searched for below it).
    #[arg(long, value_name = "DIR")]
    pub root: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `ntg jigsaws nll`.
#[derive(Debug, Args)]
pub struct NllArgs {
    /// A JIGSAWS copy (real, or written by `ntg jigsaws synth`); without it,
    /// the synthetic stand-in generated in memory with `--synth-seed`.
    #[arg(long, value_name = "DIR")]
    pub jigsaws_root: Option<PathBuf>,
    /// Seed of the synthetic stand-in (ignored with `--jigsaws-root`).
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub synth_seed: u64,
    /// Seed of both trained models' initial weights (default: the
    /// profile's, 0).
    #[arg(long, value_name = "S")]
    pub model_seed: Option<u64>,
    /// Experiment scale (epochs).
    #[arg(long, value_enum, default_value_t = crate::spec::Profile::Quick)]
    pub profile: crate::spec::Profile,
    /// Training epochs (default: the profile's).
    #[arg(long, value_name = "N")]
    pub epochs: Option<usize>,
    /// Also run the experiment with one seed changed at a time (synthetic
    /// data seeds 1–3, model seeds 1–5) and add the table to the report.
    #[arg(long)]
    pub seed_table: bool,
    /// Where the figure, the predicted graph, the report section
    /// (`jigsaws.md`) and `jigsaws.json` go.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Where the two training runs go (finished runs with the same
    /// configuration are reused); default `<out>/runs`.
    #[arg(long, value_name = "DIR")]
    pub runs: Option<PathBuf>,
}

/// Runs an `ntg jigsaws` subcommand.
pub fn run(command: JigsawsCommand) -> anyhow::Result<()> {
    run_with(
        command,
        &mut std::io::stdout().lock(),
        &mut std::io::stderr().lock(),
    )
}

/// Runs an `ntg jigsaws` subcommand, writing results to `out` and warnings
/// to `err`.
pub fn run_with(
    command: JigsawsCommand,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<()> {
    match command {
        JigsawsCommand::Synth(args) => synth(&args, out),
        JigsawsCommand::Stats(args) => stats(&args, out, err),
        JigsawsCommand::Nll(args) => nll(&args, out, err),
    }
}

fn nll(args: &NllArgs, out: &mut impl Write, err: &mut impl Write) -> anyhow::Result<()> {
    use crate::jigsaws::{
        DataSource, JigsawsConfig, Method, run_experiment, seed_table, write_outputs,
    };
    let source = match &args.jigsaws_root {
        Some(path) => DataSource::Root { path: path.clone() },
        None => DataSource::Synthetic {
            seed: args.synth_seed,
            duration_scale: 1.0,
        },
    };
    let mut config = JigsawsConfig::for_profile(args.profile, source, Default::default())?;
    if let Some(epochs) = args.epochs {
        config.optim.epochs = epochs;
    }
    if let Some(seed) = args.model_seed {
        config.model_seed = seed;
    }
    let runs = args.runs.clone().unwrap_or_else(|| args.out.join("runs"));
    let mut result = run_experiment(&config, &runs, |line| {
        let _ = writeln!(err, "{line}");
    })?;
    if args.seed_table {
        let table = seed_table(&config, Some(&result), &runs, |line| {
            let _ = writeln!(err, "{line}");
        })?;
        write!(out, "{}", crate::jigsaws::seed_table_markdown(&table))?;
        result.seeds = Some(table);
    }
    write_outputs(&result, &args.out)?;
    writeln!(out, "{}", result.source)?;
    for m in Method::ALL {
        if let Some(r) = result.method(m) {
            writeln!(
                out,
                "  {:<14} NLL {:.3} ± {:.3} (min {:.3}, max {:.3}; {} of {} steps at probability 0)",
                m.label(),
                r.mean_nll,
                r.std_nll,
                r.min_nll,
                r.max_nll,
                r.zero_probability_steps,
                r.steps
            )?;
        }
    }
    writeln!(
        out,
        "wrote {} (jigsaws.svg/png, jigsaws_graph.dot/svg, jigsaws.md, jigsaws.json)",
        args.out.display()
    )?;
    Ok(())
}

fn synth(args: &SynthArgs, out: &mut impl Write) -> anyhow::Result<()> {
    if !(args.duration_scale.is_finite() && args.duration_scale > 0.0) {
        bail!(
            "--duration-scale must be a positive number, got {}",
            args.duration_scale
        );
    }
    let config = SynthConfig {
        duration_scale: args.duration_scale,
        ..SynthConfig::new(args.seed)
    };
    let synth = write_synthetic(&config, &args.out)
        .with_context(|| format!("writing the synthetic dataset to {}", args.out.display()))?;
    writeln!(
        out,
        "wrote a synthetic JIGSAWS stand-in (generated, not real surgical data) to {} (seed {})",
        args.out.display(),
        args.seed
    )?;
    for task in synth.dataset.tasks() {
        let trials = synth.dataset.trials(task);
        let frames: usize = trials.iter().map(|t| t.kinematics.num_rows()).sum();
        let extra = synth
            .kinematics_only
            .iter()
            .filter(|(id, _)| id.task == task)
            .map(|(id, _)| id.to_string())
            .collect::<Vec<_>>();
        write!(out, "  {task}: {} trials, {frames} frames", trials.len())?;
        if !extra.is_empty() {
            write!(
                out,
                " (+ kinematics only, as in the real set: {})",
                extra.join(", ")
            )?;
        }
        writeln!(out)?;
    }
    Ok(())
}

fn stats(args: &StatsArgs, out: &mut impl Write, err: &mut impl Write) -> anyhow::Result<()> {
    let loaded = Dataset::load(&args.root)
        .with_context(|| format!("reading JIGSAWS from {}", args.root.display()))?;
    for warning in &loaded.report.warnings {
        writeln!(err, "warning: {warning}")?;
    }
    let stats = loaded.dataset.stats();
    if args.json {
        let value = serde_json::json!({
            "root": args.root,
            "task_folders": loaded.report.task_folders,
            "warnings": loaded.report.warnings.iter().map(ToString::to_string).collect::<Vec<_>>(),
            "tasks": stats.tasks,
        });
        serde_json::to_writer_pretty(&mut *out, &value)?;
        writeln!(out)?;
        return Ok(());
    }
    writeln!(out, "JIGSAWS at {}", args.root.display())?;
    for t in &stats.tasks {
        let folder = loaded
            .report
            .task_folders
            .get(&t.task)
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        print_task(out, t, &folder)?;
    }
    Ok(())
}

fn print_task(out: &mut impl Write, t: &TaskStats, folder: &str) -> anyhow::Result<()> {
    let skills = t
        .trials_by_skill
        .iter()
        .map(|(s, n)| format!("{} {n}", s.letter()))
        .collect::<Vec<_>>()
        .join(", ");
    let labelled = if t.frames == 0 {
        0.0
    } else {
        100.0 * t.labelled_frames as f64 / t.frames as f64
    };
    writeln!(out)?;
    writeln!(out, "{} ({folder})", t.task)?;
    writeln!(out, "  trials:   {} ({skills})", t.trials)?;
    writeln!(
        out,
        "  frames:   {} at 30 Hz ({:.1} min), {labelled:.1}% labelled",
        t.frames,
        t.duration_s / 60.0
    )?;
    writeln!(
        out,
        "  gestures: {} ({} segments)",
        t.gesture_set()
            .iter()
            .map(|g| g.name())
            .collect::<Vec<_>>()
            .join(" "),
        t.segments
    )?;
    for g in &t.gestures {
        writeln!(
            out,
            "    {:<4} {:>5} segments {:>7} frames  {}",
            g.gesture.name(),
            g.segments,
            g.frames,
            g.gesture.description()
        )?;
    }
    // Transition matrix over <start>, the task's gestures, <end>.
    let mut rows = vec!["<start>".to_owned()];
    rows.extend(t.gesture_set().iter().map(|g| g.name().to_owned()));
    let mut cols: Vec<String> = rows[1..].to_vec();
    cols.push("<end>".to_owned());
    writeln!(out, "  transitions (row: from, column: to):")?;
    write!(out, "    {:>7}", "")?;
    for c in &cols {
        write!(out, " {c:>5}")?;
    }
    writeln!(out)?;
    for r in &rows {
        write!(out, "    {r:>7}")?;
        for c in &cols {
            let n = t
                .transitions
                .iter()
                .find(|x| &x.from == r && &x.to == c)
                .map_or(0, |x| x.count);
            if n == 0 {
                write!(out, " {:>5}", ".")?;
            } else {
                write!(out, " {n:>5}")?;
            }
        }
        writeln!(out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_to_strings(command: JigsawsCommand) -> anyhow::Result<(String, String)> {
        let (mut out, mut err) = (Vec::new(), Vec::new());
        run_with(command, &mut out, &mut err)?;
        Ok((String::from_utf8(out)?, String::from_utf8(err)?))
    }

    #[test]
    fn synth_then_stats_reports_the_inventory_and_gesture_sets() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("jigsaws");
        let (out, _) = run_to_strings(JigsawsCommand::Synth(SynthArgs {
            out: root.clone(),
            seed: 4,
            duration_scale: 0.1,
        }))
        .unwrap();
        assert!(out.contains("Suturing: 39 trials"), "{out}");
        assert!(out.contains("Suturing_H002"), "{out}");

        let (json, err) = run_to_strings(JigsawsCommand::Stats(StatsArgs {
            root: root.clone(),
            json: true,
        }))
        .unwrap();
        assert!(
            err.contains("trial Suturing_H002 skipped: no transcription, no meta row"),
            "{err}"
        );
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        let tasks = value["tasks"].as_array().unwrap();
        let summary: Vec<(String, u64, Vec<String>)> = tasks
            .iter()
            .map(|t| {
                (
                    t["task"].as_str().unwrap().to_owned(),
                    t["trials"].as_u64().unwrap(),
                    t["gestures"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|g| g["gesture"].as_str().unwrap().to_owned())
                        .collect(),
                )
            })
            .collect();
        let names = |s: &str| s.split(' ').map(str::to_owned).collect::<Vec<_>>();
        assert_eq!(
            summary,
            [
                (
                    "Suturing".to_owned(),
                    39,
                    names("G1 G2 G3 G4 G5 G6 G8 G9 G10 G11")
                ),
                (
                    "Needle_Passing".to_owned(),
                    28,
                    names("G1 G2 G3 G4 G5 G6 G8 G11")
                ),
                ("Knot_Tying".to_owned(), 36, names("G1 G11 G12 G13 G14 G15")),
            ]
        );

        let (text, _) =
            run_to_strings(JigsawsCommand::Stats(StatsArgs { root, json: false })).unwrap();
        assert!(text.contains("Needle_Passing ("), "{text}");
        assert!(text.contains("  trials:   28 ("), "{text}");
        assert!(text.contains("gestures: G1 G11 G12 G13 G14 G15"), "{text}");
    }

    #[test]
    fn synth_refuses_a_folder_with_task_folders_and_bad_scales() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("Knot_Tying")).unwrap();
        let err = run_to_strings(JigsawsCommand::Synth(SynthArgs {
            out: dir.path().to_owned(),
            seed: 0,
            duration_scale: 1.0,
        }))
        .unwrap_err();
        assert!(format!("{err:#}").contains("already exists"), "{err:#}");
        let err = run_to_strings(JigsawsCommand::Synth(SynthArgs {
            out: dir.path().join("x"),
            seed: 0,
            duration_scale: 0.0,
        }))
        .unwrap_err();
        assert!(err.to_string().contains("--duration-scale"), "{err}");
    }

    #[test]
    fn nll_runs_on_a_jigsaws_root_and_reuses_its_runs() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("jigsaws");
        let config = SynthConfig {
            max_trials_per_task: Some(5),
            duration_scale: 0.3,
            ..SynthConfig::new(2)
        };
        write_synthetic(&config, &root).unwrap();
        let out = dir.path().join("out");
        let args = || NllArgs {
            jigsaws_root: Some(root.clone()),
            synth_seed: 0,
            model_seed: None,
            profile: crate::spec::Profile::Smoke,
            epochs: Some(1),
            seed_table: false,
            out: out.clone(),
            runs: None,
        };
        let (text, log) = run_to_strings(JigsawsCommand::Nll(args())).unwrap();
        assert!(text.contains("JIGSAWS copy at"), "{text}");
        for label in ["uniform", "NTG, no graph", "NTG (full)"] {
            assert!(text.contains(label), "{text}");
        }
        assert!(log.contains("epoch   0"), "{log}");
        for file in [
            "jigsaws.svg",
            "jigsaws.png",
            "jigsaws_graph.dot",
            "jigsaws_graph.svg",
            "jigsaws.md",
            "jigsaws.json",
        ] {
            assert!(out.join(file).is_file(), "{file} missing");
        }
        let first: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("jigsaws.json")).unwrap())
                .unwrap();
        assert_eq!(first["test_demos"], 5);
        // A second run reuses the selected models: no training, same numbers.
        let (again, log) = run_to_strings(JigsawsCommand::Nll(args())).unwrap();
        assert!(!log.contains("epoch   0"), "{log}");
        assert_eq!(again, text);
        // A different configuration in the same run folders is refused.
        let mut other = args();
        other.epochs = Some(2);
        let err = run_to_strings(JigsawsCommand::Nll(other)).unwrap_err();
        assert!(
            format!("{err:#}").contains("another configuration"),
            "{err:#}"
        );
        // So is another model seed (the flag reaches the configuration).
        let mut seeded = args();
        seeded.model_seed = Some(3);
        let err = run_to_strings(JigsawsCommand::Nll(seeded)).unwrap_err();
        assert!(
            format!("{err:#}").contains("another configuration"),
            "{err:#}"
        );
        // The seed table: on a copy on disk, model seeds only; the default
        // row is the run above (not trained again).
        let mut table = args();
        table.seed_table = true;
        let (text, log) = run_to_strings(JigsawsCommand::Nll(table)).unwrap();
        assert!(
            text.contains("| model5 |") && !text.contains("| data1 |"),
            "{text}"
        );
        assert!(text.contains(" of 6;"), "{text}");
        assert!(!log.contains("seed table: default"), "{log}");
        let report = std::fs::read_to_string(out.join("jigsaws.md")).unwrap();
        assert!(report.contains("**Seed sensitivity.**"), "{report}");
        assert!(dir.path().join("out/runs/jigsaws-seeds/model5").is_dir());
    }

    #[test]
    fn nll_on_a_wrong_root_names_it() {
        let dir = tempfile::tempdir().unwrap();
        let err = run_to_strings(JigsawsCommand::Nll(NllArgs {
            jigsaws_root: Some(dir.path().join("missing")),
            synth_seed: 0,
            model_seed: None,
            profile: crate::spec::Profile::Smoke,
            epochs: None,
            seed_table: false,
            out: dir.path().join("out"),
            runs: None,
        }))
        .unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("missing") && msg.contains("no such folder"),
            "{msg}"
        );
    }

    #[test]
    fn stats_on_a_folder_without_jigsaws_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let err = run_to_strings(JigsawsCommand::Stats(StatsArgs {
            root: dir.path().to_owned(),
            json: false,
        }))
        .unwrap_err();
        assert!(
            format!("{err:#}").contains("no JIGSAWS task folder"),
            "{err:#}"
        );
    }
}
