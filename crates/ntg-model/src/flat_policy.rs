//! The Flat Policy baseline (Duan et al., "One-Shot Imitation Learning",
//! 2017, as the NTG paper implements it): at each step, attention over the
//! encoded demonstration with the current observation as the query, then an
//! MLP to the next action. No task graph: one network maps (demo,
//! observation) to an action distribution.
//!
//! It uses the demo interpreter's architecture for the demonstration side:
//! the same observation encoder `Enc(o)`, the same GRU over the encoded demo
//! frames, and the same Luong "general" attention with the same combination
//! layer; only the query differs (the current observation instead of a
//! decoder state) and an MLP replaces the token output layer.

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::activation::{relu, softmax, tanh};
use burn::tensor::{Device, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Vocabulary};

use crate::batch::{DemoBatch, rows_tensor};
use crate::encoder::{Encoder, EncoderConfig};
use crate::interpreter::{LossOutput, luong_attention};
use crate::nn::{GruCell, Init, MASKED_LOGIT, masked_accuracy, masked_cross_entropy, to_vec};
use crate::{ModelError, Result};

/// The Flat Policy's execution memory: `1` for every action among
/// `executed` (the actions the agent has taken so far), `0` elsewhere
/// (`num_nodes` values).
pub fn executed_actions(num_nodes: usize, executed: &[ActionId]) -> Vec<f32> {
    let mut m = vec![0.0; num_nodes];
    for a in executed {
        if let Some(v) = m.get_mut(a.index()) {
            *v = 1.0;
        }
    }
    m
}

/// Configuration of a [`FlatPolicy`]; saved beside its weights as JSON.
#[derive(Config, Debug)]
pub struct FlatPolicyConfig {
    /// Number of actions `N` (the domain vocabulary's size, `<start>` and
    /// `<end>` included; `<start>` is never chosen).
    pub num_nodes: usize,
    /// Observation encoder, shared by the demo frames and the query.
    pub encoder: EncoderConfig,
    /// GRU hidden size `H` (as the demo interpreter's).
    #[config(default = 128)]
    pub hidden: usize,
    /// Hidden width of the action MLP.
    #[config(default = 128)]
    pub mlp_hidden: usize,
    /// Seed of the initial weights.
    #[config(default = 0)]
    pub seed: u64,
    /// Size of an optional execution-memory vector `m` (e.g. which actions
    /// the agent has taken so far) added to the query: `q = tanh(W_q Enc(o)
    /// + W_m m)`, so both the attention over the demo and the action MLP
    /// read it. `None` (or 0): no memory, Duan et al.'s reactive policy.
    pub memory_dim: Option<usize>,
}

impl FlatPolicyConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if self.num_nodes < 3 {
            return Err(ModelError::Config(format!(
                "flat policy: num_nodes must count <start>, <end> and at least one action, got {}",
                self.num_nodes
            )));
        }
        if self.hidden == 0 || self.mlp_hidden == 0 {
            return Err(ModelError::Config(
                "flat policy: hidden and mlp_hidden must be positive".into(),
            ));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `self.seed` on `device`.
    pub fn init(&self, device: &Device) -> Result<FlatPolicy> {
        self.validate()?;
        let encoder = self.encoder.init(self.seed.wrapping_add(11), device)?;
        let mut init = Init::new(self.seed ^ 0x5eed_0f1a, device);
        let h = self.hidden;
        Ok(FlatPolicy {
            enc_gru: GruCell::init(&mut init, encoder.out_dim(), h),
            query: init.linear(encoder.out_dim(), h, true),
            memory: match self.memory_dim {
                Some(m) if m > 0 => Some(init.linear(m, h, false)),
                _ => None,
            },
            attn: init.linear(h, h, false),
            combine: init.linear(2 * h, h, true),
            mlp: init.linear(h, self.mlp_hidden, true),
            out: init.linear(self.mlp_hidden, self.num_nodes, true),
            encoder,
            config: self.clone(),
        })
    }
}

/// The Flat Policy:
///
/// ```text
/// h̄_s = GRU(Enc(d_s), h̄_{s−1})                demo frames d_1..d_T
/// q   = tanh(W_q Enc(o))                      the current observation
/// α_s = softmax_s(qᵀ W_a h̄_s),  c = Σ_s α_s h̄_s
/// h̃   = tanh(W_c [c; q])
/// π(a | d, o) = softmax(W_o relu(W_1 h̃ + b_1) + b_o)   (<start> masked)
/// ```
///
/// Trained with cross-entropy on the next expert action of observations
/// from *another* demonstration of the same task (the conditioning demo
/// and the imitated episode differ, as in Duan et al.); run greedily.
#[derive(Module, Debug)]
pub struct FlatPolicy {
    /// `Enc(o)`, for demo frames and the current observation.
    pub encoder: Encoder,
    /// GRU over the encoded demo frames.
    pub enc_gru: GruCell,
    /// `W_q`: `Enc(o)` → query.
    pub query: Linear,
    /// `W_m`: execution memory → query (only with a memory).
    pub memory: Option<Linear>,
    /// `W_a` of the general attention score (no bias).
    pub attn: Linear,
    /// `W_c`: `[c; q]` → `h̃`.
    pub combine: Linear,
    /// First MLP layer.
    pub mlp: Linear,
    /// MLP output layer → action logits.
    pub out: Linear,
    /// The configuration the network was built from.
    #[module(skip)]
    pub config: FlatPolicyConfig,
}

/// A padded training batch for the [`FlatPolicy`]: conditioning demos,
/// the observations to act on, and the expert's next action at each.
#[derive(Debug, Clone)]
pub struct FlatBatch {
    /// Conditioning demo frames `[B, T, D]`.
    pub frames: Tensor<3>,
    /// `[B, T]`: 1 for a real frame, 0 for padding.
    pub frame_mask: Tensor<2>,
    /// Observations to act on `[B, Q, D]`.
    pub queries: Tensor<3>,
    /// Next action at each query `[B, Q]` (`<end>` at padding).
    pub targets: Tensor<2, Int>,
    /// `[B, Q]`: 1 for a real query, 0 for padding.
    pub query_mask: Tensor<2>,
    /// Execution memory at each query `[B, Q, M]` (zeros at padding), for
    /// a policy with a memory ([`FlatBatch::with_memory`]).
    pub memory: Option<Tensor<3>>,
}

/// One example of a [`FlatBatch`]: the conditioning demo's observation
/// rows, the imitated episode's observation rows, and the expert's action
/// after each of those rows (`<end>` after the last).
pub type FlatExample<'a, R> = (&'a [R], &'a [R], &'a [ActionId]);

impl FlatBatch {
    /// Builds a batch; every row has `obs_dim` values, every target is an
    /// id below `num_nodes` other than `<start>`, and each example has as
    /// many targets as query rows.
    pub fn new<R: AsRef<[f32]>>(
        examples: &[FlatExample<'_, R>],
        obs_dim: usize,
        num_nodes: usize,
        device: &Device,
    ) -> Result<Self> {
        if examples.is_empty() {
            return Err(ModelError::Input("empty flat-policy batch".into()));
        }
        let demos: Vec<(&[R], &[ActionId])> = examples.iter().map(|e| (e.0, &[][..])).collect();
        let demo = DemoBatch::new(&demos, obs_dim, num_nodes, device)?;
        let b = examples.len();
        let q = examples.iter().map(|e| e.1.len()).max().unwrap_or(0);
        if q == 0 {
            return Err(ModelError::Input(
                "flat-policy batch: every example needs at least one query".into(),
            ));
        }
        let mut queries = vec![0.0f32; b * q * obs_dim];
        let mut targets = vec![Vocabulary::END.index() as i64; b * q];
        let mut mask = vec![0.0f32; b * q];
        for (i, (_, rows, next)) in examples.iter().enumerate() {
            if rows.len() != next.len() || rows.is_empty() {
                return Err(ModelError::Input(format!(
                    "flat-policy example {i}: {} query rows and {} targets (need equal, positive)",
                    rows.len(),
                    next.len()
                )));
            }
            for (t, (row, &a)) in rows.iter().zip(next.iter()).enumerate() {
                let row = row.as_ref();
                if row.len() != obs_dim {
                    return Err(ModelError::Shape {
                        what: "flat-policy query",
                        expected: format!("{obs_dim} values"),
                        got: format!("{} values in example {i}, row {t}", row.len()),
                    });
                }
                if a.index() >= num_nodes || a == Vocabulary::START {
                    return Err(ModelError::Input(format!(
                        "flat-policy example {i}, row {t}: target {} is not an action below {num_nodes}",
                        a.index()
                    )));
                }
                let k = i * q + t;
                queries[k * obs_dim..(k + 1) * obs_dim].copy_from_slice(row);
                targets[k] = a.index() as i64;
                mask[k] = 1.0;
            }
        }
        Ok(FlatBatch {
            frames: demo.frames,
            frame_mask: demo.frame_mask,
            queries: Tensor::from_data(TensorData::new(queries, [b, q, obs_dim]), device),
            targets: Tensor::from_data(TensorData::new(targets, [b, q]), device),
            query_mask: Tensor::from_data(TensorData::new(mask, [b, q]), device),
            memory: None,
        })
    }

    /// Adds the execution memory of every query: `memory[i][t]` (`dim`
    /// values) for query row `t` of example `i`, in the order of
    /// [`FlatBatch::new`]'s examples.
    pub fn with_memory(mut self, memory: &[Vec<Vec<f32>>], dim: usize) -> Result<Self> {
        let [b, q] = self.query_mask.dims();
        if memory.len() != b || dim == 0 {
            return Err(ModelError::shape(
                "flat-policy memory",
                format!("{b} examples of positive size"),
                (memory.len(), dim),
            ));
        }
        let mut values = vec![0.0f32; b * q * dim];
        for (i, rows) in memory.iter().enumerate() {
            if rows.len() > q {
                return Err(ModelError::shape(
                    "flat-policy memory",
                    format!("at most {q} rows"),
                    rows.len(),
                ));
            }
            for (t, row) in rows.iter().enumerate() {
                if row.len() != dim {
                    return Err(ModelError::shape(
                        "flat-policy memory row",
                        format!("{dim} values"),
                        row.len(),
                    ));
                }
                let k = i * q + t;
                values[k * dim..(k + 1) * dim].copy_from_slice(row);
            }
        }
        let device = self.query_mask.device();
        self.memory = Some(Tensor::from_data(
            TensorData::new(values, [b, q, dim]),
            &device,
        ));
        Ok(self)
    }
}

/// The output of [`FlatPolicy::forward`].
#[derive(Debug, Clone)]
pub struct FlatOutput {
    /// Action logits `[B, Q, N]` (`<start>` masked).
    pub logits: Tensor<3>,
    /// Attention weights `[B, Q, T]` over the demo frames.
    pub attention: Tensor<3>,
}

/// The encoded conditioning demos: states `h̄` and keys `W_a h̄`.
#[derive(Debug, Clone)]
struct EncodedDemo {
    states: Tensor<3>,
    keys: Tensor<3>,
    frame_mask: Tensor<2>,
}

impl FlatPolicy {
    /// Number of actions `N`.
    pub fn num_nodes(&self) -> usize {
        self.config.num_nodes
    }

    /// Length `D` of one observation row.
    pub fn obs_dim(&self) -> usize {
        self.encoder.input_dim()
    }

    fn device(&self) -> Device {
        self.attn.weight.val().device()
    }

    fn encode_demo(&self, frames: Tensor<3>, frame_mask: Tensor<2>) -> Result<EncodedDemo> {
        let [batch, steps, _] = frames.dims();
        if frame_mask.dims() != [batch, steps] {
            return Err(ModelError::shape(
                "frame mask",
                format!("[{batch}, {steps}]"),
                frame_mask.dims(),
            ));
        }
        let x = self.encoder.forward_sequence(frames)?;
        let (states, _) = self
            .enc_gru
            .forward_sequence(x, None, Some(frame_mask.clone()));
        let keys = self.attn.forward(states.clone());
        Ok(EncodedDemo {
            states,
            keys,
            frame_mask,
        })
    }

    fn act(
        &self,
        demo: &EncodedDemo,
        queries: Tensor<3>,
        memory: Option<Tensor<3>>,
    ) -> Result<FlatOutput> {
        let [batch, len, _] = queries.dims();
        if demo.states.dims()[0] != batch {
            return Err(ModelError::shape(
                "queries",
                format!("[{}, Q, D]", demo.states.dims()[0]),
                queries.dims(),
            ));
        }
        let encoded = self.encoder.forward_sequence(queries)?;
        let mut q = self.query.forward(encoded);
        match (&self.memory, memory) {
            (None, None) => {}
            (Some(w), Some(m)) => {
                let dim = w.weight.dims()[0];
                if m.dims() != [batch, len, dim] {
                    return Err(ModelError::shape(
                        "flat-policy memory",
                        format!("[{batch}, {len}, {dim}]"),
                        m.dims(),
                    ));
                }
                q = q + w.forward(m);
            }
            (Some(_), None) => {
                return Err(ModelError::Input(
                    "this flat policy reads an execution memory; none was given".into(),
                ));
            }
            (None, Some(_)) => {
                return Err(ModelError::Input(
                    "this flat policy has no execution memory; one was given".into(),
                ));
            }
        }
        let q = tanh(q);
        let (combined, attention) = luong_attention(
            &self.combine,
            demo.states.clone(),
            demo.keys.clone(),
            &demo.frame_mask,
            q,
            None,
        );
        let logits = self.out.forward(relu(self.mlp.forward(combined)));
        let n = self.num_nodes();
        let mut forbid = vec![0.0f32; n];
        forbid[Vocabulary::START.index()] = MASKED_LOGIT;
        let forbid = Tensor::<1>::from_data(TensorData::new(forbid, [n]), &logits.device())
            .reshape([1, 1, n])
            .expand([batch, len, n]);
        Ok(FlatOutput {
            logits: logits + forbid,
            attention,
        })
    }

    /// Action logits for `queries` `[B, Q, D]` given demos `frames`
    /// `[B, T, D]` with `frame_mask` `[B, T]` (1 = frame, 0 = padding;
    /// every demo needs a frame).
    pub fn forward(
        &self,
        frames: Tensor<3>,
        frame_mask: Tensor<2>,
        queries: Tensor<3>,
    ) -> Result<FlatOutput> {
        self.forward_with_memory(frames, frame_mask, queries, None)
    }

    /// [`FlatPolicy::forward`] with the execution memory `[B, Q, M]` of
    /// every query (required with a memory, refused without).
    pub fn forward_with_memory(
        &self,
        frames: Tensor<3>,
        frame_mask: Tensor<2>,
        queries: Tensor<3>,
        memory: Option<Tensor<3>>,
    ) -> Result<FlatOutput> {
        let demo = self.encode_demo(frames, frame_mask)?;
        self.act(&demo, queries, memory)
    }

    /// Size of the execution memory (0: none).
    pub fn memory_dim(&self) -> usize {
        self.memory.as_ref().map_or(0, |w| w.weight.dims()[0])
    }

    /// Masked mean cross-entropy against the next actions, and accuracy.
    pub fn loss(&self, batch: &FlatBatch) -> Result<LossOutput> {
        let out = self.forward_with_memory(
            batch.frames.clone(),
            batch.frame_mask.clone(),
            batch.queries.clone(),
            batch.memory.clone(),
        )?;
        let [b, q, n] = out.logits.dims();
        let logits = out.logits.reshape([b * q, n]);
        let targets = batch.targets.clone().reshape([b * q]);
        let weights = batch.query_mask.clone().reshape([b * q]);
        let accuracy = masked_accuracy(logits.clone(), targets.clone(), weights.clone())?;
        Ok(LossOutput {
            loss: masked_cross_entropy(logits, targets, weights),
            accuracy,
        })
    }

    /// The policy for the task shown by one demonstration (its observation
    /// rows, in order), in inference mode, with the demo encoded once.
    pub fn condition<R: AsRef<[f32]>>(&self, demo: &[R]) -> Result<ConditionedFlatPolicy> {
        if demo.is_empty() {
            return Err(ModelError::Input(
                "a demonstration needs at least one observation".into(),
            ));
        }
        let model = self.valid();
        let device = model.device();
        let pairs: [(&[R], &[ActionId]); 1] = [(demo, &[])];
        let batch = DemoBatch::new(&pairs, model.obs_dim(), model.num_nodes(), &device)?;
        let encoded = model.encode_demo(batch.frames, batch.frame_mask)?;
        Ok(ConditionedFlatPolicy { model, encoded })
    }

    /// Saves the configuration (`config.json`) and weights (`model.bpk`)
    /// into `dir`, creating it if needed.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        crate::checkpoint::save(self, &self.config, dir.as_ref())
    }

    /// Loads a policy saved by [`FlatPolicy::save`] onto `device`; a
    /// missing, corrupt or mismatched file is an error naming it.
    pub fn load(dir: impl AsRef<Path>, device: &Device) -> Result<Self> {
        let config: FlatPolicyConfig =
            crate::checkpoint::load_config(dir.as_ref(), FlatPolicyConfig::validate)?;
        crate::checkpoint::load_weights(config.init(device)?, dir.as_ref())
    }
}

/// A [`FlatPolicy`] conditioned on one demonstration: a reactive policy
/// over flat observation rows.
#[derive(Debug, Clone)]
pub struct ConditionedFlatPolicy {
    model: FlatPolicy,
    encoded: EncodedDemo,
}

impl ConditionedFlatPolicy {
    /// π(·|d, o) over all `N` actions (0 for `<start>`).
    pub fn action_probabilities(&self, observation: &[f32]) -> Result<Vec<f32>> {
        self.action_probabilities_with_memory(observation, None)
    }

    /// π(·|d, o, m) for a policy with an execution memory `m`.
    pub fn action_probabilities_with_memory(
        &self,
        observation: &[f32],
        memory: Option<&[f32]>,
    ) -> Result<Vec<f32>> {
        let device = self.model.device();
        let row = rows_tensor(&[observation], self.model.obs_dim(), &device)?;
        let memory = match memory {
            Some(m) => Some(rows_tensor(&[m], m.len(), &device)?.unsqueeze_dim(0)),
            None => None,
        };
        let out = self
            .model
            .act(&self.encoded, row.unsqueeze_dim(0), memory)?;
        let n = self.model.num_nodes();
        to_vec(softmax(out.logits.reshape([1, n]), 1))
    }

    /// The most likely next action (lowest id on ties).
    pub fn next_action(&self, observation: &[f32]) -> Result<ActionId> {
        self.next_action_with_memory(observation, None)
    }

    /// The most likely next action given the execution memory `m` (for a
    /// policy with a memory).
    pub fn next_action_with_memory(
        &self,
        observation: &[f32],
        memory: Option<&[f32]>,
    ) -> Result<ActionId> {
        let p = self.action_probabilities_with_memory(observation, memory)?;
        let mut best = Vocabulary::END.index();
        for (i, &v) in p.iter().enumerate() {
            if i != Vocabulary::START.index() && v > p[best] {
                best = i;
            }
        }
        Ok(ActionId::new(best))
    }
}

#[cfg(test)]
mod tests {
    use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::StateEncoderConfig;
    use crate::model::WEIGHTS_FILE;
    use crate::nn::to_vec;
    use crate::tests::device;

    const N: usize = 7; // <start>, <end>, 5 actions
    const D: usize = 6;

    fn config(seed: u64) -> FlatPolicyConfig {
        let enc = EncoderConfig::State(StateEncoderConfig::new(D).with_hidden(24).with_out_dim(16));
        FlatPolicyConfig::new(N, enc)
            .with_hidden(24)
            .with_mlp_hidden(24)
            .with_seed(seed)
    }

    fn rows(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vec<f32>> {
        (0..n)
            .map(|_| (0..D).map(|_| rng.random_range(-1.0f32..1.0)).collect())
            .collect()
    }

    fn ids(v: &[usize]) -> Vec<ActionId> {
        v.iter().map(|&i| ActionId::new(i)).collect()
    }

    #[test]
    fn shapes_masks_and_probabilities() {
        let dev = device();
        let policy = config(1).init(&dev).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let (long, short) = (rows(&mut rng, 5), rows(&mut rng, 2));
        let (q1, q2) = (rows(&mut rng, 3), rows(&mut rng, 1));
        let (t1, t2) = (ids(&[2, 3, 1]), ids(&[1]));
        let batch = FlatBatch::new(
            &[
                (&long[..], &q1[..], &t1[..]),
                (&short[..], &q2[..], &t2[..]),
            ],
            D,
            N,
            &dev,
        )
        .unwrap();
        assert_eq!(batch.query_mask.dims(), [2, 3]);
        let out = policy
            .forward(
                batch.frames.clone(),
                batch.frame_mask.clone(),
                batch.queries.clone(),
            )
            .unwrap();
        assert_eq!(out.logits.dims(), [2, 3, N]);
        assert_eq!(out.attention.dims(), [2, 3, 5]);
        // Attention sums to 1 over real frames and ignores the padding of
        // the short demo.
        let att = to_vec(out.attention.clone()).unwrap();
        for row in att.chunks(5) {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        let second = &att[15..20];
        assert!(second[2..].iter().all(|&a| a < 1e-6), "{second:?}");
        // Padding does not change a demo's output: the short demo alone
        // gives the same logits for its query.
        let alone = policy.condition(&short).unwrap();
        let p_alone = alone.action_probabilities(&q2[0]).unwrap();
        let logits = out.logits.slice([1..2, 0..1, 0..N]).reshape([1, N]);
        let p_batch = to_vec(softmax(logits, 1)).unwrap();
        assert!(
            p_alone
                .iter()
                .zip(&p_batch)
                .all(|(a, b)| (a - b).abs() < 1e-5),
            "{p_alone:?} vs {p_batch:?}"
        );
        assert_eq!(p_alone[Vocabulary::START.index()], 0.0);
        assert!((p_alone.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert_ne!(alone.next_action(&q2[0]).unwrap(), Vocabulary::START);
        // The loss is finite and positive; accuracy is a fraction.
        let loss = policy.loss(&batch).unwrap();
        let l = to_vec(loss.loss).unwrap()[0];
        assert!(l.is_finite() && l > 0.0);
        assert!((0.0..=1.0).contains(&loss.accuracy));
    }

    #[test]
    fn bad_input_is_an_error() {
        let dev = device();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let demo = rows(&mut rng, 3);
        let q = rows(&mut rng, 2);
        let bad_dim = [vec![0.0; D + 1]];
        let two = ids(&[2, 1]);
        assert!(FlatBatch::new::<Vec<f32>>(&[], D, N, &dev).is_err());
        assert!(FlatBatch::new(&[(&demo[..], &q[..], &two[..1])], D, N, &dev).is_err());
        assert!(FlatBatch::new(&[(&demo[..], &bad_dim[..], &two[..1])], D, N, &dev).is_err());
        let start = ids(&[0, 1]);
        assert!(FlatBatch::new(&[(&demo[..], &q[..], &start[..])], D, N, &dev).is_err());
        let high = ids(&[N, 1]);
        assert!(FlatBatch::new(&[(&demo[..], &q[..], &high[..])], D, N, &dev).is_err());
        let policy = config(0).init(&dev).unwrap();
        assert!(policy.condition::<Vec<f32>>(&[]).is_err());
        let conditioned = policy.condition(&demo).unwrap();
        assert!(matches!(
            conditioned.action_probabilities(&[0.0; D + 2]),
            Err(ModelError::Shape { .. })
        ));
        assert!(matches!(
            FlatPolicyConfig::new(2, EncoderConfig::state(D)).init(&dev),
            Err(ModelError::Config(_))
        ));
    }

    #[test]
    fn save_then_load_gives_identical_outputs() {
        let dev = device();
        let policy = config(3).init(&dev).unwrap();
        let dir = tempfile::tempdir().unwrap();
        policy.save(dir.path()).unwrap();
        let back = FlatPolicy::load(dir.path(), &dev).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let demo = rows(&mut rng, 4);
        let obs = rows(&mut rng, 1);
        let a = policy.condition(&demo).unwrap();
        let b = back.condition(&demo).unwrap();
        assert_eq!(
            a.action_probabilities(&obs[0]).unwrap(),
            b.action_probabilities(&obs[0]).unwrap()
        );
        let other = config(4).init(&dev).unwrap();
        assert_ne!(
            to_vec(other.out.weight.val()).unwrap(),
            to_vec(policy.out.weight.val()).unwrap()
        );
        std::fs::write(dir.path().join(WEIGHTS_FILE), b"garbage").unwrap();
        let err = FlatPolicy::load(dir.path(), &dev).unwrap_err().to_string();
        assert!(err.contains(WEIGHTS_FILE), "{err}");
    }

    /// A task is a random map from 3 cues to actions. A demo frame shows a
    /// cue (one-hot, first 3 values) and the action taken there (one-hot
    /// over the 3 real-action slots 3..6 for actions 2..4); a query shows
    /// a cue alone. The right action can only come from the demo.
    /// A conditioning demo, query rows and their target actions.
    type Example = (Vec<Vec<f32>>, Vec<Vec<f32>>, Vec<ActionId>);

    fn task_example(rng: &mut ChaCha8Rng) -> Example {
        let map: Vec<usize> = (0..3).map(|_| rng.random_range(0..3)).collect();
        let mut cues = [0, 1, 2];
        cues.shuffle(rng);
        let demo = cues
            .iter()
            .map(|&c| {
                let mut r = vec![0.0; D];
                r[c] = 1.0;
                r[3 + map[c]] = 1.0;
                r
            })
            .collect();
        let query_cues: Vec<usize> = (0..4).map(|_| rng.random_range(0..3)).collect();
        let queries = query_cues
            .iter()
            .map(|&c| {
                let mut r = vec![0.0; D];
                r[c] = 1.0;
                r
            })
            .collect();
        let targets = query_cues
            .iter()
            .map(|&c| ActionId::new(2 + map[c]))
            .collect();
        (demo, queries, targets)
    }

    fn accuracy(policy: &FlatPolicy, examples: &[Example]) -> f32 {
        let (mut right, mut total) = (0, 0);
        for (demo, queries, targets) in examples {
            let p = policy.condition(demo).unwrap();
            for (q, &t) in queries.iter().zip(targets) {
                right += usize::from(p.next_action(q).unwrap() == t);
                total += 1;
            }
        }
        right as f32 / total as f32
    }

    /// One Adam step (lr 5e-3) on `tasks` fresh task examples: the trained
    /// policy and the step's loss.
    fn train_step(
        policy: FlatPolicy,
        optimizer: &mut ModuleOptimizer,
        rng: &mut ChaCha8Rng,
        tasks: usize,
        device: &Device,
    ) -> (FlatPolicy, Tensor<1>) {
        let examples: Vec<_> = (0..tasks).map(|_| task_example(rng)).collect();
        let refs: Vec<FlatExample<'_, Vec<f32>>> = examples
            .iter()
            .map(|(d, q, t)| (&d[..], &q[..], &t[..]))
            .collect();
        let batch = FlatBatch::new(&refs, D, N, device).unwrap();
        let loss = policy.loss(&batch).unwrap().loss;
        let grads = GradientsParams::from_grads(loss.clone().backward(), &policy);
        (optimizer.step(5e-3, policy, grads), loss)
    }

    /// Five training steps give bit-identical losses and parameters with
    /// the fused GRU sequence and with composed steps.
    #[test]
    fn training_is_the_same_with_the_fused_gru_sequence() {
        let train_dev = device().autodiff();
        let train = |composed: bool| {
            crate::nn::COMPOSED_GRU_ONLY.with(|c| c.set(composed));
            let mut policy = config(7).init(&train_dev).unwrap();
            let mut rng = ChaCha8Rng::seed_from_u64(12);
            let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
            let losses: Vec<_> = (0..5)
                .map(|_| {
                    let (trained, loss) =
                        train_step(policy.clone(), &mut optimizer, &mut rng, 8, &train_dev);
                    policy = trained;
                    loss.into_data()
                })
                .collect();
            crate::nn::COMPOSED_GRU_ONLY.with(|c| c.set(false));
            let weights = to_vec(policy.enc_gru.hidden.weight.val()).unwrap();
            let demo_input = to_vec(policy.enc_gru.input.weight.val()).unwrap();
            (losses, weights, demo_input)
        };
        assert_eq!(train(false), train(true));
    }

    #[test]
    fn learns_to_read_the_task_from_the_demo() {
        let dev = device();
        let train_dev = dev.clone().autodiff();
        let mut policy = config(7).init(&train_dev).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let held_out: Vec<_> = (0..40).map(|_| task_example(&mut rng)).collect();
        let before = accuracy(&policy.valid(), &held_out);
        let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
        for _ in 0..300 {
            policy = train_step(policy, &mut optimizer, &mut rng, 16, &train_dev).0;
        }
        let after = accuracy(&policy.valid(), &held_out);
        eprintln!("flat policy accuracy on unseen tasks: {before} -> {after}");
        // Chance is 1/3 among the right three actions (less over all six):
        // only reading the demo gets near 1.
        assert!(before < 0.6, "untrained accuracy {before}");
        assert!(after > 0.9, "accuracy on unseen tasks {before} -> {after}");
    }

    #[test]
    fn the_memory_enters_the_query_and_must_match_the_policy() {
        let dev = device();
        let policy = config(1).with_memory_dim(Some(N)).init(&dev).unwrap();
        let plain = config(1).init(&dev).unwrap();
        assert_eq!((policy.memory_dim(), plain.memory_dim()), (N, 0));
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (demo, q) = (rows(&mut rng, 4), rows(&mut rng, 2));
        let t = ids(&[2, 1]);
        let batch = FlatBatch::new(&[(&demo[..], &q[..], &t[..])], D, N, &dev).unwrap();
        // Without a memory the memory policy refuses; the plain one too with.
        assert!(policy.loss(&batch).is_err());
        let memory = vec![vec![executed_actions(N, &[]), executed_actions(N, &t[..1])]];
        let with = batch.clone().with_memory(&memory, N).unwrap();
        assert!(policy.loss(&with).is_ok());
        assert!(plain.loss(&with).is_err());
        assert!(plain.loss(&batch).is_ok());
        assert!(batch.clone().with_memory(&memory, 3).is_err());
        // Conditioned: the memory changes the action distribution.
        let cond = policy.condition(&demo).unwrap();
        let a = cond
            .action_probabilities_with_memory(&q[0], Some(&executed_actions(N, &[])))
            .unwrap();
        let b = cond
            .action_probabilities_with_memory(&q[0], Some(&executed_actions(N, &ids(&[2, 3]))))
            .unwrap();
        assert!(a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 1e-6));
        assert!(cond.next_action(&q[0]).is_err());
        // The memory's weights are saved and loaded.
        let dir = tempfile::tempdir().unwrap();
        policy.save(dir.path()).unwrap();
        let loaded = FlatPolicy::load(dir.path(), &dev).unwrap();
        let c = loaded
            .condition(&demo)
            .unwrap()
            .action_probabilities_with_memory(&q[0], Some(&executed_actions(N, &ids(&[2, 3]))))
            .unwrap();
        assert_eq!(b, c);
    }
}
