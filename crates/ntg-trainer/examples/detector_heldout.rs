//! The NTP (Detector) baseline's detector (frame → block-stacking state
//! row) trained as `ntg train --method ntp-detector` trains it
//! ([`ntg_trainer::method::detector::train_detector`]), alone: on rendered
//! frames of training-task expert episodes, the epoch selected on one
//! episode of each of the first `V` validation tasks, and scored on one
//! episode of each of the next `V` (never used to select): the mean
//! distance between estimated and true cube positions, and the gripper
//! state's accuracy. Validation tasks only: choose the detector's settings
//! here, never on test tasks.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example detector_heldout -- \
//!     OUT TASKS EPISODES EPOCHS [lr=LR] [batch=B] [hidden=H] [shards=S] [validation=V] [no-keypoints]
//! ```
//!
//! Trains on `EPISODES` primitive-level episodes spread over the first
//! `TASKS` training tasks (seeds as `ntg train`'s demos), `EPOCHS` passes,
//! in the new folder `OUT/detector_stage`, and writes the score to
//! `OUT/detector_stage/held_out.json`. (The measurements of
//! `docs/results/ntp-2026-11-25.md` with unscaled positions or coordinate
//! channels used earlier options of this program.)

use anyhow::{Context, bail};
use ntg_trainer::blocks::{self, BlocksRunConfig, Recipe};
use ntg_trainer::method::MethodId;
use ntg_trainer::method::detector::{DetectorHeldOut, DetectorSettings};
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;

const USAGE: &str = "usage: detector_heldout OUT TASKS EPISODES EPOCHS [lr=LR] [batch=B] [hidden=H] [shards=S] [validation=V] [no-keypoints]";

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
    let mut settings = DetectorSettings {
        episodes: count(2, "EPISODES")?,
        epochs: count(3, "EPOCHS")?,
        ..DetectorSettings::default()
    };
    let mut config: BlocksRunConfig =
        Recipe::Recommended.config(ObsKind::Vid, count(1, "TASKS")?, 1, 1, 0);
    config.method = MethodId::NtpDetector;
    config.optim.shards = 2;
    for option in &args[4..] {
        match option.split_once('=') {
            Some(("lr", v)) => settings.learning_rate = v.parse().context("lr=")?,
            Some(("batch", v)) => settings.batch_size = v.parse().context("batch=")?,
            Some(("hidden", v)) => settings.hidden = v.parse().context("hidden=")?,
            Some(("validation", v)) => {
                settings.validation_tasks = v.parse().context("validation=")?
            }
            Some(("shards", v)) => config.optim.shards = v.parse().context("shards=")?,
            None if option == "no-keypoints" => settings.keypoints = false,
            _ => bail!("unknown option {option:?}; {USAGE}"),
        }
    }
    let split = env_blocks::standard_split()?;
    let run = RunDir::create(&out)?;
    let device = ntg_model::cpu_device().autodiff();
    let tasks = split.train(config.train_tasks)?;
    blocks::train_ntp_detector(&run, &config, &settings, tasks, &device)?;
    let path = out
        .join(ntg_trainer::method::detector::DETECTOR_STAGE_DIR)
        .join("held_out.json");
    let held_out: DetectorHeldOut = RunDir::read_json(&path)?;
    println!(
        "held out: {} frames: position error {:.4} (answering the training frames' mean state: {:.4}), gripper {:.3}; in {}",
        held_out.detector.frames,
        held_out.detector.position_error,
        held_out.mean_state_position_error,
        held_out.detector.gripper_accuracy,
        path.display()
    );
    Ok(())
}
