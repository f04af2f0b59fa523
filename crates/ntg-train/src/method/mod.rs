//! Training methods, one file each: NTG ([`ntg`]) and the Flat Policy
//! baseline ([`flat`]); [`on_frames`] gives either of them video input.
//!
//! A method is a model type that [`crate::fit::fit`] can train (a
//! [`crate::fit::TrainedModel`] with a [`crate::fit::TrainStep`]), and that,
//! once trained, is a [`TrainedPolicy`]: conditioned on one demonstration it
//! gives an [`Agent`], the reactive policy every domain's evaluation rolls
//! out ([`crate::domain::evaluate`]). Its [`Method`] value names it, trains
//! it on the one value a domain provides ([`TrainInput`]) and loads it from
//! a run folder. An application registers the methods it offers
//! (the `ntg` binary's list adds the NTP family).

use std::any::Any;
use std::path::Path;

use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};

pub mod flat;
pub mod input;
pub mod ntg;
pub mod on_frames;

pub use input::{Demos, EpochReport, RowEncoders, TrainInput};

/// A registered method: its names and how to load a trained model of it.
pub trait Method: Sync {
    /// Name in files, run folders and on the command line (the registry's
    /// identifier, lower-cased).
    fn name(&self) -> &'static str;
    /// Name in figure legends and reports.
    fn legend(&self) -> &'static str;
    /// Loads a trained model saved in `dir`.
    fn load(&self, dir: &Path, device: &Device) -> anyhow::Result<Model>;
    /// The run-configuration options this method reads (its options type's
    /// keys: top-level, or `optim.KEY` / `video.KEY` for those runs keep
    /// there). A domain asks [`Method::reads`] before it writes an option's
    /// default or accepts its flag, instead of naming methods.
    fn options(&self) -> &'static [&'static str] {
        &[]
    }
    /// Whether this method reads the run-configuration option `option` (see
    /// [`Method::options`]).
    fn reads(&self, option: &str) -> bool {
        self.options().contains(&option)
    }
    /// Refuses, naming the flag, the options this method reads from the
    /// run's configuration `config` when they cannot be trained (called by
    /// [`Method::train`] too; a domain calls it before it creates a run
    /// folder).
    fn check(&self, config: &serde_json::Value) -> anyhow::Result<()> {
        let _ = config;
        Ok(())
    }
    /// Trains a model on what a domain provides (`input`), with the options
    /// this method reads from the run's configuration `config` (its own
    /// options type names the keys), reporting each epoch to `on_epoch`;
    /// refuses, naming the flag, what it cannot train.
    fn train(
        &self,
        input: TrainInput<'_>,
        config: &serde_json::Value,
        on_epoch: &mut dyn FnMut(&EpochReport),
    ) -> anyhow::Result<Model>;
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
    /// Writes the weights into `dir` as safetensors files in PyTorch's
    /// layout ([`ntg_model::export`]): one file per folder the model is
    /// saved in, `model.safetensors` for the network at the top and
    /// `NAME.safetensors` for a network saved in the subfolder `NAME`
    /// (`frame_encoder`, `detector`). Returns what it wrote, top first.
    fn export_safetensors(&self, dir: &Path) -> anyhow::Result<Vec<ExportedFile>>;
}

/// One safetensors file written by [`TrainedPolicy::export_safetensors`].
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ExportedFile {
    /// The file's name in the export folder (`model.safetensors`).
    pub file: String,
    /// The model folder's subfolder whose network it holds (empty for the
    /// network saved at the folder's top).
    pub folder: String,
    /// Its tensors, by name.
    pub tensors: Vec<ntg_model::export::ExportedTensor>,
}

/// Exports one network: the network saved in the model folder's
/// subfolder `folder` (empty: at its top) into `dir` (see
/// [`TrainedPolicy::export_safetensors`]).
pub fn export_network<M: burn::module::Module>(
    network: &M,
    dir: &Path,
    folder: &str,
) -> anyhow::Result<ExportedFile> {
    let file = if folder.is_empty() {
        "model.safetensors".to_owned()
    } else {
        format!("{folder}.safetensors")
    };
    let metadata = std::collections::BTreeMap::from([("ntg.folder".to_owned(), folder.to_owned())]);
    let tensors = ntg_model::export::save_safetensors(network, &dir.join(&file), &metadata)?;
    Ok(ExportedFile {
        file,
        folder: folder.to_owned(),
        tensors,
    })
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
