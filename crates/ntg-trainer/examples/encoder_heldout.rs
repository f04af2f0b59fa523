//! The shared frame encoder of block stacking (stage A) on validation-task
//! demo videos: the localizer's accuracy over every frame and over the
//! keyframes, and the edge head's. Validation tasks only: choose stage A's
//! settings here, never on test tasks.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example encoder_heldout -- score RUN [TASKS]
//! cargo run --release -p ntg-trainer --example encoder_heldout -- errors RUN [TASKS]
//! cargo run --release -p ntg-trainer --example encoder_heldout -- decisions RUN [TASKS]
//! cargo run --release -p ntg-trainer --example encoder_heldout -- \
//!     train FRAMES OUT DEMOS EPOCHS HIDDEN [lr=LR] [batch=B] [recon=W] [he] [centre] [coords] [keypoints] [tasks=TASKS]
//! ```
//!
//! `score` scores the stage A network of a video run; `errors` breaks its
//! localizer's keyframe errors down (first keyframe or later, a retry's
//! keyframe or a first visit, pick or place confused with which) and lists
//! the most frequent confusions. `decisions` replays expert videos through
//! the whole trained policy: conditioned on one validation-task video, it
//! is shown the keyframes of another video of the same task (another seed,
//! so other slips) with the expert's actions so far as its record, and
//! every next action it picks is scored against the expert's, by the
//! situation (after a slipped grasp, after a missed drop, ...), once with
//! the localizer and once with the node taken from the record
//! (`--variant executed-node`). Where the task leaves the order of towers
//! free (the first action, the next pick after a drop), a pick that starts
//! or continues any unfinished tower also counts as right (the expert
//! shuffles the towers and builds each bottom-up); the other situations
//! have one right answer.
//! `train` trains a new
//! stage A network on the frames of the first `DEMOS` demo videos of a
//! stage A frame dataset `FRAMES` (a run's `stage_a/dataset`, so that
//! settings are compared on the same frames without re-rendering them),
//! with an encoder hidden layer of `HIDDEN` (0: none), the other settings
//! `EncoderStage`'s defaults unless given (`he`: He initialisation,
//! `centre`: centred frames), scoring it after every epoch; its checkpoints
//! go to the new folder `OUT`. `TASKS` (default 100): validation tasks, one video each, recorded as `ntg train`
//! records its validation videos.

use anyhow::Context;
use burn::module::Module;
use ntg_model::FrameStageNet;
use ntg_trainer::blocks::{self, BlocksRunConfig};
use ntg_trainer::dataset::DemoDataset;
use ntg_trainer::fit::{Selection, TrainStep, ValidationScore, fit};
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::video::{
    EncoderEpochMetrics, EncoderStage, FrameStageStep, STAGE_A_DIR, frame_dataset,
};

const USAGE: &str = "usage: encoder_heldout score RUN [TASKS] | errors RUN [TASKS] | decisions RUN [TASKS] \
                     | train FRAMES OUT DEMOS EPOCHS HIDDEN [lr=LR] [batch=B] [recon=W] [he] [centre] [coords] \
                     [keypoints] [tasks=TASKS]";

fn count(args: &[String], i: usize, name: &str, default: Option<usize>) -> anyhow::Result<usize> {
    match (args.get(i), default) {
        (Some(v), _) => v
            .parse()
            .with_context(|| format!("{name}: {v:?} is not a count")),
        (None, Some(d)) => Ok(d),
        (None, None) => anyhow::bail!("{name} missing; {USAGE}"),
    }
}

/// The frames of one demo video per validation task.
fn validation_frames(
    tasks: usize,
    failures: bool,
    camera: env_blocks::Camera,
    video: &env_blocks::VideoConfig,
) -> anyhow::Result<DemoDataset> {
    let validation = env_blocks::validation_tasks(tasks)?;
    let record = |i: usize, seed: u64| {
        blocks::record_video(validation[i].clone(), failures, camera, video, seed)
    };
    frame_dataset(
        &blocks::flat_vocabulary(),
        &blocks::validation_video_pairs(tasks),
        &record,
        camera.frame_dim(),
        1.0,
    )
}

/// What kind of node an action name is: "start", "pick", "place", ...
fn kind(name: &str) -> &str {
    name.split('(').next().unwrap_or(name)
}

/// Prints the breakdown of the localizer's keyframe errors on `frames`.
fn keyframe_errors(net: &FrameStageNet, frames: &DemoDataset) -> anyhow::Result<()> {
    use burn::tensor::{Tensor, TensorData};
    use std::collections::BTreeMap;
    let vocab = frames.vocabulary();
    let name = |a: ctg_graph::ActionId| vocab.name(a).unwrap_or("?").to_owned();
    let net = net.valid();
    let device = ntg_model::cpu_device();
    let (mut total, mut wrong) = (0usize, 0usize);
    let mut by_case: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    let mut confusions: BTreeMap<(String, String), usize> = BTreeMap::new();
    for d in frames.demos() {
        let keys = d.keyframes();
        let mut rows = Vec::new();
        for &k in &keys {
            frames.extend_row(d.first_row + k, &mut rows);
        }
        let x = Tensor::<2>::from_data(
            TensorData::new(rows, [keys.len(), frames.obs_dim()]),
            &device,
        );
        let encoded = net.encode(x)?;
        let logits = encoded.matmul(net.loc_nodes.val().transpose());
        let predicted = ntg_model::nn::to_vec_int(logits.argmax(1).reshape([keys.len()]))?;
        let labels: Vec<ctg_graph::ActionId> = std::iter::once(ctg_graph::Vocabulary::START)
            .chain(d.actions.iter().copied())
            .collect();
        for (s, (&label, &p)) in labels.iter().zip(&predicted).enumerate() {
            let p = ctg_graph::ActionId::new(p as usize);
            let retry = labels[..s].contains(&label);
            let case = format!(
                "{} keyframe, {}",
                kind(&name(label)),
                if retry { "a retry" } else { "first visit" }
            );
            let entry = by_case.entry(case).or_default();
            entry.0 += 1;
            total += 1;
            if p != label {
                entry.1 += 1;
                wrong += 1;
                let (t, q) = (name(label), name(p));
                let what = if kind(&t) == kind(&q) {
                    format!("{} -> another {}", kind(&t), kind(&q))
                } else {
                    format!("{} -> {}", kind(&t), kind(&q))
                };
                *confusions.entry((what, String::new())).or_default() += 1;
                *confusions.entry((t, q)).or_default() += 1;
            }
        }
    }
    println!(
        "{} keyframes of {} videos: {} wrong ({:.3} right)",
        total,
        frames.demos().len(),
        wrong,
        1.0 - wrong as f64 / total.max(1) as f64
    );
    for (case, (n, w)) in &by_case {
        println!(
            "  {case}: {w} wrong of {n} ({:.3} right)",
            1.0 - *w as f64 / (*n).max(1) as f64
        );
    }
    let mut kinds: Vec<_> = confusions
        .iter()
        .filter(|((_, q), _)| q.is_empty())
        .collect();
    kinds.sort_by(|a, b| b.1.cmp(a.1));
    for ((what, _), n) in kinds {
        println!("  errors {what}: {n}");
    }
    let mut pairs: Vec<_> = confusions
        .iter()
        .filter(|((_, q), _)| !q.is_empty())
        .collect();
    pairs.sort_by(|a, b| b.1.cmp(a.1));
    for ((t, q), n) in pairs.into_iter().take(15) {
        println!("  {t} read as {q}: {n}");
    }
    Ok(())
}

/// The situation of the decision after `done` (the expert's actions so
/// far) when the expert's next action is `next`.
fn situation(done: &[String], next: &str) -> &'static str {
    let last_pick = done.iter().rev().find(|a| kind(a) == "pick");
    match (done.last().map(|a| kind(a)), kind(next)) {
        (None, _) => "first action",
        (_, "<end>") => "end after the last drop",
        (Some("pick"), "pick") => "retry after a slipped grasp",
        (Some("pick"), _) => "place after a grasp",
        (Some("place"), "pick") if last_pick.is_some_and(|p| p == next) => {
            "retry after a missed drop"
        }
        (Some("place"), _) => "next pick after a drop",
        _ => "other",
    }
}

/// The picks that go on with `task` after the expert's actions `done`
/// (names such as `pick(A)`): the cube of the first unmet goal of each
/// tower, where a goal is met once its cube was placed on its target and
/// not picked again right after (a missed drop).
fn valid_picks(task: &env_blocks::StackTask, done: &[String]) -> Vec<String> {
    let name = |i: usize| env_blocks::cube_letter(i).to_string();
    let mut met = Vec::new();
    for (i, action) in done.iter().enumerate() {
        let (Some(target), Some(held)) = (
            action
                .strip_prefix("place(")
                .and_then(|a| a.strip_suffix(')')),
            done[..i].iter().rev().find(|a| kind(a) == "pick"),
        ) else {
            continue;
        };
        if done.get(i + 1) != Some(held) {
            met.push((held.clone(), target.to_owned()));
        }
    }
    task.goals_by_tower()
        .iter()
        .filter_map(|tower| {
            tower
                .iter()
                .find(|g| !met.contains(&(format!("pick({})", name(g.src)), name(g.target))))
                .map(|g| format!("pick({})", name(g.src)))
        })
        .collect()
}

/// Replays `tasks` validation tasks' expert videos through the trained
/// policy of `run` (see the module docs) and prints its decisions'
/// accuracy by situation.
fn decisions(run: &str, tasks: usize) -> anyhow::Result<()> {
    use ntg_trainer::blocks::{TrainedBlocks, VALIDATION_DEMO_SEED_BASE};
    use ntg_trainer::method::TrainedPolicy;
    use ntg_trainer::method::ntg::Variant;
    use ntg_trainer::method::on_frames::NtgBased;
    use std::collections::BTreeMap;
    let device = ntg_model::cpu_device();
    let dir = RunDir::open(std::path::Path::new(run))?;
    let config: BlocksRunConfig = RunDir::read_json(&dir.config_path())?;
    let video = config
        .video
        .context("not a video run (no `video` settings)")?;
    let TrainedBlocks::Video(model) = blocks::load_trained(&dir, None, &device)? else {
        anyhow::bail!("{run} is not a video run");
    };
    let vocab = blocks::flat_vocabulary();
    let validation = env_blocks::validation_tasks(tasks)?;
    // Another seed than the demo's: an expert episode with its own slips.
    const EPISODE_SEED_OFFSET: u64 = 1_000_000;
    for variant in [Variant::LocalizerNode, Variant::ExecutedNode] {
        let mut model = model.clone();
        model.ntg_mut().config.ablation = variant.ablation();
        let mut by_case: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
        let mut wrong_as: BTreeMap<(&str, String), usize> = BTreeMap::new();
        for (i, task) in validation.iter().enumerate() {
            let seed = VALIDATION_DEMO_SEED_BASE + i as u64;
            let demo = blocks::record_video(
                task.clone(),
                config.failures,
                video.camera,
                &video.frames,
                seed,
            )?;
            let agent = model.condition(demo.frames(), &vocab)?;
            let episode = blocks::record_video(
                task.clone(),
                config.failures,
                video.camera,
                &video.frames,
                seed + EPISODE_SEED_OFFSET,
            )?;
            let keyframes = episode.keyframes();
            let mut ties = ntg_trainer::method::Ties::for_episode(seed + EPISODE_SEED_OFFSET);
            let actions = episode.actions();
            for (s, row) in keyframes.observations().iter().enumerate() {
                let expected = actions
                    .get(s)
                    .copied()
                    .unwrap_or(ctg_graph::Vocabulary::END);
                let name = |a: ctg_graph::ActionId| vocab.name(a).unwrap_or("?").to_owned();
                let done: Vec<String> = actions[..s].iter().map(|&a| name(a)).collect();
                let case = situation(&done, &name(expected));
                let chosen = agent.act(row, &actions[..s], &mut ties)?;
                let order_free = matches!(case, "first action" | "next pick after a drop");
                let right = chosen == expected
                    || (order_free && valid_picks(task, &done).contains(&name(chosen)));
                let entry = by_case.entry(case).or_default();
                entry.0 += 1;
                if !right {
                    entry.1 += 1;
                    let what = match situation(&done, &name(chosen)) {
                        c if c == case => format!("another {}", kind(&name(chosen))),
                        c => c.to_owned(),
                    };
                    *wrong_as.entry((case, what)).or_default() += 1;
                }
            }
        }
        let (n, w) = by_case
            .values()
            .fold((0, 0), |(n, w), (a, b)| (n + a, w + b));
        println!(
            "{}: {n} decisions on {tasks} validation tasks, {w} wrong ({:.3} right)",
            variant.name(),
            1.0 - w as f64 / n.max(1) as f64
        );
        for (case, (n, w)) in &by_case {
            println!(
                "  {case}: {w} wrong of {n} ({:.3} right)",
                1.0 - *w as f64 / (*n).max(1) as f64
            );
        }
        for ((case, what), k) in &wrong_as {
            println!("    {case}, chose: {what}: {k}");
        }
    }
    Ok(())
}

/// The stage A network a video run kept (its selected epoch, or its last).
fn run_stage_a(
    run: &str,
    device: &burn::tensor::Device,
) -> anyhow::Result<(BlocksRunConfig, FrameStageNet)> {
    let run = RunDir::open(std::path::Path::new(run))?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let stage_a = RunDir::open(&run.root().join(STAGE_A_DIR))?;
    let dir = match ntg_trainer::fit::selected_epoch(&stage_a)? {
        Some(_) => stage_a.best_dir(),
        None => stage_a.checkpoint_dir(),
    };
    let net = FrameStageNet::load(&dir, device)
        .with_context(|| format!("loading the stage A network in {}", dir.display()))?;
    Ok((config, net))
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let device = ntg_model::cpu_device().autodiff();
    match args.first().map(String::as_str) {
        Some(command @ ("score" | "errors")) => {
            let run = args.get(1).context(USAGE)?;
            let tasks = count(&args, 2, "TASKS", Some(100))?;
            let (config, net) = run_stage_a(run, &device)?;
            let video = config
                .video
                .context("not a video run (no `video` settings)")?;
            let frames = validation_frames(tasks, config.failures, video.camera, &video.frames)?;
            if command == "errors" {
                keyframe_errors(&net, &frames)?;
            } else {
                let acc = FrameStageStep::new(&frames, &device)?.accuracy(&net)?;
                println!(
                    "{run}: {} validation videos, localizer {:.3} (keyframes {:.3}), edges {:.3} (retries {:?}), keyframe progress {:?}",
                    tasks,
                    acc.localizer,
                    acc.keyframe_localizer,
                    acc.edge,
                    acc.retry_edge,
                    acc.keyframe_progress
                );
            }
        }
        Some("decisions") => {
            let run = args.get(1).context(USAGE)?;
            decisions(run, count(&args, 2, "TASKS", Some(100))?)?;
        }
        Some("train") => {
            let (frames_dir, out) = (args.get(1).context(USAGE)?, args.get(2).context(USAGE)?);
            let demos = count(&args, 3, "DEMOS", None)?;
            let epochs = count(&args, 4, "EPOCHS", None)?;
            let hidden = count(&args, 5, "HIDDEN", None)?;
            let mut stage = EncoderStage {
                demos,
                epochs,
                hidden,
                ..EncoderStage::default()
            };
            let mut tasks = 100;
            for option in &args[6..] {
                match option.split_once('=') {
                    Some(("lr", v)) => stage.learning_rate = v.parse().context("lr=")?,
                    Some(("batch", v)) => stage.batch_size = v.parse().context("batch=")?,
                    Some(("recon", v)) => stage.reconstruction = v.parse().context("recon=")?,
                    Some(("tasks", v)) => tasks = v.parse().context("tasks=")?,
                    None if option == "he" => stage.he_init = true,
                    None if option == "centre" => stage.centre_input = true,
                    None if option == "coords" => stage.coord_channels = true,
                    None if option == "keypoints" => stage.spatial_softmax = true,
                    _ => anyhow::bail!("unknown option {option:?}; {USAGE}"),
                }
            }
            let frames = DemoDataset::load(std::path::Path::new(frames_dir))?;
            let side = ntg_trainer::video::frame_side(frames.obs_dim())?;
            let demos = demos.min(frames.demos().len());
            let step = FrameStageStep::new(&frames, &device)?.first_demos(demos);
            let run = RunDir::open_or_create(std::path::Path::new(out), &stage)?;
            let camera = env_blocks::Camera::of_size(side as u32);
            let held_out =
                validation_frames(tasks, true, camera, &env_blocks::VideoConfig::default())?;
            let held_out = FrameStageStep::new(&held_out, &device)?;
            let mut validator = |net: &FrameStageNet| -> anyhow::Result<ValidationScore> {
                let acc = held_out.accuracy(net)?;
                println!(
                    "  held-out: localizer {:.3} (keyframes {:.3}) | edges {:.3} (retries {:?})",
                    acc.localizer, acc.keyframe_localizer, acc.edge, acc.retry_edge
                );
                Ok(ValidationScore {
                    success: acc.keyframe_localizer,
                    goal_fraction: acc.localizer,
                })
            };
            println!(
                "stage A: {} frames of {demos} demos: {stage:?}",
                step.num_examples()
            );
            let net = stage
                .net_config(frames.vocabulary().len(), side, 0)
                .init(&device)?;
            fit(
                net,
                &step,
                &stage.optim(0),
                &run,
                &device,
                Some(Selection {
                    validator: &mut validator,
                    every: 1,
                    scores: ["keyframe localizer accuracy", "localizer accuracy"],
                }),
                |m: &EncoderEpochMetrics| {
                    println!(
                        "epoch {}: localizer {:.3} | edges {:.3} | reconstruction {:?} | {:.0}s",
                        m.epoch, m.localizer_accuracy, m.edge_accuracy, m.reconstruction, m.seconds
                    )
                },
            )?;
        }
        _ => anyhow::bail!(USAGE),
    }
    Ok(())
}
