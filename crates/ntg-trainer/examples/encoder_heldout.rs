//! Scores the shared frame encoder of a block-stacking video run (its
//! stage A network) on the frames of validation-task demo videos: the
//! localizer's accuracy over every frame and over the keyframes, and the
//! edge head's. Validation tasks only: choose stage A's settings here,
//! never on test tasks.
//!
//! `cargo run --release -p ntg-trainer --example encoder_heldout -- RUN [TASKS]`
//! (default 100 tasks, one video each, recorded as `ntg train` records its
//! validation videos).

use anyhow::Context;
use ntg_model::FrameStageNet;
use ntg_trainer::blocks::{self, BlocksRunConfig, VALIDATION_DEMO_SEED_BASE};
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;
use ntg_trainer::video::{FrameStageStep, STAGE_A_DIR, frame_dataset};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = args.first().context("usage: encoder_heldout RUN [TASKS]")?;
    let tasks: usize = match args.get(1) {
        Some(t) => t
            .parse()
            .with_context(|| format!("TASKS: {t:?} is not a count"))?,
        None => 100,
    };
    let run = RunDir::open(std::path::Path::new(run))?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let video = config
        .video
        .context("not a video run (no `video` settings)")?;
    let stage_a = RunDir::open(&run.root().join(STAGE_A_DIR))?;
    let dir = match ntg_trainer::fit::selected_epoch(&stage_a)? {
        Some(_) => stage_a.best_dir(),
        None => stage_a.checkpoint_dir(),
    };
    let device = ntg_model::cpu_device();
    let net = FrameStageNet::load(&dir, &device)
        .with_context(|| format!("loading the stage A network in {}", dir.display()))?;
    let validation = env_blocks::validation_tasks(tasks)?;
    let env_cfg = blocks::env_config(ObsKind::Vid, config.failures);
    let record = |i: usize, seed: u64| {
        let v = env_blocks::record_video_demo(
            env_blocks::BlocksTask::Stack(validation[i].clone()),
            env_cfg,
            seed,
            &video.frames,
        )?;
        Ok(v.map_frames(|f| env_collect::frame_to_chw(&f)))
    };
    let pairs: Vec<(usize, u64)> = (0..tasks)
        .map(|i| (i, VALIDATION_DEMO_SEED_BASE + i as u64))
        .collect();
    let vocab = blocks::flat_vocabulary();
    let frames = frame_dataset(&vocab, &pairs, &record, 3 * 64 * 64, 1.0)?;
    let step = FrameStageStep::new(&frames, &device)?;
    let acc = step.accuracy(&net)?;
    println!(
        "{}: {} validation videos, localizer {:.3} (keyframes {:.3}), edges {:.3}",
        run.root().display(),
        tasks,
        acc.localizer,
        acc.keyframe_localizer,
        acc.edge
    );
    Ok(())
}
