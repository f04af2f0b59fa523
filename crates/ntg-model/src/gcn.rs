//! The graph completion network (paper eqs. 1–2).

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::relu;

use crate::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};
use ctg_graph::Vocabulary;

use crate::nn::{Init, to_vec};
use crate::{ModelError, Result};

/// Configuration of a [`GraphCompletionNet`].
#[derive(Config, Debug)]
pub struct GraphCompletionConfig {
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Node embedding size (the size of `NE_gcn`).
    #[config(default = 64)]
    pub hidden: usize,
    /// Hidden width of `f_set` and `f_reset`.
    #[config(default = 64)]
    pub mlp_hidden: usize,
    /// Number of edge-update + propagation iterations `T`.
    #[config(default = 3)]
    pub iterations: usize,
    /// Weight of positive (edge) entries in the binary cross-entropy, to
    /// balance sparse graphs.
    #[config(default = 1.0)]
    pub pos_weight: f32,
}

impl GraphCompletionConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        if self.num_nodes < 3 || self.hidden == 0 || self.mlp_hidden == 0 {
            return Err(ModelError::Config(format!(
                "graph completion: need num_nodes ≥ 3 and positive sizes, got {self:?}"
            )));
        }
        if !(self.pos_weight.is_finite() && self.pos_weight > 0.0) {
            return Err(ModelError::Config(format!(
                "graph completion: pos_weight must be positive, got {}",
                self.pos_weight
            )));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `seed` on `device`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<GraphCompletionNet> {
        self.validate()?;
        let mut init = Init::new(seed, device);
        let (h, m) = (self.hidden, self.mlp_hidden);
        let n = self.num_nodes;
        Ok(GraphCompletionNet {
            nodes: init.matrix(n, h, 1.0),
            f_set: PairMlp::init(&mut init, h, m),
            f_reset: PairMlp::init(&mut init, h, m),
            f_forward: init.linear(h, h, true),
            f_backward: init.linear(h, h, true),
            rnn: crate::nn::GruCell::init(&mut init, h, h),
            num_nodes: n,
            iterations: self.iterations,
            pos_weight: self.pos_weight,
        })
    }
}

/// An MLP scoring an ordered node pair, `f(N_i, N_j) = σ(w_oᵀ relu(U N_i + V N_j + b) + b_o)`
/// (an MLP on the concatenation `[N_i; N_j]` whose first layer is split
/// into `U` and `V`, so all `N²` pairs cost two `[N, H]` products).
#[derive(Module, Debug)]
pub struct PairMlp {
    /// `U` (with bias `b`).
    pub source: Linear,
    /// `V` (no bias).
    pub target: Linear,
    /// `w_o`, `b_o`.
    pub out: Linear,
}

impl PairMlp {
    fn init(init: &mut Init, hidden: usize, mlp_hidden: usize) -> Self {
        PairMlp {
            source: init.linear(hidden, mlp_hidden, true),
            target: init.linear(hidden, mlp_hidden, false),
            out: init.linear(mlp_hidden, 1, true),
        }
    }

    /// `[B, N, H]` node embeddings → `[B, N, N]` scores in `(0, 1)`, entry
    /// `(i, j)` scoring the edge `i → j`.
    pub fn forward(&self, nodes: Tensor<3>) -> Tensor<3> {
        let [b, n, _] = nodes.dims();
        let src = self.source.forward(nodes.clone()).unsqueeze_dim::<4>(2); // [B, N, 1, M]
        let dst = self.target.forward(nodes).unsqueeze_dim::<4>(1); // [B, 1, N, M]
        let pair = relu(src + dst); // [B, N, N, M]
        sigmoid(self.out.forward(pair).reshape([b, n, n]))
    }
}

/// Graph completion network: learned node embeddings `N⁰`, then `T`
/// iterations of
///
/// ```text
/// C^{t+1}_ij = (1 − C^t_ij) · f_set(N^t_i, N^t_j) + C^t_ij · f_reset(N^t_i, N^t_j)     (eq. 1)
/// N^{t+1}_i  = GRU(a_i, N^t_i),  a_i = Σ_j C^t_ij f_f(N^t_j) + C^t_ji f_b(N^t_j)       (eq. 2)
/// ```
///
/// starting from the initial adjacency `C⁰` (row = from). `C^T` is the
/// completed graph (edge probabilities) and `N^T` the node embeddings
/// `NE_gcn`. Edges that no CTG can have (into `<start>`, out of `<end>`)
/// are held at 0 after every edge update.
#[derive(Module, Debug)]
pub struct GraphCompletionNet {
    /// Initial node embeddings `N⁰` `[N, H]`.
    pub nodes: Param<Tensor<2>>,
    /// `f_set`: the probability of adding a missing edge.
    pub f_set: PairMlp,
    /// `f_reset`: the probability of keeping an existing edge.
    pub f_reset: PairMlp,
    /// `f_f`: message along an edge's direction.
    pub f_forward: Linear,
    /// `f_b`: message against an edge's direction.
    pub f_backward: Linear,
    /// The propagation GRU.
    pub rnn: crate::nn::GruCell,
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Iterations `T`.
    pub iterations: usize,
    /// Weight of positive entries in the loss.
    pub pos_weight: f32,
}

/// The output of [`GraphCompletionNet::forward`].
#[derive(Debug, Clone)]
pub struct GcnOutput {
    /// Completed adjacency `C^T` `[B, N, N]`, edge probabilities in `[0, 1]`.
    pub adjacency: Tensor<3>,
    /// Final node embeddings `NE_gcn = N^T` `[B, N, H]`.
    pub embeddings: Tensor<3>,
}

impl GraphCompletionNet {
    /// Node embedding size `H`.
    pub fn hidden(&self) -> usize {
        self.nodes.dims()[1]
    }

    /// The initial node embeddings `N⁰` broadcast to a batch, `[B, N, H]`
    /// (what the "no GCN" ablation hands the edge classifier).
    pub fn initial_embeddings(&self, batch: usize) -> Tensor<3> {
        let [n, h] = self.nodes.dims();
        self.nodes.val().unsqueeze_dim::<3>(0).expand([batch, n, h])
    }

    /// Completes a batch of graphs: `adjacency` `[B, N, N]` with entries in
    /// `[0, 1]` (row = from).
    pub fn forward(&self, adjacency: Tensor<3>) -> Result<GcnOutput> {
        let [b, n, m] = adjacency.dims();
        if n != self.num_nodes || m != self.num_nodes || b == 0 {
            return Err(ModelError::shape(
                "initial adjacency",
                format!("[B ≥ 1, {0}, {0}]", self.num_nodes),
                [b, n, m],
            ));
        }
        let h = self.hidden();
        let allowed = allowed_edges(n, &adjacency.device()).unsqueeze_dim::<3>(0);
        let mut c = adjacency;
        let mut nodes = self.initial_embeddings(b);
        for _ in 0..self.iterations {
            // Eq. 1: edge update from C^t and N^t.
            let set = self.f_set.forward(nodes.clone());
            let reset = self.f_reset.forward(nodes.clone());
            let c_next = ((c.clone().neg() + 1.0) * set + c.clone() * reset) * allowed.clone();
            // Eq. 2: propagation with C^t.
            let fwd = self.f_forward.forward(nodes.clone());
            let bwd = self.f_backward.forward(nodes.clone());
            let messages = c.clone().matmul(fwd) + c.swap_dims(1, 2).matmul(bwd);
            nodes = self
                .rnn
                .step(messages.reshape([b * n, h]), nodes.reshape([b * n, h]))
                .reshape([b, n, h]);
            c = c_next;
        }
        Ok(GcnOutput {
            adjacency: c,
            embeddings: nodes,
        })
    }

    /// Weighted binary cross-entropy of the completed adjacency against a
    /// 0/1 `target` `[B, N, N]`, averaged over entries:
    /// `−mean(w·t·ln p + (1 − t)·ln(1 − p))`, `w` = `pos_weight`.
    pub fn loss(&self, output: &GcnOutput, target: Tensor<3>) -> Result<Tensor<1>> {
        if target.dims() != output.adjacency.dims() {
            return Err(ModelError::shape(
                "target adjacency",
                format!("{:?}", output.adjacency.dims()),
                target.dims(),
            ));
        }
        let eps = 1e-6;
        let p = output.adjacency.clone().clamp(eps, 1.0 - eps);
        let pos = target.clone() * p.clone().log() * self.pos_weight;
        let neg = (target.neg() + 1.0) * (p.neg() + 1.0).log();
        Ok((pos + neg).mean().neg())
    }
}

/// The `[N, N]` 0/1 mask of the edges a CTG may have: none into `<start>`,
/// none out of `<end>`.
fn allowed_edges(n: usize, device: &Device) -> Tensor<2> {
    let mut allowed = vec![1.0f32; n * n];
    for i in 0..n {
        allowed[Vocabulary::END.index() * n + i] = 0.0;
        allowed[i * n + Vocabulary::START.index()] = 0.0;
    }
    Tensor::from_data(TensorData::new(allowed, [n, n]), device)
}

impl std::ops::Add for EdgeCounts {
    type Output = EdgeCounts;
    fn add(self, other: EdgeCounts) -> EdgeCounts {
        EdgeCounts {
            true_positives: self.true_positives + other.true_positives,
            false_positives: self.false_positives + other.false_positives,
            false_negatives: self.false_negatives + other.false_negatives,
        }
    }
}

impl std::ops::AddAssign for EdgeCounts {
    fn add_assign(&mut self, other: EdgeCounts) {
        *self = *self + other;
    }
}

/// Edge counts of a predicted graph against a target graph.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EdgeCounts {
    /// Edges in both.
    pub true_positives: usize,
    /// Predicted edges the target lacks.
    pub false_positives: usize,
    /// Target edges the prediction lacks.
    pub false_negatives: usize,
}

impl EdgeCounts {
    /// Counts edges of `predicted` (probabilities, an edge where `≥ threshold`)
    /// against `target` (an edge where `> 0.5`), both flat and of equal length.
    pub fn count(predicted: &[f32], target: &[f32], threshold: f32) -> Result<Self> {
        if predicted.len() != target.len() {
            return Err(ModelError::shape(
                "predicted adjacency",
                format!("{} entries", target.len()),
                predicted.len(),
            ));
        }
        let mut c = EdgeCounts::default();
        for (&p, &t) in predicted.iter().zip(target) {
            match (p >= threshold, t > 0.5) {
                (true, true) => c.true_positives += 1,
                (true, false) => c.false_positives += 1,
                (false, true) => c.false_negatives += 1,
                (false, false) => {}
            }
        }
        Ok(c)
    }

    /// Counts edges of a batch of completed adjacencies `[B, N, N]` against targets.
    pub fn count_tensors(predicted: Tensor<3>, target: Tensor<3>, threshold: f32) -> Result<Self> {
        Self::count(&to_vec(predicted)?, &to_vec(target)?, threshold)
    }

    /// Precision `tp / (tp + fp)` (1 when nothing was predicted).
    pub fn precision(&self) -> f32 {
        let d = self.true_positives + self.false_positives;
        if d == 0 {
            1.0
        } else {
            self.true_positives as f32 / d as f32
        }
    }

    /// Recall `tp / (tp + fn)` (1 when the target is empty).
    pub fn recall(&self) -> f32 {
        let d = self.true_positives + self.false_negatives;
        if d == 0 {
            1.0
        } else {
            self.true_positives as f32 / d as f32
        }
    }

    /// F1, the harmonic mean of precision and recall (1 when both graphs are empty).
    pub fn f1(&self) -> f32 {
        let d = 2 * self.true_positives + self.false_positives + self.false_negatives;
        if d == 0 {
            1.0
        } else {
            2.0 * self.true_positives as f32 / d as f32
        }
    }
}
