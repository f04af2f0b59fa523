//! NTG from demonstration videos, trained in stages on CPU cores.
//!
//! A demo video has several frames per flat action (a
//! `ctg_graph::VideoDemonstration`, recorded by the domain). Training all
//! four networks end to end on frames runs the CNN over every frame of a
//! batch in every step, seconds per step on two cores. The paper's
//! networks share one encoder `Enc(o)`, so training is staged instead,
//! with the paper's supervision (frames and flat action labels, nothing
//! else):
//!
//! - **Stage A** ([`FrameStageStep`]): the encoder, trained with the
//!   localizer's and the edge classifier's losses on single frames sampled
//!   across demos (`ntg_model::FrameStageNet`), in large batches. Run
//!   folder: `stage_a/` (its own checkpoint, metrics and resume). Each
//!   epoch is scored on the frames of validation-task videos (localizer,
//!   then edge accuracy, in `stage_a/validation.jsonl`) and the best epoch
//!   is kept.
//! - **Stage B**: the encoder is frozen and every training demo's frames
//!   are encoded once into an embedding cache (`embeddings/`, a dataset of
//!   video demos whose rows are `Enc(o)`; frames are re-rendered from
//!   their seeds, never stored; saved in parts as the encoding goes, so a
//!   killed one resumes: [`embeddings`]). The demo interpreter (every
//!   frame of the video), the GCN, the localizer and the edge classifier (the keyframes:
//!   the scene after each action, what the policy sees when it acts) are
//!   an `NtgModel` over embedding rows, trained by NTG's own step through
//!   [`crate::fit::fit`] at the state path's speed ([`OnFramesStep`]); the
//!   Flat Policy trains on the same embeddings with its own step.
//!
//! The result is an [`OnFrames`] model ([`VideoNtgModel`] for NTG): at run
//! time each frame is encoded once and its embedding read by all the
//! networks.

use anyhow::Context;
use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg, VideoDemonstration, Vocabulary};
use ntg_model::{EdgeCounts, FrameStageConfig, FrameStageNet, ids_tensor, successor_mask};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dataset::{DemoDataset, ObsDtype, progress_bar};
use crate::fit::{
    OptimConfig, Selection, StepContext, StepReport, TrainStep, ValidationScore, finished_model,
    fit, scalar,
};
use crate::method::ntg::{next_is_retry, task_graphs};
pub use crate::method::on_frames::{OnFrames, OnFramesStep, VideoNtgModel, encode_rows};
use crate::run_dir::RunDir;

/// Folder of the stage A run inside a video run's folder.
pub const STAGE_A_DIR: &str = "stage_a";

/// What stage A's validation score holds (its frames of validation
/// videos, not rollouts): the localizer's and the edge classifier's
/// accuracy.
pub const STAGE_A_SCORES: crate::fit::ScoreNames = ["localizer accuracy", "edge accuracy"];
/// Folder of the embedding cache inside a video run's folder.
pub const EMBEDDINGS_DIR: &str = "embeddings";

/// Settings of stage A (saved in the run configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncoderStage {
    /// Training demos whose frames train the encoder (demo 0 of every
    /// task first, then demo 1, ...), at most all of them.
    pub demos: usize,
    /// Passes over those frames.
    pub epochs: usize,
    /// Frames per step.
    pub batch_size: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Kernel side of the encoder's convolutions (3 or 4).
    pub kernel: usize,
    /// Fraction of each demo's frames stage A trains on, besides its
    /// keyframes (always kept): a seeded draw per frame. Below 1, the same
    /// number of frames comes from more demos. Absent in runs saved before
    /// it: 1 (every frame).
    #[serde(default = "one")]
    pub frame_fraction: f64,
    /// Width of the encoder's hidden layer between its feature map and the
    /// embedding (0: none; absent in runs saved before it: 0).
    #[serde(default)]
    pub hidden: usize,
    /// He initialisation of the encoder's convolutions (absent in runs
    /// saved before it: false, PyTorch's default).
    #[serde(default)]
    pub he_init: bool,
    /// Centre the frames' values on 0 (absent in runs saved before it:
    /// false).
    #[serde(default)]
    pub centre_input: bool,
    /// Weight of a frame-reconstruction loss (a decoder rebuilds each frame
    /// at half resolution from its embedding, so that the embedding keeps
    /// the scene and not only what tells actions apart; see
    /// `ntg_model::FrameStageConfig::reconstruction`). 0: none (absent in
    /// runs saved before it: 0).
    #[serde(default)]
    pub reconstruction: f32,
    /// Add x/y coordinate channels to the frames (see
    /// `ntg_model::FrameEncoderConfig::coord_channels`; absent in runs
    /// saved before it: false).
    #[serde(default)]
    pub coord_channels: bool,
    /// Read the encoder's last feature map through spatial-softmax
    /// keypoints (see `ntg_model::FrameEncoderConfig::spatial_softmax`;
    /// absent in runs saved before it: false).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub spatial_softmax: bool,
    /// Data-parallel shards of each stage-A step (see
    /// [`OptimConfig::shards`]; absent in runs saved before it, and 0 or
    /// 1: one thread).
    #[serde(default, skip_serializing_if = "crate::fit::is_one_shard")]
    pub shards: usize,
    /// Times each epoch shows a *retry keyframe*: the scene after an action
    /// whose next action repeats an earlier one (a pick after a slipped
    /// grasp or a missed drop). Retries are a few percent of the
    /// keyframes, and the edge head's loss barely weighs the scene that
    /// calls for one. Absent in runs saved before it: 1.
    #[serde(default = "one_repeat", skip_serializing_if = "is_one_repeat")]
    pub retry_repeats: usize,
    /// Weight of the progress loss (a head reads from each frame's
    /// embedding which of its demo's actions have taken effect; see
    /// `ntg_model::FrameStageConfig::progress`). 0: none (absent in runs
    /// saved before it: 0).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub progress: f32,
    /// Output channels of a stem convolution before the encoder's three
    /// (see `ntg_model::FrameEncoderConfig::stem`): for frames larger than
    /// 64×64. 0: none (absent in runs saved before it: 0).
    #[serde(default, skip_serializing_if = "is_zero_usize")]
    pub stem: usize,
}

fn is_zero_usize(n: &usize) -> bool {
    *n == 0
}

/// The side `S` of square RGB frames whose rows hold `frame_dim = 3·S²`
/// values, or an error naming the row length.
pub fn frame_side(frame_dim: usize) -> anyhow::Result<usize> {
    let side = ((frame_dim / 3) as f64).sqrt().round() as usize;
    anyhow::ensure!(
        side > 0 && 3 * side * side == frame_dim,
        "a frame row of {frame_dim} values is not a square RGB frame (3·S² values)"
    );
    Ok(side)
}

fn is_zero(w: &f32) -> bool {
    *w == 0.0
}

fn one() -> f64 {
    1.0
}

fn one_repeat() -> usize {
    1
}

fn is_one_repeat(r: &usize) -> bool {
    *r == 1
}

impl Default for EncoderStage {
    fn default() -> Self {
        EncoderStage {
            demos: 1000,
            epochs: 4,
            batch_size: 64,
            learning_rate: 1e-3,
            kernel: 3,
            frame_fraction: 1.0,
            hidden: 0,
            he_init: false,
            centre_input: false,
            reconstruction: 0.0,
            coord_channels: false,
            spatial_softmax: false,
            shards: 0,
            retry_repeats: 1,
            progress: 0.0,
            stem: 0,
        }
    }
}

impl EncoderStage {
    /// The stage's network configuration for `num_nodes` CTG nodes and
    /// frames of `image_size`×`image_size` pixels.
    pub fn net_config(&self, num_nodes: usize, image_size: usize, seed: u64) -> FrameStageConfig {
        FrameStageConfig::new(
            num_nodes,
            ntg_model::EncoderConfig::Frame(
                ntg_model::FrameEncoderConfig::new()
                    .with_image_size(image_size)
                    .with_stem((self.stem > 0).then_some(self.stem))
                    .with_kernel(self.kernel)
                    .with_hidden((self.hidden > 0).then_some(self.hidden))
                    .with_he_init(self.he_init.then_some(true))
                    .with_centre_input(self.centre_input.then_some(true))
                    .with_coord_channels(self.coord_channels.then_some(true))
                    .with_spatial_softmax(self.spatial_softmax.then_some(true)),
            ),
        )
        .with_seed(seed)
        .with_reconstruction((self.reconstruction > 0.0).then_some(self.reconstruction))
        .with_progress((self.progress > 0.0).then_some(self.progress))
    }

    /// Stage A's optimiser settings, shuffling seeded by `seed`: the
    /// stage's epochs, batch size and rate, decaying along a half cosine.
    pub fn optim(&self, seed: u64) -> OptimConfig {
        OptimConfig::stage(
            self.epochs,
            self.batch_size,
            self.learning_rate,
            seed,
            self.shards,
        )
    }

    /// Size of the embeddings stage B trains on.
    pub fn embedding_dim(&self) -> usize {
        ntg_model::FrameEncoderConfig::new().out_dim
    }
}

/// Records one training demo video, its frames featurised (CHW in
/// `[0, 1]`): `(task index, seed)` → video.
pub type VideoRecorder<'a> =
    &'a (dyn Fn(usize, u64) -> anyhow::Result<VideoDemonstration<Vec<f32>>> + Sync);

/// Metrics of one stage A epoch (`stage_a/metrics.jsonl`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncoderEpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean total loss.
    pub loss: f32,
    /// Localizer cross-entropy (frame → the action it belongs to).
    pub localizer_loss: f32,
    /// Localizer accuracy.
    pub localizer_accuracy: f32,
    /// Edge cross-entropy (frame + node → next action).
    pub edge_loss: f32,
    /// Edge accuracy.
    pub edge_accuracy: f32,
    /// Mean squared error of the rebuilt frames (with a reconstruction
    /// weight).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reconstruction: Option<f32>,
    /// Fraction of frames whose progress (the actions taken effect) the
    /// progress head gets all right (with a progress weight).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub progress_accuracy: Option<f32>,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
}

/// Per-frame accuracy of a stage A network on a set of videos.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameAccuracy {
    /// Fraction of frames whose action the localizer names.
    pub localizer: f64,
    /// Fraction of frames whose next action the edge head names.
    pub edge: f64,
    /// The localizer's accuracy on the keyframes alone (the scene after
    /// each action: what the policy localizes at run time).
    pub keyframe_localizer: f64,
    /// The edge head's accuracy on the retry keyframes (see
    /// [`EncoderStage::retry_repeats`]); `None` without any.
    #[serde(default)]
    pub retry_edge: Option<f64>,
    /// Fraction of keyframes whose progress the progress head gets all
    /// right (`None` without a head).
    #[serde(default)]
    pub keyframe_progress: Option<f64>,
}

/// Stage A's [`TrainStep`]: the examples are single frames of a dataset of
/// video demos.
pub struct FrameStageStep<'a> {
    dataset: &'a DemoDataset,
    /// Per frame: (row, its label, the next action, its demo's task, the
    /// actions taken effect by the frame as a bit set over the nodes).
    frames: Vec<(usize, ActionId, ActionId, usize, u64)>,
    /// Indices into `frames` of the keyframes (what the policy acts on).
    keyframes: Vec<usize>,
    /// Indices into `frames` of the retry keyframes (the next action
    /// repeats an earlier one).
    retries: Vec<usize>,
    /// How many of `frames` are the dataset's own (the rest repeat retry
    /// keyframes, [`FrameStageStep::with_retry_repeats`]).
    own_frames: usize,
    graphs: std::collections::BTreeMap<usize, Ctg>,
    device: Device,
}

impl<'a> FrameStageStep<'a> {
    /// The step over every frame of `dataset` (video demos).
    pub fn new(dataset: &'a DemoDataset, device: &Device) -> anyhow::Result<Self> {
        let (mut frames, mut keyframes, mut retries) = (Vec::new(), Vec::new(), Vec::new());
        for d in dataset.demos() {
            let ends = d
                .segment_ends
                .as_ref()
                .context("stage A trains on video demos")?;
            let nodes: Vec<ActionId> = std::iter::once(Vocabulary::START)
                .chain(d.actions.iter().copied())
                .collect();
            let next: Vec<ActionId> = d.actions.iter().copied().chain([Vocabulary::END]).collect();
            let done = progress_bits(&d.actions);
            let mut start = 0;
            for (s, &end) in ends.iter().enumerate() {
                for k in start..end {
                    // Segment s shows action s - 1 under way; its last
                    // frame, the keyframe, the scene after it.
                    let key = k + 1 == end;
                    if key {
                        keyframes.push(frames.len());
                        if next_is_retry(&d.actions, s) {
                            retries.push(frames.len());
                        }
                    }
                    let done = done[if key { s } else { s.saturating_sub(1) }];
                    frames.push((d.first_row + k, nodes[s], next[s], d.task, done));
                }
                start = end;
            }
        }
        Ok(FrameStageStep {
            dataset,
            own_frames: frames.len(),
            frames,
            keyframes,
            retries,
            graphs: task_graphs(dataset)?,
            device: device.clone(),
        })
    }

    /// The same step over the frames of the dataset's first `demos` demos
    /// only (all of them when it has fewer).
    pub fn first_demos(mut self, demos: usize) -> Self {
        let end = self
            .dataset
            .demos()
            .get(demos)
            .map_or(usize::MAX, |d| d.first_row);
        let own = self.frames[..self.own_frames]
            .iter()
            .take_while(|f| f.0 < end)
            .count();
        let repeated = self.frames.split_off(self.own_frames);
        self.frames.truncate(own);
        self.frames
            .extend(repeated.into_iter().filter(|f| f.0 < end));
        self.own_frames = own;
        self.keyframes.retain(|&k| k < own);
        self.retries.retain(|&k| k < own);
        self
    }

    /// The same step with each retry keyframe shown `repeats` times per
    /// epoch (see [`EncoderStage::retry_repeats`]; 0 and 1: once).
    pub fn with_retry_repeats(mut self, repeats: usize) -> Self {
        for _ in 1..repeats {
            for &k in &self.retries {
                self.frames.push(self.frames[k]);
            }
        }
        self
    }

    /// The stage's losses on the frames `batch` (indices into the frames).
    fn batch_loss(
        &self,
        model: &FrameStageNet,
        batch: &[usize],
    ) -> anyhow::Result<ntg_model::FrameStageLoss> {
        let n = model.config().num_nodes;
        let dim = self.dataset.obs_dim();
        let mut rows = Vec::with_capacity(batch.len() * dim);
        let (mut labels, mut next, mut graphs) = (Vec::new(), Vec::new(), Vec::new());
        let mut done = Vec::new();
        let with_progress = model.progress.is_some();
        if with_progress && n > 64 {
            anyhow::bail!("stage A's progress loss handles at most 64 nodes, not {n}");
        }
        for &i in batch {
            let (row, label, nx, task, bits) = self.frames[i];
            self.dataset.extend_row(row, &mut rows);
            labels.push(label);
            next.push(nx);
            graphs.push(&self.graphs[&task]);
            if with_progress {
                done.extend((0..n).map(|a| ((bits >> a) & 1) as f32));
            }
        }
        let frames =
            Tensor::<2>::from_data(TensorData::new(rows, [batch.len(), dim]), &self.device);
        let mask = successor_mask(&graphs, &labels, Some(&next), n, &self.device)?;
        let done = with_progress
            .then(|| Tensor::<2>::from_data(TensorData::new(done, [batch.len(), n]), &self.device));
        Ok(model.loss_with_progress(
            frames,
            ids_tensor(&labels, n, &self.device)?,
            ids_tensor(&next, n, &self.device)?,
            mask,
            done,
        )?)
    }

    /// `model`'s localizer and edge accuracy over every frame (no
    /// gradients): on the frames of held-out videos, how well the encoder
    /// generalises.
    pub fn accuracy(&self, model: &FrameStageNet) -> anyhow::Result<FrameAccuracy> {
        let model = model.valid();
        // Mean localizer, edge and progress accuracy over `frames`.
        let mean = |frames: &[usize]| -> anyhow::Result<[f64; 3]> {
            let mut sums = [0.0f64; 3];
            for batch in frames.chunks(256) {
                let out = self.batch_loss(&model, batch)?;
                let progress = out.progress.map_or(0.0, |p| p.accuracy);
                for (sum, a) in
                    sums.iter_mut()
                        .zip([out.localizer.accuracy, out.edge.accuracy, progress])
                {
                    *sum += f64::from(a) * batch.len() as f64;
                }
            }
            let total = frames.len().max(1) as f64;
            Ok(sums.map(|s| s / total))
        };
        let all: Vec<usize> = (0..self.own_frames).collect();
        let [localizer, edge, _] = mean(&all)?;
        let [keyframe_localizer, _, keyframe_progress] = mean(&self.keyframes)?;
        let retry_edge = if self.retries.is_empty() {
            None
        } else {
            Some(mean(&self.retries)?[1])
        };
        Ok(FrameAccuracy {
            localizer,
            edge,
            keyframe_localizer,
            retry_edge,
            keyframe_progress: model.progress.is_some().then_some(keyframe_progress),
        })
    }
}

impl TrainStep<FrameStageNet> for FrameStageStep<'_> {
    type Metrics = EncoderEpochMetrics;

    fn num_examples(&self) -> usize {
        self.frames.len()
    }

    fn step(
        &self,
        model: &FrameStageNet,
        batch: &[usize],
        _ctx: StepContext<'_>,
    ) -> anyhow::Result<StepReport> {
        let out = self.batch_loss(model, batch)?;
        // NaN marks a loss the network does not have.
        let values = vec![
            scalar(out.loss.clone())?,
            scalar(out.localizer.loss)?,
            out.localizer.accuracy,
            scalar(out.edge.loss)?,
            out.edge.accuracy,
            out.reconstruction
                .map(scalar)
                .transpose()?
                .unwrap_or(f32::NAN),
            out.progress.map_or(f32::NAN, |p| p.accuracy),
        ];
        Ok(StepReport {
            values,
            loss: out.loss,
            edges: EdgeCounts::default(),
        })
    }

    fn epoch_metrics(
        &self,
        epoch: usize,
        m: &[f32],
        _edges: &EdgeCounts,
        seconds: f32,
    ) -> EncoderEpochMetrics {
        EncoderEpochMetrics {
            epoch,
            loss: m[0],
            localizer_loss: m[1],
            localizer_accuracy: m[2],
            edge_loss: m[3],
            edge_accuracy: m[4],
            reconstruction: m.get(5).copied().filter(|r| r.is_finite()),
            progress_accuracy: m.get(6).copied().filter(|p| p.is_finite()),
            seconds,
        }
    }
}

/// The actions of a demo that have taken effect after each of its first
/// `k` actions (`k` = 0..=len), as bit sets over the nodes (ids below 64):
/// an action takes effect unless the next one repeats an earlier action (a
/// retry: the grasp slipped or the drop missed). Built from the flat
/// action labels alone, with hindsight; the bits only accumulate.
pub fn progress_bits(actions: &[ActionId]) -> Vec<u64> {
    let mut done = Vec::with_capacity(actions.len() + 1);
    let mut bits = 0u64;
    done.push(bits);
    for (j, &a) in actions.iter().enumerate() {
        if !next_is_retry(actions, j + 1) && a.index() < 64 {
            bits |= 1 << a.index();
        }
        done.push(bits);
    }
    done
}

/// The `(task, seed)` pairs of `demos_per_task` demos of `tasks` tasks
/// (demo `j` of task `t` with seed `seed_base + 1000 t + j`), ordered demo
/// 0 of every task first, then demo 1, ...: any prefix spreads over tasks.
pub fn spread_pairs(tasks: usize, demos_per_task: usize, seed_base: u64) -> Vec<(usize, u64)> {
    (0..demos_per_task)
        .flat_map(|j| (0..tasks).map(move |t| (t, seed_base + 1000 * t as u64 + j as u64)))
        .collect()
}

/// Records the videos of `pairs` in parallel, in chunks, handing each
/// chunk's videos (in order) to `sink`.
fn record_in_chunks(
    pairs: &[(usize, u64)],
    record: VideoRecorder<'_>,
    what: &str,
    mut sink: impl FnMut(Vec<(usize, u64, VideoDemonstration<Vec<f32>>)>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let bar = progress_bar(pairs.len() as u64, what);
    for chunk in pairs.chunks(64) {
        let videos = chunk
            .par_iter()
            .map(|&(t, seed)| {
                record(t, seed)
                    .with_context(|| format!("demo video of task {t}, seed {seed}"))
                    .map(|v| (t, seed, v))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        sink(videos)?;
        bar.inc(chunk.len() as u64);
    }
    bar.finish_and_clear();
    Ok(())
}

/// Stage A's dataset: the frames (as bytes) of the videos of `pairs`, each
/// video's keyframes and a `fraction` of its other frames (a draw seeded
/// by the video's seed; all of them at 1).
pub fn frame_dataset(
    vocab: &Vocabulary,
    pairs: &[(usize, u64)],
    record: VideoRecorder<'_>,
    frame_dim: usize,
    fraction: f64,
) -> anyhow::Result<DemoDataset> {
    frame_dataset_labelled(vocab, pairs, record, frame_dim, fraction, "videos (A)")
}

/// Videos per part of stage A's frame dataset, built and saved one part at
/// a time (about 4.6 GB of 128×128 frames per part).
pub const STAGE_A_PART_VIDEOS: usize = 5000;

/// [`frame_dataset`], its progress bar labelled `what`.
fn frame_dataset_labelled(
    vocab: &Vocabulary,
    pairs: &[(usize, u64)],
    record: VideoRecorder<'_>,
    frame_dim: usize,
    fraction: f64,
    what: &str,
) -> anyhow::Result<DemoDataset> {
    anyhow::ensure!(
        (0.0..=1.0).contains(&fraction),
        "the fraction of frames stage A trains on must be in [0, 1], got {fraction}"
    );
    let mut dataset = DemoDataset::from_demos(vocab.clone(), frame_dim, ObsDtype::U8, [])?;
    record_in_chunks(pairs, record, what, |videos| {
        for (t, seed, v) in videos {
            let v = if fraction < 1.0 {
                keep_frames(v, fraction, seed, vocab)?
            } else {
                v
            };
            dataset.push_video(t, seed, v)?;
        }
        Ok(())
    })?;
    Ok(dataset)
}

/// `video` with its keyframes (the last frame of each segment) and each
/// other frame with probability `fraction`, drawn from `seed`.
pub fn keep_frames<F>(
    video: VideoDemonstration<F>,
    fraction: f64,
    seed: u64,
    vocab: &Vocabulary,
) -> anyhow::Result<VideoDemonstration<F>> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_F2A3);
    let (frames, ends, actions) = video.into_parts();
    let mut kept = Vec::new();
    let mut kept_ends = Vec::with_capacity(ends.len());
    let mut segment = 0;
    for (i, f) in frames.into_iter().enumerate() {
        let keyframe = i + 1 == ends[segment];
        if keyframe || rng.random_bool(fraction) {
            kept.push(f);
        }
        if keyframe {
            kept_ends.push(kept.len());
            segment += 1;
        }
    }
    Ok(VideoDemonstration::new(kept, kept_ends, actions, vocab)?)
}

/// Stage B's dataset: the videos of `pairs`, every frame encoded once by
/// `net`'s frozen encoder.
pub fn embedding_dataset(
    vocab: &Vocabulary,
    pairs: &[(usize, u64)],
    record: VideoRecorder<'_>,
    net: &FrameStageNet,
) -> anyhow::Result<DemoDataset> {
    encode_videos(vocab, pairs, record, net, "encoding")
}

/// [`embedding_dataset`], its progress bar labelled `what`.
fn encode_videos(
    vocab: &Vocabulary,
    pairs: &[(usize, u64)],
    record: VideoRecorder<'_>,
    net: &FrameStageNet,
    what: &str,
) -> anyhow::Result<DemoDataset> {
    let net = net.valid();
    let mut dataset = DemoDataset::from_videos(vocab.clone(), net.encoder.out_dim(), [])?;
    record_in_chunks(pairs, record, what, |videos| {
        // One video per thread at a time, each in the batches it would have
        // alone: the embeddings do not depend on the number of threads.
        let encoded = videos
            .into_par_iter()
            .map(|(t, seed, v)| {
                let (frames, ends, actions) = v.into_parts();
                let embedded = encode_rows(&net, &frames)?;
                Ok((
                    t,
                    seed,
                    VideoDemonstration::new(embedded, ends, actions, vocab)?,
                ))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        for (t, seed, video) in encoded {
            dataset.push_video(t, seed, video)?;
        }
        Ok(())
    })?;
    Ok(dataset)
}

/// Everything the video stages ([`train_encoder`], [`embeddings`]) need
/// from the domain.
pub struct VideoRun<'a> {
    /// The domain's vocabulary.
    pub vocabulary: &'a Vocabulary,
    /// Every training demo, `(task, seed)`, in [`spread_pairs`] order.
    pub pairs: Vec<(usize, u64)>,
    /// Records a training demo video.
    pub record: VideoRecorder<'a>,
    /// Values per frame row.
    pub frame_dim: usize,
    /// Stage A's settings.
    pub encoder: &'a EncoderStage,
    /// Seed of stage A's weights and shuffling.
    pub seed: u64,
    /// Held-out videos that score stage A's epochs (the best is kept).
    pub validation: Option<ValidationVideos<'a>>,
}

/// Videos of validation tasks, never trained on: stage A is scored by its
/// localizer's and edge head's accuracy on their frames.
pub struct ValidationVideos<'a> {
    /// `(task, seed)` of each video (task indices are the recorder's own).
    pub pairs: Vec<(usize, u64)>,
    /// Records a validation video.
    pub record: VideoRecorder<'a>,
}

/// Stage A (resumed if started): trains the shared encoder in
/// `run/stage_a/`, returning the trained network.
pub fn train_encoder(
    run: &RunDir,
    video: &VideoRun<'_>,
    device: &Device,
) -> anyhow::Result<FrameStageNet> {
    let stage = video.encoder;
    let config = StageAConfig {
        stage: stage.clone(),
        seed: video.seed,
    };
    let dir = RunDir::open_or_create(&run.root().join(STAGE_A_DIR), &config)?;
    // A finished stage A (a resumed stage B) needs none of its data.
    let selecting = video
        .validation
        .as_ref()
        .is_some_and(|v| !v.pairs.is_empty());
    if let Some(net) = finished_model::<FrameStageNet>(&dir, stage.epochs, selecting, device)? {
        eprintln!("stage A: done; encoder read from {}", dir.root().display());
        return Ok(net);
    }
    let demos = stage.demos.min(video.pairs.len());
    // Built STAGE_A_PART_VIDEOS videos at a time, each part saved
    // (compressed row by row) and dropped, and read back mapped from disk:
    // at 128×128 the frames of 20,000 videos are 18 GB, which do not fit
    // this project's 24 GB machine in memory (about 0.3 GB on disk). The
    // same frames as built in one go (each video's draw is its own).
    let frames = DemoDataset::load_or_build_mapped_in_parts(
        &dir.dataset_dir(),
        &video.pairs[..demos],
        STAGE_A_PART_VIDEOS,
        |pairs, part| {
            frame_dataset_labelled(
                video.vocabulary,
                pairs,
                video.record,
                video.frame_dim,
                stage.frame_fraction,
                &format!("videos (A){part}"),
            )
        },
    )?;
    let net = stage
        .net_config(
            video.vocabulary.len(),
            frame_side(video.frame_dim)?,
            video.seed,
        )
        .init(device)?;
    let step = FrameStageStep::new(&frames, device)?.with_retry_repeats(stage.retry_repeats);
    eprintln!(
        "stage A: encoder on {} frames of {} demo videos, {} epochs",
        step.num_examples(),
        frames.demos().len(),
        stage.epochs
    );
    let held_out = match &video.validation {
        Some(v) if !v.pairs.is_empty() => Some(frame_dataset(
            video.vocabulary,
            &v.pairs,
            v.record,
            video.frame_dim,
            1.0,
        )?),
        _ => None,
    };
    let held_out_step = held_out
        .as_ref()
        .map(|d| FrameStageStep::new(d, device))
        .transpose()?;
    let mut validator = |net: &FrameStageNet| -> anyhow::Result<ValidationScore> {
        let step = held_out_step.as_ref().context("no validation videos")?;
        let acc = step.accuracy(net)?;
        eprintln!(
            "  stage A held-out ({} frames of {} videos): localizer {:.3} (keyframes {:.3}) | edges {:.3} (retries {})",
            step.num_examples(),
            step.dataset.demos().len(),
            acc.localizer,
            acc.keyframe_localizer,
            acc.edge,
            acc.retry_edge
                .map_or_else(|| "-".to_owned(), |a| format!("{a:.3}"))
        );
        if let Some(p) = acc.keyframe_progress {
            eprintln!("  stage A held-out keyframes' progress all right: {p:.3}");
        }
        Ok(ValidationScore {
            success: acc.localizer,
            goal_fraction: acc.edge,
        })
    };
    let selection = held_out_step.is_some().then_some(Selection {
        validator: &mut validator as &mut dyn crate::fit::Validator<FrameStageNet>,
        every: 1,
        scores: STAGE_A_SCORES,
    });
    let net = fit(
        net,
        &step,
        &stage.optim(video.seed),
        &dir,
        device,
        selection,
        |m: &EncoderEpochMetrics| {
            eprintln!(
                "  stage A epoch {}: loss {:.3} | localizer {:.3} | edges {:.3} | {:.1}s",
                m.epoch, m.loss, m.localizer_accuracy, m.edge_accuracy, m.seconds
            )
        },
    )?;
    // A finished stage A never reads its frames again (a resumed run loads
    // the encoder, as above), and they are among the largest files of a
    // run. Dropped (unmapped) before removal.
    drop(step);
    drop(frames);
    if stage_a_finished(dir.root(), stage)? {
        let frames_dir = dir.dataset_dir();
        if frames_dir.is_dir() {
            std::fs::remove_dir_all(&frames_dir)
                .with_context(|| format!("removing stage A's frames {}", frames_dir.display()))?;
            eprintln!(
                "stage A: done; its frames ({}) removed",
                frames_dir.display()
            );
        }
    }
    Ok(net)
}

/// Whether the stage A folder `stage_a` (a run's [`STAGE_A_DIR`]) holds
/// an encoder trained for all of `encoder`'s epochs (or stopped early at a
/// perfect validation score: [`crate::fit::fit`]).
pub fn stage_a_finished(stage_a: &std::path::Path, encoder: &EncoderStage) -> anyhow::Result<bool> {
    crate::fit::training_finished(stage_a, encoder.epochs)
}

/// What `stage_a/config.json` records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct StageAConfig {
    stage: EncoderStage,
    seed: u64,
}

/// The file in a run folder where stage B's encoding notes each part of
/// its embedding cache as it is built ([`EncodedPart`], one line each; a
/// part a kill interrupted is encoded and noted again).
pub const ENCODING_TIMES: &str = "encoding.jsonl";

/// One part of stage B's embedding cache, as built: its videos and frames,
/// and the wall and CPU seconds encoding them took (CPU: where its
/// process ran nothing else meanwhile).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncodedPart {
    /// Videos encoded.
    pub videos: usize,
    /// Frames encoded.
    pub frames: usize,
    /// Wall seconds.
    pub seconds: f64,
    /// CPU seconds of the process, where it ran nothing else.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_seconds: Option<f64>,
}

/// Videos encoded per saved part of stage B's embedding cache: a killed
/// encoding resumes after its last whole part (about 2 minutes each for
/// block stacking's videos on one core; 25 parts, 84 minutes in all, for
/// ntp_exp-vid-1000's 100,000 beside another run).
pub const EMBEDDING_PART_VIDEOS: usize = 4096;

/// Stage B's data: every training video of `video` encoded once with the
/// frozen encoder of `frames`, cached in `run/embeddings/` (built on the
/// first call, in parts of [`EMBEDDING_PART_VIDEOS`] videos saved as they
/// are done; read back afterwards).
pub fn embeddings(
    run: &RunDir,
    video: &VideoRun<'_>,
    frames: &FrameStageNet,
) -> anyhow::Result<DemoDataset> {
    let started = std::time::Instant::now();
    let times = run.root().join(ENCODING_TIMES);
    let embeddings = DemoDataset::load_or_build_in_parts(
        &run.root().join(EMBEDDINGS_DIR),
        &video.pairs,
        EMBEDDING_PART_VIDEOS,
        |pairs, part| {
            let (clock, part_started) = (
                crate::fit::EpochCpuClock::start(),
                std::time::Instant::now(),
            );
            let encoded = encode_videos(
                video.vocabulary,
                pairs,
                video.record,
                frames,
                &format!("encoding{part}"),
            )?;
            RunDir::append_jsonl(
                &times,
                &EncodedPart {
                    videos: pairs.len(),
                    frames: encoded.num_rows(),
                    seconds: part_started.elapsed().as_secs_f64(),
                    cpu_seconds: clock.seconds(),
                },
            )?;
            Ok(encoded)
        },
    )?;
    eprintln!(
        "stage B: {} demo videos, {} frames encoded ({:.0}s)",
        embeddings.demos().len(),
        embeddings.num_rows(),
        started.elapsed().as_secs_f32()
    );
    Ok(embeddings)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keep_frames_keeps_every_keyframe_and_about_the_fraction_of_the_rest() {
        let vocab = Vocabulary::from_sequences([["a", "b"].as_slice()]).unwrap();
        let actions = vocab.parse_sequence("a b").unwrap();
        let video = |n: usize| {
            VideoDemonstration::new(
                (0..3 * n).collect::<Vec<usize>>(),
                vec![n, 2 * n, 3 * n],
                actions.clone(),
                &vocab,
            )
            .unwrap()
        };
        let all = keep_frames(video(4), 1.0, 7, &vocab).unwrap();
        assert_eq!(all.frames(), video(4).frames());
        let keys = keep_frames(video(4), 0.0, 7, &vocab).unwrap();
        assert_eq!(keys.frames(), &[3, 7, 11], "the keyframes alone");
        assert_eq!(keys.actions(), &actions[..]);
        let some = keep_frames(video(400), 0.25, 7, &vocab).unwrap();
        let others = some.frames().len() - 3;
        assert!(
            (250..350).contains(&others),
            "{others} of 1197 non-keyframes at 0.25"
        );
        assert!(some.frames().contains(&399) && some.frames().contains(&1199));
        assert_eq!(
            some.frames(),
            keep_frames(video(400), 0.25, 7, &vocab).unwrap().frames(),
            "seeded"
        );
    }

    /// Three videos of task 0 ("a b") with `dim`-value frames: a start
    /// segment of 1 frame, then `2 + i` frames per action in demo `i`.
    fn three_videos(dim: usize) -> DemoDataset {
        let vocab = Vocabulary::from_sequences([["a", "b"].as_slice()]).unwrap();
        let actions = vocab.parse_sequence("a b").unwrap();
        let videos = (0..3).map(|i| {
            let n = 2 + i;
            let frames = (0..1 + 2 * n).map(|f| vec![f as f32 / 10.0; dim]).collect();
            let video =
                VideoDemonstration::new(frames, vec![1, 1 + n, 1 + 2 * n], actions.clone(), &vocab)
                    .unwrap();
            (0, i as u64, video)
        });
        DemoDataset::from_videos(vocab.clone(), dim, videos).unwrap()
    }

    #[test]
    fn training_on_a_device_without_autodiff_is_an_error_not_a_panic() {
        let dataset = three_videos(3 * 8 * 8);
        let device = ntg_model::cpu_device();
        let step = FrameStageStep::new(&dataset, &device).unwrap();
        let stage = EncoderStage::default();
        let mut config = stage.net_config(dataset.vocabulary().len(), 64, 0);
        config.encoder = ntg_model::EncoderConfig::Frame(
            ntg_model::FrameEncoderConfig::new().with_image_size(8),
        );
        let net = config.init(&device).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(&dir.path().join("run")).unwrap();
        let err =
            fit(net, &step, &stage.optim(0), &run, &device, None, |_| {}).expect_err("an error");
        assert!(err.to_string().contains("autodiff"), "{err}");
    }

    #[test]
    fn first_demos_keeps_the_frames_and_keyframes_of_the_first_demos() {
        let dataset = three_videos(1);
        let device = ntg_model::cpu_device();
        let all = FrameStageStep::new(&dataset, &device).unwrap();
        assert_eq!((all.num_examples(), all.keyframes.len()), (5 + 7 + 9, 9));
        let two = FrameStageStep::new(&dataset, &device)
            .unwrap()
            .first_demos(2);
        assert_eq!((two.num_examples(), two.keyframes.len()), (5 + 7, 6));
        assert!(two.frames.iter().all(|f| f.0 < 12));
        let more = FrameStageStep::new(&dataset, &device)
            .unwrap()
            .first_demos(10);
        assert_eq!(more.num_examples(), all.num_examples());
    }

    #[test]
    fn progress_counts_the_actions_that_were_not_retried() {
        let vocab = Vocabulary::new(["pick(A)", "place(B)", "pick(C)", "place(A)"]).unwrap();
        let bit = |name: &str| 1u64 << vocab.id(name).unwrap().index();
        // The grasp of A slips once, then the drop of C on A misses once.
        let actions = vocab
            .parse_sequence("pick(A) pick(A) place(B) pick(C) place(A) pick(C) place(A)")
            .unwrap();
        let done = progress_bits(&actions);
        let (a, b, c, on_a) = (
            bit("pick(A)"),
            bit("place(B)"),
            bit("pick(C)"),
            bit("place(A)"),
        );
        assert_eq!(
            done,
            vec![
                0,
                0,
                a,
                a | b,
                a | b | c,
                a | b | c,
                a | b | c,
                a | b | c | on_a
            ]
        );
    }

    #[test]
    fn retry_keyframes_are_found_and_repeated() {
        // Two videos: "a a b" (the first `a` was retried) and "a b".
        let vocab = Vocabulary::from_sequences([["a", "b"].as_slice()]).unwrap();
        let video = |actions: &str| {
            let actions = vocab.parse_sequence(actions).unwrap();
            let ends: Vec<usize> = (0..=actions.len()).map(|s| 1 + 2 * s).collect();
            let frames = (0..*ends.last().unwrap()).map(|f| vec![f as f32]).collect();
            VideoDemonstration::new(frames, ends, actions, &vocab).unwrap()
        };
        let videos = [(0, 0, video("a a b")), (1, 1, video("a b"))];
        let dataset = DemoDataset::from_videos(vocab.clone(), 1, videos).unwrap();
        let device = ntg_model::cpu_device();
        let step = FrameStageStep::new(&dataset, &device).unwrap();
        // The keyframe after the first `a` (frame 2: its next action is `a`
        // again) is the only retry.
        assert_eq!(step.retries.len(), 1);
        assert_eq!(step.frames[step.retries[0]].0, 2);
        assert_eq!(step.num_examples(), 7 + 5);
        let repeated = FrameStageStep::new(&dataset, &device)
            .unwrap()
            .with_retry_repeats(4);
        assert_eq!(repeated.num_examples(), 7 + 5 + 3);
        assert!(repeated.frames[12..].iter().all(|f| f.0 == 2));
        // Scoring counts every frame once, repeats or not.
        assert_eq!(repeated.keyframes, step.keyframes);
        // Keeping the first demo keeps its retry and its repeats.
        let first = repeated.first_demos(1);
        assert_eq!((first.num_examples(), first.retries.len()), (7 + 3, 1));
        let second_only_has_none = FrameStageStep::new(&dataset, &device)
            .unwrap()
            .with_retry_repeats(4)
            .first_demos(0);
        assert_eq!(second_only_has_none.num_examples(), 0);
    }

    #[test]
    fn spread_pairs_cover_tasks_first() {
        let pairs = spread_pairs(3, 2, 100);
        assert_eq!(
            pairs,
            [
                (0, 100),
                (1, 1100),
                (2, 2100),
                (0, 101),
                (1, 1101),
                (2, 2101)
            ]
        );
    }
}
