//! 2-D convolution as im2col and a matrix product per image and pass (or,
//! for inputs of 8+ channels, without unfolding: `conv_phases.rs`), with
//! its own backward, for burn's `flex` CPU backend.
//!
//! burn 0.22's autodiff differentiates `conv2d` through the backend's
//! default `conv2d_weight_backward`: a convolution of the input by the
//! output gradient, whose "kernel" is the whole output map. On `flex` that
//! is several times slower than the forward pass at the frame encoder's
//! sizes (64 frames, 3→32→64→64 channels, 64→32→16→8 pixels), and it was
//! most of stage A's training step (issue 19). Here every pass is one
//! matrix product per image over its unfolded input (`cols_b`, `[C·k·k,
//! L]`, kept from the forward pass for the backward), each written straight
//! into a buffer this module owns (`matmul.rs`):
//!
//! - forward: `Y_b = bias + W · cols_b`, already image `b`'s `[C_out, L]`
//!   slab of the `[B, C_out, H_out, W_out]` output;
//! - weight gradient: `∂W = Σ_b G_b · cols_bᵀ`, summed per fixed group of
//!   images, the groups added in order (deterministic at any thread
//!   count); bias gradient: sums of `G`;
//! - input gradient: `∂cols_b = Wᵀ · G_b` into a per-group scratch buffer,
//!   folded back onto image `b` at once (col2im, a scatter-add) while it
//!   is in cache.
//!
//! No product allocates its output or changes layout between passes: the
//! earlier version (one product over the whole batch through `flex`'s
//! matmul) spent about a fifth of the step allocating, zero-filling,
//! re-aligning and transposing outputs of up to 33 MB.
//!
//! Inputs of 8 or more channels (every encoder layer but the first) take
//! the phase layout of `conv_phases.rs` instead: the same three passes as
//! one product per kernel tap over strided views of the split input, with
//! the split input (not `cols`) kept for the backward pass.
//!
//! [`conv2d`] takes this path on `flex` devices (autodiff or not) and burn's
//! own `conv2d` everywhere else (ndarray, wgpu, cuda), and for dilated or
//! grouped convolutions. The two agree to float rounding (tests below);
//! they are not bit-identical, so a run trained before this module repeats
//! its numbers only to within that rounding.
//!
//! The folding loops are plain Rust over contiguous `f32` storage, split
//! across rayon's pool (the one `flex` computes on).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, DispatchDevice, Flex, TensorMetadata, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::tensor::{Shape, Tensor, TensorData};
use rayon::prelude::*;

use crate::conv_phases::Phases;
use crate::matmul::{Matrix, gemm_into};

/// Sizes of one convolution: input `[batch, channels, height, width]`,
/// square kernel `kernel`, equal stride and padding on both axes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvGeometry {
    /// Batch size `B`.
    pub batch: usize,
    /// Input channels `C`.
    pub channels: usize,
    /// Input height.
    pub height: usize,
    /// Input width.
    pub width: usize,
    /// Kernel side `k`.
    pub kernel: usize,
    /// Stride on both axes.
    pub stride: usize,
    /// Zero padding on every side.
    pub padding: usize,
}

impl ConvGeometry {
    /// Output height.
    pub fn out_height(&self) -> usize {
        (self.height + 2 * self.padding - self.kernel) / self.stride + 1
    }

    /// Output width.
    pub fn out_width(&self) -> usize {
        (self.width + 2 * self.padding - self.kernel) / self.stride + 1
    }

    /// Rows of `cols`: `C·k·k`.
    fn rows(&self) -> usize {
        self.channels * self.kernel * self.kernel
    }

    /// Output positions per image `L`.
    pub(crate) fn positions(&self) -> usize {
        self.out_height() * self.out_width()
    }

    /// For row `(c, ki, kj)` of `cols`, output row `oi` reads input row
    /// `oi·s + ki − p`; `None` where that falls in the padding.
    fn source(&self, out: usize, offset: usize, size: usize) -> Option<usize> {
        (out * self.stride + offset)
            .checked_sub(self.padding)
            .filter(|&i| i < size)
    }

    /// The output columns `lo..hi` whose source column (kernel offset
    /// `offset`) lies inside an input of width `size`, and the source of
    /// `lo`.
    fn valid(&self, offset: usize, outs: usize, size: usize) -> (usize, usize, usize) {
        let lo = (0..outs)
            .find(|&o| self.source(o, offset, size).is_some())
            .unwrap_or(outs);
        let hi = (lo..outs)
            .find(|&o| self.source(o, offset, size).is_none())
            .unwrap_or(outs);
        (
            lo,
            hi,
            (lo * self.stride + offset).saturating_sub(self.padding),
        )
    }
}

/// Unfolds one image `x` (`[C, H, W]`, contiguous) into `cols` (`[C·k·k,
/// L]`, every entry written): row `(c, ki, kj)`, column `(oi, oj)` holds
/// `x[c, oi·s+ki−p, oj·s+kj−p]` (0 in the padding).
pub fn im2col_image(x: &[f32], g: ConvGeometry, cols: &mut [f32]) {
    let (ho, wo, l) = (g.out_height(), g.out_width(), g.positions());
    let (k, step) = (g.kernel, g.stride);
    for (row, out) in cols.chunks_mut(l).enumerate() {
        let (c, ki, kj) = (row / (k * k), (row / k) % k, row % k);
        let (lo, hi, first) = g.valid(kj, wo, g.width);
        let plane = &x[c * g.height * g.width..][..g.height * g.width];
        for (oi, dst) in out.chunks_mut(wo).enumerate().take(ho) {
            let Some(i) = g.source(oi, ki, g.height) else {
                dst.fill(0.0);
                continue;
            };
            dst[..lo].fill(0.0);
            dst[hi..].fill(0.0);
            let (dst, src) = (&mut dst[lo..hi], &plane[i * g.width + first..]);
            if step == 1 {
                dst.copy_from_slice(&src[..dst.len()]);
            } else {
                for (j, d) in dst.iter_mut().enumerate() {
                    *d = src[j * step];
                }
            }
        }
    }
}

/// The adjoint of [`im2col_image`]: adds each entry of `cols` (`[C·k·k,
/// L]`) onto the position of `x` (`[C, H, W]`) it was read from.
pub fn col2im_image(cols: &[f32], g: ConvGeometry, x: &mut [f32]) {
    let (ho, wo, l) = (g.out_height(), g.out_width(), g.positions());
    let (k, step) = (g.kernel, g.stride);
    for (c, plane) in x.chunks_mut(g.height * g.width).enumerate() {
        for ki in 0..k {
            for kj in 0..k {
                let (lo, hi, first) = g.valid(kj, wo, g.width);
                let src = &cols[((c * k + ki) * k + kj) * l..][..l];
                for oi in 0..ho {
                    let Some(i) = g.source(oi, ki, g.height) else {
                        continue;
                    };
                    let dst = &mut plane[i * g.width + first..];
                    for (j, s) in src[oi * wo..][lo..hi].iter().enumerate() {
                        dst[j * step] += s;
                    }
                }
            }
        }
    }
}

/// Unfolds a batch `x` (`[B, C, H, W]`) into `[B, C·k·k, L]`, one
/// [`im2col_image`] per image, the images in parallel.
pub fn im2col(x: &[f32], g: ConvGeometry) -> Vec<f32> {
    let (image, unfolded) = (g.channels * g.height * g.width, g.rows() * g.positions());
    let mut cols = vec![0.0f32; g.batch * unfolded];
    cols.par_chunks_mut(unfolded)
        .zip(x.par_chunks(image))
        .for_each(|(cols, x)| im2col_image(x, g, cols));
    cols
}

/// The adjoint of [`im2col`]: folds `[B, C·k·k, L]` back onto `[B, C, H,
/// W]`, the images in parallel.
pub fn col2im(cols: &[f32], g: ConvGeometry) -> Vec<f32> {
    let (image, unfolded) = (g.channels * g.height * g.width, g.rows() * g.positions());
    let mut x = vec![0.0f32; g.batch * image];
    x.par_chunks_mut(image)
        .zip(cols.par_chunks(unfolded))
        .for_each(|(x, cols)| col2im_image(cols, g, x));
    x
}

/// Whether a convolution runs in the phase layout (`conv_phases.rs`)
/// rather than through im2col: where the input has enough channels for
/// one tap's matrix product (`K = C`) to keep the matrix kernel busy. The
/// frame encoder's first layer (3 colour channels) unfolds.
fn phase_layout(g: ConvGeometry) -> Option<Phases> {
    (g.channels >= 8).then(|| Phases::new(g))
}

/// The backward pass splits the batch into this many groups of
/// consecutive images, whatever the thread count: each group sums its
/// images' weight gradients, and the groups' sums are added in order, so
/// the result does not depend on how rayon schedules the groups.
const GRADIENT_GROUPS: usize = 8;

/// The contiguous `f32` values of a flex tensor.
pub(crate) fn values(t: &FlexTensor) -> std::borrow::Cow<'_, [f32]> {
    match t.as_slice::<f32>() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => {
            std::borrow::Cow::Owned(t.to_contiguous().as_slice::<f32>().unwrap_or(&[]).to_vec())
        }
    }
}

pub(crate) fn flex(values: Vec<f32>, shape: impl Into<Shape>) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape.into()))
}

/// The backend operations behind [`Im2colConv`]'s backward pass.
pub trait Im2colKernels: Backend {
    /// The forward pass: the output `[B, C_out, H_out, W_out]` and `cols`.
    fn im2col_conv_forward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        g: ConvGeometry,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// The gradients of input, weight and bias from the output gradient
    /// `grad`, each only where asked for.
    #[allow(clippy::type_complexity)]
    fn im2col_conv_backward(
        cols: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        g: ConvGeometry,
        need: [bool; 3],
    ) -> [Option<FloatTensor<Self>>; 3];
}

impl Im2colKernels for Flex {
    fn im2col_conv_forward(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        g: ConvGeometry,
    ) -> (FlexTensor, FlexTensor) {
        let c_out = weight.shape()[0];
        let (rows, l) = (g.rows(), g.positions());
        let (w, bias) = (values(&weight), values(&bias));
        if let Some(phases) = phase_layout(g) {
            let (x, image) = (values(&x), g.channels * g.height * g.width);
            let len = phases.image_len();
            // Zero: `split` writes the images, the padding keeps these zeros.
            let mut xq = vec![0.0f32; g.batch * len];
            xq.par_chunks_mut(len)
                .zip(x.par_chunks(image))
                .for_each(|(xq, x)| phases.split(x, xq));
            let mut out = vec![0.0f32; g.batch * c_out * l];
            out.par_chunks_mut(c_out * l)
                .zip(xq.par_chunks(len))
                .for_each_init(
                    || vec![0.0f32; phases.scratch_len(c_out)],
                    |scratch, (out, xq)| phases.forward(&w, &bias, xq, scratch, out),
                );
            return (
                flex(out, [g.batch, c_out, g.out_height(), g.out_width()]),
                flex(xq, [g.batch, len]),
            );
        }
        let cols = im2col(&values(&x), g);
        let w = Matrix::row_major(&w, c_out, rows);
        // Image b's output [C_out, L] = bias + W · cols_b, written in place.
        let mut out = vec![0.0f32; g.batch * c_out * l];
        out.par_chunks_mut(c_out * l)
            .zip(cols.par_chunks(rows * l))
            .for_each(|(out, cols)| {
                for (row, b) in out.chunks_mut(l).zip(bias.iter()) {
                    row.fill(*b);
                }
                gemm_into(out, true, w, Matrix::row_major(cols, rows, l));
            });
        (
            flex(out, [g.batch, c_out, g.out_height(), g.out_width()]),
            flex(cols, [g.batch, rows, l]),
        )
    }

    fn im2col_conv_backward(
        cols: FlexTensor,
        weight: FlexTensor,
        grad: FlexTensor,
        g: ConvGeometry,
        [need_x, need_w, need_b]: [bool; 3],
    ) -> [Option<FlexTensor>; 3] {
        let weight_shape = weight.shape();
        let c_out = weight_shape[0];
        let (rows, l) = (g.rows(), g.positions());
        let image = g.channels * g.height * g.width;
        let (cols, grad, w) = (values(&cols), values(&grad), values(&weight));
        let w_t = Matrix::transposed(&w, rows, c_out);
        let bias = need_b.then(|| {
            let mut sums = vec![0.0f32; c_out];
            for (row, values) in grad.chunks(l).enumerate() {
                sums[row % c_out] += values.iter().sum::<f32>();
            }
            flex(sums, [c_out])
        });
        let per_group = g.batch.div_ceil(GRADIENT_GROUPS).max(1);
        // One group of images from `first`: its summed weight gradient
        // (∂W += G_b · cols_bᵀ) and, into `dx`, its input gradients
        // (∂cols_b = Wᵀ · G_b folded back onto image b).
        let phases = phase_layout(g);
        let group = |first: usize, dx: Option<&mut [f32]>| {
            let images = first..(first + per_group).min(g.batch);
            let mut weight_sum = need_w.then(|| vec![0.0f32; c_out * rows]);
            if let Some(phases) = phases {
                // The same in the phase layout: `cols` holds the images
                // split into phases, the weight sum is tap-major.
                let len = phases.image_len();
                let mut scratch = vec![0.0f32; phases.scratch_len(c_out)];
                let mut dq = dx.is_some().then(|| vec![0.0f32; len]);
                let mut dx = dx;
                for (i, b) in images.enumerate() {
                    let input = match (dq.as_mut(), dx.as_mut()) {
                        (Some(dq), Some(dx)) => {
                            Some((dq.as_mut_slice(), &mut dx[i * image..][..image]))
                        }
                        _ => None,
                    };
                    phases.backward(
                        &w,
                        c_out,
                        &cols[b * len..][..len],
                        &grad[b * c_out * l..][..c_out * l],
                        &mut scratch,
                        weight_sum.as_deref_mut(),
                        input,
                    );
                }
                return weight_sum;
            }
            let mut d_cols = dx.is_some().then(|| vec![0.0f32; rows * l]);
            let mut dx = dx;
            for (i, b) in images.enumerate() {
                let g_b = Matrix::row_major(&grad[b * c_out * l..][..c_out * l], c_out, l);
                let cols_b = &cols[b * rows * l..][..rows * l];
                if let Some(sum) = weight_sum.as_mut() {
                    gemm_into(sum, true, g_b, Matrix::transposed(cols_b, l, rows));
                }
                if let (Some(d_cols), Some(dx)) = (d_cols.as_mut(), dx.as_mut()) {
                    gemm_into(d_cols, false, w_t, g_b);
                    col2im_image(d_cols, g, &mut dx[i * image..][..image]);
                }
            }
            weight_sum
        };
        let mut x_grad = need_x.then(|| vec![0.0f32; g.batch * image]);
        let sums: Vec<Option<Vec<f32>>> = match x_grad.as_mut() {
            Some(dx) => dx
                .par_chunks_mut(per_group * image)
                .enumerate()
                .map(|(i, dx)| group(i * per_group, Some(dx)))
                .collect(),
            None => (0..g.batch.div_ceil(per_group))
                .into_par_iter()
                .map(|i| group(i * per_group, None))
                .collect(),
        };
        let weight_grad = need_w.then(|| {
            let mut total = vec![0.0f32; c_out * rows];
            for sum in sums.into_iter().flatten() {
                for (t, s) in total.iter_mut().zip(sum) {
                    *t += s;
                }
            }
            if let Some(phases) = phases {
                let taps = std::mem::replace(&mut total, vec![0.0f32; c_out * rows]);
                phases.add_taps(&taps, c_out, &mut total);
            }
            flex(total, weight_shape)
        });
        [
            x_grad.map(|dx| flex(dx, [g.batch, g.channels, g.height, g.width])),
            weight_grad,
            bias,
        ]
    }
}

/// A convolution with bias whose backward pass is [`Im2colKernels`]'s.
#[backend_extension(Flex, Autodiff)]
pub trait Im2colConv: Backend {
    /// `conv2d(x, weight, bias)` with equal stride and padding on both axes.
    fn conv2d_im2col(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        padding: usize,
    ) -> FloatTensor<Self>;
}

/// Reads the geometry of a call from its input and weight shapes.
fn geometry(x: &Shape, weight: &Shape, stride: usize, padding: usize) -> ConvGeometry {
    ConvGeometry {
        batch: x[0],
        channels: x[1],
        height: x[2],
        width: x[3],
        kernel: weight[2],
        stride,
        padding,
    }
}

impl Im2colConv for Flex {
    fn conv2d_im2col(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        stride: usize,
        padding: usize,
    ) -> FlexTensor {
        let g = geometry(&x.shape(), &weight.shape(), stride, padding);
        Flex::im2col_conv_forward(x, weight, bias, g).0
    }
}

/// The autodiff node of [`Im2colConv::conv2d_im2col`].
#[derive(Debug)]
struct Im2colConvBackward;

impl<B: Im2colKernels> Backward<B, 3> for Im2colConvBackward {
    /// `cols`, the weight and the geometry.
    type State = (
        B::FloatTensorPrimitive,
        B::FloatTensorPrimitive,
        ConvGeometry,
    );

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_weight, node_bias] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (cols, weight, g) = ops.state;
        let need = [node_x.is_some(), node_weight.is_some(), node_bias.is_some()];
        let [gx, gw, gb] = B::im2col_conv_backward(cols, weight, grad, g, need);
        for (node, grad) in [(node_x, gx), (node_weight, gw), (node_bias, gb)] {
            if let (Some(node), Some(grad)) = (node, grad) {
                grads.register::<B>(node.id, grad);
            }
        }
    }
}

impl<B: Im2colKernels, C: CheckpointStrategy> Im2colConv for Autodiff<B, C> {
    fn conv2d_im2col(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        padding: usize,
    ) -> FloatTensor<Self> {
        let g = geometry(
            &x.primitive().shape(),
            &weight.primitive().shape(),
            stride,
            padding,
        );
        let kind = Im2colConvBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful();
        let w = weight.primitive().clone();
        let (y, cols) = B::im2col_conv_forward(
            x.into_primitive(),
            weight.into_primitive(),
            bias.into_primitive(),
            g,
        );
        match kind {
            OpsKind::Tracked(prep) => prep.finish((cols, w, g), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// Whether `device` computes on `flex` (directly or under autodiff).
pub(crate) fn is_flex(device: &DispatchDevice) -> bool {
    match device {
        DispatchDevice::Flex(_) => true,
        DispatchDevice::Autodiff(inner) => matches!(**inner, DispatchDevice::Flex(_)),
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

/// `conv.forward(x)`, through [`Im2colConv`] on `flex` where the layer
/// allows it (bias, no dilation, one group, equal explicit padding and
/// stride on both axes, square kernel), else through burn's `conv2d`.
pub fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let padding = match conv.padding {
        PaddingConfig2d::Explicit(top, left, bottom, right)
            if top == left && top == bottom && top == right =>
        {
            Some(top)
        }
        _ => None,
    };
    let [k1, k2] = conv.kernel_size;
    let [s1, s2] = conv.stride;
    let plain = conv.dilation == [1, 1] && conv.groups == 1 && k1 == k2 && s1 == s2;
    match (padding, &conv.bias) {
        (Some(p), Some(bias)) if plain && is_flex(x.device().as_dispatch()) => {
            let out = <burn::backend::Dispatch as Im2colConv>::conv2d_im2col(
                x.into_dispatch(),
                conv.weight.val().into_dispatch(),
                bias.val().into_dispatch(),
                s1,
                p,
            );
            Tensor::from_dispatch(out)
        }
        _ => conv.forward(x),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use burn::nn::conv::Conv2dConfig;
    use burn::tensor::Distribution;

    /// The im2col and phase-layout paths against burn's conv2d: outputs and
    /// the gradients of input, weight and bias, for strides 1 and 2,
    /// kernels 3 and 4, even and odd sides, and inputs below and above
    /// the phase layout's channel threshold.
    #[test]
    fn matches_burn_conv2d_forward_and_backward() {
        let device = burn::tensor::Device::flex().autodiff();
        for (c_in, c_out, side, k, s) in [
            (3, 8, 16, 3, 2),
            (4, 5, 12, 4, 2),
            (8, 6, 8, 3, 1),
            (8, 6, 9, 3, 2),
            (10, 4, 12, 4, 2),
            (16, 5, 7, 3, 1),
            (9, 3, 11, 4, 2),
        ] {
            let conv = Conv2dConfig::new([c_in, c_out], [k, k])
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(&device);
            let x: Tensor<4> =
                Tensor::random([3, c_in, side, side], Distribution::Default, &device);
            let probe = Tensor::random(
                conv.forward(x.clone()).dims(),
                Distribution::Default,
                &device,
            );
            let run = |fast: bool| {
                let x = x.clone().detach().require_grad();
                let conv = Conv2d {
                    weight: Param::from_tensor(conv.weight.val().detach()),
                    bias: conv
                        .bias
                        .as_ref()
                        .map(|b| Param::from_tensor(b.val().detach())),
                    ..conv.clone()
                };
                let y = if fast {
                    conv2d(&conv, x.clone())
                } else {
                    conv.forward(x.clone())
                };
                let grads = (y.clone() * probe.clone()).sum().backward();
                let pick = |t: Option<Tensor<4>>| {
                    t.expect("gradient")
                        .into_data()
                        .try_to_vec::<f32>()
                        .unwrap()
                };
                (
                    y.into_data().try_to_vec::<f32>().unwrap(),
                    pick(x.grad(&grads)),
                    pick(conv.weight.val().grad(&grads)),
                    conv.bias
                        .as_ref()
                        .unwrap()
                        .val()
                        .grad(&grads)
                        .unwrap()
                        .into_data()
                        .try_to_vec::<f32>()
                        .unwrap(),
                )
            };
            let (a, b) = (run(true), run(false));
            for (name, fast, reference) in [
                ("y", &a.0, &b.0),
                ("dx", &a.1, &b.1),
                ("dw", &a.2, &b.2),
                ("db", &a.3, &b.3),
            ] {
                assert_eq!(fast.len(), reference.len(), "{name}");
                let scale = reference.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                for (i, (f, r)) in fast.iter().zip(reference).enumerate() {
                    assert!(
                        (f - r).abs() <= 1e-5 * scale,
                        "{name}[{i}] {f} vs {r} (k {k}, s {s})"
                    );
                }
            }
        }
    }

    /// Without autodiff the forward pass takes the same path.
    #[test]
    fn inference_forward_matches() {
        let device = burn::tensor::Device::flex();
        let conv = Conv2dConfig::new([3, 4], [3, 3])
            .with_stride([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init(&device);
        let x: Tensor<4> = Tensor::random([2, 3, 8, 8], Distribution::Default, &device);
        let (a, b) = (conv2d(&conv, x.clone()), conv.forward(x));
        a.into_data()
            .assert_approx_eq::<f32>(&b.into_data(), burn::tensor::Tolerance::absolute(1e-5));
    }

    /// col2im is the adjoint of im2col: <im2col(x), c> = <x, col2im(c)>.
    #[test]
    fn col2im_is_the_adjoint_of_im2col() {
        let g = ConvGeometry {
            batch: 2,
            channels: 3,
            height: 7,
            width: 6,
            kernel: 3,
            stride: 2,
            padding: 1,
        };
        let n = g.batch * g.channels * g.height * g.width;
        let x: Vec<f32> = (0..n).map(|i| ((i * 37) % 11) as f32 - 5.0).collect();
        let cols = im2col(&x, g);
        let c: Vec<f32> = (0..cols.len())
            .map(|i| ((i * 13) % 7) as f32 - 3.0)
            .collect();
        let lhs: f32 = cols.iter().zip(&c).map(|(a, b)| a * b).sum();
        let rhs: f32 = x.iter().zip(col2im(&c, g)).map(|(a, b)| a * b).sum();
        assert_eq!(lhs, rhs);
    }
}
