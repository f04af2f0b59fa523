//! The gates of one GRU step as one fused operation with its own backward,
//! for burn's `flex` CPU backend.
//!
//! A [`GruCell`](crate::nn::GruCell) step is two matrix products (done by
//! burn) and then about a dozen elementwise operations: six narrows of the
//! projections, two adds, a sigmoid, a tanh, products and differences, and
//! the padding mask. Under autodiff each is a node with its own freshly
//! allocated output and gradient, and the backward of every narrow zeroes a
//! full-size gradient and copies its slice in: with `perf`, zeroing and
//! copying were 15% of NTG's state step (issue 19). Here the gates are one
//! loop over `[B, H]` and their backward one more, which writes the
//! gradients of both projections and of the previous state directly.
//!
//! ```text
//! r = σ(x_r + h_r)   z = σ(x_z + h_z)   n = tanh(x_n + r·h_n)
//! next = n + z·(h − n)
//! out  = h + m·(next − h)   (with a mask; next without)
//! ```
//!
//! with `x = [x_r, x_z, x_n]` and `h_proj = [h_r, h_z, h_n]` (`[B, 3H]`), the
//! state `h` and the mask `m` (`[B, 1]`, 1 = real step). The forward pass
//! evaluates the same float operations in the same order as the composite
//! form (with [`crate::activation`]'s `tanh` and `sigmoid`), so the outputs
//! are bit-identical to it; the gradients agree to float rounding (tests).
//! [`gru_gates`] takes this path on `flex` devices and the composite form
//! everywhere else.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Flex, TensorMetadata, backend_extension};
use burn::tensor::{DType, Tensor};
use rayon::prelude::*;

use crate::activation::{sigmoid, sigmoid_f32, tanh, tanh_f32};
use crate::conv::{flex, is_flex, values};

/// Rows of `[B, H]` per rayon task: at least this many elements per task.
const CHUNK: usize = 1 << 14;

/// The gate values of one element, recomputed in the backward pass exactly
/// as in the forward pass.
#[inline(always)]
fn gates(xr: f32, xz: f32, xn: f32, hr: f32, hz: f32, hn: f32) -> (f32, f32, f32) {
    let r = sigmoid_f32(xr + hr);
    let z = sigmoid_f32(xz + hz);
    let n = tanh_f32(xn + r * hn);
    (r, z, n)
}

/// Rows per rayon task for rows of `width` elements.
pub(crate) fn rows_per_task(width: usize) -> usize {
    (CHUNK / width.max(1)).max(1)
}

/// A `[3H]` row as its three gate slices, each exactly `n` long (so that
/// indexing them below `n` needs no bounds check and the loops vectorise).
#[inline(always)]
fn split3(row: &[f32], n: usize) -> (&[f32], &[f32], &[f32]) {
    let (a, rest) = row.split_at(n);
    let (b, c) = rest.split_at(n);
    (&a[..n], &b[..n], &c[..n])
}

/// [`split3`] of a mutable row.
#[inline(always)]
fn split3_mut(row: &mut [f32], n: usize) -> (&mut [f32], &mut [f32], &mut [f32]) {
    let (a, rest) = row.split_at_mut(n);
    let (b, c) = rest.split_at_mut(n);
    (&mut a[..n], &mut b[..n], &mut c[..n])
}

/// One row of the forward loop: `out` `[H]` from `x`, `hp` `[3H]`, `h`
/// `[H]` and the row's mask value.
#[inline(always)]
pub(crate) fn forward_row(x: &[f32], hp: &[f32], h: &[f32], m: Option<f32>, out: &mut [f32]) {
    let n = out.len();
    let ((xr, xz, xn), (hr, hz, hn)) = (split3(x, n), split3(hp, n));
    let (h, out) = (&h[..n], &mut out[..n]);
    for i in 0..n {
        let (_, z, nn) = gates(xr[i], xz[i], xn[i], hr[i], hz[i], hn[i]);
        let next = nn + z * (h[i] - nn);
        out[i] = match m {
            Some(m) => h[i] + m * (next - h[i]),
            None => next,
        };
    }
}

/// The forward loop: `out` `[B, H]` from `x`, `hp` `[B, 3H]`, `h` `[B, H]`,
/// `m` `[B]`.
fn forward_rows(x: &[f32], hp: &[f32], h: &[f32], m: Option<&[f32]>, hidden: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; h.len()];
    let rows = rows_per_task(hidden);
    out.par_chunks_mut(rows * hidden)
        .enumerate()
        .for_each(|(task, out)| {
            for (k, out) in out.chunks_mut(hidden).enumerate() {
                let b = task * rows + k;
                forward_row(
                    &x[b * 3 * hidden..][..3 * hidden],
                    &hp[b * 3 * hidden..][..3 * hidden],
                    &h[b * hidden..][..hidden],
                    m.map(|m| m[b]),
                    out,
                );
            }
        });
    out
}

/// The gradients of one row: of `x`, `hp` (`[3H]`) and `h` (`[H]`) from
/// the output gradient `g` (`[H]`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn backward_row(
    x: &[f32],
    hp: &[f32],
    h: &[f32],
    m: Option<f32>,
    g: &[f32],
    dx: &mut [f32],
    dhp: &mut [f32],
    dh: &mut [f32],
) {
    let n = dh.len();
    let ((xr, xz, xn), (hr, hz, hn)) = (split3(x, n), split3(hp, n));
    let ((dxr, dxz, dxn), (dhr, dhz, dhn)) = (split3_mut(dx, n), split3_mut(dhp, n));
    let (h, g, dh) = (&h[..n], &g[..n], &mut dh[..n]);
    for i in 0..n {
        let (r, z, nn) = gates(xr[i], xz[i], xn[i], hr[i], hz[i], hn[i]);
        let g_next = match m {
            Some(m) => m * g[i],
            None => g[i],
        };
        let dn = g_next * (1.0 - z);
        let dz = g_next * (h[i] - nn);
        let da = dn * (1.0 - nn * nn);
        let dar = (da * hn[i]) * (r * (1.0 - r));
        let daz = dz * (z * (1.0 - z));
        dxr[i] = dar;
        dxz[i] = daz;
        dxn[i] = da;
        dhr[i] = dar;
        dhz[i] = daz;
        dhn[i] = da * r;
        dh[i] = match m {
            Some(m) => (1.0 - m) * g[i] + g_next * z,
            None => g_next * z,
        };
    }
}

/// The backward loop: the gradients of `x`, `hp` (`[B, 3H]`) and `h`
/// (`[B, H]`) from the output gradient `g`.
fn backward_rows(
    x: &[f32],
    hp: &[f32],
    h: &[f32],
    m: Option<&[f32]>,
    g: &[f32],
    hidden: usize,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut dx = vec![0.0f32; x.len()];
    let mut dhp = vec![0.0f32; hp.len()];
    let mut dh = vec![0.0f32; h.len()];
    let rows = rows_per_task(hidden);
    dx.par_chunks_mut(rows * 3 * hidden)
        .zip(dhp.par_chunks_mut(rows * 3 * hidden))
        .zip(dh.par_chunks_mut(rows * hidden))
        .enumerate()
        .for_each(|(task, ((dx, dhp), dh))| {
            let rows = dx
                .chunks_mut(3 * hidden)
                .zip(dhp.chunks_mut(3 * hidden))
                .zip(dh.chunks_mut(hidden));
            for (k, ((dx, dhp), dh)) in rows.enumerate() {
                let b = task * rows_per_task(hidden) + k;
                backward_row(
                    &x[b * 3 * hidden..][..3 * hidden],
                    &hp[b * 3 * hidden..][..3 * hidden],
                    &h[b * hidden..][..hidden],
                    m.map(|m| m[b]),
                    &g[b * hidden..][..hidden],
                    dx,
                    dhp,
                    dh,
                );
            }
        });
    (dx, dhp, dh)
}

/// The backend operations behind [`FusedGru`]'s backward pass.
pub trait GruKernels: Backend {
    /// The gated state `[B, H]`.
    fn gru_gates_forward(
        x: FloatTensor<Self>,
        h_proj: FloatTensor<Self>,
        h: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> FloatTensor<Self>;

    /// The gradients of `x`, `h_proj` and `h`.
    fn gru_gates_backward(
        x: FloatTensor<Self>,
        h_proj: FloatTensor<Self>,
        h: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 3];
}

impl GruKernels for Flex {
    fn gru_gates_forward(
        x: FlexTensor,
        h_proj: FlexTensor,
        h: FlexTensor,
        mask: FlexTensor,
        masked: bool,
    ) -> FlexTensor {
        let shape = h.shape();
        let hidden = shape[1];
        let mask = values(&mask);
        let m = masked.then_some(&mask[..]);
        let out = forward_rows(&values(&x), &values(&h_proj), &values(&h), m, hidden);
        flex(out, shape)
    }

    fn gru_gates_backward(
        x: FlexTensor,
        h_proj: FlexTensor,
        h: FlexTensor,
        mask: FlexTensor,
        masked: bool,
        grad: FlexTensor,
    ) -> [FlexTensor; 3] {
        let (x_shape, h_shape) = (x.shape(), h.shape());
        let mask = values(&mask);
        let (dx, dhp, dh) = backward_rows(
            &values(&x),
            &values(&h_proj),
            &values(&h),
            masked.then_some(&mask[..]),
            &values(&grad),
            h_shape[1],
        );
        [
            flex(dx, x_shape.clone()),
            flex(dhp, x_shape),
            flex(dh, h_shape),
        ]
    }
}

/// The gates of a GRU step, whose backward pass is [`GruKernels`]'s.
#[backend_extension(Flex, Autodiff)]
pub trait FusedGru: Backend {
    /// The next state `[B, H]` from the input and hidden projections
    /// `[B, 3H]`, the state `[B, H]` and the mask `[B, 1]` (read only if
    /// `masked`).
    fn fused_gru_gates(
        x: FloatTensor<Self>,
        h_proj: FloatTensor<Self>,
        h: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> FloatTensor<Self>;
}

impl FusedGru for Flex {
    fn fused_gru_gates(
        x: FlexTensor,
        h_proj: FlexTensor,
        h: FlexTensor,
        mask: FlexTensor,
        masked: bool,
    ) -> FlexTensor {
        Flex::gru_gates_forward(x, h_proj, h, mask, masked)
    }
}

/// The autodiff node of [`FusedGru::fused_gru_gates`].
#[derive(Debug)]
struct GruGatesBackward;

impl<B: GruKernels> Backward<B, 3> for GruGatesBackward {
    /// The inputs, the mask and whether to read it.
    type State = ([B::FloatTensorPrimitive; 4], bool);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_hp, node_h] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let ([x, h_proj, h, mask], masked) = ops.state;
        let [dx, dhp, dh] = B::gru_gates_backward(x, h_proj, h, mask, masked, grad);
        for (node, grad) in [(node_x, dx), (node_hp, dhp), (node_h, dh)] {
            if let Some(node) = node {
                grads.register::<B>(node.id, grad);
            }
        }
    }
}

impl<B: GruKernels, C: CheckpointStrategy> FusedGru for Autodiff<B, C> {
    fn fused_gru_gates(
        x: FloatTensor<Self>,
        h_proj: FloatTensor<Self>,
        h: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> FloatTensor<Self> {
        let kind = GruGatesBackward
            .prepare::<C>([x.node(), h_proj.node(), h.node()])
            .compute_bound()
            .stateful();
        let state = [
            x.primitive().clone(),
            h_proj.primitive().clone(),
            h.primitive().clone(),
            mask.primitive().clone(),
        ];
        let out = B::gru_gates_forward(
            x.into_primitive(),
            h_proj.into_primitive(),
            h.into_primitive(),
            mask.into_primitive(),
            masked,
        );
        match kind {
            OpsKind::Tracked(prep) => prep.finish((state, masked), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// The GRU step's gates (see the module docs): `x_proj` and `h_proj`
/// `[B, 3H]`, the state `h` `[B, H]`, and an optional mask `[B, 1]` (1 =
/// a real step; 0 carries `h` over).
pub fn gru_gates(
    x_proj: Tensor<2>,
    h_proj: Tensor<2>,
    h: Tensor<2>,
    mask: Option<Tensor<2>>,
) -> Tensor<2> {
    if is_flex(x_proj.device().as_dispatch()) && x_proj.dtype() == DType::F32 {
        let masked = mask.is_some();
        // Without a mask the kernel reads none: a one-element stand-in.
        let mask = mask.unwrap_or_else(|| Tensor::zeros([1, 1], &h.device()));
        let out = <burn::backend::Dispatch as FusedGru>::fused_gru_gates(
            x_proj.into_dispatch(),
            h_proj.into_dispatch(),
            h.into_dispatch(),
            mask.into_dispatch(),
            masked,
        );
        return Tensor::from_dispatch(out);
    }
    let next = composite_gates(x_proj, h_proj, h.clone());
    match mask {
        Some(m) => h.clone() + m * (next - h),
        None => next,
    }
}

/// The gates as separate tensor operations (every backend but `flex`).
pub(crate) fn composite_gates(x_proj: Tensor<2>, h_proj: Tensor<2>, h: Tensor<2>) -> Tensor<2> {
    let hd = h.dims()[1];
    let x_rz = x_proj.clone().narrow(1, 0, 2 * hd);
    let h_rz = h_proj.clone().narrow(1, 0, 2 * hd);
    let rz = sigmoid(x_rz + h_rz);
    let r = rz.clone().narrow(1, 0, hd);
    let z = rz.narrow(1, hd, hd);
    let n = tanh(x_proj.narrow(1, 2 * hd, hd) + r * h_proj.narrow(1, 2 * hd, hd));
    // next = n + z ⊙ (h − n)
    n.clone() + z * (h - n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Distribution, TensorData};

    /// The fused gates against the composite form under autodiff: outputs
    /// bit-identical, the gradients of both projections and of the state
    /// within float rounding; with and without a mask, on sizes split
    /// across the pool and not.
    #[test]
    fn matches_the_composite_gates_forward_and_backward() {
        let device = burn::tensor::Device::flex().autodiff();
        for (b, hd, masked) in [
            (3, 5, false),
            (4, 7, true),
            (300, 64, true),
            (64, 128, false),
        ] {
            let normal = Distribution::Normal(0.0, 1.5);
            let x: Tensor<2> = Tensor::random([b, 3 * hd], normal, &device);
            let hp: Tensor<2> = Tensor::random([b, 3 * hd], normal, &device);
            let h: Tensor<2> = Tensor::random([b, hd], normal, &device);
            let probe: Tensor<2> = Tensor::random([b, hd], Distribution::Default, &device);
            let mask = masked.then(|| {
                let m: Vec<f32> = (0..b).map(|i| [1.0, 0.0, 1.0, 0.5][i % 4]).collect();
                Tensor::<2>::from_data(TensorData::new(m, [b, 1]), &device)
            });
            let run = |fused: bool| {
                let (x, hp, h) = (
                    x.clone().detach().require_grad(),
                    hp.clone().detach().require_grad(),
                    h.clone().detach().require_grad(),
                );
                let out = if fused {
                    gru_gates(x.clone(), hp.clone(), h.clone(), mask.clone())
                } else {
                    let next = composite_gates(x.clone(), hp.clone(), h.clone());
                    match mask.clone() {
                        Some(m) => h.clone() + m * (next - h.clone()),
                        None => next,
                    }
                };
                let grads = (out.clone() * probe.clone()).sum().backward();
                let grad = |t: &Tensor<2>| t.grad(&grads).expect("gradient").into_data();
                (out.into_data(), grad(&x), grad(&hp), grad(&h))
            };
            let (fused, composite) = (run(true), run(false));
            assert_eq!(fused.0, composite.0, "outputs (b {b}, h {hd})");
            let tolerance = burn::tensor::Tolerance::absolute(1e-6);
            fused.1.assert_approx_eq::<f32>(&composite.1, tolerance);
            fused.2.assert_approx_eq::<f32>(&composite.2, tolerance);
            fused.3.assert_approx_eq::<f32>(&composite.3, tolerance);
        }
    }
}
