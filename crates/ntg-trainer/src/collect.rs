//! The object-collection experiment (the paper's fig. "thor_all" (b)):
//! train NTG and the Flat Policy on tasks with N = 2 and 4 target objects,
//! evaluate both on unseen tasks with N = 1..5.
//!
//! Tasks come from env-collect's fixed train/test split by task identity
//! ([`env_collect::TaskSplitter`]'s default): training tasks from the train side, test
//! tasks from the test side, so every evaluated task is unseen. Seeds:
//! training demo `j` of training task `i` is recorded with seed
//! `TRAIN_SEED_BASE + 1000 i + j`; test episode `i` with `N` objects uses
//! the conditioning demo seed `DEMO_SEED_BASE + 1000 N + i` and the rollout
//! seed `ROLLOUT_SEED_BASE + 1000 N + i`, so the policy acts in a scene
//! (object places, search order, appearances) it has not seen in the demo.
//!
//! Observations: the symbolic state vector (`--obs state`, what the
//! reproduce profiles use, because training the frame encoders is too slow
//! on 2 CPU cores for the profiles' budgets) or the rendered 64×64 frame
//! (`--obs vid`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use std::collections::BTreeMap;

use anyhow::{Context, bail, ensure};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Int, Tensor, TensorData};
use clap::ValueEnum;
use ctg_graph::{ActionId, Ctg, Environment, Vocabulary, record_demonstration};
use env_collect::{CollectConfig, CollectEnv, CollectExpert, CollectObservation, Split, Task};
use ntg_model::nn::to_vec;
use ntg_model::{
    DemoBatch, EdgeCounts, EncoderConfig, FlatBatch, FlatExample, FlatPolicy, FlatPolicyConfig,
    NtgConfig, NtgModel, NtgPolicy, adjacency_tensor, executed_actions, ids_tensor, load_optimizer,
    pending_nodes, rows_tensor, save_optimizer, successor_mask,
};
use rand::seq::{IndexedRandom, SliceRandom};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::blocks::ObsKind;
use crate::dataset::{DatasetSpec, DemoDataset, ObsDtype, generate, progress_bar};
use crate::figure::{Panel, Point, Series, write_figure};
use crate::reproduce::Profile;
use crate::run_dir::RunDir;
use crate::stats::SuccessRate;
use crate::train::{EpochMetrics, OptimConfig, task_graphs};

/// Seed base of training demonstrations.
pub const TRAIN_SEED_BASE: u64 = 40_000_000;
/// Seed base of the conditioning demonstration of each test episode.
pub const DEMO_SEED_BASE: u64 = 50_000_000;
/// Seed base of the rollout scene of each test episode.
pub const ROLLOUT_SEED_BASE: u64 = 60_000_000;
/// Seed of the draw of training tasks (with N added).
pub const TRAIN_TASK_SEED: u64 = 70_000;
/// Seed of the order of test tasks (with N added).
pub const TEST_TASK_SEED: u64 = 80_000;
/// The numbers of objects evaluated.
pub const EVAL_OBJECTS: [usize; 5] = [1, 2, 3, 4, 5];

/// Values per observation row.
pub fn obs_dim(kind: ObsKind) -> usize {
    match kind {
        ObsKind::State => env_collect::STATE_LEN,
        ObsKind::Vid => env_collect::FRAME_DIM,
    }
}

/// The matching encoder.
pub fn encoder(kind: ObsKind) -> EncoderConfig {
    match kind {
        ObsKind::State => EncoderConfig::state(env_collect::STATE_LEN),
        ObsKind::Vid => EncoderConfig::frame(),
    }
}

/// The observation as a flat row: the state vector, or the frame in CHW
/// order scaled to `[0, 1]` (an empty row if the frame was not rendered,
/// which the models reject).
pub fn featurize(obs: &CollectObservation, kind: ObsKind) -> Vec<f32> {
    match kind {
        ObsKind::State => obs.state.clone(),
        ObsKind::Vid => obs.frame_chw().unwrap_or_default(),
    }
}

/// The environment configuration for `kind` (frames rendered only for `vid`).
pub fn env_config(kind: ObsKind) -> CollectConfig {
    CollectConfig {
        render: kind == ObsKind::Vid,
        ..CollectConfig::default()
    }
}

/// The two methods of the figure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Neural Task Graphs.
    Ntg,
    /// The Flat Policy baseline (attention over the demo, then an MLP).
    Flat,
}

impl Method {
    /// Name in files and legends.
    pub fn name(self) -> &'static str {
        match self {
            Method::Ntg => "ntg",
            Method::Flat => "flat",
        }
    }

    fn legend(self) -> &'static str {
        match self {
            Method::Ntg => "NTG (ours)",
            Method::Flat => "Flat Policy",
        }
    }
}

/// Which demo interpreter NTG uses (see [`ntg_model::DemoInterpreterConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum InterpreterKind {
    /// The paper's: a forward GRU over the frames, Luong attention without
    /// input feeding, the decoder starting from the encoder's final state.
    Luong,
    /// The same seq2seq with Luong attention, made length-independent:
    /// local annotations (each frame with its two neighbours) instead of
    /// GRU states, input feeding, location-aware attention and a decoder
    /// without memory. The attention steps through the demo one frame per
    /// token and every token (`<end>` included) is read from where it
    /// looks, not from a count of what was written, so it carries over to
    /// longer demos than any seen in training.
    Stepping,
}

impl InterpreterKind {
    /// Sets the interpreter options of `config` for this kind.
    pub fn apply(self, config: &mut ntg_model::DemoInterpreterConfig) {
        let on = match self {
            InterpreterKind::Luong => None,
            InterpreterKind::Stepping => Some(true),
        };
        config.bidirectional = None;
        config.input_feeding = on;
        config.location_attention = on;
        config.stateless_decoder = on;
        config.local_annotations = on;
    }

    /// The initial weight of the location-aware attention's shift +1 that
    /// new runs of this kind start from ([`LOCATION_STEP_PRIOR`] for
    /// `Stepping`; the paper's interpreter has no location-aware attention).
    pub fn default_step_prior(self) -> Option<f32> {
        match self {
            InterpreterKind::Luong => None,
            InterpreterKind::Stepping => Some(LOCATION_STEP_PRIOR),
        }
    }
}

/// The initial weight `w₊₁` of the stepping interpreter's location-aware
/// attention for the frame after the one read last (see
/// `DemoInterpreterConfig::location_step_prior`): the attention starts
/// biased by `G·w₊₁` = 3 towards moving on one frame per token. Without it
/// (weights starting at 0), one of four seeds (1) never found the stepping
/// alignment: training token accuracy stalled at 0.89 (0.90 after 60
/// epochs) and NTG fell to 0.07 / 0.004 / 0 at N = 3 / 4 / 5; with it,
/// seeds 0–3 all reach 1.0 within 5 epochs (quick profile scale).
pub const LOCATION_STEP_PRIOR: f32 = 0.3;

impl InterpreterKind {
    /// Sets the interpreter options of `config` for this kind, with the
    /// location-aware attention's initial shift +1 weight `step_prior`.
    pub fn apply_with_prior(
        self,
        config: &mut ntg_model::DemoInterpreterConfig,
        step_prior: Option<f32>,
    ) {
        self.apply(config);
        config.location_step_prior = step_prior;
    }
}

/// Everything that defines an object-collection training run (`config.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CollectRunConfig {
    /// Always `"collect"` (tells `ntg eval` which domain a run is).
    pub domain: String,
    /// Which model.
    pub method: Method,
    /// Observation kind.
    pub obs: ObsKind,
    /// Numbers of target objects of the training tasks.
    pub train_objects: Vec<usize>,
    /// Distinct training tasks per number of objects.
    pub tasks_per_n: usize,
    /// Expert demonstrations per training task.
    pub demos_per_task: usize,
    /// NTG only: the demo interpreter also learns from one random
    /// contiguous stretch of each training demo (any stretch of a
    /// demonstration, with the actions inside it, is itself a
    /// demonstration), so it does not tie the number of cycles it writes
    /// to the lengths seen in training.
    pub segments: bool,
    /// Train the policy's final `<end>` decision (both methods). The frame
    /// after the last drop-off does not show whether every target has been
    /// delivered (only the current receptacle is visible), so this label
    /// cannot be predicted from the observation; without it, the policies
    /// never choose `<end>` and episodes end at the step limit, where
    /// success is judged the same way.
    pub learn_end: bool,
    /// Give both policies an execution memory, the agent's record of the
    /// actions it has taken so far in the episode (what a single
    /// observation cannot show: e.g. how many objects are delivered). The
    /// Flat Policy adds the set of actions taken to its attention query
    /// ([`ntg_model::executed_actions`]); NTG's edge classifier reads the
    /// nodes of its task graph not yet executed
    /// ([`ntg_model::pending_nodes`]). Absent in configurations saved
    /// before it: false.
    #[serde(default)]
    pub memory: bool,
    /// NTG only: the demo interpreter.
    pub interpreter: InterpreterKind,
    /// NTG with the stepping interpreter only: the initial weight of its
    /// location-aware attention's shift +1 ([`LOCATION_STEP_PRIOR`] in new
    /// runs; `None`, as in runs saved before it, starts it at 0).
    #[serde(default)]
    pub location_step_prior: Option<f32>,
    /// Seed of the initial weights.
    pub model_seed: u64,
    /// Optimisation; the learning rate follows
    /// [`OptimConfig::learning_rate_at`] (constant, or with `cosine_decay`
    /// a half cosine per step down to a tenth), as in block stacking.
    pub optim: OptimConfig,
}

impl CollectRunConfig {
    /// Checks the values.
    pub fn validate(&self) -> anyhow::Result<()> {
        ensure!(self.domain == "collect", "domain must be \"collect\"");
        ensure!(
            !self.train_objects.is_empty()
                && self.train_objects.iter().all(|n| (1..=5).contains(n)),
            "training numbers of objects must be in 1..=5, got {:?}",
            self.train_objects
        );
        ensure!(
            self.tasks_per_n > 0 && self.demos_per_task > 0,
            "tasks per N and demos per task must be positive"
        );
        ensure!(
            self.demos_per_task >= 2,
            "training pairs each demo with another demo of its task: at least 2 demos per task are needed"
        );
        ensure!(self.optim.batch_size > 0, "batch size must be positive");
        if let Some(w) = self.location_step_prior {
            ensure!(
                self.method == Method::Ntg && self.interpreter == InterpreterKind::Stepping,
                "a location step prior needs NTG with the stepping interpreter (the Flat Policy and the paper's interpreter have no location-aware attention)"
            );
            ensure!(
                w.is_finite(),
                "the location step prior must be finite, got {w}"
            );
        }
        Ok(())
    }
}

/// The training tasks of a run: `tasks_per_n` distinct train-side tasks for
/// each N, in order of `train_objects`.
pub fn training_tasks(config: &CollectRunConfig) -> anyhow::Result<Vec<Task>> {
    let splitter = env_collect::TaskSplitter::default();
    let mut tasks = Vec::new();
    for &n in &config.train_objects {
        tasks.extend(
            splitter
                .sample_distinct(
                    n,
                    config.tasks_per_n,
                    Some(Split::Train),
                    TRAIN_TASK_SEED + n as u64,
                )
                .with_context(|| format!("drawing training tasks with {n} objects"))?,
        );
    }
    Ok(tasks)
}

/// Records the training demonstrations of a run, in parallel.
pub fn build_dataset(config: &CollectRunConfig) -> anyhow::Result<DemoDataset> {
    let tasks = training_tasks(config)?;
    let pairs: Vec<(usize, u64)> = (0..tasks.len())
        .flat_map(|t| {
            (0..config.demos_per_task)
                .map(move |j| (t, TRAIN_SEED_BASE + 1000 * t as u64 + j as u64))
        })
        .collect();
    let env_cfg = env_config(config.obs);
    let kind = config.obs;
    let bar = progress_bar(pairs.len() as u64, "demos");
    generate(
        &pairs,
        |t| Ok(CollectEnv::new(tasks[t].clone(), env_cfg)?),
        || CollectExpert,
        |o| featurize(o, kind),
        DatasetSpec {
            vocabulary: env_collect::vocabulary().clone(),
            obs_dim: obs_dim(kind),
            dtype: match kind {
                ObsKind::State => ObsDtype::F32,
                ObsKind::Vid => ObsDtype::U8,
            },
        },
        &bar,
    )
}

/// A trained model of either method.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one or two per run; boxing buys nothing
pub enum CollectModel {
    /// NTG.
    Ntg(NtgModel),
    /// The Flat Policy.
    Flat(FlatPolicy),
}

/// Metrics of one Flat Policy epoch, as logged to `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatEpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean cross-entropy of the next action.
    pub loss: f32,
    /// Fraction of steps whose next action it picks.
    pub step_accuracy: f32,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
}

/// One line of training progress, either method.
#[derive(Debug, Clone, PartialEq)]
pub enum Progress<'a> {
    /// An NTG epoch.
    Ntg(&'a EpochMetrics),
    /// A Flat Policy epoch.
    Flat(&'a FlatEpochMetrics),
}

impl Progress<'_> {
    /// One human-readable line.
    pub fn line(&self) -> String {
        match self {
            Progress::Ntg(m) => m.log_line(),
            Progress::Flat(m) => format!(
                "epoch {:>3}: loss {:.3} | steps {:.3} | {:.1}s",
                m.epoch, m.loss, m.step_accuracy, m.seconds
            ),
        }
    }
}

/// Trains (or resumes) a run in `run`, returning the model.
pub fn train_run(
    run: &RunDir,
    config: &CollectRunConfig,
    device: &Device,
    mut on_epoch: impl FnMut(Progress<'_>),
) -> anyhow::Result<CollectModel> {
    config.validate()?;
    let dataset_dir = run.dataset_dir();
    let dataset = if dataset_dir.join("index.json").is_file() {
        DemoDataset::load(&dataset_dir)?
    } else {
        let dataset = build_dataset(config)?;
        dataset.save(&dataset_dir)?;
        dataset
    };
    let n = env_collect::vocabulary().len();
    match config.method {
        Method::Ntg => {
            let mut model_config = NtgConfig::for_domain(n, encoder(config.obs));
            model_config.seed = config.model_seed;
            config
                .interpreter
                .apply_with_prior(&mut model_config.interpreter, config.location_step_prior);
            model_config.edge.memory_dim = config.memory.then_some(n);
            let model = NtgModel::new(model_config, device)?;
            let model = train_ntg(model, &dataset, config, run, device, |m| {
                on_epoch(Progress::Ntg(m))
            })?;
            Ok(CollectModel::Ntg(model))
        }
        Method::Flat => {
            let policy = FlatPolicyConfig::new(n, encoder(config.obs))
                .with_seed(config.model_seed)
                .with_memory_dim(config.memory.then_some(n))
                .init(device)?;
            let policy = train_flat(policy, &dataset, config, run, device, |m| {
                on_epoch(Progress::Flat(m))
            })?;
            Ok(CollectModel::Flat(policy))
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct EpochsDone {
    epochs_done: usize,
}

/// What one optimisation step reports: the loss to minimise, scalars to
/// average over the epoch (the first is the loss itself), and GCN edge counts.
struct StepReport {
    loss: Tensor<1>,
    values: Vec<f32>,
    edges: EdgeCounts,
}

/// The epoch loop shared by both methods: epoch `e` shuffles the examples
/// (and draws anything else it needs) with a generator seeded by
/// `(seed, e)` alone, step `k` of the run uses
/// [`OptimConfig::learning_rate_at`]`(k, total)`; after
/// each epoch the model, the optimizer state and the progress are saved
/// into `run`'s checkpoint, so a resumed run takes exactly the steps of an
/// uninterrupted one. `finish` gets the epoch, the
/// mean of each step value, the summed edge counts and the seconds taken.
#[allow(clippy::too_many_arguments)]
fn fit<M: Module>(
    mut model: M,
    num_examples: usize,
    optim: &OptimConfig,
    run: &RunDir,
    load: impl Fn(&Path) -> anyhow::Result<M>,
    save: impl Fn(&M, &Path) -> anyhow::Result<()>,
    mut step: impl FnMut(&M, &[usize], &mut ChaCha8Rng) -> anyhow::Result<StepReport>,
    mut finish: impl FnMut(usize, &[f32], &EdgeCounts, f32) -> anyhow::Result<()>,
) -> anyhow::Result<M> {
    if num_examples == 0 {
        bail!("the dataset has no demonstrations");
    }
    if optim.batch_size == 0 {
        bail!("batch size must be positive");
    }
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
    let ckpt = run.checkpoint_dir();
    let progress_path = ckpt.join("progress.json");
    let mut start = 0;
    if progress_path.is_file() {
        let progress: EpochsDone = RunDir::read_json(&progress_path)?;
        model = load(&ckpt).with_context(|| format!("resuming from {}", ckpt.display()))?;
        optimizer = load_optimizer(optimizer, ckpt.join("optimizer.bpk"))
            .with_context(|| format!("resuming from {}", ckpt.display()))?;
        start = progress.epochs_done;
    }
    let steps_per_epoch = num_examples.div_ceil(optim.batch_size);
    let total_steps = steps_per_epoch * optim.epochs;
    for epoch in start..optim.epochs {
        let started = Instant::now();
        let mut rng = ChaCha8Rng::seed_from_u64(
            optim.seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let mut order: Vec<usize> = (0..num_examples).collect();
        order.shuffle(&mut rng);
        let mut sums: Vec<f32> = Vec::new();
        let mut edges = EdgeCounts::default();
        let mut steps = 0usize;
        for chunk in order.chunks(optim.batch_size) {
            let report = step(&model, chunk, &mut rng)?;
            if sums.is_empty() {
                sums = vec![0.0; report.values.len()];
            }
            for (s, v) in sums.iter_mut().zip(&report.values) {
                *s += v;
            }
            edges.true_positives += report.edges.true_positives;
            edges.false_positives += report.edges.false_positives;
            edges.false_negatives += report.edges.false_negatives;
            steps += 1;
            let grads = GradientsParams::from_grads(report.loss.backward(), &model);
            let rate = optim.learning_rate_at(epoch * steps_per_epoch + steps - 1, total_steps);
            model = optimizer.step(rate, model, grads);
        }
        let means: Vec<f32> = sums.iter().map(|s| s / steps as f32).collect();
        let loss = means.first().copied().unwrap_or(f32::NAN);
        if !loss.is_finite() {
            bail!("training diverged at epoch {epoch} (loss {loss})");
        }
        save(&model, &ckpt)?;
        save_optimizer(&optimizer, ckpt.join("optimizer.bpk"))?;
        RunDir::write_json(
            &progress_path,
            &EpochsDone {
                epochs_done: epoch + 1,
            },
        )?;
        finish(epoch, &means, &edges, started.elapsed().as_secs_f32())?;
    }
    Ok(model)
}

fn scalar(t: Tensor<1>) -> anyhow::Result<f32> {
    Ok(to_vec(t)?.first().copied().unwrap_or(f32::NAN))
}

/// The demos of each task, to draw partners from; errors if a task has one.
fn demos_by_task(dataset: &DemoDataset) -> anyhow::Result<BTreeMap<usize, Vec<usize>>> {
    let mut by_task: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, d) in dataset.demos().iter().enumerate() {
        by_task.entry(d.task).or_default().push(i);
    }
    if let Some((task, _)) = by_task.iter().find(|(_, v)| v.len() < 2) {
        bail!(
            "task {task} has a single demonstration; training pairs a demo with another of its task"
        );
    }
    Ok(by_task)
}

/// Another demo of the same task as demo `i`, drawn with `rng`.
fn partner(
    by_task: &BTreeMap<usize, Vec<usize>>,
    dataset: &DemoDataset,
    i: usize,
    rng: &mut ChaCha8Rng,
) -> usize {
    let others: Vec<usize> = by_task[&dataset.demos()[i].task]
        .iter()
        .copied()
        .filter(|&j| j != i)
        .collect();
    *others.choose(rng).unwrap_or(&i)
}

fn demo_rows(dataset: &DemoDataset, i: usize) -> Vec<Vec<f32>> {
    dataset.demos()[i].rows().map(|r| dataset.row(r)).collect()
}

/// Trains a Flat Policy (on an autodiff device) for the epochs not yet
/// done, checkpointing into `run` after each. Each example imitates one
/// demonstration conditioned on another demonstration of the same task
/// (drawn with the epoch's generator), as in Duan et al. Reads `config`'s
/// `optim`, `learn_end` and `memory`.
pub fn train_flat(
    policy: FlatPolicy,
    dataset: &DemoDataset,
    config: &CollectRunConfig,
    run: &RunDir,
    device: &Device,
    mut on_epoch: impl FnMut(&FlatEpochMetrics),
) -> anyhow::Result<FlatPolicy> {
    let n = policy.num_nodes();
    dataset.check_num_nodes(n, "policy")?;
    let by_task = demos_by_task(dataset)?;
    let dim = dataset.obs_dim();
    let (learn_end, memory) = (config.learn_end, config.memory);
    fit(
        policy,
        dataset.demos().len(),
        &config.optim,
        run,
        |dir| Ok(FlatPolicy::load(dir, device)?),
        |p, dir| Ok(p.save(dir)?),
        |policy, chunk, rng| {
            let owned: Vec<_> = chunk
                .iter()
                .map(|&i| {
                    let entry = &dataset.demos()[i];
                    let mut next = entry.actions.clone();
                    let mut queries = demo_rows(dataset, i);
                    if learn_end {
                        next.push(Vocabulary::END);
                    } else {
                        queries.pop();
                    }
                    let cond = partner(&by_task, dataset, i, rng);
                    (demo_rows(dataset, cond), queries, next)
                })
                .collect();
            let examples: Vec<FlatExample<'_, Vec<f32>>> = owned
                .iter()
                .map(|(d, q, t)| (&d[..], &q[..], &t[..]))
                .collect();
            let mut batch = FlatBatch::new(&examples, dim, n, device)?;
            if memory {
                // Before query `t` the agent has taken the first `t` actions.
                let memories: Vec<Vec<Vec<f32>>> = owned
                    .iter()
                    .map(|(_, q, t)| (0..q.len()).map(|k| executed_actions(n, &t[..k])).collect())
                    .collect();
                batch = batch.with_memory(&memories, n)?;
            }
            let out = policy.loss(&batch)?;
            Ok(StepReport {
                values: vec![scalar(out.loss.clone())?, out.accuracy],
                loss: out.loss,
                edges: EdgeCounts::default(),
            })
        },
        |epoch, means, _, seconds| {
            let metrics = FlatEpochMetrics {
                epoch,
                loss: means[0],
                step_accuracy: means[1],
                seconds,
            };
            run.append_metrics(&metrics)?;
            on_epoch(&metrics);
            Ok(())
        },
    )
}

/// Trains NTG's four networks jointly on the paper's targets, like
/// [`crate::train::train`], except that the GCN (and so the edge
/// classifier's `NE_gcn`) reads the path of *another* demonstration of the
/// same task than the one whose observations and next actions the
/// localizer and edge classifier are trained on.
///
/// Why: at test time the graph comes from the conditioning demo and the
/// policy acts in another scene, where objects are found in another order.
/// Trained on its own demo's path, the edge classifier learns that the
/// node before `<end>` in *that* path ends the task (e.g. the last
/// receptacle of the demo), and at test time ends the episode as soon as
/// it reaches that node, whatever is still undelivered. Pairing demos
/// makes the graph carry what the task is, not the order this episode
/// happens to take.
///
/// Also reads `config`'s `segments` (the interpreter also learns from a
/// random stretch of each demo), `learn_end` (whether the edge classifier
/// learns the final `<end>`), `memory` (whether it reads the task-graph
/// nodes not yet executed) and `optim`.
pub fn train_ntg(
    model: NtgModel,
    dataset: &DemoDataset,
    config: &CollectRunConfig,
    run: &RunDir,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochMetrics),
) -> anyhow::Result<NtgModel> {
    let n = model.num_nodes();
    dataset.check_num_nodes(n, "model")?;
    let graphs = task_graphs(dataset)?;
    let by_task = demos_by_task(dataset)?;
    let (segments, learn_end, memory) = (config.segments, config.learn_end, config.memory);
    fit(
        model,
        dataset.demos().len(),
        &config.optim,
        run,
        |dir| Ok(NtgModel::load(dir, device)?),
        |m, dir| Ok(m.save(dir)?),
        |model, chunk, rng| {
            let partners: Vec<usize> = chunk
                .iter()
                .map(|&i| partner(&by_task, dataset, i, rng))
                .collect();
            let segments: Vec<(usize, usize)> = if segments {
                chunk
                    .iter()
                    .map(|&i| {
                        let k = dataset.demos()[i].actions.len();
                        let start = rng.random_range(0..k);
                        (start, rng.random_range(start + 1..=k))
                    })
                    .collect()
            } else {
                Vec::new()
            };
            let draw = StepDraw { partners, segments };
            let labels = Labels { learn_end, memory };
            ntg_step(model, dataset, &graphs, chunk, &draw, labels, device)
        },
        |epoch, m, edges, seconds| {
            let metrics = EpochMetrics {
                epoch,
                loss: m[0],
                interpreter_loss: m[1],
                token_accuracy: m[2],
                gcn_loss: m[3],
                edge_f1: crate::train::edge_f1_of(edges),
                localizer_loss: m[4],
                localizer_accuracy: m[5],
                edge_loss: m[6],
                step_accuracy: m[7],
                seconds,
            };
            run.append_metrics(&metrics)?;
            on_epoch(&metrics);
            Ok(())
        },
    )
}

/// What an NTG step drew: the partner demo of each demo of the chunk, and
/// (with segments) the stretch `start..end` of its actions the interpreter
/// also reads.
struct StepDraw {
    partners: Vec<usize>,
    segments: Vec<(usize, usize)>,
}

/// What an NTG step trains besides the paper's targets: the final `<end>`
/// decision, and the edge classifier's execution memory.
#[derive(Debug, Clone, Copy)]
struct Labels {
    learn_end: bool,
    memory: bool,
}

/// One NTG step: demo `chunk[b]` trains the interpreter, the localizer and
/// the edge classifier; the GCN completes the path of demo `partners[b]`
/// (same task) into the task graph and gives the edge classifier `NE_gcn`.
fn ntg_step(
    model: &NtgModel,
    dataset: &DemoDataset,
    graphs: &BTreeMap<usize, Ctg>,
    chunk: &[usize],
    draw: &StepDraw,
    labels: Labels,
    device: &Device,
) -> anyhow::Result<StepReport> {
    let Labels { learn_end, memory } = labels;
    let (partners, segments) = (&draw.partners, &draw.segments);
    let n = model.num_nodes();
    let dim = dataset.obs_dim();
    let entries: Vec<_> = chunk.iter().map(|&i| &dataset.demos()[i]).collect();
    let rows: Vec<Vec<Vec<f32>>> = chunk.iter().map(|&i| demo_rows(dataset, i)).collect();

    // The interpreter reads each demo whole, and (with segments) one
    // contiguous stretch of it: actions `start..end` with the frames
    // `start..=end` around them.
    let mut pairs: Vec<(&[Vec<f32>], &[ActionId])> = entries
        .iter()
        .zip(&rows)
        .map(|(e, r)| (r.as_slice(), e.actions.as_slice()))
        .collect();
    for ((e, r), &(start, end)) in entries.iter().zip(&rows).zip(segments) {
        pairs.push((&r[start..=end], &e.actions[start..end]));
    }
    let interp = model
        .interpreter
        .loss(&DemoBatch::new(&pairs, dim, n, device)?)?;

    let targets: Vec<&Ctg> = entries.iter().map(|e| &graphs[&e.task]).collect();
    let paths: Vec<Ctg> = partners
        .iter()
        .map(|&p| Ctg::from_path(n, &dataset.demos()[p].actions))
        .collect::<Result<_, _>>()?;
    let path_refs: Vec<&Ctg> = paths.iter().collect();
    let (gcn_loss, ne_gcn, edges) = if model.config().ablation.gcn {
        let target_adj = adjacency_tensor(&targets, n, device)?;
        let out = model
            .gcn
            .forward(adjacency_tensor(&path_refs, n, device)?)?;
        let loss = model.gcn.loss(&out, target_adj.clone())?;
        let edges = EdgeCounts::count_tensors(out.adjacency.clone(), target_adj, 0.5)?;
        (Some(loss), out.embeddings, edges)
    } else {
        let ne = model.gcn.initial_embeddings(entries.len());
        (None, ne, EdgeCounts::default())
    };

    // Localizer: every frame. Edge classifier: every frame with a next
    // action, the final `<end>` decision only if `learn_end`.
    // With a memory, the edge classifier also reads which nodes of the
    // task graph the agent has not executed yet: the graph is the partner
    // demo's path (what the conditioning demo shows at test time), the
    // executed actions those before the frame.
    let (mut obs, mut nodes) = (Vec::new(), Vec::new());
    let (mut e_obs, mut e_nodes, mut e_next, mut e_demo, mut e_graphs) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut e_memory: Vec<Vec<f32>> = Vec::new();
    for (b, (e, r)) in entries.iter().zip(&rows).enumerate() {
        let labels = std::iter::once(Vocabulary::START).chain(e.actions.iter().copied());
        let nexts = e.actions.iter().copied().chain([Vocabulary::END]);
        for (t, ((o, node), nx)) in r.iter().zip(labels).zip(nexts).enumerate() {
            obs.push(o);
            nodes.push(node);
            if learn_end || nx != Vocabulary::END {
                e_obs.push(o);
                e_nodes.push(node);
                e_next.push(nx);
                e_demo.push(b as i64);
                e_graphs.push(targets[b]);
                if memory {
                    e_memory.push(pending_nodes(&paths[b], &e.actions[..t]));
                }
            }
        }
    }
    let loc = model.localizer.loss(
        model.localizer.forward(rows_tensor(&obs, dim, device)?)?,
        ids_tensor(&nodes, n, device)?,
    )?;
    let index = Tensor::<1, Int>::from_data(TensorData::new(e_demo, [e_obs.len()]), device);
    let mask = successor_mask(&e_graphs, &e_nodes, Some(&e_next), n, device)?;
    let e_memory = if memory {
        Some(rows_tensor(&e_memory, n, device)?)
    } else {
        None
    };
    let edge_logits = model.edges.forward_with_memory(
        rows_tensor(&e_obs, dim, device)?,
        ids_tensor(&e_nodes, n, device)?,
        ne_gcn.select(0, index),
        model.localizer.node_embeddings(),
        mask,
        e_memory,
    )?;
    let edge = model
        .edges
        .loss(edge_logits, ids_tensor(&e_next, n, device)?)?;

    let gcn_value = match &gcn_loss {
        Some(l) => scalar(l.clone())?,
        None => 0.0,
    };
    let mut total = interp.loss.clone() + loc.loss.clone() + edge.loss.clone();
    if let Some(l) = gcn_loss {
        total = total + l;
    }
    Ok(StepReport {
        values: vec![
            scalar(total.clone())?,
            scalar(interp.loss)?,
            interp.accuracy,
            gcn_value,
            scalar(loc.loss)?,
            loc.accuracy,
            scalar(edge.loss)?,
            edge.accuracy,
        ],
        loss: total,
        edges,
    })
}

/// Loads the trained model of a run (inference device).
pub fn load_model(run: &RunDir, config: &CollectRunConfig) -> anyhow::Result<CollectModel> {
    let device = ntg_model::cpu_device();
    let dir = run.checkpoint_dir();
    let context = || format!("{} has no trained model yet", run.root().display());
    Ok(match config.method {
        Method::Ntg => CollectModel::Ntg(NtgModel::load(&dir, &device).with_context(context)?),
        Method::Flat => CollectModel::Flat(FlatPolicy::load(&dir, &device).with_context(context)?),
    })
}

/// One evaluated test episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// Number of target objects.
    pub objects: usize,
    /// Episode index among those with this N.
    pub index: usize,
    /// The task, e.g. `Apple->Fridge Egg->Sink`.
    pub task: String,
    /// Whether every target was in its receptacle at the end.
    pub success: bool,
    /// Actions taken (`<end>` included if chosen).
    pub steps: usize,
    /// The executed actions, by name.
    pub trace: Vec<String>,
    /// NTG only: the demo interpreter's transcription of the demo.
    pub transcription: Vec<String>,
    /// The expert's actual actions in the conditioning demo.
    pub demo_actions: Vec<String>,
}

/// Success at one N.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NPoint {
    /// Number of target objects.
    pub objects: usize,
    /// Success rate over the test episodes, with its 95% Wilson interval.
    pub success: SuccessRate,
    /// Episodes that ended by the policy choosing `<end>` (the others ran
    /// to the step limit). Absent in evaluations saved before it: 0.
    #[serde(default)]
    pub ended: usize,
}

/// The evaluation of one model on unseen tasks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CollectEval {
    /// Which method.
    pub method: Method,
    /// Success per N.
    pub points: Vec<NPoint>,
    /// Every episode.
    pub episodes: Vec<EpisodeRecord>,
}

/// The test episodes with `n` objects: `(task, demo seed, rollout seed)`;
/// tasks cycle through the test side's tasks with `n` objects in a seeded
/// order (there are few with N = 1, so those repeat with other scenes).
pub fn test_episodes(n: usize, episodes: usize) -> anyhow::Result<Vec<(Task, u64, u64)>> {
    let splitter = env_collect::TaskSplitter::default();
    let mut pool = splitter.tasks_with(n, Some(Split::Test))?;
    ensure!(!pool.is_empty(), "no test task with {n} objects");
    pool.shuffle(&mut ChaCha8Rng::seed_from_u64(TEST_TASK_SEED + n as u64));
    Ok((0..episodes)
        .map(|i| {
            let k = 1000 * n as u64 + i as u64;
            (
                pool[i % pool.len()].clone(),
                DEMO_SEED_BASE + k,
                ROLLOUT_SEED_BASE + k,
            )
        })
        .collect())
}

fn names(ids: &[ActionId]) -> Vec<String> {
    let vocab = env_collect::vocabulary();
    ids.iter()
        .map(|&a| vocab.name(a).unwrap_or("?").to_owned())
        .collect()
}

fn run_episode(
    model: &CollectModel,
    obs: ObsKind,
    n: usize,
    index: usize,
    (task, demo_seed, rollout_seed): &(Task, u64, u64),
) -> anyhow::Result<EpisodeRecord> {
    let mut env = CollectEnv::new(task.clone(), env_config(obs))?;
    let demo = record_demonstration(&mut env, &mut CollectExpert, *demo_seed)
        .with_context(|| format!("demo of test task {task}"))?;
    let rows: Vec<Vec<f32>> = demo
        .observations()
        .iter()
        .map(|o| featurize(o, obs))
        .collect();
    let (trace, transcription, success) = match model {
        CollectModel::Ntg(model) => {
            // The executor's greedy rollout (`GraphExecutor::run`), telling
            // the policy before each step which actions it has taken (a
            // no-op without a memory).
            let policy = NtgPolicy::from_demo(model, &rows, env_collect::vocabulary())?;
            let mapped = policy.mapped(|o: &CollectObservation| featurize(o, obs));
            let executor = policy.executor();
            let (mut o, _) = env.reset(*rollout_seed)?;
            let mut trace = Vec::new();
            loop {
                policy.set_executed(&trace);
                let action = executor
                    .action_distribution(&mut &mapped, &mut &mapped, &o)
                    .with_context(|| format!("rollout of test task {task}"))?
                    .most_likely();
                trace.push(action);
                let step = env.step(action)?;
                let done = step.is_done();
                o = step.observation;
                if done {
                    break;
                }
            }
            (trace, names(policy.demo_actions()), env.is_success())
        }
        CollectModel::Flat(policy) => {
            let memory = policy.memory_dim() > 0;
            let n = policy.num_nodes();
            let policy = policy.condition(&rows)?;
            let (mut o, _) = env.reset(*rollout_seed)?;
            let mut trace = Vec::new();
            loop {
                let m = memory.then(|| executed_actions(n, &trace));
                let action = policy.next_action_with_memory(&featurize(&o, obs), m.as_deref())?;
                trace.push(action);
                let step = env.step(action)?;
                let done = step.is_done();
                o = step.observation;
                if done {
                    break;
                }
            }
            (trace, Vec::new(), env.is_success())
        }
    };
    Ok(EpisodeRecord {
        objects: n,
        index,
        task: task.to_string(),
        success,
        steps: trace.len(),
        trace: names(&trace),
        transcription,
        demo_actions: names(demo.actions()),
    })
}

/// Evaluates `model` on `episodes` unseen test episodes for each N in
/// `objects`, in parallel.
pub fn evaluate(
    model: &CollectModel,
    method: Method,
    obs: ObsKind,
    objects: &[usize],
    episodes: usize,
) -> anyhow::Result<CollectEval> {
    let mut jobs = Vec::new();
    for &n in objects {
        for (i, ep) in test_episodes(n, episodes)?.into_iter().enumerate() {
            jobs.push((n, i, ep));
        }
    }
    let bar = progress_bar(jobs.len() as u64, "rollouts");
    let model = match model {
        CollectModel::Ntg(m) => CollectModel::Ntg(m.valid()),
        CollectModel::Flat(p) => CollectModel::Flat(p.valid()),
    };
    let records: Vec<EpisodeRecord> = jobs
        .par_iter()
        .map(|(n, i, ep)| {
            let r = run_episode(&model, obs, *n, *i, ep);
            bar.inc(1);
            r
        })
        .collect::<anyhow::Result<_>>()?;
    bar.finish_and_clear();
    let points = objects
        .iter()
        .map(|&n| NPoint {
            objects: n,
            success: SuccessRate::from_outcomes(
                records.iter().filter(|r| r.objects == n).map(|r| r.success),
            ),
            ended: records
                .iter()
                .filter(|r| r.objects == n && r.trace.last().map(String::as_str) == Some("<end>"))
                .count(),
        })
        .collect();
    Ok(CollectEval {
        method,
        points,
        episodes: records,
    })
}

/// The scale of fig. "thor_all" under a profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThorAllScale {
    /// Observation kind.
    pub obs: ObsKind,
    /// Training tasks per N (N = 2 and 4).
    pub tasks_per_n: usize,
    /// Demonstrations per training task.
    pub demos_per_task: usize,
    /// Whether both methods learn the final `<end>` decision (the paper's
    /// protocol: an episode ends when the policy says so, or at the step
    /// limit); otherwise episodes always run to the step limit.
    #[serde(default)]
    pub learn_end: bool,
    /// Whether both methods have the execution memory
    /// ([`CollectRunConfig::memory`]).
    #[serde(default)]
    pub memory: bool,
    /// NTG's training epochs (learning rate on a half cosine per step down
    /// to a tenth, [`OptimConfig::cosine_decay`]: at a constant rate Adam
    /// blew the converged interpreter up late in training).
    pub ntg_epochs: usize,
    /// The Flat Policy's training epochs (constant learning rate: with the
    /// cosine decay its attention never learned to retrieve the receptacle).
    pub flat_epochs: usize,
    /// Demonstrations per optimisation step.
    pub batch_size: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Test episodes per N.
    pub test_episodes: usize,
}

/// The scale of fig. "thor_all" under `profile`.
pub fn thor_all_scale(profile: Profile) -> ThorAllScale {
    match profile {
        Profile::Smoke => ThorAllScale {
            obs: ObsKind::State,
            learn_end: true,
            memory: true,
            tasks_per_n: 4,
            demos_per_task: 2,
            ntg_epochs: 1,
            flat_epochs: 1,
            batch_size: 32,
            learning_rate: 3e-3,
            test_episodes: 4,
        },
        Profile::Quick => ThorAllScale {
            obs: ObsKind::State,
            learn_end: true,
            memory: true,
            tasks_per_n: 200,
            demos_per_task: 3,
            ntg_epochs: 30,
            flat_epochs: 50,
            batch_size: 32,
            learning_rate: 3e-3,
            // Evaluation costs about a second on the state input; 1000
            // episodes per N resolve differences of a few percent near 1.0
            // (with 50, NTG and the Flat Policy tied at 1.00 at N = 1).
            test_episodes: 1000,
        },
        Profile::Paper => ThorAllScale {
            obs: ObsKind::Vid,
            learn_end: true,
            memory: true,
            tasks_per_n: 400,
            demos_per_task: 20,
            ntg_epochs: 30,
            flat_epochs: 50,
            batch_size: 32,
            learning_rate: 3e-3,
            test_episodes: 1000,
        },
    }
}

/// One method's line of fig. "thor_all".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThorAllLine {
    /// Which method.
    pub method: Method,
    /// Success per N on unseen tasks.
    pub points: Vec<NPoint>,
    /// Seconds spent in training epochs (summed from the run's
    /// `metrics.jsonl`, so a reused run reports its original cost).
    pub train_seconds: f64,
    /// Run folder.
    pub run: PathBuf,
}

/// Fig. "thor_all" (b) as measured (`results.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThorAllResult {
    /// The scale.
    pub scale: ThorAllScale,
    /// Numbers of objects trained on.
    pub train_objects: Vec<usize>,
    /// NTG and the Flat Policy.
    pub lines: Vec<ThorAllLine>,
}

/// Runs fig. "thor_all" at `profile`: trains both methods (finished runs
/// under `runs` are reused, interrupted ones resumed) and evaluates them.
pub fn thor_all(profile: Profile, runs: &Path) -> anyhow::Result<ThorAllResult> {
    let scale = thor_all_scale(profile);
    let train_objects = vec![2, 4];
    let mut lines = Vec::new();
    for method in [Method::Ntg, Method::Flat] {
        let config = CollectRunConfig {
            domain: "collect".into(),
            method,
            obs: scale.obs,
            train_objects: train_objects.clone(),
            tasks_per_n: scale.tasks_per_n,
            demos_per_task: scale.demos_per_task,
            segments: true,
            learn_end: scale.learn_end,
            memory: scale.memory,
            interpreter: InterpreterKind::Stepping,
            location_step_prior: match method {
                Method::Ntg => InterpreterKind::Stepping.default_step_prior(),
                Method::Flat => None,
            },
            model_seed: 0,
            optim: OptimConfig {
                epochs: match method {
                    Method::Ntg => scale.ntg_epochs,
                    Method::Flat => scale.flat_epochs,
                },
                batch_size: scale.batch_size,
                learning_rate: scale.learning_rate,
                seed: 0,
                token_dropout: 0.0,
                cosine_decay: method == Method::Ntg,
                gcn_from_other_demo: false,
            },
        };
        let dir = runs.join(format!("thor_all-{}", method.name()));
        let run = open_or_create(&dir, &config)?;
        eprintln!(
            "thor_all ({}): training -> {}",
            method.name(),
            dir.display()
        );
        let device = ntg_model::cpu_device().autodiff();
        let model = train_run(&run, &config, &device, |p| eprintln!("  {}", p.line()))?;
        let eval_path = run
            .eval_dir()
            .join(format!("collect-{}.json", scale.test_episodes));
        let eval = match cached(&run, &eval_path)? {
            Some(eval) => eval,
            None => {
                let eval = evaluate(
                    &model,
                    method,
                    scale.obs,
                    &EVAL_OBJECTS,
                    scale.test_episodes,
                )?;
                std::fs::create_dir_all(run.eval_dir())?;
                RunDir::write_json(&eval_path, &eval)?;
                eval
            }
        };
        for p in &eval.points {
            eprintln!(
                "  N = {}: success {:.3} ({:.3}-{:.3})",
                p.objects, p.success.rate, p.success.ci_low, p.success.ci_high
            );
        }
        lines.push(ThorAllLine {
            method,
            points: eval.points,
            train_seconds: metrics_seconds(&run)?,
            run: dir,
        });
    }
    Ok(ThorAllResult {
        scale,
        train_objects,
        lines,
    })
}

/// Opens the run at `dir` if it holds `config`, creates it if absent, and
/// errors if it holds another configuration.
pub fn open_or_create(dir: &Path, config: &CollectRunConfig) -> anyhow::Result<RunDir> {
    if dir.join("config.json").is_file() {
        let run = RunDir::open(dir)?;
        let saved: CollectRunConfig = RunDir::read_json(&run.config_path())?;
        if &saved != config {
            bail!(
                "{} holds a run with another configuration; move it away or delete it",
                dir.display()
            );
        }
        Ok(run)
    } else {
        let run = RunDir::create(dir)?;
        RunDir::write_json(&run.config_path(), config)?;
        Ok(run)
    }
}

/// The evaluation saved at `path`, if written after the run's last checkpoint.
fn cached(run: &RunDir, path: &Path) -> anyhow::Result<Option<CollectEval>> {
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    let checkpoint = run.checkpoint_dir().join("progress.json");
    match (modified(path), modified(&checkpoint)) {
        (Some(eval), Some(ckpt)) if eval >= ckpt => Ok(Some(RunDir::read_json(path)?)),
        _ => Ok(None),
    }
}

/// Sum of the `seconds` of every line of a run's `metrics.jsonl`.
pub fn metrics_seconds(run: &RunDir) -> anyhow::Result<f64> {
    let path = run.metrics_path();
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut total = 0.0;
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("{}: line {} is not JSON", path.display(), i + 1))?;
        total += v
            .get("seconds")
            .and_then(|s| s.as_f64())
            .with_context(|| format!("{}: line {} has no \"seconds\"", path.display(), i + 1))?;
    }
    Ok(total)
}

/// Writes the figure (one panel, success vs N for both methods) as
/// `stem.svg` and `stem.png`.
pub fn write_thor_all_figure(result: &ThorAllResult, stem: &Path) -> anyhow::Result<()> {
    let panel = Panel {
        title: format!(
            "(b) object collection, {} input",
            obs_name(result.scale.obs)
        ),
        x_label: "number of target objects N".into(),
        y_label: "success on unseen tasks".into(),
        x_log: false,
        x_ticks_at_points: true,
        y_range: (0.0, 1.0),
        series: result
            .lines
            .iter()
            .map(|l| Series {
                name: l.method.legend().into(),
                points: l
                    .points
                    .iter()
                    .map(|p| Point {
                        x: p.objects as f64,
                        y: p.success.rate,
                        lo: p.success.ci_low,
                        hi: p.success.ci_high,
                    })
                    .collect(),
            })
            .collect(),
    };
    write_figure(&[panel], stem)
}

fn obs_name(obs: ObsKind) -> &'static str {
    match obs {
        ObsKind::State => "symbolic state",
        ObsKind::Vid => "64×64 frame",
    }
}

/// The protocol sentence of the report: how episodes end and what the
/// policies remember.
fn protocol(sc: &ThorAllScale) -> &'static str {
    match (sc.learn_end, sc.memory) {
        (true, true) => {
            "the final `<end>` is a learned action, as in the paper (an episode ends when the policy chooses `<end>`, or at the step limit of twice the expert's worst case; success is judged then); since a single observation cannot show whether every target has been delivered, both policies have an execution memory, the actions they have taken so far in the episode (the Flat Policy adds them to its attention query, NTG's edge classifier reads the nodes of its task graph it has not executed yet; without it, both end episodes too early: see the README);"
        }
        (true, false) => {
            "the final `<end>` is a learned action, as in the paper (an episode ends when the policy chooses `<end>`, or at the step limit); both policies are reactive (no memory), so they cannot see from the last frame whether every target has been delivered;"
        }
        (false, _) => {
            "the final `<end>` decision is not trained (the last frame cannot show whether every target has been delivered), so episodes end at the step limit, where success is judged;"
        }
    }
}

/// The report section of fig. "thor_all" (Markdown).
pub fn report_section(result: &ThorAllResult) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let sc = &result.scale;
    let _ = writeln!(
        s,
        "## Fig. thor_all (b): object collection, generalising to other numbers of objects\n\n![thor_all](thor_all.png)\n"
    );
    let _ = writeln!(
        s,
        "Input: **the {}**{}. Trained on N = {:?} only: {} training-side tasks per N × {} demos, batch {}, Adam at {} (NTG: {} epochs, the rate decaying per step along a half cosine to a tenth; Flat Policy: {} epochs at a constant rate; each the setting under which it trained well), seed 0. Tested on {} episodes per N (tasks from the held-out side of the split; the conditioning demo and the rollout are different scenes).\n\nProtocol (both methods, see `ntg_trainer::collect`): {} each training demo is imitated while conditioned on *another* demo of its task (the Flat Policy attends over it; NTG's GCN completes its path, whose `NE_gcn` the edge classifier reads), as at test time; NTG's demo interpreter is the paper's seq2seq with Luong attention made length-independent (local annotations, input feeding, location-aware attention whose weights start biased towards the next frame (`--location-step-prior`, 0.3: without it one seed in four never learned to step), a decoder without memory; `--interpreter luong` trains the paper's) and also learns from one random contiguous stretch of each demo.\n",
        obs_name(sc.obs),
        if sc.obs == ObsKind::State {
            ", not the 64×64 frames: the frame encoders are too slow to train on 2 CPU cores within this profile's budget (`ntg train --domain collect --obs vid` trains on frames)"
        } else {
            ""
        },
        result.train_objects,
        sc.tasks_per_n,
        sc.demos_per_task,
        sc.batch_size,
        sc.learning_rate,
        sc.ntg_epochs,
        sc.flat_epochs,
        sc.test_episodes,
        protocol(sc),
    );
    let _ = write!(s, "| method | training time |");
    for n in EVAL_OBJECTS {
        let _ = write!(s, " N = {n} |");
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "|---|---|{}", "---|".repeat(EVAL_OBJECTS.len()));
    for line in &result.lines {
        let _ = write!(
            s,
            "| {} | {:.0} s |",
            line.method.legend(),
            line.train_seconds
        );
        for p in &line.points {
            let _ = write!(
                s,
                " {}/{} = {:.3} ({:.3}–{:.3}){} |",
                p.success.successes,
                p.success.trials,
                p.success.rate,
                p.success.ci_low,
                p.success.ci_high,
                if sc.learn_end {
                    format!("; {} ended by `<end>`", p.ended)
                } else {
                    String::new()
                }
            );
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(
        s,
        "\nPaper's trend: NTG well above the Flat Policy at every N, including N = 1, 3 and 5, never trained on.\n"
    );
    if let Some(sentence) = comparison_sentence(result) {
        let _ = writeln!(s, "{sentence}\n");
    }
    s
}

/// How NTG's success compares with the Flat Policy's at each N, read off
/// the measured points: above with disjoint 95% intervals, above within
/// overlapping intervals, tied, or below. `None` when a method is missing.
pub fn comparison_sentence(result: &ThorAllResult) -> Option<String> {
    let line = |m: Method| result.lines.iter().find(|l| l.method == m);
    let (ntg, flat) = (line(Method::Ntg)?, line(Method::Flat)?);
    let mut groups: [(&str, Vec<usize>); 4] = [
        ("above, with disjoint 95% intervals", Vec::new()),
        ("above, within overlapping intervals", Vec::new()),
        ("tied", Vec::new()),
        ("below", Vec::new()),
    ];
    for p in &ntg.points {
        let Some(q) = flat.points.iter().find(|q| q.objects == p.objects) else {
            continue;
        };
        let (a, b) = (&p.success, &q.success);
        let group = if a.rate > b.rate && a.ci_low > b.ci_high {
            0
        } else if a.rate > b.rate {
            1
        } else if a.rate == b.rate {
            2
        } else {
            3
        };
        groups[group].1.push(p.objects);
    }
    let parts: Vec<String> = groups
        .iter()
        .filter(|(_, ns)| !ns.is_empty())
        .map(|(what, ns)| {
            let ns: Vec<String> = ns.iter().map(usize::to_string).collect();
            format!("{what} at N = {}", ns.join(", "))
        })
        .collect();
    Some(format!("Measured: NTG's success is {}.", parts.join("; ")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(method: Method, successes: &[usize], trials: usize) -> ThorAllLine {
        ThorAllLine {
            method,
            points: successes
                .iter()
                .enumerate()
                .map(|(i, &k)| NPoint {
                    objects: i + 1,
                    success: SuccessRate::new(k, trials),
                    ended: 0,
                })
                .collect(),
            train_seconds: 0.0,
            run: PathBuf::new(),
        }
    }

    #[test]
    fn comparison_sentence_groups_each_n_by_its_intervals() {
        let result = ThorAllResult {
            scale: thor_all_scale(Profile::Smoke),
            train_objects: vec![2, 4],
            lines: vec![
                line(Method::Ntg, &[1000, 999, 500, 400, 997], 1000),
                line(Method::Flat, &[997, 900, 500, 600, 0], 1000),
            ],
        };
        assert_eq!(
            comparison_sentence(&result).unwrap(),
            "Measured: NTG's success is above, with disjoint 95% intervals at N = 2, 5; \
             above, within overlapping intervals at N = 1; tied at N = 3; below at N = 4."
        );
        let only_ntg = ThorAllResult {
            lines: result.lines[..1].to_vec(),
            ..result
        };
        assert_eq!(comparison_sentence(&only_ntg), None);
    }

    fn config(method: Method, epochs: usize) -> CollectRunConfig {
        CollectRunConfig {
            domain: "collect".into(),
            method,
            obs: ObsKind::State,
            train_objects: vec![1, 2],
            tasks_per_n: 3,
            demos_per_task: 2,
            segments: true,
            learn_end: true,
            memory: true,
            interpreter: InterpreterKind::Stepping,
            location_step_prior: match method {
                Method::Ntg => Some(LOCATION_STEP_PRIOR),
                Method::Flat => None,
            },
            model_seed: 0,
            optim: OptimConfig {
                epochs,
                batch_size: 4,
                learning_rate: 3e-3,
                seed: 1,
                token_dropout: 0.0,
                // A per-step decay depends on the total epochs, which the
                // resume test changes between the two calls.
                cosine_decay: false,
                gcn_from_other_demo: false,
            },
        }
    }

    fn weights(model: &CollectModel) -> Vec<f32> {
        match model {
            CollectModel::Ntg(m) => to_vec(m.edges.w.weight.val()).unwrap(),
            CollectModel::Flat(p) => to_vec(p.out.weight.val()).unwrap(),
        }
    }

    #[test]
    fn train_then_evaluate_both_methods_end_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [Method::Ntg, Method::Flat] {
            let config = config(method, 1);
            let run = open_or_create(&dir.path().join(method.name()), &config).unwrap();
            let model = train_run(&run, &config, &device, |_| {}).unwrap();
            assert!(metrics_seconds(&run).unwrap() > 0.0);
            let eval = evaluate(&model, method, ObsKind::State, &[1, 3], 2).unwrap();
            assert_eq!(eval.episodes.len(), 4);
            assert_eq!(eval.points.len(), 2);
            assert_eq!(eval.points[1].objects, 3);
            assert_eq!(eval.points[1].success.trials, 2);
            for e in &eval.episodes {
                assert!(e.steps >= 1 && e.steps == e.trace.len());
                assert!(!e.demo_actions.is_empty());
                assert_eq!(e.transcription.is_empty(), method == Method::Flat);
            }
            // The saved model is the trained one.
            let loaded = load_model(&run, &config).unwrap();
            assert_eq!(weights(&loaded), weights(&model));
            // Another configuration in the same folder is refused.
            let other = CollectRunConfig {
                tasks_per_n: 4,
                ..config.clone()
            };
            assert!(open_or_create(run.root(), &other).is_err());
        }
    }

    #[test]
    fn resuming_replays_the_same_steps() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [Method::Ntg, Method::Flat] {
            let straight = open_or_create(&dir.path().join("a"), &config(method, 2)).unwrap();
            let a = train_run(&straight, &config(method, 2), &device, |_| {}).unwrap();
            // One epoch, then "resume" the same folder with two.
            let split = dir.path().join("b");
            let first = open_or_create(&split, &config(method, 1)).unwrap();
            train_run(&first, &config(method, 1), &device, |_| {}).unwrap();
            let b = train_run(&first, &config(method, 2), &device, |_| {}).unwrap();
            assert_eq!(weights(&a), weights(&b), "{method:?}");
            std::fs::remove_dir_all(dir.path().join("a")).unwrap();
            std::fs::remove_dir_all(&split).unwrap();
        }
    }

    #[test]
    fn test_episodes_are_unseen_and_seeded() {
        let splitter = env_collect::TaskSplitter::default();
        let train: Vec<Task> = training_tasks(&CollectRunConfig {
            tasks_per_n: 50,
            train_objects: vec![2, 4],
            ..config(Method::Ntg, 1)
        })
        .unwrap();
        assert_eq!(train.len(), 100);
        for n in EVAL_OBJECTS {
            let eps = test_episodes(n, 30).unwrap();
            assert_eq!(eps, test_episodes(n, 30).unwrap());
            for (task, demo_seed, rollout_seed) in &eps {
                assert_eq!(task.num_objects(), n);
                assert_eq!(splitter.split_of(task), Split::Test);
                assert!(!train.contains(task));
                assert_ne!(demo_seed, rollout_seed);
            }
        }
        // Few test tasks with one object: they repeat, in other scenes.
        let ones = test_episodes(1, 30).unwrap();
        let distinct: std::collections::BTreeSet<u32> = ones.iter().map(|e| e.0.code()).collect();
        assert!(distinct.len() < 30);
    }

    #[test]
    fn bad_configurations_are_errors() {
        let mut c = config(Method::Flat, 1);
        c.location_step_prior = Some(0.3);
        assert!(c.validate().unwrap_err().to_string().contains("step prior"));
        let mut c = config(Method::Ntg, 1);
        c.interpreter = InterpreterKind::Luong;
        assert!(c.validate().unwrap_err().to_string().contains("step prior"));
        let mut c = config(Method::Ntg, 1);
        c.location_step_prior = Some(f32::NAN);
        assert!(c.validate().is_err());
        let mut c = config(Method::Flat, 1);
        c.demos_per_task = 1;
        assert!(c.validate().unwrap_err().to_string().contains("2 demos"));
        let mut c = config(Method::Ntg, 1);
        c.train_objects = vec![6];
        assert!(c.validate().is_err());
        let mut c = config(Method::Ntg, 1);
        c.domain = "blocks".into();
        assert!(c.validate().is_err());
        // Asking for more training tasks than the split has.
        let mut c = config(Method::Ntg, 1);
        c.train_objects = vec![1];
        c.tasks_per_n = 41;
        let err = format!("{:#}", training_tasks(&c).unwrap_err());
        assert!(err.contains("1 objects"), "{err}");
    }

    #[test]
    fn runs_without_memory_or_end_still_train_and_evaluate() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [Method::Ntg, Method::Flat] {
            let config = CollectRunConfig {
                learn_end: false,
                memory: false,
                ..config(method, 1)
            };
            let run = open_or_create(&dir.path().join(method.name()), &config).unwrap();
            let model = train_run(&run, &config, &device, |_| {}).unwrap();
            let eval = evaluate(&model, method, ObsKind::State, &[2], 2).unwrap();
            assert_eq!(eval.episodes.len(), 2);
        }
    }

    #[test]
    fn configurations_saved_before_the_memory_load_without_it() {
        let mut json = serde_json::to_value(config(Method::Ntg, 1)).unwrap();
        json.as_object_mut().unwrap().remove("memory");
        let old: CollectRunConfig = serde_json::from_value(json).unwrap();
        assert!(!old.memory);
    }

    #[test]
    fn metrics_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path()).unwrap();
        std::fs::write(run.metrics_path(), "{\"seconds\": 1.5}\nnot json\n").unwrap();
        let err = format!("{:#}", metrics_seconds(&run).unwrap_err());
        assert!(
            err.contains("metrics.jsonl") && err.contains("line 2"),
            "{err}"
        );
        std::fs::write(run.metrics_path(), "{\"seconds\": 1.5}\n{\"seconds\": 2}\n").unwrap();
        assert_eq!(metrics_seconds(&run).unwrap(), 3.5);
    }
}
