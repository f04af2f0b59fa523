//! The detector of the NTP (Detector) baseline: a frame → object-positions
//! regressor, trained separately on the simulator's positions (the one
//! method of the block-stacking figure that gets that extra supervision),
//! whose estimated state rows feed an NTP network trained on true states.
//!
//! ```text
//! f      = Enc(frame)                              a frame encoder
//! h      = relu(W_1 f + b_1)
//! [p; g] = W_2 h + b_2                             p: K objects × (x, y, z)
//!                                                  g: gripper logits (open, closed)
//! loss   = mean_k,d ((p_kd − p*_kd) / s)² + CE(g, g*)
//! ```
//!
//! `s` ([`DetectorConfig::position_scale`]) puts the positions on a unit
//! scale for the loss and the head: the head predicts `p / s`. Without it,
//! positions whose spread is a fraction of a unit give the squared error
//! gradients too small beside the gripper's cross-entropy.
//!
//! The output row has the layout of a state row: `3K` position values,
//! then the gripper as a one-hot `[open, closed]` (the predicted state row
//! puts a 1 on the likelier). What the positions are relative to is the
//! caller's business (block stacking: each cube relative to the gripper).

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::batch::rows_tensor;
use crate::encoder::{Encoder, EncoderConfig};
use crate::nn::{Init, masked_accuracy, masked_cross_entropy, scalar, to_vec};
use crate::{ModelError, Result};

/// Configuration of a [`Detector`]; saved beside its weights as JSON.
#[derive(Config, Debug)]
pub struct DetectorConfig {
    /// Objects `K` whose positions are estimated.
    pub num_objects: usize,
    /// The frame encoder.
    pub encoder: EncoderConfig,
    /// Width of the head's hidden layer.
    #[config(default = 256)]
    pub hidden: usize,
    /// The positions' scale `s` (e.g. their standard deviation in the
    /// training frames); `None`: 1.
    pub position_scale: Option<f32>,
    /// Seed of the initial weights.
    #[config(default = 0)]
    pub seed: u64,
}

impl DetectorConfig {
    /// Values of a state row: `3K` positions and the gripper's two.
    pub fn row_dim(&self) -> usize {
        3 * self.num_objects + 2
    }

    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if let Some(s) = self.position_scale
            && !(s.is_finite() && s > 0.0)
        {
            return Err(ModelError::Config(format!(
                "detector: the position scale must be finite and positive, got {s}"
            )));
        }
        if self.num_objects == 0 || self.hidden == 0 {
            return Err(ModelError::Config(format!(
                "detector: needs at least one object and a positive width (got {}, {})",
                self.num_objects, self.hidden
            )));
        }
        Ok(())
    }

    /// A detector with fresh weights on `device`.
    pub fn init(&self, device: &Device) -> Result<Detector> {
        self.validate()?;
        let encoder = self.encoder.init(self.seed.wrapping_add(29), device)?;
        let mut init = Init::new(self.seed ^ 0x0de7_ec70, device);
        Ok(Detector {
            hidden: init.linear(encoder.out_dim(), self.hidden, true),
            out: init.linear(self.hidden, self.row_dim(), true),
            encoder,
            config: self.clone(),
        })
    }
}

/// The frame → state-row regressor (see the module docs).
#[derive(Module, Debug)]
pub struct Detector {
    /// `Enc(frame)`.
    pub encoder: Encoder,
    /// `W_1`.
    pub hidden: Linear,
    /// `W_2`: positions and gripper logits.
    pub out: Linear,
    /// The configuration the network was built from.
    #[module(skip)]
    pub config: DetectorConfig,
}

/// A detector's loss on a batch, and what it tells.
#[derive(Debug, Clone)]
pub struct DetectorLoss {
    /// Mean squared position error plus the gripper's cross-entropy.
    pub loss: Tensor<1>,
    /// Mean Euclidean distance between estimated and true object
    /// positions (in the positions' units).
    pub position_error: f32,
    /// Fraction of frames whose gripper state is right.
    pub gripper_accuracy: f32,
}

impl Detector {
    fn device(&self) -> Device {
        self.hidden.weight.val().device()
    }

    /// Scaled positions `p / s` and gripper logits `[N, 3K + 2]` of
    /// frames `[N, D]`.
    pub fn forward(&self, frames: Tensor<2>) -> Result<Tensor<2>> {
        let features = self.encoder.forward(frames)?;
        Ok(self.out.forward(relu(self.hidden.forward(features))))
    }

    fn scale(&self) -> f32 {
        self.config.position_scale.unwrap_or(1.0)
    }

    /// The loss against true state rows `[N, 3K + 2]` (positions, then the
    /// gripper one-hot).
    pub fn loss(&self, frames: Tensor<2>, rows: Tensor<2>) -> Result<DetectorLoss> {
        let [n, d] = rows.dims();
        let k = self.config.num_objects;
        if d != self.config.row_dim() || frames.dims()[0] != n || n == 0 {
            return Err(ModelError::shape(
                "detector targets",
                format!("{} frames and [{}, {}] rows", n, n, self.config.row_dim()),
                (frames.dims(), rows.dims()),
            ));
        }
        let out = self.forward(frames)?;
        let positions = out.clone().narrow(1, 0, 3 * k);
        let logits = out.narrow(1, 3 * k, 2);
        let scale = self.scale();
        let target_positions = rows.clone().narrow(1, 0, 3 * k).div_scalar(scale);
        let diff = positions - target_positions;
        let position_loss = diff.clone().powi_scalar(2).mean();
        let distances = diff
            .detach()
            .mul_scalar(scale)
            .reshape([n, k, 3])
            .powi_scalar(2)
            .sum_dim(2)
            .sqrt();
        let position_error = scalar(distances.mean())?;
        let closed = rows
            .narrow(1, 3 * k + 1, 1)
            .reshape([n])
            .greater_elem(0.5)
            .int();
        let ones = Tensor::ones([n], &self.device());
        let gripper_loss = masked_cross_entropy(logits.clone(), closed.clone(), ones.clone());
        let gripper_accuracy = masked_accuracy(logits, closed, ones)?;
        Ok(DetectorLoss {
            loss: position_loss + gripper_loss,
            position_error,
            gripper_accuracy,
        })
    }

    /// Estimated state rows of `frames` (each of `D` values): positions,
    /// then the gripper one-hot of the likelier state.
    pub fn predict_rows<R: AsRef<[f32]>>(&self, frames: &[R]) -> Result<Vec<Vec<f32>>> {
        if frames.is_empty() {
            return Ok(Vec::new());
        }
        let device = self.device();
        let out = to_vec(self.forward(rows_tensor(frames, self.encoder.input_dim(), &device)?)?)?;
        let width = self.config.row_dim();
        let k = self.config.num_objects;
        Ok(out
            .chunks(width)
            .map(|row| {
                let mut state: Vec<f32> = row[..3 * k].iter().map(|p| p * self.scale()).collect();
                let closed = row[3 * k + 1] > row[3 * k];
                state.extend([f32::from(u8::from(!closed)), f32::from(u8::from(closed))]);
                state
            })
            .collect())
    }

    /// Saves the configuration (`config.json`) and weights (`model.bpk`)
    /// into `dir`, creating it if needed.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        crate::checkpoint::save(self, &self.config, dir.as_ref())
    }

    /// Loads a detector saved by [`Detector::save`] onto `device`; a
    /// missing, corrupt or mismatched file is an error naming it.
    pub fn load(dir: impl AsRef<Path>, device: &Device) -> Result<Self> {
        let config: DetectorConfig =
            crate::checkpoint::load_config(dir.as_ref(), DetectorConfig::validate)?;
        crate::checkpoint::load_weights(config.init(device)?, dir.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::device as cpu_device;
    use crate::{EncoderConfig, FrameEncoderConfig};
    use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const SIDE: usize = 16;

    fn small_encoder() -> EncoderConfig {
        EncoderConfig::Frame(
            FrameEncoderConfig::new()
                .with_image_size(SIDE)
                .with_conv_channels([8, 16, 16])
                .with_coord_channels(Some(true))
                .with_out_dim(32),
        )
    }

    /// A black frame with one white 2×2 square at `(x, y)` (pixels), and
    /// its state row: the square's centre scaled to `[0, 1]` as object 0's
    /// x and y, z = 0, and the gripper closed when the square is in the
    /// frame's left half.
    fn scene(rng: &mut ChaCha8Rng) -> (Vec<f32>, Vec<f32>) {
        let x = rng.random_range(0..SIDE - 1);
        let y = rng.random_range(0..SIDE - 1);
        let mut frame = vec![0.0f32; 3 * SIDE * SIDE];
        for c in 0..3 {
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                frame[c * SIDE * SIDE + (y + dy) * SIDE + x + dx] = 1.0;
            }
        }
        let scale = (SIDE - 1) as f32;
        let closed = x < SIDE / 2;
        let row = vec![
            (x as f32 + 0.5) / scale,
            (y as f32 + 0.5) / scale,
            0.0,
            f32::from(u8::from(!closed)),
            f32::from(u8::from(closed)),
        ];
        (frame, row)
    }

    #[test]
    fn bad_sizes_are_errors() {
        assert!(DetectorConfig::new(0, small_encoder()).validate().is_err());
        let net = DetectorConfig::new(1, small_encoder())
            .init(&cpu_device())
            .unwrap();
        let device = cpu_device();
        let frames = Tensor::<2>::zeros([2, 3 * SIDE * SIDE], &device);
        assert!(
            net.loss(frames.clone(), Tensor::zeros([2, 4], &device))
                .is_err()
        );
        assert!(net.loss(frames, Tensor::zeros([3, 5], &device)).is_err());
        assert!(net.predict_rows(&[vec![0.0; 7]]).is_err());
    }

    /// The detector learns where a square is, and the gripper bit, on
    /// frames it never saw: held-out position error well under that of
    /// always answering the mean position.
    #[test]
    fn the_detector_learns_positions_it_is_scored_on_held_out_frames() {
        let device = cpu_device().autodiff();
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let train: Vec<_> = (0..256).map(|_| scene(&mut rng)).collect();
        let held_out: Vec<_> = (0..64).map(|_| scene(&mut rng)).collect();
        let mut net = DetectorConfig::new(1, small_encoder())
            .with_hidden(64)
            .with_seed(4)
            .init(&device)
            .unwrap();
        let mut optim: ModuleOptimizer = AdamConfig::new().init();
        let tensors = |set: &[(Vec<f32>, Vec<f32>)], device: &Device| {
            let frames: Vec<&[f32]> = set.iter().map(|(f, _)| &f[..]).collect();
            let rows: Vec<&[f32]> = set.iter().map(|(_, r)| &r[..]).collect();
            (
                rows_tensor(&frames, 3 * SIDE * SIDE, device).unwrap(),
                rows_tensor(&rows, 5, device).unwrap(),
            )
        };
        for _epoch in 0..40 {
            for batch in train.chunks(32) {
                let (frames, rows) = tensors(batch, &device);
                let out = net.loss(frames, rows).unwrap();
                let grads = GradientsParams::from_grads(out.loss.backward(), &net);
                net = optim.step(3e-3, net, grads);
            }
        }
        let valid = net.valid();
        let plain = cpu_device();
        let (frames, rows) = tensors(&held_out, &plain);
        let scored = valid.loss(frames, rows).unwrap();
        // Always answering the mean position (0.5, 0.5): about 0.38 away.
        let baseline: f32 = held_out
            .iter()
            .map(|(_, r)| ((r[0] - 0.5).powi(2) + (r[1] - 0.5).powi(2)).sqrt())
            .sum::<f32>()
            / held_out.len() as f32;
        eprintln!(
            "held-out: position error {:.4} (mean position: {baseline:.4}), gripper {:.3}",
            scored.position_error, scored.gripper_accuracy
        );
        assert!(
            scored.position_error < 0.35 * baseline,
            "held-out position error {} vs {baseline} for the mean",
            scored.position_error
        );
        assert!(
            scored.gripper_accuracy > 0.9,
            "gripper {}",
            scored.gripper_accuracy
        );
        // Predicted rows have the state-row layout, gripper one-hot.
        let predicted = valid.predict_rows(&[&held_out[0].0[..]]).unwrap();
        assert_eq!(predicted[0].len(), 5);
        assert_eq!(predicted[0][3] + predicted[0][4], 1.0);
        // Saved and loaded, it predicts the same rows.
        let dir = tempfile::tempdir().unwrap();
        valid.save(dir.path()).unwrap();
        let loaded = Detector::load(dir.path(), &plain).unwrap();
        assert_eq!(
            loaded.predict_rows(&[&held_out[0].0[..]]).unwrap(),
            predicted
        );
    }
}
