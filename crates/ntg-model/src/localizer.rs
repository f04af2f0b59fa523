//! The node localizer ℓ(n|o).

use burn::config::Config;
use burn::module::{Module, Param};
use burn::tensor::{Device, Int, Tensor};

use crate::encoder::{Encoder, EncoderConfig};
use crate::interpreter::LossOutput;
use crate::nn::{Init, masked_accuracy, masked_cross_entropy};
use crate::{ModelError, Result};

/// Configuration of a [`NodeLocalizer`].
#[derive(Config, Debug)]
pub struct NodeLocalizerConfig {
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Observation encoder; its output size is the node embedding size.
    /// With `previous_observation` it reads rows twice as long as an
    /// observation ([`NodeLocalizer::in_context`]).
    pub encoder: EncoderConfig,
    /// Temporal context (not in the paper): the localizer reads the
    /// observation the agent acted on before this one beside the current
    /// one, as `[o_t, o_t − o_{t−1}]` (the first observation of an episode
    /// is its own previous one). A single frame after `pick(X)` (X held
    /// just above its spot) and after `place(X)` (a cube let go onto X)
    /// can look alike; the change since the last decision tells them
    /// apart. `None`: off (configurations saved before it load).
    pub previous_observation: Option<bool>,
}

impl NodeLocalizerConfig {
    /// Whether the localizer reads the previous observation too
    /// ([`NodeLocalizerConfig::previous_observation`]).
    pub fn reads_previous(&self) -> bool {
        self.previous_observation.unwrap_or(false)
    }

    /// Length of one observation row (the encoder reads twice that with
    /// the previous observation).
    pub fn obs_dim(&self) -> usize {
        if self.reads_previous() {
            self.encoder.input_dim() / 2
        } else {
            self.encoder.input_dim()
        }
    }

    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if self.reads_previous() {
            match &self.encoder {
                EncoderConfig::State(c) if c.pairwise_objects == 0 && c.input_dim % 2 == 0 => {}
                _ => {
                    return Err(ModelError::Config(
                        "node localizer: the previous observation is read by a plain state encoder (no pairwise object features) of twice the observation's length".into(),
                    ));
                }
            }
        }
        if self.num_nodes < 3 {
            return Err(ModelError::Config(format!(
                "node localizer: num_nodes must be at least 3, got {}",
                self.num_nodes
            )));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `seed` on `device`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<NodeLocalizer> {
        self.validate()?;
        let encoder = self.encoder.init(seed, device)?;
        let mut init = Init::new(seed ^ 0x5eed_0002, device);
        let h = encoder.out_dim();
        Ok(NodeLocalizer {
            nodes: init.matrix(self.num_nodes, h, 1.0 / (h as f32).sqrt()),
            encoder,
        })
    }
}

/// Node localizer: `ℓ(n|o) ∝ exp(Enc(o)ᵀ NE_loc(n))`, trained with
/// cross-entropy against the CTG node of each frame (the last action taken,
/// `<start>` before the first).
#[derive(Module, Debug)]
pub struct NodeLocalizer {
    /// `Enc(o)`.
    pub encoder: Encoder,
    /// Node embeddings `NE_loc` `[N, H]`.
    pub nodes: Param<Tensor<2>>,
}

impl NodeLocalizer {
    /// Number of CTG nodes `N`.
    pub fn num_nodes(&self) -> usize {
        self.nodes.dims()[0]
    }

    /// `NE_loc` `[N, H]` (also the edge classifier's target-node embeddings).
    pub fn node_embeddings(&self) -> Tensor<2> {
        self.nodes.val()
    }

    /// Node logits `Enc(o)ᵀ NE_loc(n)` `[B, N]` of observations `[B, D]`.
    pub fn forward(&self, obs: Tensor<2>) -> Result<Tensor<2>> {
        let enc = self.encoder.forward(obs)?;
        Ok(self.forward_encoded(enc))
    }

    /// The localizer's input with temporal context: `[o_t, o_t − o_{t−1}]`
    /// `[B, 2D]` from observations `[B, D]` and the previous ones `[B, D]`
    /// ([`NodeLocalizerConfig::previous_observation`]).
    pub fn in_context(obs: Tensor<2>, previous: Tensor<2>) -> Result<Tensor<2>> {
        if obs.dims() != previous.dims() {
            return Err(ModelError::shape(
                "previous observations",
                format!("{:?}", obs.dims()),
                previous.dims(),
            ));
        }
        let change = obs.clone() - previous;
        Ok(Tensor::cat(vec![obs, change], 1))
    }

    /// Node logits from already encoded observations `[B, H]`.
    pub fn forward_encoded(&self, encoded: Tensor<2>) -> Tensor<2> {
        encoded.matmul(self.nodes.val().transpose())
    }

    /// Mean cross-entropy of node logits `[B, N]` (from
    /// [`NodeLocalizer::forward`]) against the true nodes `[B]` (ids below
    /// `N`), and localization accuracy.
    pub fn loss(&self, logits: Tensor<2>, nodes: Tensor<1, Int>) -> Result<LossOutput> {
        let [b, _] = logits.dims();
        if nodes.dims() != [b] {
            return Err(ModelError::shape(
                "node labels",
                format!("[{b}]"),
                nodes.dims(),
            ));
        }
        let weights = Tensor::ones([b], &logits.device());
        let accuracy = masked_accuracy(logits.clone(), nodes.clone(), weights.clone())?;
        Ok(LossOutput {
            loss: masked_cross_entropy(logits, nodes, weights),
            accuracy,
        })
    }
}
