//! Building blocks shared by the four networks: seeded initialisation, a
//! fused GRU cell, and masked losses.
//!
//! burn's own initialisers draw from a process-wide generator, so two
//! models built at the same time on different threads would interfere.
//! Every parameter here is drawn from a ChaCha generator seeded by the
//! caller instead: the same seed gives the same weights, on any thread.

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::nn::{Linear, PaddingConfig2d};
use burn::tensor::activation::log_softmax;

use burn::tensor::{Bool, Device, Int, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::{ModelError, Result};

/// A seeded source of initial weights on one device.
pub(crate) struct Init {
    rng: ChaCha8Rng,
    device: Device,
}

impl Init {
    /// A generator for `seed` that creates parameters on `device`.
    pub(crate) fn new(seed: u64, device: &Device) -> Self {
        Init {
            rng: ChaCha8Rng::seed_from_u64(seed),
            device: device.clone(),
        }
    }

    /// `n` numbers uniform in `[-bound, bound]`.
    fn uniform(&mut self, n: usize, bound: f32) -> Vec<f32> {
        (0..n)
            .map(|_| self.rng.random_range(-1.0f32..=1.0) * bound)
            .collect()
    }

    /// A trainable `[rows, cols]` matrix, uniform in `[-bound, bound]`.
    pub(crate) fn matrix(&mut self, rows: usize, cols: usize, bound: f32) -> Param<Tensor<2>> {
        let values = self.uniform(rows * cols, bound);
        Param::from_data(TensorData::new(values, [rows, cols]), &self.device)
    }

    /// A trainable vector, uniform in `[-bound, bound]`.
    pub(crate) fn vector(&mut self, len: usize, bound: f32) -> Param<Tensor<1>> {
        let values = self.uniform(len, bound);
        Param::from_data(TensorData::new(values, [len]), &self.device)
    }

    /// A dense layer `y = x W + b` with `W: [d_in, d_out]`, both uniform
    /// in `±1/√d_in` (PyTorch's default for `nn.Linear`).
    pub(crate) fn linear(&mut self, d_in: usize, d_out: usize, bias: bool) -> Linear {
        let bound = 1.0 / (d_in.max(1) as f32).sqrt();
        Linear {
            weight: self.matrix(d_in, d_out, bound),
            bias: bias.then(|| self.vector(d_out, bound)),
        }
    }

    /// A square-kernel 2-D convolution: weights uniform in `±1/√(c_in·k²)`
    /// (PyTorch's default for `nn.Conv2d`), or with `he` in
    /// `±√(6/(c_in·k²))` (He initialisation for a ReLU after it: variance
    /// `2/fan_in` keeps activations at one scale through a stack of ReLU
    /// layers, where PyTorch's default shrinks them about 2.4× per layer);
    /// bias uniform in `±1/√(c_in·k²)`.
    pub(crate) fn conv2d(
        &mut self,
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
        he: bool,
    ) -> Conv2d {
        let fan_in = c_in * kernel * kernel;
        let bound = if he {
            (6.0 / fan_in.max(1) as f32).sqrt()
        } else {
            1.0 / (fan_in.max(1) as f32).sqrt()
        };
        let values = self.uniform(c_out * fan_in, bound);
        Conv2d {
            weight: Param::from_data(
                TensorData::new(values, [c_out, c_in, kernel, kernel]),
                &self.device,
            ),
            bias: Some(self.vector(c_out, 1.0 / (fan_in.max(1) as f32).sqrt())),
            stride: [stride, stride],
            kernel_size: [kernel, kernel],
            dilation: [1, 1],
            groups: 1,
            padding: PaddingConfig2d::Explicit(padding, padding, padding, padding),
        }
    }
}

/// A GRU cell with fused gate weights (PyTorch's "reset-after" convention,
/// the same as burn's `Gru`):
///
/// ```text
/// r  = σ(W_ir x + b_ir + W_hr h + b_hr)
/// z  = σ(W_iz x + b_iz + W_hz h + b_hz)
/// n  = tanh(W_in x + b_in + r ⊙ (W_hn h + b_hn))
/// h' = (1 − z) ⊙ n + z ⊙ h
/// ```
///
/// The three input projections are one `[d_in, 3H]` matrix and the three
/// hidden projections one `[H, 3H]` matrix, so a step is two matrix
/// products, and the input projection of a whole sequence is one.
#[derive(Module, Debug)]
pub struct GruCell {
    /// `x ↦ [W_ir x + b_ir, W_iz x + b_iz, W_in x + b_in]`.
    pub input: Linear,
    /// `h ↦ [W_hr h + b_hr, W_hz h + b_hz, W_hn h + b_hn]`.
    pub hidden: Linear,
    /// Hidden size `H`.
    pub d_hidden: usize,
}

impl GruCell {
    pub(crate) fn init(init: &mut Init, d_input: usize, d_hidden: usize) -> Self {
        GruCell {
            input: init.linear(d_input, 3 * d_hidden, true),
            hidden: init.linear(d_hidden, 3 * d_hidden, true),
            d_hidden,
        }
    }

    /// The input projections `[…, 3H]` of inputs `[…, d_in]` (any rank):
    /// compute once per sequence, then feed slices to [`GruCell::step_projected`].
    pub fn project_input<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        self.input.forward(x)
    }

    /// One step from a projected input `[B, 3H]` and state `[B, H]`.
    pub fn step_projected(&self, x_proj: Tensor<2>, h: Tensor<2>) -> Tensor<2> {
        let h_proj = self.hidden.forward(h.clone());
        crate::gru::gru_gates(x_proj, h_proj, h, None)
    }

    /// One step from an input `[B, d_in]` and state `[B, H]`.
    pub fn step(&self, x: Tensor<2>, h: Tensor<2>) -> Tensor<2> {
        self.step_projected(self.project_input(x), h)
    }

    /// Runs over a sequence `[B, T, d_in]` from `h0` (zeros if `None`).
    ///
    /// With a `mask` `[B, T]` (1 = real step, 0 = padding) the state is
    /// carried unchanged through padded steps, so the final state of each
    /// sequence is its state after its last real step. Returns every
    /// step's state `[B, T, H]` and the final state `[B, H]`.
    pub fn forward_sequence(
        &self,
        x: Tensor<3>,
        h0: Option<Tensor<2>>,
        mask: Option<Tensor<2>>,
    ) -> (Tensor<3>, Tensor<2>) {
        let [batch, steps, _] = x.dims();
        let x_proj = self.project_input(x);
        if let (true, Some(bias)) = (
            steps > 0 && crate::gru_sequence::fused_available(&x_proj) && !composed_only(),
            &self.hidden.bias,
        ) {
            let device = x_proj.device();
            let h0 = h0.unwrap_or_else(|| Tensor::zeros([batch, self.d_hidden], &device));
            let states = crate::gru_sequence::gru_sequence(
                x_proj,
                h0,
                self.hidden.weight.val(),
                bias.val(),
                mask,
            );
            // Both outputs are cut from the sequence's output, so that the
            // gradients of all the states' uses are summed before the final
            // state's is added to them, as burn sums them for composed
            // steps (where the states' uses meet in their stack): the same
            // float sums, the same bits.
            let last = states
                .clone()
                .narrow(1, steps - 1, 1)
                .reshape([batch, self.d_hidden]);
            return (states.narrow(1, 0, steps), last);
        }
        self.forward_sequence_composed(x_proj, h0, mask)
    }

    /// [`GruCell::forward_sequence`] from the input projections `[B, T, 3H]`
    /// as a loop of steps, each a node of its own under autodiff: what
    /// backends without the fused sequence run (and the reference the
    /// fused one is tested against).
    pub(crate) fn forward_sequence_composed(
        &self,
        x_proj: Tensor<3>,
        h0: Option<Tensor<2>>,
        mask: Option<Tensor<2>>,
    ) -> (Tensor<3>, Tensor<2>) {
        let [batch, steps, _] = x_proj.dims();
        let device = x_proj.device();
        let mut h = h0.unwrap_or_else(|| Tensor::zeros([batch, self.d_hidden], &device));
        let projected = unstack_steps(x_proj);
        let mut outputs = Vec::with_capacity(steps);
        for (t, xt) in projected.into_iter().enumerate() {
            let h_proj = self.hidden.forward(h.clone());
            // Padded steps (mask 0) carry the state over.
            let m = mask.as_ref().map(|mask| mask.clone().narrow(1, t, 1)); // [B, 1]
            h = crate::gru::gru_gates(xt, h_proj, h, m);
            outputs.push(h.clone());
        }
        if outputs.is_empty() {
            return (Tensor::zeros([batch, 0, self.d_hidden], &device), h);
        }
        (Tensor::stack(outputs, 1), h)
    }
}

#[cfg(test)]
thread_local! {
    /// Set by tests to run [`GruCell::forward_sequence`] as composed steps
    /// on this thread (to compare whole models against the fused sequence).
    pub(crate) static COMPOSED_GRU_ONLY: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether this thread runs GRU sequences as composed steps (tests only).
fn composed_only() -> bool {
    #[cfg(test)]
    return COMPOSED_GRU_ONLY.with(|c| c.get());
    #[cfg(not(test))]
    false
}

/// The steps of a sequence `x` `[B, T, D]` as `T` tensors `[B, D]`, in
/// order, cut out by halving `x` recursively.
///
/// Under autodiff the backward of a narrow builds a gradient of its input's
/// full size (zeroed, its slice copied in) that is then added to the
/// input's gradient, so narrowing each of `T` steps out of `x` directly
/// moves `T` full-size tensors: quadratic in `T`, most of the interpreter's
/// step on 60-frame demo videos (`perf`: memmove, memset and adds were 35%
/// of a paper-recipe stage B step). Halving moves `x`'s size once per
/// level, `log₂ T` times. Each step's values are the same as a direct
/// narrow's, and so are the gradients (every element of `x`'s gradient
/// still comes from the one step it belongs to, plus zeros).
pub fn unstack_steps(x: Tensor<3>) -> Vec<Tensor<2>> {
    fn halve(x: Tensor<3>, out: &mut Vec<Tensor<2>>) {
        let [batch, steps, dim] = x.dims();
        match steps {
            0 => {}
            1 => out.push(x.reshape([batch, dim])),
            _ => {
                let half = steps / 2;
                halve(x.clone().narrow(1, 0, half), out);
                halve(x.narrow(1, half, steps - half), out);
            }
        }
    }
    let mut out = Vec::with_capacity(x.dims()[1]);
    halve(x, &mut out);
    out
}

/// Masked mean cross-entropy: `−Σ_m w_m log softmax(logits_m)[target_m] / Σ_m w_m`.
///
/// `logits` `[M, C]`, `targets` `[M]` (class ids), `weights` `[M]` (1 for a
/// counted row, 0 for padding). Returns a one-element tensor.
pub(crate) fn masked_cross_entropy(
    logits: Tensor<2>,
    targets: Tensor<1, Int>,
    weights: Tensor<1>,
) -> Tensor<1> {
    let [m, _] = logits.dims();
    let logp = log_softmax(logits, 1);
    let picked = logp.gather(1, targets.reshape([m, 1])).reshape([m]);
    let total = weights.clone().sum().clamp_min(1.0);
    (picked * weights).sum().neg() / total
}

/// Masked accuracy of arg-max predictions: `Σ_m w_m [argmax = target] / Σ_m w_m`.
pub(crate) fn masked_accuracy(
    logits: Tensor<2>,
    targets: Tensor<1, Int>,
    weights: Tensor<1>,
) -> Result<f32> {
    let [m, _] = logits.dims();
    let predicted = logits.detach().argmax(1).reshape([m]);
    let weights = weights.detach();
    let correct = predicted.equal(targets).float() * weights.clone();
    let total = scalar(weights.sum())?;
    if total <= 0.0 {
        return Ok(0.0);
    }
    Ok(scalar(correct.sum())? / total)
}

/// Fills the logits where `allowed` is false with a large negative number,
/// so that softmax gives them (numerically) zero probability.
pub(crate) fn mask_logits<const D: usize>(
    logits: Tensor<D>,
    allowed: Tensor<D, Bool>,
) -> Tensor<D> {
    logits.mask_fill(allowed.bool_not(), MASKED_LOGIT)
}

/// The logit given to masked-out entries.
pub const MASKED_LOGIT: f32 = -1.0e9;

/// Reads a one-element tensor.
pub(crate) fn scalar(t: Tensor<1>) -> Result<f32> {
    let values = to_vec(t)?;
    values
        .first()
        .copied()
        .ok_or_else(|| ModelError::Data("empty tensor".into()))
}

/// Reads a float tensor as a flat `Vec<f32>` (row-major).
pub fn to_vec<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .try_into_vec_as::<f32>()
        .map_err(|e| ModelError::Data(format!("{e:?}")))
}

/// Reads an int tensor as a flat `Vec<i64>` (row-major).
pub fn to_vec_int<const D: usize>(t: Tensor<D, Int>) -> Result<Vec<i64>> {
    t.into_data()
        .try_into_vec_as::<i64>()
        .map_err(|e| ModelError::Data(format!("{e:?}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// Halving gives each step of the sequence, in order, with the values
    /// and the gradient of narrowing each step out directly; for lengths
    /// that are and are not powers of two, and the empty sequence.
    #[test]
    fn unstack_steps_matches_narrowing_each_step() {
        let device = Device::flex().autodiff();
        for steps in [0, 1, 2, 5, 8, 63] {
            let x: Tensor<3> = Tensor::random([3, steps, 4], Distribution::Default, &device);
            let weights: Tensor<2> = Tensor::random([3, 4], Distribution::Default, &device);
            let run = |halved: bool| {
                let x = x.clone().detach().require_grad();
                let parts = if halved {
                    unstack_steps(x.clone())
                } else {
                    (0..steps)
                        .map(|t| x.clone().narrow(1, t, 1).reshape([3, 4]))
                        .collect()
                };
                let values: Vec<TensorData> = parts.iter().map(|p| p.clone().into_data()).collect();
                // Each step weighted differently, so a step out of place shows.
                let loss = parts
                    .into_iter()
                    .enumerate()
                    .map(|(t, p)| (p * weights.clone()).sum() * (t as f32 + 1.0))
                    .fold(x.clone().sum() * 0.0, |a, b| a + b);
                let grads = loss.backward();
                (values, x.grad(&grads).map(|g| g.into_data()))
            };
            let (halved, direct) = (run(true), run(false));
            assert_eq!(halved.0.len(), steps);
            assert_eq!(halved.0, direct.0, "values, {steps} steps");
            assert_eq!(halved.1, direct.1, "gradient, {steps} steps");
        }
    }
}
