//! The NTG policy: demo → CTG → completed CTG → neural scorers for
//! `ctg_graph`'s executor.

use std::cell::RefCell;

use burn::module::Module;
use burn::tensor::Tensor;
use ctg_graph::{
    ActionDistribution, ActionId, Ctg, CtgError, EdgeScorer, GraphExecutor, NodeScorer,
    NodeSelection, Vocabulary,
};

use crate::batch::rows_tensor;
use crate::model::NtgModel;
use crate::nn::to_vec;
use crate::{ModelError, Result};

/// Raw scores of one observation, computed once and reused by the node and
/// edge scorers.
#[derive(Debug, Clone)]
struct Scores {
    observation: Vec<f32>,
    memory: Option<Vec<f32>>,
    /// The previous observation the localizer read with this one (with
    /// temporal context; `None` otherwise).
    previous: Option<Vec<f32>>,
    /// The last executed action, when the node comes from the record.
    executed_node: Option<ActionId>,
    /// Whether `<end>` is blocked where another successor exists
    /// ([`crate::AblationConfig::end_after_demo`] with demo actions
    /// pending).
    end_blocked: bool,
    /// Localizer logits `[N]` (`None` when the localizer is ablated;
    /// 0 at the executed node and −∞ elsewhere with
    /// [`crate::AblationConfig::executed_node`]).
    node_logits: Option<Vec<f32>>,
    /// Edge logits `[N × N]`, row = current node (`None` when ablated).
    edge_logits: Option<Vec<f32>>,
}

/// A reactive policy built from one demonstration:
/// `π(a|o) ∝ Σ_n ε(a|n,o) ℓ(n|o)` over the edges of the CTG the demo
/// interpreter and GCN produced (or `ε(a|n*,o)` at the arg-max node, per
/// the config's [`NodeSelection`]).
///
/// It implements [`NodeScorer`] and [`EdgeScorer`] for flat observation
/// rows `[f32]`, both on itself and on `&NtgPolicy`, so one policy can be
/// passed as both scorers: `executor.run(&mut env, &mut &policy, &mut &policy, seed)`.
/// The encodings of the last observation are cached, so the node and edge
/// calls for one observation run the networks once.
///
/// The scorers return probabilities: ℓ(·|o) a softmax over nodes, each row
/// of ε(·|n,o) a softmax over the successors of `n` in the graph the
/// executor passes (zero elsewhere, and an all-zero row for a node without
/// successors).
///
/// With [`NtgConfig::soft_edges`](crate::NtgConfig::soft_edges) the policy
/// executes every edge the fully connected graph allows, each row of
/// ε(·|n,o) weighted by the completed graph's edge probabilities,
/// `ε(a|n,o) ∝ C_na · exp(s(a|n,o))` ([`NtgPolicy::edge_weights`]);
/// [`NtgPolicy::graph`] is still the thresholded graph (for display).
#[derive(Debug)]
pub struct NtgPolicy {
    model: NtgModel,
    demo_actions: Vec<ActionId>,
    initial: Ctg,
    probabilities: Ctg,
    graph: Ctg,
    /// The graph the policy executes: `graph`, or with soft edges the
    /// support of `weights`.
    execution: Ctg,
    /// Soft-edge weights (`None`: the hard mask).
    weights: Option<Ctg>,
    ne_gcn: Tensor<2>,
    memory: RefCell<Option<Vec<f32>>>,
    /// The last action executed (`<start>` before the first), from
    /// [`NtgPolicy::set_executed`].
    last_executed: RefCell<ActionId>,
    /// Whether an action of the demo's transcription has not been executed
    /// yet, from [`NtgPolicy::set_executed`] (read only with
    /// [`crate::AblationConfig::end_after_demo`]).
    demo_pending: RefCell<bool>,
    /// The observation acted on before the current one, from
    /// [`NtgPolicy::set_previous_observation`].
    previous: RefCell<Option<Vec<f32>>>,
    cache: RefCell<Option<Scores>>,
}

impl NtgPolicy {
    /// Builds the policy for the task shown by one demonstration (its
    /// observation rows, in order): demo interpreter → path CTG → GCN →
    /// thresholded CTG. `vocab` must be the model's domain vocabulary.
    pub fn from_demo<R: AsRef<[f32]>>(
        model: &NtgModel,
        demo_observations: &[R],
        vocab: &Vocabulary,
    ) -> Result<Self> {
        check_vocab(model, vocab)?;
        let model = model.valid();
        let (actions, initial) = model.initial_graph(demo_observations)?;
        Self::build(model, actions, initial)
    }

    /// Builds the policy from a given initial graph (skipping the demo
    /// interpreter), e.g. a ground-truth path or the union of several demos.
    pub fn from_graph(model: &NtgModel, initial: Ctg) -> Result<Self> {
        Self::build(model.valid(), Vec::new(), initial)
    }

    /// Builds the policy from a known action sequence (its path graph).
    pub fn from_actions(model: &NtgModel, actions: &[ActionId]) -> Result<Self> {
        let initial = Ctg::from_path(model.num_nodes(), actions)?;
        Self::build(model.valid(), actions.to_vec(), initial)
    }

    fn build(model: NtgModel, demo_actions: Vec<ActionId>, initial: Ctg) -> Result<Self> {
        let completed = model.complete_graph(&initial)?;
        let (execution, weights) = if model.config.uses_soft_edges() {
            let weights = model.edge_weights(&initial, &completed.probabilities)?;
            (weights.threshold(f32::MIN_POSITIVE)?, Some(weights))
        } else {
            (completed.graph.clone(), None)
        };
        Ok(NtgPolicy {
            model,
            demo_actions,
            initial,
            probabilities: completed.probabilities,
            graph: completed.graph,
            execution,
            weights,
            ne_gcn: completed.embeddings,
            memory: RefCell::new(None),
            last_executed: RefCell::new(Vocabulary::START),
            demo_pending: RefCell::new(false),
            previous: RefCell::new(None),
            cache: RefCell::new(None),
        })
    }

    /// The demo interpreter's transcription (empty if it was not used).
    pub fn demo_actions(&self) -> &[ActionId] {
        &self.demo_actions
    }

    /// The initial CTG (the demo's path, or fully connected when ablated).
    pub fn initial_graph(&self) -> &Ctg {
        &self.initial
    }

    /// The GCN's edge probabilities.
    pub fn edge_probabilities(&self) -> &Ctg {
        &self.probabilities
    }

    /// The thresholded CTG (the graph this policy executes, unless it uses
    /// soft edges).
    pub fn graph(&self) -> &Ctg {
        &self.graph
    }

    /// The graph this policy executes: [`NtgPolicy::graph`], or with soft
    /// edges every edge of positive weight.
    pub fn execution_graph(&self) -> &Ctg {
        &self.execution
    }

    /// The soft-edge weights `C` (`None` for the hard mask).
    pub fn edge_weights(&self) -> Option<&Ctg> {
        self.weights.as_ref()
    }

    /// An executor over [`NtgPolicy::execution_graph`] with the configured
    /// node selection.
    pub fn executor(&self) -> GraphExecutor {
        GraphExecutor::new(self.execution.clone())
            .with_node_selection(self.model.config.node_selection)
    }

    /// Whether the edge classifier reads an execution memory (then
    /// [`NtgPolicy::set_executed`] must be called before scoring).
    pub fn has_memory(&self) -> bool {
        self.model.edges.memory_dim > 0
    }

    /// Whether the current node is taken from the record of executed
    /// actions ([`crate::AblationConfig::executed_node`]; then
    /// [`NtgPolicy::set_executed`] must be called before scoring).
    pub fn uses_executed_node(&self) -> bool {
        self.model.config.ablation.executed_node == Some(true)
    }

    /// Tells a policy with an execution memory which actions the agent has
    /// taken so far in this episode; its edge classifier then reads
    /// [`crate::pending_nodes`] of the initial graph (the demo's path). With
    /// [`crate::AblationConfig::executed_node`] the last of them is the
    /// current node. A no-op for a policy without either.
    pub fn set_executed(&self, executed: &[ActionId]) {
        *self.last_executed.borrow_mut() = executed.last().copied().unwrap_or(Vocabulary::START);
        *self.demo_pending.borrow_mut() = self
            .demo_actions
            .iter()
            .any(|action| !executed.contains(action));
        if self.has_memory() {
            *self.memory.borrow_mut() = Some(crate::pending_nodes(&self.initial, executed));
        }
    }

    /// Whether `<end>` waits for the demo's actions
    /// ([`crate::AblationConfig::end_after_demo`]; then
    /// [`NtgPolicy::set_executed`] must be called before scoring).
    pub fn ends_after_demo(&self) -> bool {
        self.model.config.ablation.end_after_demo == Some(true)
    }

    /// Whether the localizer reads the previous observation too
    /// ([`crate::NodeLocalizerConfig::previous_observation`]; then the
    /// agent tells it with [`NtgPolicy::set_previous_observation`]).
    pub fn reads_previous_observation(&self) -> bool {
        self.model.config.localizer.reads_previous()
    }

    /// Tells a localizer with temporal context the observation the agent
    /// acted on before the one it scores next (`None` at the first
    /// decision of an episode: the observation is then its own previous
    /// one, as the first frame of a demo is in training). A no-op for a
    /// localizer without it.
    pub fn set_previous_observation(&self, previous: Option<&[f32]>) {
        if self.reads_previous_observation() {
            *self.previous.borrow_mut() = previous.map(<[f32]>::to_vec);
        }
    }

    /// The model (in inference mode) behind this policy.
    pub fn model(&self) -> &NtgModel {
        &self.model
    }

    /// π(·|o) for one observation row.
    pub fn action_distribution(&self, observation: &[f32]) -> Result<ActionDistribution> {
        let exec = self.executor();
        Ok(exec.action_distribution(&mut &*self, &mut &*self, observation)?)
    }

    /// `ln π(a|o)` for every node `a` (`-inf` where π is 0), computed in
    /// log space so small probabilities do not underflow; consistent with
    /// [`NtgPolicy::action_distribution`].
    pub fn log_probabilities(&self, observation: &[f32]) -> Result<Vec<f32>> {
        let scores = self.scores(observation)?;
        let n = self.execution.num_nodes();
        let log_node = log_node_probabilities(&scores, n);
        // Log-ε rows over successors; None for nodes without successors.
        let log_edge: Vec<Option<Vec<f64>>> = (0..n)
            .map(|from| log_edge_row(&self.execution, self.weights.as_ref(), &scores, from))
            .collect();
        let mut out = vec![f64::NEG_INFINITY; n];
        match self.model.config.node_selection {
            NodeSelection::Marginal => {
                let valid: Vec<f64> = (0..n)
                    .filter(|&i| log_edge[i].is_some())
                    .map(|i| log_node[i])
                    .collect();
                let norm = log_sum_exp(&valid);
                for (a, slot) in out.iter_mut().enumerate() {
                    let terms: Vec<f64> = (0..n)
                        .filter_map(|from| {
                            log_edge[from].as_ref().map(|row| log_node[from] + row[a])
                        })
                        .collect();
                    *slot = log_sum_exp(&terms) - norm;
                }
            }
            NodeSelection::ArgMax => {
                // Same choice as the executor: the most likely node with a
                // successor (lowest id on ties).
                let best = (0..n)
                    .filter(|&i| log_edge[i].is_some() && log_node[i] > f64::NEG_INFINITY)
                    .max_by(|&a, &b| log_node[a].total_cmp(&log_node[b]).then(b.cmp(&a)));
                if let Some(row) = best.and_then(|i| log_edge[i].as_ref()) {
                    out.copy_from_slice(row);
                }
            }
        }
        if out.iter().all(|&l| l == f64::NEG_INFINITY || l.is_nan()) {
            return Err(CtgError::NoValidAction.into());
        }
        Ok(out.into_iter().map(|l| l as f32).collect())
    }

    /// `ln π(action|o)`, for negative log-likelihood scoring.
    pub fn log_probability(&self, observation: &[f32], action: ActionId) -> Result<f32> {
        let all = self.log_probabilities(observation)?;
        all.get(action.index()).copied().ok_or_else(|| {
            ModelError::Input(format!(
                "action {} is outside the {} nodes",
                action.index(),
                all.len()
            ))
        })
    }

    /// ℓ(·|o) of the observation scored last, as probabilities over all
    /// `N` nodes: what the node localizer read from it. `None` before the
    /// first observation, and where the localizer did not choose the node
    /// (the node taken from the agent's record, or the localizer ablated).
    pub fn last_localizer_probabilities(&self) -> Option<Vec<f32>> {
        let cache = self.cache.borrow();
        let scores = cache.as_ref()?;
        if scores.executed_node.is_some() || scores.node_logits.is_none() {
            return None;
        }
        let n = self.graph.num_nodes();
        Some(
            log_node_probabilities(scores, n)
                .into_iter()
                .map(|l| l.exp() as f32)
                .collect(),
        )
    }

    /// ℓ(n|o) as probabilities over all `N` nodes.
    pub fn node_probabilities(&self, observation: &[f32]) -> Result<Vec<f32>> {
        let scores = self.scores(observation)?;
        let n = self.graph.num_nodes();
        Ok(log_node_probabilities(&scores, n)
            .into_iter()
            .map(|l| l.exp() as f32)
            .collect())
    }

    /// ℓ(n|o) as the graph executor over `graph` reads it:
    /// [`NtgPolicy::node_probabilities`], unless every node from which an
    /// action can follow in `graph` (a node with a successor, as
    /// [`NtgPolicy::edge_probabilities_for`] scores them) has probability 0
    /// in `f32`, because the localizer is sure beyond `f32`'s range of a
    /// node without one (such as `<end>`). Then ℓ renormalised over those
    /// nodes, computed in log space (0 elsewhere). The executor divides
    /// by the mass of those nodes anyway, so this is the same action
    /// distribution (as [`NtgPolicy::log_probabilities`] computes it);
    /// from the underflowed one the executor would find no action at all.
    pub fn executable_node_probabilities(
        &self,
        graph: &Ctg,
        observation: &[f32],
    ) -> Result<Vec<f32>> {
        let scores = self.scores(observation)?;
        let n = graph.num_nodes();
        let acts: Vec<bool> = (0..n)
            .map(|i| log_edge_row(graph, self.weights.as_ref(), &scores, i).is_some())
            .collect();
        Ok(renormalised_if_underflowed(
            &log_node_probabilities(&scores, n),
            &acts,
        ))
    }

    /// ε(·|n,o) as an `N × N` row-major matrix of probabilities over the
    /// successors of each node in `graph` (weighted by the soft-edge
    /// weights, if any).
    pub fn edge_probabilities_for(&self, graph: &Ctg, observation: &[f32]) -> Result<Vec<f32>> {
        let scores = self.scores(observation)?;
        let n = graph.num_nodes();
        if n != self.graph.num_nodes() {
            return Err(ModelError::shape(
                "graph",
                format!("{} nodes", self.graph.num_nodes()),
                n,
            ));
        }
        let mut out = vec![0.0f32; n * n];
        for from in 0..n {
            if let Some(row) = log_edge_row(graph, self.weights.as_ref(), &scores, from) {
                for (o, l) in out[from * n..(from + 1) * n].iter_mut().zip(row) {
                    *o = l.exp() as f32;
                }
            }
        }
        Ok(out)
    }

    /// Runs (or reuses) the networks on one observation.
    fn scores(&self, observation: &[f32]) -> Result<Scores> {
        let memory = self.memory.borrow().clone();
        let previous = self.previous.borrow().clone();
        let executed_node = self
            .uses_executed_node()
            .then(|| *self.last_executed.borrow());
        let end_blocked = self.ends_after_demo() && *self.demo_pending.borrow();
        if let Some(cached) = self.cache.borrow().as_ref()
            && cached.observation == observation
            && cached.memory == memory
            && cached.previous == previous
            && cached.executed_node == executed_node
            && cached.end_blocked == end_blocked
        {
            return Ok(cached.clone());
        }
        let model = &self.model;
        let ablation = &model.config.ablation;
        let device = model.device();
        let obs = rows_tensor(&[observation], model.obs_dim(), &device)?;
        let n = model.num_nodes();
        let node_logits = if let Some(node) = executed_node {
            if node.index() >= n {
                return Err(ModelError::Input(format!(
                    "executed action {} is outside the {n} nodes",
                    node.index()
                )));
            }
            Some(
                (0..n)
                    .map(|i| {
                        if i == node.index() {
                            0.0
                        } else {
                            f32::NEG_INFINITY
                        }
                    })
                    .collect(),
            )
        } else if ablation.node_localizer {
            let input = if model.config.localizer.reads_previous() {
                let before = match &previous {
                    Some(p) => rows_tensor(&[p.as_slice()], model.obs_dim(), &device)?,
                    None => obs.clone(),
                };
                crate::localizer::NodeLocalizer::in_context(obs.clone(), before)?
            } else {
                obs.clone()
            };
            Some(to_vec(model.localizer.forward(input)?)?)
        } else {
            None
        };
        let edge_logits = if ablation.edge_classifier {
            let encoded = model.edges.encoder.forward(obs)?; // [1, H]
            let h = encoded.dims()[1];
            let encoded = encoded.expand([n, h]);
            let memory = match (&memory, model.edges.memory_dim) {
                (_, 0) => None,
                (Some(m), dim) => {
                    Some(rows_tensor(&[m.as_slice()], dim, &device)?.expand([n, dim]))
                }
                (None, _) => {
                    return Err(ModelError::Config(
                        "the edge classifier reads an execution memory: call set_executed first"
                            .into(),
                    ));
                }
            };
            model.edges.check_memory(n, memory.as_ref())?;
            let logits = model.edges.unmasked_logits(
                encoded,
                self.ne_gcn.clone(),
                model.localizer.node_embeddings(),
                memory,
            );
            Some(to_vec(logits)?)
        } else {
            None
        };
        let scores = Scores {
            observation: observation.to_vec(),
            memory,
            previous,
            executed_node,
            end_blocked,
            node_logits,
            edge_logits,
        };
        *self.cache.borrow_mut() = Some(scores.clone());
        Ok(scores)
    }
}

fn check_vocab(model: &NtgModel, vocab: &Vocabulary) -> Result<()> {
    if vocab.len() != model.num_nodes() {
        return Err(ModelError::Config(format!(
            "the vocabulary has {} nodes but the model was built for {}",
            vocab.len(),
            model.num_nodes()
        )));
    }
    Ok(())
}

fn log_sum_exp(values: &[f64]) -> f64 {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        return f64::NEG_INFINITY;
    }
    max + values.iter().map(|v| (v - max).exp()).sum::<f64>().ln()
}

/// ln ℓ(n|o) for every node: a log-softmax of the localizer logits, or
/// uniform when ablated.
fn log_node_probabilities(scores: &Scores, n: usize) -> Vec<f64> {
    match &scores.node_logits {
        Some(logits) => {
            let l: Vec<f64> = logits.iter().map(|&x| f64::from(x)).collect();
            let z = log_sum_exp(&l);
            l.into_iter().map(|x| x - z).collect()
        }
        None => vec![-(n as f64).ln(); n],
    }
}

/// `exp(log_node)` as `f32`, or, where that is 0 at every node `acts`
/// marks while the log-probabilities of some are finite, the distribution
/// renormalised over the marked nodes in log space (0 elsewhere); see
/// [`NtgPolicy::executable_node_probabilities`].
fn renormalised_if_underflowed(log_node: &[f64], acts: &[bool]) -> Vec<f32> {
    let probabilities: Vec<f32> = log_node.iter().map(|l| l.exp() as f32).collect();
    let kept: Vec<f64> = (0..log_node.len())
        .filter(|&i| acts[i])
        .map(|i| log_node[i])
        .collect();
    let norm = log_sum_exp(&kept);
    let underflowed = norm > f64::NEG_INFINITY
        && (0..log_node.len()).all(|i| !acts[i] || probabilities[i] == 0.0);
    if !underflowed {
        return probabilities;
    }
    (0..log_node.len())
        .map(|i| {
            if acts[i] {
                (log_node[i] - norm).exp() as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// ln ε(·|from,o) over the successors of `from` in `graph` (−∞ elsewhere),
/// or `None` if `from` has no successors. With soft-edge `weights`, each
/// successor's logit is raised by `ln C` (successors of weight 0 dropped).
fn log_edge_row(
    graph: &Ctg,
    weights: Option<&Ctg>,
    scores: &Scores,
    from: usize,
) -> Option<Vec<f64>> {
    let n = graph.num_nodes();
    let weight = |to: usize| {
        weights.map_or(1.0, |w| {
            f64::from(w.weight(ActionId::new(from), ActionId::new(to)))
        })
    };
    let mut succ: Vec<bool> = (0..n)
        .map(|to| graph.has_edge(ActionId::new(from), ActionId::new(to)) && weight(to) > 0.0)
        .collect();
    // `<end>` waits for the demo's pending actions where the node leads
    // elsewhere too (`AblationConfig::end_after_demo`).
    let end = Vocabulary::END.index();
    if scores.end_blocked && end < n && succ[end] && succ.iter().filter(|&&s| s).count() > 1 {
        succ[end] = false;
    }
    let count = succ.iter().filter(|&&s| s).count();
    if count == 0 {
        return None;
    }
    let raw: Vec<f64> = match &scores.edge_logits {
        Some(logits) => logits[from * n..(from + 1) * n]
            .iter()
            .map(|&x| f64::from(x))
            .collect(),
        None => vec![0.0; n],
    };
    let raw: Vec<f64> = if weights.is_some() {
        raw.iter()
            .enumerate()
            .map(|(a, &x)| if succ[a] { x + weight(a).ln() } else { x })
            .collect()
    } else {
        raw
    };
    let kept: Vec<f64> = (0..n).filter(|&a| succ[a]).map(|a| raw[a]).collect();
    let z = log_sum_exp(&kept);
    Some(
        (0..n)
            .map(|a| {
                if succ[a] {
                    raw[a] - z
                } else {
                    f64::NEG_INFINITY
                }
            })
            .collect(),
    )
}

fn to_ctg_error(e: ModelError) -> CtgError {
    match e {
        ModelError::Graph(g) => g,
        other => CtgError::InvalidScores(format!("ntg-model: {other}")),
    }
}

impl NodeScorer<[f32]> for &NtgPolicy {
    fn score_nodes(&mut self, graph: &Ctg, observation: &[f32]) -> ctg_graph::Result<Vec<f32>> {
        if graph.num_nodes() != self.execution.num_nodes() {
            return Err(CtgError::SizeMismatch {
                left: graph.num_nodes(),
                right: self.graph.num_nodes(),
            });
        }
        self.executable_node_probabilities(graph, observation)
            .map_err(to_ctg_error)
    }
}

impl EdgeScorer<[f32]> for &NtgPolicy {
    fn score_edges(&mut self, graph: &Ctg, observation: &[f32]) -> ctg_graph::Result<Vec<f32>> {
        self.edge_probabilities_for(graph, observation)
            .map_err(to_ctg_error)
    }
}

impl NodeScorer<[f32]> for NtgPolicy {
    fn score_nodes(&mut self, graph: &Ctg, observation: &[f32]) -> ctg_graph::Result<Vec<f32>> {
        (&*self).score_nodes(graph, observation)
    }
}

impl EdgeScorer<[f32]> for NtgPolicy {
    fn score_edges(&mut self, graph: &Ctg, observation: &[f32]) -> ctg_graph::Result<Vec<f32>> {
        (&*self).score_edges(graph, observation)
    }
}

/// Adapts an [`NtgPolicy`] to an environment whose observations are not
/// flat rows: `flatten` turns each observation into its row.
///
/// Like the policy, `&MappedPolicy` is both scorers:
/// `executor.run(&mut env, &mut &mapped, &mut &mapped, seed)`.
pub struct MappedPolicy<'a, F> {
    policy: &'a NtgPolicy,
    flatten: F,
}

impl NtgPolicy {
    /// This policy for observations of type `O`, flattened by `flatten`.
    pub fn mapped<O: ?Sized, F: Fn(&O) -> Vec<f32>>(&self, flatten: F) -> MappedPolicy<'_, F> {
        MappedPolicy {
            policy: self,
            flatten,
        }
    }
}

impl<O: ?Sized, F: Fn(&O) -> Vec<f32>> NodeScorer<O> for &MappedPolicy<'_, F> {
    fn score_nodes(&mut self, graph: &Ctg, observation: &O) -> ctg_graph::Result<Vec<f32>> {
        let row = (self.flatten)(observation);
        (&*self.policy).score_nodes(graph, row.as_slice())
    }
}

impl<O: ?Sized, F: Fn(&O) -> Vec<f32>> EdgeScorer<O> for &MappedPolicy<'_, F> {
    fn score_edges(&mut self, graph: &Ctg, observation: &O) -> ctg_graph::Result<Vec<f32>> {
        let row = (self.flatten)(observation);
        (&*self.policy).score_edges(graph, row.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log_softmax(logits: &[f64]) -> Vec<f64> {
        let z = log_sum_exp(logits);
        logits.iter().map(|l| l - z).collect()
    }

    /// The localizer sure, beyond `f32`'s range, of node 0, from which no
    /// action follows: the executor gets the other nodes' probabilities
    /// renormalised, in the ratio of their logits, not zeros.
    #[test]
    fn node_probabilities_underflowing_at_every_acting_node_are_renormalised_over_them() {
        let log_node = log_softmax(&[200.0, 0.0, -5.0]);
        let acts = [false, true, true];
        assert_eq!(
            log_node.iter().map(|l| l.exp() as f32).collect::<Vec<_>>()[1..],
            [0.0, 0.0]
        );
        let p = renormalised_if_underflowed(&log_node, &acts);
        assert_eq!(p[0], 0.0);
        assert!((p[1] - 1.0 / (1.0 + (-5.0f32).exp())).abs() < 1e-6, "{p:?}");
        assert!((p[1] + p[2] - 1.0).abs() < 1e-6);
    }

    /// Otherwise the probabilities are the plain ones, bit for bit, and no
    /// node at all to act from stays no node.
    #[test]
    fn other_node_probabilities_are_left_as_they_are() {
        let log_node = log_softmax(&[2.0, 0.0, -5.0]);
        let plain: Vec<f32> = log_node.iter().map(|l| l.exp() as f32).collect();
        assert_eq!(
            renormalised_if_underflowed(&log_node, &[false, true, true]),
            plain
        );
        let sure = log_softmax(&[200.0, 0.0, -5.0]);
        let plain: Vec<f32> = sure.iter().map(|l| l.exp() as f32).collect();
        assert_eq!(
            renormalised_if_underflowed(&sure, &[false, false, false]),
            plain
        );
        let only_end = [0.0, f64::NEG_INFINITY, f64::NEG_INFINITY];
        assert_eq!(
            renormalised_if_underflowed(&only_end, &[false, true, true]),
            [1.0, 0.0, 0.0]
        );
    }
}
