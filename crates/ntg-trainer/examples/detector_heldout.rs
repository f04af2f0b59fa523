//! The NTP (Detector) baseline's detector (frame → block-stacking state
//! row) trained on rendered frames of training-task expert episodes and
//! scored on frames of validation-task episodes it never saw: the mean
//! distance between estimated and true cube positions, and the gripper
//! state's accuracy. Validation tasks only: choose the detector's settings
//! here, never on test tasks.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example detector_heldout -- \
//!     OUT TASKS DEMOS EPOCHS [lr=LR] [batch=B] [hidden=H] [coords] [shards=S] [validation=V] [noscale]
//! ```
//!
//! The detector predicts positions divided by their standard deviation in
//! the training frames (`noscale`: raw positions).
//!
//! Trains on `DEMOS` primitive-level episodes of each of the first `TASKS`
//! training tasks (seeds as `ntg train`'s demos), `EPOCHS` passes, into
//! the new run folder `OUT`; scores after every epoch on one episode of
//! each of the first `V` (default 50) validation tasks and keeps the best
//! epoch, then scores that epoch on the next `V` validation tasks (never
//! used to select) and writes it to `OUT/held_out.json`, beside the error
//! of always answering the training frames' mean state.

use anyhow::{Context, bail};
use ntg_model::{DetectorConfig, EncoderConfig, FrameEncoderConfig};
use ntg_trainer::blocks::{self, TRAIN_SEED_BASE, VALIDATION_DEMO_SEED_BASE};
use ntg_trainer::fit::{OptimConfig, fit};
use ntg_trainer::method::detector::{DetectorDataset, DetectorEpochMetrics, DetectorStep};
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;

const USAGE: &str = "usage: detector_heldout OUT TASKS DEMOS EPOCHS [lr=LR] [batch=B] [hidden=H] [coords] [shards=S] [validation=V] [noscale]";

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        bail!("{USAGE}");
    }
    let count = |i: usize, name: &str| -> anyhow::Result<usize> {
        args[i]
            .parse()
            .with_context(|| format!("{name}: {:?} is not a count; {USAGE}", args[i]))
    };
    let out = std::path::PathBuf::from(&args[0]);
    let (tasks, demos, epochs) = (count(1, "TASKS")?, count(2, "DEMOS")?, count(3, "EPOCHS")?);
    let (mut lr, mut batch, mut hidden, mut coords, mut shards, mut validation) =
        (1e-3f64, 32usize, 256usize, false, 2usize, 50usize);
    let mut scaled = true;
    for option in &args[4..] {
        match option.split_once('=') {
            Some(("lr", v)) => lr = v.parse().context("lr=")?,
            Some(("batch", v)) => batch = v.parse().context("batch=")?,
            Some(("hidden", v)) => hidden = v.parse().context("hidden=")?,
            Some(("shards", v)) => shards = v.parse().context("shards=")?,
            Some(("validation", v)) => validation = v.parse().context("validation=")?,
            None if option == "coords" => coords = true,
            None if option == "noscale" => scaled = false,
            _ => bail!("unknown option {option:?}; {USAGE}"),
        }
    }
    let env = blocks::env_config(ObsKind::Vid, true);
    let split = env_blocks::standard_split()?;
    let started = std::time::Instant::now();
    let train = DetectorDataset::record(split.train(tasks)?, demos, TRAIN_SEED_BASE, env)?;
    let validation_tasks = env_blocks::validation_tasks(2 * validation)?;
    let (select_tasks, report_tasks) = validation_tasks.split_at(validation);
    let held_out = DetectorDataset::record(select_tasks, 1, VALIDATION_DEMO_SEED_BASE, env)?;
    let report = DetectorDataset::record(report_tasks, 1, VALIDATION_DEMO_SEED_BASE + 1, env)?;
    eprintln!(
        "{} training frames, {} + {} held-out frames, recorded in {:.1}s",
        train.len(),
        held_out.len(),
        report.len(),
        started.elapsed().as_secs_f32()
    );
    let device = ntg_model::cpu_device().autodiff();
    let config = DetectorConfig::new(
        env_blocks::world::NUM_OBJECTS,
        EncoderConfig::Frame(
            FrameEncoderConfig::new()
                .with_he_init(Some(true))
                .with_centre_input(Some(true))
                .with_coord_channels(coords.then_some(true)),
        ),
    )
    .with_hidden(hidden)
    .with_position_scale(scaled.then(|| train.position_std()));
    eprintln!("position scale: {:?}", config.position_scale);
    let run = RunDir::create(&out)?;
    let step = DetectorStep {
        dataset: &train,
        device: device.clone(),
    };
    let optim = OptimConfig {
        epochs,
        batch_size: batch,
        learning_rate: lr,
        seed: 0,
        token_dropout: 0.0,
        gcn_from_other_demo: false,
        cosine_decay: true,
        shards,
    };
    let plain = ntg_model::cpu_device();
    let mut validator =
        |net: &ntg_model::Detector| -> anyhow::Result<ntg_trainer::fit::ValidationScore> {
            let score = held_out.score(net, &plain)?;
            eprintln!(
                "  held out ({} frames): position error {:.4} | gripper {:.3}",
                score.frames, score.position_error, score.gripper_accuracy
            );
            // Higher is better: the negated error.
            Ok(ntg_trainer::fit::ValidationScore {
                success: -score.position_error,
                goal_fraction: score.gripper_accuracy,
            })
        };
    let net = fit(
        config.init(&device)?,
        &step,
        &optim,
        &run,
        &device,
        Some(ntg_trainer::fit::Selection {
            validator: &mut validator,
            every: 1,
        }),
        |m: &DetectorEpochMetrics| {
            eprintln!(
                "epoch {:>3}: loss {:.4} | position error {:.4} | gripper {:.3} | {:.1}s",
                m.epoch, m.loss, m.position_error, m.gripper_accuracy, m.seconds
            )
        },
    )?;
    let score = report.score(&net, &plain)?;
    let mean_error = report.mean_state_error(&train);
    RunDir::write_json(
        &out.join("held_out.json"),
        &serde_json::json!({ "detector": score, "mean_state_position_error": mean_error }),
    )?;
    println!(
        "held out: {} frames of {validation} other validation tasks: position error {:.4} (answering the training frames' mean state: {mean_error:.4}), gripper {:.3}",
        score.frames, score.position_error, score.gripper_accuracy
    );
    Ok(())
}
