//! Observation encoders `Enc(o)`: one flat observation row `[D]` in, one
//! embedding `[H]` out.
//!
//! Observations arrive as flat `f32` rows, a batch being a `[B, D]` tensor:
//!
//! - **state** (`D` = e.g. 26 for block stacking): an MLP;
//! - **frame** (`D = 3·S·S`, CHW order, values in `[0, 1]`): three strided
//!   convolutions and a linear layer;
//! - **kinematics window** (`D = W·C`, `W` rows of `C` = 76 columns,
//!   row-major): a per-row linear layer shared across time, then an MLP over
//!   the window.
//!
//! [`EncoderConfig`] picks one; everything downstream sees `[B, H]`.

use burn::config::Config;
use burn::module::Module;
use burn::nn::Linear;
use burn::nn::conv::Conv2d;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::nn::Init;
use crate::{ModelError, Result};

/// An MLP over a state vector: `Enc(o) = W_out h_L + b_out` with
/// `h_1 = relu(W₁ o + b₁)` and `h_{k+1} = relu(W_k h_k + b_k)` for
/// `hidden_layers = L` hidden layers.
#[derive(Config, Debug)]
pub struct StateEncoderConfig {
    /// Length `D` of the state vector (26 for block stacking).
    pub input_dim: usize,
    /// Hidden width.
    #[config(default = 128)]
    pub hidden: usize,
    /// Number of hidden layers `L ≥ 1`. Relations between objects (is a
    /// cube on the one under the gripper?) need more than one.
    #[config(default = 1)]
    pub hidden_layers: usize,
    /// Relational input: when `K > 0`, the first `3K` values of the state
    /// are `K` object positions, and the MLP reads the state followed by
    /// every pairwise difference `p_i − p_j` (`3K²` more values). The
    /// encoder sees nothing new, only structure: whether one cube is on
    /// another becomes a single feature instead of a learned comparison.
    #[config(default = 0)]
    pub pairwise_objects: usize,
    /// Heights read as far as `limit` only: with `Some(limit)`, the
    /// vertical coordinate (every third value) of the first
    /// [`StateEncoderConfig::clamped_objects`] positions, and of every
    /// pairwise difference, is clamped to `[−limit, limit]` before the MLP.
    /// At a limit no training state exceeds this is the identity on the
    /// training data; on taller towers than any trained on it shows a cube
    /// far below as "far below" instead of a value the MLP never saw.
    /// `None` (and configurations saved before it): off.
    pub height_clamp: Option<f32>,
    /// How many object positions (`x, y, z` each, from the start of the
    /// state) [`StateEncoderConfig::height_clamp`] applies to; `None`:
    /// [`StateEncoderConfig::pairwise_objects`].
    pub clamped_objects: Option<usize>,
    /// Embedding size `H`.
    #[config(default = 128)]
    pub out_dim: usize,
}

/// A CNN over `S×S` RGB frames: three `k×k` convolutions (`k` = 3 or 4)
/// of stride 2 and padding 1 (`S → S/2 → S/4 → S/8`) with ReLU, then a
/// linear layer to `H`, or (with a `hidden` width) a one-hidden-layer MLP to
/// `H`.
#[derive(Config, Debug)]
pub struct FrameEncoderConfig {
    /// Frame side `S` in pixels (a multiple of 8).
    #[config(default = 64)]
    pub image_size: usize,
    /// Colour channels.
    #[config(default = 3)]
    pub channels: usize,
    /// Output channels of the three convolutions.
    #[config(default = "[32, 64, 64]")]
    pub conv_channels: [usize; 3],
    /// Kernel side `k` of the convolutions: 3 (default; about 20% faster
    /// to train on CPU) or 4.
    #[config(default = 3)]
    pub kernel: usize,
    /// Width of a hidden layer between the flattened feature map and `H`
    /// (the feature map maps linearly to `H` without it). A linear read-out
    /// of the feature map can only add up what each position sees; which
    /// cube sits under the gripper is a relation between positions.
    /// (`None` or 0: none; an `Option` so that checkpoints saved before it
    /// load.)
    pub hidden: Option<usize>,
    /// He initialisation of the convolutions (weight variance `2/fan_in`,
    /// made for the ReLU after each) instead of PyTorch's default (a third
    /// of `1/fan_in`), under which the activations shrink about 2.4× per
    /// layer and the encoder starts near zero. `None`: off.
    pub he_init: Option<bool>,
    /// Shift the frame's values from `[0, 1]` to `[-0.5, 0.5]` before the
    /// first convolution. `None`: off.
    pub centre_input: Option<bool>,
    /// Two coordinate channels (x and y, from −1 to 1) added to the frame
    /// before the first convolution ("CoordConv"), so that where something
    /// is in the frame is an input the convolutions can read, not only a
    /// position in the feature map. `None`: off.
    pub coord_channels: Option<bool>,
    /// Spatial-softmax keypoints (Levine et al. 2016, "deep spatial
    /// autoencoders"): the third convolution keeps its input's resolution
    /// (stride 1, an `S/4` map), each of its `C₃` channels becomes the
    /// expected image coordinates `(x, y)` (from −1 to 1) under a softmax
    /// over the map, and the linear layer (or MLP) reads those `2C₃`
    /// coordinates instead of the flattened map. Made for reading
    /// positions off a frame (NTP (Detector)'s detector). `None`: off.
    pub spatial_softmax: Option<bool>,
    /// A stem: one more `k×k` convolution of stride 2 with this many output
    /// channels before the three (`S → S/2`, so the three see an `S/2`
    /// frame: `S` a multiple of 16). For larger frames (128×128) at about
    /// the cost of the three on a frame of half the side. `None` or 0:
    /// none (checkpoints saved before it load).
    pub stem: Option<usize>,
    /// Embedding size `H`.
    #[config(default = 128)]
    pub out_dim: usize,
}

impl FrameEncoderConfig {
    /// Output channels of the stem convolution, if there is one.
    pub fn stem_channels(&self) -> Option<usize> {
        self.stem.filter(|&c| c > 0)
    }

    /// Side of the frame the three main convolutions read: `S`, or `S/2`
    /// after a stem.
    pub fn trunk_input_side(&self) -> usize {
        match self.stem_channels() {
            Some(_) => self.image_size / 2,
            None => self.image_size,
        }
    }
}

/// An encoder for kinematics windows of `window` rows by `columns` columns:
/// `Enc(o) = W₂ relu(W₁ [relu(V r₁ + c); …; relu(V r_W + c)] + b₁) + b₂`,
/// where `r_t` is row `t` and `V` is shared across rows.
#[derive(Config, Debug)]
pub struct KinematicsEncoderConfig {
    /// Rows per window `W`.
    pub window: usize,
    /// Columns per row (76 for JIGSAWS).
    #[config(default = 76)]
    pub columns: usize,
    /// Width of the per-row projection.
    #[config(default = 32)]
    pub row_hidden: usize,
    /// Hidden width of the window MLP.
    #[config(default = 128)]
    pub hidden: usize,
    /// Embedding size `H`.
    #[config(default = 128)]
    pub out_dim: usize,
}

/// Which observation encoder to use.
#[derive(Config, Debug)]
pub enum EncoderConfig {
    /// Full state vectors.
    State(StateEncoderConfig),
    /// RGB frames.
    Frame(FrameEncoderConfig),
    /// Kinematics windows.
    Kinematics(KinematicsEncoderConfig),
}

impl EncoderConfig {
    /// The state encoder for vectors of length `input_dim`, default sizes.
    pub fn state(input_dim: usize) -> Self {
        EncoderConfig::State(StateEncoderConfig::new(input_dim))
    }

    /// The frame encoder for 64×64 RGB frames, default sizes.
    pub fn frame() -> Self {
        EncoderConfig::Frame(FrameEncoderConfig::new())
    }

    /// The kinematics encoder for windows of `window` rows of 76 columns.
    pub fn kinematics(window: usize) -> Self {
        EncoderConfig::Kinematics(KinematicsEncoderConfig::new(window))
    }

    /// Length `D` of one flat observation row.
    pub fn input_dim(&self) -> usize {
        match self {
            EncoderConfig::State(c) => c.input_dim,
            EncoderConfig::Frame(c) => c.channels * c.image_size * c.image_size,
            EncoderConfig::Kinematics(c) => c.window * c.columns,
        }
    }

    /// Embedding size `H`.
    pub fn out_dim(&self) -> usize {
        match self {
            EncoderConfig::State(c) => c.out_dim,
            EncoderConfig::Frame(c) => c.out_dim,
            EncoderConfig::Kinematics(c) => c.out_dim,
        }
    }

    /// Checks that the sizes can build an encoder.
    pub fn validate(&self) -> Result<()> {
        let positive = |name: &str, v: usize| {
            if v == 0 {
                Err(ModelError::Config(format!(
                    "encoder: {name} must be positive"
                )))
            } else {
                Ok(())
            }
        };
        match self {
            EncoderConfig::State(c) => {
                positive("input_dim", c.input_dim)?;
                positive("hidden", c.hidden)?;
                positive("hidden_layers", c.hidden_layers)?;
                if let Some(limit) = c.height_clamp
                    && !(limit.is_finite() && limit > 0.0)
                {
                    return Err(ModelError::Config(format!(
                        "encoder: height_clamp must be a positive number, got {limit}"
                    )));
                }
                let clamped = c.clamped_objects.unwrap_or(c.pairwise_objects);
                if c.height_clamp.is_some() && 3 * clamped > c.input_dim {
                    return Err(ModelError::Config(format!(
                        "encoder: height_clamp over {clamped} objects needs at least {} state values, got {}",
                        3 * clamped,
                        c.input_dim
                    )));
                }
                if 3 * c.pairwise_objects > c.input_dim {
                    return Err(ModelError::Config(format!(
                        "encoder: pairwise_objects = {} needs at least {} state values, got {}",
                        c.pairwise_objects,
                        3 * c.pairwise_objects,
                        c.input_dim
                    )));
                }
                positive("out_dim", c.out_dim)
            }
            EncoderConfig::Frame(c) => {
                positive("channels", c.channels)?;
                positive("out_dim", c.out_dim)?;
                for &ch in &c.conv_channels {
                    positive("conv_channels", ch)?;
                }
                if c.kernel != 3 && c.kernel != 4 {
                    return Err(ModelError::Config(format!(
                        "encoder: kernel must be 3 or 4, got {}",
                        c.kernel
                    )));
                }
                if c.image_size == 0 || c.image_size % 8 != 0 {
                    return Err(ModelError::Config(format!(
                        "encoder: image_size must be a positive multiple of 8, got {}",
                        c.image_size
                    )));
                }
                if c.stem_channels().is_some() && !c.image_size.is_multiple_of(16) {
                    return Err(ModelError::Config(format!(
                        "encoder: a stem needs image_size a multiple of 16, got {}",
                        c.image_size
                    )));
                }
                Ok(())
            }
            EncoderConfig::Kinematics(c) => {
                positive("window", c.window)?;
                positive("columns", c.columns)?;
                positive("row_hidden", c.row_hidden)?;
                positive("hidden", c.hidden)?;
                positive("out_dim", c.out_dim)
            }
        }
    }

    /// Builds the encoder with weights drawn from `seed` on `device`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<Encoder> {
        self.validate()?;
        let mut init = Init::new(seed, device);
        Ok(match self {
            EncoderConfig::State(c) => Encoder::State(StateEncoder {
                fc1: init.linear(
                    c.input_dim + 3 * c.pairwise_objects * c.pairwise_objects,
                    c.hidden,
                    true,
                ),
                mid: (1..c.hidden_layers)
                    .map(|_| init.linear(c.hidden, c.hidden, true))
                    .collect(),
                fc2: init.linear(c.hidden, c.out_dim, true),
                input_dim: c.input_dim,
                pairwise_objects: c.pairwise_objects,
                height_clamp: c.height_clamp.unwrap_or(0.0),
                clamped_objects: match c.height_clamp {
                    Some(_) => c.clamped_objects.unwrap_or(c.pairwise_objects),
                    None => 0,
                },
            }),
            EncoderConfig::Frame(c) => {
                let [c1, c2, c3] = c.conv_channels;
                let keypoints = c.spatial_softmax == Some(true);
                let side = c.trunk_input_side() / 8;
                let flat = if keypoints { 2 * c3 } else { c3 * side * side };
                let he = c.he_init == Some(true);
                let mut conv = |c_in: usize, c_out: usize, stride: usize| {
                    // Stride 1 keeps the side with padding 1 at kernel 3.
                    let kernel = if stride == 1 { 3 } else { c.kernel };
                    init.conv2d(c_in, c_out, kernel, stride, 1, he)
                };
                let coords = c.coord_channels == Some(true);
                let c_in = c.channels + if coords { 2 } else { 0 };
                let stem = c.stem_channels().map(|s| conv(c_in, s, 2));
                let c0 = c.stem_channels().unwrap_or(c_in);
                let (conv1, conv2) = (conv(c0, c1, 2), conv(c1, c2, 2));
                let conv3 = conv(c2, c3, if keypoints { 1 } else { 2 });
                let (fc, head) = if let Some(hidden) = c.hidden.filter(|&h| h > 0) {
                    let fc = init.linear(flat, hidden, true);
                    (fc, Some(init.linear(hidden, c.out_dim, true)))
                } else {
                    (init.linear(flat, c.out_dim, true), None)
                };
                Encoder::Frame(FrameEncoder {
                    stem,
                    conv1,
                    conv2,
                    conv3,
                    fc,
                    head,
                    input_shift: if c.centre_input == Some(true) {
                        -0.5
                    } else {
                        0.0
                    },
                    channels: c.channels,
                    image_size: c.image_size,
                    coords,
                    keypoints,
                })
            }
            EncoderConfig::Kinematics(c) => Encoder::Kinematics(KinematicsEncoder {
                row: init.linear(c.columns, c.row_hidden, true),
                fc1: init.linear(c.window * c.row_hidden, c.hidden, true),
                fc2: init.linear(c.hidden, c.out_dim, true),
                window: c.window,
                columns: c.columns,
            }),
        })
    }
}

/// The state MLP (see [`StateEncoderConfig`]).
#[derive(Module, Debug)]
pub struct StateEncoder {
    /// First layer.
    pub fc1: Linear,
    /// Hidden layers after the first (`hidden_layers − 1` of them).
    pub mid: Vec<Linear>,
    /// Output layer.
    pub fc2: Linear,
    /// Length `D` of the state.
    pub input_dim: usize,
    /// `K` of [`StateEncoderConfig::pairwise_objects`].
    pub pairwise_objects: usize,
    /// [`StateEncoderConfig::height_clamp`]'s limit (0: off).
    pub height_clamp: f32,
    /// The positions it applies to (0: off).
    pub clamped_objects: usize,
}

/// The frame CNN (see [`FrameEncoderConfig`]).
#[derive(Module, Debug)]
pub struct FrameEncoder {
    /// `S → S/2` before the three (with [`FrameEncoderConfig::stem`]).
    pub stem: Option<Conv2d>,
    /// `S → S/2` (after a stem: `S/2 → S/4`, and so on below).
    pub conv1: Conv2d,
    /// `S/2 → S/4`.
    pub conv2: Conv2d,
    /// `S/4 → S/8`.
    pub conv3: Conv2d,
    /// Flattened feature map to `H`, or to the hidden layer when `head`
    /// is present.
    pub fc: Linear,
    /// Hidden layer to `H` (with [`FrameEncoderConfig::hidden`] > 0).
    pub head: Option<Linear>,
    /// Added to every input value (−0.5 with
    /// [`FrameEncoderConfig::centre_input`], else 0).
    pub input_shift: f32,
    /// Colour channels.
    pub channels: usize,
    /// Frame side.
    pub image_size: usize,
    /// With [`FrameEncoderConfig::coord_channels`].
    pub coords: bool,
    /// With [`FrameEncoderConfig::spatial_softmax`].
    pub keypoints: bool,
}

/// The kinematics-window encoder (see [`KinematicsEncoderConfig`]).
#[derive(Module, Debug)]
pub struct KinematicsEncoder {
    /// Per-row projection, shared across the window.
    pub row: Linear,
    /// Window MLP, first layer.
    pub fc1: Linear,
    /// Window MLP, output layer.
    pub fc2: Linear,
    /// Rows per window.
    pub window: usize,
    /// Columns per row.
    pub columns: usize,
}

/// An observation encoder `Enc(o)`: `[B, D]` → `[B, H]`.
#[derive(Module, Debug)]
#[allow(clippy::large_enum_variant)] // a handful per model; boxing buys nothing
pub enum Encoder {
    /// State MLP.
    State(StateEncoder),
    /// Frame CNN.
    Frame(FrameEncoder),
    /// Kinematics-window encoder.
    Kinematics(KinematicsEncoder),
}

impl Encoder {
    /// Length `D` of the observation rows this encoder reads.
    pub fn input_dim(&self) -> usize {
        match self {
            Encoder::State(e) => e.input_dim,
            Encoder::Frame(e) => e.channels * e.image_size * e.image_size,
            Encoder::Kinematics(e) => e.window * e.columns,
        }
    }

    /// Embedding size `H`.
    pub fn out_dim(&self) -> usize {
        match self {
            Encoder::State(e) => e.fc2.weight.dims()[1],
            Encoder::Frame(e) => e.head.as_ref().unwrap_or(&e.fc).weight.dims()[1],
            Encoder::Kinematics(e) => e.fc2.weight.dims()[1],
        }
    }

    /// `Enc(o)` for a batch of flat observation rows `[B, D]` → `[B, H]`.
    pub fn forward(&self, obs: Tensor<2>) -> Result<Tensor<2>> {
        let [batch, dim] = obs.dims();
        if dim != self.input_dim() || batch == 0 {
            return Err(ModelError::shape(
                "observations",
                format!("[B ≥ 1, {}]", self.input_dim()),
                [batch, dim],
            ));
        }
        Ok(self.forward_unchecked(obs))
    }

    /// [`Encoder::forward`] without the shape check.
    pub(crate) fn forward_unchecked(&self, obs: Tensor<2>) -> Tensor<2> {
        let [batch, _] = obs.dims();
        match self {
            Encoder::State(e) => {
                let k = e.pairwise_objects;
                let limit = e.height_clamp;
                let diffs = (k > 0).then(|| {
                    let p: Tensor<3> = obs.clone().narrow(1, 0, 3 * k).reshape([batch, k, 3]);
                    let diff = p.clone().unsqueeze_dim::<4>(2) - p.unsqueeze_dim::<4>(1);
                    let diff = if limit > 0.0 {
                        clamp_heights(diff, limit)
                    } else {
                        diff
                    };
                    diff.reshape([batch, 3 * k * k])
                });
                let m = e.clamped_objects;
                let obs = if limit > 0.0 && m > 0 {
                    let dim = obs.dims()[1];
                    let p: Tensor<3> = obs.clone().narrow(1, 0, 3 * m).reshape([batch, m, 3]);
                    let p: Tensor<2> = clamp_heights(p, limit).reshape([batch, 3 * m]);
                    if dim > 3 * m {
                        Tensor::cat(vec![p, obs.narrow(1, 3 * m, dim - 3 * m)], 1)
                    } else {
                        p
                    }
                } else {
                    obs
                };
                let x = match diffs {
                    Some(d) => Tensor::cat(vec![obs, d], 1),
                    None => obs,
                };
                let h = e
                    .mid
                    .iter()
                    .fold(relu(e.fc1.forward(x)), |h, layer| relu(layer.forward(h)));
                e.fc2.forward(h)
            }
            Encoder::Frame(e) => {
                let s = e.image_size;
                let obs_device = obs.device();
                let mut x: Tensor<4> = obs.reshape([batch, e.channels, s, s]);
                if e.input_shift != 0.0 {
                    x = x.add_scalar(e.input_shift);
                }
                if e.coords {
                    x = Tensor::cat(vec![x, coordinate_channels(batch, s, &obs_device)], 1);
                }
                let x = match &e.stem {
                    Some(stem) => relu(crate::conv::conv2d(stem, x)),
                    None => x,
                };
                let x = relu(crate::conv::conv2d(&e.conv1, x));
                let x = relu(crate::conv::conv2d(&e.conv2, x));
                let x = relu(crate::conv::conv2d(&e.conv3, x));
                let x: Tensor<2> = if e.keypoints {
                    expected_coordinates(x)
                } else {
                    x.reshape([batch as i32, -1])
                };
                match &e.head {
                    Some(head) => head.forward(relu(e.fc.forward(x))),
                    None => e.fc.forward(x),
                }
            }
            Encoder::Kinematics(e) => {
                let rows: Tensor<3> = obs.reshape([batch, e.window, e.columns]);
                let rows = relu(e.row.forward(rows));
                let flat: Tensor<2> = rows.reshape([batch as i32, -1]);
                e.fc2.forward(relu(e.fc1.forward(flat)))
            }
        }
    }

    /// Encodes a batch of sequences `[B, T, D]` → `[B, T, H]`.
    pub fn forward_sequence(&self, obs: Tensor<3>) -> Result<Tensor<3>> {
        let [batch, steps, dim] = obs.dims();
        if dim != self.input_dim() || batch == 0 || steps == 0 {
            return Err(ModelError::shape(
                "observation sequences",
                format!("[B ≥ 1, T ≥ 1, {}]", self.input_dim()),
                [batch, steps, dim],
            ));
        }
        let flat = self.forward_unchecked(obs.reshape([batch * steps, dim]));
        Ok(flat.reshape([batch, steps, self.out_dim()]))
    }
}

/// `[batch, 2, s, s]`: x then y of each pixel, from −1 to 1.
/// The spatial softmax of feature maps `[B, C, S, S]`: per channel, the
/// expected `x` then `y` (from −1 to 1) under the softmax of its values
/// `x` (last axis `x, y, z`) with its `z` clamped to `[−limit, limit]`
/// ([`StateEncoderConfig::height_clamp`]).
fn clamp_heights<const D: usize>(x: Tensor<D>, limit: f32) -> Tensor<D> {
    let last = D - 1;
    let xy = x.clone().narrow(last, 0, 2);
    let z = x.narrow(last, 2, 1).clamp(-limit, limit);
    Tensor::cat(vec![xy, z], last)
}

/// over the map, `[B, 2C]` (every `x`, then every `y`).
fn expected_coordinates(maps: Tensor<4>) -> Tensor<2> {
    let [batch, channels, s, _] = maps.dims();
    let device = maps.device();
    let p: Tensor<3> = burn::tensor::activation::softmax(maps.reshape([batch, channels, s * s]), 2);
    let grid: Tensor<3> = coordinate_channels(1, s, &device).reshape([1, 2, s * s]);
    let x = p.clone().mul(grid.clone().narrow(1, 0, 1)).sum_dim(2);
    let y = p.mul(grid.narrow(1, 1, 1)).sum_dim(2);
    Tensor::cat(vec![x, y], 1).reshape([batch, 2 * channels])
}

fn coordinate_channels(batch: usize, s: usize, device: &burn::tensor::Device) -> Tensor<4> {
    let at = |i: usize| 2.0 * i as f32 / (s.max(2) - 1) as f32 - 1.0;
    let mut values = Vec::with_capacity(2 * s * s);
    values.extend((0..s * s).map(|k| at(k % s)));
    values.extend((0..s * s).map(|k| at(k / s)));
    Tensor::<4>::from_data(burn::tensor::TensorData::new(values, [1, 2, s, s]), device)
        .repeat_dim(0, batch)
}

#[cfg(test)]
mod tests {
    use super::{Encoder, EncoderConfig, StateEncoderConfig};
    use burn::tensor::{Tensor, TensorData};

    #[test]
    fn height_clamp_reads_heights_up_to_its_limit_only() {
        const D: usize = 9;
        let dev = crate::cpu_device();
        let close =
            |a: &[f32], b: &[f32], tol: f32| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
        // Three objects' positions, pairwise on. Same seed, so the same
        // weights with and without the clamp.
        let plain = StateEncoderConfig::new(D)
            .with_hidden(16)
            .with_out_dim(12)
            .with_pairwise_objects(3);
        let clamped = plain.clone().with_height_clamp(Some(0.3));
        let e = EncoderConfig::State(plain).init(0, &dev).unwrap();
        let c = EncoderConfig::State(clamped.clone()).init(0, &dev).unwrap();
        let enc = |e: &Encoder, r: &[f32]| {
            let rows = Tensor::<2>::from_data(TensorData::new(r.to_vec(), [1, D]), &dev);
            crate::nn::to_vec(e.forward(rows).unwrap()).unwrap()
        };
        // Heights and height differences within the limit: the identity.
        let within = [0.1, 0.2, 0.0, -0.3, 0.1, 0.1, 0.5, -0.4, 0.15];
        assert!(close(&enc(&e, &within), &enc(&c, &within), 1e-6));
        // Within the limit a height still tells scenes apart.
        let lower = [0.1, 0.2, -0.05, -0.3, 0.1, 0.1, 0.5, -0.4, 0.15];
        assert!(!close(&enc(&c, &within), &enc(&c, &lower), 1e-4));
        // Beyond it, heights and their differences read alike.
        let all_far = [0.1, 0.2, -5.0, -0.3, 0.1, 3.0, 0.5, -0.4, -4.0];
        let all_limit = [0.1, 0.2, -5.5, -0.3, 0.1, 3.5, 0.5, -0.4, -4.5];
        assert!(close(&enc(&c, &all_far), &enc(&c, &all_limit), 1e-6));
        assert!(!close(&enc(&e, &all_far), &enc(&e, &all_limit), 1e-4));
        // x and y are never clamped.
        let wide = [5.0, 0.2, 0.0, -0.3, 0.1, 0.1, 0.5, -0.4, 0.15];
        assert!(!close(&enc(&c, &wide), &enc(&c, &within), 1e-4));
        // A limit that is not a positive number, or over more objects than
        // the state holds, is a configuration error.
        for bad in [0.0, -1.0, f32::NAN] {
            let config = clamped.clone().with_height_clamp(Some(bad));
            assert!(EncoderConfig::State(config).init(0, &dev).is_err());
        }
        let config = clamped.with_clamped_objects(Some(4));
        assert!(EncoderConfig::State(config).init(0, &dev).is_err());
    }

    /// A map peaked at one cell gives that cell's coordinates; a flat map
    /// the centre.
    #[test]
    fn spatial_softmax_gives_the_expected_coordinates_of_each_channel() {
        use burn::tensor::{Tensor, TensorData};
        let device = crate::cpu_device();
        let mut values = vec![0.0f32; 2 * 4 * 4];
        values[4 + 3] = 50.0; // channel 0: row 1, column 3
        let maps = Tensor::<4>::from_data(TensorData::new(values, [1, 2, 4, 4]), &device);
        let v = crate::nn::to_vec(super::expected_coordinates(maps)).unwrap();
        // [x₀, x₁, y₀, y₁]
        let expected = [1.0, 0.0, -1.0 / 3.0, 0.0];
        for (got, want) in v.iter().zip(expected) {
            assert!((got - want).abs() < 1e-4, "{v:?}");
        }
    }

    #[test]
    fn coordinate_channels_run_from_minus_one_to_one_along_x_then_y() {
        let device = crate::cpu_device();
        let c = super::coordinate_channels(2, 4, &device);
        assert_eq!(c.dims(), [2, 2, 4, 4]);
        let v = crate::nn::to_vec(c).unwrap();
        let close = |a: [f32; 4]| {
            a.iter()
                .zip([-1.0, -1.0 / 3.0, 1.0 / 3.0, 1.0])
                .all(|(x, y)| (x - y).abs() < 1e-6)
        };
        // Batch item 0: x channel row 0, then y channel column 0.
        assert!(close([v[0], v[1], v[2], v[3]]), "{:?}", &v[..4]);
        assert!(close([v[16], v[20], v[24], v[28]]), "{v:?}");
        // Batch item 1 repeats item 0.
        assert_eq!(&v[..32], &v[32..]);
    }
}
