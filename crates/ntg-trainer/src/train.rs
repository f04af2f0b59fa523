//! Training the four NTG networks jointly on a [`DemoDataset`], with Adam,
//! seeded, with per-epoch metrics and resumable checkpoints.
//!
//! The targets are the paper's (section 4.3): for each demonstration, the
//! demo interpreter transcribes its observations into its action sequence;
//! the GCN completes its path graph into its task's ground-truth CTG (the
//! union of all demonstrated paths of that task); the localizer maps each
//! observation to the node it sits at (the last action taken); and the edge
//! classifier, given the observation, its node and the GCN's embeddings of
//! the demo's graph, predicts the next action among the node's CTG
//! successors. The four losses are summed and one Adam step updates all.
//! A model with [`NtgConfig::soft_edges`] trains the edge classifier as its
//! policy uses it: a softmax over every node of the fully connected graph,
//! each logit raised by `ln C` of the graph the GCN completed from its
//! input path (that path's edges at 1, floored at
//! [`ntg_model::SOFT_EDGE_FLOOR`], no gradient into the GCN through `C`).
//!
//! Determinism and resuming: epoch `e` shuffles with a generator seeded by
//! `(seed, e)` alone, so a run resumed from the checkpoint of epoch `e - 1`
//! takes exactly the same steps as an uninterrupted one.
//!
//! Model selection: [`train_with`] scores the model after every
//! epoch on held-out tasks (a caller-supplied [`Validator`]) and keeps the
//! best epoch's weights in the run's `best/` folder. How well the demo
//! interpreter transcribes unseen demos swings from epoch to epoch (at 1000
//! block-stacking tasks, 20 and 28 epochs of the same run scored 0.996 and
//! 0.923 held-out token accuracy), so the last epoch is not a safe choice.

use std::collections::BTreeMap;

use anyhow::{Context, bail};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bool, Device, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg};
use ntg_model::nn::to_vec;
use ntg_model::{
    DemoBatch, EdgeCounts, NtgConfig, NtgModel, ids_tensor, load_optimizer, rows_tensor,
    save_optimizer, successor_mask,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::DemoDataset;
use crate::run_dir::RunDir;

/// Optimisation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OptimConfig {
    /// Passes over the dataset.
    pub epochs: usize,
    /// Demonstrations per step.
    pub batch_size: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Seed of the shuffling.
    pub seed: u64,
    /// Probability that the demo interpreter's decoder reads `<start>`
    /// instead of the previous action in training (regularises it towards
    /// reading the demo; 0 = plain teacher forcing).
    #[serde(default)]
    pub token_dropout: f32,
    /// The GCN reads another demo of the same task than the one the edge
    /// classifier imitates (drawn from a seeded generator; the demo itself
    /// when its task has no other). Otherwise the GCN's node embeddings
    /// carry where the imitated demo itself ends or retries, and the edge
    /// classifier learns to copy that instead of reading the observation.
    #[serde(default)]
    pub gcn_from_other_demo: bool,
    /// Decay the learning rate along a half cosine from `learning_rate` to
    /// a tenth of it over the run (per step); off = constant.
    #[serde(default)]
    pub cosine_decay: bool,
}

impl OptimConfig {
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

/// Metrics of one epoch, as logged to `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean total loss.
    pub loss: f32,
    /// Demo interpreter loss.
    pub interpreter_loss: f32,
    /// Demo interpreter token accuracy (teacher forced).
    pub token_accuracy: f32,
    /// GCN binary cross-entropy.
    pub gcn_loss: f32,
    /// GCN edge F1 against the task graphs (threshold 0.5); `None` when no
    /// edges were predicted (the GCN switched off, or a model without one).
    #[serde(default)]
    pub edge_f1: Option<f32>,
    /// Localizer cross-entropy.
    pub localizer_loss: f32,
    /// Localizer accuracy.
    pub localizer_accuracy: f32,
    /// Edge classifier cross-entropy.
    pub edge_loss: f32,
    /// Edge classifier accuracy: the fraction of steps whose next action it
    /// picks (step accuracy).
    pub step_accuracy: f32,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
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

/// Scores a model (on the training device) on held-out tasks after each
/// epoch. It must be deterministic: a resumed run re-scores nothing, it
/// reads earlier scores back from the run folder.
pub trait Validator {
    /// The score of `model`.
    fn validate(&mut self, model: &NtgModel) -> anyhow::Result<ValidationScore>;
}

impl<F: FnMut(&NtgModel) -> anyhow::Result<ValidationScore>> Validator for F {
    fn validate(&mut self, model: &NtgModel) -> anyhow::Result<ValidationScore> {
        self(model)
    }
}

/// The epoch `run`'s `best/` folder holds, if validation selected one.
pub fn selected_epoch(run: &RunDir) -> anyhow::Result<Option<ValidationRecord>> {
    let path = run.best_dir().join("selection.json");
    if path.is_file() {
        Ok(Some(RunDir::read_json(&path)?))
    } else {
        Ok(None)
    }
}

/// How a domain's observations and actions change when its objects are
/// renamed: object `i`'s observation columns are
/// `obs_offset + obs_stride * i ..` (`obs_stride` of them), and each action
/// family (say `pick(·)`) lists its action id for every object. Columns and
/// actions outside these are left alone.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectSymmetry {
    /// Number of interchangeable objects.
    pub num_objects: usize,
    /// First observation column of object 0.
    pub obs_offset: usize,
    /// Observation columns per object.
    pub obs_stride: usize,
    /// Per family, the action id of each object (`num_objects` each).
    pub action_families: Vec<Vec<ActionId>>,
}

/// Most renamings [`ObjectSymmetry::random_accepted`] draws before it gives
/// up.
pub const MAX_RENAMING_DRAWS: usize = 10_000;

/// Decides whether a renaming `perm` (object `i` becomes `perm[i]`) of a
/// demo of dataset task `task` may be trained on (see
/// [`TrainExtras::accept_renaming`]).
pub type RenamingFilter<'a> = &'a (dyn Fn(usize, &[usize]) -> bool + Sync);

/// One renaming of the objects: object `i` becomes `perm[i]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Relabeling {
    perm: Vec<usize>,
    /// Action id -> renamed action id, over the whole vocabulary.
    actions: Vec<ActionId>,
}

impl ObjectSymmetry {
    /// Checks the description against a vocabulary of `num_actions` and
    /// rows of `obs_dim` values.
    pub fn validate(&self, num_actions: usize, obs_dim: usize) -> anyhow::Result<()> {
        if self.obs_offset + self.obs_stride * self.num_objects > obs_dim {
            bail!(
                "the object symmetry covers columns up to {}, rows have {obs_dim}",
                self.obs_offset + self.obs_stride * self.num_objects
            );
        }
        for family in &self.action_families {
            if family.len() != self.num_objects {
                bail!(
                    "an action family of the object symmetry lists {} actions for {} objects",
                    family.len(),
                    self.num_objects
                );
            }
            if let Some(a) = family.iter().find(|a| a.index() >= num_actions) {
                bail!("the object symmetry names action {a:?}; the vocabulary has {num_actions}");
            }
        }
        Ok(())
    }

    /// A uniformly random renaming.
    pub fn random(&self, num_actions: usize, rng: &mut impl Rng) -> Relabeling {
        let mut perm: Vec<usize> = (0..self.num_objects).collect();
        perm.shuffle(rng);
        self.relabeling(perm, num_actions)
    }

    /// A uniformly random renaming among those `accept` takes: drawn again
    /// until one is accepted, an error after [`MAX_RENAMING_DRAWS`] draws.
    pub fn random_accepted(
        &self,
        num_actions: usize,
        rng: &mut impl Rng,
        accept: impl Fn(&[usize]) -> bool,
    ) -> anyhow::Result<Relabeling> {
        for _ in 0..MAX_RENAMING_DRAWS {
            let relabeling = self.random(num_actions, rng);
            if accept(&relabeling.perm) {
                return Ok(relabeling);
            }
        }
        bail!("no acceptable renaming of the objects in {MAX_RENAMING_DRAWS} draws")
    }

    /// The renaming `perm` (object `i` becomes `perm[i]`).
    pub fn relabeling(&self, perm: Vec<usize>, num_actions: usize) -> Relabeling {
        let mut actions: Vec<ActionId> = (0..num_actions).map(ActionId::new).collect();
        for family in &self.action_families {
            for (i, &a) in family.iter().enumerate() {
                actions[a.index()] = family[perm[i]];
            }
        }
        Relabeling { perm, actions }
    }

    /// `row` with object `i`'s columns moved to object `perm[i]`'s place.
    pub fn apply_to_row(&self, relabeling: &Relabeling, row: &[f32]) -> Vec<f32> {
        let mut out = row.to_vec();
        let w = self.obs_stride;
        for (i, &j) in relabeling.perm.iter().enumerate() {
            let from = self.obs_offset + w * i;
            let to = self.obs_offset + w * j;
            out[to..to + w].copy_from_slice(&row[from..from + w]);
        }
        out
    }
}

impl Relabeling {
    /// The renamed action.
    pub fn action(&self, a: ActionId) -> ActionId {
        self.actions[a.index()]
    }

    /// The renamed action sequence.
    pub fn sequence(&self, actions: &[ActionId]) -> Vec<ActionId> {
        actions.iter().map(|&a| self.action(a)).collect()
    }

    /// The graph with its nodes renamed.
    pub fn graph(&self, graph: &Ctg) -> anyhow::Result<Ctg> {
        let mut out = Ctg::empty(graph.num_nodes());
        for e in graph.edges() {
            out.set_weight(self.action(e.from), self.action(e.to), e.weight)?;
        }
        Ok(out)
    }
}

/// Optional parts of training beyond the four losses.
#[derive(Default)]
pub struct TrainExtras<'a> {
    /// Scores every epoch and selects the best (see [`train_with`]).
    pub validator: Option<&'a mut dyn Validator>,
    /// Rename the objects of every training demo by a fresh random
    /// permutation (seeded by the run seed, epoch and step) through this
    /// symmetry: observation columns, actions and task graph consistently.
    /// For domains whose dynamics do not depend on object identity (block
    /// stacking), this shows the networks many more task configurations
    /// than were demonstrated. Not in the paper.
    pub permute_objects: Option<&'a ObjectSymmetry>,
    /// With `permute_objects`: which renamings of a demo of dataset task
    /// `task` may be trained on; the others are drawn again. Block stacking
    /// refuses the renamings that turn a training task into a held-out
    /// (test or validation) one, so no held-out task is ever trained on
    /// under another name. `None` accepts every renaming.
    pub accept_renaming: Option<RenamingFilter<'a>>,
    /// Validate after every this many epochs (and after the last); 0 and 1
    /// mean every epoch.
    pub validate_every: usize,
    /// Weight, in the edge classifier's loss, of the steps whose next
    /// action repeats one the demo already took (recovery after a failure:
    /// re-picking a cube that slipped or fell). Recovery steps are rare, so
    /// with weight 1 the classifier learns to move on. Values ≤ 1 (and the
    /// default 0) mean 1. Not in the paper.
    pub retry_weight: f32,
    /// Stop the edge classifier's loss from flowing into the GCN: the GCN
    /// then learns only to complete task graphs, and the edge classifier
    /// reads its node embeddings as fixed inputs. Trained jointly, the edge
    /// loss also reshapes the GCN's embeddings, and where it is large (the
    /// GCN reading another demo, recovery steps weighted up) it costs the
    /// GCN edges (measured: edge F1 0.93 → 0.78). Not in the paper.
    pub detach_gcn_from_edges: bool,
}

impl EpochMetrics {
    /// One human-readable log line.
    pub fn log_line(&self) -> String {
        format!(
            "epoch {:>3}: loss {:.3} | tokens {:.3} | edge F1 {} | localizer {:.3} | steps {:.3} | {:.1}s",
            self.epoch,
            self.loss,
            self.token_accuracy,
            self.edge_f1_text(),
            self.localizer_accuracy,
            self.step_accuracy,
            self.seconds
        )
    }

    /// The edge F1 for logs: three decimals, or `n/a` without a GCN.
    pub fn edge_f1_text(&self) -> String {
        self.edge_f1
            .map_or_else(|| "n/a".to_owned(), |f| format!("{f:.3}"))
    }
}

/// The edge F1 of an epoch's counts, `None` if nothing was counted (no GCN
/// output was compared: the task graphs are never empty).
pub fn edge_f1_of(counts: &EdgeCounts) -> Option<f32> {
    let counted = counts.true_positives + counts.false_positives + counts.false_negatives;
    (counted > 0).then(|| counts.f1())
}

/// Progress saved with each checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Progress {
    epochs_done: usize,
}

/// The ground-truth CTG of every task in `dataset`: the union of the paths
/// of that task's demonstrations.
pub fn task_graphs(dataset: &DemoDataset) -> anyhow::Result<BTreeMap<usize, Ctg>> {
    let n = dataset.vocabulary().len();
    let mut graphs: BTreeMap<usize, Ctg> = BTreeMap::new();
    for d in dataset.demos() {
        graphs
            .entry(d.task)
            .or_insert_with(|| Ctg::empty(n))
            .add_path(&d.actions)?;
    }
    Ok(graphs)
}

fn scalar(t: Tensor<1>) -> anyhow::Result<f32> {
    Ok(to_vec(t)?.first().copied().unwrap_or(f32::NAN))
}

/// Trains `model` (on an autodiff device) for the epochs not yet done,
/// checkpointing into `run` after each and appending metrics. Returns the
/// trained model.
pub fn train(
    model: NtgModel,
    dataset: &DemoDataset,
    optim: &OptimConfig,
    run: &RunDir,
    device: &Device,
    on_epoch: impl FnMut(&EpochMetrics),
) -> anyhow::Result<NtgModel> {
    train_with(
        model,
        dataset,
        optim,
        run,
        device,
        on_epoch,
        TrainExtras::default(),
    )
}

/// [`train`] with extras. With a validator it also scores every epoch, logs
/// the score to `validation.jsonl`, keeps the best epoch's weights in
/// `best/` (ties keep the earlier epoch) and returns those instead of the
/// last.
pub fn train_with(
    mut model: NtgModel,
    dataset: &DemoDataset,
    optim: &OptimConfig,
    run: &RunDir,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochMetrics),
    extras: TrainExtras<'_>,
) -> anyhow::Result<NtgModel> {
    let TrainExtras {
        mut validator,
        permute_objects: symmetry,
        accept_renaming,
        validate_every,
        retry_weight,
        detach_gcn_from_edges,
    } = extras;
    let validate_every = validate_every.max(1);
    if let Some(s) = symmetry {
        s.validate(dataset.vocabulary().len(), dataset.obs_dim())?;
    }
    if dataset.demos().is_empty() {
        bail!("the dataset has no demonstrations");
    }
    if optim.batch_size == 0 {
        bail!("batch size must be positive");
    }
    let n = model.num_nodes();
    dataset.check_num_nodes(n, "model")?;
    let graphs = task_graphs(dataset)?;
    let mut demos_of_task: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, e) in dataset.demos().iter().enumerate() {
        demos_of_task.entry(e.task).or_default().push(i);
    }
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();

    // Resume from the checkpoint if there is one.
    let ckpt = run.checkpoint_dir();
    let progress_path = ckpt.join("progress.json");
    let mut start = 0;
    if progress_path.is_file() {
        let progress: Progress = RunDir::read_json(&progress_path)?;
        model = NtgModel::load(&ckpt, device)
            .with_context(|| format!("resuming from {}", ckpt.display()))?;
        optimizer = load_optimizer(optimizer, ckpt.join("optimizer.bpk"))
            .with_context(|| format!("resuming from {}", ckpt.display()))?;
        start = progress.epochs_done;
    }

    let steps_per_epoch = dataset.demos().len().div_ceil(optim.batch_size);
    let total_steps = steps_per_epoch * optim.epochs;
    for epoch in start..optim.epochs {
        let started = std::time::Instant::now();
        let mut order: Vec<usize> = (0..dataset.demos().len()).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(
            optim.seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        order.shuffle(&mut rng);
        let mut sums = [0.0f32; 8];
        let mut edge_counts = EdgeCounts::default();
        let mut steps = 0usize;
        let bar = crate::dataset::progress_bar(steps_per_epoch as u64, &format!("epoch {epoch}"));
        for chunk in order.chunks(optim.batch_size) {
            let dropout = TokenDropout {
                rate: optim.token_dropout,
                seed: optim.seed ^ (epoch as u64) << 32 ^ steps as u64,
            };
            // The demo each GCN input path comes from (see
            // `OptimConfig::gcn_from_other_demo`).
            let gcn_sources: Vec<usize> = if optim.gcn_from_other_demo {
                let mut rng = ChaCha8Rng::seed_from_u64(dropout.seed ^ 0x005E_ED0F_07E4);
                chunk
                    .iter()
                    .map(|&i| {
                        let same = &demos_of_task[&dataset.demos()[i].task];
                        let others: Vec<usize> = same.iter().copied().filter(|&j| j != i).collect();
                        if others.is_empty() {
                            i
                        } else {
                            others[rng.random_range(0..others.len())]
                        }
                    })
                    .collect()
            } else {
                chunk.to_vec()
            };
            // The renaming of each demo's objects (see
            // `TrainExtras::permute_objects`).
            let relabelings: Option<(&ObjectSymmetry, Vec<Relabeling>)> = match symmetry {
                None => None,
                Some(s) => {
                    let mut rng = ChaCha8Rng::seed_from_u64(dropout.seed ^ 0x0B1E_C75E_ED00);
                    let drawn = chunk
                        .iter()
                        .map(|&i| match accept_renaming {
                            None => Ok(s.random(n, &mut rng)),
                            Some(accept) => {
                                let task = dataset.demos()[i].task;
                                s.random_accepted(n, &mut rng, |perm| accept(task, perm))
                            }
                        })
                        .collect::<anyhow::Result<Vec<_>>>()?;
                    Some((s, drawn))
                }
            };
            let out = step(
                &model,
                dataset,
                &graphs,
                Batch {
                    chunk,
                    gcn_sources: &gcn_sources,
                    relabelings: relabelings.as_ref().map(|(s, r)| (*s, r.as_slice())),
                    retry_weight: retry_weight.max(1.0),
                    detach_gcn_from_edges,
                },
                &dropout,
                device,
            )?;
            let grads = GradientsParams::from_grads(out.total.backward(), &model);
            let lr = optim.learning_rate_at(epoch * steps_per_epoch + steps, total_steps);
            model = optimizer.step(lr, model, grads);
            for (s, v) in sums.iter_mut().zip(out.values) {
                *s += v;
            }
            edge_counts.true_positives += out.edges.true_positives;
            edge_counts.false_positives += out.edges.false_positives;
            edge_counts.false_negatives += out.edges.false_negatives;
            steps += 1;
            bar.inc(1);
        }
        bar.finish_and_clear();
        let mean = |i: usize| sums[i] / steps as f32;
        let metrics = EpochMetrics {
            epoch,
            loss: mean(0),
            interpreter_loss: mean(1),
            token_accuracy: mean(2),
            gcn_loss: mean(3),
            edge_f1: edge_f1_of(&edge_counts),
            localizer_loss: mean(4),
            localizer_accuracy: mean(5),
            edge_loss: mean(6),
            step_accuracy: mean(7),
            seconds: started.elapsed().as_secs_f32(),
        };
        if !metrics.loss.is_finite() {
            bail!("training diverged at epoch {epoch} (loss {})", metrics.loss);
        }
        // Select before checkpointing: a run killed in between redoes this
        // epoch and finds `best/` either untouched or holding this very
        // epoch (which it then overwrites with identical weights).
        let mut validation = None;
        let validate_now = (epoch + 1) % validate_every == 0 || epoch + 1 == optim.epochs;
        if let Some(validator) = validator.as_deref_mut().filter(|_| validate_now) {
            let score = validator.validate(&model)?;
            let record = ValidationRecord { epoch, score };
            let improves = match selected_epoch(run)? {
                None => true,
                Some(best) => best.epoch >= epoch || score.beats(&best.score),
            };
            if improves {
                let best = run.best_dir();
                model.save(&best)?;
                RunDir::write_json(&best.join("selection.json"), &record)?;
            }
            validation = Some(record);
        }
        model.save(&ckpt)?;
        save_optimizer(&optimizer, ckpt.join("optimizer.bpk"))?;
        RunDir::write_json(
            &progress_path,
            &Progress {
                epochs_done: epoch + 1,
            },
        )?;
        run.append_metrics(&metrics)?;
        if let Some(record) = validation {
            RunDir::append_jsonl(&run.validation_path(), &record)?;
        }
        on_epoch(&metrics);
    }
    if validator.is_some()
        && let Some(best) = selected_epoch(run)?
    {
        return NtgModel::load(run.best_dir(), device).with_context(|| {
            format!(
                "loading the weights of epoch {} selected on validation tasks",
                best.epoch
            )
        });
    }
    Ok(model)
}

struct StepOutput {
    total: Tensor<1>,
    /// loss, interpreter loss, token acc, gcn loss, loc loss, loc acc, edge loss, edge acc
    values: [f32; 8],
    edges: EdgeCounts,
}

/// Decoder-input dropout of one step: rate and the seed of its mask.
struct TokenDropout {
    rate: f32,
    seed: u64,
}

impl TokenDropout {
    /// The `[B, L]` mask (true = read `<start>`), or `None` at rate 0.
    fn mask(&self, batch: &DemoBatch, device: &Device) -> Option<Tensor<2, Bool>> {
        if self.rate <= 0.0 {
            return None;
        }
        let [b, l] = batch.targets.dims();
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let values: Vec<bool> = (0..b * l)
            .map(|i| i % l != 0 && rng.random::<f32>() < self.rate)
            .collect();
        Some(Tensor::from_data(TensorData::new(values, [b, l]), device))
    }
}

/// The demos of one step.
struct Batch<'a> {
    /// Dataset indices of the demos imitated.
    chunk: &'a [usize],
    /// Per demo, the dataset index of the demo the GCN reads.
    gcn_sources: &'a [usize],
    /// Per demo, the renaming of its objects, if any.
    relabelings: Option<(&'a ObjectSymmetry, &'a [Relabeling])>,
    /// Edge-loss weight of recovery steps (see `TrainExtras::retry_weight`).
    retry_weight: f32,
    /// See `TrainExtras::detach_gcn_from_edges`.
    detach_gcn_from_edges: bool,
}

fn step(
    model: &NtgModel,
    dataset: &DemoDataset,
    graphs: &BTreeMap<usize, Ctg>,
    batch_demos: Batch<'_>,
    dropout: &TokenDropout,
    device: &Device,
) -> anyhow::Result<StepOutput> {
    let Batch {
        chunk,
        gcn_sources,
        relabelings,
        retry_weight,
        detach_gcn_from_edges,
    } = batch_demos;
    let n = model.num_nodes();
    let dim = dataset.obs_dim();
    let entries: Vec<_> = chunk.iter().map(|&i| &dataset.demos()[i]).collect();
    let relabel = |b: usize| relabelings.map(|(s, r)| (s, &r[b]));
    let demo_rows: Vec<Vec<Vec<f32>>> = entries
        .iter()
        .enumerate()
        .map(|(b, e)| {
            e.rows()
                .map(|r| match relabel(b) {
                    Some((s, r_b)) => s.apply_to_row(r_b, &dataset.row(r)),
                    None => dataset.row(r),
                })
                .collect()
        })
        .collect();
    let sequence = |b: usize, actions: &[ActionId]| match relabel(b) {
        Some((_, r_b)) => r_b.sequence(actions),
        None => actions.to_vec(),
    };
    let demo_actions: Vec<Vec<ActionId>> = entries
        .iter()
        .enumerate()
        .map(|(b, e)| sequence(b, &e.actions))
        .collect();

    // Demo interpreter.
    let pairs: Vec<(&[Vec<f32>], &[ActionId])> = demo_rows
        .iter()
        .zip(&demo_actions)
        .map(|(rows, actions)| (rows.as_slice(), actions.as_slice()))
        .collect();
    let batch = DemoBatch::new(&pairs, dim, n, device)?;
    let interp = model
        .interpreter
        .loss_with_token_dropout(&batch, dropout.mask(&batch, device))?;

    // GCN: a demo's path graph (this demo's, or another of its task's)
    // -> the task's graph.
    let paths: Vec<Ctg> = gcn_sources
        .iter()
        .enumerate()
        .map(|(b, &i)| Ctg::from_path(n, &sequence(b, &dataset.demos()[i].actions)))
        .collect::<Result<_, _>>()?;
    let owned_targets: Vec<Ctg> = entries
        .iter()
        .enumerate()
        .map(|(b, e)| match relabel(b) {
            Some((_, r_b)) => r_b.graph(&graphs[&e.task]),
            None => Ok(graphs[&e.task].clone()),
        })
        .collect::<anyhow::Result<_>>()?;
    let targets: Vec<&Ctg> = owned_targets.iter().collect();
    let path_refs: Vec<&Ctg> = paths.iter().collect();
    let adjacency = ntg_model::adjacency_tensor(&path_refs, n, device)?;
    let target_adj = ntg_model::adjacency_tensor(&targets, n, device)?;
    let gcn_loss;
    let ne_gcn;
    let edges;
    // Soft edges: the weights `C` of the graph each row's policy would use
    // (see `NtgConfig::soft_edges`), `[B, N, N]`, not trained through.
    let mut soft_weights = None;
    if model.config().ablation.gcn {
        let gcn_out = model.gcn.forward(adjacency.clone())?;
        gcn_loss = model.gcn.loss(&gcn_out, target_adj.clone())?;
        edges = EdgeCounts::count_tensors(gcn_out.adjacency.clone(), target_adj, 0.5)?;
        if model.config().uses_soft_edges() {
            let mut c = gcn_out.adjacency.clone().detach();
            if model.config().keep_demo_edges {
                c = c.max_pair(adjacency);
            }
            soft_weights = Some(c);
        }
        ne_gcn = gcn_out.embeddings;
    } else {
        gcn_loss = Tensor::zeros([1], device);
        edges = EdgeCounts::default();
        ne_gcn = model.gcn.initial_embeddings(entries.len());
    }

    // Localizer and edge classifier over every observation of the batch.
    let mut rows: Vec<&Vec<f32>> = Vec::new();
    let mut nodes = Vec::new();
    let mut next = Vec::new();
    let mut row_weights: Vec<f32> = Vec::new();
    let mut demo_index = Vec::new();
    let mut row_graphs = Vec::new();
    for (b, (actions, obs)) in demo_actions.iter().zip(&demo_rows).enumerate() {
        let labels = std::iter::once(ctg_graph::Vocabulary::START).chain(actions.iter().copied());
        let nexts = actions
            .iter()
            .copied()
            .chain(std::iter::once(ctg_graph::Vocabulary::END));
        for (i, ((o, node), nx)) in obs.iter().zip(labels).zip(nexts).enumerate() {
            let repeats = actions[..i.min(actions.len())].contains(&nx);
            row_weights.push(if repeats { retry_weight } else { 1.0 });
            rows.push(o);
            nodes.push(node);
            next.push(nx);
            demo_index.push(b as i64);
            row_graphs.push(targets[b]);
        }
    }
    let obs = rows_tensor(&rows, dim, device)?;
    let node_ids = ids_tensor(&nodes, n, device)?;
    let next_ids = ids_tensor(&next, n, device)?;
    let loc_logits = model.localizer.forward(obs.clone())?;
    let loc = model.localizer.loss(loc_logits, node_ids.clone())?;
    let index = Tensor::<1, burn::tensor::Int>::from_data(
        burn::tensor::TensorData::new(demo_index, [rows.len()]),
        device,
    );
    let ne_gcn = if detach_gcn_from_edges {
        ne_gcn.detach()
    } else {
        ne_gcn
    };
    let row_ne_gcn = ne_gcn.select(0, index.clone());
    let full = Ctg::fully_connected(n);
    let mask = if soft_weights.is_some() {
        let all = vec![&full; rows.len()];
        successor_mask(&all, &nodes, Some(&next), n, device)?
    } else {
        successor_mask(&row_graphs, &nodes, Some(&next), n, device)?
    };
    let mut edge_logits = model.edges.forward(
        obs,
        node_ids.clone(),
        row_ne_gcn,
        model.localizer.node_embeddings(),
        mask,
    )?;
    if let Some(c) = soft_weights {
        // ln C of each row's node: rows of C [R, N, N] gathered at the node.
        let r = rows.len();
        let gather = node_ids.reshape([r, 1, 1]).expand([r, 1, n]);
        let c_rows = c.select(0, index).gather(1, gather).reshape([r, n]);
        // Edges the fully connected graph lacks stay masked.
        edge_logits = edge_logits + c_rows.clamp(ntg_model::SOFT_EDGE_FLOOR, 1.0).log();
    }
    let row_weights = Tensor::<1>::from_data(
        burn::tensor::TensorData::new(row_weights, [rows.len()]),
        device,
    );
    let edge = model
        .edges
        .weighted_loss(edge_logits, next_ids, row_weights)?;

    let mut total = interp.loss.clone() + loc.loss.clone();
    if model.config().ablation.gcn {
        total = total + gcn_loss.clone();
    }
    total = total + edge.loss.clone();
    let values = [
        scalar(total.clone())?,
        scalar(interp.loss)?,
        interp.accuracy,
        scalar(gcn_loss)?,
        scalar(loc.loss)?,
        loc.accuracy,
        scalar(edge.loss)?,
        edge.accuracy,
    ];
    Ok(StepOutput {
        total,
        values,
        edges,
    })
}

/// A fresh model for `config` on `device`, or an error naming the problem.
pub fn new_model(config: NtgConfig, device: &Device) -> anyhow::Result<NtgModel> {
    Ok(NtgModel::new(config, device)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepted_renamings_are_drawn_again_until_accepted() {
        let sym = ObjectSymmetry {
            num_objects: 4,
            obs_offset: 0,
            obs_stride: 1,
            action_families: vec![(0..4).map(ActionId::new).collect()],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let r = sym
                .random_accepted(5, &mut rng, |perm| perm[0] == 0)
                .unwrap();
            assert_eq!(r.perm[0], 0);
        }
        let err = sym
            .random_accepted(5, &mut rng, |_| false)
            .unwrap_err()
            .to_string();
        assert!(err.contains("no acceptable renaming"), "{err}");
    }

    #[test]
    fn edge_f1_is_absent_when_nothing_was_counted() {
        assert_eq!(edge_f1_of(&EdgeCounts::default()), None);
        let counts = EdgeCounts {
            true_positives: 3,
            false_positives: 1,
            false_negatives: 2,
        };
        assert_eq!(edge_f1_of(&counts), Some(6.0 / 9.0));
        let mut m = EpochMetrics {
            epoch: 0,
            loss: 1.0,
            interpreter_loss: 0.0,
            token_accuracy: 0.0,
            gcn_loss: 0.0,
            edge_f1: None,
            localizer_loss: 0.0,
            localizer_accuracy: 0.0,
            edge_loss: 0.0,
            step_accuracy: 0.0,
            seconds: 0.0,
        };
        assert_eq!(m.edge_f1_text(), "n/a");
        m.edge_f1 = Some(0.5);
        assert_eq!(m.edge_f1_text(), "0.500");
        // Metrics logged before the field was optional still read.
        let old = r#"{"epoch":0,"loss":1.0,"interpreter_loss":0.0,"token_accuracy":0.0,"gcn_loss":0.0,"edge_f1":1.0,"localizer_loss":0.0,"localizer_accuracy":0.0,"edge_loss":0.0,"step_accuracy":0.0,"seconds":0.0}"#;
        let parsed: EpochMetrics = serde_json::from_str(old).unwrap();
        assert_eq!(parsed.edge_f1, Some(1.0));
    }
}
