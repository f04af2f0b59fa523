//! `ntg trace`: one test task executed step by step, written out so a
//! person can see what the policy did and why.
//!
//! The trace folder holds `trace.json` (every step: the localised node with
//! its probability, the CTG successors of that node with ε, the chosen
//! action with π, and what the environment reported), `trace.txt` (the same
//! as a table), `ctg.dot` / `ctg.svg` (the executed graph, rendered
//! in-process), `demo.txt`, and one PNG per observation under `frames/`
//! plus `contact-sheet.png` (the frames captioned with each step's action),
//! `rollout.gif` (the same frames as an animation) and `lerobot/` (the
//! rollout as a one-episode dataset in LeRobot's layout, [`crate::lerobot`]).
//!
//! The NTP baselines have no graph: their trace ([`trace_baseline`]) shows,
//! per primitive, the programs running when it was chosen (NTP's call
//! stack and each program's scope of the demo), with the same files but
//! the graph's.
//!
//! The rollout is the one `ntg eval` scores for the same task: same
//! conditioning-demo seed, same rollout seed, greedy action choice. Frames
//! are rendered even for state-input runs; rendering draws no random
//! numbers, so the rollout is unchanged by it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use ctg_graph::{ActionId, Environment, GraphExecutor, Vocabulary};
use env_blocks::{BlocksEnv, BlocksObservation};
use ntg_model::NtgModel;
use serde::{Deserialize, Serialize};

use crate::blocks::{ObsKind, ROLLOUT_SEED_BASE, env_config, featurize};

/// A node or action with its probability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scored {
    /// Vocabulary name.
    pub name: String,
    /// Probability.
    pub p: f32,
}

/// One executed step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TraceStep {
    /// Step index (0-based); frame `frames/step_NNN.png` is the observation
    /// the step was decided on.
    pub step: usize,
    /// The most likely node under ℓ(·|o), and the next two.
    pub localized: Vec<Scored>,
    /// Successors of the most likely node in the CTG with ε(·|n,o).
    pub edges_from_localized: Vec<Scored>,
    /// The chosen action with π(a|o).
    pub chosen: Scored,
    /// What went wrong in the environment, if anything (slip, off-centre
    /// drop, invalid action).
    pub failure: Option<String>,
    /// Whether every goal held after the step.
    pub success_after: bool,
}

/// The whole trace (`trace.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trace {
    /// Index in the standard test set.
    pub index: usize,
    /// Task id.
    pub task: String,
    /// The expert's actions in the conditioning demo.
    pub demo_actions: Vec<String>,
    /// The demo interpreter's transcription.
    pub transcription: Vec<String>,
    /// Steps in order.
    pub steps: Vec<TraceStep>,
    /// Whether the task was completed.
    pub success: bool,
    /// Whether the step limit cut the episode.
    pub truncated: bool,
}

fn top(probabilities: &[f32], vocab: &Vocabulary, k: usize) -> Vec<Scored> {
    let mut order: Vec<usize> = (0..probabilities.len()).collect();
    order.sort_by(|&a, &b| {
        probabilities[b]
            .total_cmp(&probabilities[a])
            .then(a.cmp(&b))
    });
    order
        .into_iter()
        .take(k)
        .filter(|&i| probabilities[i] > 0.0)
        .map(|i| Scored {
            name: vocab.name(ActionId::new(i)).unwrap_or("?").to_owned(),
            p: probabilities[i],
        })
        .collect()
}

/// Resolves `task` (a test-set index or a task id such as `stack_1003`) to
/// its index in the test set of the task set `tasks`
/// ([`crate::blocks::task_split`]; `None`: the standard one).
pub fn resolve_test_task(
    tasks: crate::blocks::TaskSource<'_>,
    task: &str,
) -> anyhow::Result<usize> {
    let split = crate::blocks::task_split(tasks)?;
    if let Ok(i) = task.parse::<usize>() {
        if i < split.test.len() {
            return Ok(i);
        }
        bail!(
            "test task index {i} is out of range (the test set has {} tasks)",
            split.test.len()
        );
    }
    split
        .test
        .iter()
        .position(|t| t.id == task)
        .with_context(|| {
            format!(
                "no test task with id {task:?} (ids run from {:?} to {:?}; or give an index)",
                split.test.first().map(|t| t.id.as_str()).unwrap_or(""),
                split.test.last().map(|t| t.id.as_str()).unwrap_or("")
            )
        })
}

/// Runs test task `index` with `model` and writes the trace into `out`
/// (created; it must not exist or be empty, so nothing is overwritten).
pub fn trace_task(
    model: &NtgModel,
    tasks: crate::blocks::TaskSource<'_>,
    obs: ObsKind,
    failures: bool,
    index: usize,
    out: &Path,
) -> anyhow::Result<Trace> {
    prepare_out(out)?;
    let split = crate::blocks::task_split(tasks)?;
    let task = split
        .test
        .get(index)
        .with_context(|| format!("test task index {index} is out of range"))?;
    let vocab = env_blocks::vocabulary(false, env_blocks::ActionLevel::Flat);
    let mut env_cfg = env_config(obs, failures);
    env_cfg.render = true;
    let mut env = BlocksEnv::stacking(task.clone(), env_cfg)?;
    let (demo, policy) = crate::blocks::conditioned_policy(model, &mut env, task, index, obs)?;
    let names = |ids: &[ActionId]| -> Vec<String> {
        ids.iter()
            .map(|&a| vocab.name(a).unwrap_or("?").to_owned())
            .collect()
    };

    let exec: GraphExecutor = policy.executor();
    let n = vocab.len();
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir)
        .with_context(|| format!("creating {}", frames_dir.display()))?;
    let mut frames = Vec::new();
    let mut rows = Vec::new();
    let mut steps = Vec::new();
    let rollout_seed = ROLLOUT_SEED_BASE + index as u64;
    let (mut observation, _) = env.reset(rollout_seed)?;
    // The same tie-breaking as the evaluation's episode.
    let mut ties = crate::method::Ties::for_episode(rollout_seed);
    // What the agent has done so far, as the evaluation tells the policy
    // (read by an execution memory or a node taken from it).
    let mut executed: Vec<ActionId> = Vec::new();
    let (success, truncated) = loop {
        policy.set_executed(&executed);
        let row = featurize(&observation, obs);
        let mapped = policy.mapped(|o: &BlocksObservation| featurize(o, obs));
        let (mut nodes, mut edges) = (&mapped, &mapped);
        let dist = exec.action_distribution(&mut nodes, &mut edges, &observation)?;
        let node_p = policy.node_probabilities(&row)?;
        let edge_p = policy.edge_probabilities_for(policy.graph(), &row)?;
        let node = dist.localized_node();
        let action = dist.most_likely_breaking_ties(ties.draw());
        let frame = observation
            .frame()
            .context("the environment returned no frame with rendering on")?
            .clone();
        save_png(
            &frame,
            &frames_dir.join(format!("step_{:03}.png", steps.len())),
        )?;
        rows.push(crate::lerobot::Row {
            frame: frame.clone(),
            state: Some(observation.state().to_vec()),
            action: action.index(),
            success_after: false,
        });
        frames.push(frame);
        executed.push(action);
        let step = env.step(action)?;
        if let Some(row) = rows.last_mut() {
            row.success_after = step.info.success;
        }
        steps.push(TraceStep {
            step: steps.len(),
            localized: top(&node_p, &vocab, 3),
            edges_from_localized: top(&edge_p[node.index() * n..(node.index() + 1) * n], &vocab, n),
            chosen: Scored {
                name: vocab.name(action).unwrap_or("?").to_owned(),
                p: dist.probability(action),
            },
            failure: step.info.failure.as_ref().map(|f| f.to_string()),
            success_after: step.info.success,
        });
        let done = step.is_done();
        let truncated = step.truncated;
        observation = step.observation;
        if done {
            break (env.is_success(), truncated);
        }
    };
    if let Some(frame) = observation.frame() {
        save_png(
            frame,
            &frames_dir.join(format!("step_{:03}.png", steps.len())),
        )?;
        frames.push(frame.clone());
        rows.push(crate::lerobot::Row {
            frame: frame.clone(),
            state: Some(observation.state().to_vec()),
            action: Vocabulary::END.index(),
            success_after: success,
        });
    }
    write_rollout_dataset(
        out,
        &vocab,
        task,
        rollout_seed,
        rows,
        success,
        "NTG".to_owned(),
    )?;
    let mut captions: Vec<String> = steps
        .iter()
        .map(|st| format!("{} {}", st.step, st.chosen.name))
        .collect();
    captions.push(end_caption(success, truncated));
    write_rollout_images(out, &frames, &captions)?;

    let dot = policy.graph().to_dot(&vocab)?;
    write(&out.join("ctg.dot"), &dot)?;
    write(&out.join("ctg.svg"), &crate::svg::dot_to_svg(&dot)?)?;
    let trace = Trace {
        index,
        task: task.id.clone(),
        demo_actions: names(demo.actions()),
        transcription: names(policy.demo_actions()),
        steps,
        success,
        truncated,
    };
    write(
        &out.join("demo.txt"),
        &format!(
            "demo (expert):        {}\ntranscribed (NTG):    {}\n",
            trace.demo_actions.join(" "),
            trace.transcription.join(" ")
        ),
    )?;
    write(&out.join("trace.txt"), &trace_table(&trace))?;
    crate::run_dir::RunDir::write_json(&out.join("trace.json"), &trace)?;
    Ok(trace)
}

/// One primitive of a baseline's trace.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaselineStep {
    /// Step index (0-based); frame `frames/step_NNN.png` is the observation
    /// the step was decided on.
    pub step: usize,
    /// What the policy was running when it chose (NTP: its call stack with
    /// each program's scope of the demo's rows).
    pub programs: Option<String>,
    /// The chosen action.
    pub chosen: String,
    /// What went wrong in the environment, if anything.
    pub failure: Option<String>,
    /// Whether every goal held after the step.
    pub success_after: bool,
}

/// A baseline's whole trace (`trace.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaselineTrace {
    /// The method's name.
    pub method: String,
    /// Index in the standard test set.
    pub index: usize,
    /// Task id.
    pub task: String,
    /// The expert's actions in the conditioning demo (one demo row before
    /// each).
    pub demo_actions: Vec<String>,
    /// Steps in order.
    pub steps: Vec<BaselineStep>,
    /// Whether the task was completed.
    pub success: bool,
    /// Whether the step limit cut the episode.
    pub truncated: bool,
}

/// Runs test task `index` with an NTP baseline `model` trained as
/// `config` says (its method, task set, input, camera and failure model)
/// exactly as `ntg eval` does, and writes its trace into `out` (created;
/// it must not exist or be empty).
pub fn trace_baseline(
    model: &dyn crate::method::TrainedPolicy,
    config: &crate::blocks::BlocksRunConfig,
    index: usize,
    out: &Path,
) -> anyhow::Result<BaselineTrace> {
    let (method, obs, failures) = (config.method, config.obs, config.failures);
    prepare_out(out)?;
    let split = crate::blocks::task_split(config.task_source())?;
    let task = split
        .test
        .get(index)
        .with_context(|| format!("test task index {index} is out of range"))?;
    let domain = crate::blocks::BlocksDomain::new(obs, failures)
        .with_camera(config.camera())
        .at_primitive_level()
        .rendering();
    let seeds = crate::blocks::Seeds::TEST;
    let episode = crate::domain::Episode {
        group: 0,
        index,
        task: task.clone(),
        demo_seed: seeds.demo + index as u64,
        rollout_seed: seeds.rollout + index as u64,
    };
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir)
        .with_context(|| format!("creating {}", frames_dir.display()))?;
    let vocab = env_blocks::vocabulary(false, env_blocks::ActionLevel::Primitive);
    let (mut frames, mut steps, mut truncated) = (Vec::new(), Vec::new(), false);
    let mut rows = Vec::new();
    let model = model.for_inference();
    let record = crate::domain::run_episode_observed(&domain, model.as_ref(), &episode, |d| {
        let mut shown = vec![d.observation];
        if d.step.is_done() {
            shown.push(&d.step.observation);
            truncated = d.step.truncated;
        }
        for (k, o) in shown.into_iter().enumerate() {
            let frame = o
                .frame()
                .context("the environment returned no frame with rendering on")?;
            save_png(
                frame,
                &frames_dir.join(format!("step_{:03}.png", frames.len())),
            )?;
            frames.push(frame.clone());
            // The observation decided on, then (after the last decision)
            // the final one with `<end>`.
            rows.push(crate::lerobot::Row {
                frame: frame.clone(),
                state: Some(o.state().to_vec()),
                action: if k == 0 {
                    d.action.index()
                } else {
                    Vocabulary::END.index()
                },
                success_after: d.step.info.success,
            });
        }
        steps.push(BaselineStep {
            step: steps.len(),
            programs: d.explanation,
            chosen: vocab.name(d.action).unwrap_or("?").to_owned(),
            failure: d.step.info.failure.as_ref().map(|f| f.to_string()),
            success_after: d.step.info.success,
        });
        Ok(())
    })?;
    write_rollout_dataset(
        out,
        &vocab,
        task,
        episode.rollout_seed,
        rows,
        record.success,
        method.legend().to_owned(),
    )?;
    let mut captions: Vec<String> = steps
        .iter()
        .map(|st: &BaselineStep| format!("{} {}", st.step, st.chosen))
        .collect();
    captions.push(end_caption(record.success, truncated));
    write_rollout_images(out, &frames, &captions)?;
    let trace = BaselineTrace {
        method: method.name().to_owned(),
        index,
        task: task.id.clone(),
        demo_actions: record.demo_actions,
        steps,
        success: record.success,
        truncated,
    };
    write(
        &out.join("demo.txt"),
        &format!("demo (expert): {}\n", trace.demo_actions.join(" ")),
    )?;
    write(&out.join("trace.txt"), &baseline_table(&trace))?;
    crate::run_dir::RunDir::write_json(&out.join("trace.json"), &trace)?;
    Ok(trace)
}

/// A baseline's trace as a plain-text table (`trace.txt`).
pub fn baseline_table(trace: &BaselineTrace) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "task {} (test index {}), {}: {}",
        trace.task,
        trace.index,
        trace.method,
        outcome(trace.success, trace.truncated)
    );
    let _ = writeln!(
        s,
        "{:>4}  {:<12} {:<56} environment",
        "step", "primitive", "running programs (scopes: demo rows)"
    );
    for st in &trace.steps {
        let _ = writeln!(
            s,
            "{:>4}  {:<12} {:<56} {}",
            st.step,
            st.chosen,
            st.programs.as_deref().unwrap_or(""),
            environment_note(st.failure.as_deref(), st.success_after)
        );
    }
    s
}

fn outcome(success: bool, truncated: bool) -> &'static str {
    if success {
        "success"
    } else if truncated {
        "failed (step limit)"
    } else {
        "failed"
    }
}

fn environment_note(failure: Option<&str>, success_after: bool) -> &str {
    failure.unwrap_or(if success_after { "goal reached" } else { "" })
}

/// The trace as a plain-text table (`trace.txt`).
pub fn trace_table(trace: &Trace) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "task {} (test index {}): {}",
        trace.task,
        trace.index,
        outcome(trace.success, trace.truncated)
    );
    let _ = writeln!(
        s,
        "{:>4}  {:<22} {:<22} {:<34} environment",
        "step", "localised node", "chosen edge", "other successors"
    );
    for st in &trace.steps {
        let node = st
            .localized
            .first()
            .map(|n| format!("{} ({:.2})", n.name, n.p))
            .unwrap_or_default();
        let others: Vec<String> = st
            .edges_from_localized
            .iter()
            .filter(|e| e.name != st.chosen.name)
            .take(3)
            .map(|e| format!("{} {:.2}", e.name, e.p))
            .collect();
        let _ = writeln!(
            s,
            "{:>4}  {:<22} {:<22} {:<34} {}",
            st.step,
            node,
            format!("{} ({:.2})", st.chosen.name, st.chosen.p),
            others.join(", "),
            environment_note(st.failure.as_deref(), st.success_after)
        );
    }
    s
}

fn prepare_out(out: &Path) -> anyhow::Result<()> {
    if out.exists() {
        let mut entries = std::fs::read_dir(out)
            .with_context(|| format!("{} exists and is not a readable folder", out.display()))?;
        if entries.next().is_some() {
            bail!(
                "{} already exists and is not empty; choose another --out (nothing was overwritten)",
                out.display()
            );
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))
}

fn write(path: &PathBuf, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// The caption of an episode's last frame.
fn end_caption(success: bool, truncated: bool) -> String {
    match (success, truncated) {
        (true, _) => "end: success".into(),
        (false, true) => "end: step limit".into(),
        (false, false) => "end: failed".into(),
    }
}

/// How long `rollout.gif` shows each frame, in milliseconds.
const GIF_FRAME_MS: u32 = 700;

/// Writes a rollout's frames (one per observation, the last after the
/// last step) as `contact-sheet.png`, each captioned with `captions` (the
/// step and the action chosen on it), and as the animation `rollout.gif`
/// (frames scaled 2x, looping).
/// The rollout as a one-episode dataset in LeRobot's layout
/// (`OUT/lerobot/`, [`crate::lerobot`]).
fn write_rollout_dataset(
    out: &Path,
    vocab: &Vocabulary,
    task: &env_blocks::StackTask,
    rollout_seed: u64,
    rows: Vec<crate::lerobot::Row>,
    success: bool,
    policy: String,
) -> anyhow::Result<()> {
    let info = crate::lerobot::DatasetInfo {
        robot_type: "ntg-rs block stacking".into(),
        source: format!("{policy}'s rollout of test task {} (ntg trace)", task.id),
        vocabulary: vocab.names().to_vec(),
        fps: 1,
    };
    let mut writer = crate::lerobot::DatasetWriter::create(&out.join(DATASET_DIR), info)?;
    writer.add(&crate::lerobot::Episode {
        task: crate::blocks::stack_words(task),
        task_id: task.id.clone(),
        seed: rollout_seed,
        rows,
        success,
    })?;
    writer.finish()?;
    Ok(())
}

/// The folder of a trace that holds its rollout as a LeRobot dataset.
pub const DATASET_DIR: &str = "lerobot";

fn write_rollout_images(
    out: &Path,
    frames: &[image::RgbImage],
    captions: &[String],
) -> anyhow::Result<()> {
    let cells: Vec<(&image::RgbImage, String)> = frames
        .iter()
        .zip(
            captions
                .iter()
                .cloned()
                .chain(std::iter::repeat(String::new())),
        )
        .collect();
    save_png(
        &env_blocks::sheet::captioned_contact_sheet(&cells, 8, 2, 4),
        &out.join("contact-sheet.png"),
    )?;
    let path = out.join("rollout.gif");
    let file =
        std::fs::File::create(&path).with_context(|| format!("writing {}", path.display()))?;
    let mut encoder =
        image::codecs::gif::GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    encoder
        .set_repeat(image::codecs::gif::Repeat::Infinite)
        .with_context(|| format!("writing {}", path.display()))?;
    let delay = image::Delay::from_numer_denom_ms(GIF_FRAME_MS, 1);
    for frame in frames {
        let scaled = image::imageops::resize(
            frame,
            frame.width() * 2,
            frame.height() * 2,
            image::imageops::FilterType::Nearest,
        );
        let rgba = image::DynamicImage::ImageRgb8(scaled).into_rgba8();
        encoder
            .encode_frame(image::Frame::from_parts(rgba, 0, 0, delay))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn save_png(image: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    image
        .save(path)
        .with_context(|| format!("writing {}", path.display()))
}
