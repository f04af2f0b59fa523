//! NTG as a training method: the four networks trained jointly with Adam on
//! the paper's targets (section 4.3), one [`TrainStep`] for every domain.
//!
//! For each demonstration, the demo interpreter transcribes its
//! observations into its action sequence; the GCN completes a path graph
//! into its task's ground-truth CTG (the union of all demonstrated paths of
//! that task); the localizer maps each observation to the node it sits at
//! (the last action taken); and the edge classifier, given the observation,
//! its node and the GCN's embeddings, predicts the next action among the
//! node's CTG successors. The four losses are summed and one Adam step
//! updates all. A model with [`ntg_model::NtgConfig::soft_edges`] trains the edge
//! classifier as its policy uses it: a softmax over every node of the
//! fully connected graph, each logit raised by `ln C` of the graph the GCN
//! completed from its input path (that path's edges at 1, floored at
//! [`ntg_model::SOFT_EDGE_FLOOR`], no gradient into the GCN through `C`).
//!
//! What a domain may add ([`NtgTraining`], all off in the paper's method):
//! the GCN reading another demo of the task than the one imitated, decoder
//! token dropout, random stretches of demos for the interpreter, the final
//! `<end>` decision left out, an execution memory, recovery steps weighted
//! up, the GCN kept out of the edge loss, and object renaming.

use std::collections::BTreeMap;

use burn::module::Module;
use burn::tensor::{Bool, Device, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg, Vocabulary};
use ntg_model::{
    AblationConfig, DemoBatch, EdgeCounts, NtgModel, NtgPolicy, adjacency_tensor, ids_tensor,
    pending_nodes, rows_tensor, successor_mask,
};
use rand::seq::IndexedRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::DemoDataset;
use crate::fit::{
    OptimConfig, Selection, StepContext, StepReport, TrainStep, Validator, fit, scalar,
};
use crate::method::input::{Demos, EpochLog, EpochReport, TrainInput, fit_model};
use crate::method::{Agent, Model, TrainedPolicy};
use crate::run_dir::RunDir;
use crate::symmetry::{ObjectSymmetry, Relabeling, RenamingFilter};

/// Metrics of one NTG epoch, as logged to `metrics.jsonl`.
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

impl EpochLog for EpochMetrics {
    fn epoch(&self) -> usize {
        self.epoch
    }
    fn log_line(&self) -> String {
        EpochMetrics::log_line(self)
    }
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

/// Whether the action after the first `done` of a demo's `actions`
/// repeats one of them: a retry (the grasp slipped or the drop missed).
/// `false` after the last action (`<end>` comes next).
pub fn next_is_retry(actions: &[ActionId], done: usize) -> bool {
    actions
        .get(done)
        .is_some_and(|next| actions[..done].contains(next))
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

/// Which demo's path the GCN completes for each imitated demo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GcnSource {
    /// The imitated demo itself (the paper).
    #[default]
    Own,
    /// Another demo of the same task (the demo itself when its task has no
    /// other), from a generator seeded by the run seed, epoch and step
    /// ([`OptimConfig::gcn_from_other_demo`], block stacking).
    OtherSeeded,
    /// Another demo of the same task drawn from the epoch's generator
    /// (object collection, where the draw predates the seeded one; the
    /// domain requires two demos per task).
    OtherFromEpoch,
}

/// What NTG training adds to the paper's four losses; the default is the
/// paper's method.
#[derive(Default, Clone, Copy)]
pub struct NtgTraining<'a> {
    /// Which demo the GCN reads. Trained on its own demo's path, the edge
    /// classifier can read off the GCN's embeddings where that very demo
    /// ends or retries, instead of reading the observation.
    pub gcn_source: GcnSource,
    /// Probability that the decoder reads `<start>` instead of the previous
    /// action ([`OptimConfig::token_dropout`]).
    pub token_dropout: f32,
    /// The interpreter also learns from one random contiguous stretch of
    /// each demo (any stretch of a demonstration, with the actions inside
    /// it, is itself a demonstration), drawn from the epoch's generator.
    pub segments: bool,
    /// Leave the final `<end>` decision out of the edge classifier's loss
    /// (a last frame that cannot show whether the task is done).
    pub skip_end: bool,
    /// The edge classifier reads the task-graph nodes not yet executed
    /// ([`ntg_model::pending_nodes`] of the GCN's input path).
    pub memory: bool,
    /// Weight, in the edge classifier's loss, of the steps whose next
    /// action repeats one the demo already took (recovery after a failure).
    /// Recovery steps are rare, so with weight 1 the classifier learns to
    /// move on. Values ≤ 1 mean 1. Not in the paper.
    pub retry_weight: f32,
    /// Stop the edge classifier's loss from flowing into the GCN: the GCN
    /// then learns only to complete task graphs. Trained jointly, a large
    /// edge loss costs the GCN edges (measured: edge F1 0.93 → 0.78). Not
    /// in the paper.
    pub detach_gcn_from_edges: bool,
    /// Rename the objects of every training demo by a fresh random
    /// permutation (seeded by the run seed, epoch and step) through this
    /// symmetry. Not in the paper.
    pub permute_objects: Option<&'a ObjectSymmetry>,
    /// With `permute_objects`: which renamings of a demo of dataset task
    /// `task` may be trained on; the others are drawn again. Block stacking
    /// refuses those that turn a training task into a held-out one. `None`
    /// accepts every renaming.
    pub accept_renaming: Option<RenamingFilter<'a>>,
    /// Sum the losses as interpreter + localizer + edge + GCN instead of
    /// interpreter + localizer + GCN + edge. The sum is the same; the order
    /// decides in which order burn accumulates the gradients of parameters
    /// that several losses share, which changes weights in the last bits.
    /// Object collection's runs were trained in this order, and keep it so
    /// that they reproduce bit for bit.
    pub gcn_loss_last: bool,
}

/// NTG's [`TrainStep`] on a dataset of demonstrations.
pub struct NtgStep<'a> {
    dataset: &'a DemoDataset,
    graphs: BTreeMap<usize, Ctg>,
    demos_of_task: BTreeMap<usize, Vec<usize>>,
    training: NtgTraining<'a>,
    device: Device,
}

impl<'a> NtgStep<'a> {
    /// The step for `model`'s vocabulary on `dataset`, or an error naming
    /// what does not fit.
    pub fn new(
        model: &NtgModel,
        dataset: &'a DemoDataset,
        training: NtgTraining<'a>,
        device: &Device,
    ) -> anyhow::Result<Self> {
        dataset.check_num_nodes(model.num_nodes(), "model")?;
        if let Some(s) = training.permute_objects {
            s.validate(dataset.vocabulary().len(), dataset.obs_dim())?;
        }
        let mut demos_of_task: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, e) in dataset.demos().iter().enumerate() {
            demos_of_task.entry(e.task).or_default().push(i);
        }
        Ok(NtgStep {
            dataset,
            graphs: task_graphs(dataset)?,
            demos_of_task,
            training,
            device: device.clone(),
        })
    }

    /// The other demos of demo `i`'s task.
    fn others(&self, i: usize) -> Vec<usize> {
        self.demos_of_task[&self.dataset.demos()[i].task]
            .iter()
            .copied()
            .filter(|&j| j != i)
            .collect()
    }

    /// The demo whose path the GCN reads, for each demo of `chunk`.
    fn gcn_sources(&self, chunk: &[usize], step_seed: u64, rng: &mut ChaCha8Rng) -> Vec<usize> {
        match self.training.gcn_source {
            GcnSource::Own => chunk.to_vec(),
            GcnSource::OtherSeeded => {
                let mut rng = ChaCha8Rng::seed_from_u64(step_seed ^ 0x005E_ED0F_07E4);
                chunk
                    .iter()
                    .map(|&i| {
                        let others = self.others(i);
                        if others.is_empty() {
                            i
                        } else {
                            others[rng.random_range(0..others.len())]
                        }
                    })
                    .collect()
            }
            GcnSource::OtherFromEpoch => chunk
                .iter()
                .map(|&i| *self.others(i).choose(rng).unwrap_or(&i))
                .collect(),
        }
    }

    /// The renaming of each demo's objects, if any.
    fn relabelings(
        &self,
        chunk: &[usize],
        step_seed: u64,
    ) -> anyhow::Result<Option<(&'a ObjectSymmetry, Vec<Relabeling>)>> {
        let Some(s) = self.training.permute_objects else {
            return Ok(None);
        };
        let n = self.dataset.vocabulary().len();
        let mut rng = ChaCha8Rng::seed_from_u64(step_seed ^ 0x0B1E_C75E_ED00);
        let drawn = chunk
            .iter()
            .map(|&i| match self.training.accept_renaming {
                None => Ok(s.random(n, &mut rng)),
                Some(accept) => {
                    let task = self.dataset.demos()[i].task;
                    s.random_accepted(n, &mut rng, |perm| accept(task, perm))
                }
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(Some((s, drawn)))
    }
}

/// The `[B, L]` decoder-input dropout mask (true = read `<start>`), or
/// `None` at rate 0.
fn token_dropout_mask(
    rate: f32,
    seed: u64,
    batch: &DemoBatch,
    device: &Device,
) -> Option<Tensor<2, Bool>> {
    if rate <= 0.0 {
        return None;
    }
    let [b, l] = batch.targets.dims();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let values: Vec<bool> = (0..b * l)
        .map(|i| i % l != 0 && rng.random::<f32>() < rate)
        .collect();
    Some(Tensor::from_data(TensorData::new(values, [b, l]), device))
}

impl TrainStep<NtgModel> for NtgStep<'_> {
    type Metrics = EpochMetrics;

    fn num_examples(&self) -> usize {
        self.dataset.demos().len()
    }

    fn step(
        &self,
        model: &NtgModel,
        chunk: &[usize],
        ctx: StepContext<'_>,
    ) -> anyhow::Result<StepReport> {
        let t = &self.training;
        let (dataset, device) = (self.dataset, &self.device);
        let n = model.num_nodes();
        let dim = dataset.obs_dim();
        let step_seed = ctx.seed ^ (ctx.epoch as u64) << 32 ^ ctx.step as u64;

        // Everything random of the step.
        let gcn_sources = self.gcn_sources(chunk, step_seed, ctx.rng);
        let segments: Vec<(usize, usize)> = if t.segments {
            chunk
                .iter()
                .map(|&i| {
                    let k = dataset.demos()[i].actions.len();
                    let start = ctx.rng.random_range(0..k);
                    (start, ctx.rng.random_range(start + 1..=k))
                })
                .collect()
        } else {
            Vec::new()
        };
        let relabelings = self.relabelings(chunk, step_seed)?;
        let relabel = |b: usize| relabelings.as_ref().map(|(s, r)| (*s, &r[b]));
        let sequence = |b: usize, actions: &[ActionId]| match relabel(b) {
            Some((_, r_b)) => r_b.sequence(actions),
            None => actions.to_vec(),
        };

        let entries: Vec<_> = chunk.iter().map(|&i| &dataset.demos()[i]).collect();
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
        // The row at each CTG node: every row, or a video's keyframes.
        let keyframes: Vec<Vec<usize>> = entries.iter().map(|e| e.keyframes()).collect();
        let demo_actions: Vec<Vec<ActionId>> = entries
            .iter()
            .enumerate()
            .map(|(b, e)| sequence(b, &e.actions))
            .collect();

        // Demo interpreter: each demo whole (every frame of a video), and
        // (with segments) one contiguous stretch of it: actions
        // `start..end` with the frames from node `start` to node `end`.
        let mut pairs: Vec<(&[Vec<f32>], &[ActionId])> = demo_rows
            .iter()
            .zip(&demo_actions)
            .map(|(rows, actions)| (rows.as_slice(), actions.as_slice()))
            .collect();
        for (b, &(start, end)) in segments.iter().enumerate() {
            let (rows, key) = (&demo_rows[b], &keyframes[b]);
            pairs.push((&rows[key[start]..=key[end]], &demo_actions[b][start..end]));
        }
        let ablation = model.config().ablation.clone();
        let interp = if ablation.demo_interpreter {
            let mut batch = DemoBatch::new(&pairs, dim, n, device)?;
            if model.interpreter.aligned {
                let rows = keyframes
                    .iter()
                    .zip(&demo_actions)
                    .map(|(key, actions)| aligned_rows(key, 0, actions.len()))
                    .chain(
                        segments
                            .iter()
                            .enumerate()
                            .map(|(b, &(start, end))| aligned_rows(&keyframes[b], start, end)),
                    )
                    .collect();
                batch = batch.with_aligned_rows(rows)?;
            }
            let mask = token_dropout_mask(t.token_dropout, step_seed, &batch, device);
            Some(model.interpreter.loss_with_token_dropout(&batch, mask)?)
        } else {
            None
        };

        // GCN: a demo's path graph (this demo's, or another of its task's)
        // -> the task's graph.
        let paths: Vec<Ctg> = gcn_sources
            .iter()
            .enumerate()
            .map(|(b, &i)| Ctg::from_path(n, &sequence(b, &dataset.demos()[i].actions)))
            .collect::<Result<_, _>>()?;
        let targets: Vec<Ctg> = entries
            .iter()
            .enumerate()
            .map(|(b, e)| match relabel(b) {
                Some((_, r_b)) => r_b.graph(&self.graphs[&e.task]),
                None => Ok(self.graphs[&e.task].clone()),
            })
            .collect::<anyhow::Result<_>>()?;
        let target_refs: Vec<&Ctg> = targets.iter().collect();
        let path_refs: Vec<&Ctg> = paths.iter().collect();
        let adjacency = adjacency_tensor(&path_refs, n, device)?;
        let (gcn_loss, ne_gcn, edges, soft_weights) = if ablation.gcn {
            let target_adj = adjacency_tensor(&target_refs, n, device)?;
            let out = model.gcn.forward(adjacency.clone())?;
            let loss = model.gcn.loss(&out, target_adj.clone())?;
            let edges = EdgeCounts::count_tensors(out.adjacency.clone(), target_adj, 0.5)?;
            // Soft edges: the weights `C` of the graph each row's policy
            // would use (see `NtgConfig::soft_edges`), not trained through.
            let soft = model.config().uses_soft_edges().then(|| {
                let c = out.adjacency.clone().detach();
                if model.config().keep_demo_edges {
                    c.max_pair(adjacency)
                } else {
                    c
                }
            });
            (Some(loss), Some(out.embeddings), edges, soft)
        } else {
            (None, None, EdgeCounts::default(), None)
        };

        // Localizer: every observation. Edge classifier: every observation
        // with a next action (the final `<end>` unless `skip_end`), with a
        // memory of the task-graph nodes not executed before it.
        let retry_weight = t.retry_weight.max(1.0);
        let (mut obs, mut nodes) = (Vec::new(), Vec::new());
        // With temporal context, the keyframe before each (the first its
        // own), as the agent reads the observation of its last decision.
        let reads_previous = model.config().localizer.reads_previous();
        let mut previous = Vec::new();
        let (mut e_obs, mut e_nodes, mut e_next, mut e_demo, mut e_graphs) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut e_weights, mut e_memory): (Vec<f32>, Vec<Vec<f32>>) = (Vec::new(), Vec::new());
        for (b, (actions, rows)) in demo_actions.iter().zip(&demo_rows).enumerate() {
            let labels = std::iter::once(Vocabulary::START).chain(actions.iter().copied());
            let nexts = actions.iter().copied().chain([Vocabulary::END]);
            let nodes_rows = keyframes[b].iter().map(|&k| &rows[k]);
            for (i, ((o, node), nx)) in nodes_rows.zip(labels).zip(nexts).enumerate() {
                obs.push(o);
                nodes.push(node);
                if reads_previous {
                    previous.push(&rows[keyframes[b][i.saturating_sub(1)]]);
                }
                if t.skip_end && nx == Vocabulary::END {
                    continue;
                }
                let repeats = next_is_retry(actions, i);
                e_weights.push(if repeats { retry_weight } else { 1.0 });
                e_obs.push(o);
                e_nodes.push(node);
                e_next.push(nx);
                e_demo.push(b as i64);
                e_graphs.push(target_refs[b]);
                if t.memory {
                    e_memory.push(pending_nodes(&paths[b], &actions[..i]));
                }
            }
        }
        let obs_tensor = rows_tensor(&obs, dim, device)?;
        let loc_input = if reads_previous {
            ntg_model::NodeLocalizer::in_context(
                obs_tensor.clone(),
                rows_tensor(&previous, dim, device)?,
            )?
        } else {
            obs_tensor.clone()
        };
        let loc_logits = model.localizer.forward(loc_input)?;
        let loc = model
            .localizer
            .loss(loc_logits, ids_tensor(&nodes, n, device)?)?;
        let r = e_obs.len();
        let e_obs_tensor = if r == obs.len() {
            obs_tensor
        } else {
            rows_tensor(&e_obs, dim, device)?
        };
        let e_node_ids = ids_tensor(&e_nodes, n, device)?;
        let index = Tensor::<1, Int>::from_data(TensorData::new(e_demo, [r]), device);
        // Each row's graph embeddings: the GCN's output for its demo, or
        // without a GCN its task-independent initial embeddings `N⁰`.
        let row_ne_gcn = match ne_gcn {
            Some(ne) if t.detach_gcn_from_edges => ne.detach().select(0, index.clone()),
            Some(ne) => ne.select(0, index.clone()),
            None if t.detach_gcn_from_edges => model.gcn.initial_embeddings(r).detach(),
            None => model.gcn.initial_embeddings(r),
        };
        // Soft edges, and a model without a demo interpreter (whose graph
        // is fully connected), score every node.
        let full = Ctg::fully_connected(n);
        let mask = if soft_weights.is_some() || !ablation.demo_interpreter {
            successor_mask(&vec![&full; r], &e_nodes, Some(&e_next), n, device)?
        } else {
            successor_mask(&e_graphs, &e_nodes, Some(&e_next), n, device)?
        };
        let memory = if t.memory {
            Some(rows_tensor(&e_memory, n, device)?)
        } else {
            None
        };
        let mut edge_logits = model.edges.forward(
            e_obs_tensor,
            e_node_ids.clone(),
            row_ne_gcn,
            model.localizer.node_embeddings(),
            mask,
            memory,
        )?;
        if let Some(c) = soft_weights {
            // ln C of each row's node: rows of C [R, N, N] gathered at the
            // node. Edges the fully connected graph lacks stay masked.
            let gather = e_node_ids.reshape([r, 1, 1]).expand([r, 1, n]);
            let c_rows = c.select(0, index).gather(1, gather).reshape([r, n]);
            edge_logits = edge_logits + c_rows.clamp(ntg_model::SOFT_EDGE_FLOOR, 1.0).log();
        }
        let weights = Tensor::<1>::from_data(TensorData::new(e_weights, [r]), device);
        let edge =
            model
                .edges
                .weighted_loss(edge_logits, ids_tensor(&e_next, n, device)?, weights)?;

        // A model trained without the localizer or the edge classifier
        // (an ablation) still reports their untrained accuracy, but their
        // losses train nothing.
        let loc_loss = ablation.node_localizer.then(|| loc.loss.clone());
        let edge_loss = ablation.edge_classifier.then(|| edge.loss.clone());
        let mut total = match (&interp, loc_loss) {
            (Some(i), Some(l)) => i.loss.clone() + l,
            (Some(i), None) => i.loss.clone(),
            (None, Some(l)) => l,
            (None, None) => edge.loss.clone().mul_scalar(0.0),
        };
        let gcn_value = match &gcn_loss {
            Some(l) => scalar(l.clone())?,
            None => 0.0,
        };
        match (gcn_loss, edge_loss) {
            (Some(l), Some(e)) if t.gcn_loss_last => total = total + e + l,
            (Some(l), Some(e)) => total = total + l + e,
            (Some(l), None) => total = total + l,
            (None, Some(e)) => total = total + e,
            (None, None) => {}
        }
        Ok(StepReport {
            values: vec![
                scalar(total.clone())?,
                interp
                    .as_ref()
                    .map_or(Ok(0.0), |i| scalar(i.loss.clone()))?,
                interp.as_ref().map_or(0.0, |i| i.accuracy),
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

    fn epoch_metrics(
        &self,
        epoch: usize,
        m: &[f32],
        edges: &EdgeCounts,
        seconds: f32,
    ) -> EpochMetrics {
        EpochMetrics {
            epoch,
            loss: m[0],
            interpreter_loss: m[1],
            token_accuracy: m[2],
            gcn_loss: m[3],
            edge_f1: edge_f1_of(edges),
            localizer_loss: m[4],
            localizer_accuracy: m[5],
            edge_loss: m[6],
            step_accuracy: m[7],
            seconds,
        }
    }
}

/// Optional parts of [`train_with`]: model selection and what training adds
/// to the paper's method.
#[derive(Default)]
pub struct TrainExtras<'a> {
    /// Scores every `validate_every` epochs and selects the best.
    pub validator: Option<&'a mut dyn Validator<NtgModel>>,
    /// Validate after every this many epochs (and after the last); 0 and 1
    /// mean every epoch.
    pub validate_every: usize,
    /// What training adds to the paper's method. Its `gcn_source` and
    /// `token_dropout` are taken from the [`OptimConfig`] by [`train_with`].
    pub training: NtgTraining<'a>,
}

/// Trains `model` (on an autodiff device) for the epochs not yet done,
/// checkpointing into `run` after each and appending metrics (see
/// [`fit`]), and returns it. With a validator it also scores the model, logs
/// the score to `validation.jsonl`, keeps the best epoch's weights in
/// `best/` (ties keep the earlier epoch) and returns those instead of the
/// last. The GCN reads another demo of the task when
/// `optim.gcn_from_other_demo` (seeded per step), and the decoder drops
/// tokens at `optim.token_dropout`.
pub fn train_with(
    model: NtgModel,
    dataset: &DemoDataset,
    optim: &OptimConfig,
    run: &RunDir,
    device: &Device,
    on_epoch: impl FnMut(&EpochMetrics),
    extras: TrainExtras<'_>,
) -> anyhow::Result<NtgModel> {
    let training = NtgTraining {
        gcn_source: if optim.gcn_from_other_demo {
            GcnSource::OtherSeeded
        } else {
            GcnSource::Own
        },
        token_dropout: optim.token_dropout,
        ..extras.training
    };
    let step = NtgStep::new(&model, dataset, training, device)?;
    let selection = extras.validator.map(|validator| Selection {
        validator,
        every: extras.validate_every,
        scores: crate::fit::ROLLOUT_SCORES,
    });
    fit(model, &step, optim, run, device, selection, on_epoch)
}

/// Trains the paper's NTG on `dataset`'s observation rows (each encoded by
/// an MLP over its values, weights seeded by `optim.seed`, no validation)
/// in `run`: the shortest way to NTG on a domain of one's own, through the
/// same [`TrainInput`] and [`train`] every domain uses.
pub fn train_on_rows(
    dataset: &DemoDataset,
    optim: &OptimConfig,
    run: &RunDir,
    device: &Device,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<NtgModel> {
    let demos = || {
        Ok(Demos {
            dataset: dataset.clone(),
            frames: None,
        })
    };
    let input = TrainInput::of_rows(
        &demos,
        dataset.vocabulary(),
        dataset.obs_dim(),
        optim,
        run,
        device,
    );
    let model = train(input, &NtgOptions::default(), on_epoch)?;
    use anyhow::Context;
    model
        .as_any()
        .downcast_ref::<NtgModel>()
        .cloned()
        .context("NTG on rows is an NtgModel")
}

/// NTG's options, read from a run's configuration (see
/// [`crate::method::input::options_of`]): top-level keys, and the few that
/// runs keep under `optim` and `video`. An absent key means the paper's
/// method, so configurations saved before a key existed read as they were
/// trained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NtgOptions {
    /// The part of NTG trained without ([`Variant::trains`]; `full`: none).
    #[serde(default)]
    pub ablation: Variant,
    /// Edge-loss weight of recovery steps ([`NtgTraining::retry_weight`]).
    #[serde(default)]
    pub retry_weight: f32,
    /// Keep the edge loss out of the GCN
    /// ([`NtgTraining::detach_gcn_from_edges`]).
    #[serde(default)]
    pub detach_gcn_from_edges: bool,
    /// Soft edges ([`ntg_model::NtgConfig::soft_edges`]).
    #[serde(default)]
    pub soft_edges: bool,
    /// Hidden width of the edge classifier's fusion layer (0: the paper's
    /// linear `W`).
    #[serde(default)]
    pub edge_fusion_hidden: usize,
    /// The interpreter also learns from random stretches of demos
    /// ([`NtgTraining::segments`]).
    #[serde(default)]
    pub segments: bool,
    /// Train the final `<end>` decision (false: [`NtgTraining::skip_end`]).
    #[serde(default = "yes")]
    pub learn_end: bool,
    /// The edge classifier reads the nodes not yet executed
    /// ([`NtgTraining::memory`]).
    #[serde(default)]
    pub memory: bool,
    /// `<end>` only once the demo's actions are executed
    /// ([`ntg_model::AblationConfig::end_after_demo`]).
    #[serde(default)]
    pub end_after_demo: bool,
    /// The demo interpreter (absent: the paper's).
    #[serde(default)]
    pub interpreter: Option<InterpreterKind>,
    /// With the stepping interpreter: the initial weight of its
    /// location-aware attention's shift +1 (absent: 0).
    #[serde(default)]
    pub location_step_prior: Option<f32>,
    /// The current node is the last action executed, not the localizer's
    /// (runs on states; video runs keep it under `video`).
    #[serde(default)]
    pub executed_node: bool,
    /// The options runs keep under `optim`.
    #[serde(default)]
    pub optim: NtgOptimOptions,
    /// The options runs from demo videos keep under `video`.
    #[serde(default)]
    pub video: Option<NtgVideoOptions>,
}

fn yes() -> bool {
    true
}

impl Default for NtgOptions {
    /// The paper's method.
    fn default() -> Self {
        NtgOptions::deserialize(serde_json::json!({})).expect("every option has a default")
    }
}

/// NTG's options under a run configuration's `optim`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct NtgOptimOptions {
    /// Decoder token dropout ([`NtgTraining::token_dropout`]).
    #[serde(default)]
    pub token_dropout: f32,
    /// The GCN reads another demo of the task, seeded per step
    /// ([`GcnSource::OtherSeeded`]).
    #[serde(default)]
    pub gcn_from_other_demo: bool,
}

/// NTG's options under a video run configuration's `video`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct NtgVideoOptions {
    /// The current node is the last action executed, not the localizer's.
    #[serde(default)]
    pub executed_node: bool,
    /// The demo interpreter reads frames averaged in windows of this many.
    #[serde(default)]
    pub interpreter_frame_pool: usize,
    /// The node localizer reads the frame the agent acted on before this
    /// one too ([`ntg_model::NodeLocalizerConfig::previous_observation`]).
    #[serde(default)]
    pub localizer_previous_frame: bool,
}

impl NtgOptions {
    /// The keys of the run configuration these options are read from
    /// ([`crate::method::Method::options`]).
    pub const KEYS: &'static [&'static str] = &[
        "ablation",
        "retry_weight",
        "detach_gcn_from_edges",
        "soft_edges",
        "edge_fusion_hidden",
        "segments",
        "learn_end",
        "memory",
        "end_after_demo",
        "interpreter",
        "location_step_prior",
        "optim.token_dropout",
        "optim.gcn_from_other_demo",
        "executed_node",
        "video.executed_node",
        "video.interpreter_frame_pool",
        "video.localizer_previous_frame",
    ];

    /// Refuses what cannot be trained, naming the flag.
    pub fn check(&self) -> anyhow::Result<()> {
        if !self.ablation.trains() {
            anyhow::bail!(
                "--ablation {}: a run is trained full or without one part (no-demo-interpreter, no-node-localizer, no-edge-classifier, no-gcn); {} is an evaluation setting (ntg eval --variant)",
                self.ablation.name(),
                self.ablation.name()
            );
        }
        if self.location_step_prior.is_some()
            && !matches!(
                self.interpreter,
                Some(
                    InterpreterKind::Stepping
                        | InterpreterKind::SteppingVideo
                        | InterpreterKind::SteppingAligned
                        | InterpreterKind::SteppingVideoAligned
                )
            )
        {
            anyhow::bail!(
                "--location-step-prior: a location step prior needs NTG with a stepping interpreter (--interpreter stepping, stepping-video, stepping-aligned or stepping-video-aligned; the paper's interpreter has no location-aware attention)"
            );
        }
        if let Some(w) = self.location_step_prior
            && !w.is_finite()
        {
            anyhow::bail!("--location-step-prior must be finite, got {w}");
        }
        if let Some(video) = &self.video
            && video.localizer_previous_frame
            && (video.executed_node || self.executed_node)
        {
            anyhow::bail!(
                "--localizer-previous-frame: the run takes the current node from the agent's record (--node-source executed, the recommended recipe's on video), so the localizer does not choose it; add --node-source localizer"
            );
        }
        Ok(())
    }

    /// The untrained model's configuration for `input`'s vocabulary and
    /// encoders.
    pub fn model_config(&self, input: &TrainInput<'_>) -> ntg_model::NtgConfig {
        let n = input.vocabulary.len();
        let mut config = ntg_model::NtgConfig::for_domain(n, input.encoders.sequence.clone());
        config.localizer.encoder = input.encoders.observation.clone();
        config.edge.encoder = input.encoders.observation.clone();
        if self.edge_fusion_hidden > 0 {
            config.edge.fusion_hidden = Some(self.edge_fusion_hidden);
        }
        if self.soft_edges {
            config.soft_edges = Some(true);
        }
        if let Some(interpreter) = self.interpreter {
            interpreter.apply(&mut config.interpreter, self.location_step_prior);
        }
        config.edge.memory_dim = self.memory.then_some(n);
        let video = self.video.clone().unwrap_or_default();
        if video.interpreter_frame_pool > 1 {
            config.interpreter.frame_pool = Some(video.interpreter_frame_pool);
        }
        if video.localizer_previous_frame {
            // The model's validation refuses any other encoder.
            if let ntg_model::EncoderConfig::State(c) = &mut config.localizer.encoder {
                c.input_dim *= 2;
            }
            config.localizer.previous_observation = Some(true);
        }
        // The trained part switched off; the current node from the agent's
        // record only where the run asks (an ablation's own choice of it
        // is an evaluation setting).
        let executed_node = (video.executed_node || self.executed_node)
            .then_some(true)
            .or(config.ablation.executed_node);
        config.ablation = self.ablation.ablation();
        config.ablation.executed_node = executed_node;
        config.ablation.end_after_demo = self.end_after_demo.then_some(true);
        config.seed = input.model_seed;
        config
    }

    /// What training adds to the paper's losses, for `input`.
    pub fn training<'a>(&self, input: &TrainInput<'a>) -> NtgTraining<'a> {
        NtgTraining {
            gcn_source: if input.other_demo_each_epoch {
                GcnSource::OtherFromEpoch
            } else if self.optim.gcn_from_other_demo {
                GcnSource::OtherSeeded
            } else {
                GcnSource::Own
            },
            token_dropout: self.optim.token_dropout,
            segments: self.segments,
            skip_end: !self.learn_end,
            memory: self.memory,
            retry_weight: self.retry_weight,
            detach_gcn_from_edges: self.detach_gcn_from_edges,
            permute_objects: input.renaming.map(|r| r.symmetry),
            accept_renaming: input.renaming.and_then(|r| r.accept),
            gcn_loss_last: input.other_demo_each_epoch,
        }
    }
}

/// Trains NTG on `input` with `options` (on frame embeddings behind the
/// frozen frame encoder when the demos come with one), selecting the epoch
/// on the input's validation, if any.
pub fn train(
    input: TrainInput<'_>,
    options: &NtgOptions,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    options.check()?;
    let Demos { dataset, frames } = input.load_demos()?;
    if let Some(kind) = options.interpreter
        && kind.states_only()
        && frames.is_some()
    {
        anyhow::bail!(
            "--interpreter {}: its attention is trained one demo row per action, as state demos have; demo videos span several frames per action (--interpreter stepping-video-aligned trains it onto the frame each action ends on)",
            crate::spec::Choice::name(kind)
        );
    }
    let model = NtgModel::new(options.model_config(&input), input.device)?;
    let training = options.training(&input);
    let step = NtgStep::new(&model, &dataset, training, input.device)?;
    fit_model(model, step, frames, &input, input.validation, on_epoch)
}

/// The aligned row of each token of the stretch of a demo from node
/// `start` to node `end` (actions `start..end`, then `<end>`), counted from
/// the stretch's first row, for aligned attention
/// ([`ntg_model::DemoBatch::aligned_rows`]): the keyframe each action ends
/// on, and for `<end>` the last one. `keyframes[k]` is the demo's row at
/// node `k` (a state demo's row `k`: rows `1..=K`, then `K` for the whole
/// demo).
fn aligned_rows(keyframes: &[usize], start: usize, end: usize) -> Vec<usize> {
    (start..end)
        .map(|j| keyframes[j + 1] - keyframes[start])
        .chain(std::iter::once(keyframes[end] - keyframes[start]))
        .collect()
}

/// Which demo interpreter NTG uses (see [`ntg_model::DemoInterpreterConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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
    /// The stepping interpreter with a wider location window for demo
    /// videos: its attention may move on by −1..=[`VIDEO_MAX_SHIFT`]
    /// frames per token (every forward shift starting at the step prior),
    /// so it can jump one action's frames per token (an object-collection
    /// action spans 2–9 frames; −1..=2 stalls on videos).
    SteppingVideo,
    /// The stepping interpreter with its attention trained onto the demo's
    /// rows one per token ([`ntg_model::DemoInterpreterConfig::aligned_attention`]):
    /// token `t` reads row `t + 1`, the state action `t` left, and `<end>`
    /// the final state. The alignment is taught, not left for the
    /// attention to find (the stepping interpreter stalled at one of two
    /// block-stacking seeds). For state demos (one row per action plus the
    /// final state); refused for demo videos.
    SteppingAligned,
    /// The stepping interpreter for demo videos
    /// ([`InterpreterKind::SteppingVideo`]) with its attention trained onto
    /// the keyframe each action ends on (`<end>` the last keyframe;
    /// windows of them where the frames are pooled). For demo videos, and
    /// state demos too (where it reads the rows `SteppingAligned` does).
    SteppingVideoAligned,
}

/// The largest forward shift of [`InterpreterKind::SteppingVideo`]'s
/// location-aware attention: the longest action of an object-collection
/// demo video (a drop-off: approach 4 + open 2 + drop 3 frames) plus one.
pub const VIDEO_MAX_SHIFT: usize = 10;

/// The initial weight of a stepping interpreter's forward location shifts
/// that new runs start from where their domain chooses none of its own:
/// the value object collection chose on validation tasks (0.3; see
/// `ntg_trainer::collect::LOCATION_STEP_PRIOR`).
pub const DEFAULT_LOCATION_STEP_PRIOR: f32 = 0.3;

impl InterpreterKind {
    /// [`DEFAULT_LOCATION_STEP_PRIOR`] for the stepping kinds, none for the
    /// paper's interpreter (it has no location-aware attention).
    pub fn step_prior(self) -> Option<f32> {
        match self {
            InterpreterKind::Luong => None,
            InterpreterKind::Stepping
            | InterpreterKind::SteppingVideo
            | InterpreterKind::SteppingAligned
            | InterpreterKind::SteppingVideoAligned => Some(DEFAULT_LOCATION_STEP_PRIOR),
        }
    }

    /// Whether it reads state demos only (one row per action plus the
    /// final state), not demo videos.
    pub fn states_only(self) -> bool {
        self == InterpreterKind::SteppingAligned
    }

    /// Sets the interpreter options of `config` for this kind, with the
    /// location-aware attention's initial shift +1 weight `step_prior`.
    pub fn apply(self, config: &mut ntg_model::DemoInterpreterConfig, step_prior: Option<f32>) {
        let on = match self {
            InterpreterKind::Luong => None,
            InterpreterKind::Stepping
            | InterpreterKind::SteppingVideo
            | InterpreterKind::SteppingAligned
            | InterpreterKind::SteppingVideoAligned => Some(true),
        };
        config.location_max_shift = matches!(
            self,
            InterpreterKind::SteppingVideo | InterpreterKind::SteppingVideoAligned
        )
        .then_some(VIDEO_MAX_SHIFT);
        config.bidirectional = None;
        config.input_feeding = on;
        config.location_attention = on;
        config.stateless_decoder = on;
        config.local_annotations = on;
        config.location_step_prior = step_prior;
        config.aligned_attention = matches!(
            self,
            InterpreterKind::SteppingAligned | InterpreterKind::SteppingVideoAligned
        )
        .then_some(true);
    }
}

impl crate::spec::Choice for InterpreterKind {
    const ALL: &'static [Self] = &[
        InterpreterKind::Luong,
        InterpreterKind::Stepping,
        InterpreterKind::SteppingVideo,
        InterpreterKind::SteppingAligned,
        InterpreterKind::SteppingVideoAligned,
    ];

    fn name(self) -> &'static str {
        match self {
            InterpreterKind::Luong => "luong",
            InterpreterKind::Stepping => "stepping",
            InterpreterKind::SteppingVideo => "stepping-video",
            InterpreterKind::SteppingAligned => "stepping-aligned",
            InterpreterKind::SteppingVideoAligned => "stepping-video-aligned",
        }
    }

    fn help(self) -> &'static str {
        match self {
            InterpreterKind::Luong => "The paper's: a GRU over the frames and Luong attention",
            InterpreterKind::Stepping => {
                "Length-independent: local annotations, input feeding, location-aware attention"
            }
            InterpreterKind::SteppingVideo => {
                "Stepping, its attention moving up to 10 frames per token (for demo videos)"
            }
            InterpreterKind::SteppingAligned => {
                "Stepping, its attention trained one demo row per action (state demos only)"
            }
            InterpreterKind::SteppingVideoAligned => {
                "Stepping-video, its attention trained onto the frame each action ends on"
            }
        }
    }
}

/// NTG's policy variants: the full model and its ablations, at evaluation
/// (`ntg eval --variant`) and, for the paper's ablations, in training too
/// (`ntg train --ablation`, fig. "ablation" (a); see [`Variant::trains`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// The full NTG model, as trained (its current node from the localizer,
    /// or from the agent's record where the run was configured so).
    #[default]
    Full,
    /// Uniform ε over successors (no edge classifier).
    NoEdgeClassifier,
    /// Uniform ℓ (no node localizer).
    NoNodeLocalizer,
    /// ℓ replaced by the agent's record: the current node is the last
    /// action it executed (not in the paper).
    ExecutedNode,
    /// The current node from the node localizer (the paper's way), also in
    /// a run configured to take it from the agent's record.
    LocalizerNode,
    /// Fully connected initial graph (no demo interpreter).
    NoDemoInterpreter,
    /// The demo's path graph as is (no GCN).
    NoGcn,
}

impl Variant {
    /// The ablation switches of this variant.
    pub fn ablation(self) -> AblationConfig {
        let a = AblationConfig::new();
        match self {
            Variant::Full => a,
            Variant::NoEdgeClassifier => a.with_edge_classifier(false),
            // Uniform ℓ, whatever the run's source of the current node.
            Variant::NoNodeLocalizer => {
                a.with_node_localizer(false).with_executed_node(Some(false))
            }
            Variant::ExecutedNode => a.with_executed_node(Some(true)),
            Variant::LocalizerNode => a.with_executed_node(Some(false)),
            Variant::NoDemoInterpreter => a.with_demo_interpreter(false),
            Variant::NoGcn => a.with_gcn(false),
        }
    }

    /// The switches of this variant for a model trained with `trained`:
    /// the variant's own, with the trained model's source of the current
    /// node unless the variant names one. A part the model was trained
    /// without stays off (a variant never switches on a network that was
    /// not trained, or feeds the edge classifier embeddings it was not
    /// trained with).
    pub fn ablation_of(self, trained: &AblationConfig) -> AblationConfig {
        let mut a = self.ablation();
        a.executed_node = a.executed_node.or(trained.executed_node);
        // The `<end>` rule is part of the policy the run trained and
        // selected with; no variant changes it.
        a.end_after_demo = trained.end_after_demo;
        a.demo_interpreter &= trained.demo_interpreter;
        a.node_localizer &= trained.node_localizer;
        a.edge_classifier &= trained.edge_classifier;
        a.gcn &= trained.gcn;
        a
    }

    /// Whether a model can be trained as this variant (the paper's
    /// ablations, fig. "ablation" (a)): the full model or one without a
    /// part. The others choose where the current node comes from, an
    /// evaluation setting.
    pub fn trains(self) -> bool {
        !matches!(self, Variant::ExecutedNode | Variant::LocalizerNode)
    }

    /// Whether this is [`Variant::Full`] (for serde's `skip_serializing_if`).
    pub fn is_full(&self) -> bool {
        *self == Variant::Full
    }

    /// Name used in files and reports.
    pub fn name(self) -> &'static str {
        crate::spec::Choice::name(self)
    }
}

impl crate::spec::Choice for Variant {
    const ALL: &'static [Self] = &[
        Variant::Full,
        Variant::NoEdgeClassifier,
        Variant::NoNodeLocalizer,
        Variant::ExecutedNode,
        Variant::LocalizerNode,
        Variant::NoDemoInterpreter,
        Variant::NoGcn,
    ];

    fn help(self) -> &'static str {
        match self {
            Variant::Full => "The full NTG model, as trained",
            Variant::NoEdgeClassifier => "Uniform over successors (no edge classifier)",
            Variant::NoNodeLocalizer => "Uniform current node (no node localizer)",
            Variant::ExecutedNode => {
                "The current node is the last action executed (not in the paper)"
            }
            Variant::LocalizerNode => "The current node from the node localizer (the paper's way)",
            Variant::NoDemoInterpreter => "Fully connected initial graph (no demo interpreter)",
            Variant::NoGcn => "The demo's path graph as is (no GCN)",
        }
    }

    fn name(self) -> &'static str {
        match self {
            Variant::Full => "full",
            Variant::NoEdgeClassifier => "no-edge-classifier",
            Variant::NoNodeLocalizer => "no-node-localizer",
            Variant::ExecutedNode => "executed-node",
            Variant::LocalizerNode => "localizer-node",
            Variant::NoDemoInterpreter => "no-demo-interpreter",
            Variant::NoGcn => "no-gcn",
        }
    }
}

impl std::fmt::Display for Variant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// NTG in the method registry.
pub struct Ntg;

impl crate::method::Method for Ntg {
    fn name(&self) -> &'static str {
        "ntg"
    }
    fn legend(&self) -> &'static str {
        "NTG (ours)"
    }
    fn load(&self, dir: &std::path::Path, device: &Device) -> anyhow::Result<Model> {
        super::on_frames::load_either::<NtgModel>(dir, device)
    }
    fn options(&self) -> &'static [&'static str] {
        NtgOptions::KEYS
    }
    fn check(&self, config: &serde_json::Value) -> anyhow::Result<()> {
        crate::method::input::options_of::<NtgOptions>(self.legend(), config)?.check()
    }
    fn train(
        &self,
        input: TrainInput<'_>,
        config: &serde_json::Value,
        on_epoch: &mut dyn FnMut(&EpochReport),
    ) -> anyhow::Result<Model> {
        let options: NtgOptions = crate::method::input::options_of(self.legend(), config)?;
        train(input, &options, on_epoch)
    }
}

impl TrainedPolicy for NtgModel {
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &ctg_graph::Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        Ok(Box::new(NtgAgent {
            policy: NtgPolicy::from_demo(self, demo, vocabulary)?,
            names: (0..vocabulary.len())
                .map(|i| vocabulary.name(ActionId::new(i)).unwrap_or("?").to_owned())
                .collect(),
            previous: std::cell::RefCell::new(None),
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn export_safetensors(
        &self,
        dir: &std::path::Path,
    ) -> anyhow::Result<Vec<crate::method::ExportedFile>> {
        Ok(vec![crate::method::export_network(self, dir, "")?])
    }
}

/// NTG's agent as evaluation conditions it: the graph executor over the
/// demo's completed task graph (the policy), with the names of its nodes,
/// so that [`Agent::explain`] can say which node the localizer read from
/// the frame.
struct NtgAgent {
    policy: NtgPolicy,
    names: Vec<String>,
    /// The observation of the last decision (for a localizer with
    /// temporal context).
    previous: std::cell::RefCell<Option<Vec<f32>>>,
}

impl Agent for NtgAgent {
    fn act(
        &self,
        row: &[f32],
        executed: &[ActionId],
        ties: &mut crate::method::Ties,
    ) -> anyhow::Result<ActionId> {
        if self.policy.reads_previous_observation() {
            let mut previous = self.previous.borrow_mut();
            self.policy.set_previous_observation(previous.as_deref());
            *previous = Some(row.to_vec());
        }
        self.policy.set_executed(executed);
        Ok(self
            .policy
            .action_distribution(row)?
            .most_likely_breaking_ties(ties.draw()))
    }
    fn transcription(&self) -> &[ActionId] {
        self.policy.demo_actions()
    }
    /// `localized NODE P, NODE P`: the node localizer's two most likely
    /// nodes for the last observation (nothing where the node came from the
    /// agent's record).
    fn explain(&self) -> Option<String> {
        let p = self.policy.last_localizer_probabilities()?;
        Some(format!("localized {}", localized_top(&p, &self.names, 2)))
    }
}

/// The `k` most likely nodes of `p` as `NAME P` joined by `, ` (lowest id
/// first on ties).
fn localized_top(p: &[f32], names: &[String], k: usize) -> String {
    let mut order: Vec<usize> = (0..p.len()).collect();
    order.sort_by(|&a, &b| p[b].total_cmp(&p[a]).then(a.cmp(&b)));
    order
        .into_iter()
        .take(k)
        .map(|i| format!("{} {:.3}", names.get(i).map_or("?", String::as_str), p[i]))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aligned_rows_are_the_keyframes_actions_end_on_then_the_last() {
        // A state demo: rows 1..=K, then K (the model's own rule).
        assert_eq!(aligned_rows(&[0, 1, 2, 3], 0, 3), vec![1, 2, 3, 3]);
        // A video: the frame each action ends on, counted from the stretch.
        let key = [0, 7, 12, 20, 26];
        assert_eq!(aligned_rows(&key, 0, 4), vec![7, 12, 20, 26, 26]);
        assert_eq!(aligned_rows(&key, 1, 3), vec![5, 13, 13]);
    }

    #[test]
    fn the_video_aligned_interpreter_is_stepping_video_taught_its_alignment() {
        let encoder = ntg_model::EncoderConfig::State(ntg_model::StateEncoderConfig::new(4));
        let mut config = ntg_model::DemoInterpreterConfig::new(18, encoder);
        InterpreterKind::SteppingVideoAligned.apply(&mut config, Some(0.3));
        assert_eq!(config.aligned_attention, Some(true));
        assert_eq!(config.location_max_shift, Some(VIDEO_MAX_SHIFT));
        assert_eq!(config.location_attention, Some(true));
        assert!(!InterpreterKind::SteppingVideoAligned.states_only());
        InterpreterKind::SteppingVideo.apply(&mut config, Some(0.3));
        assert_eq!(config.aligned_attention, None);
    }

    #[test]
    fn the_listed_option_keys_are_the_keys_the_options_are_read_from() {
        let options = NtgOptions {
            video: Some(NtgVideoOptions::default()),
            ..NtgOptions::default()
        };
        let serde_json::Value::Object(top) = serde_json::to_value(&options).unwrap() else {
            panic!("options serialise to an object");
        };
        let mut keys = Vec::new();
        for (key, value) in top {
            match value {
                serde_json::Value::Object(inner) => {
                    keys.extend(inner.keys().map(|k| format!("{key}.{k}")))
                }
                _ => keys.push(key),
            }
        }
        let mut listed: Vec<String> = NtgOptions::KEYS.iter().map(|k| k.to_string()).collect();
        keys.sort();
        listed.sort();
        assert_eq!(keys, listed);
        // Read back from the same keys, the options are what was written.
        let json = serde_json::to_value(&options).unwrap();
        assert_eq!(NtgOptions::deserialize(json).unwrap(), options);
    }

    #[test]
    fn the_explanation_names_the_most_likely_nodes_first() {
        let names: Vec<String> = ["<start>", "pick(A)", "place(B)"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(
            localized_top(&[0.1, 0.3, 0.6], &names, 2),
            "place(B) 0.600, pick(A) 0.300"
        );
        // Ties keep the lower id first.
        assert_eq!(
            localized_top(&[0.5, 0.5, 0.0], &names, 2),
            "<start> 0.500, pick(A) 0.500"
        );
    }

    #[test]
    fn full_keeps_the_trained_source_of_the_current_node_and_others_name_theirs() {
        let localizer = AblationConfig::new();
        let executed = AblationConfig::new().with_executed_node(Some(true));
        assert_eq!(Variant::Full.ablation_of(&localizer).executed_node, None);
        assert_eq!(
            Variant::Full.ablation_of(&executed).executed_node,
            Some(true)
        );
        let forced = Variant::LocalizerNode.ablation_of(&executed);
        assert_eq!(forced.executed_node, Some(false));
        assert_eq!(
            Variant::ExecutedNode.ablation_of(&localizer).executed_node,
            Some(true)
        );
        // An ablation keeps the trained source and switches its part off.
        let no_gcn = Variant::NoGcn.ablation_of(&executed);
        assert!(!no_gcn.gcn);
        assert_eq!(no_gcn.executed_node, Some(true));
        // Without the localizer ℓ is uniform, not the agent's record.
        let uniform = Variant::NoNodeLocalizer.ablation_of(&executed);
        assert!(!uniform.node_localizer);
        assert_eq!(uniform.executed_node, Some(false));
        // The `<end>` rule stays what the run trained with, in every variant.
        let ruled = AblationConfig::new().with_end_after_demo(Some(true));
        for variant in [Variant::Full, Variant::LocalizerNode, Variant::NoGcn] {
            assert_eq!(variant.ablation_of(&ruled).end_after_demo, Some(true));
            assert_eq!(variant.ablation_of(&localizer).end_after_demo, None);
        }
        // A model trained without a part: no variant switches it back on.
        let trained = AblationConfig::new()
            .with_gcn(false)
            .with_edge_classifier(false);
        for variant in [
            Variant::Full,
            Variant::NoDemoInterpreter,
            Variant::LocalizerNode,
        ] {
            let a = variant.ablation_of(&trained);
            assert!(!a.gcn && !a.edge_classifier, "{variant:?}");
        }
        assert!(
            !Variant::NoDemoInterpreter
                .ablation_of(&trained)
                .demo_interpreter
        );
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
        let old = concat!(
            r#"{"epoch":0,"loss":1.0,"interpreter_loss":0.0,"token_accuracy":0.0,"gcn_loss":0.0,"edge_f1":1.0,"#,
            r#""localizer_loss":0.0,"localizer_accuracy":0.0,"edge_loss":0.0,"step_accuracy":0.0,"seconds":0.0}"#
        );
        let parsed: EpochMetrics = serde_json::from_str(old).unwrap();
        assert_eq!(parsed.edge_f1, Some(1.0));
    }
}
