//! `ntg blocks ...`: block-stacking task sets and demos, object-sorting demos.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use env_blocks::{
    BlocksTask, EnvConfig, RichDemo, SortTask, StackTask, TaskStats, expert_success,
    read_ntp_tasks, record_rich_demo,
    sheet::{captioned_contact_sheet, contact_sheet},
    standard_sort_tasks, standard_tasks, write_ntp_tasks,
};

/// Subcommands of `ntg blocks`.
#[derive(Debug, Subcommand)]
pub enum BlocksCommand {
    /// Task-set statistics (NTP README format), or write the standard set.
    Tasks(TasksArgs),
    /// Record one expert demo of a block-stacking task: JSON, PNG frames and
    /// a contact sheet.
    Demo(DemoArgs),
    /// Record expert demos of many block-stacking tasks as one LeRobot
    /// dataset (parquet).
    ///
    /// LeRobot's layout: a parquet file an episode (frames as PNG, states,
    /// actions by id and name), the tasks in meta/tasks.jsonl; pyarrow and
    /// pandas read it (docs/EXPORT.md).
    Demos(DemosArgs),
    /// Run the expert once on every task of a set and report its success rate.
    Replay(ReplayArgs),
    /// Object sorting.
    #[command(subcommand)]
    Sorting(SortingCommand),
}

/// Subcommands of `ntg blocks sorting`.
#[derive(Debug, Subcommand)]
pub enum SortingCommand {
    /// Record one expert demo of a sorting task.
    Demo(SortDemoArgs),
}

/// Arguments of `ntg blocks tasks`.
#[derive(Debug, Args)]
pub struct TasksArgs {
    /// Print the statistics (the default when nothing else is asked).
    #[arg(long)]
    pub stats: bool,
    /// An NTP-format task file; without it, the standard generated set.
    #[arg(long, value_name = "FILE")]
    pub source: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Write the task set in NTP format to FILE (refused if FILE exists,
    /// unless --force).
    #[arg(long, value_name = "FILE")]
    pub write: Option<PathBuf>,
    /// Overwrite an existing --write FILE.
    #[arg(long, requires = "write")]
    pub force: bool,
}

/// Options shared by the demo commands.
#[derive(Debug, Args)]
pub struct DemoOptions {
    /// Seed of the scene, the failures and the expert.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder (created if needed; refused if it holds anything,
    /// unless --force).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Write into a --out folder that is not empty, replacing the files of
    /// the same names.
    #[arg(long)]
    pub force: bool,
    /// Turn the stochastic failures off (they are on by default).
    #[arg(long)]
    pub no_failures: bool,
    /// Frames per row of the contact sheet.
    #[arg(long, default_value_t = 6, value_parser = crate::spec::parse::positive)]
    pub columns: usize,
    /// Integer upscaling of the frames in the contact sheet (1 to 16).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub scale: u32,
}

/// Arguments of `ntg blocks demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Task id (`stack_17`) or index (`17`).
    #[arg(long)]
    pub task: String,
    /// An NTP-format task file; without it, the standard generated set.
    #[arg(long, value_name = "FILE")]
    pub source: Option<PathBuf>,
    /// Demo options.
    #[command(flatten)]
    pub demo: DemoOptions,
}

/// Arguments of `ntg blocks demos`.
#[derive(Debug, Args)]
pub struct DemosArgs {
    /// The dataset folder to write (must not exist, or be empty).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Replace an earlier dataset in --out (a folder holding
    /// `meta/info.json`); any other folder is never replaced.
    #[arg(long)]
    pub force: bool,
    /// How many tasks (one demo each).
    #[arg(long, default_value_t = 10, value_parser = crate::spec::parse::positive)]
    pub count: usize,
    /// Index of the first task in the set.
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// An NTP-format task file; without it, the standard generated set.
    #[arg(long, value_name = "FILE")]
    pub source: Option<PathBuf>,
    /// Seed of the first demo (the demo of task i uses seed + i).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Turn the stochastic failures off (they are on by default).
    #[arg(long)]
    pub no_failures: bool,
    /// Frame width and height in pixels (a multiple of 8; 64 is the
    /// standard camera).
    #[arg(long, default_value_t = env_blocks::Camera::default().size)]
    pub camera_size: u32,
}

/// Arguments of `ntg blocks sorting demo`.
#[derive(Debug, Args)]
pub struct SortDemoArgs {
    /// Task id (`sort_3`) or index (`3`) among the 256 standard sorting tasks.
    #[arg(long)]
    pub task: String,
    /// Number of objects that start already in their bins (part-done scene).
    #[arg(long, default_value_t = 0)]
    pub presorted: usize,
    /// Demo options.
    #[command(flatten)]
    pub demo: DemoOptions,
}

/// Arguments of `ntg blocks replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// An NTP-format task file; without it, the standard generated set.
    #[arg(long, value_name = "FILE")]
    pub source: Option<PathBuf>,
    /// Turn the stochastic failures off.
    #[arg(long)]
    pub no_failures: bool,
    /// Seed of the first task's episode (task i uses seed + i).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs an `ntg blocks` subcommand.
pub fn run(command: BlocksCommand) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    match command {
        BlocksCommand::Tasks(args) => run_tasks(&args, &mut out),
        BlocksCommand::Demo(args) => {
            let tasks = load_tasks(args.source.as_deref())?;
            let task = find_stack_task(&tasks, &args.task)?;
            write_demo(BlocksTask::Stack(task.clone()), &args.demo, &mut out)
        }
        BlocksCommand::Demos(args) => write_demos(&args, &mut out),
        BlocksCommand::Replay(args) => run_replay(&args, &mut out),
        BlocksCommand::Sorting(SortingCommand::Demo(args)) => {
            let tasks = standard_sort_tasks()?;
            let task = find_sort_task(&tasks, &args.task)?;
            let task = task.with_random_presorted(args.presorted, args.demo.seed);
            write_demo(BlocksTask::Sort(task), &args.demo, &mut out)
        }
    }
}

fn load_tasks(source: Option<&Path>) -> anyhow::Result<Vec<StackTask>> {
    Ok(match source {
        Some(path) => read_ntp_tasks(path)?,
        None => standard_tasks()?,
    })
}

fn find_stack_task<'a>(tasks: &'a [StackTask], key: &str) -> anyhow::Result<&'a StackTask> {
    if let Some(t) = tasks.iter().find(|t| t.id == key) {
        return Ok(t);
    }
    match key.parse::<usize>() {
        Ok(i) => tasks
            .get(i)
            .with_context(|| format!("task index {i} is out of range ({} tasks)", tasks.len())),
        Err(_) => bail!("no task with id `{key}` (give an id such as stack_17 or an index)"),
    }
}

fn find_sort_task<'a>(tasks: &'a [SortTask], key: &str) -> anyhow::Result<&'a SortTask> {
    if let Some(t) = tasks.iter().find(|t| t.id == key) {
        return Ok(t);
    }
    match key.parse::<usize>() {
        Ok(i) => tasks.get(i).with_context(|| {
            format!(
                "sorting task index {i} is out of range ({} tasks)",
                tasks.len()
            )
        }),
        Err(_) => bail!("no sorting task with id `{key}` (give an id such as sort_3 or an index)"),
    }
}

/// Runs `ntg blocks tasks`, writing to `out`.
pub fn run_tasks(args: &TasksArgs, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    let tasks = load_tasks(args.source.as_deref())?;
    if let Some(path) = &args.write {
        if path.exists() && !args.force {
            bail!(
                "{} already exists; pass --force to overwrite it",
                path.display()
            );
        }
        std::fs::write(path, write_ntp_tasks(&tasks))
            .with_context(|| format!("writing {}", path.display()))?;
        writeln!(out, "wrote {} tasks to {}", tasks.len(), path.display())?;
    }
    if args.stats || args.write.is_none() {
        let stats = TaskStats::of(&tasks);
        if args.json {
            serde_json::to_writer_pretty(&mut *out, &stats)?;
            writeln!(out)?;
        } else {
            write!(out, "{}", stats.to_text())?;
        }
    }
    Ok(())
}

fn run_replay(args: &ReplayArgs, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    let tasks: Vec<BlocksTask> = load_tasks(args.source.as_deref())?
        .into_iter()
        .map(BlocksTask::Stack)
        .collect();
    let mut config = EnvConfig::state_only();
    if args.no_failures {
        config = config.without_failures();
    }
    let stats = expert_success(&tasks, config, args.seed);
    serde_json::to_writer_pretty(
        &mut *out,
        &serde_json::json!({
            "failures_on": !args.no_failures,
            "success_rate": stats.success_rate(),
            "stats": stats,
        }),
    )?;
    writeln!(out)?;
    Ok(())
}

/// The rows of a recorded demo: frame and state before each action, then
/// the final frame with `<end>`.
fn demo_episode(demo: &RichDemo, task: &str) -> crate::lerobot::Episode {
    let rows = (0..demo.frames.len())
        .map(|t| {
            let step = demo.steps.get(t);
            crate::lerobot::Row {
                frame: demo.frames[t].clone(),
                state: demo.states.get(t).cloned(),
                action: step.map_or(ctg_graph::Vocabulary::END.index(), |s| s.action_id),
                success_after: step.map_or(demo.success, |s| s.success),
            }
        })
        .collect();
    crate::lerobot::Episode {
        task: task.to_owned(),
        task_id: demo.task.id().to_owned(),
        seed: demo.seed,
        rows,
        success: demo.success,
    }
}

/// Runs `ntg blocks demos`: records the demos (in parallel, in batches)
/// into a staging folder beside --out, then moves it into place.
fn write_demos(args: &DemosArgs, out: &mut impl std::io::Write) -> anyhow::Result<()> {
    use rayon::prelude::*;
    let marker = crate::lerobot::INFO_FILE;
    crate::cli::export::check_out(&args.out, args.force, marker, "an earlier dataset")?;
    let camera = env_blocks::Camera::of_size(args.camera_size);
    camera
        .validate()
        .map_err(|e| anyhow::anyhow!("--camera-size {}: {e}", args.camera_size))?;
    let tasks = load_tasks(args.source.as_deref())?;
    let end = args.first.saturating_add(args.count);
    if end > tasks.len() {
        bail!(
            "--first {} --count {} asks for tasks up to index {}, but the set has {} tasks",
            args.first,
            args.count,
            end - 1,
            tasks.len()
        );
    }
    let mut config = EnvConfig {
        camera,
        ..EnvConfig::default()
    };
    if args.no_failures {
        config = config.without_failures();
    }
    let vocabulary = env_blocks::vocabulary(false, env_blocks::ActionLevel::Flat);
    let info = crate::lerobot::DatasetInfo {
        robot_type: "ntg-rs block stacking".into(),
        source: format!(
            "expert demos of tasks {}..{} of {} (seed {} + task offset, failures {})",
            args.first,
            end,
            args.source
                .as_ref()
                .map_or("the standard task set".to_owned(), |p| p
                    .display()
                    .to_string()),
            args.seed,
            if args.no_failures { "off" } else { "on" }
        ),
        vocabulary: vocabulary.names().to_vec(),
        fps: 1,
    };
    let staging = crate::cli::export::staging_dir(&args.out)?;
    let written = (|| -> anyhow::Result<crate::lerobot::Written> {
        let mut writer = crate::lerobot::DatasetWriter::create(&staging, info)?;
        let progress = indicatif::ProgressBar::new(args.count as u64).with_message("demos");
        let indices: Vec<usize> = (args.first..end).collect();
        for batch in indices.chunks(64) {
            let episodes = batch
                .par_iter()
                .map(|&i| {
                    let seed = args.seed.wrapping_add((i - args.first) as u64);
                    record_rich_demo(BlocksTask::Stack(tasks[i].clone()), config, seed)
                        .map(|demo| demo_episode(&demo, &crate::blocks::stack_words(&tasks[i])))
                        .with_context(|| format!("recording the demo of task {}", tasks[i].id))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            for episode in &episodes {
                writer.add(episode)?;
                progress.inc(1);
            }
        }
        progress.finish_and_clear();
        writer.finish()
    })();
    let written = match written {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    crate::cli::export::move_into_place(&staging, &args.out)?;
    writeln!(
        out,
        "wrote {} expert demos ({} frames, {} tasks) to {} in LeRobot's layout ({})",
        written.episodes,
        written.frames,
        written.tasks,
        args.out.display(),
        args.out.join(marker).display()
    )?;
    Ok(())
}

fn save_png(img: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    img.save(path)
        .with_context(|| format!("writing {}", path.display()))
}

/// Records the demo and writes `demo.json`, `frames/*.png`,
/// `contact-sheet.png` (flat steps, captioned) and
/// `contact-sheet-primitives.png` (the frames `frames/step_NNN.png` and
/// `frames/step_NNN_prim_J.png` tiled).
pub fn write_demo(
    task: BlocksTask,
    opts: &DemoOptions,
    out: &mut impl std::io::Write,
) -> anyhow::Result<()> {
    let occupied = std::fs::read_dir(&opts.out).is_ok_and(|mut d| d.next().is_some());
    if occupied && !opts.force {
        bail!(
            "{} is not empty; pass --force to write the demo into it anyway, or choose another --out",
            opts.out.display()
        );
    }
    let mut config = EnvConfig::default();
    if opts.no_failures {
        config = config.without_failures();
    }
    let demo: RichDemo =
        record_rich_demo(task, config, opts.seed).context("recording the expert demo")?;
    let frames_dir = opts.out.join("frames");
    std::fs::create_dir_all(&frames_dir)
        .with_context(|| format!("creating {}", frames_dir.display()))?;
    let mut json = serde_json::to_value(&demo)?;
    json["primitive_sequence"] = serde_json::json!(demo.trace.primitives());
    json["action_sequence"] = serde_json::json!(demo.action_sequence());
    let json_path = opts.out.join("demo.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    let mut all_frames = Vec::new();
    for (k, frame) in demo.frames.iter().enumerate() {
        save_png(frame, &frames_dir.join(format!("step_{k:03}.png")))?;
        all_frames.push(frame);
        if let Some(prims) = demo.primitive_frames.get(k) {
            for (j, f) in prims.iter().enumerate() {
                save_png(
                    f,
                    &frames_dir.join(format!("step_{:03}_prim_{j}.png", k + 1)),
                )?;
                all_frames.push(f);
            }
        }
    }
    // Frame k shows the scene after the demo's k-th action.
    let actions: Vec<&str> = demo.steps.iter().map(|st| st.action.as_str()).collect();
    let flat: Vec<(&image::RgbImage, String)> = demo
        .frames
        .iter()
        .enumerate()
        .map(|(k, frame)| {
            let caption = match k.checked_sub(1).and_then(|i| actions.get(i)) {
                Some(action) => format!("{k} {action}"),
                None => format!("{k} <start>"),
            };
            (frame, caption)
        })
        .collect();
    save_png(
        &captioned_contact_sheet(&flat, opts.columns, opts.scale, 2),
        &opts.out.join("contact-sheet.png"),
    )?;
    save_png(
        &contact_sheet(&all_frames, opts.columns, opts.scale, 2),
        &opts.out.join("contact-sheet-primitives.png"),
    )?;
    writeln!(
        out,
        "{}: {} actions, success {}: {}\nwrote {}",
        demo.task.id(),
        demo.steps.len(),
        demo.success,
        demo.action_sequence(),
        opts.out.display()
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../env-blocks/tests/fixtures/ntp_small.json")
    }

    #[test]
    fn stats_json_of_a_file() {
        let args = TasksArgs {
            stats: true,
            source: Some(fixture()),
            json: true,
            write: None,
            force: false,
        };
        let mut out = Vec::new();
        run_tasks(&args, &mut out).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["tasks"], 3);
        assert_eq!(v["goals_per_task"]["3"], 1);
        assert_eq!(v["towers_per_task"]["2"], 2);
    }

    #[test]
    fn missing_source_is_an_error_naming_the_file() {
        let args = TasksArgs {
            stats: true,
            source: Some("/nonexistent.json".into()),
            json: false,
            write: None,
            force: false,
        };
        let err = run_tasks(&args, &mut Vec::new()).unwrap_err();
        assert!(format!("{err:#}").contains("/nonexistent.json"), "{err:#}");
    }

    #[test]
    fn existing_files_are_not_overwritten_without_force() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("tasks.json");
        std::fs::write(&file, "mine").unwrap();
        let mut args = TasksArgs {
            stats: false,
            source: Some(fixture()),
            json: false,
            write: Some(file.clone()),
            force: false,
        };
        let err = run_tasks(&args, &mut Vec::new()).unwrap_err();
        assert!(format!("{err:#}").contains("--force"), "{err:#}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
        args.force = true;
        run_tasks(&args, &mut Vec::new()).unwrap();
        assert_eq!(read_ntp_tasks(&file).unwrap().len(), 3);

        let note = dir.path().join("notes.txt");
        std::fs::write(&note, "mine").unwrap();
        let tasks = load_tasks(Some(&fixture())).unwrap();
        let mut opts = DemoOptions {
            seed: 1,
            out: dir.path().to_owned(),
            no_failures: true,
            columns: 4,
            scale: 2,
            force: false,
        };
        let task = || BlocksTask::Stack(tasks[0].clone());
        let err = write_demo(task(), &opts, &mut Vec::new()).unwrap_err();
        assert!(format!("{err:#}").contains("not empty"), "{err:#}");
        assert!(!dir.path().join("demo.json").exists());
        opts.force = true;
        write_demo(task(), &opts, &mut Vec::new()).unwrap();
        assert!(dir.path().join("demo.json").exists());
        assert_eq!(std::fs::read_to_string(&note).unwrap(), "mine");
    }

    #[test]
    fn demo_writes_json_frames_and_sheets() {
        let dir = tempfile::tempdir().unwrap();
        let tasks = load_tasks(Some(&fixture())).unwrap();
        let task = find_stack_task(&tasks, "stack_2").unwrap().clone();
        let opts = DemoOptions {
            seed: 1,
            out: dir.path().to_owned(),
            no_failures: true,
            columns: 4,
            scale: 2,
            force: false,
        };
        write_demo(BlocksTask::Stack(task), &opts, &mut Vec::new()).unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("demo.json")).unwrap())
                .unwrap();
        assert_eq!(json["success"], true);
        assert_eq!(json["steps"].as_array().unwrap().len(), 8);
        assert_eq!(json["primitive_sequence"].as_array().unwrap().len(), 16);
        assert!(dir.path().join("frames/step_000.png").exists());
        assert!(dir.path().join("frames/step_008_prim_1.png").exists());
        let sheet = image::open(dir.path().join("contact-sheet.png")).unwrap();
        assert_eq!(sheet.width(), 4 * 128 + 5 * 2);
        assert!(find_stack_task(&tasks, "stack_9").is_err());
        assert!(find_stack_task(&tasks, "1").is_ok());
    }
}
