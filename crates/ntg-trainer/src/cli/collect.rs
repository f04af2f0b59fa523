//! `ntg collect ...`: the env-collect commands (object collection).
//!
//! - `ntg collect demo --objects N --seed S --out DIR`: draws a task with N
//!   targets and records the expert's demonstration in the scene of seed S,
//!   writing `DIR/demo.json`, `DIR/frames/step_NNN.png` and
//!   `DIR/contact-sheet.png`.
//! - `ntg collect tasks --objects N --count K --split test`: lists distinct
//!   tasks of one side of the fixed train/test split.
//!
//! `ntg train --domain collect` reads [`crate::collect::CollectFlags`] (in
//! [`super::train`]).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, Subcommand, ValueEnum};
use env_collect::{CollectConfig, Split, TaskSplitter, export};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::experiment::thor_all;

/// Subcommands of `ntg collect`.
#[derive(Debug, Subcommand)]
pub enum CollectCommand {
    /// Record one expert demonstration and write it as JSON, PNG frames and
    /// a contact sheet.
    Demo(DemoArgs),
    /// List distinct tasks with N objects from one side of the train/test
    /// split.
    Tasks(TasksArgs),
    /// Run fig. "thor_all" (b) alone, as `ntg reproduce` does: train NTG
    /// and the Flat Policy on N = 2 and 4, evaluate on N = 1..5, write the
    /// figure and print the report section.
    Figure(FigureArgs),
}

/// Arguments of `ntg collect figure`.
#[derive(Debug, Args)]
pub struct FigureArgs {
    /// Experiment scale.
    #[arg(long, value_enum, default_value_t = crate::spec::Profile::Quick)]
    pub profile: crate::spec::Profile,
    /// Where run folders go, in a subfolder per profile (`DIR/PROFILE/RUN`);
    /// finished runs are reused.
    #[arg(long, value_name = "DIR", default_value = "runs/figures")]
    pub runs: PathBuf,
    /// Where `thor_all.svg` and `thor_all.png` go (`ntg reproduce` writes
    /// the committed figures; this scratch folder keeps them apart).
    #[arg(long, default_value = "runs/figures/thor_all")]
    pub out: PathBuf,
}

/// Which side of the fixed train/test split to draw tasks from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SplitArg {
    /// Training tasks only.
    Train,
    /// Held-out tasks only.
    Test,
    /// Any task.
    Any,
}

impl SplitArg {
    fn split(self) -> Option<Split> {
        match self {
            SplitArg::Train => Some(Split::Train),
            SplitArg::Test => Some(Split::Test),
            SplitArg::Any => None,
        }
    }
}

/// Arguments of `ntg collect demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Number of target objects N, 1 to 6.
    #[arg(long, value_name = "N")]
    pub objects: usize,
    /// Episode seed (where objects are, search order, appearances).
    #[arg(long, value_name = "S")]
    pub seed: u64,
    /// Output folder (created if needed).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Seed of the task draw (default: the episode seed).
    #[arg(long, value_name = "T")]
    pub task_seed: Option<u64>,
    /// Side of the train/test split to draw the task from.
    #[arg(long, value_enum, default_value_t = SplitArg::Any)]
    pub split: SplitArg,
    /// Most distractor objects in the scene.
    #[arg(long, default_value_t = 3)]
    pub max_distractors: usize,
    /// Write into a non-empty --out (an earlier demo's frames there are
    /// removed first, so none is left beside the new ones).
    #[arg(long)]
    pub force: bool,
}

/// Arguments of `ntg collect tasks`.
#[derive(Debug, Args)]
pub struct TasksArgs {
    /// Number of target objects N, 1 to 6.
    #[arg(long, value_name = "N")]
    pub objects: usize,
    /// How many distinct tasks to list.
    #[arg(long, default_value_t = 10)]
    pub count: usize,
    /// Side of the train/test split.
    #[arg(long, value_enum, default_value_t = SplitArg::Any)]
    pub split: SplitArg,
    /// Seed of the draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs an `ntg collect` subcommand, printing to standard output.
pub fn run(command: CollectCommand) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    match command {
        CollectCommand::Demo(args) => demo(&args, &mut out),
        CollectCommand::Tasks(args) => tasks(&args, &mut out),
        CollectCommand::Figure(args) => figure(&args, &mut out),
    }
}

/// `ntg collect demo`: writes the demonstration and prints a summary.
pub fn demo(args: &DemoArgs, out: &mut impl Write) -> anyhow::Result<()> {
    use env_collect::domain::{MAX_OBJECTS, MIN_OBJECTS};
    if !(MIN_OBJECTS..=MAX_OBJECTS).contains(&args.objects) {
        bail!(
            "--objects {}: a task has {MIN_OBJECTS} to {MAX_OBJECTS} target objects",
            args.objects
        );
    }
    let occupied = std::fs::read_dir(&args.out).is_ok_and(|mut d| d.next().is_some());
    if occupied && !args.force {
        bail!(
            "--out {} is not empty; pass --force to write the demo into it anyway, or choose another folder",
            args.out.display()
        );
    }
    if occupied {
        remove_earlier_frames(&args.out)?;
    }
    let room =
        env_collect::domain::NUM_CATEGORIES - args.objects.min(env_collect::domain::NUM_CATEGORIES);
    if args.max_distractors > room {
        bail!(
            "--max-distractors {}: a scene with {} target objects has room for at most {room} distractors (one per other category)",
            args.max_distractors,
            args.objects
        );
    }
    let splitter = TaskSplitter::default();
    let mut rng = ChaCha8Rng::seed_from_u64(args.task_seed.unwrap_or(args.seed));
    let task = splitter
        .sample(args.objects, args.split.split(), &mut rng)
        .context("drawing the task")?;
    let config = CollectConfig {
        max_distractors: args.max_distractors,
        ..CollectConfig::default()
    };
    let written = export::write_demo(&args.out, &task, args.seed, &config)
        .with_context(|| format!("writing the demonstration to {}", args.out.display()))?;
    let vocab = env_collect::vocabulary();
    writeln!(out, "task: {task}")?;
    writeln!(out, "seed: {}", args.seed)?;
    writeln!(
        out,
        "actions ({}): {}",
        written.demo.len(),
        vocab.format_sequence(written.demo.actions())
    )?;
    writeln!(out, "wrote {}", written.json.display())?;
    writeln!(
        out,
        "wrote {} frames to {}",
        written.frames.len(),
        args.out.display()
    )?;
    if let Some(sheet) = &written.contact_sheet {
        writeln!(out, "wrote {}", sheet.display())?;
    }
    Ok(())
}

/// Removes the frames an earlier `ntg collect demo` wrote into `dir`
/// (`frames/step_NNN.png`), so that a shorter demo leaves none of them
/// behind; other files in `frames/` stay.
fn remove_earlier_frames(dir: &std::path::Path) -> anyhow::Result<()> {
    let frames = dir.join(env_collect::export::FRAMES_DIR);
    if !frames.is_dir() {
        return Ok(());
    }
    for entry in
        std::fs::read_dir(&frames).with_context(|| format!("reading {}", frames.display()))?
    {
        let path = entry?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let frame = name.as_deref().is_some_and(|n| {
            n.strip_prefix("step_")
                .and_then(|n| n.strip_suffix(".png"))
                .is_some_and(|k| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit()))
        });
        if frame && path.is_file() {
            std::fs::remove_file(&path).with_context(|| format!("removing {}", path.display()))?;
        }
    }
    Ok(())
}

/// `ntg collect figure`: runs the panel, writes the figure, prints the
/// report section and the wall time.
pub fn figure(args: &FigureArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let profile = serde_json::to_value(args.profile)?;
    let runs = args.runs.join(profile.as_str().unwrap_or("profile"));
    let experiment = thor_all::ThorAllExperiment::load(crate::experiment::Source::BuiltIn)?;
    let result = thor_all::run(
        &experiment,
        args.profile,
        &crate::experiment::Plan::train_all(&runs, 2),
    )?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    thor_all::write_figure(&result, &args.out.join("thor_all"))?;
    write!(out, "{}", thor_all::report_section(&result))?;
    writeln!(
        out,
        "wrote {} in {:.0} s",
        args.out.join("thor_all.png").display(),
        started.elapsed().as_secs_f64()
    )?;
    Ok(())
}

/// `ntg collect tasks`: one task per line, `code<TAB>task`.
pub fn tasks(args: &TasksArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let tasks = TaskSplitter::default()
        .sample_distinct(args.objects, args.count, args.split.split(), args.seed)
        .context("drawing tasks")?;
    for task in tasks {
        writeln!(out, "{}\t{task}", task.code())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn more_distractors_than_the_scene_has_room_for_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let args = DemoArgs {
            objects: 5,
            seed: 0,
            out: dir.path().join("demo"),
            task_seed: None,
            split: SplitArg::Test,
            max_distractors: 4,
            force: false,
        };
        let err = demo(&args, &mut Vec::new()).unwrap_err().to_string();
        assert!(
            err.contains("--max-distractors 4") && err.contains("at most 3"),
            "{err}"
        );
        assert!(!args.out.exists(), "nothing written");
    }

    #[test]
    fn demo_writes_the_files_and_summarises() {
        let dir = tempfile::tempdir().unwrap();
        let args = DemoArgs {
            objects: 2,
            seed: 4,
            out: dir.path().join("demo"),
            task_seed: None,
            split: SplitArg::Test,
            max_distractors: 3,
            force: false,
        };
        let mut text = Vec::new();
        demo(&args, &mut text).unwrap();
        let text = String::from_utf8(text).unwrap();
        assert!(text.starts_with("task: "), "{text}");
        assert!(dir.path().join("demo/demo.json").is_file());
        assert!(dir.path().join("demo/frames/step_000.png").is_file());
        assert!(dir.path().join("demo/contact-sheet.png").is_file());

        // Written again only with --force, leaving no frame of the earlier
        // demo beside the new one's (a demo of one object is shorter), and
        // files that are not frames as they were.
        let frames = |dir: &std::path::Path| {
            std::fs::read_dir(dir.join("frames"))
                .unwrap()
                .filter(|e| {
                    e.as_ref()
                        .unwrap()
                        .file_name()
                        .to_string_lossy()
                        .starts_with("step_")
                })
                .count()
        };
        let before = frames(&args.out);
        std::fs::write(args.out.join("notes.txt"), "mine").unwrap();
        let shorter = DemoArgs { objects: 1, ..args };
        let err = demo(&shorter, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.contains("--force"), "{err}");
        assert_eq!(frames(&shorter.out), before);
        let shorter = DemoArgs {
            force: true,
            ..shorter
        };
        demo(&shorter, &mut Vec::new()).unwrap();
        let after = frames(&shorter.out);
        assert!(after < before, "{after} frames, {before} before");
        assert_eq!(
            std::fs::read_to_string(shorter.out.join("notes.txt")).unwrap(),
            "mine"
        );
    }

    #[test]
    fn bad_arguments_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let args = DemoArgs {
            objects: 6,
            seed: 0,
            out: dir.path().to_owned(),
            task_seed: None,
            split: SplitArg::Any,
            max_distractors: 3,
            force: false,
        };
        assert!(demo(&args, &mut Vec::new()).is_err());
        let args = TasksArgs {
            objects: 1,
            count: 41,
            split: SplitArg::Any,
            seed: 0,
        };
        assert!(tasks(&args, &mut Vec::new()).is_err());
        let args = TasksArgs {
            objects: 1,
            count: 40,
            split: SplitArg::Any,
            seed: 0,
        };
        let mut text = Vec::new();
        tasks(&args, &mut text).unwrap();
        assert_eq!(String::from_utf8(text).unwrap().lines().count(), 40);
    }
}
