//! The graph executor: a CTG plus node and edge scorers is a reactive policy.
//!
//! At each step the executor asks a [`NodeScorer`] where in the graph the
//! current observation is, ℓ(n|o), and an [`EdgeScorer`] which outgoing edge
//! to take from each node, ε(a|n,o). Edge scores are masked to the node's
//! CTG successors and normalised per node, then combined:
//!
//! π(a|o) ∝ Σ_n ε(a|n,o) ℓ(n|o)            ([`NodeSelection::Marginal`])
//!
//! or, with [`NodeSelection::ArgMax`], π(a|o) = ε(a|n*,o) for the most likely
//! node n*. The network scorers live in `ntg-model`; the symbolic ones here
//! ([`UniformNodeScorer`], [`UniformEdgeScorer`], [`OracleNodeScorer`],
//! [`OracleEdgeScorer`]) make the executor testable without a network.

use crate::{ActionId, Ctg, CtgError, Environment, Result, Vocabulary};

/// Scores ℓ(n|o): how likely the agent is at each CTG node given `observation`.
pub trait NodeScorer<O: ?Sized> {
    /// One non-negative score per graph node (`graph.num_nodes()` values);
    /// need not be normalised.
    fn score_nodes(&mut self, graph: &Ctg, observation: &O) -> Result<Vec<f32>>;
}

/// Scores ε(a|n,o): which action to take next from each node.
pub trait EdgeScorer<O: ?Sized> {
    /// A row-major `n x n` matrix of non-negative scores, row `n` scoring
    /// the next action from node `n`; need not be normalised or masked (the
    /// executor keeps only CTG successors).
    fn score_edges(&mut self, graph: &Ctg, observation: &O) -> Result<Vec<f32>>;
}

/// ℓ(n|o) = 1/N for every node: the "no node localizer" ablation.
#[derive(Debug, Clone, Copy, Default)]
pub struct UniformNodeScorer;

impl<O: ?Sized> NodeScorer<O> for UniformNodeScorer {
    fn score_nodes(&mut self, graph: &Ctg, _: &O) -> Result<Vec<f32>> {
        Ok(vec![1.0; graph.num_nodes()])
    }
}

/// ε(a|n,o) uniform over the successors of n: the "no edge classifier" ablation.
#[derive(Debug, Clone, Copy, Default)]
pub struct UniformEdgeScorer;

impl<O: ?Sized> EdgeScorer<O> for UniformEdgeScorer {
    fn score_edges(&mut self, graph: &Ctg, _: &O) -> Result<Vec<f32>> {
        Ok(vec![1.0; graph.num_nodes() * graph.num_nodes()])
    }
}

/// A node scorer that knows the true node: all mass on `locate(observation)`.
pub struct OracleNodeScorer<F>(pub F);

impl<O: ?Sized, F: FnMut(&O) -> ActionId> NodeScorer<O> for OracleNodeScorer<F> {
    fn score_nodes(&mut self, graph: &Ctg, observation: &O) -> Result<Vec<f32>> {
        let node = (self.0)(observation);
        one_hot(graph.num_nodes(), node)
    }
}

/// An edge scorer that knows the right next action: from every node, all
/// mass on `next(observation)`. The executor still masks it to the CTG, so
/// on a graph missing that edge the oracle cannot take it.
pub struct OracleEdgeScorer<F>(pub F);

impl<O: ?Sized, F: FnMut(&O) -> ActionId> EdgeScorer<O> for OracleEdgeScorer<F> {
    fn score_edges(&mut self, graph: &Ctg, observation: &O) -> Result<Vec<f32>> {
        let n = graph.num_nodes();
        let row = one_hot(n, (self.0)(observation))?;
        Ok(row.repeat(n))
    }
}

fn one_hot(n: usize, id: ActionId) -> Result<Vec<f32>> {
    if id.index() >= n {
        return Err(CtgError::ActionOutOfRange {
            id: id.index(),
            len: n,
        });
    }
    let mut v = vec![0.0; n];
    v[id.index()] = 1.0;
    Ok(v)
}

/// How the executor turns node scores into a policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum NodeSelection {
    /// π(a|o) ∝ Σ_n ε(a|n,o) ℓ(n|o) (the paper's default).
    #[default]
    Marginal,
    /// Use only the most likely node that has a scorable successor.
    ArgMax,
}

/// A probability distribution over the next action (one entry per node;
/// zero outside the CTG successors of the nodes considered).
#[derive(Debug, Clone, PartialEq)]
pub struct ActionDistribution {
    probabilities: Vec<f32>,
    node: ActionId,
}

impl ActionDistribution {
    /// π(a|o) for every node `a`; sums to 1.
    pub fn probabilities(&self) -> &[f32] {
        &self.probabilities
    }

    /// π(action|o) (0 if out of range).
    pub fn probability(&self, action: ActionId) -> f32 {
        self.probabilities
            .get(action.index())
            .copied()
            .unwrap_or(0.0)
    }

    /// ln π(action|o); `-inf` for an action with zero probability.
    pub fn log_probability(&self, action: ActionId) -> f32 {
        self.probability(action).ln()
    }

    /// The most probable action (lowest id on ties).
    pub fn most_likely(&self) -> ActionId {
        let mut best = 0;
        for (i, &p) in self.probabilities.iter().enumerate() {
            if p > self.probabilities[best] {
                best = i;
            }
        }
        ActionId::new(best)
    }

    /// The most probable action, an exact tie between several broken by
    /// `uniform`, a number in `[0, 1)` drawn by the caller: of the `k` tied
    /// actions (in id order) the `⌊uniform·k⌋`-th. Where a policy has a
    /// constant term (an ablated edge classifier is uniform over a node's
    /// successors) ties are the rule, and [`ActionDistribution::most_likely`]
    /// would always take the lowest id: an artefact of how the vocabulary is
    /// numbered, not a choice of the policy.
    pub fn most_likely_breaking_ties(&self, uniform: f64) -> ActionId {
        let best = self.probabilities[self.most_likely().index()];
        let tied: Vec<usize> = (0..self.probabilities.len())
            .filter(|&i| self.probabilities[i] == best)
            .collect();
        let k = ((uniform.clamp(0.0, 1.0) * tied.len() as f64) as usize).min(tied.len() - 1);
        ActionId::new(tied[k])
    }

    /// Samples an action given `uniform`, a number in `[0, 1)` drawn by the
    /// caller (this crate has no random number generator).
    pub fn sample(&self, uniform: f64) -> ActionId {
        let mut acc = 0.0f64;
        let mut last_positive = self.most_likely();
        for (i, &p) in self.probabilities.iter().enumerate() {
            if p > 0.0 {
                acc += f64::from(p);
                last_positive = ActionId::new(i);
                if uniform < acc {
                    return last_positive;
                }
            }
        }
        last_positive
    }

    /// The node the agent was most likely at (arg-max of ℓ(n|o)).
    pub fn localized_node(&self) -> ActionId {
        self.node
    }
}

/// One executed step of a [`Rollout`].
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ExecutedStep {
    /// The most likely node given the observation before the action.
    pub localized_node: ActionId,
    /// The action taken (the edge `localized_node -> action`).
    pub action: ActionId,
    /// π(action|o).
    pub probability: f32,
}

/// The outcome of [`GraphExecutor::run`].
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Rollout {
    /// Every step, `<end>` included if the policy chose it.
    pub steps: Vec<ExecutedStep>,
    /// The environment's success check at the end of the episode.
    pub success: bool,
    /// Whether the episode ended by termination (`<end>` or a terminal state).
    pub terminated: bool,
    /// Whether the step limit cut the episode off.
    pub truncated: bool,
}

impl Rollout {
    /// The actions taken, `<end>` excluded.
    pub fn actions(&self) -> Vec<ActionId> {
        self.steps
            .iter()
            .map(|s| s.action)
            .filter(|&a| a != Vocabulary::END)
            .collect()
    }
}

/// Executes a CTG as a policy with pluggable scorers.
///
/// ```
/// use ctg_graph::{Ctg, GraphExecutor, UniformNodeScorer, UniformEdgeScorer, Vocabulary};
/// let vocab = Vocabulary::new(["a", "b"]).unwrap();
/// let graph = Ctg::from_path(vocab.len(), &vocab.parse_sequence("a b").unwrap()).unwrap();
/// let exec = GraphExecutor::new(graph);
/// let dist = exec
///     .action_distribution(&mut UniformNodeScorer, &mut UniformEdgeScorer, &())
///     .unwrap();
/// // Uniform node scores: <start> leads to a, a to b, b to <end>.
/// assert!((dist.probability(vocab.id("a").unwrap()) - 1.0 / 3.0).abs() < 1e-6);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct GraphExecutor {
    graph: Ctg,
    node_selection: NodeSelection,
}

impl GraphExecutor {
    /// An executor over `graph` (edges are those with positive weight;
    /// threshold a weighted graph first) with marginal node selection.
    pub fn new(graph: Ctg) -> Self {
        GraphExecutor {
            graph,
            node_selection: NodeSelection::Marginal,
        }
    }

    /// Sets how node scores are used.
    pub fn with_node_selection(mut self, node_selection: NodeSelection) -> Self {
        self.node_selection = node_selection;
        self
    }

    /// The graph being executed.
    pub fn graph(&self) -> &Ctg {
        &self.graph
    }

    /// π(·|o): the distribution over the next action given `observation`.
    pub fn action_distribution<O: ?Sized>(
        &self,
        nodes: &mut (impl NodeScorer<O> + ?Sized),
        edges: &mut (impl EdgeScorer<O> + ?Sized),
        observation: &O,
    ) -> Result<ActionDistribution> {
        let n = self.graph.num_nodes();
        let node_scores = nodes.score_nodes(&self.graph, observation)?;
        check_scores("node", &node_scores, n)?;
        let edge_scores = edges.score_edges(&self.graph, observation)?;
        check_scores("edge", &edge_scores, n * n)?;

        // Per node: edge scores masked to CTG successors and normalised.
        let rows: Vec<Option<Vec<f32>>> = (0..n)
            .map(|from| {
                let row: Vec<f32> = (0..n)
                    .map(|to| {
                        if self.graph.has_edge(ActionId::new(from), ActionId::new(to)) {
                            edge_scores[from * n + to]
                        } else {
                            0.0
                        }
                    })
                    .collect();
                let total: f32 = row.iter().sum();
                (total > 0.0).then(|| row.into_iter().map(|s| s / total).collect())
            })
            .collect();

        let argmax_node = argmax(&node_scores);
        let mut probabilities = vec![0.0f32; n];
        match self.node_selection {
            NodeSelection::Marginal => {
                for (from, row) in rows.iter().enumerate() {
                    if let Some(row) = row {
                        for (p, &e) in probabilities.iter_mut().zip(row) {
                            *p += node_scores[from] * e;
                        }
                    }
                }
            }
            NodeSelection::ArgMax => {
                let best = (0..n)
                    .filter(|&i| rows[i].is_some() && node_scores[i] > 0.0)
                    .max_by(|&a, &b| node_scores[a].total_cmp(&node_scores[b]).then(b.cmp(&a)));
                if let Some(row) = best.and_then(|i| rows[i].as_ref()) {
                    probabilities.copy_from_slice(row);
                }
            }
        }
        let total: f32 = probabilities.iter().sum();
        if total <= 0.0 || !total.is_finite() {
            return Err(CtgError::NoValidAction);
        }
        for p in &mut probabilities {
            *p /= total;
        }
        Ok(ActionDistribution {
            probabilities,
            node: ActionId::new(argmax_node),
        })
    }

    /// Runs the policy greedily (most likely action each step) in `env` from
    /// `reset(seed)` until `<end>`, termination, or truncation.
    pub fn run<E: Environment>(
        &self,
        env: &mut E,
        nodes: &mut (impl NodeScorer<E::Observation> + ?Sized),
        edges: &mut (impl EdgeScorer<E::Observation> + ?Sized),
        seed: u64,
    ) -> Result<Rollout> {
        self.run_with(env, nodes, edges, seed, |dist| dist.most_likely())
    }

    /// Like [`GraphExecutor::run`], with `choose` picking the action from
    /// each step's distribution (e.g. sampling with a seeded generator).
    pub fn run_with<E: Environment>(
        &self,
        env: &mut E,
        nodes: &mut (impl NodeScorer<E::Observation> + ?Sized),
        edges: &mut (impl EdgeScorer<E::Observation> + ?Sized),
        seed: u64,
        mut choose: impl FnMut(&ActionDistribution) -> ActionId,
    ) -> Result<Rollout> {
        self.graph.check_vocabulary(env.vocabulary())?;
        let (mut observation, _) = env.reset(seed)?;
        let mut steps = Vec::new();
        loop {
            let dist = self.action_distribution(nodes, edges, &observation)?;
            let action = choose(&dist);
            let step = env.step(action)?;
            steps.push(ExecutedStep {
                localized_node: dist.localized_node(),
                action,
                probability: dist.probability(action),
            });
            let done = step.is_done();
            observation = step.observation;
            if done {
                return Ok(Rollout {
                    steps,
                    success: env.is_success(),
                    terminated: step.terminated,
                    truncated: step.truncated,
                });
            }
        }
    }
}

fn check_scores(what: &str, scores: &[f32], expected: usize) -> Result<()> {
    if scores.len() != expected {
        return Err(CtgError::InvalidScores(format!(
            "{what} scorer returned {} values, expected {expected}",
            scores.len()
        )));
    }
    if let Some(bad) = scores.iter().find(|s| !s.is_finite() || **s < 0.0) {
        return Err(CtgError::InvalidScores(format!(
            "{what} scorer returned {bad}; scores must be finite and non-negative"
        )));
    }
    Ok(())
}

fn argmax(values: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in values.iter().enumerate() {
        if v > values[best] {
            best = i;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::symbolic::{SequenceObservation, SequenceTask};

    fn setup() -> (Vocabulary, Ctg) {
        let v = Vocabulary::new(["a", "b", "c"]).unwrap();
        let g = Ctg::from_paths(
            v.len(),
            [
                v.parse_sequence("a b c").unwrap().as_slice(),
                v.parse_sequence("a c b").unwrap().as_slice(),
            ],
        )
        .unwrap();
        (v, g)
    }

    #[test]
    fn masks_to_successors() {
        let (v, g) = setup();
        let exec = GraphExecutor::new(g);
        // Oracle says "b", but we are at <start>, whose only successor is a.
        let b = v.id("b").unwrap();
        let mut nodes = OracleNodeScorer(|_: &()| Vocabulary::START);
        let mut edges = OracleEdgeScorer(|_: &()| b);
        assert_eq!(
            exec.action_distribution(&mut nodes, &mut edges, &()),
            Err(CtgError::NoValidAction)
        );
        let mut uniform = UniformEdgeScorer;
        let dist = exec
            .action_distribution(&mut nodes, &mut uniform, &())
            .unwrap();
        assert_eq!(dist.most_likely(), v.id("a").unwrap());
        assert_eq!(dist.probability(v.id("a").unwrap()), 1.0);
    }

    #[test]
    fn marginal_and_argmax_differ() {
        let (v, g) = setup();
        let (a, b, c) = (v.id("a").unwrap(), v.id("b").unwrap(), v.id("c").unwrap());
        // 60% at a (successors b, c), 40% at b (successors c, <end>).
        struct Split(ActionId, ActionId);
        impl NodeScorer<()> for Split {
            fn score_nodes(&mut self, g: &Ctg, _: &()) -> Result<Vec<f32>> {
                let mut s = vec![0.0; g.num_nodes()];
                s[self.0.index()] = 0.6;
                s[self.1.index()] = 0.4;
                Ok(s)
            }
        }
        let marginal = GraphExecutor::new(g.clone())
            .action_distribution(&mut Split(a, b), &mut UniformEdgeScorer, &())
            .unwrap();
        assert!((marginal.probability(b) - 0.3).abs() < 1e-6);
        assert!((marginal.probability(c) - 0.5).abs() < 1e-6);
        assert!((marginal.probability(Vocabulary::END) - 0.2).abs() < 1e-6);
        assert_eq!(marginal.localized_node(), a);
        let argmax = GraphExecutor::new(g)
            .with_node_selection(NodeSelection::ArgMax)
            .action_distribution(&mut Split(a, b), &mut UniformEdgeScorer, &())
            .unwrap();
        assert_eq!(argmax.probability(b), 0.5);
        assert_eq!(argmax.probability(Vocabulary::END), 0.0);
    }

    /// At `a` a uniform edge scorer ties `b` and `c`: the greedy choice
    /// always takes the lower id, the tie-breaking one takes each for half
    /// of `[0, 1)`; an untied distribution ignores the number.
    #[test]
    fn exact_ties_are_broken_by_the_callers_number() {
        let (v, g) = setup();
        let (a, b, c) = (v.id("a").unwrap(), v.id("b").unwrap(), v.id("c").unwrap());
        let exec = GraphExecutor::new(g);
        let mut at_a = OracleNodeScorer(|_: &()| a);
        let tied = exec
            .action_distribution(&mut at_a, &mut UniformEdgeScorer, &())
            .unwrap();
        assert_eq!(tied.most_likely(), b.min(c));
        let picks: Vec<ActionId> = [0.0, 0.25, 0.49, 0.5, 0.75, 0.999, 1.0]
            .iter()
            .map(|&u| tied.most_likely_breaking_ties(u))
            .collect();
        assert_eq!(picks, [b, b, b, c, c, c, c]);
        let mut to_c = OracleEdgeScorer(|_: &()| c);
        let sure = exec.action_distribution(&mut at_a, &mut to_c, &()).unwrap();
        for u in [0.0, 0.5, 0.99] {
            assert_eq!(sure.most_likely_breaking_ties(u), c);
        }
    }

    #[test]
    fn rejects_bad_scores() {
        let (_, g) = setup();
        struct Bad(Vec<f32>);
        impl NodeScorer<()> for Bad {
            fn score_nodes(&mut self, _: &Ctg, _: &()) -> Result<Vec<f32>> {
                Ok(self.0.clone())
            }
        }
        let exec = GraphExecutor::new(g);
        for scores in [vec![1.0; 2], vec![-1.0; 5], vec![f32::NAN; 5]] {
            assert!(matches!(
                exec.action_distribution(&mut Bad(scores), &mut UniformEdgeScorer, &()),
                Err(CtgError::InvalidScores(_))
            ));
        }
    }

    #[test]
    fn sampling_follows_the_distribution() {
        let (v, g) = setup();
        let exec = GraphExecutor::new(g);
        let mut nodes = OracleNodeScorer(|_: &()| v.id("a").unwrap());
        let dist = exec
            .action_distribution(&mut nodes, &mut UniformEdgeScorer, &())
            .unwrap();
        assert_eq!(dist.sample(0.1), v.id("b").unwrap());
        assert_eq!(dist.sample(0.9), v.id("c").unwrap());
        assert_eq!(dist.sample(1.0), v.id("c").unwrap());
        assert_eq!(dist.log_probability(Vocabulary::START), f32::NEG_INFINITY);
    }

    #[test]
    fn oracle_replays_a_path_with_revisits() {
        let v = Vocabulary::new(["a", "b"]).unwrap();
        let path = v.parse_sequence("a b a a b").unwrap();
        let g = Ctg::from_path(v.len(), &path).unwrap();
        let mut env = SequenceTask::new(v.clone(), path.clone());
        let target = path.clone();
        let mut nodes = OracleNodeScorer(|o: &SequenceObservation| o.last);
        let mut edges = OracleEdgeScorer(move |o: &SequenceObservation| {
            target.get(o.step).copied().unwrap_or(Vocabulary::END)
        });
        let rollout = GraphExecutor::new(g)
            .run(&mut env, &mut nodes, &mut edges, 0)
            .unwrap();
        assert_eq!(rollout.actions(), path);
        assert!(rollout.success && rollout.terminated && !rollout.truncated);
        assert_eq!(rollout.steps.last().unwrap().action, Vocabulary::END);
    }
}
