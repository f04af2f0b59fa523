//! Training methods, one file each, registered in [`MethodId`]: NTG
//! ([`ntg`]) and the Flat Policy baseline ([`flat`]). A method is a
//! [`crate::fit::TrainStep`] (its loss on a batch and its metrics line)
//! plus a model type [`crate::fit::TrainedModel`]; [`crate::fit::fit`]
//! trains every method the same way.
//!
//! Adding a method: a new file here with its step, one variant in
//! [`MethodId`] (the compiler then lists every `match` that must learn
//! it), and its model in [`Model`].

use burn::module::Module;
use burn::tensor::Device;
use clap::ValueEnum;
use ntg_model::{FlatPolicy, NtgModel};
use serde::{Deserialize, Serialize};

use crate::fit::TrainedModel;

pub mod flat;
pub mod ntg;

/// The registered methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum MethodId {
    /// Neural Task Graphs.
    Ntg,
    /// The Flat Policy baseline (attention over the demo, then an MLP).
    Flat,
}

impl MethodId {
    /// Name in files and run folders.
    pub fn name(self) -> &'static str {
        match self {
            MethodId::Ntg => "ntg",
            MethodId::Flat => "flat",
        }
    }

    /// Name in figure legends and reports.
    pub fn legend(self) -> &'static str {
        match self {
            MethodId::Ntg => "NTG (ours)",
            MethodId::Flat => "Flat Policy",
        }
    }

    /// Loads this method's model saved in `dir`.
    pub fn load(self, dir: &std::path::Path, device: &Device) -> anyhow::Result<Model> {
        Ok(match self {
            MethodId::Ntg => Model::Ntg(NtgModel::load_from(dir, device)?),
            MethodId::Flat => Model::Flat(FlatPolicy::load_from(dir, device)?),
        })
    }
}

/// A trained model of any method.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one or two per run; boxing buys nothing
pub enum Model {
    /// NTG.
    Ntg(NtgModel),
    /// The Flat Policy.
    Flat(FlatPolicy),
}

impl Model {
    /// The same model on its inference backend (no autodiff).
    pub fn valid(&self) -> Model {
        match self {
            Model::Ntg(m) => Model::Ntg(m.valid()),
            Model::Flat(p) => Model::Flat(p.valid()),
        }
    }
}

/// A model conditioned on one demonstration: a reactive policy over
/// observation rows, the same for every domain.
#[allow(clippy::large_enum_variant)] // one per episode; boxing buys nothing
pub enum Agent {
    /// NTG's graph executor over the demo's completed task graph.
    Ntg(ntg_model::NtgPolicy),
    /// The Flat Policy, attending over the demo.
    Flat {
        /// The conditioned policy.
        policy: ntg_model::ConditionedFlatPolicy,
        /// Whether it reads the actions taken so far.
        memory: bool,
        /// Vocabulary size.
        num_nodes: usize,
    },
}

impl Model {
    /// The policy conditioned on the demo with observation rows `demo`.
    pub fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &ctg_graph::Vocabulary,
    ) -> anyhow::Result<Agent> {
        Ok(match self {
            Model::Ntg(m) => Agent::Ntg(ntg_model::NtgPolicy::from_demo(m, demo, vocabulary)?),
            Model::Flat(p) => Agent::Flat {
                policy: p.condition(demo)?,
                memory: p.memory_dim() > 0,
                num_nodes: p.num_nodes(),
            },
        })
    }
}

impl Agent {
    /// The greedy next action for the observation row `row`, the agent
    /// having taken `executed` so far in the episode (read only by policies
    /// with an execution memory).
    pub fn act(
        &self,
        row: &[f32],
        executed: &[ctg_graph::ActionId],
    ) -> anyhow::Result<ctg_graph::ActionId> {
        Ok(match self {
            Agent::Ntg(policy) => {
                policy.set_executed(executed);
                policy.action_distribution(row)?.most_likely()
            }
            Agent::Flat {
                policy,
                memory,
                num_nodes,
            } => {
                let m = memory.then(|| ntg_model::executed_actions(*num_nodes, executed));
                policy.next_action_with_memory(row, m.as_deref())?
            }
        })
    }

    /// NTG's transcription of the demo (empty for the Flat Policy).
    pub fn transcription(&self) -> &[ctg_graph::ActionId] {
        match self {
            Agent::Ntg(policy) => policy.demo_actions(),
            Agent::Flat { .. } => &[],
        }
    }
}
