//! The whole NTG model: configuration, the four networks, ablations,
//! checkpoints.

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::tensor::{Device, Tensor};
use ctg_graph::{ActionId, Ctg, NodeSelection};

use crate::batch::adjacency_tensor;
use crate::edge::{EdgeClassifier, EdgeClassifierConfig};
use crate::encoder::EncoderConfig;
use crate::gcn::{GraphCompletionConfig, GraphCompletionNet};
use crate::interpreter::{DemoInterpreter, DemoInterpreterConfig};
use crate::localizer::{NodeLocalizer, NodeLocalizerConfig};
use crate::nn::to_vec;
use crate::{ModelError, Result};

/// Which NTG components are switched on (all by default). Switching one
/// off gives the paper's ablations:
///
/// - `demo_interpreter: false`: the initial CTG is fully connected instead
///   of the demo's path;
/// - `node_localizer: false`: ℓ(n|o) is uniform;
/// - `executed_node: true` (not an ablation of the paper: a replacement,
///   not in the paper): ℓ(n|o) is 1 at the last action the agent executed
///   (`<start>` before the first), read from its own record instead of the
///   frame. Demo frames are labelled with the action they belong to, so
///   after an action the localizer's target is that action: this is the
///   localizer's answer without its reading errors;
/// - `edge_classifier: false`: ε(a|n,o) is uniform over the successors of n;
/// - `gcn: false`: the initial CTG is used as is, and the edge classifier
///   gets the GCN's initial (task-independent) node embeddings `N⁰`.
#[derive(Config, Debug, PartialEq, Eq)]
pub struct AblationConfig {
    /// Use the demo interpreter's path as the initial CTG.
    #[config(default = true)]
    pub demo_interpreter: bool,
    /// Use the node localizer.
    #[config(default = true)]
    pub node_localizer: bool,
    /// Use the edge classifier.
    #[config(default = true)]
    pub edge_classifier: bool,
    /// Take the current node from the agent's record of its actions (the
    /// last one executed) instead of the localizer (see above; overrides
    /// `node_localizer`). `None`: off (an `Option` so that models saved
    /// before it load).
    pub executed_node: Option<bool>,
    /// The policy may choose `<end>` only once every action of the demo
    /// interpreter's transcription has been executed (the agent's record
    /// of its actions), wherever the current node has another successor
    /// too. A symbolic rule on top of the learned scores, not the paper's
    /// reactive policy: a scene that looks finished is not ended while the
    /// demo's actions are pending. Training is the same. `None`: off (an
    /// `Option` so that models saved before it load).
    pub end_after_demo: Option<bool>,
    /// Complete the initial CTG with the GCN.
    #[config(default = true)]
    pub gcn: bool,
}

/// Configuration of a whole [`NtgModel`]; saved beside its weights as JSON.
///
/// One model serves one domain: `num_nodes` is the domain vocabulary's size
/// (`<start>` and `<end>` included).
#[derive(Config, Debug)]
pub struct NtgConfig {
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// The demo interpreter.
    pub interpreter: DemoInterpreterConfig,
    /// The graph completion network.
    pub gcn: GraphCompletionConfig,
    /// The node localizer.
    pub localizer: NodeLocalizerConfig,
    /// The edge classifier.
    pub edge: EdgeClassifierConfig,
    /// Ablation switches.
    #[config(default = "AblationConfig::new()")]
    pub ablation: AblationConfig,
    /// How the policy combines node and edge scores.
    #[config(default = "NodeSelection::Marginal")]
    pub node_selection: NodeSelection,
    /// Completed-graph edges with probability at least this are kept.
    #[config(default = 0.5)]
    pub edge_threshold: f32,
    /// Keep the initial graph's edges in the thresholded graph even when
    /// the GCN's probability for them falls below the threshold.
    #[config(default = true)]
    pub keep_demo_edges: bool,
    /// Soft edges: the policy weighs the edge classifier's scores by the
    /// completed graph's edge probabilities instead of masking them to the
    /// thresholded graph, `ε(a|n,o) ∝ C_na · exp(s(a|n,o))` with `C` from
    /// [`NtgModel::edge_weights`] (the initial graph's edges at weight 1
    /// when `keep_demo_edges`, every weight at least [`SOFT_EDGE_FLOOR`]).
    /// The thresholded graph is then only the displayed graph. The edge
    /// classifier must be trained the same way (the trainer adds `ln C`
    /// of the graph the GCN completes to the logits, softmax over every
    /// node); off = the hard mask.
    /// (`None` = off: configurations saved before this option load.)
    pub soft_edges: Option<bool>,
    /// Seed of the initial weights.
    #[config(default = 0)]
    pub seed: u64,
}

impl NtgConfig {
    /// Whether the policy weighs edges softly ([`NtgConfig::soft_edges`]).
    pub fn uses_soft_edges(&self) -> bool {
        self.soft_edges.unwrap_or(false)
    }

    /// A consistent configuration for a domain with `num_nodes` CTG nodes
    /// and the given observation encoder, with default sizes everywhere.
    pub fn for_domain(num_nodes: usize, encoder: EncoderConfig) -> Self {
        let gcn = GraphCompletionConfig::new(num_nodes);
        let loc_dim = encoder.out_dim();
        NtgConfig::new(
            num_nodes,
            DemoInterpreterConfig::new(num_nodes, encoder.clone()),
            gcn.clone(),
            NodeLocalizerConfig::new(num_nodes, encoder.clone()),
            EdgeClassifierConfig::new(num_nodes, encoder, gcn.hidden, loc_dim),
        )
    }

    /// Checks every part and that the parts agree with each other.
    pub fn validate(&self) -> Result<()> {
        self.interpreter.validate()?;
        self.gcn.validate()?;
        self.localizer.validate()?;
        self.edge.validate()?;
        let n = self.num_nodes;
        if [
            self.interpreter.num_nodes,
            self.gcn.num_nodes,
            self.localizer.num_nodes,
            self.edge.num_nodes,
        ]
        .iter()
        .any(|&m| m != n)
        {
            return Err(ModelError::Config(format!(
                "every part must have num_nodes = {n}"
            )));
        }
        if self.edge.gcn_dim != self.gcn.hidden {
            return Err(ModelError::Config(format!(
                "edge classifier gcn_dim {} differs from the GCN's hidden size {}",
                self.edge.gcn_dim, self.gcn.hidden
            )));
        }
        if self.edge.loc_dim != self.localizer.encoder.out_dim() {
            return Err(ModelError::Config(format!(
                "edge classifier loc_dim {} differs from the localizer's embedding size {}",
                self.edge.loc_dim,
                self.localizer.encoder.out_dim()
            )));
        }
        let dims = [
            self.interpreter.encoder.input_dim(),
            self.localizer.obs_dim(),
            self.edge.encoder.input_dim(),
        ];
        if dims.iter().any(|&d| d != dims[0]) {
            return Err(ModelError::Config(format!(
                "the encoders read observations of different lengths {dims:?}"
            )));
        }
        if !(0.0..=1.0).contains(&self.edge_threshold) {
            return Err(ModelError::Config(format!(
                "edge_threshold must be in [0, 1], got {}",
                self.edge_threshold
            )));
        }
        Ok(())
    }

    /// Length `D` of one observation row.
    pub fn obs_dim(&self) -> usize {
        self.localizer.obs_dim()
    }
}

/// The four NTG networks of one domain, plus their configuration.
///
/// A burn module: train it (or any of its parts) with an optimizer on an
/// autodiff device, run it with [`Module::valid`] for inference.
#[derive(Module, Debug)]
pub struct NtgModel {
    /// Demo → action sequence.
    pub interpreter: DemoInterpreter,
    /// Initial CTG → completed CTG and `NE_gcn`.
    pub gcn: GraphCompletionNet,
    /// ℓ(n|o).
    pub localizer: NodeLocalizer,
    /// ε(a|n,o).
    pub edges: EdgeClassifier,
    /// The configuration the networks were built from.
    #[module(skip)]
    pub config: NtgConfig,
}

/// The smallest edge weight of a soft-edge policy
/// ([`NtgConfig::soft_edges`]): a numerical floor that keeps `ln C` finite
/// (`ln 1e-6 ≈ −13.8`, so an edge the GCN rules out is still practically
/// absent); the same value in training and at test.
pub const SOFT_EDGE_FLOOR: f32 = 1e-6;

/// File name of the configuration in a checkpoint directory.
pub const CONFIG_FILE: &str = "config.json";
/// File name of the weights (burnpack) in a checkpoint directory.
pub const WEIGHTS_FILE: &str = "model.bpk";

impl NtgModel {
    /// Builds a model with fresh weights (drawn from `config.seed`) on `device`.
    pub fn new(config: NtgConfig, device: &Device) -> Result<Self> {
        config.validate()?;
        let seed = config.seed;
        Ok(NtgModel {
            interpreter: config.interpreter.init(seed.wrapping_add(1), device)?,
            gcn: config.gcn.init(seed.wrapping_add(2), device)?,
            localizer: config.localizer.init(seed.wrapping_add(3), device)?,
            edges: config.edge.init(seed.wrapping_add(4), device)?,
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &NtgConfig {
        &self.config
    }

    /// The device the weights live on.
    pub fn device(&self) -> Device {
        self.localizer.nodes.val().device()
    }

    /// Number of CTG nodes `N`.
    pub fn num_nodes(&self) -> usize {
        self.config.num_nodes
    }

    /// Length `D` of one observation row.
    pub fn obs_dim(&self) -> usize {
        self.config.obs_dim()
    }

    /// The initial CTG of a demonstration: the path of the interpreter's
    /// transcription, or the fully connected graph when the demo
    /// interpreter is ablated. Returns the transcription (empty when
    /// ablated) and the graph.
    pub fn initial_graph<R: AsRef<[f32]>>(
        &self,
        observations: &[R],
    ) -> Result<(Vec<ActionId>, Ctg)> {
        if observations.is_empty() {
            return Err(ModelError::Input(
                "a demonstration needs at least one observation".into(),
            ));
        }
        let n = self.num_nodes();
        if self.config.ablation.demo_interpreter {
            let actions = self.interpreter.decode(observations)?;
            let graph = Ctg::from_path(n, &actions)?;
            Ok((actions, graph))
        } else {
            for (i, row) in observations.iter().enumerate() {
                if row.as_ref().len() != self.obs_dim() {
                    return Err(ModelError::Shape {
                        what: "demonstration frame",
                        expected: format!("{} values", self.obs_dim()),
                        got: format!("{} values in frame {i}", row.as_ref().len()),
                    });
                }
            }
            Ok((Vec::new(), Ctg::fully_connected(n)))
        }
    }

    /// Completes `initial` with the GCN (unless ablated), returning the
    /// edge probabilities, the thresholded graph the policy executes, and
    /// `NE_gcn` `[N, H]`.
    pub fn complete_graph(&self, initial: &Ctg) -> Result<CompletedGraph> {
        let n = self.num_nodes();
        if initial.num_nodes() != n {
            return Err(ModelError::shape(
                "initial graph",
                format!("{n} nodes"),
                initial.num_nodes(),
            ));
        }
        if !self.config.ablation.gcn {
            let h = self.gcn.hidden();
            return Ok(CompletedGraph {
                probabilities: initial.clone(),
                graph: initial.threshold(f32::MIN_POSITIVE)?,
                embeddings: self.gcn.initial_embeddings(1).reshape([n, h]),
            });
        }
        let out = self
            .gcn
            .forward(adjacency_tensor(&[initial], n, &self.device())?)?;
        let h = self.gcn.hidden();
        let probs: Vec<f32> = to_vec(out.adjacency)?
            .into_iter()
            .map(|p| if p.is_nan() { 0.0 } else { p.clamp(0.0, 1.0) })
            .collect();
        let probabilities = Ctg::from_adjacency(n, probs)?;
        let mut graph =
            probabilities.threshold(self.config.edge_threshold.max(f32::MIN_POSITIVE))?;
        if self.config.keep_demo_edges {
            graph = graph.union(&initial.threshold(f32::MIN_POSITIVE)?)?;
        }
        Ok(CompletedGraph {
            probabilities,
            graph,
            embeddings: out.embeddings.reshape([n, h]),
        })
    }

    /// The edge weights of a soft-edge policy ([`NtgConfig::soft_edges`]):
    /// the completed graph's probabilities, with the initial graph's edges
    /// at weight 1 when `keep_demo_edges`, floored at [`SOFT_EDGE_FLOOR`] on
    /// every edge of the fully connected graph (and 0 elsewhere: into
    /// `<start>`, out of `<end>`).
    pub fn edge_weights(&self, initial: &Ctg, probabilities: &Ctg) -> Result<Ctg> {
        let mut weights = probabilities.clone();
        if self.config.keep_demo_edges {
            weights.union_with(&initial.threshold(f32::MIN_POSITIVE)?)?;
        }
        let full = Ctg::fully_connected(self.num_nodes());
        let floored: Vec<f32> = weights
            .adjacency()
            .iter()
            .zip(full.adjacency())
            .map(|(&w, &allowed)| {
                if allowed > 0.0 {
                    w.clamp(SOFT_EDGE_FLOOR, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        Ok(Ctg::from_adjacency(self.num_nodes(), floored)?)
    }

    /// `NE_gcn` `[B, N, H]` for a batch of graphs, honouring the GCN
    /// ablation (the initial embeddings `N⁰` when it is off): what the edge
    /// classifier is trained with.
    pub fn graph_embeddings(&self, graphs: &[&Ctg]) -> Result<Tensor<3>> {
        if self.config.ablation.gcn {
            let adjacency = adjacency_tensor(graphs, self.num_nodes(), &self.device())?;
            Ok(self.gcn.forward(adjacency)?.embeddings)
        } else if graphs.is_empty() {
            Err(ModelError::Input("empty batch of graphs".into()))
        } else {
            Ok(self.gcn.initial_embeddings(graphs.len()))
        }
    }

    /// Saves the configuration (`config.json`) and weights (`model.bpk`)
    /// into `dir`, creating it if needed.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        crate::checkpoint::save(self, &self.config, dir.as_ref())
    }

    /// Reads the configuration saved in `dir` by [`NtgModel::save`].
    pub fn load_config(dir: impl AsRef<Path>) -> Result<NtgConfig> {
        crate::checkpoint::load_config(dir.as_ref(), NtgConfig::validate)
    }

    /// Loads a model saved by [`NtgModel::save`] onto `device`. A missing,
    /// corrupt or mismatched file is an error naming it.
    pub fn load(dir: impl AsRef<Path>, device: &Device) -> Result<Self> {
        let config = Self::load_config(&dir)?;
        crate::checkpoint::load_weights(NtgModel::new(config, device)?, dir.as_ref())
    }
}

/// Saves an optimizer's state (e.g. Adam's moments) to `path` (burnpack).
pub fn save_optimizer(optimizer: &ModuleOptimizer, path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    optimizer
        .save(path)
        .map_err(|e| ModelError::file(path, e))?;
    crate::checkpoint::seal(path)
}

/// Loads optimizer state saved by [`save_optimizer`] into `optimizer`
/// (a freshly initialised optimizer of the same kind).
pub fn load_optimizer(
    optimizer: ModuleOptimizer,
    path: impl AsRef<Path>,
) -> Result<ModuleOptimizer> {
    let path = path.as_ref();
    if !path.is_file() {
        return Err(ModelError::file(path, "no such file"));
    }
    crate::checkpoint::verify(path)?;
    crate::checkpoint::decode(path, || {
        optimizer.load(path).map_err(|e| ModelError::file(path, e))
    })
}

/// The result of [`NtgModel::complete_graph`].
#[derive(Debug, Clone)]
pub struct CompletedGraph {
    /// Edge probabilities of the completed graph (the initial graph when
    /// the GCN is ablated).
    pub probabilities: Ctg,
    /// The binary graph the policy executes.
    pub graph: Ctg,
    /// `NE_gcn` `[N, H]`.
    pub embeddings: Tensor<2>,
}
