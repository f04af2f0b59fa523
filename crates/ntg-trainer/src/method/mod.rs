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
