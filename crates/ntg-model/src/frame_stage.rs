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
//! Optionally (`reconstruction`), a small decoder also rebuilds each frame
//! at half resolution from `Enc(o)`: the two heads alone need only what
//! tells actions apart, and leave most of the scene (where each cube is)
//! out of the embedding, while the networks of stage B need it. The
//! decoder sees the raw frame only: no positions or other labels.
//!
//! Then the encoder is frozen, every demo frame is encoded once, and the
//! demo interpreter, the GCN, the localizer and the edge classifier train
//! on the embeddings (stage B, an [`crate::NtgModel`] whose observations are
//! `Enc(o)` rows; see `ntg-trainer`). At run time each frame is encoded
//! once and its embedding read by all three.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::nn::conv::Conv2d;
use burn::tensor::activation::{relu, softplus};
use burn::tensor::{Bool, Device, Int, Tensor};

use crate::encoder::{Encoder, EncoderConfig};
use crate::interpreter::LossOutput;
use crate::nn::{Init, mask_logits, masked_accuracy, masked_cross_entropy, to_vec};
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
    /// Weight of the frame-reconstruction loss (a decoder rebuilds each
    /// frame at half resolution from `Enc(o)`; see the module docs).
    /// `None` or 0: no decoder. An `Option` so that networks saved before
    /// it load.
    pub reconstruction: Option<f32>,
    /// Weight of the progress loss: a linear head reads from `Enc(o)`
    /// which actions of the demo have taken effect by the frame (a
    /// multi-hot target over the `N` nodes, built from the flat action
    /// labels alone; see `FrameStageNet::loss_with_progress`), so that
    /// the embedding keeps what is done in the scene and not only the last
    /// action. `None` or 0: no head. An `Option` so that networks saved
    /// before it load.
    pub progress: Option<f32>,
}

impl FrameStageConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if let Some(w) = self.reconstruction
            && !(w.is_finite() && w >= 0.0)
        {
            return Err(ModelError::Config(format!(
                "frame stage: reconstruction weight must be finite and at least 0, got {w}"
            )));
        }
        if self.reconstruction.is_some_and(|w| w > 0.0)
            && !matches!(self.encoder, EncoderConfig::Frame(_))
        {
            return Err(ModelError::Config(
                "frame stage: reconstruction needs a frame encoder".into(),
            ));
        }
        if self.reconstruction.is_some_and(|w| w > 0.0)
            && matches!(&self.encoder, EncoderConfig::Frame(f) if f.stem_channels().is_some())
        {
            return Err(ModelError::Config(
                "frame stage: reconstruction is not built for an encoder with a stem".into(),
            ));
        }
        if let Some(w) = self.progress
            && !(w.is_finite() && w >= 0.0)
        {
            return Err(ModelError::Config(format!(
                "frame stage: progress weight must be finite and at least 0, got {w}"
            )));
        }
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
        let loc_nodes = init.matrix(self.num_nodes, h, bound);
        let edge_nodes = init.matrix(self.num_nodes, h, bound);
        let w = init.linear(2 * h, h, true);
        let decoder = match (&self.encoder, self.reconstruction) {
            (EncoderConfig::Frame(frame), Some(weight)) if weight > 0.0 => {
                let side = frame.image_size / 8;
                let [_, c2, c3] = frame.conv_channels;
                Some(FrameDecoder {
                    fc: init.linear(h, c3 * side * side, true),
                    conv1: init.conv2d(c3, c2, 3, 1, 1, true),
                    conv2: init.conv2d(c2, frame.channels, 3, 1, 1, false),
                    channels: [c3, frame.channels],
                    side,
                    input_shift: if frame.centre_input == Some(true) {
                        -0.5
                    } else {
                        0.0
                    },
                    weight,
                })
            }
            _ => None,
        };
        // Drawn last, so that the other weights do not depend on it.
        let progress = self
            .progress
            .is_some_and(|w| w > 0.0)
            .then(|| init.linear(h, self.num_nodes, true));
        Ok(FrameStageNet {
            loc_nodes,
            edge_nodes,
            w,
            decoder,
            progress,
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
    /// The frame decoder of [`FrameStageConfig::reconstruction`].
    pub decoder: Option<FrameDecoder>,
    /// The progress head of [`FrameStageConfig::progress`]: `Enc(o)` →
    /// one logit per node.
    pub progress: Option<Linear>,
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
    /// Mean squared error of the rebuilt frames (unweighted), with a
    /// decoder.
    pub reconstruction: Option<Tensor<1>>,
    /// The progress head's binary cross-entropy (summed over the nodes,
    /// unweighted) and the fraction of frames whose whole multi-hot it
    /// gets right, with a progress head and targets.
    pub progress: Option<LossOutput>,
}

/// Rebuilds a frame at half resolution from its embedding: a dense layer
/// to the encoder's last feature map shape (`S/8`), then twice a nearest
/// ×2 upsampling and a 3×3 convolution (to `S/2`).
#[derive(Module, Debug)]
pub struct FrameDecoder {
    /// `Enc(o)` → `[C3, S/8, S/8]`.
    pub fc: Linear,
    /// `C3 → C2` at `S/4`.
    pub conv1: Conv2d,
    /// `C2 →` colour channels at `S/2`.
    pub conv2: Conv2d,
    /// `[C3, colour channels]`.
    pub channels: [usize; 2],
    /// `S/8`.
    pub side: usize,
    /// The encoder's input shift (the target frames get it too).
    pub input_shift: f32,
    /// Weight of the loss.
    pub weight: f32,
}

/// Nearest-neighbour ×2 upsampling of `[B, C, H, W]`.
fn upsample2(x: Tensor<4>) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    let x: Tensor<6> = x.reshape([b, c, h, 1, w, 1]);
    x.repeat_dim(3, 2)
        .repeat_dim(5, 2)
        .reshape([b, c, 2 * h, 2 * w])
}

impl FrameDecoder {
    /// The rebuilt frames `[B, C, S/2, S/2]` of embeddings `[B, H]`.
    pub fn forward(&self, encoded: Tensor<2>) -> Tensor<4> {
        let b = encoded.dims()[0];
        let s = self.side;
        let x: Tensor<4> = relu(self.fc.forward(encoded)).reshape([b, self.channels[0], s, s]);
        let x = relu(crate::conv::conv2d(&self.conv1, upsample2(x)));
        crate::conv::conv2d(&self.conv2, upsample2(x))
    }

    /// Mean squared error against frames `[B, D]` (flattened CHW),
    /// averaged over 2×2 blocks and shifted as the encoder shifts them.
    pub fn loss(&self, encoded: Tensor<2>, frames: Tensor<2>) -> Tensor<1> {
        let b = frames.dims()[0];
        let (c, half) = (self.channels[1], 4 * self.side);
        let target: Tensor<6> = frames
            .add_scalar(self.input_shift)
            .reshape([b, c, half, 2, half, 2]);
        let target: Tensor<4> = target.mean_dim(5).mean_dim(3).reshape([b, c, half, half]);
        (self.forward(encoded) - target).powi_scalar(2).mean()
    }
}

/// Binary cross-entropy of `logits` `[B, N]` against 0/1 `targets`,
/// summed over the nodes and averaged over the rows, and the fraction of
/// rows whose every node is on the right side of 0.
fn progress_loss(logits: Tensor<2>, targets: Tensor<2>) -> Result<LossOutput> {
    let b = logits.dims()[0];
    // softplus(z) − y·z = −[y ln σ(z) + (1 − y) ln(1 − σ(z))].
    let loss = (softplus(logits.clone(), 1.0) - logits.clone() * targets.clone())
        .sum()
        .div_scalar(b as f32);
    let predicted = logits.detach().greater_elem(0.0).float();
    let wrong = (predicted - targets).abs().sum_dim(1).reshape([b]);
    let right = to_vec(wrong.lower_elem(0.5).float())?;
    let accuracy = right.iter().sum::<f32>() / b.max(1) as f32;
    Ok(LossOutput {
        loss: loss.reshape([1]),
        accuracy,
    })
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
        self.check_nodes(b, &nodes, &successors)?;
        let encoded = self.encode(frames)?;
        Ok(self.heads(encoded, nodes, successors))
    }

    /// Checks that `nodes` is `[b]` and `successors` `[b, N]`.
    fn check_nodes(
        &self,
        b: usize,
        nodes: &Tensor<1, Int>,
        successors: &Tensor<2, Bool>,
    ) -> Result<()> {
        let n = self.config.num_nodes;
        if nodes.dims() != [b] || successors.dims() != [b, n] {
            return Err(ModelError::shape(
                "frame stage nodes / successors",
                format!("[{b}] and [{b}, {n}]"),
                (nodes.dims(), successors.dims()),
            ));
        }
        Ok(())
    }

    /// [`FrameStageNet::forward`] from embeddings `[B, H]`.
    fn heads(
        &self,
        encoded: Tensor<2>,
        nodes: Tensor<1, Int>,
        successors: Tensor<2, Bool>,
    ) -> (Tensor<2>, Tensor<2>) {
        let ne_loc = self.loc_nodes.val();
        let loc_logits = encoded.clone().matmul(ne_loc.clone().transpose());
        let node_rows = self.edge_nodes.val().select(0, nodes);
        let query = self.w.forward(Tensor::cat(vec![encoded, node_rows], 1));
        let edge_logits = mask_logits(query.matmul(ne_loc.transpose()), successors);
        (loc_logits, edge_logits)
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
        self.loss_with_progress(frames, labels, next, successors, None)
    }

    /// [`FrameStageNet::loss`] plus, with a progress head, its loss against
    /// `done` `[B, N]`: 1 at each action of the frame's demo that has
    /// taken effect by the frame, 0 elsewhere. (Without `done` a progress
    /// head is not trained; without a head `done` is ignored.)
    pub fn loss_with_progress(
        &self,
        frames: Tensor<2>,
        labels: Tensor<1, Int>,
        next: Tensor<1, Int>,
        successors: Tensor<2, Bool>,
        done: Option<Tensor<2>>,
    ) -> Result<FrameStageLoss> {
        let b = frames.dims()[0];
        if let Some(d) = &done
            && d.dims() != [b, self.config.num_nodes]
        {
            return Err(ModelError::shape(
                "progress targets",
                format!("[{b}, {}]", self.config.num_nodes),
                d.dims(),
            ));
        }
        if next.dims() != [b] {
            return Err(ModelError::shape(
                "next actions",
                format!("[{b}]"),
                next.dims(),
            ));
        }
        self.check_nodes(b, &labels, &successors)?;
        let encoded = self.encode(frames.clone())?;
        let reconstruction = self
            .decoder
            .as_ref()
            .map(|d| d.loss(encoded.clone(), frames));
        let progress = match (&self.progress, done) {
            (Some(head), Some(done)) => Some(progress_loss(head.forward(encoded.clone()), done)?),
            _ => None,
        };
        let (loc_logits, edge_logits) = self.heads(encoded, labels.clone(), successors);
        let ones = Tensor::<1>::ones([b], &loc_logits.device());
        let localizer = LossOutput {
            accuracy: masked_accuracy(loc_logits.clone(), labels.clone(), ones.clone())?,
            loss: masked_cross_entropy(loc_logits, labels, ones.clone()),
        };
        let edge = LossOutput {
            accuracy: masked_accuracy(edge_logits.clone(), next.clone(), ones.clone())?,
            loss: masked_cross_entropy(edge_logits, next, ones),
        };
        let mut loss = localizer.loss.clone() + edge.loss.clone();
        if let (Some(decoder), Some(r)) = (&self.decoder, &reconstruction) {
            loss = loss + r.clone().mul_scalar(decoder.weight);
        }
        if let (Some(weight), Some(p)) = (self.config.progress, &progress) {
            loss = loss + p.loss.clone().mul_scalar(weight);
        }
        Ok(FrameStageLoss {
            loss,
            localizer,
            edge,
            reconstruction,
            progress,
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

    /// With a progress weight, the head learns a multi-hot target that the
    /// frame shows (which of two regions is bright), and the other weights
    /// start as without the head.
    #[test]
    fn the_progress_head_learns_what_the_frame_shows_is_done() {
        let device = Device::flex().autodiff();
        let config = small().with_progress(Some(1.0));
        let mut net = config.init(&device).unwrap();
        let plain = small().init(&device).unwrap();
        assert_eq!(
            crate::nn::to_vec(net.loc_nodes.val()).unwrap(),
            crate::nn::to_vec(plain.loc_nodes.val()).unwrap()
        );
        let dim = 3 * 16 * 16;
        // Frame k: the left half bright if bit 0 of k, the right if bit 1;
        // targets: node 2 for the left, node 3 for the right.
        let rows: Vec<Vec<f32>> = (0..8)
            .map(|k| {
                (0..dim)
                    .map(|i| {
                        let left = i % 16 < 8;
                        let on = if left { k & 1 == 1 } else { k & 2 == 2 };
                        if on { 0.9 } else { 0.1 }
                    })
                    .collect()
            })
            .collect();
        let done: Vec<f32> = (0..8)
            .flat_map(|k| {
                let mut row = vec![0.0; 5];
                row[2] = (k & 1) as f32;
                row[3] = ((k >> 1) & 1) as f32;
                row
            })
            .collect();
        let labels = vec![ActionId::new(2); 8];
        let graph = Ctg::from_path(5, &[ActionId::new(2)]).unwrap();
        let next = vec![ActionId::new(1); 8];
        let mut optim = AdamConfig::new().init();
        let mut accuracy = 0.0;
        for _ in 0..80 {
            let out = net
                .loss_with_progress(
                    rows_tensor(&rows, dim, &device).unwrap(),
                    ids_tensor(&labels, 5, &device).unwrap(),
                    ids_tensor(&next, 5, &device).unwrap(),
                    successor_mask(&[&graph; 8], &labels, Some(&next), 5, &device).unwrap(),
                    Some(Tensor::from_data(
                        burn::tensor::TensorData::new(done.clone(), [8, 5]),
                        &device,
                    )),
                )
                .unwrap();
            accuracy = out.progress.as_ref().unwrap().accuracy;
            let grads = GradientsParams::from_grads(out.loss.backward(), &net);
            net = optim.step(3e-3, net, grads);
        }
        assert_eq!(accuracy, 1.0);
        // Targets of the wrong shape are an error, not a panic.
        assert!(
            net.loss_with_progress(
                rows_tensor(&rows, dim, &device).unwrap(),
                ids_tensor(&labels, 5, &device).unwrap(),
                ids_tensor(&next, 5, &device).unwrap(),
                successor_mask(&[&graph; 8], &labels, Some(&next), 5, &device).unwrap(),
                Some(Tensor::zeros([8, 4], &device)),
            )
            .is_err()
        );
    }

    /// The trainer encodes frames on whatever pool a run has (one thread,
    /// or two), and caches the embeddings for later stages and other runs
    /// to read: the full-size encoder's output must be the same, bit for
    /// bit, on one thread and on two.
    #[test]
    fn encoding_does_not_depend_on_the_thread_count() {
        let device = Device::flex();
        let net = FrameStageConfig::new(5, EncoderConfig::frame())
            .init(&device)
            .unwrap();
        let dim = net.encoder.input_dim();
        let rows: Vec<Vec<f32>> = (0..48)
            .map(|r| {
                (0..dim)
                    .map(|k| ((r * 7919 + k * 104_729) % 1000) as f32 / 1000.0)
                    .collect()
            })
            .collect();
        let encode_on = |threads: usize| {
            let pool = crate::parallel::compute_pool_builder(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let encoded = net
                    .encode(rows_tensor(&rows, dim, &device).unwrap())
                    .unwrap();
                crate::nn::to_vec(encoded).unwrap()
            })
        };
        let (one, two) = (encode_on(1), encode_on(2));
        assert_eq!(one.len(), 48 * net.encoder.out_dim());
        let differing = one
            .iter()
            .zip(&two)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .count();
        assert_eq!(differing, 0, "{differing} of {} values differ", one.len());
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
        for field in ["hidden", "he_init", "centre_input", "coord_channels"] {
            frame.remove(field);
        }
        json.as_object_mut().unwrap().remove("reconstruction");
        json.as_object_mut().unwrap().remove("progress");
        std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
        std::fs::remove_file(dir.path().join("config.json.sha256")).unwrap();
        assert!(FrameStageNet::load(dir.path(), &device).is_ok());
    }

    /// With a reconstruction weight, the embedding learns to keep where a
    /// bright square sits (which the heads' labels do not tell): the
    /// decoder's error falls far below that of the best frame-blind guess
    /// (the mean frame).
    #[test]
    fn the_decoder_learns_to_rebuild_frames_from_the_embedding() {
        let device = Device::flex().autodiff();
        let config = small().with_reconstruction(Some(1.0));
        let mut net = config.init(&device).unwrap();
        assert!(net.decoder.is_some());
        assert!(
            small()
                .with_reconstruction(Some(0.0))
                .init(&device)
                .unwrap()
                .decoder
                .is_none()
        );
        let dim = 3 * 16 * 16;
        // A 4×4 square at one of 9 places; the label is the same for all.
        let rows: Vec<Vec<f32>> = (0..9)
            .map(|i| {
                let (y0, x0) = (4 * (i / 3), 4 * (i % 3));
                (0..dim)
                    .map(|k| {
                        let (y, x) = ((k % 256) / 16, k % 16);
                        let inside = (y0..y0 + 4).contains(&y) && (x0..x0 + 4).contains(&x);
                        if inside { 1.0 } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let labels = vec![ActionId::new(2); 9];
        let next = vec![ActionId::new(1); 9];
        let graph = Ctg::from_path(5, &[ActionId::new(2)]).unwrap();
        let mut optim = AdamConfig::new().init();
        let mut errors = Vec::new();
        for _ in 0..150 {
            let out = net
                .loss(
                    rows_tensor(&rows, dim, &device).unwrap(),
                    ids_tensor(&labels, 5, &device).unwrap(),
                    ids_tensor(&next, 5, &device).unwrap(),
                    successor_mask(&[&graph; 9], &labels, Some(&next), 5, &device).unwrap(),
                )
                .unwrap();
            errors.push(crate::nn::to_vec(out.reconstruction.clone().unwrap()).unwrap()[0]);
            let grads = GradientsParams::from_grads(out.loss.backward(), &net);
            net = optim.step(3e-3, net, grads);
        }
        // The mean frame at half resolution: 36 of its 64 pixels are lit in
        // 1 frame of 9 (variance 8/81), the others never.
        let blind = 36.0 / 64.0 * 8.0 / 81.0;
        let (first, last) = (errors[0], *errors.last().unwrap());
        assert!(
            last < 0.5 * blind,
            "reconstruction error {first} -> {last}, mean frame {blind}"
        );
    }
}
