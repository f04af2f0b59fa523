//! Task domains, one file each, registered in [`DomainId`]: block stacking
//! ([`blocks`]), object collection ([`collect`]) and object sorting
//! ([`sorting`]). (JIGSAWS is a dataset
//! scored by NLL, not rolled out: see [`crate::jigsaws`].)
//!
//! A domain is a small adapter behind [`Domain`]: its environment and
//! expert, how an observation becomes a row, a task's name and how many of
//! its goals hold. Everything else is shared: [`evaluate`] is the one
//! evaluation loop (every episode records its conditioning demo, conditions
//! any method's model on it and rolls the policy out in another scene, in
//! parallel), and [`crate::fit::fit`] the one training loop.
//!
//! Adding a domain: a new file here implementing [`Domain`] (with its task
//! split, seeds, dataset and run configuration) and [`DomainRuns`] (its
//! `ntg train` / `ntg eval`), and one line in the `domains!` list below.

use std::path::PathBuf;

use anyhow::Context;
use clap::ValueEnum;
use ctg_graph::{Environment, Expert, Vocabulary, record_demonstration};
use serde::{Deserialize, Serialize};

use crate::dataset::{DatasetSpec, DemoDataset, ObsDtype, generate, progress_bar};
use crate::evaluate::in_parallel;
use crate::method::TrainedPolicy;
use crate::method::ntg::Variant;
use crate::run_dir::RunDir;
use crate::spec::ObsKind;
use crate::stats::SuccessRate;

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
    #[arg(long, value_enum, default_value_t = Variant::Full)]
    pub ablation: Variant,
    /// Observation kind.
    #[arg(long, value_enum, default_value_t = ObsKind::State)]
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
    /// Continue the run in --out from its last checkpoint.
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
    }

    /// Refuses the frame-encoder flags on a run that has no frames.
    pub fn check_encoder_flags(&self) -> anyhow::Result<()> {
        if self.obs == ObsKind::State && self.sets_the_frame_encoder() {
            anyhow::bail!(
                "--encoder-demos, --encoder-epochs, --encoder-frame-fraction, --encoder-hidden, --encoder-lr, --encoder-reconstruction, --encoder-keypoints, --encoder-retry-repeats and --encoder-progress set the frame encoder of --obs vid runs"
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
    #[arg(long, value_enum, default_value_t = Variant::Full)]
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
}

/// What the shared loops need to know of a domain.
pub trait Domain: Sync {
    /// A task of the domain.
    type Task: Sync;
    /// Its environment.
    type Env: Environment;
    /// Its scripted expert.
    type Expert: Expert<Self::Env>;
    /// The flat action vocabulary (the CTG's nodes).
    fn vocabulary(&self) -> &Vocabulary;
    /// A fresh environment for `task`.
    fn env(&self, task: &Self::Task) -> anyhow::Result<Self::Env>;
    /// A fresh expert.
    fn expert(&self) -> Self::Expert;
    /// What the networks see.
    fn obs_kind(&self) -> ObsKind;
    /// Values per observation row.
    fn obs_dim(&self) -> usize;
    /// The observation as the networks' flat row.
    fn featurize(&self, observation: &<Self::Env as Environment>::Observation) -> Vec<f32>;
    /// The task's name in records.
    fn task_name(&self, task: &Self::Task) -> String;
    /// How many of the task's goals hold in `env` at the end of an
    /// episode, and how many it has.
    fn goals(&self, task: &Self::Task, env: &Self::Env) -> (usize, usize);
    /// The conditioning demo a policy reads: the expert's demonstration of
    /// `task` recorded with `seed` in `env`, as observation rows, and its
    /// actions. By default one row per CTG node; a domain that records
    /// demo videos gives every frame.
    fn record_demo(
        &self,
        env: &mut Self::Env,
        _task: &Self::Task,
        seed: u64,
    ) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ctg_graph::ActionId>)> {
        record_keyframes(self, env, seed)
    }
}

/// [`Domain::record_demo`]'s default: the expert's demonstration recorded
/// with `seed` in `env`, one featurised row per CTG node, and its actions.
pub fn record_keyframes<D: Domain + ?Sized>(
    domain: &D,
    env: &mut D::Env,
    seed: u64,
) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ctg_graph::ActionId>)> {
    let demo = record_demonstration(env, &mut domain.expert(), seed)?;
    let rows = demo
        .observations()
        .iter()
        .map(|o| domain.featurize(o))
        .collect();
    Ok((rows, demo.actions().to_vec()))
}

/// One evaluation episode: a task, the seed of its conditioning demo and
/// the seed of the scene the policy acts in.
#[derive(Debug, Clone, PartialEq)]
pub struct Episode<T> {
    /// The group the episode is reported in (object collection: the number
    /// of objects N; block stacking: 0).
    pub group: usize,
    /// Index of the episode within its group.
    pub index: usize,
    /// The task.
    pub task: T,
    /// Seed of the expert's conditioning demonstration.
    pub demo_seed: u64,
    /// Seed of the rollout scene.
    pub rollout_seed: u64,
}

/// One evaluated episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// The episode's group (see [`Episode::group`]).
    #[serde(default)]
    pub group: usize,
    /// Index of the episode within its group.
    pub index: usize,
    /// The task.
    pub task: String,
    /// Whether the task was done at the end.
    pub success: bool,
    /// Actions taken (`<end>` included if chosen).
    pub steps: usize,
    /// Goals that held at the end (block stacking: `on_top` constraints;
    /// object collection: objects delivered).
    #[serde(default)]
    pub goals_met: usize,
    /// Goals of the task.
    #[serde(default)]
    pub goals: usize,
    /// The executed actions, by name (empty in committed run records:
    /// [`crate::record`]).
    #[serde(default)]
    pub trace: Vec<String>,
    /// NTG only: the demo interpreter's transcription of the demo.
    #[serde(default)]
    pub transcription: Vec<String>,
    /// The expert's actual actions in the conditioning demo.
    #[serde(default)]
    pub demo_actions: Vec<String>,
    /// Methods with a demo interpreter: whether its transcription is the
    /// demo's action sequence exactly (kept in committed run records,
    /// which drop the sequences themselves; absent in evaluations saved
    /// before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transcribed_exactly: Option<bool>,
}

impl EpisodeRecord {
    /// [`Self::transcribed_exactly`], or where it was not saved, the
    /// comparison of the saved sequences (`None` without a transcription).
    pub fn transcription_exact(&self) -> Option<bool> {
        self.transcribed_exactly.or_else(|| {
            (!self.transcription.is_empty()).then(|| self.transcription == self.demo_actions)
        })
    }
}

/// The fraction of `records`' demos the demo interpreter transcribed
/// exactly, with its 95% Wilson interval, over the records that say
/// ([`EpisodeRecord::transcription_exact`]); `None` if none does.
pub fn transcription_exact_rate<'a>(
    records: impl IntoIterator<Item = &'a EpisodeRecord>,
) -> Option<SuccessRate> {
    let outcomes: Vec<bool> = records
        .into_iter()
        .filter_map(EpisodeRecord::transcription_exact)
        .collect();
    (!outcomes.is_empty()).then(|| SuccessRate::from_outcomes(outcomes))
}

/// Where a method with a demo interpreter failed: in transcribing the demo,
/// or in acting on a right transcription.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TranscriptionSplit {
    /// The fraction of demos transcribed exactly.
    pub exact: SuccessRate,
    /// Success on the episodes whose demo was transcribed exactly.
    pub success_if_exact: SuccessRate,
    /// Success on the others.
    pub success_otherwise: SuccessRate,
}

impl TranscriptionSplit {
    /// The split of `records` ([`EpisodeRecord::transcription_exact`]),
    /// over the records that say; `None` if none does.
    pub fn of(records: &[EpisodeRecord]) -> Option<Self> {
        let said: Vec<(bool, bool)> = records
            .iter()
            .filter_map(|r| r.transcription_exact().map(|e| (e, r.success)))
            .collect();
        (!said.is_empty()).then(|| TranscriptionSplit {
            exact: SuccessRate::from_outcomes(said.iter().map(|&(e, _)| e)),
            success_if_exact: SuccessRate::from_outcomes(
                said.iter().filter(|&&(e, _)| e).map(|&(_, s)| s),
            ),
            success_otherwise: SuccessRate::from_outcomes(
                said.iter().filter(|&&(e, _)| !e).map(|&(_, s)| s),
            ),
        })
    }
}

/// The success rate of `records`, with its 95% Wilson interval.
pub fn success_rate<'a>(records: impl IntoIterator<Item = &'a EpisodeRecord>) -> SuccessRate {
    SuccessRate::from_outcomes(records.into_iter().map(|r| r.success))
}

/// The mean over `records` of the fraction of each task's goals met.
pub fn mean_goal_fraction(records: &[EpisodeRecord]) -> f64 {
    records
        .iter()
        .map(|r| r.goals_met as f64 / r.goals.max(1) as f64)
        .sum::<f64>()
        / records.len().max(1) as f64
}

/// Records `demos_per_task` expert demonstrations of each of `tasks` in
/// parallel (demo `j` of task `t` with seed `seed_base + 1000 t + j`) into
/// a dataset; frames are stored as bytes.
pub fn record_demos<D: Domain>(
    domain: &D,
    tasks: &[D::Task],
    demos_per_task: usize,
    seed_base: u64,
) -> anyhow::Result<DemoDataset> {
    let pairs: Vec<(usize, u64)> = (0..tasks.len())
        .flat_map(|t| (0..demos_per_task).map(move |j| (t, seed_base + 1000 * t as u64 + j as u64)))
        .collect();
    let bar = progress_bar(pairs.len() as u64, "demos");
    generate(
        &pairs,
        |t| domain.env(&tasks[t]),
        || domain.expert(),
        |o| domain.featurize(o),
        DatasetSpec {
            vocabulary: domain.vocabulary().clone(),
            obs_dim: domain.obs_dim(),
            dtype: match domain.obs_kind() {
                ObsKind::State => ObsDtype::F32,
                ObsKind::Vid => ObsDtype::U8,
            },
        },
        &bar,
    )
}

/// The one evaluation loop: for every episode, in parallel, the expert
/// records the conditioning demo in the task's environment, `model` is
/// conditioned on it, and the policy acts greedily in the rollout scene
/// until the episode ends (`<end>` or the step limit).
pub fn evaluate<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episodes: &[Episode<D::Task>],
) -> anyhow::Result<Vec<EpisodeRecord>> {
    let model = model.for_inference();
    in_parallel(episodes, "rollouts", |_, episode| {
        run_episode(domain, model.as_ref(), episode)
    })
}

fn run_episode<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episode: &Episode<D::Task>,
) -> anyhow::Result<EpisodeRecord> {
    run_episode_observed(domain, model, episode, |_| Ok(()))
}

/// One decision of an episode, as [`run_episode_observed`] shows it.
pub struct Decision<'a, E: Environment> {
    /// The observation the agent acted on.
    pub observation: &'a E::Observation,
    /// The action it chose.
    pub action: ctg_graph::ActionId,
    /// What the agent says it was doing (see [`crate::method::Agent::explain`]).
    pub explanation: Option<String>,
    /// What the environment returned.
    pub step: &'a ctg_graph::Step<E::Observation, E::Info>,
}

/// One evaluation episode exactly as [`evaluate`] runs it (`model` must
/// already be the inference model), calling `observe` after every
/// decision: for traces.
pub fn run_episode_observed<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episode: &Episode<D::Task>,
    mut observe: impl FnMut(Decision<'_, D::Env>) -> anyhow::Result<()>,
) -> anyhow::Result<EpisodeRecord> {
    let name = domain.task_name(&episode.task);
    let mut env = domain.env(&episode.task)?;
    let (rows, demo_actions) = domain
        .record_demo(&mut env, &episode.task, episode.demo_seed)
        .with_context(|| format!("demo of task {name}"))?;
    let agent = model.condition(&rows, domain.vocabulary())?;
    let (mut observation, _) = env.reset(episode.rollout_seed)?;
    let mut ties = crate::method::Ties::for_episode(episode.rollout_seed);
    let mut trace = Vec::new();
    loop {
        let action = agent
            .act(&domain.featurize(&observation), &trace, &mut ties)
            .with_context(|| format!("rollout of task {name}"))?;
        trace.push(action);
        let step = env.step(action)?;
        observe(Decision {
            observation: &observation,
            action,
            explanation: agent.explain(),
            step: &step,
        })?;
        let done = step.is_done();
        observation = step.observation;
        if done {
            break;
        }
    }
    let (goals_met, goals) = domain.goals(&episode.task, &env);
    let vocab = domain.vocabulary();
    let names = |ids: &[ctg_graph::ActionId]| -> Vec<String> {
        ids.iter()
            .map(|&a| vocab.name(a).unwrap_or("?").to_owned())
            .collect()
    };
    Ok(EpisodeRecord {
        group: episode.group,
        index: episode.index,
        task: name,
        success: env.is_success(),
        steps: trace.len(),
        goals_met,
        goals,
        trace: names(&trace),
        transcribed_exactly: (!agent.transcription().is_empty())
            .then(|| agent.transcription() == demo_actions.as_slice()),
        transcription: names(agent.transcription()),
        demo_actions: names(&demo_actions),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(transcription: &[&str], demo: &[&str], saved: Option<bool>) -> EpisodeRecord {
        let names = |a: &[&str]| a.iter().map(|s| (*s).to_owned()).collect();
        EpisodeRecord {
            group: 0,
            index: 0,
            task: "t".into(),
            success: false,
            steps: 0,
            goals_met: 0,
            goals: 1,
            trace: Vec::new(),
            transcription: names(transcription),
            demo_actions: names(demo),
            transcribed_exactly: saved,
        }
    }

    #[test]
    fn exact_transcriptions_are_counted_over_the_records_that_say() {
        let records = [
            record(&["a", "b"], &["a", "b"], None),
            record(&["a", "c"], &["a", "b"], None),
            // A committed record: sequences dropped, the verdict kept.
            record(&[], &[], Some(true)),
            // No demo interpreter (NTP): not counted.
            record(&[], &["a"], None),
        ];
        assert_eq!(records[0].transcription_exact(), Some(true));
        assert_eq!(records[1].transcription_exact(), Some(false));
        assert_eq!(records[3].transcription_exact(), None);
        let rate = transcription_exact_rate(&records).unwrap();
        assert_eq!((rate.successes, rate.trials), (2, 3));
        let mut records = records.to_vec();
        records[0].success = true;
        let split = TranscriptionSplit::of(&records).unwrap();
        assert_eq!((split.exact.successes, split.exact.trials), (2, 3));
        let (hit, miss) = (split.success_if_exact, split.success_otherwise);
        assert_eq!((hit.successes, hit.trials), (1, 2));
        assert_eq!((miss.successes, miss.trials), (0, 1));
        assert!(transcription_exact_rate(&records[3..]).is_none());
    }
}
