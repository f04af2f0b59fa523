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
    pub encoder: EncoderConfig,
}

impl NodeLocalizerConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
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
