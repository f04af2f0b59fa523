//! Training the detector of the NTP (Detector) baseline
//! ([`ntg_model::Detector`]): frames rendered along the expert's
//! primitive-level block-stacking episodes, each labelled with the
//! simulator's state row (each cube relative to the gripper, the gripper's
//! state): the one method of the figure that gets position labels.
//!
//! The NTP (Detector) method itself is [`crate::method::ntp_detector`];
//! what is here is the detector's data, its [`TrainStep`] for
//! [`crate::fit::fit`], its training stage ([`train_detector`]) and its
//! position error on held-out frames.

use anyhow::Context;
use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use env_blocks::{BlocksTask, EnvConfig, StackTask};
use ntg_model::{Detector, DetectorConfig, EdgeCounts, EncoderConfig, FrameEncoderConfig};
use serde::{Deserialize, Serialize};

use crate::evaluate::in_parallel;
use crate::fit::{
    OptimConfig, Selection, StepContext, StepReport, TrainStep, ValidationScore, finished_model,
    fit,
};
use crate::run_dir::RunDir;

/// Folder of the detector's training stage inside a run folder.
pub const DETECTOR_STAGE_DIR: &str = "detector_stage";

/// What the detector stage's validation score holds: the negated mean
/// position error (higher is better) and the gripper's accuracy.
pub const DETECTOR_SCORES: crate::fit::ScoreNames = ["negated position error", "gripper accuracy"];

/// How the NTP (Detector) baseline's detector is trained (a run
/// configuration's `detector`). The defaults were chosen on validation
/// frames (`examples/detector_heldout.rs`, `docs/results/ntp-2026-11-25.md`):
/// positions scaled by their training spread, a 256-wide head, 1e-3 along a
/// cosine; spatial-softmax keypoints (held-out error 0.060 against 0.121
/// without, 20k frames, 6 epochs), 15 epochs (0.050 against 0.060 at 6);
/// more frames kept lowering the held-out error (0.121 at 20k frames, 0.090
/// at 40k, without keypoints), hence about 2000 episodes (40k frames). NTP
/// trains on the detector's estimates (validation success 5/100, goals met
/// 0.283, against 0/100, 0.076 trained on true states, 1000 tasks x 10
/// demos).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectorSettings {
    /// Primitive-level expert episodes rendered for the detector's frames,
    /// spread over the training tasks (see
    /// [`DetectorDataset::record_spread`]: a task's `j`-th is its `j`-th
    /// training demo).
    pub episodes: usize,
    /// Passes over the frames.
    pub epochs: usize,
    /// Frames per optimiser step.
    pub batch_size: usize,
    /// Adam's learning rate, decayed along a cosine to a tenth.
    pub learning_rate: f64,
    /// Width of the head's hidden layer.
    pub hidden: usize,
    /// Validation tasks: one episode of each of the first this many selects
    /// the epoch; one of each of the next as many scores the selected
    /// detector (`held_out.json` in the stage's folder). 0: keep the last
    /// epoch, score nothing.
    pub validation_tasks: usize,
    /// The frame encoder reads positions through spatial-softmax keypoints
    /// (see `ntg_model::FrameEncoderConfig::spatial_softmax`). Absent in
    /// runs saved before it: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub keypoints: bool,
    /// NTP behind the detector trains on the detector's estimates of its
    /// training episodes' frames (the rows it is fed when it acts) instead
    /// of the simulator's true states. It does not change the detector's
    /// own stage. Default: on; absent in runs saved before it: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub ntp_on_estimates: bool,
    /// The camera the detector's frames (training and acting) are rendered
    /// with; a run of NTP (Detector) keeps no video settings, so a video
    /// panel's camera is carried here (`Recipe::for_method`). Absent: the
    /// standard 64×64 camera.
    #[serde(default, skip_serializing_if = "is_standard_camera")]
    pub camera: env_blocks::Camera,
    /// A stride-2 stem of this many channels in front of the detector's
    /// frame encoder (`ntg_model::FrameEncoderConfig::stem`), carried
    /// with the camera from a video panel's `video.encoder.stem`. Absent:
    /// none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stem: Option<usize>,
}

fn is_standard_camera(c: &env_blocks::Camera) -> bool {
    *c == env_blocks::Camera::default()
}

impl Default for DetectorSettings {
    fn default() -> Self {
        DetectorSettings {
            episodes: 2000,
            epochs: 15,
            batch_size: 32,
            learning_rate: 1e-3,
            hidden: 256,
            validation_tasks: 50,
            keypoints: true,
            ntp_on_estimates: true,
            camera: env_blocks::Camera::default(),
            stem: None,
        }
    }
}

impl DetectorSettings {
    /// Checks the counts and the learning rate.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.episodes > 0 && self.epochs > 0 && self.batch_size > 0 && self.hidden > 0,
            "detector: episodes, epochs, batch_size and hidden must be positive ({self:?})"
        );
        anyhow::ensure!(
            self.learning_rate.is_finite() && self.learning_rate > 0.0,
            "detector: the learning rate must be finite and positive, got {}",
            self.learning_rate
        );
        Ok(())
    }

    /// The detector these settings train on frames of
    /// `image_size`×`image_size` pixels, its positions scaled by `scale`
    /// (the training positions' spread), weights from `seed`.
    pub fn net_config(&self, scale: f32, image_size: usize, seed: u64) -> DetectorConfig {
        DetectorConfig::new(
            env_blocks::world::NUM_OBJECTS,
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(image_size)
                    .with_he_init(Some(true))
                    .with_centre_input(Some(true))
                    .with_spatial_softmax(self.keypoints.then_some(true))
                    .with_stem(self.stem),
            ),
        )
        .with_hidden(self.hidden)
        .with_position_scale(Some(scale))
        .with_seed(seed)
    }

    /// The optimiser settings of the stage.
    pub fn optim(&self, seed: u64, shards: usize) -> OptimConfig {
        OptimConfig::stage(
            self.epochs,
            self.batch_size,
            self.learning_rate,
            seed,
            shards,
        )
    }
}

/// What the detector's stage folder's `config.json` holds: a folder
/// trained with other settings is refused, never overwritten.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct DetectorStageConfig {
    settings: DetectorSettings,
    train_tasks: usize,
    failures: bool,
    seed: u64,
    shards: usize,
}

/// Frames a detector stage reads: training frames, validation frames that
/// select the epoch, other validation frames that score it.
pub struct DetectorFrames {
    /// Training frames.
    pub train: DetectorDataset,
    /// Frames that select the epoch (may be empty).
    pub select: DetectorDataset,
    /// Frames that score the selected detector (may be empty).
    pub report: DetectorDataset,
}

/// The selected detector's score on frames never used to train or select
/// it (`held_out.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectorHeldOut {
    /// The detector's score.
    pub detector: DetectorScore,
    /// Position error of always answering the training frames' mean state.
    pub mean_state_position_error: f64,
}

/// Trains (or resumes, or reloads) the detector stage of the run `run`
/// (folder [`DETECTOR_STAGE_DIR`]) on the frames `frames` records: the
/// epoch whose position error on `select` is lowest is kept, then scored
/// on `report` into `held_out.json`. A finished (and scored) stage is read
/// back without recording any frame. `train_tasks` and `failures` are
/// recorded in the stage's configuration.
#[allow(clippy::too_many_arguments)]
pub fn train_detector(
    run: &RunDir,
    frames: impl FnOnce() -> anyhow::Result<DetectorFrames>,
    settings: &DetectorSettings,
    train_tasks: usize,
    failures: bool,
    seed: u64,
    shards: usize,
    device: &Device,
) -> anyhow::Result<Detector> {
    settings.validate()?;
    let stage = DetectorStageConfig {
        // What NTP trains on does not change the detector: a detector
        // stage is the same either way.
        settings: DetectorSettings {
            ntp_on_estimates: false,
            ..settings.clone()
        },
        train_tasks,
        failures,
        seed,
        shards,
    };
    let dir = RunDir::open_or_create(&run.root().join(DETECTOR_STAGE_DIR), &stage)?;
    // A finished stage (a resumed NTP run) needs none of its frames.
    let selecting = settings.validation_tasks > 0;
    let scored = !selecting || dir.root().join("held_out.json").is_file();
    if scored
        && let Some(net) = finished_model::<Detector>(&dir, settings.epochs, selecting, device)?
    {
        eprintln!("detector: done; read from {}", dir.root().display());
        return Ok(net);
    }
    let frames = frames()?;
    let plain = device.clone().inner();
    let side = crate::video::frame_side(frames.train.frame_dim())?;
    let net = settings
        .net_config(frames.train.position_std(), side, seed)
        .init(device)?;
    let step = DetectorStep {
        dataset: &frames.train,
        device: device.clone(),
    };
    eprintln!(
        "detector: {} frames of {} training tasks, {} epochs",
        frames.train.len(),
        train_tasks,
        settings.epochs
    );
    let mut validator = |net: &Detector| -> anyhow::Result<ValidationScore> {
        let score = frames.select.score(&net.valid(), &plain)?;
        eprintln!(
            "  detector held out ({} frames): position error {:.4} | gripper {:.3}",
            score.frames, score.position_error, score.gripper_accuracy
        );
        // Selection keeps the highest score: the negated error, then the
        // gripper's accuracy.
        Ok(ValidationScore {
            success: -score.position_error,
            goal_fraction: score.gripper_accuracy,
        })
    };
    let selection = (!frames.select.is_empty()).then_some(Selection {
        validator: &mut validator as &mut dyn crate::fit::Validator<Detector>,
        every: 1,
        scores: DETECTOR_SCORES,
    });
    let net = fit(
        net,
        &step,
        &settings.optim(seed, shards),
        &dir,
        device,
        selection,
        |m: &DetectorEpochMetrics| {
            eprintln!(
                "  detector epoch {}: loss {:.4} | position error {:.4} | gripper {:.3} | {:.1}s",
                m.epoch, m.loss, m.position_error, m.gripper_accuracy, m.seconds
            )
        },
    )?;
    if !frames.report.is_empty() {
        let held_out = DetectorHeldOut {
            detector: frames.report.score(&net.valid(), &plain)?,
            mean_state_position_error: frames.report.mean_state_error(&frames.train),
        };
        eprintln!(
            "detector on {} other held-out frames: position error {:.4} (the training frames' mean state: {:.4}), gripper {:.3}",
            held_out.detector.frames,
            held_out.detector.position_error,
            held_out.mean_state_position_error,
            held_out.detector.gripper_accuracy
        );
        RunDir::write_json(&dir.root().join("held_out.json"), &held_out)?;
    }
    Ok(net)
}

/// Frames (CHW bytes) and the state rows they show.
#[derive(Debug, Clone, Default)]
pub struct DetectorDataset {
    frames: Vec<Vec<u8>>,
    rows: Vec<Vec<f32>>,
}

impl DetectorDataset {
    /// Every observation of `demos_per_task` expert episodes of each of
    /// `tasks` at the primitive level, rendered (episode `j` of task `t`
    /// with seed `seed_base + 1000 t + j`, as the training demos), in
    /// parallel. `env` must render frames.
    pub fn record(
        tasks: &[StackTask],
        demos_per_task: usize,
        seed_base: u64,
        env: EnvConfig,
    ) -> anyhow::Result<Self> {
        let pairs: Vec<(usize, u64)> = (0..tasks.len())
            .flat_map(|t| {
                (0..demos_per_task).map(move |j| (t, seed_base + 1000 * t as u64 + j as u64))
            })
            .collect();
        Self::record_pairs(tasks, &pairs, env)
    }

    /// `episodes` episodes spread over `tasks`: episode `i` is the
    /// `(i div N)`-th of task `i mod N` (seeded as in [`Self::record`]), so
    /// the first `N` are each task's first demo.
    pub fn record_spread(
        tasks: &[StackTask],
        episodes: usize,
        seed_base: u64,
        env: EnvConfig,
    ) -> anyhow::Result<Self> {
        let n = tasks.len().max(1);
        let pairs: Vec<(usize, u64)> = (0..episodes)
            .map(|i| (i % n, seed_base + 1000 * (i % n) as u64 + (i / n) as u64))
            .collect();
        Self::record_pairs(tasks, &pairs, env)
    }

    /// The episodes `(task index, seed)`, in parallel.
    fn record_pairs(
        tasks: &[StackTask],
        pairs: &[(usize, u64)],
        env: EnvConfig,
    ) -> anyhow::Result<Self> {
        let episodes = in_parallel(pairs, "detector frames", |_, &(t, seed)| {
            let task = BlocksTask::Stack(tasks[t].clone());
            let demo = env_blocks::record_ntp_demo(&task, env, seed)
                .with_context(|| format!("demo of task {} (seed {seed})", tasks[t].id))?;
            demo.observations
                .iter()
                .map(|o| {
                    let frame = o.frame().with_context(|| {
                        format!(
                            "demo of task {} (seed {seed}) has no frames: the environment must render",
                            tasks[t].id
                        )
                    })?;
                    Ok((chw_bytes(frame), o.state().to_vec()))
                })
                .collect::<anyhow::Result<Vec<_>>>()
        })?;
        let (frames, rows) = episodes.into_iter().flatten().unzip();
        Ok(DetectorDataset { frames, rows })
    }

    /// Values per frame row (0 when there are no frames).
    pub fn frame_dim(&self) -> usize {
        self.frames.first().map_or(0, Vec::len)
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether it holds no frame.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Frames `[N, 3·H·W]` (values in `[0, 1]`) and state rows of the
    /// examples `indices`.
    pub fn tensors(&self, indices: &[usize], device: &Device) -> (Tensor<2>, Tensor<2>) {
        let n = indices.len();
        let frame_dim = self.frames.first().map_or(0, Vec::len);
        let row_dim = self.rows.first().map_or(0, Vec::len);
        let frames: Vec<f32> = indices
            .iter()
            .flat_map(|&i| self.frames[i].iter().map(|&b| f32::from(b) / 255.0))
            .collect();
        let rows: Vec<f32> = indices
            .iter()
            .flat_map(|&i| self.rows[i].iter().copied())
            .collect();
        (
            Tensor::from_data(TensorData::new(frames, [n, frame_dim]), device),
            Tensor::from_data(TensorData::new(rows, [n, row_dim]), device),
        )
    }

    /// Standard deviation of the position values of the rows (every cube
    /// and coordinate pooled): the detector's position scale.
    pub fn position_std(&self) -> f32 {
        let objects = self
            .rows
            .first()
            .map_or(0, |r| r.len().saturating_sub(2) / 3);
        let values: Vec<f64> = self
            .rows
            .iter()
            .flat_map(|r| r[..3 * objects].iter().map(|&v| f64::from(v)))
            .collect();
        let n = values.len().max(1) as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        var.sqrt() as f32
    }

    /// Mean position error over this set's frames of always answering
    /// `train`'s mean state (what a detector must beat).
    pub fn mean_state_error(&self, train: &DetectorDataset) -> f64 {
        let Some(width) = train.rows.first().map(Vec::len) else {
            return f64::NAN;
        };
        let mut mean = vec![0.0f64; width];
        for row in &train.rows {
            for (m, &v) in mean.iter_mut().zip(row) {
                *m += f64::from(v) / train.len() as f64;
            }
        }
        let objects = width.saturating_sub(2) / 3;
        let mut total = 0.0;
        for row in &self.rows {
            for k in 0..objects {
                let d: f64 = (0..3)
                    .map(|c| (f64::from(row[3 * k + c]) - mean[3 * k + c]).powi(2))
                    .sum();
                total += d.sqrt() / objects as f64;
            }
        }
        total / self.len().max(1) as f64
    }

    /// Mean position error and gripper accuracy of `model` over every frame
    /// (in batches of 256).
    pub fn score(&self, model: &Detector, device: &Device) -> anyhow::Result<DetectorScore> {
        let all: Vec<usize> = (0..self.len()).collect();
        let (mut error, mut gripper) = (0.0f64, 0.0f64);
        for chunk in all.chunks(256) {
            let (frames, rows) = self.tensors(chunk, device);
            let out = model.loss(frames, rows)?;
            error += f64::from(out.position_error) * chunk.len() as f64;
            gripper += f64::from(out.gripper_accuracy) * chunk.len() as f64;
        }
        let n = self.len().max(1) as f64;
        Ok(DetectorScore {
            frames: self.len(),
            position_error: error / n,
            gripper_accuracy: gripper / n,
        })
    }
}

/// A frame as CHW bytes (the layout of `env_collect::frame_to_chw`).
fn chw_bytes(frame: &image::RgbImage) -> Vec<u8> {
    let plane = (frame.width() * frame.height()) as usize;
    let mut out = vec![0; 3 * plane];
    for (i, px) in frame.pixels().enumerate() {
        for (c, &v) in px.0.iter().enumerate() {
            out[c * plane + i] = v;
        }
    }
    out
}

/// A detector's score on a set of frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectorScore {
    /// Frames scored.
    pub frames: usize,
    /// Mean Euclidean distance between estimated and true cube positions.
    pub position_error: f64,
    /// Fraction of frames whose gripper state is right.
    pub gripper_accuracy: f64,
}

/// The detector's training step: squared position error plus the
/// gripper's cross-entropy on a batch of frames.
pub struct DetectorStep<'a> {
    /// The frames.
    pub dataset: &'a DetectorDataset,
    /// The training device.
    pub device: Device,
}

/// One line of a detector run's `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectorEpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean loss.
    pub loss: f32,
    /// Mean position error on the training batches.
    pub position_error: f32,
    /// Gripper states right on the training batches.
    pub gripper_accuracy: f32,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
}

impl TrainStep<Detector> for DetectorStep<'_> {
    type Metrics = DetectorEpochMetrics;

    fn num_examples(&self) -> usize {
        self.dataset.len()
    }

    fn step(
        &self,
        model: &Detector,
        batch: &[usize],
        _: StepContext<'_>,
    ) -> anyhow::Result<StepReport> {
        let (frames, rows) = self.dataset.tensors(batch, &self.device);
        let out = model.loss(frames, rows)?;
        StepReport::scored(out.loss, &[out.position_error, out.gripper_accuracy])
    }

    fn epoch_metrics(
        &self,
        epoch: usize,
        means: &[f32],
        _: &EdgeCounts,
        seconds: f32,
    ) -> DetectorEpochMetrics {
        let at = |i: usize| means.get(i).copied().unwrap_or(f32::NAN);
        DetectorEpochMetrics {
            epoch,
            loss: at(0),
            position_error: at(1),
            gripper_accuracy: at(2),
            seconds,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{OptimConfig, fit};
    use crate::run_dir::RunDir;
    use ntg_model::{DetectorConfig, EncoderConfig, FrameEncoderConfig};

    /// Frames and rows line up with the episodes, a short fit lowers the
    /// training loss, and the held-out score is a finite error over every
    /// held-out frame.
    #[test]
    fn the_detector_trains_on_rendered_frames_and_is_scored_on_others() {
        let split = env_blocks::standard_split().unwrap();
        let tasks = split.train(2).unwrap();
        let env = EnvConfig::default();
        let train = DetectorDataset::record(tasks, 2, 0, env).unwrap();
        let held_out = DetectorDataset::record(tasks, 1, 777, env).unwrap();
        assert!(train.len() >= 4 * 8, "{} frames", train.len());
        assert_eq!(train.frames[0].len(), 3 * 64 * 64);
        assert_eq!(train.rows[0].len(), env_blocks::STATE_DIM);
        let device = ntg_model::cpu_device().autodiff();
        let config = DetectorConfig::new(
            env_blocks::world::NUM_OBJECTS,
            EncoderConfig::Frame(FrameEncoderConfig::new().with_conv_channels([8, 16, 16])),
        )
        .with_hidden(32);
        let net = config.init(&device).unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(&tmp.path().join("detector")).unwrap();
        let step = DetectorStep {
            dataset: &train,
            device: device.clone(),
        };
        let optim = OptimConfig {
            epochs: 4,
            batch_size: 16,
            learning_rate: 3e-3,
            seed: 0,
            token_dropout: 0.0,
            gcn_from_other_demo: false,
            cosine_decay: false,
            shards: 2,
        };
        let mut losses = Vec::new();
        let net = fit(
            net,
            &step,
            &optim,
            &run,
            &device,
            None,
            |m: &DetectorEpochMetrics| losses.push(m.loss),
        )
        .unwrap();
        assert!(losses[3] < losses[0], "losses {losses:?}");
        let score = held_out.score(&net, &ntg_model::cpu_device()).unwrap();
        assert_eq!(score.frames, held_out.len());
        assert!(score.position_error.is_finite() && score.position_error > 0.0);
        let mean = held_out.mean_state_error(&train);
        assert!(mean.is_finite() && mean > 0.0, "{mean}");
        let std = train.position_std();
        assert!(std.is_finite() && std > 0.0, "{std}");
        // Saved by fit, it loads.
        assert!(Detector::load(run.checkpoint_dir(), &ntg_model::cpu_device()).is_ok());
    }
}
