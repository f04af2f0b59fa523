//! A whole GRU sequence as one fused operation with its own backward pass
//! (backpropagation through time in one loop), for burn's `flex` CPU
//! backend.
//!
//! [`GruCell::forward_sequence`](crate::nn::GruCell::forward_sequence)
//! composed per step: the step's input projection cut out of the whole
//! sequence's (`nn::unstack_steps`), the hidden projection, the fused gates
//! of [`crate::gru`], and a stack of the states. Under autodiff the cuts
//! alone cost a full-size zeroed gradient and a copy per level of halving
//! (`perf`: 12.5% of a paper-recipe video stage-B epoch, most of the
//! memmove and memset), and every step adds nodes. Here the sequence is one
//! node: the forward loop writes every state into one `[B, T, H]` buffer,
//! and the backward loop reads the step inputs and writes their gradients
//! in place in one `[B, T, 3H]` buffer.
//!
//! The result is **bit-identical** to the composed form, values and
//! gradients (tests): the hidden projection and its three gradients are
//! burn's own `linear` kernels called the way burn's autodiff calls them,
//! the gates are [`crate::gru`]'s row kernels, and every gradient that
//! burn accumulates over steps is summed in burn's order: the hidden
//! weights' and biases' from the last step to the first (`new + sum`), a
//! state's as `(gates + projection) + later use`.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::{FloatTensorOps, ModuleOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Flex, TensorMetadata, backend_extension};
use burn::tensor::{DType, Tensor};
use rayon::prelude::*;

use crate::conv::{flex, is_flex, values};
use crate::gru::{backward_row, forward_row, rows_per_task};

/// Sizes of one sequence: batch `B`, steps `T`, hidden size `H`.
#[derive(Clone, Copy, Debug)]
struct Dims {
    batch: usize,
    steps: usize,
    hidden: usize,
}

impl Dims {
    /// Offset of row `b`'s step `t` in a `[B, T, width]` buffer.
    fn at(self, b: usize, t: usize, width: usize) -> usize {
        (b * self.steps + t) * width
    }
}

/// The forward loop of one step `t`: the next state `[B, H]` from the
/// sequence's input projections `x` `[B, T, 3H]`, the step's hidden
/// projection `hp` `[B, 3H]`, the state `h` `[B, H]` and the mask `[B, T]`.
fn forward_step(
    d: Dims,
    t: usize,
    x: &[f32],
    hp: &[f32],
    h: &[f32],
    mask: Option<&[f32]>,
) -> Vec<f32> {
    let hd = d.hidden;
    let mut out = vec![0.0f32; d.batch * hd];
    let rows = rows_per_task(hd);
    out.par_chunks_mut(rows * hd)
        .enumerate()
        .for_each(|(task, out)| {
            for (k, out) in out.chunks_mut(hd).enumerate() {
                let b = task * rows + k;
                forward_row(
                    &x[d.at(b, t, 3 * hd)..][..3 * hd],
                    &hp[b * 3 * hd..][..3 * hd],
                    &h[b * hd..][..hd],
                    mask.map(|m| m[b * d.steps + t]),
                    out,
                );
            }
        });
    out
}

/// The backward loop of one step `t`, from the gradient `g` `[B, H]` of
/// the step's output state: writes the step's input-projection gradient
/// into `dx` `[B, T, 3H]` and returns the gradients of the hidden
/// projection `[B, 3H]` and, through the gates, of the previous state
/// `[B, H]`.
#[allow(clippy::too_many_arguments)]
fn backward_step(
    d: Dims,
    t: usize,
    x: &[f32],
    hp: &[f32],
    h: &[f32],
    mask: Option<&[f32]>,
    g: &[f32],
    dx: &mut [f32],
) -> (Vec<f32>, Vec<f32>) {
    let hd = d.hidden;
    let mut dhp = vec![0.0f32; d.batch * 3 * hd];
    let mut dh = vec![0.0f32; d.batch * hd];
    let rows = rows_per_task(hd);
    dx.par_chunks_mut(rows * d.steps * 3 * hd)
        .zip(dhp.par_chunks_mut(rows * 3 * hd))
        .zip(dh.par_chunks_mut(rows * hd))
        .enumerate()
        .for_each(|(task, ((dx, dhp), dh))| {
            let per_row = dx
                .chunks_mut(d.steps * 3 * hd)
                .zip(dhp.chunks_mut(3 * hd))
                .zip(dh.chunks_mut(hd));
            for (k, ((dx, dhp), dh)) in per_row.enumerate() {
                let b = task * rows + k;
                backward_row(
                    &x[d.at(b, t, 3 * hd)..][..3 * hd],
                    &hp[b * 3 * hd..][..3 * hd],
                    &h[b * hd..][..hd],
                    mask.map(|m| m[b * d.steps + t]),
                    &g[b * hd..][..hd],
                    &mut dx[t * 3 * hd..][..3 * hd],
                    dhp,
                    dh,
                );
            }
        });
    (dhp, dh)
}

/// `a + b`, elementwise, as burn's `float_add` of the two.
fn add(a: &[f32], b: &[f32]) -> Vec<f32> {
    a.iter().zip(b).map(|(a, b)| a + b).collect()
}

/// What the backward pass needs of the forward pass.
#[derive(Clone, Debug)]
pub struct SequenceSaved<T> {
    /// The states before each step: `h0` and the first `T − 1` outputs,
    /// each `[B, H]`.
    states: Vec<T>,
    /// The hidden projection of each step, `[B, 3H]`.
    projections: Vec<T>,
}

/// The backend operations behind [`FusedGruSequence`]'s backward pass.
pub trait GruSequenceKernels: Backend {
    /// The states `[B, T, H]` and what the backward pass reads.
    fn gru_sequence_forward(
        x_proj: FloatTensor<Self>,
        h0: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> (FloatTensor<Self>, SequenceSaved<FloatTensor<Self>>);

    /// The gradients of `x_proj`, `h0`, `weight` and `bias` from the
    /// states' gradient `grad` `[B, T, H]`.
    fn gru_sequence_backward(
        x_proj: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
        saved: SequenceSaved<FloatTensor<Self>>,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 4];
}

impl GruSequenceKernels for Flex {
    fn gru_sequence_forward(
        x_proj: FlexTensor,
        h0: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        mask: FlexTensor,
        masked: bool,
    ) -> (FlexTensor, SequenceSaved<FlexTensor>) {
        let [batch, steps, _] = x_proj.shape().dims();
        let hidden = h0.shape()[1];
        let d = Dims {
            batch,
            steps,
            hidden,
        };
        let (x, mask) = (values(&x_proj), values(&mask));
        let mask = masked.then_some(&mask[..]);
        let mut out = vec![0.0f32; batch * steps * hidden];
        let mut saved = SequenceSaved {
            states: Vec::with_capacity(steps),
            projections: Vec::with_capacity(steps),
        };
        let mut h = h0;
        for t in 0..steps {
            let hp = Flex::linear(h.clone(), weight.clone(), Some(bias.clone()));
            let next = forward_step(d, t, &x, &values(&hp), &values(&h), mask);
            for (b, row) in next.chunks(hidden).enumerate() {
                out[d.at(b, t, hidden)..][..hidden].copy_from_slice(row);
            }
            saved.states.push(h);
            saved.projections.push(hp);
            h = flex(next, [batch, hidden]);
        }
        (flex(out, [batch, steps, hidden]), saved)
    }

    fn gru_sequence_backward(
        x_proj: FlexTensor,
        weight: FlexTensor,
        mask: FlexTensor,
        masked: bool,
        saved: SequenceSaved<FlexTensor>,
        grad: FlexTensor,
    ) -> [FlexTensor; 4] {
        let x_shape = x_proj.shape();
        let [batch, steps, _] = x_shape.dims();
        let hidden = weight.shape()[0];
        let d = Dims {
            batch,
            steps,
            hidden,
        };
        let (x, mask, grad) = (values(&x_proj), values(&mask), values(&grad));
        let mask = masked.then_some(&mask[..]);
        let mut dx = vec![0.0f32; x.len()];
        // The gradient reaching the state after step `t` from step `t + 1`
        // (through its gates and its hidden projection).
        let mut carried: Option<Vec<f32>> = None;
        // Each step's hidden-projection gradient `[B, 3H]`, last step first.
        let mut projection_grads = Vec::with_capacity(steps);
        // The weights' gradient, summed from the last step to the first as
        // burn does (each step's product node is deeper than the one before).
        let mut d_weight: Option<FlexTensor> = None;
        for t in (0..steps).rev() {
            let mut g = vec![0.0f32; batch * hidden];
            for (b, row) in g.chunks_mut(hidden).enumerate() {
                let from_output = &grad[d.at(b, t, hidden)..][..hidden];
                match &carried {
                    Some(c) => {
                        let c = &c[b * hidden..][..hidden];
                        for ((g, o), c) in row.iter_mut().zip(from_output).zip(c) {
                            *g = o + c;
                        }
                    }
                    None => row.copy_from_slice(from_output),
                }
            }
            let (h, hp) = (&saved.states[t], &saved.projections[t]);
            let (dhp, dh) = backward_step(d, t, &x, &values(hp), &values(h), mask, &g, &mut dx);
            let dhp = flex(dhp, [batch, 3 * hidden]);
            // burn's linear backward, registered in its order: the state's
            // gradient first (after the gates'), then the weight's, the bias'.
            let through_projection = Flex::linear_x_backward(weight.clone(), dhp.clone());
            carried = Some(add(&values(&through_projection), &dh));
            let dw = Flex::linear_weight_backward(h.clone(), dhp.clone());
            d_weight = Some(match d_weight {
                Some(sum) => Flex::float_add(dw, sum),
                None => dw,
            });
            projection_grads.push(dhp);
        }
        // The biases' gradient, summed from the first step to the last: the
        // bias reaches each step's sum through a reshape node of its own,
        // and burn runs those (all one node away from the parameter) in the
        // order its graph walk met them, first step first.
        let mut d_bias: Option<FlexTensor> = None;
        for dhp in projection_grads.into_iter().rev() {
            let db = Flex::linear_bias_backward(dhp);
            d_bias = Some(match d_bias {
                Some(sum) => Flex::float_add(db, sum),
                None => db,
            });
        }
        let d_h0 = carried.unwrap_or_else(|| vec![0.0; batch * hidden]);
        let d_weight =
            d_weight.unwrap_or_else(|| flex(vec![0.0; hidden * 3 * hidden], weight.shape()));
        let d_bias = d_bias.unwrap_or_else(|| flex(vec![0.0; 3 * hidden], [3 * hidden]));
        [
            flex(dx, x_shape),
            flex(d_h0, [batch, hidden]),
            d_weight,
            d_bias,
        ]
    }
}

/// A GRU run over a whole sequence, whose backward pass is
/// [`GruSequenceKernels`]'s.
#[backend_extension(Flex, Autodiff)]
pub trait FusedGruSequence: Backend {
    /// The states `[B, T, H]` of a GRU over input projections `x_proj`
    /// `[B, T, 3H]` from `h0` `[B, H]`, with hidden weights `[H, 3H]`,
    /// biases `[3H]` and the mask `[B, T]` (read only if `masked`).
    fn fused_gru_sequence(
        x_proj: FloatTensor<Self>,
        h0: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> FloatTensor<Self>;
}

impl FusedGruSequence for Flex {
    fn fused_gru_sequence(
        x_proj: FlexTensor,
        h0: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        mask: FlexTensor,
        masked: bool,
    ) -> FlexTensor {
        Flex::gru_sequence_forward(x_proj, h0, weight, bias, mask, masked).0
    }
}

/// The autodiff node of [`FusedGruSequence::fused_gru_sequence`].
#[derive(Debug)]
struct GruSequenceBackward;

/// The backward pass's state: the input projections, the hidden weights,
/// the mask, whether to read it, and what the forward pass saved.
type SequenceState<T> = (T, T, T, bool, SequenceSaved<T>);

impl<B: GruSequenceKernels> Backward<B, 4> for GruSequenceBackward {
    type State = SequenceState<B::FloatTensorPrimitive>;

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let (x_proj, weight, mask, masked, saved) = ops.state;
        let gradients = B::gru_sequence_backward(x_proj, weight, mask, masked, saved, grad);
        for (node, grad) in ops.parents.into_iter().zip(gradients) {
            if let Some(node) = node {
                grads.register::<B>(node.id, grad);
            }
        }
    }
}

impl<B: GruSequenceKernels, C: CheckpointStrategy> FusedGruSequence for Autodiff<B, C> {
    fn fused_gru_sequence(
        x_proj: FloatTensor<Self>,
        h0: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        mask: FloatTensor<Self>,
        masked: bool,
    ) -> FloatTensor<Self> {
        let kind = GruSequenceBackward
            .prepare::<C>([x_proj.node(), h0.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful();
        let (x_state, w_state, m_state) = (
            x_proj.primitive().clone(),
            weight.primitive().clone(),
            mask.primitive().clone(),
        );
        let (out, saved) = B::gru_sequence_forward(
            x_proj.into_primitive(),
            h0.into_primitive(),
            weight.into_primitive(),
            bias.into_primitive(),
            mask.into_primitive(),
            masked,
        );
        match kind {
            OpsKind::Tracked(prep) => prep.finish((x_state, w_state, m_state, masked, saved), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// Whether [`gru_sequence`] can run a sequence on `x_proj`'s device.
pub(crate) fn fused_available(x_proj: &Tensor<3>) -> bool {
    is_flex(x_proj.device().as_dispatch()) && x_proj.dtype() == DType::F32
}

/// The states `[B, T, H]` of a GRU over input projections `x_proj`
/// `[B, T, 3H]` from `h0`, hidden weights `[H, 3H]` and biases `[3H]`,
/// with an optional mask `[B, T]` (1 = real step; 0 carries the state
/// over). Only where [`fused_available`].
pub(crate) fn gru_sequence(
    x_proj: Tensor<3>,
    h0: Tensor<2>,
    weight: Tensor<2>,
    bias: Tensor<1>,
    mask: Option<Tensor<2>>,
) -> Tensor<3> {
    let masked = mask.is_some();
    // Without a mask the kernels read none: a one-element stand-in.
    let mask = mask.unwrap_or_else(|| Tensor::zeros([1, 1], &h0.device()));
    let out = <burn::backend::Dispatch as FusedGruSequence>::fused_gru_sequence(
        x_proj.into_dispatch(),
        h0.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        mask.into_dispatch(),
        masked,
    );
    Tensor::from_dispatch(out)
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Device, Distribution, Tensor, TensorData};

    use crate::nn::{GruCell, Init};

    /// Everything a sequence run computes that training reads: the states,
    /// the final state, and the gradients of the input, of `h0` and of
    /// every parameter of the cell.
    fn run(
        cell: &GruCell,
        x: &Tensor<3>,
        h0: Option<&Tensor<2>>,
        mask: Option<&Tensor<2>>,
        fused: bool,
    ) -> Vec<TensorData> {
        let x = x.clone().detach().require_grad();
        let h0 = h0.map(|h| h.clone().detach().require_grad());
        let (states, last) = if fused {
            cell.forward_sequence(x.clone(), h0.clone(), mask.cloned())
        } else {
            cell.forward_sequence_composed(cell.project_input(x.clone()), h0.clone(), mask.cloned())
        };
        // The final state read twice, as the interpreter's decoder does
        // (its start state and its attention), so that its gradient is a
        // sum of several uses.
        let [b, t, hd] = states.dims();
        let probe = |seed: u64, dims: [usize; 2]| {
            let n = dims[0] * dims[1];
            let v: Vec<f32> = (0..n)
                .map(|i| ((i as u64 * 7 + seed) % 11) as f32 * 0.1 - 0.5)
                .collect();
            Tensor::<2>::from_data(TensorData::new(v, dims), &x.device())
        };
        let loss = (states.clone().reshape([b * t, hd]) * probe(1, [b * t, hd])).sum()
            + (last.clone() * probe(2, [b, hd])).sum()
            + (last.clone().tanh() * probe(3, [b, hd])).sum();
        let grads = loss.backward();
        let mut out = vec![states.into_data(), last.into_data()];
        out.push(x.grad(&grads).expect("x grad").into_data());
        if let Some(h0) = &h0 {
            out.push(h0.grad(&grads).expect("h0 grad").into_data());
        }
        for linear in [&cell.input, &cell.hidden] {
            out.push(linear.weight.grad(&grads).expect("weight grad").into_data());
            let bias = linear.bias.as_ref().expect("bias");
            out.push(bias.grad(&grads).expect("bias grad").into_data());
        }
        out
    }

    /// The fused sequence against the composed steps: every value and
    /// every gradient bit-identical, with and without a mask and `h0`, on
    /// sizes split across the pool and not, and a one-step sequence.
    #[test]
    fn fused_sequence_is_bit_identical_to_the_composed_steps() {
        let device = Device::flex().autodiff();
        for (b, t, d_in, hd, masked, with_h0) in [
            (2, 1, 3, 4, false, false),
            (3, 5, 4, 6, true, false),
            (4, 9, 5, 7, false, true),
            (5, 7, 6, 8, true, true),
            (64, 12, 16, 96, true, true),
        ] {
            let cell = GruCell::init(&mut Init::new(b as u64, &device), d_in, hd);
            let x: Tensor<3> =
                Tensor::random([b, t, d_in], Distribution::Normal(0.0, 1.0), &device);
            let h0: Tensor<2> = Tensor::random([b, hd], Distribution::Normal(0.0, 0.5), &device);
            // Sequences of different lengths, padded at the end.
            let mask = masked.then(|| {
                let m: Vec<f32> = (0..b * t)
                    .map(|i| {
                        if i % t < t - (i / t) % t.min(3) {
                            1.0
                        } else {
                            0.0
                        }
                    })
                    .collect();
                Tensor::<2>::from_data(TensorData::new(m, [b, t]), &device)
            });
            let h0 = with_h0.then_some(&h0);
            let fused = run(&cell, &x, h0, mask.as_ref(), true);
            let composed = run(&cell, &x, h0, mask.as_ref(), false);
            assert_eq!(fused.len(), composed.len());
            for (i, (f, c)) in fused.iter().zip(&composed).enumerate() {
                assert_eq!(
                    f, c,
                    "output {i} differs (b {b}, t {t}, h {hd}, mask {masked}, h0 {with_h0})"
                );
            }
        }
    }

    /// Without autodiff (evaluation) the fused sequence gives the composed
    /// steps' states.
    #[test]
    fn fused_sequence_without_autodiff_matches() {
        let device = Device::flex();
        let cell = GruCell::init(&mut Init::new(3, &device), 5, 6);
        let x: Tensor<3> = Tensor::random([3, 4, 5], Distribution::Normal(0.0, 1.0), &device);
        let (fused, last) = cell.forward_sequence(x.clone(), None, None);
        let (composed, composed_last) =
            cell.forward_sequence_composed(cell.project_input(x), None, None);
        assert_eq!(fused.into_data(), composed.into_data());
        assert_eq!(last.into_data(), composed_last.into_data());
    }
}
