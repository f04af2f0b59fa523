//! How well a block-stacking video run's demo interpreter transcribes demo
//! videos it never saw: one video of each of the first TASKS validation
//! tasks (never test tasks), recorded as `ntg eval --split validation`
//! records its demos (same seeds, failures as the run), encoded by the
//! run's frozen stage A encoder and decoded greedily by the interpreter of
//! the run's selected epoch.
//!
//! Prints the token accuracy (tokens equal at the same position, over the
//! longer of the two sequences, summed over videos) and the fraction of
//! videos transcribed exactly.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example interpreter_heldout -- RUN [TASKS]
//! ```

use anyhow::{Context, ensure};
use ctg_graph::ActionId;
use ntg_trainer::blocks::{self, BlocksRunConfig};
use ntg_trainer::fit::TrainedModel;
use ntg_trainer::method::on_frames::VideoNtgModel;
use ntg_trainer::run_dir::RunDir;

fn main() -> anyhow::Result<()> {
    let usage = "usage: interpreter_heldout RUN [TASKS]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = RunDir::open(std::path::Path::new(args.first().context(usage)?))?;
    let tasks: usize = args.get(1).map_or(Ok(200), |t| t.parse()).context(usage)?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let video = config
        .video
        .as_ref()
        .with_context(|| format!("{} is not a video run", run.root().display()))?;
    let dir = match ntg_trainer::fit::selected_epoch(&run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    let model = VideoNtgModel::load_from(&dir, &ntg_model::cpu_device())?;

    let validation = env_blocks::validation_tasks(tasks)?;
    let (mut equal, mut total, mut exact) = (0usize, 0usize, 0usize);
    let mut frames_per_video = Vec::with_capacity(tasks);
    for (i, seed) in blocks::validation_video_pairs(tasks) {
        let demo = blocks::record_video(
            validation[i].clone(),
            config.failures,
            video.camera,
            &video.frames,
            seed,
        )?;
        let embedded = model.encode_rows(demo.frames())?;
        let decoded: Vec<ActionId> = model.policy.interpreter.decode(&embedded)?;
        let truth = demo.actions();
        equal += decoded.iter().zip(truth).filter(|(a, b)| a == b).count();
        total += truth.len().max(decoded.len());
        exact += usize::from(decoded.as_slice() == truth);
        frames_per_video.push(demo.num_frames());
    }
    ensure!(total > 0, "no validation videos");
    frames_per_video.sort_unstable();
    println!(
        "{tasks} held-out validation videos ({} to {} frames, median {}): token accuracy {:.4} ({equal}/{total}), transcribed exactly {exact}/{tasks} = {:.3}",
        frames_per_video[0],
        frames_per_video[tasks - 1],
        frames_per_video[tasks / 2],
        equal as f64 / total as f64,
        exact as f64 / tasks as f64,
    );
    Ok(())
}
