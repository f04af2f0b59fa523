//! Training methods, one file each, registered in one list ([`MethodId`]):
//! NTG ([`ntg`]), the Flat Policy baseline ([`flat`]), NTP and NTP Flat
//! ([`ntp`]), and NTP (Detector) ([`ntp_detector`]).
//!
//! A method is a model type that [`crate::fit::fit`] can train (a
//! [`crate::fit::TrainedModel`] with a [`crate::fit::TrainStep`]), and that,
//! once trained, is a [`TrainedPolicy`]: conditioned on one demonstration it
//! gives an [`Agent`], the reactive policy every domain's evaluation rolls
//! out ([`crate::domain::evaluate`]). Its [`Method`] value names it and loads
//! it from a run folder.
//!
//! Adding a method: a new file here (its model, step, [`Method`],
//! [`TrainedPolicy`] and [`Agent`]), and one line in the `methods!` list
//! below. A domain that trains it maps its run configuration onto the
//! method's options in its `train_run`.

use std::any::Any;
use std::path::Path;

use burn::tensor::Device;
use clap::ValueEnum;
use ctg_graph::{ActionId, Vocabulary};
use serde::{Deserialize, Serialize};

pub mod detector;
pub mod flat;
pub mod ntg;
pub mod ntp;
pub mod ntp_detector;
pub mod on_frames;

/// A registered method: its names and how to load a trained model of it.
pub trait Method: Sync {
    /// Name in files, run folders and on the command line (the registry's
    /// identifier, lower-cased).
    fn name(&self) -> &'static str;
    /// Name in figure legends and reports.
    fn legend(&self) -> &'static str;
    /// Loads a trained model saved in `dir`.
    fn load(&self, dir: &Path, device: &Device) -> anyhow::Result<Model>;
}

/// A trained model of any method, ready to be conditioned on demos.
pub trait TrainedPolicy: Send + Sync {
    /// The same model on the inference backend (no autodiff).
    fn for_inference(&self) -> Model;
    /// The policy conditioned on the demo with observation rows `demo`.
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>>;
    /// The concrete model (for tests and tools that need its weights).
    fn as_any(&self) -> &dyn Any;
}

/// A trained model of any method.
pub type Model = Box<dyn TrainedPolicy>;

/// The numbers that break exact ties between equally probable actions in
/// one episode: a generator seeded from the episode's rollout seed, so an
/// episode replays exactly. Only a policy with a constant term ties (NTG
/// without its edge classifier is uniform over a node's successors); the
/// others never draw.
pub struct Ties(rand_chacha::ChaCha8Rng);

impl Ties {
    /// The tie-breaker of the episode rolled out from `rollout_seed`.
    pub fn for_episode(rollout_seed: u64) -> Self {
        use rand::SeedableRng;
        Self(rand_chacha::ChaCha8Rng::seed_from_u64(
            rollout_seed ^ 0x7135_B2EA_C0DE,
        ))
    }

    /// The next number in `[0, 1)`.
    pub fn draw(&mut self) -> f64 {
        use rand::Rng;
        self.0.random()
    }
}

/// A model conditioned on one demonstration: a reactive policy over
/// observation rows, the same for every domain.
pub trait Agent {
    /// The greedy next action for the observation row `row`, the agent
    /// having taken `executed` so far in the episode (read only by policies
    /// with an execution memory); an exact tie between the most probable
    /// actions is broken with a number from `ties`.
    fn act(&self, row: &[f32], executed: &[ActionId], ties: &mut Ties) -> anyhow::Result<ActionId>;
    /// What the method read from the demo as its action sequence (NTG's
    /// demo interpreter), if anything.
    fn transcription(&self) -> &[ActionId] {
        &[]
    }
    /// What the agent was doing when it chose its last action, in words,
    /// for traces (NTP: its running programs and their scopes of the demo),
    /// if it says.
    fn explain(&self) -> Option<String> {
        None
    }
}

/// The registry: one line per method, `Identifier => value implementing
/// Method`; it makes [`MethodId`] (serialised and parsed lower-case).
macro_rules! methods {
    ($($(#[$doc:meta])* $id:ident => $method:expr,)*) => {
        /// The registered methods.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
        #[serde(rename_all = "kebab-case")]
        pub enum MethodId {
            $($(#[$doc])* $id,)*
        }

        impl MethodId {
            /// Every registered method, in registry order.
            pub const ALL: &[MethodId] = &[$(MethodId::$id,)*];

            /// The method itself.
            pub fn method(self) -> &'static dyn Method {
                match self {
                    $(MethodId::$id => &$method,)*
                }
            }
        }
    };
}

methods! {
    /// Neural Task Graphs.
    Ntg => ntg::Ntg,
    /// The Flat Policy baseline (attention over the demo, then an MLP).
    Flat => flat::Flat,
    /// Neural Task Programming (Xu et al. 2018), block stacking.
    Ntp => ntp::Ntp,
    /// NTP trained on the lowest level only, block stacking.
    NtpFlat => ntp::NtpFlat,
    /// NTP on the states a frame detector estimates (video input), block
    /// stacking.
    NtpDetector => ntp_detector::NtpDetector,
}

impl Default for MethodId {
    /// NTG, the method of runs saved before the field existed.
    fn default() -> Self {
        MethodId::Ntg
    }
}

impl MethodId {
    /// Whether it is NTG.
    pub fn is_ntg(&self) -> bool {
        *self == MethodId::Ntg
    }

    /// Whether it is one of the NTP baselines.
    pub fn is_ntp(&self) -> bool {
        matches!(
            self,
            MethodId::Ntp | MethodId::NtpFlat | MethodId::NtpDetector
        )
    }

    /// Name in files, run folders and on the command line.
    pub fn name(self) -> &'static str {
        self.method().name()
    }

    /// Name in figure legends and reports.
    pub fn legend(self) -> &'static str {
        self.method().legend()
    }

    /// Loads this method's model saved in `dir`.
    pub fn load(self, dir: &Path, device: &Device) -> anyhow::Result<Model> {
        self.method().load(dir, device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_is_named_as_it_is_serialised() {
        for &id in MethodId::ALL {
            let serialised = serde_json::to_value(id).unwrap();
            assert_eq!(serialised.as_str(), Some(id.name()));
            let parsed: MethodId = serde_json::from_value(serialised).unwrap();
            assert_eq!(parsed, id);
            assert_eq!(
                MethodId::from_str(id.name(), false).unwrap(),
                id,
                "the command line accepts {}",
                id.name()
            );
        }
    }
}
