//! NTG on videos, stage A: the one shared frame encoder `Enc(o)`, trained
//! with the executor's two losses on single frames.
//!
//! Training NTG end to end on demo videos runs the CNN over every frame of
//! every demo in every step: on two CPU cores that is seconds per step.
//! Instead, the encoder is trained first, on frames sampled across demos in
//! large batches, with the losses of the two networks that read single
//! frames (paper section 4.3, same supervision: frames and flat action
//! labels):
//!
//! - localizer: `ℓ(n|o) ∝ exp(Enc(o)ᵀ NE_loc(n))` against the flat action
//!   the frame belongs to (`<start>` before the first);
//! - edge classifier: `ε(a|n,o) ∝ exp((W [Enc(o); NE(n)])ᵀ NE_loc(a))`,
//!   masked to the successors of `n` in the task's graph, against the
//!   action that follows the frame's segment. `NE(n)` is a learned node
//!   embedding, standing in for the GCN's, which needs a whole demo.
//!
//! Then the encoder is frozen, every demo frame is encoded once, and the
//! demo interpreter, the GCN, the localizer and the edge classifier train
//! on the embeddings (stage B, an [`crate::NtgModel`] whose observations are
//! `Enc(o)` rows; see `ntg-trainer`). At run time each frame is encoded
//! once and its embedding read by all three.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::{Bool, Device, Int, Tensor};

use crate::encoder::{Encoder, EncoderConfig};
use crate::interpreter::LossOutput;
use crate::nn::{Init, mask_logits, masked_accuracy, masked_cross_entropy};
use crate::{ModelError, Result};

/// Configuration of a [`FrameStageNet`].
#[derive(Config, Debug)]
pub struct FrameStageConfig {
    /// Number of CTG nodes `N` (the domain vocabulary, `<start>` and
    /// `<end>` included).
    pub num_nodes: usize,
    /// The shared encoder `Enc(o)` (a frame encoder).
    pub encoder: EncoderConfig,
    /// Seed of the initial weights.
    #[config(default = 0)]
    pub seed: u64,
}

impl FrameStageConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if self.num_nodes < 3 {
            return Err(ModelError::Config(format!(
                "frame stage: num_nodes must be at least 3, got {}",
                self.num_nodes
            )));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `self.seed` on `device`.
    pub fn init(&self, device: &Device) -> Result<FrameStageNet> {
        self.validate()?;
        let encoder = self.encoder.init(self.seed.wrapping_add(11), device)?;
        let h = encoder.out_dim();
        let mut init = Init::new(self.seed ^ 0x5eed_00a1, device);
        let bound = 1.0 / (h as f32).sqrt();
        Ok(FrameStageNet {
            loc_nodes: init.matrix(self.num_nodes, h, bound),
            edge_nodes: init.matrix(self.num_nodes, h, bound),
            w: init.linear(2 * h, h, true),
            encoder,
            config: self.clone(),
        })
    }
}

/// Stage A's network: the shared encoder and the two single-frame heads.
#[derive(Module, Debug)]
pub struct FrameStageNet {
    /// `Enc(o)`: what stage B freezes and every network reads.
    pub encoder: Encoder,
    /// `NE_loc` `[N, H]`.
    pub loc_nodes: Param<Tensor<2>>,
    /// `NE(n)` `[N, H]`, the edge head's node embeddings.
    pub edge_nodes: Param<Tensor<2>>,
    /// `W`: `[Enc(o); NE(n)]` → query in `NE_loc` space.
    pub w: Linear,
    /// The configuration the network was built from.
    #[module(skip)]
    pub config: FrameStageConfig,
}

/// Stage A's losses on a batch of frames.
#[derive(Debug, Clone)]
pub struct FrameStageLoss {
    /// Sum of the two losses.
    pub loss: Tensor<1>,
    /// Localizer cross-entropy and accuracy.
    pub localizer: LossOutput,
    /// Edge cross-entropy and accuracy.
    pub edge: LossOutput,
}

impl FrameStageNet {
    /// The configuration.
    pub fn config(&self) -> &FrameStageConfig {
        &self.config
    }

    /// `Enc(o)` `[B, H]` of frames `[B, D]`.
    pub fn encode(&self, frames: Tensor<2>) -> Result<Tensor<2>> {
        self.encoder.forward(frames)
    }

    /// Localizer and masked edge logits `([B, N], [B, N])` of frames
    /// `[B, D]` at nodes `[B]`, with `successors` `[B, N]` true at the task
    /// graph's successors of each row's node.
    pub fn forward(
        &self,
        frames: Tensor<2>,
        nodes: Tensor<1, Int>,
        successors: Tensor<2, Bool>,
    ) -> Result<(Tensor<2>, Tensor<2>)> {
        let b = frames.dims()[0];
        let n = self.config.num_nodes;
        if nodes.dims() != [b] || successors.dims() != [b, n] {
            return Err(ModelError::shape(
                "frame stage nodes / successors",
                format!("[{b}] and [{b}, {n}]"),
                (nodes.dims(), successors.dims()),
            ));
        }
        let encoded = self.encode(frames)?;
        let ne_loc = self.loc_nodes.val();
        let loc_logits = encoded.clone().matmul(ne_loc.clone().transpose());
        let node_rows = self.edge_nodes.val().select(0, nodes);
        let query = self.w.forward(Tensor::cat(vec![encoded, node_rows], 1));
        let edge_logits = mask_logits(query.matmul(ne_loc.transpose()), successors);
        Ok((loc_logits, edge_logits))
    }

    /// The two losses of frames `[B, D]`: `labels` `[B]` the action each
    /// frame belongs to (also its node), `next` `[B]` the action after it
    /// (a successor of its node in `successors`).
    pub fn loss(
        &self,
        frames: Tensor<2>,
        labels: Tensor<1, Int>,
        next: Tensor<1, Int>,
        successors: Tensor<2, Bool>,
    ) -> Result<FrameStageLoss> {
        let b = frames.dims()[0];
        if next.dims() != [b] {
            return Err(ModelError::shape(
                "next actions",
                format!("[{b}]"),
                next.dims(),
            ));
        }
        let (loc_logits, edge_logits) = self.forward(frames, labels.clone(), successors)?;
        let ones = Tensor::<1>::ones([b], &loc_logits.device());
        let localizer = LossOutput {
            accuracy: masked_accuracy(loc_logits.clone(), labels.clone(), ones.clone())?,
            loss: masked_cross_entropy(loc_logits, labels, ones.clone()),
        };
        let edge = LossOutput {
            accuracy: masked_accuracy(edge_logits.clone(), next.clone(), ones.clone())?,
            loss: masked_cross_entropy(edge_logits, next, ones),
        };
        Ok(FrameStageLoss {
            loss: localizer.loss.clone() + edge.loss.clone(),
            localizer,
            edge,
        })
    }

    /// Saves the configuration and weights into `dir`.
    pub fn save(&self, dir: impl AsRef<std::path::Path>) -> Result<()> {
        crate::checkpoint::save(self, &self.config, dir.as_ref())
    }

    /// Loads a network saved by [`FrameStageNet::save`].
    pub fn load(dir: impl AsRef<std::path::Path>, device: &Device) -> Result<Self> {
        let config: FrameStageConfig =
            crate::checkpoint::load_config(dir.as_ref(), FrameStageConfig::validate)?;
        crate::checkpoint::load_weights(config.init(device)?, dir.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FrameEncoderConfig, ids_tensor, rows_tensor, successor_mask};
    use burn::optim::{AdamConfig, GradientsParams};
    use ctg_graph::{ActionId, Ctg};

    fn small() -> FrameStageConfig {
        FrameStageConfig::new(
            5,
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(16)
                    .with_conv_channels([4, 8, 8])
                    .with_out_dim(16),
            ),
        )
    }

    /// Frames whose mean colour tells their label: the network must learn
    /// to localize them, and the edge head to follow the graph.
    #[test]
    fn learns_frame_labels_and_next_actions() {
        let device = Device::flex().autodiff();
        let mut net = small().init(&device).unwrap();
        let dim = 3 * 16 * 16;
        let labels: Vec<ActionId> = (0..12).map(|i| ActionId::new(2 + i % 3)).collect();
        let rows: Vec<Vec<f32>> = labels
            .iter()
            .map(|a| {
                (0..dim)
                    .map(|k| ((a.index() * 7 + k % 3) % 10) as f32 / 10.0)
                    .collect()
            })
            .collect();
        // The path 2 -> 3 -> 4: next of 2 is 3, of 3 is 4, of 4 is <end>.
        let graph =
            Ctg::from_path(5, &[ActionId::new(2), ActionId::new(3), ActionId::new(4)]).unwrap();
        let next: Vec<ActionId> = labels
            .iter()
            .map(|a| {
                if a.index() == 4 {
                    ActionId::new(1)
                } else {
                    ActionId::new(a.index() + 1)
                }
            })
            .collect();
        let mask = || successor_mask(&[&graph; 12], &labels, Some(&next), 5, &device).unwrap();
        let mut optim = AdamConfig::new().init();
        let mut first: Option<f32> = None;
        let mut last: Option<(f32, f32)> = None;
        for _ in 0..60 {
            let out = net
                .loss(
                    rows_tensor(&rows, dim, &device).unwrap(),
                    ids_tensor(&labels, 5, &device).unwrap(),
                    ids_tensor(&next, 5, &device).unwrap(),
                    mask(),
                )
                .unwrap();
            let value = crate::nn::to_vec(out.loss.clone()).unwrap()[0];
            first.get_or_insert(value);
            last = Some((value, out.localizer.accuracy));
            let grads = GradientsParams::from_grads(out.loss.backward(), &net);
            net = optim.step(3e-3, net, grads);
        }
        let (end, accuracy) = last.unwrap();
        assert!(
            end < 0.2 * first.unwrap(),
            "loss {} -> {end}",
            first.unwrap()
        );
        assert_eq!(accuracy, 1.0);
    }

    #[test]
    fn saves_and_loads() {
        let device = Device::flex();
        let net = small().init(&device).unwrap();
        let dir = tempfile::tempdir().unwrap();
        net.save(dir.path()).unwrap();
        let back = FrameStageNet::load(dir.path(), &device).unwrap();
        let x = Tensor::<2>::ones([2, 3 * 16 * 16], &device);
        let a = crate::nn::to_vec(net.encode(x.clone()).unwrap()).unwrap();
        let b = crate::nn::to_vec(back.encode(x).unwrap()).unwrap();
        assert_eq!(a, b);
    }

    /// Stage A networks saved before the encoder's optional settings
    /// existed (no `hidden`, `he_init`, `centre_input`) still load.
    #[test]
    fn networks_saved_without_the_optional_encoder_settings_still_load() {
        let device = Device::flex();
        let net = small().init(&device).unwrap();
        let dir = tempfile::tempdir().unwrap();
        net.save(dir.path()).unwrap();
        let path = dir.path().join("config.json");
        let mut json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let frame = json["encoder"]["Frame"].as_object_mut().unwrap();
        for field in ["hidden", "he_init", "centre_input"] {
            frame.remove(field);
        }
        std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
        std::fs::remove_file(dir.path().join("config.json.sha256")).unwrap();
        assert!(FrameStageNet::load(dir.path(), &device).is_ok());
    }
}
