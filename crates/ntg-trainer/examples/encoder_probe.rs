//! A diagnostic of the shared frame encoder of a block-stacking video run
//! (or of a stage A folder written by the `encoder_heldout` example):
//! how much of the simulator state (cube positions relative to the gripper,
//! the gripper's state) a linear read-out recovers from its embeddings of
//! validation-task keyframes. The state is used here only to diagnose, never
//! to train.
//!
//! Writes, for the keyframes of one demo video per validation task, raw
//! little-endian f32 matrices (rows = keyframes) to the new folder `OUT`:
//! `state.f32` (the 26-number state), `embedding.f32` (the run's stage A
//! encoder), `random.f32` (the same encoder freshly initialised: what the
//! architecture keeps untrained), `pixels.f32` (the frames) and `task.u32`
//! (each row's validation task), with their shapes in `shapes.json`.
//! `encoder_probe.py` beside this file fits the read-outs.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example encoder_probe -- RUN OUT [TASKS]
//! python3 crates/ntg-trainer/examples/encoder_probe.py OUT
//! ```

use std::io::Write;

use anyhow::{Context, ensure};
use ntg_model::FrameStageNet;
use ntg_trainer::blocks::{self, BlocksDomain, BlocksRunConfig};
use ntg_trainer::domain::Domain;
use ntg_trainer::method::on_frames::encode_rows;
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;
use ntg_trainer::video::STAGE_A_DIR;

fn write_rows(path: &std::path::Path, rows: &[Vec<f32>]) -> anyhow::Result<()> {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    for row in rows {
        for v in row {
            file.write_all(&v.to_le_bytes())?;
        }
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let usage = "usage: encoder_probe RUN OUT [TASKS]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = RunDir::open(std::path::Path::new(args.first().context(usage)?))?;
    let out = std::path::PathBuf::from(args.get(1).context(usage)?);
    let tasks: usize = args.get(2).map_or(Ok(300), |t| t.parse()).context(usage)?;
    ensure!(!out.exists(), "{} exists; choose a new OUT", out.display());
    // A video run, or a stage A folder of `encoder_heldout train` (videos
    // recorded as that example records its validation videos).
    let (failures, camera, frames, stage_a) = if run.root().join(STAGE_A_DIR).is_dir() {
        let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
        let video = config.video.context("not a video run")?;
        let stage_a = RunDir::open(&run.root().join(STAGE_A_DIR))?;
        (config.failures, video.camera, video.frames, stage_a)
    } else {
        let camera = env_blocks::Camera::default();
        (true, camera, env_blocks::VideoConfig::default(), run)
    };
    let dir = match ntg_trainer::fit::selected_epoch(&stage_a)? {
        Some(_) => stage_a.best_dir(),
        None => stage_a.checkpoint_dir(),
    };
    let device = ntg_model::cpu_device();
    let trained = FrameStageNet::load(&dir, &device)?;
    let random = trained.config().init(&device)?;

    let state_domain = BlocksDomain::new(ObsKind::State, failures);
    let validation = env_blocks::validation_tasks(tasks)?;
    let (mut states, mut pixels, mut task_of) = (Vec::new(), Vec::new(), Vec::new());
    for (i, seed) in blocks::validation_video_pairs(tasks) {
        let task = &validation[i];
        let video = blocks::record_video(task.clone(), failures, camera, &frames, seed)?;
        let mut env = state_domain.env(task)?;
        let (rows, actions) = state_domain.record_demo(&mut env, task, seed)?;
        let keyframes = video.keyframes();
        ensure!(
            actions == video.actions() && rows.len() == keyframes.observations().len(),
            "task {i}: the state demo and the video differ"
        );
        states.extend(rows);
        pixels.extend(keyframes.observations().iter().cloned());
        task_of.extend(std::iter::repeat_n(
            i as u32,
            keyframes.observations().len(),
        ));
    }
    let embedded = encode_rows(&trained, &pixels)?;
    let embedded_random = encode_rows(&random, &pixels)?;
    std::fs::create_dir_all(&out)?;
    write_rows(&out.join("state.f32"), &states)?;
    write_rows(&out.join("embedding.f32"), &embedded)?;
    write_rows(&out.join("random.f32"), &embedded_random)?;
    write_rows(&out.join("pixels.f32"), &pixels)?;
    std::fs::write(
        out.join("task.u32"),
        task_of
            .iter()
            .flat_map(|t| t.to_le_bytes())
            .collect::<Vec<u8>>(),
    )?;
    let shapes = serde_json::json!({
        "rows": states.len(),
        "state": states[0].len(),
        "embedding": embedded[0].len(),
        "random": embedded_random[0].len(),
        "pixels": pixels[0].len(),
    });
    std::fs::write(out.join("shapes.json"), shapes.to_string())?;
    println!(
        "{} keyframes of {tasks} validation tasks: {shapes}",
        states.len()
    );
    Ok(())
}
