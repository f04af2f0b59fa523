//! The graph prior of full NTG: the completed graph as a prior on the no-graph model's head.

use super::*;

/// The policy of [`Method::Full`]: the demo's completed graph as a prior on
/// a demo-independent policy head.
///
/// `π(a|o) ∝ Σ_n ℓ(n|o) ε_τ(a|n,o)` with
/// `ε_τ(a|n,o) ∝ C_na^τ · ε₀(a|n,o)`, where `ℓ` and `ε₀` (a softmax over
/// every action of the fully connected graph) are the no-graph model's node
/// localizer and edge classifier, `C` the soft-edge weights of the graph the
/// full model's demo interpreter and GCN build from the demo
/// ([`NtgModel::edge_weights`]: the transcribed path's edges at 1, the
/// GCN's probabilities elsewhere, at least [`ntg_model::SOFT_EDGE_FLOOR`]),
/// and `τ ∈ [0, 1]` the prior's weight: 1 is the soft-edge policy
/// `ε ∝ C·exp(s)` on the no-graph head, 0 the no-graph policy itself.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphPrior {
    /// `C`, row-major `N × N`.
    pub(super) weights: Vec<f64>,
    /// `N`.
    pub(super) num_nodes: usize,
}

impl GraphPrior {
    /// The prior the full model `graph` builds from one demonstration.
    pub fn from_demo(
        graph: &NtgModel,
        demo_observations: &[Vec<f32>],
    ) -> anyhow::Result<GraphPrior> {
        let mut model = graph.valid();
        model.config.ablation = AblationConfig::new();
        let (_, initial) = model.initial_graph(demo_observations)?;
        let completed = model.complete_graph(&initial)?;
        let c = model.edge_weights(&initial, &completed.probabilities)?;
        Ok(GraphPrior {
            weights: c.adjacency().iter().map(|&w| f64::from(w)).collect(),
            num_nodes: c.num_nodes(),
        })
    }

    /// `ln π(·|o)` over every node for a head's node probabilities `ℓ`
    /// (`[N]`) and edge rows `ε₀` (`[N × N]`, row = current node), with
    /// the prior raised to `weight` (`-inf` where the probability is 0).
    pub fn log_probabilities(
        &self,
        node: &[f32],
        edge: &[f32],
        weight: f64,
    ) -> anyhow::Result<Vec<f32>> {
        let n = self.num_nodes;
        ensure!(
            node.len() == n && edge.len() == n * n,
            "a graph prior over {n} nodes got {} node and {} edge probabilities",
            node.len(),
            edge.len()
        );
        ensure!(
            weight.is_finite() && weight >= 0.0,
            "the prior weight must be a non-negative number, got {weight}"
        );
        let mut out = vec![0f64; n];
        let mut row = vec![0f64; n];
        for from in 0..n {
            let l = f64::from(node[from]);
            if l <= 0.0 {
                continue;
            }
            for (a, r) in row.iter_mut().enumerate() {
                let c = self.weights[from * n + a];
                *r = if c > 0.0 {
                    f64::from(edge[from * n + a]) * c.powf(weight)
                } else {
                    0.0
                };
            }
            let z: f64 = row.iter().sum();
            if z > 0.0 {
                for (o, r) in out.iter_mut().zip(&row) {
                    *o += l * r / z;
                }
            }
        }
        let total: f64 = out.iter().sum();
        Ok(out
            .iter()
            .map(|&p| {
                if total > 0.0 {
                    (p / total).ln() as f32
                } else {
                    f32::NEG_INFINITY
                }
            })
            .collect())
    }
}

/// One demo's step NLLs and its number of probability-0 steps.
type StepNlls = (Vec<f64>, usize);

/// The no-graph head's `(ℓ(·|o), ε₀(·|·,o))` for every observation of a
/// demo (see [`GraphPrior`]).
fn head_outputs(
    head: &NtgPolicy,
    demo: &Demonstration<Vec<f32>>,
) -> anyhow::Result<Vec<(Vec<f32>, Vec<f32>)>> {
    let full = Ctg::fully_connected(head.graph().num_nodes());
    demo.observations()
        .iter()
        .map(|o| {
            Ok((
                head.node_probabilities(o)?,
                head.edge_probabilities_for(&full, o)?,
            ))
        })
        .collect()
}

/// Leave-one-out scores of [`Method::Full`] on `test` for every prior
/// weight in `weights` (one list of scores per weight, in order): the
/// head's outputs are computed once per demo, the prior once per
/// conditioning demo.
pub fn graph_prior_scores(
    head: &NtgModel,
    graph: &NtgModel,
    vocab: &Vocabulary,
    test: &[TestDemo],
    smoothing: f64,
    weights: &[f64],
) -> anyhow::Result<Vec<Vec<DemoScore>>> {
    ensure!(
        test.len() >= 2,
        "scoring needs at least 2 demonstrations, got {}",
        test.len()
    );
    let choices = num_choices(vocab);
    let mut head = head.valid();
    head.config.ablation = Method::NoGraph
        .ablation()
        .context("the no-graph method has ablation switches")?;
    head.config.soft_edges = None;
    let head_policy = NtgPolicy::from_demo(&head, test[0].demo.observations(), vocab)?;
    let outputs: Vec<Vec<(Vec<f32>, Vec<f32>)>> = test
        .iter()
        .map(|t| head_outputs(&head_policy, &t.demo))
        .collect::<anyhow::Result<_>>()?;
    // table[d][w][e]: the step NLLs of e under d's prior at weight w.
    let table: Vec<Vec<Vec<StepNlls>>> = test
        .par_iter()
        .map(|d| {
            let prior = GraphPrior::from_demo(graph, d.demo.observations())
                .with_context(|| format!("graph prior from {}", d.trial))?;
            weights
                .iter()
                .map(|&w| {
                    test.iter()
                        .zip(&outputs)
                        .map(|(e, out)| {
                            if std::ptr::eq(e, d) {
                                return Ok((Vec::new(), 0));
                            }
                            let mut step = out.iter();
                            demo_step_nlls(
                                &e.demo,
                                |_| {
                                    let (node, edge) =
                                        step.next().context("one head output per step")?;
                                    prior.log_probabilities(node, edge, w)
                                },
                                smoothing,
                                choices,
                            )
                        })
                        .collect()
                })
                .collect()
        })
        .collect::<anyhow::Result<_>>()?;
    Ok((0..weights.len())
        .map(|w| leave_one_out(test, |d, e| (&table[d][w][e].0, table[d][w][e].1)))
        .collect())
}
