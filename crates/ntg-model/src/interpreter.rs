//! The demo interpreter: a seq2seq model with Luong attention that reads a
//! demonstration and writes its action sequence.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::{softmax, tanh};
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
        Ok(DemoInterpreter {
            enc_gru: GruCell::init(&mut init, encoder.out_dim(), h),
            encoder,
            tokens: init.matrix(self.num_nodes, self.token_embed, 1.0),
            dec_gru: GruCell::init(&mut init, self.token_embed, h),
            attn: init.linear(h, h, false),
            combine: init.linear(2 * h, h, true),
            out: init.linear(h, self.num_nodes, true),
            num_nodes: self.num_nodes,
            max_decode_len: self.max_decode_len,
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
#[derive(Module, Debug)]
pub struct DemoInterpreter {
    /// `Enc(o)` for the demo frames.
    pub encoder: Encoder,
    /// Encoder GRU over the encoded frames.
    pub enc_gru: GruCell,
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
    /// `h̄` `[B, T, H]`.
    states: Tensor<3>,
    /// `W_a h̄` `[B, T, H]`.
    keys: Tensor<3>,
    /// `h̄_T` `[B, H]`.
    last: Tensor<2>,
}

/// Luong "general" attention of queries `[B, L, H]` over encoder states
/// `[B, T, H]` with keys `W_a h̄` `[B, T, H]`, padding frames (`frame_mask`
/// `[B, T]` below 0.5) masked out: returns `h̃ = tanh(W_c [c; query])`
/// `[B, L, H]` and the weights `α` `[B, L, T]`. Shared by the demo
/// interpreter and the Flat Policy baseline.
pub(crate) fn luong_attention(
    combine: &Linear,
    states: Tensor<3>,
    keys: Tensor<3>,
    frame_mask: &Tensor<2>,
    queries: Tensor<3>,
) -> (Tensor<3>, Tensor<3>) {
    let [batch, len, _] = queries.dims();
    let steps = states.dims()[1];
    let scores = queries.clone().matmul(keys.swap_dims(1, 2)); // [B, L, T]
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
        let (states, last) = self.enc_gru.forward_sequence(x, None, Some(frame_mask));
        let keys = self.attn.forward(states.clone());
        Ok(Encoded { states, keys, last })
    }

    /// Luong attention of decoder states `[B, L, H]` over the encoder states.
    fn attend(
        &self,
        enc: &Encoded,
        frame_mask: &Tensor<2>,
        dec: Tensor<3>,
    ) -> (Tensor<3>, Tensor<3>) {
        let (combined, alpha) = luong_attention(
            &self.combine,
            enc.states.clone(),
            enc.keys.clone(),
            frame_mask,
            dec,
        );
        (self.out.forward(combined), alpha)
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
        let [batch, len] = targets.dims();
        if batch != frames.dims()[0] || len == 0 {
            return Err(ModelError::shape(
                "target tokens",
                format!("[{}, L ≥ 1]", frames.dims()[0]),
                [batch, len],
            ));
        }
        let enc = self.encode(frames, frame_mask.clone())?;
        let device = targets.device();
        let start = Tensor::<2, Int>::full([batch, 1], Vocabulary::START.index() as i64, &device);
        let inputs = Tensor::cat(vec![start, targets.narrow(1, 0, len - 1)], 1);
        let embedded = self
            .tokens
            .val()
            .select(0, inputs.reshape([batch * len]))
            .reshape([batch, len, self.tokens.dims()[1]]);
        let (dec, _) = self
            .dec_gru
            .forward_sequence(embedded, Some(enc.last.clone()), None);
        let (logits, attention) = self.attend(&enc, &frame_mask, dec);
        Ok(InterpreterOutput { logits, attention })
    }

    /// Masked token cross-entropy and teacher-forced token accuracy on a batch.
    pub fn loss(&self, batch: &DemoBatch) -> Result<LossOutput> {
        let out = self.forward(
            batch.frames.clone(),
            batch.frame_mask.clone(),
            batch.targets.clone(),
        )?;
        let [b, l, n] = out.logits.dims();
        let logits = out.logits.reshape([b * l, n]);
        let targets = batch.targets.clone().reshape([b * l]);
        let weights = batch.target_mask.clone().reshape([b * l]);
        let accuracy = masked_accuracy(logits.clone(), targets.clone(), weights.clone())?;
        Ok(LossOutput {
            loss: masked_cross_entropy(logits, targets, weights),
            accuracy,
        })
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
            h = self.dec_gru.step(x, h);
            let (logits, _) = self.attend(&enc, &batch.frame_mask, h.clone().unsqueeze_dim(1));
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
