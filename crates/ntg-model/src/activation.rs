//! `tanh` and `sigmoid` computed in vectorised loops, with their own
//! backward, for burn's `flex` CPU backend.
//!
//! `flex` computes both activations one element at a time through libm
//! (`tanhf`, which calls `expm1f`, and `expf`): 16% of NTG's state-input
//! training step (`perf`, issue 19), for the GRU gates of the demo
//! interpreter and the GCN, the interpreter's annotations and attention, and
//! the GCN's edge probabilities. Here both are one branch-free loop over the
//! tensor that the compiler vectorises:
//!
//! - `exp(x)` by Cody–Waite reduction, `x = n·ln 2 + r` with `|r| ≤ ln2/2`,
//!   a degree-7 Taylor polynomial for `e^r` (truncation below 3e-9) and `2^n`
//!   built from its exponent bits; inputs are clamped to `[-87.3, 88.3]`, so
//!   the result is never infinite or subnormal;
//! - `sigmoid(x) = 1 / (1 + exp(−x))`;
//! - `tanh(x) = 1 − 2 / (exp(2x) + 1)`, and for `|x| < 0.125` its odd
//!   Taylor polynomial to `x⁹` (where the formula would lose digits).
//!
//! Both stay within a few float ulps of libm (abs. 3e-7, tests below). The
//! backward pass reads the output: `∂tanh = 1 − y²`, `∂σ = y (1 − y)`, one
//! fused loop each. No fused multiply-add is used, so the results do not
//! depend on the CPU's features.
//!
//! [`tanh`] and [`sigmoid`] take this path on `flex` devices (autodiff or
//! not) and burn's own activations everywhere else. The two agree to float
//! rounding, not bit for bit: a run trained before this module repeats its
//! numbers only to within that rounding.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Flex, TensorMetadata, backend_extension};
use burn::tensor::{DType, Tensor};
use rayon::prelude::*;

use crate::conv::{flex, is_flex, values};

/// Elements per rayon task: smaller tensors are computed on the caller's
/// thread.
const CHUNK: usize = 1 << 15;

/// `e^x` for `x` clamped to `[-87.3, 88.3]`, branch-free.
#[inline(always)]
fn exp_clamped(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 split so that n · LN2_HI is exact for |n| < 2^11.
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5 · 2^23: adding it rounds to an integer, kept in the low mantissa
    // bits.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.3, 88.3);
    let shifted = x * LOG2E + ROUND;
    let n = shifted - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0
                        + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // 2^n: n sits in the low bits of `shifted` (offset by ROUND's bits).
    let exponent = shifted
        .to_bits()
        .wrapping_sub(ROUND.to_bits())
        .wrapping_add(127)
        << 23;
    p * f32::from_bits(exponent)
}

/// `tanh(x)`, branch-free (both forms are computed, one is kept).
#[inline(always)]
pub fn tanh_f32(x: f32) -> f32 {
    let x2 = x * x;
    // tanh x = x − x³/3 + 2x⁵/15 − 17x⁷/315 + 62x⁹/2835 − …
    let small = x
        * (1.0
            + x2 * (-1.0 / 3.0 + x2 * (2.0 / 15.0 + x2 * (-17.0 / 315.0 + x2 * (62.0 / 2835.0)))));
    let large = 1.0 - 2.0 / (exp_clamped(2.0 * x) + 1.0);
    if x.abs() < 0.125 { small } else { large }
}

/// `1 / (1 + e^(−x))`, branch-free.
#[inline(always)]
pub fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + exp_clamped(-x))
}

/// `out[i] = f(src[i])`, split across rayon's pool for large tensors.
fn map_into(src: &[f32], out: &mut [f32], f: impl Fn(f32) -> f32 + Sync) {
    let run = |(s, o): (&[f32], &mut [f32])| {
        for (o, &x) in o.iter_mut().zip(s) {
            *o = f(x);
        }
    };
    if src.len() <= CHUNK {
        run((src, out));
    } else {
        src.par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(run);
    }
}

/// `out[i] = f(a[i], b[i])`, split across rayon's pool for large tensors.
fn zip_into(a: &[f32], b: &[f32], out: &mut [f32], f: impl Fn(f32, f32) -> f32 + Sync) {
    let run = |((a, b), o): ((&[f32], &[f32]), &mut [f32])| {
        for ((o, &a), &b) in o.iter_mut().zip(a).zip(b) {
            *o = f(a, b);
        }
    };
    if a.len() <= CHUNK {
        run(((a, b), out));
    } else {
        a.par_chunks(CHUNK)
            .zip(b.par_chunks(CHUNK))
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(run);
    }
}

/// Which activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `tanh`.
    Tanh,
    /// The logistic sigmoid.
    Sigmoid,
}

impl Activation {
    fn forward(self, src: &[f32], out: &mut [f32]) {
        match self {
            Activation::Tanh => map_into(src, out, tanh_f32),
            Activation::Sigmoid => map_into(src, out, sigmoid_f32),
        }
    }

    /// `grad · f'(x)` from the output `y = f(x)`.
    fn backward(self, y: &[f32], grad: &[f32], out: &mut [f32]) {
        match self {
            Activation::Tanh => zip_into(y, grad, out, |y, g| g * (1.0 - y * y)),
            Activation::Sigmoid => zip_into(y, grad, out, |y, g| g * (y * (1.0 - y))),
        }
    }
}

/// The backend operations behind [`VectorActivation`]'s backward pass.
pub trait ActivationKernels: Backend {
    /// `f(x)` elementwise.
    fn activation_forward(x: FloatTensor<Self>, f: Activation) -> FloatTensor<Self>;
    /// `grad · f'(x)` from the output `y = f(x)`.
    fn activation_backward(
        y: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        f: Activation,
    ) -> FloatTensor<Self>;
}

impl ActivationKernels for Flex {
    fn activation_forward(x: FlexTensor, f: Activation) -> FlexTensor {
        let src = values(&x);
        let mut out = vec![0.0f32; src.len()];
        f.forward(&src, &mut out);
        flex(out, x.shape())
    }

    fn activation_backward(y: FlexTensor, grad: FlexTensor, f: Activation) -> FlexTensor {
        let (ys, gs) = (values(&y), values(&grad));
        let mut out = vec![0.0f32; gs.len()];
        f.backward(&ys, &gs, &mut out);
        flex(out, grad.shape())
    }
}

/// An elementwise activation whose backward pass is
/// [`ActivationKernels`]'s.
#[backend_extension(Flex, Autodiff)]
pub trait VectorActivation: Backend {
    /// `f(x)` elementwise.
    fn vector_activation(x: FloatTensor<Self>, f: Activation) -> FloatTensor<Self>;
}

impl VectorActivation for Flex {
    fn vector_activation(x: FlexTensor, f: Activation) -> FlexTensor {
        Flex::activation_forward(x, f)
    }
}

/// The autodiff node of [`VectorActivation::vector_activation`].
#[derive(Debug)]
struct ActivationBackward;

impl<B: ActivationKernels> Backward<B, 1> for ActivationBackward {
    /// The output and the activation.
    type State = (B::FloatTensorPrimitive, Activation);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (y, f) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::activation_backward(y, grad, f));
        }
    }
}

impl<B: ActivationKernels, C: CheckpointStrategy> VectorActivation for Autodiff<B, C> {
    fn vector_activation(x: FloatTensor<Self>, f: Activation) -> FloatTensor<Self> {
        let kind = ActivationBackward
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful();
        let y = B::activation_forward(x.into_primitive(), f);
        match kind {
            OpsKind::Tracked(prep) => prep.finish((y.clone(), f), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

fn apply<const D: usize>(x: Tensor<D>, f: Activation) -> Tensor<D> {
    if is_flex(x.device().as_dispatch()) && x.dtype() == DType::F32 {
        let out =
            <burn::backend::Dispatch as VectorActivation>::vector_activation(x.into_dispatch(), f);
        Tensor::from_dispatch(out)
    } else {
        match f {
            Activation::Tanh => burn::tensor::activation::tanh(x),
            Activation::Sigmoid => burn::tensor::activation::sigmoid(x),
        }
    }
}

/// `tanh(x)`: vectorised on `flex`, burn's elsewhere.
pub fn tanh<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    apply(x, Activation::Tanh)
}

/// The logistic sigmoid: vectorised on `flex`, burn's elsewhere.
pub fn sigmoid<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    apply(x, Activation::Sigmoid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// Every float in a sweep (and the extremes) against libm.
    #[test]
    fn scalar_forms_match_libm() {
        let mut xs: Vec<f32> = (-200_000..=200_000).map(|i| i as f32 * 1e-4).collect();
        xs.extend([
            -1e30, -1000.0, -100.0, -88.5, -87.0, -44.0, -9.0, 9.0, 44.0, 87.0, 88.5, 100.0,
            1000.0, 1e30, 1e-30, -1e-30, 0.0, -0.0, 0.124_999, 0.125, 0.125_001,
        ]);
        for &x in &xs {
            let (t, s) = (tanh_f32(x), sigmoid_f32(x));
            let (rt, rs) = (x.tanh(), 1.0 / (1.0 + (-(x as f64)).exp()) as f32);
            assert!(
                (t - rt).abs() <= 3e-7 + 2e-6 * rt.abs(),
                "tanh({x}) = {t}, libm {rt}"
            );
            assert!(
                (s - rs).abs() <= 3e-7 * rs.max(1e-30) + 1e-37,
                "sigmoid({x}) = {s}, {rs}"
            );
            assert!((-1.0..=1.0).contains(&t) && (0.0..=1.0).contains(&s), "{x}");
        }
        assert!(tanh_f32(f32::NAN).is_nan() && sigmoid_f32(f32::NAN).is_nan());
        assert_eq!(tanh_f32(0.0), 0.0);
        assert_eq!(sigmoid_f32(0.0), 0.5);
    }

    /// Outputs and input gradients against burn's activations, under
    /// autodiff, on a non-contiguous input and one large enough to be split
    /// across the pool.
    #[test]
    fn matches_burn_forward_and_backward() {
        let device = burn::tensor::Device::flex().autodiff();
        for dims in [[7, 13], [300, 257]] {
            let x: Tensor<2> = Tensor::random(dims, Distribution::Normal(0.0, 3.0), &device);
            let probe: Tensor<2> = Tensor::random(dims, Distribution::Default, &device);
            for f in [Activation::Tanh, Activation::Sigmoid] {
                let run = |fast: bool| {
                    let x = x.clone().detach().require_grad();
                    // A transposed view: the kernels must read it in order.
                    let xt = x.clone().transpose();
                    let y = match (fast, f) {
                        (true, Activation::Tanh) => tanh(xt),
                        (true, Activation::Sigmoid) => sigmoid(xt),
                        (false, Activation::Tanh) => burn::tensor::activation::tanh(xt),
                        (false, Activation::Sigmoid) => burn::tensor::activation::sigmoid(xt),
                    };
                    let grads = (y.clone() * probe.clone().transpose()).sum().backward();
                    let grad = x.grad(&grads).expect("gradient");
                    (y.into_data(), grad.into_data())
                };
                let ((y, g), (ry, rg)) = (run(true), run(false));
                let tolerance = burn::tensor::Tolerance::absolute(1e-6);
                y.assert_approx_eq::<f32>(&ry, tolerance);
                g.assert_approx_eq::<f32>(&rg, tolerance);
            }
        }
    }

    /// Without autodiff the forward pass takes the same path.
    #[test]
    fn inference_forward_matches() {
        let device = burn::tensor::Device::flex();
        let x: Tensor<3> = Tensor::random([2, 3, 5], Distribution::Normal(0.0, 2.0), &device);
        let tolerance = burn::tensor::Tolerance::absolute(1e-6);
        tanh(x.clone()).into_data().assert_approx_eq::<f32>(
            &burn::tensor::activation::tanh(x.clone()).into_data(),
            tolerance,
        );
        sigmoid(x.clone())
            .into_data()
            .assert_approx_eq::<f32>(&burn::tensor::activation::sigmoid(x).into_data(), tolerance);
    }
}
