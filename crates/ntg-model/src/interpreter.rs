//! The demo interpreter: a seq2seq model with Luong attention that reads a
//! demonstration and writes its action sequence.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::softmax;

use crate::activation::tanh;
use burn::tensor::{Device, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Vocabulary};

use crate::batch::{DemoBatch, rows_tensor};
use crate::encoder::{Encoder, EncoderConfig};
use crate::nn::{GruCell, Init, MASKED_LOGIT, masked_accuracy, masked_cross_entropy, to_vec_int};
use crate::{ModelError, Result};

/// Configuration of a [`DemoInterpreter`].
#[derive(Config, Debug)]
pub struct DemoInterpreterConfig {
    /// Number of CTG nodes `N` (the vocabulary size, `<start>`/`<end>` included).
    pub num_nodes: usize,
    /// Frame encoder.
    pub encoder: EncoderConfig,
    /// GRU hidden size `H` of the encoder and decoder.
    #[config(default = 128)]
    pub hidden: usize,
    /// Size of the decoder's token embeddings.
    #[config(default = 64)]
    pub token_embed: usize,
    /// Most tokens greedy decoding emits before giving up on `<end>`.
    #[config(default = 64)]
    pub max_decode_len: usize,
    /// Read the demo with a bidirectional GRU (`Some(true)`): each frame's
    /// annotation then also summarises the frames after it (so the last
    /// frame is recognisable as last). `None` (the default, and what older
    /// checkpoints hold) means false.
    pub bidirectional: Option<bool>,
    /// Luong's input feeding (`Some(true)`): the decoder reads the previous
    /// step's attentional state `h̃_{t−1}` besides the previous token, so it
    /// knows where it looked last. `None` means false.
    pub input_feeding: Option<bool>,
    /// Location-aware attention (`Some(true)`, needs input feeding;
    /// Chorowski et al. 2015): the score of frame `s` at step `t` also gets
    /// `G Σ_j w_j α_{t−1}(s − j)` for shifts `j` in −1..=2 (learned `w`,
    /// fixed gain `G` = `LOCATION_GAIN` (10), `α_{−1}` on the first frame), so
    /// the attention can learn to move on by one frame per token whatever
    /// the demo's length. `None` means false.
    pub location_attention: Option<bool>,
    /// Initial weight of shift +1 in location-aware attention (the other
    /// shifts start at 0): `Some(w)` starts the attention biased by
    /// `G·w` towards the frame after the one it read last, the monotonic
    /// alignment of a demo's frames and actions, instead of starting
    /// without a preference and having to find it. `None` means 0.
    pub location_step_prior: Option<f32>,
    /// The largest forward shift of location-aware attention (`Some(k)`,
    /// k ≥ 2): shifts −1..=k instead of −1..=2, and `location_step_prior`
    /// then starts *every* forward shift 1..=k at the prior, a window that
    /// lets the attention move on by up to `k` frames per token. For demo
    /// videos, whose actions span several frames each (2–9 in object
    /// collection): reading one token per action, the attention has to
    /// jump a whole action's frames, which −1..=2 cannot. `None` means
    /// −1..=2 with the prior on +1 only.
    pub location_max_shift: Option<usize>,
    /// A decoder without memory (`Some(true)`, needs input feeding): each
    /// step starts from a zero state and sees only the previous token and
    /// the previous attentional state `h̃_{t−1}`, so it cannot count how
    /// many actions it has written; what it writes, `<end>` included, has
    /// to come from where it looks. `None` means false.
    pub stateless_decoder: Option<bool>,
    /// Local annotations (`Some(true)`, not with `bidirectional`): frame
    /// `s` is annotated by `tanh(W_l [x_{s−1}; x_s; x_{s+1}])` over the
    /// encoded frames `x` (zeros beyond the demo) instead of a GRU state,
    /// so an annotation depends on its neighbours only, not on how long
    /// the demo has run. `None` means false.
    pub local_annotations: Option<bool>,
    /// Temporal pooling (`Some(k)`, k ≥ 2): the encoded frames are averaged
    /// in windows of `k` consecutive frames (padding frames left out)
    /// before the encoder GRU, so the GRU and the attention run over `T/k`
    /// steps. For demo videos, whose actions span several frames each:
    /// the interpreter's cost grows with the frames it reads. `None` (and
    /// `Some(1)`) means no pooling.
    pub frame_pool: Option<usize>,
    /// Attention aligned one row per token (`Some(true)`, needs
    /// location-aware attention): teacher-forced passes also train each
    /// token's attention onto its aligned row, by `−log(α + ALIGNMENT_FLOOR)`
    /// at that row averaged over the real tokens, added to the token loss.
    /// The rows come with the batch ([`DemoBatch::aligned_rows`]: for a
    /// video, the keyframe each action ends on, `<end>` on the last one);
    /// without them, the state-demo rule: token `t` onto row `t + 1`, the
    /// state action `t` left (its local window holds the state before it
    /// too), one step on from the first row where the attention starts,
    /// and `<end>` onto the last row (the final state) again; a demo with
    /// another number of rows than one per action plus the first state is
    /// then an input error in the loss. With `frame_pool`, a row's target
    /// is the window that holds it. The attention then learns to step
    /// through the demo from the labels instead of finding the alignment
    /// on its own (which stalls at some seeds). `None` means false.
    pub aligned_attention: Option<bool>,
}

impl DemoInterpreterConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if self.num_nodes < 3 {
            return Err(ModelError::Config(format!(
                "demo interpreter: num_nodes must count <start>, <end> and at least one action, got {}",
                self.num_nodes
            )));
        }
        if (self.location_attention == Some(true) || self.stateless_decoder == Some(true))
            && self.input_feeding != Some(true)
        {
            return Err(ModelError::Config(
                "demo interpreter: location-aware attention and a stateless decoder need input feeding"
                    .into(),
            ));
        }
        if self.local_annotations == Some(true) && self.bidirectional == Some(true) {
            return Err(ModelError::Config(
                "demo interpreter: local annotations replace the (bidirectional) GRU states; choose one"
                    .into(),
            ));
        }
        if let Some(k) = self.location_max_shift
            && !(2..=MAX_LOCATION_SHIFT).contains(&k)
        {
            return Err(ModelError::Config(format!(
                "demo interpreter: location_max_shift must be in 2..={MAX_LOCATION_SHIFT}, got {k}"
            )));
        }
        if self.aligned_attention == Some(true) && self.location_attention != Some(true) {
            return Err(ModelError::Config(
                "demo interpreter: aligned attention trains the location-aware attention one row per token; it needs location_attention".into(),
            ));
        }
        if self.frame_pool == Some(0) {
            return Err(ModelError::Config(
                "demo interpreter: frame_pool must be at least 1".into(),
            ));
        }
        if self.hidden == 0 || self.token_embed == 0 || self.max_decode_len == 0 {
            return Err(ModelError::Config(
                "demo interpreter: hidden, token_embed and max_decode_len must be positive".into(),
            ));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `seed` on `device`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<DemoInterpreter> {
        self.validate()?;
        let encoder = self.encoder.init(seed, device)?;
        let mut init = Init::new(seed ^ 0x5eed_0001, device);
        let h = self.hidden;
        let feeding = self.input_feeding.unwrap_or(false);
        let dec_in = self.token_embed + if feeding { h } else { 0 };
        let enc_gru = GruCell::init(&mut init, encoder.out_dim(), h);
        let tokens = init.matrix(self.num_nodes, self.token_embed, 1.0);
        let dec_gru = GruCell::init(&mut init, dec_in, h);
        let attn = init.linear(h, h, false);
        let combine = init.linear(2 * h, h, true);
        let out = init.linear(h, self.num_nodes, true);
        // The optional parts draw from their own generator, so the default
        // configuration's weights do not depend on them.
        let mut extra = Init::new(seed ^ 0x5eed_0b1d, device);
        let encoder_dim = encoder.out_dim();
        let (bwd_gru, merge) = if self.bidirectional.unwrap_or(false) {
            (
                Some(GruCell::init(&mut extra, encoder.out_dim(), h)),
                Some(extra.linear(2 * h, h, true)),
            )
        } else {
            (None, None)
        };
        Ok(DemoInterpreter {
            enc_gru,
            bwd_gru,
            merge,
            encoder,
            tokens,
            dec_gru,
            attn,
            combine,
            out,
            num_nodes: self.num_nodes,
            max_decode_len: self.max_decode_len,
            input_feeding: feeding,
            location: (self.location_attention == Some(true)).then(|| {
                let shifts = location_shifts(self.location_max_shift);
                let weights = extra.vector(shifts.len(), 0.0);
                match self.location_step_prior {
                    None => weights,
                    Some(prior) => {
                        // The default window primes shift +1 only; a wider
                        // one primes every forward shift.
                        let primed = |j: isize| match self.location_max_shift {
                            None => j == 1,
                            Some(_) => j >= 1,
                        };
                        let values: Vec<f32> = shifts
                            .iter()
                            .map(|&j| if primed(j) { prior } else { 0.0 })
                            .collect();
                        Param::from_data(TensorData::new(values, [shifts.len()]), device)
                    }
                }
            }),
            stateless: self.stateless_decoder == Some(true),
            local: (self.local_annotations == Some(true))
                .then(|| extra.linear(3 * encoder_dim, h, true)),
            frame_pool: self.frame_pool.unwrap_or(1),
            aligned: self.aligned_attention == Some(true),
        })
    }
}

/// Seq2seq demo interpreter (Luong et al. 2015, global attention with the
/// "general" score, no input feeding):
///
/// ```text
/// h̄_s = GRU_enc(Enc(o_s), h̄_{s−1})                      encoder, s = 1..T
/// h_t = GRU_dec(E[y_{t−1}], h_{t−1}),  h_0 = h̄_T, y_0 = <start>
/// α_ts = softmax_s(h_tᵀ W_a h̄_s)       (padding frames masked out)
/// c_t = Σ_s α_ts h̄_s
/// h̃_t = tanh(W_c [c_t; h_t])
/// p(y_t | y_<t, d) = softmax(W_o h̃_t)
/// ```
///
/// Trained with teacher forcing on the demo's actions followed by `<end>`;
/// decoded greedily at test time.
///
/// Two options of [`DemoInterpreterConfig`] (both off by default) change
/// this: `bidirectional` replaces `h̄_s` by `tanh(W_m [h̄→_s; h̄←_s])`, with
/// a second GRU read from the last frame back; `input_feeding` makes the
/// decoder read `[E[y_{t−1}]; h̃_{t−1}]` (with `h̃_0 = 0`);
/// `location_attention` (with input feeding) adds
/// `G Σ_j w_j α_{t−1}(s − j)` to the scores; `stateless_decoder` (with
/// input feeding) runs every decoder step from a zero state;
/// `local_annotations` uses `h̄_s = tanh(W_l [x_{s−1}; x_s; x_{s+1}])`.
#[derive(Module, Debug)]
pub struct DemoInterpreter {
    /// `Enc(o)` for the demo frames.
    pub encoder: Encoder,
    /// Encoder GRU over the encoded frames.
    pub enc_gru: GruCell,
    /// Backward encoder GRU (bidirectional configurations only).
    pub bwd_gru: Option<GruCell>,
    /// `W_m`: `[h̄→; h̄←]` → `h̄` (bidirectional configurations only).
    pub merge: Option<Linear>,
    /// Token embeddings `E` `[N, token_embed]`.
    pub tokens: Param<Tensor<2>>,
    /// Decoder GRU.
    pub dec_gru: GruCell,
    /// `W_a` of the general attention score (no bias).
    pub attn: Linear,
    /// `W_c`: `[c_t; h_t]` → `h̃_t`.
    pub combine: Linear,
    /// `W_o`: `h̃_t` → token logits.
    pub out: Linear,
    /// Number of CTG nodes `N`.
    pub num_nodes: usize,
    /// Greedy decoding limit.
    pub max_decode_len: usize,
    /// Whether the decoder reads the previous attentional state.
    pub input_feeding: bool,
    /// Location-aware attention weights `w` over the shifts −1..=k (k = 2
    /// unless `location_max_shift` says otherwise; the length gives k).
    pub location: Option<Param<Tensor<1>>>,
    /// Whether each decoder step starts from a zero state.
    pub stateless: bool,
    /// `W_l` of local annotations.
    pub local: Option<Linear>,
    /// Frames averaged into one step of the encoder (1: none).
    pub frame_pool: usize,
    /// Whether the loss also trains the attention one row per token
    /// ([`DemoInterpreterConfig::aligned_attention`]).
    pub aligned: bool,
}

/// The output of [`DemoInterpreter::forward`].
#[derive(Debug, Clone)]
pub struct InterpreterOutput {
    /// Token logits `[B, L, N]`.
    pub logits: Tensor<3>,
    /// Attention weights `α` `[B, L, T]` (each row sums to 1 over real frames).
    pub attention: Tensor<3>,
}

/// A loss and its metric, as returned by the `loss` methods.
#[derive(Debug, Clone)]
pub struct LossOutput {
    /// Mean loss (one element), to call `backward()` on.
    pub loss: Tensor<1>,
    /// Fraction of (unmasked) predictions whose arg-max is the target.
    pub accuracy: f32,
}

struct Encoded {
    /// The (pooled) frame mask `[B, T]` the states were read with.
    mask: Tensor<2>,
    /// `h̄` `[B, T, H]`.
    states: Tensor<3>,
    /// `W_a h̄` `[B, T, H]`.
    keys: Tensor<3>,
    /// `h̄_T` `[B, H]`.
    last: Tensor<2>,
}

/// The shifts `j` of location-aware attention by default (see
/// [`DemoInterpreterConfig::location_attention`]).
pub const LOCATION_SHIFTS: [isize; 4] = [-1, 0, 1, 2];
/// The largest `location_max_shift` a configuration may ask for.
pub const MAX_LOCATION_SHIFT: usize = 32;

/// The shifts −1..=k of location-aware attention with largest forward
/// shift `max_shift` (`None`: [`LOCATION_SHIFTS`]).
pub fn location_shifts(max_shift: Option<usize>) -> Vec<isize> {
    match max_shift {
        None => LOCATION_SHIFTS.to_vec(),
        Some(k) => (-1..=k as isize).collect(),
    }
}
/// The fixed gain `G` of location-aware attention: the learned weights start
/// at 0 and reach score-sized values in a few hundred Adam steps.
pub const LOCATION_GAIN: f32 = 10.0;

/// Encoded frames `x` `[B, T, E]` averaged in windows of `k` consecutive
/// frames, padding frames (mask 0) left out: `[B, ⌈T/k⌉, E]` and the mask
/// of the windows holding at least one frame `[B, ⌈T/k⌉]`.
fn pool_frames(x: Tensor<3>, frame_mask: Tensor<2>, k: usize) -> (Tensor<3>, Tensor<2>) {
    let [b, steps, e] = x.dims();
    let pooled = steps.div_ceil(k);
    let pad = pooled * k - steps;
    let device = x.device();
    let (x, mask) = if pad > 0 {
        (
            Tensor::cat(vec![x, Tensor::zeros([b, pad, e], &device)], 1),
            Tensor::cat(vec![frame_mask, Tensor::zeros([b, pad], &device)], 1),
        )
    } else {
        (x, frame_mask)
    };
    let weights = mask.reshape([b, pooled, k]);
    let counts = weights.clone().sum_dim(2); // [B, T/k, 1]
    let sums = (x.reshape([b, pooled, k, e]) * weights.unsqueeze_dim::<4>(3))
        .sum_dim(2)
        .reshape([b, pooled, e]);
    let means = sums / counts.clone().clamp_min(1.0);
    (means, counts.reshape([b, pooled]).clamp_max(1.0))
}

/// `[x_{s−1}; x_s; x_{s+1}]` `[B, T, 3E]` for encoded frames `x` `[B, T, E]`,
/// with padding frames (mask 0) and the frames beyond the ends as zeros.
fn local_windows(x: Tensor<3>, frame_mask: &Tensor<2>) -> Tensor<3> {
    let [b, steps, e] = x.dims();
    let x = x * frame_mask.clone().unsqueeze_dim::<3>(2);
    let zero = Tensor::<3>::zeros([b, 1, e], &x.device());
    let (prev, next) = if steps > 1 {
        (
            Tensor::cat(vec![zero.clone(), x.clone().narrow(1, 0, steps - 1)], 1),
            Tensor::cat(vec![x.clone().narrow(1, 1, steps - 1), zero], 1),
        )
    } else {
        (zero.clone(), zero)
    };
    Tensor::cat(vec![prev, x, next], 2)
}

/// The sequential decoder's state: GRU state, previous `h̃`, previous
/// attention `[B, T]`.
#[derive(Debug, Clone)]
struct FedState {
    h: Tensor<2>,
    feed: Tensor<2>,
    alpha: Tensor<2>,
}

/// Luong "general" attention of queries `[B, L, H]` over encoder states
/// `[B, T, H]` with keys `W_a h̄` `[B, T, H]`, padding frames (`frame_mask`
/// `[B, T]` below 0.5) masked out: returns `h̃ = tanh(W_c [c; query])`
/// `[B, L, H]` and the weights `α` `[B, L, T]`. `bias` `[B, L, T]` is added
/// to the scores (location-aware attention). Shared by the demo
/// interpreter and the Flat Policy baseline.
pub(crate) fn luong_attention(
    combine: &Linear,
    states: Tensor<3>,
    keys: Tensor<3>,
    frame_mask: &Tensor<2>,
    queries: Tensor<3>,
    bias: Option<Tensor<3>>,
) -> (Tensor<3>, Tensor<3>) {
    let [batch, len, _] = queries.dims();
    let steps = states.dims()[1];
    let mut scores = queries.clone().matmul(keys.swap_dims(1, 2)); // [B, L, T]
    if let Some(bias) = bias {
        scores = scores + bias;
    }
    let padding = frame_mask
        .clone()
        .lower_elem(0.5)
        .unsqueeze_dim::<3>(1)
        .expand([batch, len, steps]);
    let alpha = softmax(scores.mask_fill(padding, MASKED_LOGIT), 2);
    let context = alpha.clone().matmul(states); // [B, L, H]
    let combined = tanh(combine.forward(Tensor::cat(vec![context, queries], 2)));
    (combined, alpha)
}

/// What aligned attention adds to the weight on a token's row before the
/// log: each token's alignment loss is at most `−ln 0.1` ≈ 2.3, about the
/// token loss of a uniform guess among ten actions, so attention placed
/// far off cannot outweigh the tokens (unbounded, `−ln α` diverged in a
/// block-stacking pilot at 3e-3).
pub const ALIGNMENT_FLOOR: f32 = 0.1;

/// `−log(α_t(r_t) + ALIGNMENT_FLOOR)` averaged over the real tokens of
/// `batch` (see [`DemoInterpreterConfig::aligned_attention`]), for
/// attention `[B, L, T']` over the demo's rows pooled in windows of
/// `frame_pool`: `r_t` is token `t`'s row of [`DemoBatch::aligned_rows`]
/// (its window), or by the state-demo rule `min(t + 1, T − 1)`, where an
/// input error names a demo whose rows are not one more than its actions.
fn alignment_loss(attention: Tensor<3>, batch: &DemoBatch, frame_pool: usize) -> Result<Tensor<1>> {
    let [b, l, t] = attention.dims();
    let rows = crate::nn::to_vec(batch.frame_mask.clone().sum_dim(1))?;
    let tokens = crate::nn::to_vec(batch.target_mask.clone().sum_dim(1))?;
    let mut target = vec![0.0f32; b * l * t];
    let mut count = 0usize;
    for (i, (&rows, &tokens)) in rows.iter().zip(&tokens).enumerate() {
        let (rows, tokens) = (rows.round() as usize, tokens.round() as usize);
        let aligned: Vec<usize> = match &batch.aligned_rows {
            Some(given) => given[i].clone(),
            None if rows != tokens => {
                return Err(ModelError::Input(format!(
                    "aligned attention: demo {i} of the batch has {rows} rows for {} actions; without aligned rows given it needs one row per action plus the final state (state demos), not frames of a video",
                    tokens.saturating_sub(1)
                )));
            }
            None => (0..tokens).map(|j| (j + 1).min(rows - 1)).collect(),
        };
        for (j, &row) in aligned.iter().enumerate().take(tokens) {
            target[(i * l + j) * t + (row / frame_pool.max(1)).min(t - 1)] = 1.0;
        }
        count += tokens;
    }
    let target = Tensor::<3>::from_data(TensorData::new(target, [b, l, t]), &attention.device());
    let nll = ((attention + ALIGNMENT_FLOOR).log() * target).sum().neg();
    Ok(nll / count.max(1) as f32)
}

impl DemoInterpreter {
    fn encode(&self, frames: Tensor<3>, frame_mask: Tensor<2>) -> Result<Encoded> {
        let [batch, steps, _] = frames.dims();
        if frame_mask.dims() != [batch, steps] {
            return Err(ModelError::shape(
                "frame mask",
                format!("[{batch}, {steps}]"),
                frame_mask.dims(),
            ));
        }
        let x = self.encoder.forward_sequence(frames)?;
        let (x, frame_mask) = if self.frame_pool > 1 {
            pool_frames(x, frame_mask, self.frame_pool)
        } else {
            (x, frame_mask)
        };
        let (forward, last) =
            self.enc_gru
                .forward_sequence(x.clone(), None, Some(frame_mask.clone()));
        let states = match (&self.local, &self.bwd_gru, &self.merge) {
            (Some(local), _, _) => tanh(local.forward(local_windows(x, &frame_mask))),
            (None, Some(bwd), Some(merge)) => {
                // Padding comes first in the reversed sequence and leaves the
                // zero state untouched, so each demo is read from its own
                // last frame.
                let (backward, _) =
                    bwd.forward_sequence(x.flip([1]), None, Some(frame_mask.clone().flip([1])));
                tanh(merge.forward(Tensor::cat(vec![forward, backward.flip([1])], 2)))
            }
            _ => forward,
        };
        let keys = self.attn.forward(states.clone());
        Ok(Encoded {
            mask: frame_mask,
            states,
            keys,
            last,
        })
    }

    /// Luong attention of decoder states `[B, L, H]` over the encoder
    /// states: token logits `[B, L, N]`, weights `[B, L, T]` and the
    /// attentional states `h̃` `[B, L, H]`.
    fn attend(
        &self,
        enc: &Encoded,
        dec: Tensor<3>,
        bias: Option<Tensor<3>>,
    ) -> (Tensor<3>, Tensor<3>, Tensor<3>) {
        let (combined, alpha) = luong_attention(
            &self.combine,
            enc.states.clone(),
            enc.keys.clone(),
            &enc.mask,
            dec,
            bias,
        );
        (self.out.forward(combined.clone()), alpha, combined)
    }

    /// The state of the sequential (input-feeding) decoder before its
    /// first step: `h̄_T`, `h̃ = 0`, and the previous attention on frame 0.
    fn start_state(&self, enc: &Encoded) -> FedState {
        let [b, hd] = enc.last.dims();
        let steps = enc.states.dims()[1];
        let device = enc.last.device();
        let first = Tensor::<2>::ones([b, 1], &device);
        let alpha = if steps > 1 {
            Tensor::cat(vec![first, Tensor::zeros([b, steps - 1], &device)], 1)
        } else {
            first
        };
        FedState {
            h: enc.last.clone(),
            feed: Tensor::zeros([b, hd], &device),
            alpha,
        }
    }

    /// `G Σ_j w_j α(s − j)` `[B, 1, T]` from the previous attention `[B, T]`.
    fn location_bias(&self, alpha: &Tensor<2>) -> Option<Tensor<3>> {
        let w = self.location.as_ref()?.val();
        let [b, steps] = alpha.dims();
        let device = alpha.device();
        let mut bias = Tensor::<2>::zeros([b, steps], &device);
        // The weights' length says which shifts they are: −1..=len−2.
        let shifts: Vec<isize> = (-1..w.dims()[0] as isize - 1).collect();
        for (k, &j) in shifts.iter().enumerate() {
            let shift = j.unsigned_abs();
            if shift >= steps {
                continue;
            }
            let kept = steps - shift;
            let pad = Tensor::<2>::zeros([b, shift], &device);
            let shifted = if shift == 0 {
                alpha.clone()
            } else if j > 0 {
                Tensor::cat(vec![pad, alpha.clone().narrow(1, 0, kept)], 1)
            } else {
                Tensor::cat(vec![alpha.clone().narrow(1, shift, kept), pad], 1)
            };
            bias = bias + shifted * w.clone().narrow(0, k, 1).unsqueeze_dim::<2>(0);
        }
        Some((bias * LOCATION_GAIN).unsqueeze_dim(1))
    }

    /// Decoder step with input feeding: `[B, E]` token embeddings and the
    /// state → logits `[B, 1, N]`, weights `[B, 1, T]` and the next state.
    fn fed_step(
        &self,
        enc: &Encoded,
        x: Tensor<2>,
        state: FedState,
    ) -> (Tensor<3>, Tensor<3>, FedState) {
        let [b, hd] = state.h.dims();
        let bias = self.location_bias(&state.alpha);
        let h0 = if self.stateless {
            state.h.zeros_like()
        } else {
            state.h
        };
        let h = self.dec_gru.step(Tensor::cat(vec![x, state.feed], 1), h0);
        let (logits, alpha, combined) = self.attend(enc, h.clone().unsqueeze_dim(1), bias);
        let steps = alpha.dims()[2];
        let next = FedState {
            h,
            feed: combined.reshape([b, hd]),
            alpha: alpha.clone().reshape([b, steps]),
        };
        (logits, alpha, next)
    }

    /// Teacher-forced forward pass.
    ///
    /// `frames` `[B, T, D]`, `frame_mask` `[B, T]` (1 = frame, 0 = padding;
    /// every demo needs at least one frame), `targets` `[B, L]` token ids
    /// below `N` (the decoder reads `<start>, targets[.., ..L−1]`).
    pub fn forward(
        &self,
        frames: Tensor<3>,
        frame_mask: Tensor<2>,
        targets: Tensor<2, Int>,
    ) -> Result<InterpreterOutput> {
        self.forward_with_token_dropout(frames, frame_mask, targets, None)
    }

    /// [`DemoInterpreter::forward`] with decoder-input dropout: where
    /// `dropped` `[B, L]` is true, the decoder reads `<start>` (the "no
    /// previous token" input) instead of the previous target token, so it
    /// must find the action in the demo through attention rather than
    /// predict it from the tokens before. The caller draws `dropped` from
    /// its own seeded generator; column 0 is `<start>` already.
    pub fn forward_with_token_dropout(
        &self,
        frames: Tensor<3>,
        frame_mask: Tensor<2>,
        targets: Tensor<2, Int>,
        dropped: Option<Tensor<2, burn::tensor::Bool>>,
    ) -> Result<InterpreterOutput> {
        let [batch, len] = targets.dims();
        if batch != frames.dims()[0] || len == 0 {
            return Err(ModelError::shape(
                "target tokens",
                format!("[{}, L ≥ 1]", frames.dims()[0]),
                [batch, len],
            ));
        }
        let enc = self.encode(frames, frame_mask)?;
        let device = targets.device();
        let start = Tensor::<2, Int>::full([batch, 1], Vocabulary::START.index() as i64, &device);
        let mut inputs = Tensor::cat(vec![start, targets.narrow(1, 0, len - 1)], 1);
        if let Some(dropped) = dropped {
            if dropped.dims() != [batch, len] {
                return Err(ModelError::shape(
                    "token dropout mask",
                    format!("[{batch}, {len}]"),
                    dropped.dims(),
                ));
            }
            inputs = inputs.mask_fill(dropped, Vocabulary::START.index() as i64);
        }
        let embedded = self
            .tokens
            .val()
            .select(0, inputs.reshape([batch * len]))
            .reshape([batch, len, self.tokens.dims()[1]]);
        if self.input_feeding {
            let mut state = self.start_state(&enc);
            let (mut logits, mut attention) = (Vec::new(), Vec::new());
            for x in crate::nn::unstack_steps(embedded) {
                let (l, a, next) = self.fed_step(&enc, x, state);
                logits.push(l);
                attention.push(a);
                state = next;
            }
            return Ok(InterpreterOutput {
                logits: Tensor::cat(logits, 1),
                attention: Tensor::cat(attention, 1),
            });
        }
        let (dec, _) = self
            .dec_gru
            .forward_sequence(embedded, Some(enc.last.clone()), None);
        let (logits, attention, _) = self.attend(&enc, dec, None);
        Ok(InterpreterOutput { logits, attention })
    }

    /// Masked token cross-entropy and teacher-forced token accuracy on a batch.
    pub fn loss(&self, batch: &DemoBatch) -> Result<LossOutput> {
        self.loss_with_token_dropout(batch, None)
    }

    /// [`DemoInterpreter::loss`] with decoder-input dropout (see
    /// [`DemoInterpreter::forward_with_token_dropout`]).
    pub fn loss_with_token_dropout(
        &self,
        batch: &DemoBatch,
        dropped: Option<Tensor<2, burn::tensor::Bool>>,
    ) -> Result<LossOutput> {
        let out = self.forward_with_token_dropout(
            batch.frames.clone(),
            batch.frame_mask.clone(),
            batch.targets.clone(),
            dropped,
        )?;
        let [b, l, n] = out.logits.dims();
        let logits = out.logits.reshape([b * l, n]);
        let targets = batch.targets.clone().reshape([b * l]);
        let weights = batch.target_mask.clone().reshape([b * l]);
        let accuracy = masked_accuracy(logits.clone(), targets.clone(), weights.clone())?;
        let mut loss = masked_cross_entropy(logits, targets, weights);
        if self.aligned {
            loss = loss + alignment_loss(out.attention, batch, self.frame_pool)?;
        }
        Ok(LossOutput { loss, accuracy })
    }

    /// Greedy transcription of one demonstration (its observation rows, in
    /// order): the actions up to, not including, `<end>`. `<start>` is never
    /// emitted; at most `max_decode_len` tokens are produced.
    pub fn decode<R: AsRef<[f32]>>(&self, observations: &[R]) -> Result<Vec<ActionId>> {
        let mut all = self.decode_batch(&[observations])?;
        Ok(all.pop().unwrap_or_default())
    }

    /// Greedy transcription of several demonstrations at once.
    pub fn decode_batch<R: AsRef<[f32]>>(&self, demos: &[&[R]]) -> Result<Vec<Vec<ActionId>>> {
        if demos.is_empty() {
            return Ok(Vec::new());
        }
        let device = self.tokens.val().device();
        let dim = self.encoder.input_dim();
        let pairs: Vec<(&[R], &[ActionId])> = demos.iter().map(|d| (*d, &[][..])).collect();
        let batch = DemoBatch::new(&pairs, dim, self.num_nodes, &device)?;
        let b = demos.len();
        let enc = self.encode(batch.frames, batch.frame_mask.clone())?;
        let mut h = enc.last.clone();
        let mut state = self.start_state(&enc);
        let mut tokens = vec![Vocabulary::START.index() as i64; b];
        let mut done = vec![false; b];
        let mut out = vec![Vec::new(); b];
        // Never emit <start>.
        let mut forbid = vec![0.0f32; self.num_nodes];
        forbid[Vocabulary::START.index()] = MASKED_LOGIT;
        let forbid = Tensor::<1>::from_data(TensorData::new(forbid, [self.num_nodes]), &device)
            .unsqueeze_dim::<2>(0);
        for _ in 0..self.max_decode_len {
            let ids = Tensor::<1, Int>::from_data(TensorData::new(tokens.clone(), [b]), &device);
            let x = self.tokens.val().select(0, ids);
            let logits = if self.input_feeding {
                let (logits, _, next) = self.fed_step(&enc, x, state.clone());
                state = next;
                logits
            } else {
                h = self.dec_gru.step(x, h);
                self.attend(&enc, h.clone().unsqueeze_dim(1), None).0
            };
            let logits = logits.reshape([b, self.num_nodes]) + forbid.clone();
            let next = to_vec_int(logits.argmax(1).reshape([b]))?;
            for i in 0..b {
                if done[i] {
                    continue;
                }
                let id = ActionId::new(next[i] as usize);
                if id == Vocabulary::END {
                    done[i] = true;
                } else {
                    out[i].push(id);
                }
            }
            if done.iter().all(|&d| d) {
                break;
            }
            tokens = next;
        }
        Ok(out)
    }

    /// Attention weights `[B, L, T]` of a teacher-forced pass (for
    /// inspection and tests).
    pub fn attention(&self, batch: &DemoBatch) -> Result<Tensor<3>> {
        Ok(self
            .forward(
                batch.frames.clone(),
                batch.frame_mask.clone(),
                batch.targets.clone(),
            )?
            .attention)
    }

    /// Encodes observation rows without decoding (`[T, D]` → `[T, H]`),
    /// for callers that want the frame embeddings.
    pub fn encode_rows<R: AsRef<[f32]>>(&self, rows: &[R]) -> Result<Tensor<2>> {
        let device = self.tokens.val().device();
        self.encoder
            .forward(rows_tensor(rows, self.encoder.input_dim(), &device)?)
    }
}
