//! The predicted task graph of one Needle Passing demo, for the figure.

use super::*;

/// The full model's predicted graph for one Needle Passing demonstration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictedGraph {
    /// The conditioning trial.
    pub trial: String,
    /// The expert's gestures in it.
    pub demo_gestures: Vec<String>,
    /// The demo interpreter's transcription of it.
    pub transcription: Vec<String>,
    /// Edges of the transcription's path graph.
    pub path_edges: usize,
    /// Edges of the completed, thresholded graph the policy executes.
    pub graph_edges: usize,
    /// Edges the GCN added (in the graph, not in the path), as `from -> to`.
    pub added_edges: Vec<String>,
    /// Edges of the ground-truth Needle Passing graph (union of all its
    /// demos' paths).
    pub truth_edges: usize,
    /// Edges of the graph that are in the ground truth.
    pub correct_edges: usize,
    /// The graph as DOT: path edges solid, added edges dashed with their
    /// GCN probability.
    pub dot: String,
}

/// Builds the full model's graph for test demo `index` and compares it with
/// the ground-truth Needle Passing graph.
pub fn predicted_graph(
    model: &NtgModel,
    data: &JigsawsData,
    index: usize,
) -> anyhow::Result<PredictedGraph> {
    let vocab = &data.vocab;
    let test = data
        .test
        .get(index)
        .with_context(|| format!("no test demo {index}"))?;
    let mut model = model.valid();
    model.config.ablation = AblationConfig::new();
    let policy = NtgPolicy::from_demo(&model, test.demo.observations(), vocab)?;
    let n = vocab.len();
    let path = Ctg::from_path(n, policy.demo_actions())?;
    let graph = policy.graph();
    let mut truth = Ctg::empty(n);
    for t in &data.test {
        truth.add_path(t.demo.actions())?;
    }
    let mut shown = path.clone();
    let mut added = Vec::new();
    for edge in graph.edges() {
        if !path.has_edge(edge.from, edge.to) {
            let p = policy.edge_probabilities().weight(edge.from, edge.to);
            // Below 1 so `to_dot` draws it dashed with its probability.
            shown.set_weight(edge.from, edge.to, p.min(0.99))?;
            added.push(format!(
                "{} -> {}",
                name(vocab, edge.from),
                name(vocab, edge.to)
            ));
        }
    }
    let names = |ids: &[ActionId]| ids.iter().map(|&a| name(vocab, a)).collect();
    Ok(PredictedGraph {
        trial: test.trial.clone(),
        demo_gestures: names(test.demo.actions()),
        transcription: names(policy.demo_actions()),
        path_edges: path.num_edges(),
        graph_edges: graph.num_edges(),
        added_edges: added,
        truth_edges: truth.num_edges(),
        correct_edges: graph
            .edges()
            .filter(|e| truth.has_edge(e.from, e.to))
            .count(),
        dot: shown.to_dot(vocab)?,
    })
}

fn name(vocab: &Vocabulary, id: ActionId) -> String {
    vocab.name(id).unwrap_or("?").to_owned()
}
