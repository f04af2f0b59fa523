//! The one epoch loop: every method of every domain trains through [`fit`].
//!
//! A method supplies a [`TrainStep`] (the loss of one batch of example
//! indices, and how an epoch's mean step values become its metrics line);
//! a domain optionally supplies a [`Validator`] (rollouts on held-out
//! tasks). `fit` owns everything else: shuffling, the learning-rate
//! schedule, Adam, the progress bar, `metrics.jsonl` (and its TensorBoard
//! copy, [`crate::events`]), validation and
//! best-epoch selection into `best/`, checkpoints and resuming.
//!
//! Determinism and resuming: epoch `e` shuffles with a generator seeded by
//! `(seed, e)` alone, and the step gets that generator (after the shuffle)
//! and its `(epoch, step)` to draw anything else it needs, so a run resumed
//! from the checkpoint of epoch `e - 1` takes exactly the same steps as an
//! uninterrupted one. Nothing random needs saving.
//!
//! Kills: each epoch is logged first (`metrics.jsonl`, `validation.jsonl`),
//! then its checkpoint (weights, optimizer state, progress) and `best/` are
//! committed whole by [`crate::run_dir::replace_dir`]. A run killed at any
//! moment resumes from a complete checkpoint, drops the lines of the epoch
//! it did not commit, and redoes that epoch; logged epochs beyond the
//! checkpoint by more than that (a checkpoint removed by hand) are an
//! error, not a silent restart.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, bail};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor};
use ntg_model::{EdgeCounts, FlatPolicy, NtgModel, ParallelOptimizer};
use rand::seq::SliceRandom;
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::events::EventWriter;
use crate::run_dir::{RunDir, drop_lines_from_epoch, recover_dir, replace_dir};

/// Trainings and evaluations running in this process now, and how many
/// have started: an epoch's process CPU time is its run's own only if no
/// other job ran at any moment of it.
static JOBS_RUNNING: AtomicUsize = AtomicUsize::new(0);
static JOBS_STARTED: AtomicUsize = AtomicUsize::new(0);

/// One of several trainings or evaluations an application runs at once in
/// one process (`ntg reproduce --jobs`), counted while it lives: [`fit`]
/// records an epoch's CPU seconds only when its job was the only one
/// running throughout. A process that runs one job at a time needs none.
pub struct RunningJob(());

impl RunningJob {
    /// Counts a job starting now.
    pub fn start() -> Self {
        JOBS_STARTED.fetch_add(1, Ordering::SeqCst);
        JOBS_RUNNING.fetch_add(1, Ordering::SeqCst);
        RunningJob(())
    }
}

impl Drop for RunningJob {
    fn drop(&mut self) {
        JOBS_RUNNING.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Ticks per second of the times in `/proc/PID/stat` (the kernel's fixed
/// user-space `USER_HZ`).
const PROC_TICKS_PER_SECOND: f64 = 100.0;

/// The CPU time this process has used (user and system, every thread), in
/// ticks of 1/100 s, from `/proc/self/stat`. `None` off Linux or if it
/// cannot be read.
fn process_cpu_ticks() -> Option<u64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    cpu_ticks_of_stat(&stat)
}

/// `utime + stime` of a `/proc/PID/stat` line, in ticks. The command name
/// (field 2, in parentheses) may hold spaces: fields are counted from after
/// its closing parenthesis (field 3 first).
fn cpu_ticks_of_stat(stat: &str) -> Option<u64> {
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i)?.parse::<u64>().ok();
    // Fields 14 and 15 of proc(5): utime, stime.
    Some(ticks(11)? + ticks(12)?)
}

/// Measures an epoch's (or another stretch of a run's) CPU time when it
/// is its process's only job.
pub(crate) struct EpochCpuClock(Option<(u64, usize)>);

impl EpochCpuClock {
    pub(crate) fn start() -> Self {
        let alone = JOBS_RUNNING.load(Ordering::SeqCst) <= 1;
        EpochCpuClock(
            alone
                .then(|| Some((process_cpu_ticks()?, JOBS_STARTED.load(Ordering::SeqCst))))
                .flatten(),
        )
    }

    /// The process's CPU seconds since `start`, or `None` if another job
    /// of this process ran meanwhile (or the time cannot be read).
    pub(crate) fn seconds(&self) -> Option<f64> {
        let (ticks, started) = self.0?;
        let alone = JOBS_RUNNING.load(Ordering::SeqCst) <= 1
            && JOBS_STARTED.load(Ordering::SeqCst) == started;
        let spent = process_cpu_ticks()?.checked_sub(ticks)?;
        alone.then_some(spent as f64 / PROC_TICKS_PER_SECOND)
    }
}

/// The paper's Adam learning rate (the default of every method's training
/// unless a recipe says otherwise).
pub const PAPER_LEARNING_RATE: f64 = 1e-3;

/// Optimisation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OptimConfig {
    /// Passes over the dataset.
    pub epochs: usize,
    /// Examples (demonstrations) per step.
    pub batch_size: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Seed of the shuffling (and of every other draw of training).
    pub seed: u64,
    /// NTG: probability that the demo interpreter's decoder reads `<start>`
    /// instead of the previous action in training (regularises it towards
    /// reading the demo; 0 = plain teacher forcing).
    #[serde(default)]
    pub token_dropout: f32,
    /// NTG: the GCN reads another demo of the same task than the one the
    /// edge classifier imitates (drawn from a seeded generator; the demo
    /// itself when its task has no other). Otherwise the GCN's node
    /// embeddings carry where the imitated demo itself ends or retries, and
    /// the edge classifier learns to copy that instead of reading the
    /// observation.
    #[serde(default)]
    pub gcn_from_other_demo: bool,
    /// Decay the learning rate along a half cosine from `learning_rate` to
    /// a tenth of it over the run (per step); off = constant.
    #[serde(default)]
    pub cosine_decay: bool,
    /// Data-parallel training: each batch is split into this many shards
    /// of (nearly) equal size whose losses and gradients are computed on
    /// their own threads, on their own copy of the model, and summed
    /// (weighted by shard size) before one optimiser step. 0 and 1: the
    /// whole batch on the calling thread. The result is the same for the
    /// same seed and shard count, but differs between shard counts: a
    /// shard's per-step draws come from its own generator, seeded from the
    /// epoch's, and losses averaged over masked items average per shard.
    #[serde(default, skip_serializing_if = "is_one_shard")]
    pub shards: usize,
}

/// Whether `shards` means one shard (serde: such a count is not written).
pub fn is_one_shard(shards: &usize) -> bool {
    *shards <= 1
}

impl OptimConfig {
    /// A training stage's settings (a frame encoder, a detector): `epochs`
    /// over batches of `batch_size` at `learning_rate` decaying along a
    /// cosine, shuffled from `seed`, on `shards` threads; none of NTG's
    /// options.
    pub fn stage(
        epochs: usize,
        batch_size: usize,
        learning_rate: f64,
        seed: u64,
        shards: usize,
    ) -> Self {
        OptimConfig {
            epochs,
            batch_size,
            learning_rate,
            seed,
            token_dropout: 0.0,
            gcn_from_other_demo: false,
            cosine_decay: true,
            shards,
        }
    }

    /// The learning rate at `step` of `total_steps`.
    pub fn learning_rate_at(&self, step: usize, total_steps: usize) -> f64 {
        if !self.cosine_decay || total_steps <= 1 {
            return self.learning_rate;
        }
        let progress = step.min(total_steps - 1) as f64 / (total_steps - 1) as f64;
        let floor = 0.1 * self.learning_rate;
        floor + (self.learning_rate - floor) * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos())
    }
}

/// A model [`fit`] can train and checkpoint.
pub trait TrainedModel: Module + Clone {
    /// Saves the weights and configuration into `dir`.
    fn save_to(&self, dir: &Path) -> anyhow::Result<()>;
    /// Loads what [`TrainedModel::save_to`] wrote.
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self>;
}

impl TrainedModel for NtgModel {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(NtgModel::load(dir, device)?)
    }
}

impl TrainedModel for FlatPolicy {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(FlatPolicy::load(dir, device)?)
    }
}

impl TrainedModel for ntg_model::Detector {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(ntg_model::Detector::load(dir, device)?)
    }
}

/// Where a step is in the run, and the epoch's generator to draw from.
pub struct StepContext<'a> {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Step index within the epoch (from 0).
    pub step: usize,
    /// The run's shuffling seed ([`OptimConfig::seed`]).
    pub seed: u64,
    /// The epoch's generator, after it shuffled the examples; steps draw
    /// from it in order.
    pub rng: &'a mut ChaCha8Rng,
}

/// What one optimisation step reports: the loss to minimise, scalars to
/// average over the epoch, and GCN edge counts (summed over the epoch).
pub struct StepReport {
    /// The loss; its gradients update the model.
    pub loss: Tensor<1>,
    /// Values averaged over the epoch's steps; the first is the loss.
    pub values: Vec<f32>,
    /// GCN edge counts (zero for models without a GCN).
    pub edges: EdgeCounts,
}

impl StepReport {
    /// The report of a model without a GCN: the loss, its value first,
    /// then `metrics`.
    pub fn scored(loss: Tensor<1>, metrics: &[f32]) -> anyhow::Result<Self> {
        let mut values = vec![scalar(loss.clone())?];
        values.extend_from_slice(metrics);
        Ok(StepReport {
            loss,
            values,
            edges: EdgeCounts::default(),
        })
    }
}

/// One method's training step: the loss on a batch of examples (indices
/// into the method's dataset), and the metrics line of an epoch.
pub trait TrainStep<M> {
    /// What `metrics.jsonl` records per epoch.
    type Metrics: Serialize;
    /// Number of training examples.
    fn num_examples(&self) -> usize;
    /// The loss of examples `batch` under `model`.
    fn step(&self, model: &M, batch: &[usize], ctx: StepContext<'_>) -> anyhow::Result<StepReport>;
    /// The epoch's metrics from the mean of each step value, the summed
    /// edge counts and the epoch's seconds.
    fn epoch_metrics(
        &self,
        epoch: usize,
        means: &[f32],
        edges: &EdgeCounts,
        seconds: f32,
    ) -> Self::Metrics;
}

/// A model's score on held-out validation tasks; higher is better, compared
/// by success rate, then by the fraction of goals met.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationScore {
    /// Fraction of validation tasks completed.
    pub success: f64,
    /// Mean fraction of each validation task's goals met at the end.
    pub goal_fraction: f64,
}

impl ValidationScore {
    /// Whether `self` is strictly better than `other`.
    pub fn beats(&self, other: &ValidationScore) -> bool {
        (self.success, self.goal_fraction) > (other.success, other.goal_fraction)
    }

    /// Whether no score can beat `self`: every validation task completed
    /// and every goal met. Training stops at a selected epoch with such a
    /// score ([`fit`]), since ties keep the earlier epoch.
    pub fn is_perfect(&self) -> bool {
        self.success >= 1.0 && self.goal_fraction >= 1.0
    }
}

/// One line of `validation.jsonl`, and the contents of `best/selection.json`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationRecord {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// The score after that epoch.
    #[serde(flatten)]
    pub score: ValidationScore,
}

/// Scores a model (on the training device) on held-out tasks after an
/// epoch. It must be deterministic: a resumed run re-scores nothing, it
/// reads earlier scores back from the run folder.
pub trait Validator<M> {
    /// The score of `model`.
    fn validate(&mut self, model: &M) -> anyhow::Result<ValidationScore>;
}

impl<M, F: FnMut(&M) -> anyhow::Result<ValidationScore>> Validator<M> for F {
    fn validate(&mut self, model: &M) -> anyhow::Result<ValidationScore> {
        self(model)
    }
}

/// Model selection of a [`fit`]: a validator, how often it runs, and what
/// its numbers are.
pub struct Selection<'a, M> {
    /// Scores the model.
    pub validator: &'a mut dyn Validator<M>,
    /// Validate after every this many epochs (and after the last); 0 and 1
    /// mean every epoch.
    pub every: usize,
    /// The names of the score's two numbers in the training log.
    pub scores: ScoreNames,
}

/// The names of a [`ValidationScore`]'s [`success`](ValidationScore::success)
/// and [`goal_fraction`](ValidationScore::goal_fraction) in the training
/// log: what the validator measures with them.
pub type ScoreNames = [&'static str; 2];

/// Rollouts on validation tasks: the fraction completed, the goals met.
pub const ROLLOUT_SCORES: ScoreNames = ["success", "goals met"];

/// The epoch `run`'s `best/` folder holds, if validation selected one.
pub fn selected_epoch(run: &RunDir) -> anyhow::Result<Option<ValidationRecord>> {
    let path = run.best_dir().join("selection.json");
    if path.is_file() {
        Ok(Some(RunDir::read_json(&path)?))
    } else {
        Ok(None)
    }
}

/// The folder of `run`'s trained model: `best/` when validation selected
/// an epoch, else the last checkpoint.
pub fn trained_dir(run: &RunDir) -> anyhow::Result<std::path::PathBuf> {
    Ok(match selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    })
}

/// Progress saved with each checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Progress {
    epochs_done: usize,
    /// Training stopped before its last epoch because the selected epoch's
    /// validation score was perfect (absent in older checkpoints: false).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    stopped_early: bool,
}

impl Progress {
    /// Whether a run of `epochs` epochs has nothing left to train.
    fn finished(&self, epochs: usize) -> bool {
        self.stopped_early || self.epochs_done >= epochs
    }
}

/// Whether the run folder `run` holds a checkpoint with nothing left to
/// train for `epochs` epochs: all of them done, or training stopped early
/// at a perfect validation score (see [`fit`]). False without a checkpoint,
/// and false in a run folder restored from a committed record, or a stage
/// folder of one (its training is recorded, but it holds no weights to
/// reuse).
pub fn training_finished(run: &Path, epochs: usize) -> anyhow::Result<bool> {
    let path = run.join("checkpoint").join("progress.json");
    let restored =
        crate::run_dir::is_restored(run) || run.parent().is_some_and(crate::run_dir::is_restored);
    if restored || !path.is_file() {
        return Ok(false);
    }
    let progress: Progress = RunDir::read_json(&path)?;
    Ok(progress.finished(epochs))
}

/// The generator of epoch `epoch`: seeded by `(seed, epoch)` alone.
pub fn epoch_rng(seed: u64, epoch: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// Trains `model` (on an autodiff device) for the epochs of `optim` not yet
/// done in `run`, resuming from its checkpoint if there is one. After each
/// epoch: the metrics line goes to `metrics.jsonl` (and `on_epoch`), the
/// model, the optimizer state and the progress to the checkpoint. With a
/// `selection`, the model is scored at its epochs (before checkpointing, so
/// a run killed in between redoes the epoch and finds `best/` untouched or
/// holding this very epoch), the score logged to `validation.jsonl`, the
/// best epoch's weights kept in `best/` (ties keep the earlier) and
/// returned instead of the last. Once the selected epoch's score is
/// perfect ([`ValidationScore::is_perfect`]) no later epoch can be
/// selected, so training stops there (the checkpoint says so, and a
/// resumed run trains nothing): the same selected model, fewer epochs.
pub fn fit<M, S>(
    mut model: M,
    step: &S,
    optim: &OptimConfig,
    run: &RunDir,
    device: &Device,
    mut selection: Option<Selection<'_, M>>,
    mut on_epoch: impl FnMut(&S::Metrics),
) -> anyhow::Result<M>
where
    M: TrainedModel + Send,
    S: TrainStep<M> + Sync,
{
    let num_examples = step.num_examples();
    if num_examples == 0 {
        bail!("the dataset has no demonstrations");
    }
    if optim.batch_size == 0 {
        bail!("batch size must be positive");
    }
    if !device.is_autodiff() {
        bail!("training needs an autodiff device (`device.autodiff()`), got {device:?}");
    }
    let _writer = run.lock()?;
    // Adam, its update split across the pool's threads (bit-identical to
    // one optimizer; the state file is the same either way).
    let mut optimizer =
        ParallelOptimizer::new(rayon::current_num_threads(), || AdamConfig::new().init());
    let ckpt = run.checkpoint_dir();
    let progress_path = ckpt.join("progress.json");
    // A kill leaves the checkpoint and `best/` whole (see `replace_dir`),
    // and at most the lines of the epoch after the checkpoint logged.
    recover_dir(&ckpt)?;
    recover_dir(&run.best_dir())?;
    recover_dir(&run.initial_dir())?;
    let mut start = 0;
    let mut stopped_early = false;
    if progress_path.is_file() {
        let progress: Progress = RunDir::read_json(&progress_path)?;
        model = M::load_from(&ckpt, device)
            .with_context(|| format!("resuming from {}", ckpt.display()))?;
        optimizer = optimizer
            .load(ckpt.join("optimizer.bpk"))
            .with_context(|| format!("resuming from {}", ckpt.display()))?;
        start = progress.epochs_done;
        stopped_early = progress.stopped_early;
    }
    // The weights before any step (same seed, same bits), kept once: what
    // a series is compared with to show it learned (`RunDir::initial_dir`).
    if start == 0 && !run.initial_dir().is_dir() {
        replace_dir(&run.initial_dir(), |dir| model.save_to(dir))?;
    }
    drop_lines_from_epoch(&run.metrics_path(), start)?;
    drop_lines_from_epoch(&run.validation_path(), start)?;
    if start < optim.epochs && !stopped_early {
        crate::provenance::note_session(run, start)?;
    }
    let steps_per_epoch = num_examples.div_ceil(optim.batch_size);
    let total_steps = steps_per_epoch * optim.epochs;
    let last = if stopped_early { start } else { optim.epochs };
    // TensorBoard's copy of the log, a file per session (see `events`).
    let mut events = (start < last)
        .then(|| EventWriter::start_session(run.root(), start))
        .transpose()?;
    for epoch in start..last {
        let started = std::time::Instant::now();
        let cpu_clock = EpochCpuClock::start();
        let mut rng = epoch_rng(optim.seed, epoch);
        let mut order: Vec<usize> = (0..num_examples).collect();
        order.shuffle(&mut rng);
        let mut sums: Vec<f32> = Vec::new();
        let mut edges = EdgeCounts::default();
        let bar = crate::dataset::progress_bar(steps_per_epoch as u64, &format!("epoch {epoch}"));
        for (k, batch) in order.chunks(optim.batch_size).enumerate() {
            let (grads, values, step_edges) =
                sharded_step(&model, step, batch, epoch, k, optim, &mut rng)?;
            add_weighted(&mut sums, &mut edges, &values, &step_edges, 1.0);
            let rate = optim.learning_rate_at(epoch * steps_per_epoch + k, total_steps);
            model = optimizer.step(rate, model, grads);
            bar.inc(1);
        }
        bar.finish_and_clear();
        let means: Vec<f32> = sums.iter().map(|s| s / steps_per_epoch as f32).collect();
        let loss = means.first().copied().unwrap_or(f32::NAN);
        if !loss.is_finite() {
            bail!("training diverged at epoch {epoch} (loss {loss})");
        }
        let metrics = step.epoch_metrics(epoch, &means, &edges, started.elapsed().as_secs_f32());
        let cpu_seconds = cpu_clock.seconds();
        let validate_now =
            |every: usize| (epoch + 1) % every.max(1) == 0 || epoch + 1 == optim.epochs;
        let mut validation = None;
        if let Some(sel) = selection.as_mut().filter(|s| validate_now(s.every)) {
            let score = sel.validator.validate(&model)?;
            // Labelled: `ntg reproduce --jobs` interleaves runs' lines.
            let [first, second] = sel.scores;
            eprintln!(
                "  [{}] epoch {epoch:>3} validation: {first} {:.3}, {second} {:.3}",
                run.root().file_name().unwrap_or_default().to_string_lossy(),
                score.success,
                score.goal_fraction
            );
            let record = ValidationRecord { epoch, score };
            let improves = match selected_epoch(run)? {
                None => true,
                Some(best) => best.epoch >= epoch || score.beats(&best.score),
            };
            if improves {
                replace_dir(&run.best_dir(), |dir| {
                    model.save_to(dir)?;
                    RunDir::write_json(&dir.join("selection.json"), &record)
                })?;
            }
            let selected = if improves {
                Some(record)
            } else {
                selected_epoch(run)?
            };
            stopped_early =
                epoch + 1 < optim.epochs && selected.is_some_and(|best| best.score.is_perfect());
            validation = Some(record);
        }
        // Log, then checkpoint: a run killed in between redoes the epoch
        // and drops its lines first.
        let line = with_cpu_seconds(&metrics, cpu_seconds)?;
        run.append_metrics(&line)?;
        if let Some(record) = validation {
            RunDir::append_jsonl(&run.validation_path(), &record)?;
        }
        if let Some(events) = events.as_mut() {
            events.scalars("train", epoch, &line)?;
            if let (Some(record), Some(sel)) = (validation, selection.as_ref()) {
                let [first, second] = sel.scores;
                events.named_scalars(
                    "validation",
                    epoch,
                    &[
                        (first, record.score.success),
                        (second, record.score.goal_fraction),
                    ],
                )?;
            }
        }
        replace_dir(&ckpt, |dir| {
            model.save_to(dir)?;
            optimizer.save(dir.join("optimizer.bpk"))?;
            RunDir::write_json(
                &dir.join("progress.json"),
                &Progress {
                    epochs_done: epoch + 1,
                    stopped_early,
                },
            )
        })?;
        on_epoch(&metrics);
        if stopped_early {
            eprintln!(
                "  [{}] the selected epoch's validation score is perfect, so no later epoch can be selected: training stops after {} of its {} epochs",
                run.root().file_name().unwrap_or_default().to_string_lossy(),
                epoch + 1,
                optim.epochs
            );
            break;
        }
    }
    if selection.is_some()
        && let Some(selected) = selected_model(run, device)?
    {
        return Ok(selected);
    }
    Ok(model)
}

/// The weights in `run`'s `best/`, if validation selected an epoch.
fn selected_model<M: TrainedModel>(run: &RunDir, device: &Device) -> anyhow::Result<Option<M>> {
    let Some(best) = selected_epoch(run)? else {
        return Ok(None);
    };
    M::load_from(&run.best_dir(), device)
        .with_context(|| {
            format!(
                "loading the weights of epoch {} selected on validation tasks",
                best.epoch
            )
        })
        .map(Some)
}

/// What [`fit`] would return for `run` if its checkpoint has `epochs`
/// epochs done, read from the run folder alone (no dataset, no step): the
/// epoch selected on validation when `selecting` (fit called with a
/// [`Selection`]) and one was, else the checkpoint's. `None` while epochs
/// remain.
pub fn finished_model<M: TrainedModel>(
    run: &RunDir,
    epochs: usize,
    selecting: bool,
    device: &Device,
) -> anyhow::Result<Option<M>> {
    let _writer = run.lock()?;
    let ckpt = run.checkpoint_dir();
    recover_dir(&ckpt)?;
    recover_dir(&run.best_dir())?;
    recover_dir(&run.initial_dir())?;
    let progress_path = ckpt.join("progress.json");
    if !progress_path.is_file() {
        return Ok(None);
    }
    let progress: Progress = RunDir::read_json(&progress_path)?;
    if !progress.finished(epochs) {
        return Ok(None);
    }
    if selecting && let Some(selected) = selected_model(run, device)? {
        return Ok(Some(selected));
    }
    M::load_from(&ckpt, device)
        .with_context(|| format!("reading the model in {}", ckpt.display()))
        .map(Some)
}

/// `metrics` as its `metrics.jsonl` line: with `cpu_seconds` (the
/// process's CPU time over the epoch's steps, every thread, where the run
/// had the process to itself) beside the method's own fields, whose
/// `seconds` is wall time.
fn with_cpu_seconds(
    metrics: &impl Serialize,
    cpu_seconds: Option<f64>,
) -> anyhow::Result<serde_json::Value> {
    let mut line = serde_json::to_value(metrics)?;
    if let (Some(cpu), Some(fields)) = (cpu_seconds, line.as_object_mut()) {
        fields.insert("cpu_seconds".into(), serde_json::json!(cpu));
    }
    Ok(line)
}

/// One step's gradients, values and edge counts on `batch`: on the calling
/// thread with the epoch's generator, or split into
/// [`OptimConfig::shards`] shards on their own threads (see there).
fn sharded_step<M, S>(
    model: &M,
    step: &S,
    batch: &[usize],
    epoch: usize,
    index: usize,
    optim: &OptimConfig,
    rng: &mut ChaCha8Rng,
) -> anyhow::Result<(GradientsParams, Vec<f32>, EdgeCounts)>
where
    M: Module + Send,
    S: TrainStep<M> + Sync,
{
    let shards = optim.shards.clamp(1, batch.len().max(1));
    if shards == 1 {
        let ctx = StepContext {
            epoch,
            step: index,
            seed: optim.seed,
            rng,
        };
        let report = step.step(model, batch, ctx)?;
        let grads = GradientsParams::from_grads(report.loss.backward(), model);
        return Ok((grads, report.values, report.edges));
    }
    let seeds: Vec<u64> = (0..shards).map(|_| rng.next_u64()).collect();
    let (base, extra) = (batch.len() / shards, batch.len() % shards);
    let mut parts = Vec::with_capacity(shards);
    let mut from = 0;
    for i in 0..shards {
        let len = base + usize::from(i < extra);
        parts.push(&batch[from..from + len]);
        from += len;
    }
    let total = batch.len() as f32;
    let (grads, reports) = ntg_model::sharded_gradients(model, shards, |replica, i| {
        let mut rng = ChaCha8Rng::seed_from_u64(seeds[i]);
        let ctx = StepContext {
            epoch,
            step: index,
            seed: optim.seed,
            rng: &mut rng,
        };
        let report = step.step(replica, parts[i], ctx)?;
        let weight = parts[i].len() as f32 / total;
        Ok::<_, anyhow::Error>((
            report.loss.mul_scalar(weight),
            (report.values, report.edges, weight),
        ))
    })?;
    let mut values: Vec<f32> = Vec::new();
    let mut edges = EdgeCounts::default();
    for (shard_values, shard_edges, weight) in reports {
        add_weighted(&mut values, &mut edges, &shard_values, &shard_edges, weight);
    }
    Ok((grads, values, edges))
}

/// Adds `weight` × `values` to `sums` (sized on first use) and `more` to
/// `edges`.
fn add_weighted(
    sums: &mut Vec<f32>,
    edges: &mut EdgeCounts,
    values: &[f32],
    more: &EdgeCounts,
    weight: f32,
) {
    if sums.is_empty() {
        sums.resize(values.len(), 0.0);
    }
    for (s, v) in sums.iter_mut().zip(values) {
        *s += weight * v;
    }
    edges.true_positives += more.true_positives;
    edges.false_positives += more.false_positives;
    edges.false_negatives += more.false_negatives;
}

/// The first value of a one-element tensor (NaN if empty).
pub fn scalar(t: Tensor<1>) -> anyhow::Result<f32> {
    Ok(ntg_model::nn::to_vec(t)?
        .first()
        .copied()
        .unwrap_or(f32::NAN))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;
    use burn::tensor::TensorData;

    /// Least squares on 5 fixed examples: the loss of a batch is the mean
    /// of its examples' squared errors.
    struct LeastSquares {
        device: Device,
    }

    impl LeastSquares {
        fn example(i: usize) -> ([f32; 3], f32) {
            let x = [i as f32 * 0.3, 1.0 - i as f32 * 0.2, (i % 2) as f32];
            (x, 0.5 * x[0] - x[1] + 2.0 * x[2])
        }
    }

    impl TrainStep<burn::nn::Linear> for LeastSquares {
        type Metrics = ();
        fn num_examples(&self) -> usize {
            5
        }
        fn step(
            &self,
            model: &burn::nn::Linear,
            batch: &[usize],
            _: StepContext<'_>,
        ) -> anyhow::Result<StepReport> {
            let n = batch.len();
            let (xs, ys): (Vec<[f32; 3]>, Vec<f32>) =
                batch.iter().map(|&i| Self::example(i)).unzip();
            let x = Tensor::<2>::from_data(TensorData::new(xs.concat(), [n, 3]), &self.device);
            let y = Tensor::<2>::from_data(TensorData::new(ys, [n, 1]), &self.device);
            let loss = (model.forward(x) - y).powi_scalar(2).mean();
            let value = scalar(loss.clone())?;
            Ok(StepReport {
                loss,
                values: vec![value],
                edges: EdgeCounts::default(),
            })
        }
        fn epoch_metrics(&self, _: usize, _: &[f32], _: &EdgeCounts, _: f32) {}
    }

    #[test]
    fn shards_sum_to_the_whole_batch_gradient_and_repeat_exactly() {
        let device = ntg_model::cpu_device().autodiff();
        let model = LinearConfig::new(3, 1).init(&device);
        let step = LeastSquares {
            device: device.clone(),
        };
        let batch = [4, 0, 2, 1, 3];
        let run = |shards: usize| {
            let optim = OptimConfig {
                epochs: 1,
                batch_size: 5,
                learning_rate: 1e-2,
                seed: 0,
                token_dropout: 0.0,
                cosine_decay: false,
                gcn_from_other_demo: false,
                shards,
            };
            let mut rng = epoch_rng(0, 0);
            let (grads, values, _) =
                sharded_step(&model, &step, &batch, 0, 0, &optim, &mut rng).unwrap();
            let weight = grads.get::<2>(model.weight.id).unwrap();
            (weight.into_data().try_to_vec::<f32>().unwrap(), values[0])
        };
        let (whole, whole_loss) = run(1);
        for shards in [2, 3, 5, 9] {
            // Shards of 3 and 2 (or 2, 2, 1, ...) weighted by their sizes:
            // the same mean loss and gradient up to rounding.
            let (sharded, loss) = run(shards);
            assert!(
                (loss - whole_loss).abs() < 1e-5,
                "{shards} shards: loss {loss} vs {whole_loss}"
            );
            for (a, b) in sharded.iter().zip(&whole) {
                assert!((a - b).abs() < 1e-5, "{shards} shards: gradient {a} vs {b}");
            }
            // The same shard count gives the same bits.
            assert_eq!(run(shards).0, sharded);
        }
    }

    /// A linear model saved as its values in JSON.
    impl TrainedModel for burn::nn::Linear {
        fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
            let values = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
            let bias = self.bias.as_ref().unwrap().val().unsqueeze::<2>();
            std::fs::create_dir_all(dir)?;
            let json = serde_json::to_vec(&(values(self.weight.val()), values(bias)))?;
            Ok(std::fs::write(dir.join("linear.json"), json)?)
        }
        fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
            use burn::module::Param;
            let (w, b): (Vec<f32>, Vec<f32>) =
                serde_json::from_slice(&std::fs::read(dir.join("linear.json"))?)?;
            let mut linear = LinearConfig::new(3, 1).init(device);
            linear.weight =
                Param::from_tensor(Tensor::from_data(TensorData::new(w, [3, 1]), device));
            linear.bias = Some(Param::from_tensor(Tensor::from_data(
                TensorData::new(b, [1]),
                device,
            )));
            Ok(linear)
        }
    }

    #[test]
    fn a_finished_run_gives_fit_s_model_without_its_data() {
        let device = ntg_model::cpu_device().autodiff();
        let step = LeastSquares {
            device: device.clone(),
        };
        let optim = OptimConfig {
            epochs: 3,
            batch_size: 2,
            learning_rate: 0.1,
            seed: 0,
            token_dropout: 0.0,
            cosine_decay: false,
            gcn_from_other_demo: false,
            shards: 1,
        };
        let values = |m: &burn::nn::Linear| m.weight.val().into_data().try_to_vec::<f32>().unwrap();
        for selecting in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            let run = RunDir::create(&dir.path().join("run")).unwrap();
            let unfinished = |run: &RunDir| {
                finished_model::<burn::nn::Linear>(run, optim.epochs, selecting, &device).unwrap()
            };
            assert!(unfinished(&run).is_none(), "nothing trained yet");
            // Validation scores epoch 1 best of the three.
            let mut scores = [0.2, 0.9, 0.5].into_iter();
            let mut validator = |_: &burn::nn::Linear| {
                Ok(ValidationScore {
                    success: scores.next().unwrap(),
                    goal_fraction: 0.0,
                })
            };
            fn selection(
                selecting: bool,
                validator: &mut dyn Validator<burn::nn::Linear>,
            ) -> Option<Selection<'_, burn::nn::Linear>> {
                selecting.then_some(Selection {
                    validator,
                    every: 1,
                    scores: ROLLOUT_SCORES,
                })
            }
            let two = OptimConfig {
                epochs: 2,
                ..optim.clone()
            };
            let init = LinearConfig::new(3, 1).init(&device);
            fit(
                init.clone(),
                &step,
                &two,
                &run,
                &device,
                selection(selecting, &mut validator),
                |_| {},
            )
            .unwrap();
            assert!(unfinished(&run).is_none(), "2 of 3 epochs done");
            let fitted = fit(
                init,
                &step,
                &optim,
                &run,
                &device,
                selection(selecting, &mut validator),
                |_| {},
            )
            .unwrap();
            let read = unfinished(&run).expect("finished");
            assert_eq!(values(&read), values(&fitted), "selecting: {selecting}");
            let last = burn::nn::Linear::load_from(&run.checkpoint_dir(), &device).unwrap();
            assert_eq!(
                values(&fitted) != values(&last),
                selecting,
                "selecting: {selecting}"
            );
        }
    }

    /// A perfect validation score at the selected epoch ends training
    /// there: the run counts as finished, a resumed fit trains nothing, and
    /// the selected model is the one a full run would select.
    #[test]
    fn training_stops_at_a_perfect_validation_score() {
        let device = ntg_model::cpu_device().autodiff();
        let step = LeastSquares {
            device: device.clone(),
        };
        let optim = OptimConfig {
            epochs: 5,
            batch_size: 2,
            learning_rate: 0.1,
            seed: 0,
            token_dropout: 0.0,
            cosine_decay: true,
            gcn_from_other_demo: false,
            shards: 1,
        };
        let values = |m: &burn::nn::Linear| m.weight.val().into_data().try_to_vec::<f32>().unwrap();
        let score = |success: f64, goal_fraction: f64| ValidationScore {
            success,
            goal_fraction,
        };
        // Perfect at epoch 1 (of 0..5); nearly perfect at epoch 0 does not stop.
        let init = LinearConfig::new(3, 1).init(&device);
        let scores = [
            score(1.0, 0.9),
            score(1.0, 1.0),
            score(1.0, 1.0),
            score(0.5, 0.5),
            score(1.0, 1.0),
        ];
        let train = |run: &RunDir, calls: &mut usize| {
            let mut validator = |_: &burn::nn::Linear| {
                *calls += 1;
                Ok(scores[*calls - 1])
            };
            fit(
                init.clone(),
                &step,
                &optim,
                run,
                &device,
                Some(Selection {
                    validator: &mut validator,
                    every: 1,
                    scores: ROLLOUT_SCORES,
                }),
                |_| {},
            )
            .unwrap()
        };
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(&dir.path().join("run")).unwrap();
        let mut calls = 0;
        let fitted = train(&run, &mut calls);
        assert_eq!(calls, 2, "validated epochs 0 and 1, then stopped");
        let logged: Vec<serde_json::Value> =
            crate::run_dir::read_jsonl(&run.metrics_path()).unwrap();
        assert_eq!(logged.len(), 2);
        assert_eq!(selected_epoch(&run).unwrap().unwrap().epoch, 1);
        assert!(training_finished(run.root(), optim.epochs).unwrap());
        let read = finished_model::<burn::nn::Linear>(&run, optim.epochs, true, &device)
            .unwrap()
            .expect("finished");
        assert_eq!(values(&read), values(&fitted));
        // Resumed: nothing more is trained or validated.
        let mut again = 0;
        let resumed = train(&run, &mut again);
        assert_eq!(again, 0);
        assert_eq!(values(&resumed), values(&fitted));
        let logged: Vec<serde_json::Value> =
            crate::run_dir::read_jsonl(&run.metrics_path()).unwrap();
        assert_eq!(logged.len(), 2);

        // The same run trained to its end selects the same epoch's weights.
        let whole = tempfile::tempdir().unwrap();
        let run = RunDir::create(&whole.path().join("run")).unwrap();
        let mut validator = {
            let mut i = 0;
            move |_: &burn::nn::Linear| {
                i += 1;
                // Scores below perfect never stop a run.
                Ok(score(
                    scores[i - 1].success * 0.99,
                    scores[i - 1].goal_fraction,
                ))
            }
        };
        let full = fit(
            init.clone(),
            &step,
            &optim,
            &run,
            &device,
            Some(Selection {
                validator: &mut validator,
                every: 1,
                scores: ROLLOUT_SCORES,
            }),
            |_| {},
        )
        .unwrap();
        let logged: Vec<serde_json::Value> =
            crate::run_dir::read_jsonl(&run.metrics_path()).unwrap();
        assert_eq!(logged.len(), 5, "no perfect score: every epoch");
        assert_eq!(selected_epoch(&run).unwrap().unwrap().epoch, 1);
        assert_eq!(values(&full), values(&fitted), "the same selected weights");
    }

    /// utime 1234 and stime 66 ticks: 13 s, counted after the command
    /// name however many spaces and parentheses it holds.
    #[test]
    fn cpu_time_is_read_after_the_command_name() {
        let stat = "4242 (ntg (x) y) R 1 4242 4242 0 -1 4194304 100 0 0 0 1234 66 0 0 20 0 3 0";
        assert_eq!(cpu_ticks_of_stat(stat), Some(1300));
        assert_eq!(cpu_ticks_of_stat("4242 (ntg) R 1"), None);
        assert_eq!(cpu_ticks_of_stat("garbage"), None);
        if cfg!(target_os = "linux") {
            assert!(process_cpu_ticks().is_some(), "/proc/self/stat on Linux");
        }
    }

    /// The CPU time joins the method's fields; without it the line is the
    /// method's alone. An epoch during which another job ran has none.
    #[test]
    fn a_metrics_line_gets_the_cpu_time_where_there_is_one() {
        #[derive(Serialize)]
        struct Line {
            epoch: usize,
            seconds: f32,
        }
        let line = Line {
            epoch: 3,
            seconds: 2.5,
        };
        assert_eq!(
            with_cpu_seconds(&line, Some(1.25)).unwrap(),
            serde_json::json!({"epoch": 3, "seconds": 2.5, "cpu_seconds": 1.25})
        );
        assert_eq!(
            with_cpu_seconds(&line, None).unwrap(),
            serde_json::json!({"epoch": 3, "seconds": 2.5})
        );
        let clock = EpochCpuClock(Some((0, JOBS_STARTED.load(Ordering::SeqCst))));
        let other = RunningJob::start();
        assert_eq!(clock.seconds(), None);
        drop(other);
    }

    #[test]
    fn cosine_decay_runs_from_the_rate_to_a_tenth() {
        let optim = OptimConfig {
            epochs: 1,
            batch_size: 1,
            learning_rate: 1e-2,
            seed: 0,
            token_dropout: 0.0,
            cosine_decay: true,
            gcn_from_other_demo: false,
            shards: 1,
        };
        assert!((optim.learning_rate_at(0, 101) - 1e-2).abs() < 1e-12);
        assert!((optim.learning_rate_at(50, 101) - 5.5e-3).abs() < 1e-9);
        assert!((optim.learning_rate_at(100, 101) - 1e-3).abs() < 1e-12);
        let constant = OptimConfig {
            cosine_decay: false,
            ..optim
        };
        assert_eq!(constant.learning_rate_at(100, 101), 1e-2);
    }
}
