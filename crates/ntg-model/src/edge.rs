//! The edge classifier ε(a|n,o).

use burn::config::Config;
use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::{Bool, Device, Int, Tensor};

use crate::encoder::{Encoder, EncoderConfig};
use crate::interpreter::LossOutput;
use crate::nn::{Init, mask_logits, masked_accuracy, masked_cross_entropy};
use crate::{ModelError, Result};

/// The execution memory of a task graph: `1` for every action node of
/// `graph` (a node with an edge, `<start>` and `<end>` excluded) that is not
/// among `executed`, the actions the agent has taken so far; `0` elsewhere
/// (`graph.num_nodes()` values). Executing a task graph, the agent knows
/// which of its nodes it has already run; what is still pending is what a
/// single observation cannot show (e.g. whether every object has been
/// delivered).
pub fn pending_nodes(graph: &ctg_graph::Ctg, executed: &[ctg_graph::ActionId]) -> Vec<f32> {
    use ctg_graph::{ActionId, Vocabulary};
    let n = graph.num_nodes();
    let mut pending: Vec<f32> = (0..n)
        .map(|i| {
            let a = ActionId::new(i);
            let in_graph = !Vocabulary::is_reserved(a)
                && (!graph.successors(a).is_empty() || !graph.predecessors(a).is_empty());
            if in_graph { 1.0 } else { 0.0 }
        })
        .collect();
    for a in executed {
        if let Some(p) = pending.get_mut(a.index()) {
            *p = 0.0;
        }
    }
    pending
}

/// Configuration of an [`EdgeClassifier`].
#[derive(Config, Debug)]
pub struct EdgeClassifierConfig {
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Observation encoder.
    pub encoder: EncoderConfig,
    /// Size of the GCN node embeddings `NE_gcn`.
    pub gcn_dim: usize,
    /// Size of the localizer node embeddings `NE_loc`.
    pub loc_dim: usize,
    /// Size of an optional execution-memory vector `m` that `W` also reads
    /// (`W [Enc(o); NE_gcn(n); m]`), e.g. which task-graph nodes the agent
    /// has not executed yet. `None` (or 0) means no memory: the paper's
    /// reactive ε(a|n,o).
    pub memory_dim: Option<usize>,
    /// Hidden width of an optional fusion layer: `W` becomes
    /// `W₂ relu(W₁ [Enc(o); NE_gcn(n)] + b₁)`. The paper's linear `W` makes
    /// each logit a sum of an observation term and a node term, so it
    /// cannot express "at this node, check this relation in the scene"
    /// (e.g. at `place(G)`, whether the cube just dropped sits on G); the
    /// fusion layer can. `None` (or 0) = the paper's linear `W`.
    pub fusion_hidden: Option<usize>,
}

impl EdgeClassifierConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if self.num_nodes < 3 || self.gcn_dim == 0 || self.loc_dim == 0 {
            return Err(ModelError::Config(format!(
                "edge classifier: need num_nodes ≥ 3 and positive sizes, got num_nodes {}, gcn_dim {}, loc_dim {}",
                self.num_nodes, self.gcn_dim, self.loc_dim
            )));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `seed` on `device`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<EdgeClassifier> {
        self.validate()?;
        let encoder = self.encoder.init(seed, device)?;
        let mut init = Init::new(seed ^ 0x5eed_0003, device);
        let input = encoder.out_dim() + self.gcn_dim + self.memory_dim.unwrap_or(0);
        let (fusion, w) = match self.fusion_hidden.filter(|&h| h > 0) {
            Some(hidden) => (
                Some(init.linear(input, hidden, true)),
                init.linear(hidden, self.loc_dim, true),
            ),
            None => (None, init.linear(input, self.loc_dim, true)),
        };
        Ok(EdgeClassifier {
            fusion,
            w,
            encoder,
            num_nodes: self.num_nodes,
            gcn_dim: self.gcn_dim,
            memory_dim: self.memory_dim.unwrap_or(0),
        })
    }
}

/// Edge classifier: `ε(a|n,o) ∝ exp((W [Enc(o); NE_gcn(n)])ᵀ NE_loc(n_a))`
/// (paper eq. 3), with the logits of actions that are not CTG successors of
/// `n` set to a large negative number, so they get zero probability;
/// trained with cross-entropy against the demo's next action.
///
/// `NE_loc` comes from the [`NodeLocalizer`](crate::NodeLocalizer) and is
/// passed in: detach it to train the edge classifier alone, or leave it
/// attached to train both together.
#[derive(Module, Debug)]
pub struct EdgeClassifier {
    /// `Enc(o)`.
    pub encoder: Encoder,
    /// The optional fusion layer `W₁` (see
    /// [`EdgeClassifierConfig::fusion_hidden`]).
    pub fusion: Option<Linear>,
    /// `W` (or `W₂` after the fusion layer): `[Enc(o); NE_gcn(n)]` → query
    /// in `NE_loc` space.
    pub w: Linear,
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Size of `NE_gcn`.
    pub gcn_dim: usize,
    /// Size of the execution memory `m` (0: none).
    pub memory_dim: usize,
}

impl EdgeClassifier {
    /// Masked edge logits `[B, N]`.
    ///
    /// - `obs` `[B, D]`: observations;
    /// - `nodes` `[B]`: the current node `n` of each row (ids below `N`);
    /// - `ne_gcn` `[B, N, H_gcn]`: each row's task graph node embeddings;
    /// - `ne_loc` `[N, H_loc]`: localizer node embeddings;
    /// - `successors` `[B, N]`: true at the CTG successors of `n`;
    /// - `memory` `[B, M]`: each row's execution memory, required when the
    ///   classifier was built with a memory and refused otherwise.
    pub fn forward(
        &self,
        obs: Tensor<2>,
        nodes: Tensor<1, Int>,
        ne_gcn: Tensor<3>,
        ne_loc: Tensor<2>,
        successors: Tensor<2, Bool>,
        memory: Option<Tensor<2>>,
    ) -> Result<Tensor<2>> {
        let [b, n, h] = ne_gcn.dims();
        if nodes.dims() != [b] || n != self.num_nodes || h != self.gcn_dim {
            return Err(ModelError::shape(
                "node ids / NE_gcn",
                format!("[B] and [B, {}, {}]", self.num_nodes, self.gcn_dim),
                (nodes.dims(), ne_gcn.dims()),
            ));
        }
        self.check_memory(b, memory.as_ref())?;
        let loc_dim = self.w.weight.dims()[1];
        if obs.dims()[0] != b
            || ne_loc.dims() != [self.num_nodes, loc_dim]
            || successors.dims() != [b, self.num_nodes]
        {
            return Err(ModelError::shape(
                "edge classifier inputs",
                format!(
                    "observations [{b}, D], NE_loc [{}, {loc_dim}], successors [{b}, {}]",
                    self.num_nodes, self.num_nodes
                ),
                (obs.dims(), ne_loc.dims(), successors.dims()),
            ));
        }
        let index = nodes.reshape([b, 1, 1]).expand([b, 1, h]);
        let rows = ne_gcn.gather(1, index).reshape([b, h]);
        let encoded = self.encoder.forward(obs)?;
        let logits = self.unmasked_logits(encoded, rows, ne_loc, memory);
        Ok(mask_logits(logits, successors))
    }

    /// Errors unless `memory` is `[b, M]` for a classifier with a memory of
    /// size `M`, or absent for one without.
    pub(crate) fn check_memory(&self, b: usize, memory: Option<&Tensor<2>>) -> Result<()> {
        match (memory, self.memory_dim) {
            (None, 0) => Ok(()),
            (Some(m), dim) if dim > 0 && m.dims() == [b, dim] => Ok(()),
            (m, dim) => Err(ModelError::shape(
                "execution memory",
                if dim == 0 {
                    "none (the classifier has no memory)".to_owned()
                } else {
                    format!("[{b}, {dim}]")
                },
                m.map(|m| m.dims().to_vec()).unwrap_or_default(),
            )),
        }
    }

    /// `(W [Enc(o); NE_gcn(n); m])ᵀ NE_loc(a)` for every `a`, unmasked,
    /// `[B, N]` (`m` only with a memory; shapes checked by the caller).
    pub(crate) fn unmasked_logits(
        &self,
        encoded: Tensor<2>,
        node_gcn: Tensor<2>,
        ne_loc: Tensor<2>,
        memory: Option<Tensor<2>>,
    ) -> Tensor<2> {
        let mut parts = vec![encoded, node_gcn];
        parts.extend(memory);
        let mut joint = Tensor::cat(parts, 1);
        if let Some(fusion) = &self.fusion {
            joint = burn::tensor::activation::relu(fusion.forward(joint));
        }
        let query = self.w.forward(joint);
        query.matmul(ne_loc.transpose())
    }

    /// Mean cross-entropy of masked logits `[B, N]` (from
    /// [`EdgeClassifier::forward`]) against the next actions `[B]`, and
    /// accuracy.
    pub fn loss(&self, logits: Tensor<2>, next_actions: Tensor<1, Int>) -> Result<LossOutput> {
        let [b, _] = logits.dims();
        let ones = Tensor::ones([b], &logits.device());
        self.weighted_loss(logits, next_actions, ones)
    }

    /// [`EdgeClassifier::loss`] with a weight per row `[B]` (a weighted
    /// mean); the accuracy stays unweighted.
    pub fn weighted_loss(
        &self,
        logits: Tensor<2>,
        next_actions: Tensor<1, Int>,
        weights: Tensor<1>,
    ) -> Result<LossOutput> {
        let [b, _] = logits.dims();
        if next_actions.dims() != [b] || weights.dims() != [b] {
            return Err(ModelError::shape(
                "next actions and row weights",
                format!("[{b}]"),
                next_actions.dims(),
            ));
        }
        let ones = Tensor::ones([b], &logits.device());
        let accuracy = masked_accuracy(logits.clone(), next_actions.clone(), ones)?;
        Ok(LossOutput {
            loss: masked_cross_entropy(logits, next_actions, weights),
            accuracy,
        })
    }
}
