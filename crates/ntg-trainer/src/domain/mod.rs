//! This repository's task domains, one file each, registered in
//! [`DomainId`]: block stacking ([`blocks`]), object collection
//! ([`collect`]) and object sorting ([`sorting`]). (JIGSAWS is a dataset
//! scored by NLL, not rolled out: see [`crate::jigsaws`].)
//!
//! Each domain is a small adapter behind ntg-train's [`Domain`]
//! (re-exported here with the evaluation loop [`evaluate`] and
//! [`record_demos`]), plus its command-line side, [`DomainRuns`]: its
//! `ntg train` and `ntg eval`.
//!
//! Adding a domain: a new file here implementing [`Domain`] (with its task
//! split, seeds, dataset and run configuration) and [`DomainRuns`], and one
//! line in the `domains!` list below. Architecture invariant: no domain
//! file imports another (what block stacking and sorting share is
//! [`crate::block_world`]); `tests/integration/module_cycles.rs` checks it.

use std::path::PathBuf;

use clap::ValueEnum;
use serde::{Deserialize, Serialize};

use crate::method::ntg::Variant;
use crate::run_dir::RunDir;
use crate::spec::ObsKind;

pub use ntg_train::domain::*;

pub mod blocks;
pub mod collect;
pub mod sorting;

/// What the command line needs of a domain, whatever its types:
/// `ntg train --domain NAME` and `ntg eval` on its runs.
pub trait DomainRuns: Sync {
    /// Name on the command line and in files.
    fn name(&self) -> &'static str;
    /// `ntg train`: builds the run configuration from the shared flags and
    /// the domain's own, starts (or with `--resume` continues) the run in
    /// `--out`, and trains it.
    fn train(&self, flags: &TrainFlags, own: &DomainFlags) -> anyhow::Result<()>;
    /// Whether `config` (a run folder's `config.json`) is a run of this
    /// domain.
    fn owns(&self, config: &serde_json::Value) -> bool;
    /// `ntg eval` on a run of this domain: evaluates it on unseen tasks,
    /// writes the records under `eval/` and prints the success rates.
    fn evaluate(&self, run: &RunDir, flags: &EvalFlags) -> anyhow::Result<()>;
    /// The trained model of a run of this domain (`ntg export`): the epoch
    /// selected on validation tasks if there is one, else the last
    /// checkpoint, on the inference device.
    fn trained(&self, run: &RunDir) -> anyhow::Result<TrainedRun>;
}

/// A run's trained model and where it was read from ([`DomainRuns::trained`]).
pub struct TrainedRun {
    /// The model.
    pub model: crate::method::Model,
    /// The model folder it was loaded from (`best/` or `checkpoint/`).
    pub dir: PathBuf,
    /// Its method's name (`ntg`, `flat`, `ntp`, ...).
    pub method: &'static str,
}

/// The registry: one line per domain, `Identifier => value implementing
/// DomainRuns, flags field: its own ntg train flags`; it makes [`DomainId`]
/// and [`DomainFlags`].
macro_rules! domains {
    ($($(#[$doc:meta])* $id:ident => $value:expr, flags $field:ident: $flags:ty,)*) => {
        /// The registered domains.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
        #[serde(rename_all = "lowercase")]
        pub enum DomainId {
            $($(#[$doc])* $id,)*
        }

        impl DomainId {
            /// Every registered domain, in registry order.
            pub const ALL: &[DomainId] = &[$(DomainId::$id,)*];

            /// The domain's command-line side.
            pub fn runs(self) -> &'static dyn DomainRuns {
                match self {
                    $(DomainId::$id => &$value,)*
                }
            }

            /// The clap group of the domain's own `ntg train` flags.
            pub fn flags_group(self) -> Option<clap::Id> {
                match self {
                    $(DomainId::$id => <$flags as clap::Args>::group_id(),)*
                }
            }
        }

        /// Every domain's own `ntg train` flags.
        #[derive(Debug, Clone, clap::Args)]
        pub struct DomainFlags {
            $(
                #[allow(missing_docs)]
                #[command(flatten)]
                pub $field: $flags,
            )*
        }
    };
}

domains! {
    /// Block stacking (the paper's main experiment, fig. "ntp_exp").
    Blocks => blocks::Blocks, flags blocks: blocks::BlocksFlags,
    /// Object collection (fig. "thor_all" (b)): NTG or the Flat Policy.
    Collect => collect::Collect, flags collect: collect::CollectFlags,
    /// Object sorting (fig. "ablation" (b)): NTG on part-sorted scenes.
    Sorting => sorting::Sorting, flags sorting: sorting::SortingFlags,
}

impl DomainId {
    /// Name in run folders, files and on the command line.
    pub fn name(self) -> &'static str {
        self.runs().name()
    }

    /// The domain whose run `config` (a `config.json`) is.
    pub fn of_run(config: &serde_json::Value) -> Option<DomainId> {
        DomainId::ALL
            .iter()
            .copied()
            .find(|d| d.runs().owns(config))
    }
}

/// Writes the evaluation record `value` as `run`'s `eval/FILE` and says
/// where, for the line that prints the result: "records in PATH", or, where
/// the run folder cannot be written (a read-only copy, a model zoo entry
/// checked out read-only), "not recorded (REASON)": the printed numbers are
/// the result either way.
pub fn record_eval(run: &RunDir, file: &str, value: &impl Serialize) -> String {
    let path = run.eval_dir().join(file);
    let written = std::fs::create_dir_all(run.eval_dir())
        .map_err(anyhow::Error::from)
        .and_then(|()| RunDir::write_json(&path, value));
    match written {
        Ok(()) => format!("records in {}", path.display()),
        Err(e) => format!("not recorded ({e:#})"),
    }
}

/// Opens the run folder `path` and finds the domain it is a run of.
pub fn open_run(path: &std::path::Path) -> anyhow::Result<(RunDir, DomainId)> {
    let run = RunDir::open(path)?;
    let config: serde_json::Value = RunDir::read_json(&run.config_path())?;
    let domain = DomainId::of_run(&config).ok_or_else(|| {
        anyhow::anyhow!(
            "{} is not a run of any domain ntg knows",
            run.config_path().display()
        )
    })?;
    Ok((run, domain))
}

/// The `ntg train` flags every domain reads.
#[derive(Debug, Clone, clap::Args)]
pub struct TrainFlags {
    /// Where the networks run: the CPU, or a GPU backend compiled in with
    /// `--features wgpu` / `--features cuda`.
    #[arg(long, value_enum, default_value_t = crate::spec::DeviceKind::Cpu)]
    pub device: crate::spec::DeviceKind,
    /// Which model to train: ntg, or a baseline (block stacking: ntp,
    /// ntp-flat, ntp-detector with --obs vid; object collection: flat).
    #[arg(long, value_enum, default_value_t = crate::method::MethodId::Ntg)]
    pub method: crate::method::MethodId,
    /// Train (and evaluate) NTG without one of its parts, as in the
    /// paper's ablations (block stacking and object sorting):
    /// no-demo-interpreter, no-node-localizer, no-edge-classifier or
    /// no-gcn.
    #[arg(long, value_parser = crate::spec::parse::choice::<Variant>(), default_value_t = Variant::Full)]
    pub ablation: Variant,
    /// Observation kind.
    #[arg(long, value_parser = crate::spec::parse::choice::<ObsKind>(), default_value_t = ObsKind::State)]
    pub obs: ObsKind,
    /// Training tasks (blocks: a prefix of the standard 1000-task pool;
    /// collect: distinct training tasks per number of objects).
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 100)]
    pub train_tasks: usize,
    /// Expert demonstrations per training task.
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 20)]
    pub demos_per_task: usize,
    /// Passes over the demonstrations.
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 20)]
    pub epochs: usize,
    /// Demonstrations per optimisation step.
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 32)]
    pub batch_size: usize,
    /// Adam learning rate [default: blocks 3e-3 with --recipe recommended,
    /// else 1e-3].
    #[arg(long, value_parser = crate::spec::parse::positive_real)]
    pub lr: Option<f64>,
    /// Seed of the weights and the shuffling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Decay the learning rate along a half cosine to a tenth of --lr.
    #[arg(long)]
    pub cosine_decay: bool,
    /// NTG: which demo interpreter [default: object collection: stepping
    /// for --obs state, stepping-video for --obs vid; block stacking:
    /// luong, the paper's].
    #[arg(long, value_parser = crate::spec::parse::choice::<crate::method::ntg::InterpreterKind>())]
    pub interpreter: Option<crate::method::ntg::InterpreterKind>,
    /// Give the policy an execution memory, the actions the agent has
    /// taken so far: NTG's edge classifier reads the task-graph nodes not
    /// yet executed (object collection; block stacking, not in the paper
    /// there), the Flat Policy reads them in its attention query (object
    /// collection).
    #[arg(long)]
    pub memory: bool,
    /// NTG with a stepping interpreter: initial weight of its
    /// location-aware attention's forward shifts, a bias towards reading
    /// on (0 = no preference) [default: 0.3 with a stepping interpreter].
    #[arg(long, value_name = "W", value_parser = crate::spec::parse::finite)]
    pub location_step_prior: Option<f32>,
    /// Data-parallel training: split each batch into this many shards
    /// trained on their own threads, gradients summed (--obs vid: both
    /// stages). A run's results depend on its shard count (saved
    /// in its config.json), not on the machine; 1 reproduces runs made
    /// before this flag existed.
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 2)]
    pub shards: usize,
    /// Run folder to create (or, with --resume, to continue).
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the run in --out from its last checkpoint, with the
    /// arguments it was started with; a larger --epochs extends a finished
    /// run where the result equals a run of that many epochs from the
    /// start (no cosine decay; the old count a multiple of
    /// --validate-every), and is refused, saying why, where not.
    #[arg(long)]
    pub resume: bool,
    /// --obs vid: demo videos whose frames train the shared frame encoder
    /// (stage A) [default: block stacking 20000, object collection 1000].
    #[arg(long, value_parser = crate::spec::parse::positive)]
    pub encoder_demos: Option<usize>,
    /// --obs vid: passes of stage A over those frames [default: block
    /// stacking 3, object collection 4].
    #[arg(long, value_parser = crate::spec::parse::positive)]
    pub encoder_epochs: Option<usize>,
    /// --obs vid: fraction of each demo's frames besides its keyframes
    /// that stage A trains on [default: block stacking 0.15, object
    /// collection 1].
    #[arg(long, value_name = "F", value_parser = crate::spec::parse::fraction)]
    pub encoder_frame_fraction: Option<f64>,
    /// --obs vid: width of the frame encoder's hidden layer between its
    /// feature map and the embedding, 0 for none [default: the domain's].
    #[arg(long, value_name = "WIDTH")]
    pub encoder_hidden: Option<usize>,
    /// --obs vid: stage A's Adam learning rate [default: the domain's].
    #[arg(long, value_name = "LR", value_parser = crate::spec::parse::positive_real)]
    pub encoder_lr: Option<f64>,
    /// --obs vid: weight of stage A's frame-reconstruction loss (a decoder
    /// rebuilds each frame from its embedding), 0 for none [default: 0].
    #[arg(long, value_name = "W", value_parser = crate::spec::parse::non_negative)]
    pub encoder_reconstruction: Option<f32>,
    /// --obs vid: the frame encoder reads its last feature map through
    /// spatial-softmax keypoints (`--encoder-keypoints false` to turn them
    /// off) [default: the domain's: on for block stacking, off for object
    /// collection].
    #[arg(long, value_name = "BOOL", num_args = 0..=1, default_missing_value = "true")]
    pub encoder_keypoints: Option<bool>,
    /// --obs vid: stage A shows each keyframe whose next action repeats an
    /// earlier one (a retry after a slip or a missed drop) this many times
    /// per epoch [default: 8 for block stacking's recommended recipe,
    /// else 1].
    #[arg(long, value_name = "R", value_parser = crate::spec::parse::positive)]
    pub encoder_retry_repeats: Option<usize>,
    /// --obs vid: weight of stage A's progress loss (a head reads from each
    /// frame's embedding which of the demo's actions have taken effect,
    /// built from the action labels), 0 for none [default: 0.1 for block
    /// stacking's recommended recipe, else 0].
    #[arg(long, value_name = "W", value_parser = crate::spec::parse::non_negative)]
    pub encoder_progress: Option<f32>,
    /// --obs vid: output channels of a stem convolution (stride 2) before
    /// the frame encoder's three, for frames larger than 64×64 (their
    /// side a multiple of 16), 0 for none [default: 0].
    #[arg(long, value_name = "CHANNELS")]
    pub encoder_stem: Option<usize>,
}

impl TrainFlags {
    /// Whether any `--encoder-*` flag (stage A's settings) is given.
    pub fn sets_the_frame_encoder(&self) -> bool {
        self.encoder_demos.is_some()
            || self.encoder_epochs.is_some()
            || self.encoder_frame_fraction.is_some()
            || self.encoder_hidden.is_some()
            || self.encoder_lr.is_some()
            || self.encoder_reconstruction.is_some()
            || self.encoder_keypoints.is_some()
            || self.encoder_retry_repeats.is_some()
            || self.encoder_progress.is_some()
            || self.encoder_stem.is_some()
    }

    /// Refuses the frame-encoder flags on a run that has no frames.
    pub fn check_encoder_flags(&self) -> anyhow::Result<()> {
        if self.obs == ObsKind::State && self.sets_the_frame_encoder() {
            anyhow::bail!(
                "--encoder-demos, --encoder-epochs, --encoder-frame-fraction, --encoder-hidden, --encoder-lr, \
                 --encoder-reconstruction, --encoder-keypoints, --encoder-retry-repeats, --encoder-progress \
                 and --encoder-stem set the frame encoder of --obs vid runs"
            );
        }
        Ok(())
    }

    /// Overrides `stage`'s settings with the frame-encoder flags given.
    pub fn apply_encoder_flags(&self, stage: &mut crate::video::EncoderStage) {
        stage.demos = self.encoder_demos.unwrap_or(stage.demos);
        stage.epochs = self.encoder_epochs.unwrap_or(stage.epochs);
        stage.frame_fraction = self.encoder_frame_fraction.unwrap_or(stage.frame_fraction);
        stage.hidden = self.encoder_hidden.unwrap_or(stage.hidden);
        stage.learning_rate = self.encoder_lr.unwrap_or(stage.learning_rate);
        stage.reconstruction = self.encoder_reconstruction.unwrap_or(stage.reconstruction);
        stage.spatial_softmax = self.encoder_keypoints.unwrap_or(stage.spatial_softmax);
        stage.retry_repeats = self.encoder_retry_repeats.unwrap_or(stage.retry_repeats);
        stage.progress = self.encoder_progress.unwrap_or(stage.progress);
        stage.stem = self.encoder_stem.unwrap_or(stage.stem);
        stage.shards = self.shards;
    }
}

/// The flags of `ntg eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalFlags {
    /// Where the networks run: the CPU, or a GPU backend compiled in with
    /// `--features wgpu` / `--features cuda`.
    #[arg(long, value_enum, default_value_t = crate::spec::DeviceKind::Cpu)]
    pub device: crate::spec::DeviceKind,
    /// Run folder written by `ntg train`.
    #[arg(long)]
    pub run: PathBuf,
    /// Number of unseen test tasks (blocks: from the start of the standard
    /// test set; collect: test episodes per number of objects).
    #[arg(long, value_parser = crate::spec::parse::positive, default_value_t = 100)]
    pub test_tasks: usize,
    /// Which policy to evaluate (NTG block-stacking runs).
    #[arg(long, value_parser = crate::spec::parse::choice::<Variant>(), default_value_t = Variant::Full)]
    pub variant: Variant,
    /// Keep GCN edges with probability at least this (default: the
    /// model's configured threshold, 0.5; NTG block-stacking runs).
    #[arg(long, value_parser = crate::spec::parse::unit)]
    pub edge_threshold: Option<f32>,
    /// Which tasks to evaluate on (blocks): the test set, or the held-out
    /// validation tasks, where settings such as --edge-threshold can be
    /// chosen without looking at the test set.
    #[arg(long, value_enum, default_value_t = EvalSplit::Test)]
    pub split: EvalSplit,
    /// Evaluate on the tasks of this NTP-format task file instead of a
    /// split (block stacking; the first --test-tasks of them, or all if it
    /// has fewer): a user's own tasks. Tasks with the end configuration of
    /// one of the run's training tasks are named as such.
    #[arg(long, value_name = "FILE", conflicts_with = "split")]
    pub tasks: Option<PathBuf>,
    /// NTP baselines (block stacking): instead of rolling out, check each
    /// decision the network takes against the expert's trace in each
    /// task's rollout scene (teacher forcing), and print, per step of
    /// the program hierarchy, how often it decides as the trace does.
    #[arg(long)]
    pub decisions: bool,
}

impl EvalFlags {
    /// `ntg eval --run RUN --test-tasks N --split SPLIT` with every other
    /// flag at its default (the whole model, on the CPU).
    pub fn of_run(run: &std::path::Path, test_tasks: usize, split: EvalSplit) -> EvalFlags {
        EvalFlags {
            device: crate::spec::DeviceKind::Cpu,
            run: run.to_path_buf(),
            test_tasks,
            variant: Variant::Full,
            edge_threshold: None,
            split,
            tasks: None,
            decisions: false,
        }
    }
}

/// Task sets `ntg eval` can use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EvalSplit {
    /// The standard test set (the reported numbers).
    Test,
    /// The validation tasks (`env_blocks::validation_tasks`).
    Validation,
    /// The run's own training tasks (block stacking), with demos and
    /// scenes it never trained on: whether a method does what it was
    /// trained on.
    Seen,
    /// Block-stacking tasks whose structures (the task once cube names
    /// are ignored) no task of the standard training pool has: the 10
    /// structures with a tower of five or more cubes
    /// (`env_blocks::structure_test_tasks`). Not in the paper.
    Structure,
    /// Runs on the structure benchmark (`--task-set structure`): tasks
    /// whose towers are taller than any training structure's. Not in the
    /// paper.
    Taller,
}

impl EvalSplit {
    /// Its name on the command line (`--split NAME`).
    pub fn name(self) -> &'static str {
        match self {
            EvalSplit::Test => "test",
            EvalSplit::Validation => "validation",
            EvalSplit::Seen => "seen",
            EvalSplit::Structure => "structure",
            EvalSplit::Taller => "taller",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_split_is_named_as_the_command_line_names_it() {
        for split in EvalSplit::value_variants() {
            assert_eq!(split.to_possible_value().unwrap().get_name(), split.name());
        }
    }
}
