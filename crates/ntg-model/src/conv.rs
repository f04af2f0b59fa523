//! 2-D convolution as im2col and one matrix product per pass, with its own
//! backward, for burn's `flex` CPU backend.
//!
//! burn 0.22's autodiff differentiates `conv2d` through the backend's
//! default `conv2d_weight_backward`: a convolution of the input by the
//! output gradient, whose "kernel" is the whole output map. On `flex` that
//! is several times slower than the forward pass at the frame encoder's
//! sizes (64 frames, 3→32→64→64 channels, 64→32→16→8 pixels), and it was
//! most of stage A's training step (issue 19). Here every pass is one large
//! matrix product over the unfolded input (`cols`, `[C·k·k, B·L]`, kept
//! from the forward pass for the weight gradient):
//!
//! - forward: `Y = W · cols` (`[C_out, B·L]`), bias added while writing
//!   `[B, C_out, H_out, W_out]`;
//! - weight gradient: `∂W = G · colsᵀ`; bias gradient: row sums of `G`;
//! - input gradient: `∂cols = Wᵀ · G`, folded back onto the input
//!   (col2im, a scatter-add).
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
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, DispatchDevice, Flex, TensorMetadata, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::tensor::{Shape, Tensor, TensorData};
use rayon::prelude::*;

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
    fn positions(&self) -> usize {
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

/// Unfolds `x` (`[B, C, H, W]`, contiguous) into `cols` `[C·k·k, B·L]`:
/// row `(c, ki, kj)`, column `(b, oi, oj)` holds `x[b, c, oi·s+ki−p,
/// oj·s+kj−p]` (0 in the padding).
pub fn im2col(x: &[f32], g: ConvGeometry) -> Vec<f32> {
    let (ho, wo, l) = (g.out_height(), g.out_width(), g.positions());
    let k = g.kernel;
    let mut cols = vec![0.0f32; g.rows() * g.batch * l];
    cols.par_chunks_mut(g.batch * l)
        .enumerate()
        .for_each(|(row, out)| {
            let (c, ki, kj) = (row / (k * k), (row / k) % k, row % k);
            let (lo, hi, first) = g.valid(kj, wo, g.width);
            for b in 0..g.batch {
                let plane = &x[(b * g.channels + c) * g.height * g.width..][..g.height * g.width];
                for oi in 0..ho {
                    let Some(i) = g.source(oi, ki, g.height) else {
                        continue;
                    };
                    let src = &plane[i * g.width + first..];
                    let dst = &mut out[b * l + oi * wo..][lo..hi];
                    if g.stride == 1 {
                        dst.copy_from_slice(&src[..hi - lo]);
                    } else {
                        for (d, s) in dst.iter_mut().zip(src.iter().step_by(g.stride)) {
                            *d = *s;
                        }
                    }
                }
            }
        });
    cols
}

/// The adjoint of [`im2col`]: adds each entry of `cols` `[C·k·k, B·L]`
/// onto the input position it was read from; returns `[B, C, H, W]`.
pub fn col2im(cols: &[f32], g: ConvGeometry) -> Vec<f32> {
    let (ho, wo, l) = (g.out_height(), g.out_width(), g.positions());
    let k = g.kernel;
    let plane_size = g.height * g.width;
    let mut x = vec![0.0f32; g.batch * g.channels * plane_size];
    x.par_chunks_mut(plane_size)
        .enumerate()
        .for_each(|(bc, plane)| {
            let (b, c) = (bc / g.channels, bc % g.channels);
            for ki in 0..k {
                for kj in 0..k {
                    let (lo, hi, first) = g.valid(kj, wo, g.width);
                    let row = (c * k + ki) * k + kj;
                    let src = &cols[row * g.batch * l + b * l..][..l];
                    for oi in 0..ho {
                        let Some(i) = g.source(oi, ki, g.height) else {
                            continue;
                        };
                        let dst = &mut plane[i * g.width + first..];
                        let src = &src[oi * wo..][lo..hi];
                        for (d, s) in dst.iter_mut().step_by(g.stride).zip(src) {
                            *d += s;
                        }
                    }
                }
            }
        });
    x
}

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
        let cols = flex(im2col(&values(&x), g), [rows, g.batch * l]);
        let w = Flex::float_reshape(weight, Shape::new([c_out, rows]));
        let y = Flex::float_matmul(w, cols.clone());
        let (y, bias) = (values(&y), values(&bias));
        // [C_out, B·L] → [B, C_out, L], plus the bias.
        let mut out = vec![0.0f32; g.batch * c_out * l];
        out.par_chunks_mut(l).enumerate().for_each(|(bo, dst)| {
            let (b, o) = (bo / c_out, bo % c_out);
            for (d, s) in dst.iter_mut().zip(&y[o * g.batch * l + b * l..][..l]) {
                *d = s + bias[o];
            }
        });
        (
            flex(out, [g.batch, c_out, g.out_height(), g.out_width()]),
            cols,
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
        // [B, C_out, L] → G = [C_out, B·L].
        let grad = values(&grad);
        let mut g2 = vec![0.0f32; c_out * g.batch * l];
        g2.par_chunks_mut(l).enumerate().for_each(|(ob, dst)| {
            let (o, b) = (ob / g.batch, ob % g.batch);
            dst.copy_from_slice(&grad[(b * c_out + o) * l..][..l]);
        });
        let bias = need_b.then(|| {
            let sums: Vec<f32> = g2.par_chunks(g.batch * l).map(|r| r.iter().sum()).collect();
            flex(sums, [c_out])
        });
        let g2 = flex(g2, [c_out, g.batch * l]);
        let weight_grad = need_w.then(|| {
            let gw = Flex::float_matmul(g2.clone(), Flex::float_transpose(cols));
            Flex::float_reshape(gw, weight_shape.clone())
        });
        let x = need_x.then(|| {
            let w = Flex::float_reshape(weight, Shape::new([c_out, rows]));
            let dcols = Flex::float_matmul(Flex::float_transpose(w), g2);
            flex(
                col2im(&values(&dcols), g),
                [g.batch, g.channels, g.height, g.width],
            )
        });
        [x, weight_grad, bias]
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

    /// The im2col path against burn's conv2d: outputs and the gradients of
    /// input, weight and bias, for the encoder's shapes and a stride-1 and
    /// kernel-4 case.
    #[test]
    fn matches_burn_conv2d_forward_and_backward() {
        let device = burn::tensor::Device::flex().autodiff();
        for (c_in, c_out, side, k, s) in [(3, 8, 16, 3, 2), (8, 6, 8, 3, 1), (4, 5, 12, 4, 2)] {
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
