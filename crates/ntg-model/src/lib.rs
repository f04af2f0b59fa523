//! The Neural Task Graph networks (Huang et al., "Neural Task Graphs",
//! CVPR 2019, section 4), in burn 0.22.
//!
//! What is here:
//!
//! - observation encoders `Enc(o)` ([`EncoderConfig`]: an MLP for state
//!   vectors, a CNN for 64×64 RGB frames, an encoder for kinematics windows);
//! - [`DemoInterpreter`]: GRU seq2seq with Luong attention, demo frames →
//!   action sequence (teacher forcing to train, greedy to decode);
//! - [`GraphCompletionNet`]: the GCN of eqs. 1–2, initial CTG → completed
//!   CTG (edge probabilities) and node embeddings `NE_gcn`;
//! - [`NodeLocalizer`]: ℓ(n|o) ∝ exp(Enc(o)ᵀ NE_loc(n));
//! - [`EdgeClassifier`]: ε(a|n,o) ∝ exp((W[Enc(o), NE_gcn(n)])ᵀ NE_loc(n_a)),
//!   masked to the CTG successors of n;
//! - [`FrameStageNet`]: training NTG on videos, stage A: the one shared
//!   frame encoder trained with the localizer's and edge classifier's
//!   losses on single frames (stage B trains the rest on its embeddings);
//! - [`FlatPolicy`]: the Flat Policy baseline (Duan et al. 2017), attention
//!   over the encoded demo with the current observation as the query, then
//!   an MLP to the next action;
//! - [`NtpNet`]: the Neural Task Programming baseline (Xu et al. 2018), a
//!   program interpreter conditioned on the demo, run by a [`ProgramStack`];
//! - [`Detector`]: the NTP (Detector) baseline's frame → object-positions
//!   regressor, whose estimated state rows feed an NTP trained on states;
//! - [`NtgModel`] (the four together, with [`NtgConfig`], ablation switches
//!   and checkpoints) and [`NtgPolicy`], which turns one demonstration into
//!   `ctg_graph`'s [`NodeScorer`](ctg_graph::NodeScorer) and
//!   [`EdgeScorer`](ctg_graph::EdgeScorer) for the graph executor.
//!
//! Every network is a burn `#[derive(Module)]` built from a
//! `#[derive(Config)]` struct with an explicit seed, runs on whatever
//! [`Device`](burn::tensor::Device) it is given ([`BackendKind`] picks one:
//! `flex` by default, burn-ndarray, wgpu and CUDA behind features), and
//! exposes a batched forward pass plus a loss the trainer calls in its own
//! optimizer loop. Bad input is a [`ModelError`], never a panic.
//!
//! **Architecture invariant:** this crate must never depend on an
//! environment crate (`env-*`) or on the trainer: it sees observations as
//! flat `f32` rows and tensors, and task graphs as `ctg_graph` types.

pub mod activation;
mod backend;
mod batch;
mod checkpoint;
pub mod conv;
mod conv_phases;
mod detector;
mod edge;
mod encoder;
mod error;
pub mod export;
mod flat_policy;
pub mod float_mode;
mod frame_stage;
mod gcn;
mod gru;
mod gru_sequence;
mod interpreter;
mod localizer;
mod matmul;
mod model;
pub mod nn;
mod ntp;
mod optimizer;
mod parallel;
mod policy;

pub use backend::{BackendKind, cpu_device};
pub use batch::{DemoBatch, adjacency_tensor, ids_tensor, rows_tensor, successor_mask};
pub use detector::{Detector, DetectorConfig, DetectorLoss};
pub use edge::{EdgeClassifier, EdgeClassifierConfig, pending_nodes};
pub use encoder::{
    Encoder, EncoderConfig, FrameEncoder, FrameEncoderConfig, KinematicsEncoder,
    KinematicsEncoderConfig, StateEncoder, StateEncoderConfig,
};
pub use error::{ModelError, Result};
pub use flat_policy::{
    ConditionedFlatPolicy, FlatBatch, FlatExample, FlatOutput, FlatPolicy, FlatPolicyConfig,
    executed_actions,
};
pub use float_mode::{
    apply_float_mode, flush_subnormals_on_this_thread, flushes_subnormals, init_float_mode,
};
pub use frame_stage::{FrameStageConfig, FrameStageLoss, FrameStageNet};
pub use gcn::{EdgeCounts, GcnOutput, GraphCompletionConfig, GraphCompletionNet, PairMlp};
pub use interpreter::{
    ALIGNMENT_FLOOR, DemoInterpreter, DemoInterpreterConfig, InterpreterOutput, LossOutput,
};
pub use localizer::{NodeLocalizer, NodeLocalizerConfig};
pub use model::{
    AblationConfig, CONFIG_FILE, CompletedGraph, NtgConfig, NtgModel, SOFT_EDGE_FLOOR,
    WEIGHTS_FILE, load_optimizer, save_optimizer,
};
pub use ntp::{
    CallSteps, ConditionedNtp, CoreState, EncodedSpec, NtpBatch, NtpConfig, NtpCore, NtpDecision,
    NtpDecisionCheck, NtpExample, NtpLoss, NtpNet, NtpOutput, ProgramCall, ProgramStack,
    StackFrame, StackStep, scope_from_logits,
};
pub use optimizer::ParallelOptimizer;
pub use parallel::{
    ThreadPoolInfo, compute_pool_builder, init_thread_pool, pinned_pool_builder, sharded_gradients,
};
pub use policy::{MappedPolicy, NtgPolicy};

#[cfg(test)]
mod tests;
