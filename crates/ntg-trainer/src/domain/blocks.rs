//! The block-stacking experiment (the paper's fig. "ntp_exp"): datasets from
//! the standard task split, training, and evaluation on unseen tasks.
//!
//! Seeds: training demo `j` of pool task `i` is recorded with seed
//! `TRAIN_SEED_BASE + 1000 i + j`; for test task `i`, the conditioning demo
//! uses `DEMO_SEED_BASE + i` and the rollout `ROLLOUT_SEED_BASE + i`, so the
//! policy acts in a scene it has not seen in the demo. Validation task `i`
//! (see `env_blocks::validation_tasks`) uses `VALIDATION_DEMO_SEED_BASE + i`
//! and `VALIDATION_ROLLOUT_SEED_BASE + i` in the same way.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use burn::tensor::Device;
use clap::ValueEnum;
use ctg_graph::{ActionId, record_demonstration};
use env_blocks::{BlocksEnv, BlocksExpert, BlocksObservation, EnvConfig, StackTask};
use ntg_model::{NtgConfig, NtgModel, NtgPolicy};
use serde::{Deserialize, Serialize};

use crate::dataset::DemoDataset;
use crate::domain::{
    self, Domain, DomainFlags, DomainRuns, Episode, EpisodeRecord, EvalFlags, TrainFlags,
};
use crate::fit::{OptimConfig, PAPER_LEARNING_RATE, ValidationScore};
use crate::method::detector::DetectorSettings;
use crate::method::input::{Renaming, Validation};
pub use crate::method::ntg::Variant;
use crate::method::ntp::{EncodeRows, NtpDataset, NtpRenaming, PrimitiveInput, PrimitiveLevel};
use crate::method::on_frames::{NtgBased, VideoNtgModel};
use crate::method::{Demos, EpochReport, MethodId, Model, RowEncoders, TrainInput};
use crate::run_dir::RunDir;
pub use crate::spec::ObsKind;
use crate::stats::SuccessRate;
use crate::symmetry::{ObjectSymmetry, RenamingFilter};
use crate::video::{EncoderStage, VideoRun};

/// Seed base of training demonstrations.
pub const TRAIN_SEED_BASE: u64 = 10_000_000;
/// Seed base of the conditioning demonstration of each test task.
pub const DEMO_SEED_BASE: u64 = 20_000_000;
/// Seed base of the rollout scene of each test task.
pub const ROLLOUT_SEED_BASE: u64 = 30_000_000;
/// Seed base of the conditioning demonstration of each validation task.
pub const VALIDATION_DEMO_SEED_BASE: u64 = 40_000_000;
/// Seed base of the rollout scene of each validation task.
pub const VALIDATION_ROLLOUT_SEED_BASE: u64 = 50_000_000;
/// Seed base of the conditioning demonstration of each seen (training)
/// task evaluated by `ntg eval --split seen` (never a training demo's).
pub const SEEN_DEMO_SEED_BASE: u64 = 60_000_000;
/// Seed base of the rollout scene of each seen task so evaluated.
pub const SEEN_ROLLOUT_SEED_BASE: u64 = 70_000_000;

pub use crate::block_world::{encoder, env_config, featurize, obs_dim};

/// Everything that defines a block-stacking training run (`config.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BlocksRunConfig {
    /// Observation kind.
    pub obs: ObsKind,
    /// Number of training tasks (a prefix of the standard training pool).
    pub train_tasks: usize,
    /// Expert demonstrations per training task.
    pub demos_per_task: usize,
    /// Stochastic failures in training demonstrations and evaluation.
    pub failures: bool,
    /// Seed of the model's initial weights.
    pub model_seed: u64,
    /// Hidden layers of the node localizer's and edge classifier's state
    /// encoder MLPs (the demo interpreter keeps one; ignored for video).
    #[serde(default = "one")]
    pub state_hidden_layers: usize,
    /// The localizer's and edge classifier's state encoders also read every
    /// pairwise difference of cube positions (see
    /// `StateEncoderConfig::pairwise_objects`).
    #[serde(default)]
    pub pairwise: bool,
    /// Held-out validation tasks (`env_blocks::validation_tasks`, disjoint
    /// from the training pool and the test set) scored after every epoch;
    /// the best epoch's weights are the run's result. 0 = keep the last
    /// epoch.
    #[serde(default)]
    pub validation_tasks: usize,
    /// Validate after every this many epochs (and after the last); 0 or 1 =
    /// every epoch.
    #[serde(default)]
    pub validate_every: usize,
    /// Train on demos whose cubes are renamed by a random permutation per
    /// demo and step (state observations only; see [`object_symmetry`]).
    /// Not in the paper.
    #[serde(default)]
    pub permute_objects: bool,
    /// With `permute_objects`: never train on a renaming that turns a
    /// training task into a held-out one (any of the 1000 test tasks or the
    /// first [`HELD_OUT_VALIDATION_TASKS`] validation tasks); such renamings
    /// are drawn again. Without it about one renamed demo in 2000 is a test
    /// task under another name. Runs saved before it: false.
    #[serde(default)]
    pub exclude_held_out_renamings: bool,
    /// Hidden width of the edge classifier's fusion layer (see
    /// `EdgeClassifierConfig::fusion_hidden`); 0 = the paper's linear `W`.
    #[serde(default)]
    pub edge_fusion_hidden: usize,
    /// Edge-loss weight of recovery steps (see
    /// `TrainExtras::retry_weight`); 0 or 1 = unweighted.
    #[serde(default)]
    pub retry_weight: f32,
    /// Keep the edge classifier's loss out of the GCN (see
    /// `TrainExtras::detach_gcn_from_edges`). Not in the paper.
    #[serde(default)]
    pub detach_gcn_from_edges: bool,
    /// Soft edges (see `NtgConfig::soft_edges`): the policy weighs the edge
    /// classifier's scores by the completed graph's edge probabilities
    /// instead of cutting them to the graph thresholded at 0.5, and the
    /// classifier is trained the same way (softmax over every node).
    #[serde(default)]
    pub soft_edges: bool,
    /// The part of NTG this run is trained and evaluated without (fig.
    /// "ablation" (a); [`Variant::trains`]): `full` = none. The switch is
    /// in the model's configuration, so every evaluation of the run keeps
    /// it. Runs saved before it: full.
    #[serde(default, skip_serializing_if = "Variant::is_full")]
    pub ablation: Variant,
    /// Video runs (`obs: vid`): how demo videos are recorded and the
    /// staged training's encoder stage (see [`crate::video`]). `None` on
    /// state runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<BlocksVideo>,
    /// The method trained: NTG, or an NTP baseline (which reads only
    /// `obs`, the task and demo counts, `failures`, `model_seed`,
    /// `state_hidden_layers`, `pairwise`, `validation_tasks`,
    /// `validate_every`, the renaming fields and `optim`). Runs saved
    /// before it: NTG.
    #[serde(default, skip_serializing_if = "MethodId::is_ntg")]
    pub method: MethodId,
    /// NTP (Detector) runs: how its detector is trained (before NTP, in the
    /// run's `detector_stage/` folder). `None` for every other method.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<DetectorSettings>,
    /// The NTP family's core network (`--ntp-core`): reactive (the
    /// design's default; every run saved before it) or the recurrent GRU
    /// variant. Read by NTP, NTP Flat and NTP (Detector) only.
    #[serde(default, skip_serializing_if = "NtpCoreKind::is_reactive")]
    pub ntp_core: NtpCoreKind,
    /// The task set (`--tasks FILE`): an NTP task file, such as NTP's own
    /// `stack_2000.json`, split by the standard rule ([`task_split`]);
    /// `None`: the generated stand-in set (`datasets/blocks/stack_2000.json`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tasks: Option<PathBuf>,
    /// The structure benchmark's task set (`--task-set structure`, not
    /// with `tasks`): training tasks of its training structures,
    /// validation tasks of its validation structures, test tasks of its
    /// test structures ([`TaskSource::Structure`]). Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub structure_benchmark: bool,
    /// NTG on states: the policy's current node is the last action the
    /// agent executed (`ntg_model::AblationConfig::executed_node`, not in
    /// the paper), not the node localizer's reading of the state. Training
    /// is the same; model selection and evaluation roll out with it. On
    /// video the same switch is `video.executed_node`. Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub executed_node: bool,
    /// State runs: the state encoders that read pairwise cube offsets (the
    /// node localizer's, the edge classifier's, the NTP family's) read
    /// every height (gripper-relative and between two cubes) only as far
    /// as this many metres (`ntg_model::StateEncoderConfig::height_clamp`;
    /// `--state-height-clamp`). Below two cube sizes it keeps "on" from
    /// "further above", and a tower taller than any trained on reads
    /// as the same relations a trained one has. Not in the paper. Absent:
    /// heights read as they are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state_height_clamp: Option<f32>,
    /// NTG: an execution memory (`--memory`, as object collection's): the
    /// edge classifier also reads the nodes of the task graph the agent
    /// has not executed yet (`ntg_model::pending_nodes`), so that a scene
    /// that looks finished is not taken for one while the demo's actions
    /// are pending. Not in the paper's block stacking. Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub memory: bool,
    /// NTG: the policy may choose `<end>` only once every action of the
    /// demo's transcription has been executed, where the current node
    /// leads elsewhere too (`--end-after-demo`;
    /// `ntg_model::AblationConfig::end_after_demo`). A symbolic rule, not
    /// in the paper; training is the same, model selection and evaluation
    /// roll out with it. Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub end_after_demo: bool,
    /// NTG's demo interpreter (`--interpreter`; absent: the paper's Luong
    /// interpreter, as in every run saved before it). Read by NTG only.
    /// `"luong"` reads as absent, so that a figure's panel can pin the
    /// paper's interpreter under a recipe that sets another.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "luong_is_absent"
    )]
    pub interpreter: Option<crate::method::ntg::InterpreterKind>,
    /// With a stepping interpreter: the initial weight of its location-aware
    /// attention's forward shifts (`--location-step-prior`; absent: none).
    /// `0` reads as absent, as `--location-step-prior 0` does.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "zero_is_absent"
    )]
    pub location_step_prior: Option<f32>,
    /// Optimisation.
    pub optim: OptimConfig,
}

impl BlocksRunConfig {
    /// Where the run's tasks come from.
    pub fn task_source(&self) -> TaskSource<'_> {
        match (&self.tasks, self.structure_benchmark) {
            (_, true) => TaskSource::Structure,
            (Some(file), false) => TaskSource::File(file),
            (None, false) => TaskSource::Standard,
        }
    }

    /// The run's task set in words, for messages.
    pub fn task_source_name(&self) -> String {
        match self.task_source() {
            TaskSource::Standard => "standard task set".into(),
            TaskSource::File(path) => format!("task file {}", path.display()),
            TaskSource::Structure => "structure benchmark".into(),
        }
    }

    /// The camera the run's frames are rendered with: its video settings'
    /// (the standard 64×64 camera on state runs, which render none).
    pub fn camera(&self) -> env_blocks::Camera {
        match (&self.video, &self.detector) {
            (Some(v), _) => v.camera,
            (None, Some(d)) => d.camera,
            (None, None) => Default::default(),
        }
    }
}

/// `ntg train --domain blocks --task-set`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TaskSetKind {
    /// The generated stand-in for NTP's task set, split by the standard rule.
    Standard,
    /// The structure benchmark (`env_blocks::structure`).
    Structure,
}

/// `ntg train --domain blocks --node-source`: where NTG's policy takes its
/// current node from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NodeSource {
    /// The node localizer's reading of the observation (the paper's
    /// policy).
    Localizer,
    /// The last action the agent executed (not in the paper).
    Executed,
}

/// Where a block-stacking run's training, validation and test tasks come
/// from ([`BlocksRunConfig::task_source`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskSource<'a> {
    /// The generated stand-in for NTP's task set
    /// (`datasets/blocks/stack_2000.json`), split by the standard rule.
    Standard,
    /// An NTP task file (`--tasks FILE`), split by the standard rule.
    File(&'a Path),
    /// The structure benchmark (`--task-set structure`,
    /// `env_blocks::structure`): training, validation and test tasks of
    /// disjoint structures, and taller towers (`ntg eval --split taller`).
    Structure,
}

/// Seeds of the structure benchmark's task draws: training pool, test,
/// validation, taller (each set drawn once from its own).
const STRUCTURE_TASK_SEEDS: [u64; 4] = [61_000, 61_001, 61_002, 61_003];

/// Tasks of the structure benchmark's training pool and of its test set.
pub const STRUCTURE_TASKS: usize = env_blocks::TRAIN_POOL;

/// The structure benchmark of the committed seed.
pub fn structure_benchmark() -> env_blocks::structure::StructureBenchmark {
    env_blocks::structure::StructureBenchmark::new(env_blocks::structure::STRUCTURE_BENCHMARK_SEED)
}

/// `count` tasks of the structure benchmark's taller set (a tower of five
/// cubes or more, taller than any training structure's).
pub fn taller_tasks(count: usize) -> anyhow::Result<Vec<StackTask>> {
    Ok(structure_benchmark().tasks(
        env_blocks::structure::StructureSet::Taller,
        count,
        STRUCTURE_TASK_SEEDS[3],
    )?)
}

/// The first `count` tasks of the structure benchmark's `set` as a run on
/// it sees them: its training pool's, its test tasks, its validation
/// tasks, or its taller towers.
pub fn task_set_tasks(
    set: env_blocks::structure::StructureSet,
    count: usize,
) -> anyhow::Result<Vec<StackTask>> {
    use env_blocks::structure::StructureSet;
    let split = task_split(TaskSource::Structure)?;
    let first = |tasks: &[StackTask]| -> anyhow::Result<Vec<StackTask>> {
        tasks
            .get(..count)
            .map(<[StackTask]>::to_vec)
            .with_context(|| {
                format!(
                    "asked for {count} tasks of the {} set; it has {}",
                    set.name(),
                    tasks.len()
                )
            })
    };
    match set {
        StructureSet::Train => first(&split.train_pool),
        StructureSet::Test => first(&split.test),
        StructureSet::Validation => validation_tasks_of(TaskSource::Structure, count),
        StructureSet::Taller => taller_tasks(count),
    }
}

/// The outcomes of an evaluation on the structure benchmark's `set`,
/// grouped by structure: `(towers, successes)` per structure in
/// structure-key order, `towers` its tower heights (`"2+3"`), `successes`
/// its tasks' outcomes in the evaluation's order. `records` must be the
/// first `records.len()` tasks of the set, as a run on the benchmark
/// scores them ([`task_set_tasks`]); an error names the first that is not.
pub fn outcomes_by_structure(
    set: env_blocks::structure::StructureSet,
    records: &[EpisodeRecord],
) -> anyhow::Result<Vec<(String, Vec<bool>)>> {
    use std::collections::BTreeMap;
    let tasks = task_set_tasks(set, records.len())?;
    /// A structure's tower heights and its tasks' outcomes.
    type Outcomes = (String, Vec<bool>);
    let mut by_key: BTreeMap<Vec<(usize, usize)>, Outcomes> = BTreeMap::new();
    for (record, task) in records.iter().zip(&tasks) {
        anyhow::ensure!(
            record.task == task.id,
            "task {} where the structure benchmark's {} set has {}",
            record.task,
            set.name(),
            task.id
        );
        let towers = task
            .towers()
            .iter()
            .map(|t| t.len().to_string())
            .collect::<Vec<_>>()
            .join("+");
        by_key
            .entry(task.structure_key())
            .or_insert_with(|| (towers, Vec::new()))
            .1
            .push(record.success);
    }
    Ok(by_key.into_values().collect())
}

/// The task split of `source`: the standard stand-in split, or a file's
/// tasks split by the same rule (its first [`env_blocks::TRAIN_POOL`]
/// tasks are the training pool, `n` training tasks its first `n`, the rest
/// the test tasks), or the structure benchmark's training pool and test
/// set ([`STRUCTURE_TASKS`] each). Read once per process.
pub fn task_split(source: TaskSource<'_>) -> anyhow::Result<Arc<env_blocks::StandardSplit>> {
    use std::collections::BTreeMap;
    use std::sync::Mutex;
    /// A task file (or none), and whether the structure benchmark.
    type Key = (Option<PathBuf>, bool);
    static SPLITS: Mutex<BTreeMap<Key, Arc<env_blocks::StandardSplit>>> =
        Mutex::new(BTreeMap::new());
    let key = match source {
        TaskSource::Standard => (None, false),
        TaskSource::File(path) => (Some(path.to_path_buf()), false),
        TaskSource::Structure => (None, true),
    };
    if let Some(split) = SPLITS.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
        return Ok(split.clone());
    }
    let split = match source {
        TaskSource::Standard => env_blocks::standard_split()?,
        TaskSource::Structure => {
            use env_blocks::structure::StructureSet;
            let benchmark = structure_benchmark();
            env_blocks::StandardSplit {
                train_pool: benchmark.tasks(
                    StructureSet::Train,
                    STRUCTURE_TASKS,
                    STRUCTURE_TASK_SEEDS[0],
                )?,
                test: benchmark.tasks(
                    StructureSet::Test,
                    STRUCTURE_TASKS,
                    STRUCTURE_TASK_SEEDS[1],
                )?,
            }
        }
        TaskSource::File(path) => {
            let mut tasks = env_blocks::read_ntp_tasks(path)?;
            if tasks.len() <= env_blocks::TRAIN_POOL {
                bail!(
                    "{}: {} tasks; the split takes the first {} as the training pool and the rest as test tasks, so it needs more",
                    path.display(),
                    tasks.len(),
                    env_blocks::TRAIN_POOL
                );
            }
            let test = tasks.split_off(env_blocks::TRAIN_POOL);
            env_blocks::StandardSplit {
                train_pool: tasks,
                test,
            }
        }
    };
    let split = Arc::new(split);
    SPLITS
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(key, split.clone());
    Ok(split)
}

/// `count` validation tasks of `source`: drawn as
/// `env_blocks::validation_tasks` draws them, outside every end
/// configuration of the task set; for the structure benchmark, tasks of
/// its validation structures (which no training or test task has).
pub fn validation_tasks_of(source: TaskSource<'_>, count: usize) -> anyhow::Result<Vec<StackTask>> {
    Ok(match source {
        TaskSource::Standard => env_blocks::validation_tasks(count)?,
        TaskSource::Structure => structure_benchmark().tasks(
            env_blocks::structure::StructureSet::Validation,
            count,
            STRUCTURE_TASK_SEEDS[2],
        )?,
        TaskSource::File(_) => {
            let split = task_split(source)?;
            let all: Vec<StackTask> = split
                .train_pool
                .iter()
                .chain(&split.test)
                .cloned()
                .collect();
            env_blocks::validation_tasks_avoiding(count, &all)?
        }
    })
}

/// How a block-stacking video run records its demos and trains its encoder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BlocksVideo {
    /// Frames per phase of each primitive's motion.
    pub frames: env_blocks::VideoConfig,
    /// The camera every frame of the run is rendered with: demo videos,
    /// stage A's frames, validation and test rollouts (absent in runs
    /// saved before it: the standard 64×64).
    #[serde(default, skip_serializing_if = "is_standard_camera")]
    pub camera: env_blocks::Camera,
    /// Stage A: the shared frame encoder.
    pub encoder: EncoderStage,
    /// Cube renaming for frames (not in the paper): a task's demos are
    /// recorded in groups of this many, the first group on the task itself
    /// and every other group on the task with its cubes renamed by a
    /// seeded permutation (a cube's colour follows its name; never onto a
    /// held-out configuration). Each renamed group is its own task for the
    /// GCN's target graph. 0 = no renaming.
    pub demos_per_renaming: usize,
    /// The demo interpreter reads the video's frame embeddings averaged in
    /// windows of this many frames (`DemoInterpreterConfig::frame_pool`;
    /// 1 = every frame, as runs saved before it).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub interpreter_frame_pool: usize,
    /// The policy takes its current node from its own record, the last
    /// action it executed, instead of the node localizer's reading of the
    /// frame (not in the paper; `ntg_model::AblationConfig::executed_node`;
    /// `ntg eval --variant localizer-node` scores the localizer's way).
    /// Absent in runs saved before it: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub executed_node: bool,
    /// NTG's node localizer reads the frame of the agent's previous
    /// decision beside the current one, `[o_t, o_t − o_{t−1}]` on their
    /// frame embeddings (not in the paper; temporal context,
    /// `ntg_model::NodeLocalizerConfig::previous_observation`). Absent in
    /// runs saved before it: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub localizer_previous_frame: bool,
    /// What stage A's frame encoder is trained to tell apart in NTP's and
    /// NTP Flat's video runs (NTG's always reads flat actions). Absent in
    /// runs saved before it: [`FrameLabels::Flat`].
    #[serde(default, skip_serializing_if = "FrameLabels::is_flat")]
    pub encoder_labels: FrameLabels,
}

/// The labels stage A's frame encoder is trained on (`--encoder-labels`).
///
/// NTG acts once per flat action (`pick(X)`, `place(Y)`), on the scene
/// after it; its stage A labels every frame with the flat action under way
/// (the localizer's node) and the next one (the edge classifier's), so the
/// frames inside a `place(Y)` (the cube carried above `Y`) and the scene
/// after it (the cube released) share their labels, and the encoder is
/// trained to map them alike. NTP acts once per primitive: after
/// `move(Y)` it must `drop`, after `drop` return, and those are exactly
/// the two scenes. With [`FrameLabels::Primitive`], NTP's and NTP Flat's
/// encoder is trained instead on the frames NTP acts on (the scene before
/// each primitive and the last), labelled with NTP's own lowest-level
/// supervision: the primitive just taken and the next.
pub use crate::method::ntp::FrameLabels;
pub use crate::method::ntp::NtpCoreKind;

fn is_one(n: &usize) -> bool {
    *n == 1
}

fn is_standard_camera(c: &env_blocks::Camera) -> bool {
    *c == env_blocks::Camera::default()
}

impl BlocksVideo {
    /// The recommended settings (renaming in groups of 4 demos) or the
    /// paper's (no renaming). Either way stage A's encoder starts from He
    /// initialisation on centred frames and trains at 3e-3: chosen on the
    /// held-out keyframe localization of validation-task videos (5000
    /// training videos, 2 epochs: 0.43 with PyTorch's default
    /// initialisation at 1e-3, 0.54 with He and centring, 0.62 also at
    /// 3e-3; 1e-2 diverged; a 256-wide hidden layer learned slower;
    /// `docs/results/video-2026-11-24.md`). Its last feature map is read
    /// through spatial-softmax keypoints, chosen on validation tasks too:
    /// held-out keyframes 0.663 against 0.603 (3000 videos, 4 epochs),
    /// and at 1000 tasks x 20 demos 0.872 against 0.749 after stage A and
    /// NTG's validation success far above the 0.08 without (same file).
    ///
    /// Stage A's scale: up to 20,000 training videos (demo 0 of every task
    /// first), their keyframes and 15% of their other frames, 3 epochs: the
    /// 1000 x 20 settings of `docs/results/video-2026-11-24.md` (keyframes
    /// 0.749 at 20,000 x 3 against 0.510 at 1 epoch on the old camera).
    ///
    /// The recommended recipe adds, all chosen on validation tasks (same
    /// file, Sessions 16 and 17): retry keyframes shown 8 times per epoch
    /// and the progress head at weight 0.1 (3000 videos: validation success
    /// 0.305 without the head, 0.450 with it), the interpreter reading
    /// frames averaged in windows of 4 (1000 x 20, 200 validation tasks:
    /// every frame 0.595, pairs 0.625; with the changes here pairs 0.860
    /// and 4 0.845, paired 8 tasks won to 5, a tie, and a stage B step
    /// 1.23x the state path's instead of 1.62x, idle bench), and the
    /// policy's current node taken from the agent's record (200 validation
    /// tasks, 1000 x 20: 0.595 -> 0.675, 0.625 -> 0.710 and 0.785 -> 0.825
    /// on three runs).
    pub fn new(recommended: bool) -> Self {
        BlocksVideo {
            frames: env_blocks::VideoConfig::default(),
            camera: env_blocks::Camera::default(),
            encoder: EncoderStage {
                demos: 20_000,
                epochs: 3,
                frame_fraction: 0.15,
                he_init: true,
                centre_input: true,
                learning_rate: 3e-3,
                spatial_softmax: true,
                retry_repeats: if recommended { 8 } else { 1 },
                progress: if recommended { 0.1 } else { 0.0 },
                ..EncoderStage::default()
            },
            demos_per_renaming: if recommended { 4 } else { 0 },
            interpreter_frame_pool: if recommended { 4 } else { 1 },
            executed_node: recommended,
            localizer_previous_frame: false,
            encoder_labels: FrameLabels::Flat,
        }
    }
}

fn one() -> usize {
    1
}

/// [`BlocksRunConfig::interpreter`] read with the paper's interpreter
/// named (`"luong"`) taken for the absent field that means it: one
/// configuration, one serialisation.
fn luong_is_absent<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> Result<Option<crate::method::ntg::InterpreterKind>, D::Error> {
    use crate::method::ntg::InterpreterKind;
    let kind = Option::<InterpreterKind>::deserialize(deserializer)?;
    Ok(kind.filter(|&kind| kind != InterpreterKind::Luong))
}

/// [`BlocksRunConfig::location_step_prior`] read with a prior of 0 (no
/// prior) taken for the absent field that means it.
fn zero_is_absent<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> Result<Option<f32>, D::Error> {
    let prior = Option::<f32>::deserialize(deserializer)?;
    Ok(prior.filter(|&w| w != 0.0))
}

/// A set of training choices for block stacking: what `ntg train` starts
/// from (`--recipe`). (`ntg reproduce`'s figure keeps its own
/// configuration, see `experiments/ntp_exp.toml`.)
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Recipe {
    /// ntg-rs's recommended recipe: the paper's networks trained with lr
    /// 3e-3 decayed along a cosine, 3-layer state encoders that also read
    /// pairwise cube differences, an edge-classifier fusion layer of 256,
    /// the GCN reading another demo than the one imitated (on video also
    /// kept out of the edge loss), soft edges, and on state input cube
    /// renaming that never renames a training task into a held-out one,
    /// the policy's node from the executed actions, `<end>` only once the
    /// demo's actions are executed, and the stepping interpreter taught
    /// one demo row per action. Measured on states, 1000 tasks x 100
    /// demos, 30 epochs, seed 0: 0.989 success on 1000 unseen tasks
    /// (README).
    Recommended,
    /// Only what the paper describes: lr 1e-3, constant; one-layer state
    /// encoders on raw positions; nothing added.
    Paper,
}

impl Recipe {
    /// The recipe's name, as `--recipe` and the experiment files write it.
    pub fn name(self) -> &'static str {
        match self {
            Recipe::Recommended => "recommended",
            Recipe::Paper => "paper",
        }
    }

    /// The run configuration of this recipe for `obs` on `train_tasks` x
    /// `demos_per_task` demos (failures on), trained `epochs` epochs with
    /// weights and shuffling from `seed`, selected on 100 validation tasks.
    pub fn config(
        self,
        obs: ObsKind,
        train_tasks: usize,
        demos_per_task: usize,
        epochs: usize,
        seed: u64,
    ) -> BlocksRunConfig {
        let recommended = self == Recipe::Recommended;
        BlocksRunConfig {
            obs,
            train_tasks,
            demos_per_task,
            failures: true,
            model_seed: seed,
            state_hidden_layers: if recommended { 3 } else { 1 },
            pairwise: recommended,
            validation_tasks: 100,
            validate_every: 1,
            // Frames carry no column per cube to rename.
            permute_objects: recommended && obs == ObsKind::State,
            exclude_held_out_renamings: recommended && obs == ObsKind::State,
            edge_fusion_hidden: if recommended { 256 } else { 0 },
            retry_weight: 0.0,
            // On states the GCN also learns from the edge loss: chosen on
            // the structure benchmark's validation structures (0.972 against
            // 0.933 detached, mean best validation success of seeds 0-2)
            // and no lower on the standard split (0.971 against 0.955 at
            // 1000 tasks x 100 demos; docs/results/
            // structure-benchmark-2026-12-06.md). Video keeps it detached
            // until the choice is made there too.
            detach_gcn_from_edges: recommended && obs == ObsKind::Vid,
            soft_edges: recommended,
            ablation: Variant::Full,
            video: (obs == ObsKind::Vid).then(|| BlocksVideo::new(recommended)),
            method: MethodId::Ntg,
            detector: None,
            ntp_core: NtpCoreKind::Reactive,
            tasks: None,
            structure_benchmark: false,
            // On states, three more choices of the structure benchmark's
            // validation structures, each against the recipe before it by
            // a rule fixed before its runs (mean over seeds 0-2 of 600
            // validation tasks; experiments/structure.toml): the policy's
            // node from the actions it executed (0.985 against the
            // localizer's 0.963), `<end>` only once the demo's actions are
            // executed (1763 of 1800 against 1761), and the stepping
            // interpreter taught one demo row per action (1785 against
            // 1763). No lower on the standard split: 0.989 (0.980-0.994)
            // against 0.971 at 1000 tasks x 100 demos (docs/results/
            // structure-taller-2026-12-07.md). None is the paper's policy,
            // and each is named in a figure's row.
            executed_node: recommended && obs == ObsKind::State,
            state_height_clamp: None,
            memory: false,
            end_after_demo: recommended && obs == ObsKind::State,
            interpreter: (recommended && obs == ObsKind::State)
                .then_some(crate::method::ntg::InterpreterKind::SteppingAligned),
            location_step_prior: (recommended && obs == ObsKind::State)
                .then_some(crate::method::ntg::DEFAULT_LOCATION_STEP_PRIOR),
            optim: OptimConfig {
                epochs,
                batch_size: 32,
                learning_rate: if recommended {
                    3e-3
                } else {
                    PAPER_LEARNING_RATE
                },
                seed,
                token_dropout: 0.0,
                cosine_decay: recommended,
                shards: 1,
                gcn_from_other_demo: recommended,
            },
        }
    }
}

impl Recipe {
    /// `config` (a configuration of this recipe, made for NTG) turned into
    /// `method`'s. A method with a detector stage (NTP (Detector)) reads no
    /// demo video (its demo is one frame per primitive) and trains its
    /// detector (default settings unless `config` has some); its NTP reads
    /// state rows, whose cubes this recipe renames as on state input.
    pub fn for_method(self, mut config: BlocksRunConfig, method: MethodId) -> BlocksRunConfig {
        config.method = method;
        // What only NTG's policy and interpreter read is NTG's part of
        // the recipe.
        let ntg = method.method();
        config.executed_node &= ntg.reads("executed_node");
        config.end_after_demo &= ntg.reads("end_after_demo");
        if !ntg.reads("interpreter") {
            config.interpreter = None;
            config.location_step_prior = None;
        }
        if method.method().reads("detector") {
            let renames = self == Recipe::Recommended;
            config.permute_objects |= renames;
            config.exclude_held_out_renamings |= renames;
            // The detector renders its frames with the video settings'
            // camera, and reads them through their stem; nothing else of
            // them (stage A) is its.
            let video = config.video.take();
            let detector = config
                .detector
                .get_or_insert_with(DetectorSettings::default);
            if let Some(video) = video {
                detector.camera = video.camera;
                detector.stem = detector
                    .stem
                    .or((video.encoder.stem > 0).then_some(video.encoder.stem));
            }
        }
        config
    }
}

/// What the run `config` adds to the paper's recipe, each as a figure row
/// names it: every setting in which `config` differs from the paper
/// recipe's configuration of the same method, input, tasks, demos, epochs
/// and seed, read from the whole configuration (a setting without a name
/// here is named `key = value`, so none goes unnamed). The ablation and
/// the method are named by the row itself; the thread layout (`shards`)
/// does not change what is trained, and `exclude_held_out_renamings` only
/// filters cube renaming, which is named.
pub fn additions(config: &BlocksRunConfig) -> Vec<String> {
    let skipped = [
        "ablation",
        "method",
        "optim.shards",
        "video.encoder.shards",
        "exclude_held_out_renamings",
    ];
    differing_settings(config, Recipe::Paper)
        .into_iter()
        .filter(|(key, _)| !skipped.contains(&key.as_str()))
        .map(|(key, v)| addition_name(&key, &v))
        .collect()
}

/// The settings (`(dotted.key, value)`, in key order) in which `config`
/// differs from `recipe`'s configuration of the same method, input, tasks,
/// demos, epochs and seed.
fn differing_settings(
    config: &BlocksRunConfig,
    recipe: Recipe,
) -> Vec<(String, serde_json::Value)> {
    let theirs = recipe_settings(config, recipe);
    let mut ours = Vec::new();
    flatten_json(
        "",
        &serde_json::to_value(config).unwrap_or_default(),
        &mut ours,
    );
    ours.into_iter()
        .filter(|(key, v)| theirs.iter().find(|(k, _)| k == key).map(|(_, w)| w) != Some(v))
        .collect()
}

/// Where a run of the recommended recipe was trained with another choice
/// than the recipe now makes, each as a figure row names it: the recipe's
/// own settings (not the scale, input or perception a panel sets) in which
/// `config` differs from `Recipe::Recommended`'s configuration of the same
/// method, input, tasks, demos, epochs and seed. A run trained before the
/// recipe changed keeps the choice it was trained with, and its row says
/// so. Settings NTP's networks do not have (the GCN's and the edge
/// classifier's) are left out for the baselines. Empty for the paper's
/// recipe, whose every difference is an addition ([`additions`]).
pub fn recipe_changes(config: &BlocksRunConfig, recipe: Recipe) -> Vec<String> {
    if recipe == Recipe::Paper {
        return Vec::new();
    }
    let ntg_only = [
        "detach_gcn_from_edges",
        "soft_edges",
        "edge_fusion_hidden",
        "optim.gcn_from_other_demo",
        "interpreter",
        "location_step_prior",
        "executed_node",
        "end_after_demo",
    ];
    let recipe_keys = [
        "state_hidden_layers",
        "pairwise",
        "permute_objects",
        "retry_weight",
        "optim.learning_rate",
        "optim.cosine_decay",
        "optim.token_dropout",
        "video.demos_per_renaming",
        "video.interpreter_frame_pool",
    ];
    let of_recipe = |key: &str| {
        recipe_keys.contains(&key) || (config.method.is_ntg() && ntg_only.contains(&key))
    };
    // The executed node and the `<end>` rule, where a run has them, are
    // named with its curve (`executed node`, `ends only after ...`).
    let named_with_curve = |key: &str, v: &serde_json::Value| {
        matches!(key, "executed_node" | "end_after_demo") && *v == serde_json::Value::Bool(true)
    };
    let mut changes: Vec<(String, String)> = differing_settings(config, recipe)
        .into_iter()
        .filter(|(key, v)| of_recipe(key) && !named_with_curve(key, v))
        .map(|(key, v)| {
            let name = match v {
                serde_json::Value::Bool(false) => recipe_setting_off(&key),
                v => addition_name(&key, &v),
            };
            (key, name)
        })
        .collect();
    // What the recipe now sets and the run has not at all (saved without
    // the field: off, or the paper's choice).
    let mut ours = Vec::new();
    flatten_json(
        "",
        &serde_json::to_value(config).unwrap_or_default(),
        &mut ours,
    );
    let interpreter_absent = config.interpreter.is_none();
    for (key, _) in recipe_settings(config, recipe) {
        let absent = !ours.iter().any(|(k, _)| *k == key);
        // Without a stepping interpreter there is no step prior to name.
        let implied = key == "location_step_prior" && interpreter_absent;
        if absent && !implied && of_recipe(&key) {
            let name = recipe_setting_off(&key);
            changes.push((key, name));
        }
    }
    changes.sort_by(|a, b| a.0.cmp(&b.0));
    changes.into_iter().map(|(_, name)| name).collect()
}

/// The recipe's configuration of `config`'s method, input, scale and seed,
/// as `(dotted.key, value)` leaves.
fn recipe_settings(config: &BlocksRunConfig, recipe: Recipe) -> Vec<(String, serde_json::Value)> {
    let own = recipe.for_method(
        recipe.config(
            config.obs,
            config.train_tasks,
            config.demos_per_task,
            config.optim.epochs,
            config.model_seed,
        ),
        config.method,
    );
    let mut leaves = Vec::new();
    flatten_json(
        "",
        &serde_json::to_value(&own).unwrap_or_default(),
        &mut leaves,
    );
    leaves
}

/// How a row names a run without the recipe's setting `key` (off, or the
/// paper's choice where the setting is not a switch).
fn recipe_setting_off(key: &str) -> String {
    match key {
        "executed_node" | "video.executed_node" => "localizer choosing the node".into(),
        "end_after_demo" => "may end before the demo's actions".into(),
        "interpreter" => "the paper's interpreter".into(),
        "location_step_prior" => "no location step prior".into(),
        _ => format!(
            "without {}",
            addition_name(key, &serde_json::Value::Bool(true))
        ),
    }
}

/// Every setting of `config` that says how a run trained, as a figure row
/// would name it (`(dotted.key, name)`, in key order): what tells two
/// curves of one method and input apart where their runs differ in a
/// setting. The scale (tasks, demos, epochs), the seeds, the method and
/// the thread layout are left out: a curve's points differ in those.
pub fn named_settings(config: &BlocksRunConfig) -> Vec<(String, String)> {
    let skipped = [
        "ablation",
        "method",
        "model_seed",
        "train_tasks",
        "demos_per_task",
        "optim.seed",
        "optim.epochs",
        "optim.shards",
        "video.encoder.shards",
    ];
    let mut settings = Vec::new();
    flatten_json(
        "",
        &serde_json::to_value(config).unwrap_or_default(),
        &mut settings,
    );
    settings
        .into_iter()
        .filter(|(key, _)| !skipped.contains(&key.as_str()))
        .map(|(key, v)| {
            let name = addition_name(&key, &v);
            (key, name)
        })
        .collect()
}

/// The leaves of `value` as `(dotted.key, value)`, in key order.
fn flatten_json(
    prefix: &str,
    value: &serde_json::Value,
    out: &mut Vec<(String, serde_json::Value)>,
) {
    match value {
        serde_json::Value::Object(map) => {
            for (k, v) in map {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten_json(&key, v, out);
            }
        }
        leaf => out.push((prefix.to_owned(), leaf.clone())),
    }
}

/// How a figure row names the setting `key` at `value` (see [`additions`]).
fn addition_name(key: &str, value: &serde_json::Value) -> String {
    // Numbers to six decimals: an `f32` setting reads as it was written.
    let v = match value {
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Number(n) if !n.is_i64() && !n.is_u64() => {
            let x = n.as_f64().unwrap_or(f64::NAN);
            format!("{:?}", (x * 1e6).round() / 1e6)
        }
        other => other.to_string(),
    };
    match key {
        "permute_objects" => "cube renaming".into(),
        "state_hidden_layers" => format!("{v}-layer state encoders"),
        "pairwise" => "pairwise cube offsets".into(),
        "edge_fusion_hidden" => format!("edge fusion layer ({v})"),
        "retry_weight" => format!("retry weight {v}"),
        "detach_gcn_from_edges" => "GCN detached from the edge loss".into(),
        "soft_edges" => "soft edges".into(),
        "validate_every" => format!("validated every {v} epochs"),
        "validation_tasks" => format!("{v} validation tasks"),
        "tasks" => format!("task set {v}"),
        "structure_benchmark" => "structure benchmark's task set".into(),
        "interpreter" if v == "stepping-aligned" => {
            "stepping interpreter, attention taught one demo row per action".to_owned()
        }
        "interpreter" if v == "stepping-video-aligned" => {
            "stepping interpreter, attention taught the frame each action ends on".to_owned()
        }
        "interpreter" => format!("{v} interpreter"),
        "location_step_prior" => format!("location step prior {v}"),
        "optim.learning_rate" => format!("learning rate {v}"),
        "optim.cosine_decay" => "cosine learning-rate decay".into(),
        "optim.gcn_from_other_demo" => "GCN reads another demo".into(),
        "optim.token_dropout" => format!("token dropout {v}"),
        "video.demos_per_renaming" => format!("video cube renaming in groups of {v}"),
        "executed_node" | "video.executed_node" => "executed node (not the localizer)".into(),
        "state_height_clamp" => format!("heights read to {v} m"),
        "memory" => "execution memory".into(),
        "end_after_demo" => "ends only after the demo's actions".into(),
        "video.interpreter_frame_pool" => format!("interpreter frame pooling {v}"),
        "video.localizer_previous_frame" => "localizer reads the previous frame".into(),
        "video.encoder_labels" => format!("stage A labels {v}"),
        "ntp_core" if v == "gru" => "recurrent (GRU) core".into(),
        "ntp_core" => format!("{v} core"),
        "video.encoder.retry_repeats" => format!("retry frames x{v} in stage A"),
        "video.encoder.progress" => format!("progress head {v}"),
        "video.camera.size" | "detector.camera.size" => format!("camera {v}x{v} px"),
        "video.camera.framing" | "detector.camera.framing" => format!("{v} camera framing"),
        "detector.stem" => format!("detector stem of {v} channels"),
        "video.encoder.stem" => format!("encoder stem of {v} channels"),
        _ => match key.strip_prefix("video.encoder.") {
            Some(k) => format!("stage A {k} = {v}"),
            None => format!("{key} = {v}"),
        },
    }
}

/// Records the training demonstrations of a run, in parallel.
pub fn build_dataset(config: &BlocksRunConfig, tasks: &[StackTask]) -> anyhow::Result<DemoDataset> {
    let domain = BlocksDomain::new(config.obs, config.failures).with_camera(config.camera());
    let tasks = tasks.get(..config.train_tasks).with_context(|| {
        format!(
            "{} training tasks asked for, {} given",
            config.train_tasks,
            tasks.len()
        )
    })?;
    domain::record_demos(&domain, tasks, config.demos_per_task, TRAIN_SEED_BASE)
}

/// The untrained model of a block-stacking run (seeded by
/// `config.model_seed`).
pub fn new_model(config: &BlocksRunConfig, device: &Device) -> anyhow::Result<NtgModel> {
    let vocab = flat_vocabulary();
    let mut model_config = NtgConfig::for_domain(vocab.len(), encoder(config.obs, 1, false));
    // The localizer and edge classifier judge a single observation, so
    // relations between cubes (is something on the cube under the
    // gripper?) must come from their encoders. The demo interpreter has its
    // GRU on top of its encoder and keeps the plain one-layer MLP: with the
    // relational input it fit its training demos as well but transcribed
    // unseen ones worse (held-out token accuracy 0.73 against 0.98 at 1000
    // tasks x 20 demos).
    model_config.localizer.encoder = observation_encoder(config);
    model_config.edge.encoder = observation_encoder(config);
    if config.edge_fusion_hidden > 0 {
        model_config.edge.fusion_hidden = Some(config.edge_fusion_hidden);
    }
    if config.soft_edges {
        model_config.soft_edges = Some(true);
    }
    if config.executed_node || config.video.as_ref().is_some_and(|v| v.executed_node) {
        model_config.ablation.executed_node = Some(true);
    }
    if config.memory {
        model_config.edge.memory_dim = Some(vocab.len());
    }
    if let Some(kind) = config.interpreter {
        kind.apply(&mut model_config.interpreter, config.location_step_prior);
    }
    if let Some(pool) = config.video.as_ref().map(|v| v.interpreter_frame_pool)
        && pool > 1
    {
        model_config.interpreter.frame_pool = Some(pool);
    }
    if config
        .video
        .as_ref()
        .is_some_and(|v| v.localizer_previous_frame)
    {
        if let ntg_model::EncoderConfig::State(c) = &mut model_config.localizer.encoder {
            c.input_dim *= 2;
        }
        model_config.localizer.previous_observation = Some(true);
    }
    let executed_node = model_config.ablation.executed_node;
    model_config.ablation = config.ablation.ablation();
    model_config.ablation.executed_node = executed_node;
    model_config.ablation.end_after_demo = config.end_after_demo.then_some(true);
    model_config.seed = config.model_seed;
    Ok(NtgModel::new(model_config, device)?)
}

/// The encoder of the networks that judge one observation (NTG's node
/// localizer and edge classifier, the NTP family's core): the block
/// world's [`encoder`] with the run's layers and pairwise offsets, heights
/// clamped where the run asks ([`BlocksRunConfig::state_height_clamp`],
/// state runs only).
pub fn observation_encoder(config: &BlocksRunConfig) -> ntg_model::EncoderConfig {
    let encoder = encoder(config.obs, config.state_hidden_layers, config.pairwise);
    match (encoder, config.state_height_clamp) {
        (ntg_model::EncoderConfig::State(state), Some(limit)) if config.obs == ObsKind::State => {
            ntg_model::EncoderConfig::State(
                state
                    .with_height_clamp(Some(limit))
                    .with_clamped_objects(Some(env_blocks::world::NUM_OBJECTS)),
            )
        }
        (encoder, _) => encoder,
    }
}

/// A trained block-stacking model: NTG on state rows, or on frames.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one value per run; never in a collection
pub enum TrainedBlocks {
    /// State observations.
    State(NtgModel),
    /// Demo videos and frames (staged training).
    Video(VideoNtgModel),
}

impl TrainedBlocks {
    /// Evaluates the model on `tasks` (see [`evaluate_tasks`]).
    pub fn evaluate_tasks(
        &self,
        failures: bool,
        camera: env_blocks::Camera,
        tasks: &[StackTask],
        seeds: Seeds,
        variant: Variant,
    ) -> anyhow::Result<EvalResult> {
        match self {
            TrainedBlocks::State(m) => {
                evaluate_tasks(m, ObsKind::State, failures, camera, tasks, seeds, variant)
            }
            TrainedBlocks::Video(m) => {
                evaluate_tasks(m, ObsKind::Vid, failures, camera, tasks, seeds, variant)
            }
        }
    }

    /// Evaluates the model on the first `test_tasks` unseen tasks of the
    /// task set `tasks` ([`task_split`]).
    pub fn evaluate(
        &self,
        tasks: TaskSource<'_>,
        failures: bool,
        camera: env_blocks::Camera,
        test_tasks: usize,
        variant: Variant,
    ) -> anyhow::Result<EvalResult> {
        let split = task_split(tasks)?;
        self.evaluate_tasks(
            failures,
            camera,
            test_tasks_of(&split, test_tasks)?,
            Seeds::TEST,
            variant,
        )
    }

    /// The NTG networks.
    pub fn ntg(&self) -> &NtgModel {
        match self {
            TrainedBlocks::State(m) => m,
            TrainedBlocks::Video(m) => &m.policy,
        }
    }

    /// The NTG networks, to change their evaluation settings.
    pub fn ntg_mut(&mut self) -> &mut NtgModel {
        match self {
            TrainedBlocks::State(m) => m,
            TrainedBlocks::Video(m) => &mut m.policy,
        }
    }
}

/// Trains (or resumes) a block-stacking run in `run` with the method its
/// configuration names, returning the model: the domain provides the
/// vocabulary, the demos (state rows, or the frame embeddings of its demo
/// videos behind a frozen stage A, [`crate::video`]), the encoders, cube
/// renaming, validation on held-out tasks and, for the NTP family, the
/// primitive level ([`BlocksPrimitive`]); the method trains.
pub fn train_model(
    run: &RunDir,
    config: &BlocksRunConfig,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    // One writer from the first cache this run builds (demos, frame
    // embeddings, stages) to its last epoch, not only during epochs.
    let _writer = run.lock()?;
    let json = serde_json::to_value(config)?;
    config.method.method().check(&json)?;
    check_encoder_labels(config)?;
    check_ntp_core(config)?;
    check_executed_node(config)?;
    check_state_height_clamp(config)?;
    check_memory(config)?;
    check_end_after_demo(config)?;
    check_interpreter_input(config)?;
    let split = task_split(config.task_source())?;
    let tasks = split.train(config.train_tasks)?;
    let demos = || -> anyhow::Result<Demos> {
        match config.obs {
            ObsKind::State => {
                let dataset = DemoDataset::load_or_build(&run.dataset_dir(), || {
                    build_dataset(config, tasks)
                })?;
                Ok(Demos {
                    dataset,
                    frames: None,
                })
            }
            ObsKind::Vid => with_video_run(config, |_, video_run, _| {
                let frames = crate::video::train_encoder(run, video_run, device)?;
                let dataset = crate::video::embeddings(run, video_run, &frames)?;
                Ok(Demos {
                    dataset,
                    frames: Some(frames),
                })
            }),
        }
    };
    // The primitive level holds what NTG's training shares with NTP's: the
    // validation tasks and the filter of held-out renamings.
    let level = BlocksPrimitive::new(config)?;
    let (validation, accept) = (level.validation.clone(), level.accept.clone());
    let primitive = PrimitiveInput(Box::new(level));
    let symmetry = object_symmetry();
    // Cube renaming is for state rows; a video run renames cubes in its
    // demo videos instead (`BlocksVideo::demos_per_renaming`).
    let renaming = (config.permute_objects && config.obs == ObsKind::State).then(|| Renaming {
        symmetry: &symmetry,
        accept: accept.as_deref().map(|f| f as RenamingFilter<'_>),
    });
    let domain = BlocksDomain::new(config.obs, config.failures).with_camera(config.camera());
    let score = |model: &dyn crate::method::TrainedPolicy| {
        let result = evaluate_on(&domain, model, "full", &validation, Seeds::VALIDATION)?;
        Ok(validation_result(&result))
    };
    let vocabulary = flat_vocabulary();
    let input = TrainInput {
        vocabulary: &vocabulary,
        demos: &demos,
        encoders: RowEncoders {
            sequence: encoder(config.obs, 1, false),
            observation: observation_encoder(config),
        },
        renaming,
        validation: (!validation.is_empty()).then_some(Validation {
            score: &score,
            every: config.validate_every,
        }),
        other_demo_each_epoch: false,
        model_seed: config.model_seed,
        optim: &config.optim,
        run,
        device,
        extension: Some(&primitive),
    };
    config.method.method().train(input, &json, &mut on_epoch)
}

/// Trains (or resumes) an NTG run of block stacking (see [`train_model`]).
pub fn train_run(
    run: &RunDir,
    config: &BlocksRunConfig,
    device: &Device,
    on_epoch: impl FnMut(&EpochReport),
) -> anyhow::Result<TrainedBlocks> {
    if !config.method.is_ntg() {
        bail!(
            "{} is not NTG: train it with train_model",
            config.method.legend()
        );
    }
    let model = train_model(run, config, device, on_epoch)?;
    let any = model.as_any();
    if let Some(m) = any.downcast_ref::<NtgModel>() {
        return Ok(TrainedBlocks::State(m.clone()));
    }
    any.downcast_ref::<VideoNtgModel>()
        .map(|m| TrainedBlocks::Video(m.clone()))
        .context("NTG trained on block stacking is NTG on states or on frames")
}

/// `task` with cube `i` renamed `perm[i]`.
pub fn renamed_task(task: &StackTask, perm: &[usize]) -> StackTask {
    StackTask {
        id: task.id.clone(),
        goals: task
            .goals
            .iter()
            .map(|g| env_blocks::Goal {
                src: perm[g.src],
                target: perm[g.target],
            })
            .collect(),
    }
}

/// The renaming of group `group` of `task`'s demos: the identity for group
/// 0, else a permutation drawn from `(task index, group)` that does not
/// rename the task into a held-out configuration.
fn group_renaming(
    task: &StackTask,
    index: usize,
    group: usize,
    held_out: &HeldOutConfigurations,
) -> Vec<usize> {
    use rand::seq::SliceRandom;
    let mut perm: Vec<usize> = (0..env_blocks::world::NUM_OBJECTS).collect();
    if group == 0 {
        return perm;
    }
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(
        0x00C0_10E5 ^ ((index as u64) << 20) ^ group as u64,
    );
    loop {
        perm.shuffle(&mut rng);
        if !held_out.contains_renamed(task, &perm) {
            return perm;
        }
    }
}

/// The demo video of `task` with `seed` (failures as `failures` says),
/// its frames featurised (CHW in `[0, 1]`).
pub fn record_video(
    task: StackTask,
    failures: bool,
    camera: env_blocks::Camera,
    frames: &env_blocks::VideoConfig,
    seed: u64,
) -> anyhow::Result<ctg_graph::VideoDemonstration<Vec<f32>>> {
    let v = env_blocks::record_video_demo(
        env_blocks::BlocksTask::Stack(task),
        env_config(ObsKind::Vid, failures).with_camera(camera),
        seed,
        frames,
    )?;
    Ok(v.map_frames(|f| env_collect::frame_to_chw(&f)))
}

/// `(validation task, seed)` of the one demo video recorded per validation
/// task (the first `tasks` of `env_blocks::validation_tasks`).
pub fn validation_video_pairs(tasks: usize) -> Vec<(usize, u64)> {
    (0..tasks)
        .map(|i| (i, VALIDATION_DEMO_SEED_BASE + i as u64))
        .collect()
}

/// A block-stacking video run's training videos: demo `j` of training task
/// `t` is recorded (seed as the state path's demos) on the task with its
/// cubes renamed by its group's renaming (group `j / demos_per_renaming`,
/// see [`BlocksVideo::demos_per_renaming`]), and is *virtual task*
/// `t * groups + group` (each renamed group is its own task).
pub struct VideoPlan {
    tasks: Vec<StackTask>,
    groups: usize,
    demos_per_renaming: usize,
    held_out: HeldOutConfigurations,
}

impl VideoPlan {
    /// The plan of `config` (a video run).
    pub fn new(config: &BlocksRunConfig, video: &BlocksVideo) -> anyhow::Result<Self> {
        let split = task_split(config.task_source())?;
        let tasks = split.train(config.train_tasks)?.to_vec();
        let groups = match video.demos_per_renaming {
            0 => 1,
            g => config.demos_per_task.div_ceil(g),
        };
        Ok(VideoPlan {
            tasks,
            groups,
            demos_per_renaming: video.demos_per_renaming,
            held_out: HeldOutConfigurations::new(config.task_source())?,
        })
    }

    /// `(virtual task, seed)` of every training demo, demo 0 of every task
    /// first, then demo 1, ...
    pub fn pairs(&self, demos_per_task: usize) -> Vec<(usize, u64)> {
        (0..demos_per_task)
            .flat_map(|j| {
                let group = j.checked_div(self.demos_per_renaming).unwrap_or(0);
                (0..self.tasks.len()).map(move |t| {
                    (
                        t * self.groups + group,
                        TRAIN_SEED_BASE + 1000 * t as u64 + j as u64,
                    )
                })
            })
            .collect()
    }

    /// The task (renamed) that virtual task `virtual_task` records.
    pub fn task(&self, virtual_task: usize) -> StackTask {
        let (t, group) = (virtual_task / self.groups, virtual_task % self.groups);
        let perm = group_renaming(&self.tasks[t], t, group, &self.held_out);
        renamed_task(&self.tasks[t], &perm)
    }
}

/// Builds the demo videos of the video run `config` (training videos as
/// [`VideoPlan`] says, one video per validation task) and stage A's
/// settings into a [`VideoRun`], and hands it to `train`.
fn with_video_run<R>(
    config: &BlocksRunConfig,
    train: impl FnOnce(&VideoPlan, &VideoRun<'_>, &[StackTask]) -> anyhow::Result<R>,
) -> anyhow::Result<R> {
    let video = config
        .video
        .clone()
        .context("a video run's configuration needs its `video` settings")?;
    video.frames.validate()?;
    let plan = VideoPlan::new(config, &video)?;
    let record = |virtual_task: usize, seed: u64| {
        record_video(
            plan.task(virtual_task),
            config.failures,
            video.camera,
            &video.frames,
            seed,
        )
    };
    let validation = validation_tasks_of(config.task_source(), config.validation_tasks)?;
    let record_validation = |i: usize, seed: u64| {
        record_video(
            validation[i].clone(),
            config.failures,
            video.camera,
            &video.frames,
            seed,
        )
    };
    let vocab = flat_vocabulary();
    let video_run = VideoRun {
        vocabulary: &vocab,
        pairs: plan.pairs(config.demos_per_task),
        record: &record,
        frame_dim: video.camera.frame_dim(),
        encoder: &video.encoder,
        seed: config.model_seed,
        validation: Some(crate::video::ValidationVideos {
            pairs: validation_video_pairs(validation.len()),
            record: &record_validation,
        }),
    };
    train(&plan, &video_run, &validation)
}

/// The score of a validation evaluation (printed by `fit`).
fn validation_result(result: &EvalResult) -> ValidationScore {
    ValidationScore {
        success: result.success.rate,
        goal_fraction: result.mean_goal_fraction,
    }
}

/// Block stacking's primitive level, as the NTP family trains on it
/// ([`PrimitiveLevel`]): the expert's primitive-level episodes of the run's
/// training tasks (the tasks and seeds of NTG's demos), its frame encoder
/// and detector stages, and validation acting at the primitive level.
pub struct BlocksPrimitive {
    config: BlocksRunConfig,
    tasks: Arc<Vec<StackTask>>,
    validation: Arc<Vec<StackTask>>,
    accept: Option<OwnedFilter>,
}

/// A renaming filter that owns what it reads (see [`RenamingFilter`]).
type OwnedFilter = Arc<dyn Fn(usize, &[usize]) -> bool + Send + Sync>;

impl BlocksPrimitive {
    /// The primitive level of the run `config`.
    pub fn new(config: &BlocksRunConfig) -> anyhow::Result<Self> {
        let split = task_split(config.task_source())?;
        let tasks = Arc::new(split.train(config.train_tasks)?.to_vec());
        let accept = HeldOutConfigurations::for_run(config)?.map(|held_out| {
            let tasks = tasks.clone();
            Arc::new(move |task: usize, perm: &[usize]| {
                !held_out.contains_renamed(&tasks[task], perm)
            }) as OwnedFilter
        });
        let validation = validation_tasks_of(config.task_source(), config.validation_tasks)?;
        Ok(BlocksPrimitive {
            validation: Arc::new(validation),
            config: config.clone(),
            tasks,
            accept,
        })
    }
}

impl PrimitiveLevel for BlocksPrimitive {
    fn obs(&self) -> ObsKind {
        self.config.obs
    }

    fn encoder(&self, on_frames: bool) -> ntg_model::EncoderConfig {
        let c = &self.config;
        match on_frames {
            false => observation_encoder(&BlocksRunConfig {
                obs: ObsKind::State,
                ..c.clone()
            }),
            true => encoder(ObsKind::Vid, c.state_hidden_layers, false),
        }
    }

    fn state_episodes(&self) -> anyhow::Result<NtpDataset> {
        let env = env_config(ObsKind::State, self.config.failures);
        NtpDataset::record(
            &self.tasks,
            self.config.demos_per_task,
            TRAIN_SEED_BASE,
            env,
            |o| featurize(o, ObsKind::State),
        )
    }

    fn renaming(&self) -> Option<NtpRenaming<'_>> {
        self.config.permute_objects.then(|| NtpRenaming {
            symmetry: ObjectSymmetry {
                action_families: Vec::new(),
                ..object_symmetry()
            },
            accept: self.accept.as_deref().map(|f| f as RenamingFilter<'_>),
        })
    }

    fn frame_encoder(
        &self,
        labels: FrameLabels,
        run: &RunDir,
        device: &Device,
    ) -> anyhow::Result<ntg_model::FrameStageNet> {
        let config = &self.config;
        with_video_run(config, |plan, video_run, validation| match labels {
            FrameLabels::Flat => crate::video::train_encoder(run, video_run, device),
            FrameLabels::Primitive => {
                let vocab = primitive_vocabulary();
                let camera = config.camera();
                let record = |virtual_task: usize, seed: u64| {
                    record_primitive_video(plan.task(virtual_task), config.failures, camera, seed)
                };
                let record_validation = |i: usize, seed: u64| {
                    record_primitive_video(validation[i].clone(), config.failures, camera, seed)
                };
                let primitive_run = VideoRun {
                    vocabulary: &vocab,
                    record: &record,
                    validation: Some(crate::video::ValidationVideos {
                        pairs: validation_video_pairs(validation.len()),
                        record: &record_validation,
                    }),
                    pairs: video_run.pairs.clone(),
                    frame_dim: video_run.frame_dim,
                    encoder: video_run.encoder,
                    seed: video_run.seed,
                };
                crate::video::train_encoder(run, &primitive_run, device)
            }
        })
    }

    fn frame_episodes(
        &self,
        run: &RunDir,
        encode: EncodeRows<'_>,
        what: &str,
    ) -> anyhow::Result<NtpDataset> {
        let config = &self.config;
        // The demo videos' (renamed) tasks and seeds, or without videos
        // the training tasks and NTG's demo seeds.
        let plan = match &config.video {
            Some(video) => Some(VideoPlan::new(config, video)?),
            None => None,
        };
        let pairs = match &plan {
            Some(plan) => plan.pairs(config.demos_per_task),
            None => NtpDataset::pairs(self.tasks.len(), config.demos_per_task, TRAIN_SEED_BASE),
        };
        let task = |t: usize| match &plan {
            Some(plan) => plan.task(t),
            None => self.tasks[t].clone(),
        };
        // Cached with what `encode` makes of a fixed frame, so another
        // encoder's rows are never read.
        let probe = encode(&[vec![0.5; config.camera().frame_dim()]])?.concat();
        NtpDataset::load_or_build_in_parts(
            &run.root().join(crate::method::ntp::NTP_FRAMES_DIR),
            &probe,
            &pairs,
            crate::method::ntp::NTP_PART_EPISODES,
            |pairs, part| {
                record_ntp_frames(
                    pairs,
                    task,
                    env_config(ObsKind::Vid, config.failures).with_camera(config.camera()),
                    &format!("{what}{part}"),
                    encode,
                )
            },
        )
    }

    fn detector(
        &self,
        settings: &DetectorSettings,
        run: &RunDir,
        device: &Device,
    ) -> anyhow::Result<ntg_model::Detector> {
        train_ntp_detector(run, &self.config, settings, &self.tasks, device)
    }

    fn score(&self, model: &dyn crate::method::TrainedPolicy) -> anyhow::Result<ValidationScore> {
        let c = &self.config;
        let result = evaluate_ntp_tasks(
            model,
            c.obs,
            c.failures,
            c.camera(),
            &self.validation,
            Seeds::VALIDATION,
        )?;
        Ok(validation_result(&result))
    }
}

/// Refuses NTP's primitive frame labels ([`FrameLabels::Primitive`]) for a
/// method that does not read them (NTG's stage A reads flat actions, NTP
/// (Detector) reads frames through its detector).
fn check_encoder_labels(config: &BlocksRunConfig) -> anyhow::Result<()> {
    let primitive = config
        .video
        .as_ref()
        .is_some_and(|v| v.encoder_labels == FrameLabels::Primitive);
    if primitive && !config.method.method().reads("video.encoder_labels") {
        bail!(
            "video.encoder_labels = \"primitive\" (--encoder-labels) trains the frame encoder of NTP and NTP Flat on NTP's primitives; {} does not read it",
            config.method.legend()
        );
    }
    Ok(())
}

/// Refuses NTP's recurrent core ([`NtpCoreKind::Gru`]) for a method
/// without NTP's core.
fn check_ntp_core(config: &BlocksRunConfig) -> anyhow::Result<()> {
    if !config.ntp_core.is_reactive() && !config.method.method().reads("ntp_core") {
        bail!(
            "ntp_core = \"gru\" (--ntp-core) sets NTP's core network; {} has none",
            config.method.legend()
        );
    }
    Ok(())
}

/// Refuses the state runs' executed node ([`BlocksRunConfig::executed_node`])
/// on video, whose switch is `video.executed_node`, and for a method
/// without NTG's policy.
fn check_executed_node(config: &BlocksRunConfig) -> anyhow::Result<()> {
    if !config.executed_node {
        return Ok(());
    }
    if config.obs != ObsKind::State {
        bail!(
            "executed_node = true is the state runs' switch; a video run takes its node source from video.executed_node"
        );
    }
    if !config.method.method().reads("executed_node") {
        bail!(
            "executed_node = true sets where NTG's policy takes its current node; {} has no node localizer",
            config.method.legend()
        );
    }
    Ok(())
}

/// Refuses an execution memory ([`BlocksRunConfig::memory`]) for a method
/// whose networks read none.
fn check_memory(config: &BlocksRunConfig) -> anyhow::Result<()> {
    if config.memory && !config.method.method().reads("memory") {
        bail!(
            "memory = true gives NTG's edge classifier the task-graph nodes not yet executed; {} has no edge classifier",
            config.method.legend()
        );
    }
    Ok(())
}

/// Refuses the `<end>` rule ([`BlocksRunConfig::end_after_demo`]) for a
/// method without a demo transcription to wait for.
fn check_end_after_demo(config: &BlocksRunConfig) -> anyhow::Result<()> {
    if config.end_after_demo && !config.method.method().reads("end_after_demo") {
        bail!(
            "end_after_demo = true keeps NTG's policy from ending before the demo's actions are executed; {} has no demo interpreter",
            config.method.legend()
        );
    }
    Ok(())
}

/// Refuses an interpreter that reads state demos only
/// ([`crate::method::ntg::InterpreterKind::states_only`]) on a video run.
fn check_interpreter_input(config: &BlocksRunConfig) -> anyhow::Result<()> {
    if let Some(kind) = config.interpreter
        && kind.states_only()
        && config.obs != ObsKind::State
    {
        bail!(
            "interpreter = \"{}\" trains its attention one demo row per action, as state demos have; a video run's demos span several frames per action (interpreter = \"stepping-video-aligned\" is taught the frame each action ends on)",
            ntg_train::spec::Choice::name(kind)
        );
    }
    Ok(())
}

/// Refuses a height clamp ([`BlocksRunConfig::state_height_clamp`]) that is
/// not a positive number of metres, or on video, whose frames have no
/// heights to clamp.
fn check_state_height_clamp(config: &BlocksRunConfig) -> anyhow::Result<()> {
    let Some(limit) = config.state_height_clamp else {
        return Ok(());
    };
    if !(limit.is_finite() && limit > 0.0) {
        bail!("state_height_clamp must be a positive number of metres, got {limit}");
    }
    if config.obs != ObsKind::State {
        bail!("state_height_clamp = {limit} applies to state rows; a video run reads frames");
    }
    Ok(())
}

/// NTP's primitive-level vocabulary for block stacking: `move(X)`,
/// `grasp`, `drop`.
pub fn primitive_vocabulary() -> ctg_graph::Vocabulary {
    env_blocks::vocabulary(false, env_blocks::ActionLevel::Primitive)
}

/// The expert episode of `task` with `seed` at NTP's primitive level as a
/// "video" of the frames NTP acts on: segment 0 the first frame, segment
/// `i + 1` the scene after primitive `i`, one frame each (every frame a
/// keyframe), actions in [`primitive_vocabulary`]. What stage A trains on
/// with [`FrameLabels::Primitive`]; the same episodes and frames as NTP's
/// training rows ([`ntp_video_dataset`]).
pub fn record_primitive_video(
    task: StackTask,
    failures: bool,
    camera: env_blocks::Camera,
    seed: u64,
) -> anyhow::Result<ctg_graph::VideoDemonstration<Vec<f32>>> {
    let task = env_blocks::BlocksTask::Stack(task);
    let env = env_config(ObsKind::Vid, failures).with_camera(camera);
    let demo = env_blocks::record_ntp_demo(&task, env, seed)
        .with_context(|| format!("NTP demo of task {} (seed {seed})", task.id()))?;
    let segments = demo
        .observations
        .iter()
        .map(|o| vec![featurize(o, ObsKind::Vid)])
        .collect();
    Ok(ctg_graph::VideoDemonstration::from_segments(
        segments,
        demo.actions,
        &primitive_vocabulary(),
    )?)
}

/// NTP's training episodes on frames: the training demos `pairs` of `plan`
/// (virtual task, seed; `plan.pairs`) recorded at the primitive level
/// (with the failure model if `failures`), each episode's frame before
/// each primitive and its last frame encoded by `frames`' frozen encoder;
/// the progress bar labelled `what`.
pub fn ntp_video_dataset(
    plan: &VideoPlan,
    pairs: &[(usize, u64)],
    failures: bool,
    camera: env_blocks::Camera,
    frames: &ntg_model::FrameStageNet,
    what: &str,
) -> anyhow::Result<NtpDataset> {
    let net = burn::module::Module::valid(frames);
    record_ntp_frames(
        pairs,
        |t| plan.task(t),
        env_config(ObsKind::Vid, failures).with_camera(camera),
        what,
        |rows| crate::method::on_frames::encode_rows(&net, rows),
    )
}

/// NTP's training episodes `pairs` (task index, seed) of the tasks `task`
/// gives, recorded at the primitive level on frames, each episode's frame
/// rows mapped by `encode` (an encoder's embeddings, a detector's estimated
/// states). Recorded in parallel chunks and mapped as they come, so frames
/// are never all held at once.
fn record_ntp_frames(
    pairs: &[(usize, u64)],
    task: impl Fn(usize) -> StackTask + Sync,
    env: EnvConfig,
    what: &str,
    encode: impl Fn(&[Vec<f32>]) -> anyhow::Result<Vec<Vec<f32>>>,
) -> anyhow::Result<NtpDataset> {
    use rayon::prelude::*;
    let bar = crate::dataset::progress_bar(pairs.len() as u64, what);
    let mut episodes = Vec::with_capacity(pairs.len());
    for chunk in pairs.chunks(256) {
        let recorded = chunk
            .par_iter()
            .map(|&(t, seed)| {
                let task = env_blocks::BlocksTask::Stack(task(t));
                let demo = env_blocks::record_ntp_demo(&task, env, seed)
                    .with_context(|| format!("NTP demo of task {t} (seed {seed})"))?;
                let rows: Vec<Vec<f32>> = demo
                    .observations
                    .iter()
                    .map(|o| featurize(o, ObsKind::Vid))
                    .collect();
                Ok((t, rows, demo.root))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        for (task, rows, trace) in recorded {
            let rows = encode(&rows)?;
            episodes.push(crate::method::ntp::NtpEpisode { task, rows, trace });
        }
        bar.inc(chunk.len() as u64);
    }
    bar.finish_and_clear();
    Ok(NtpDataset::new(episodes))
}

/// The detector stage of an NTP (Detector) run: frames of
/// `config.detector.episodes` primitive-level expert episodes of the
/// training tasks (their first demos are NTP's own training episodes),
/// the epoch selected on one episode of each of the first validation
/// tasks, scored on one of each of the next.
pub fn train_ntp_detector(
    run: &RunDir,
    config: &BlocksRunConfig,
    settings: &DetectorSettings,
    tasks: &[StackTask],
    device: &Device,
) -> anyhow::Result<ntg_model::Detector> {
    use crate::method::detector::{DetectorDataset, DetectorFrames, train_detector};
    settings.validate()?;
    let env = env_config(ObsKind::Vid, config.failures).with_camera(config.camera());
    let validation = validation_tasks_of(config.task_source(), 2 * settings.validation_tasks)?;
    let (select, report) = validation.split_at(settings.validation_tasks);
    let frames = || {
        Ok(DetectorFrames {
            train: DetectorDataset::record_spread(tasks, settings.episodes, TRAIN_SEED_BASE, env)?,
            select: DetectorDataset::record(select, 1, VALIDATION_DEMO_SEED_BASE, env)?,
            report: DetectorDataset::record(report, 1, VALIDATION_DEMO_SEED_BASE + 1, env)?,
        })
    };
    train_detector(
        run,
        frames,
        settings,
        config.train_tasks,
        config.failures,
        config.model_seed,
        config.optim.shards,
        device,
    )
}

/// Validation tasks a renamed training demo may not be (see
/// [`BlocksRunConfig::exclude_held_out_renamings`]): more than any run
/// validates or `ntg eval --split validation` is used with here.
pub const HELD_OUT_VALIDATION_TASKS: usize = 1000;

/// The end configurations (`StackTask::configuration_key`) of the held-out
/// tasks: the 1000 test tasks and the first [`HELD_OUT_VALIDATION_TASKS`]
/// validation tasks.
#[derive(Debug, Clone)]
pub struct HeldOutConfigurations {
    keys: std::collections::HashSet<Vec<Vec<usize>>>,
}

impl HeldOutConfigurations {
    /// The configurations `config`'s renamings must avoid, if it renames
    /// cubes and excludes held-out renamings.
    pub fn for_run(config: &BlocksRunConfig) -> anyhow::Result<Option<Self>> {
        if config.permute_objects && config.exclude_held_out_renamings {
            Ok(Some(HeldOutConfigurations::new(config.task_source())?))
        } else {
            Ok(None)
        }
    }

    /// The held-out configurations of the split of the task set `tasks`
    /// ([`task_split`]; `None`: the standard one).
    pub fn new(tasks: TaskSource<'_>) -> anyhow::Result<Self> {
        let split = task_split(tasks)?;
        let validation = validation_tasks_of(tasks, HELD_OUT_VALIDATION_TASKS)?;
        let keys = split
            .test
            .iter()
            .chain(&validation)
            .map(StackTask::configuration_key)
            .collect();
        Ok(HeldOutConfigurations { keys })
    }

    /// Whether `task` with cube `i` renamed `perm[i]` ends in a held-out
    /// configuration.
    pub fn contains_renamed(&self, task: &StackTask, perm: &[usize]) -> bool {
        self.keys.contains(&renamed_configuration(task, perm))
    }
}

/// The end configuration of `task` with cube `i` renamed `perm[i]`, in the
/// form of `StackTask::configuration_key` (towers bottom to top, sorted).
pub fn renamed_configuration(task: &StackTask, perm: &[usize]) -> Vec<Vec<usize>> {
    let mut towers: Vec<Vec<usize>> = task
        .towers()
        .iter()
        .map(|tower| tower.iter().map(|&c| perm[c]).collect())
        .collect();
    towers.sort();
    towers
}

/// Block stacking's symmetry under renaming cubes, for state observations:
/// cube `i`'s position is state columns `3i..3i+3`, and `pick(·)` and
/// `place(·)` name cubes. The dynamics, the expert and the task
/// distribution treat all cubes alike, so a demo with its cubes renamed is
/// a demo of the renamed task.
pub fn object_symmetry() -> ObjectSymmetry {
    let vocab = flat_vocabulary();
    let family = |verb: &str| -> Vec<ActionId> {
        (0..env_blocks::world::NUM_OBJECTS)
            .map(|i| {
                let name = format!("{verb}({})", char::from(b'A' + i as u8));
                vocab
                    .id(&name)
                    .unwrap_or_else(|| unreachable!("{name} is in the stacking vocabulary"))
            })
            .collect()
    };
    ObjectSymmetry {
        num_objects: env_blocks::world::NUM_OBJECTS,
        obs_offset: 0,
        obs_stride: 3,
        action_families: vec![family("pick"), family("place")],
    }
}

/// Seed bases of an evaluation: the conditioning demo of task `i` is
/// recorded with `demo + i`, its rollout scene drawn with `rollout + i`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Seeds {
    /// Seed base of the conditioning demos.
    pub demo: u64,
    /// Seed base of the rollout scenes.
    pub rollout: u64,
}

impl Seeds {
    /// The test tasks' seeds.
    pub const TEST: Seeds = Seeds {
        demo: DEMO_SEED_BASE,
        rollout: ROLLOUT_SEED_BASE,
    };
    /// The validation tasks' seeds.
    pub const VALIDATION: Seeds = Seeds {
        demo: VALIDATION_DEMO_SEED_BASE,
        rollout: VALIDATION_ROLLOUT_SEED_BASE,
    };
    /// The seen (training) tasks' seeds: demos and scenes the run never
    /// trained on.
    pub const SEEN: Seeds = Seeds {
        demo: SEEN_DEMO_SEED_BASE,
        rollout: SEEN_ROLLOUT_SEED_BASE,
    };
    /// The structure split's seeds (`ntg eval --split structure`).
    pub const STRUCTURE: Seeds = Seeds {
        demo: 80_000_000,
        rollout: 90_000_000,
    };
}

/// The result of evaluating a model on test tasks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    /// Which policy variant was evaluated.
    pub variant: String,
    /// Success rate with its 95% interval.
    pub success: SuccessRate,
    /// Mean over tasks of the fraction of goal constraints that held at
    /// the end: partial progress, informative where whole tasks rarely
    /// succeed.
    #[serde(default)]
    pub mean_goal_fraction: f64,
    /// Per-task records.
    pub tasks: Vec<EpisodeRecord>,
}

impl EvalResult {
    /// `"; demos transcribed exactly R"` for a method with a demo
    /// interpreter ([`crate::domain::transcription_exact_rate`]), else empty.
    pub fn transcribed_note(&self) -> String {
        crate::domain::transcription_exact_rate(&self.tasks).map_or_else(String::new, |r| {
            format!("; demos transcribed exactly {:.3}", r.rate)
        })
    }
}

/// Records the conditioning demo of test task `index` (seed
/// `DEMO_SEED_BASE + index`) in `env` and builds the policy from it: the
/// first half of every evaluation episode, for `ntg trace`.
pub fn conditioned_policy(
    model: &NtgModel,
    env: &mut BlocksEnv,
    task: &StackTask,
    index: usize,
    obs: ObsKind,
) -> anyhow::Result<(ctg_graph::Demonstration<BlocksObservation>, NtgPolicy)> {
    let seed = DEMO_SEED_BASE + index as u64;
    let demo = record_demonstration(env, &mut BlocksExpert::new(), seed)
        .with_context(|| format!("demo of task {}", task.id))?;
    let rows: Vec<Vec<f32>> = demo
        .observations()
        .iter()
        .map(|o| featurize(o, obs))
        .collect();
    let policy = NtgPolicy::from_demo(model, &rows, &flat_vocabulary())?;
    Ok((demo, policy))
}

/// Block stacking as a [`Domain`]: the observation kind, and whether grasps
/// and drops fail at random.
#[derive(Debug, Clone)]
pub struct BlocksDomain {
    obs: ObsKind,
    env_config: EnvConfig,
    vocabulary: ctg_graph::Vocabulary,
    video: env_blocks::VideoConfig,
}

impl BlocksDomain {
    /// The domain seen through `obs`, with stochastic failures on or off.
    /// On frames, conditioning demos are videos timed by the default
    /// [`env_blocks::VideoConfig`].
    pub fn new(obs: ObsKind, failures: bool) -> Self {
        BlocksDomain {
            obs,
            env_config: env_config(obs, failures),
            vocabulary: flat_vocabulary(),
            video: env_blocks::VideoConfig::default(),
        }
    }

    /// The same domain with frames (observations and demo videos)
    /// rendered by `camera`.
    pub fn with_camera(mut self, camera: env_blocks::Camera) -> Self {
        self.env_config.camera = camera;
        self
    }
}

/// Step limit of NTP's primitive-level episodes: NTG's 40 flat actions,
/// each of which is at most two primitives.
pub const PRIMITIVE_STEP_LIMIT: usize = 80;

impl BlocksDomain {
    /// The same domain acted in at NTP's primitive level (`move(X)`,
    /// `grasp`, `drop`), with [`PRIMITIVE_STEP_LIMIT`]; conditioning demos
    /// have a row before every primitive and after the last.
    pub fn at_primitive_level(mut self) -> Self {
        self.env_config.level = env_blocks::ActionLevel::Primitive;
        self.env_config.max_steps = Some(PRIMITIVE_STEP_LIMIT);
        self.vocabulary = env_blocks::vocabulary(false, env_blocks::ActionLevel::Primitive);
        self
    }

    /// The same domain with frames rendered whatever the observation kind
    /// (for traces; rendering draws no random numbers, so episodes are
    /// unchanged).
    pub fn rendering(mut self) -> Self {
        self.env_config.render = true;
        self
    }
}

impl Domain for BlocksDomain {
    type Task = StackTask;
    type Env = BlocksEnv;
    type Expert = BlocksExpert;

    fn vocabulary(&self) -> &ctg_graph::Vocabulary {
        &self.vocabulary
    }
    fn env(&self, task: &StackTask) -> anyhow::Result<BlocksEnv> {
        Ok(BlocksEnv::stacking(task.clone(), self.env_config)?)
    }
    fn expert(&self) -> BlocksExpert {
        BlocksExpert::new()
    }
    fn obs_kind(&self) -> ObsKind {
        self.obs
    }
    fn obs_dim(&self) -> usize {
        match self.obs {
            ObsKind::State => obs_dim(ObsKind::State),
            ObsKind::Vid => self.env_config.camera.frame_dim(),
        }
    }
    fn featurize(&self, observation: &BlocksObservation) -> Vec<f32> {
        featurize(observation, self.obs)
    }
    fn task_name(&self, task: &StackTask) -> String {
        task.id.clone()
    }
    fn goals(&self, task: &StackTask, env: &BlocksEnv) -> (usize, usize) {
        let met = task
            .goals
            .iter()
            .filter(|g| env.world().on_top(g.src, g.target))
            .count();
        (met, task.goals.len())
    }
    fn record_demo(
        &self,
        env: &mut BlocksEnv,
        task: &StackTask,
        seed: u64,
    ) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ActionId>)> {
        // NTP reads its demo one row per primitive, on frames too (see
        // `crate::method::ntp_detector`).
        if self.obs == ObsKind::State || self.env_config.level == env_blocks::ActionLevel::Primitive
        {
            return domain::record_keyframes(self, env, seed);
        }
        let video = env_blocks::record_video_demo(
            env_blocks::BlocksTask::Stack(task.clone()),
            self.env_config,
            seed,
            &self.video,
        )?;
        let actions = video.actions().to_vec();
        let rows = video
            .frames()
            .iter()
            .map(env_collect::frame_to_chw)
            .collect();
        Ok((rows, actions))
    }
}

/// The flat action vocabulary of block stacking (the CTG's nodes).
pub fn flat_vocabulary() -> ctg_graph::Vocabulary {
    env_blocks::vocabulary(false, env_blocks::ActionLevel::Flat)
}

/// Evaluates `model` on the first `test_tasks` unseen tasks: one demo per
/// task → policy → rollout in a fresh scene, in parallel.
pub fn evaluate(
    model: &NtgModel,
    obs: ObsKind,
    failures: bool,
    test_tasks: usize,
    variant: Variant,
) -> anyhow::Result<EvalResult> {
    let split = task_split(TaskSource::Standard)?;
    evaluate_tasks(
        model,
        obs,
        failures,
        env_blocks::Camera::default(),
        test_tasks_of(&split, test_tasks)?,
        Seeds::TEST,
        variant,
    )
}

/// The first `test_tasks` tasks of `split`'s test set.
fn test_tasks_of(
    split: &env_blocks::StandardSplit,
    test_tasks: usize,
) -> anyhow::Result<&[StackTask]> {
    if test_tasks > split.test.len() {
        bail!(
            "asked for {test_tasks} test tasks; there are {}",
            split.test.len()
        );
    }
    Ok(&split.test[..test_tasks])
}

/// Evaluates `model` (NTG on states, or on frames) on `tasks` with the
/// given seeds (see [`evaluate`]).
pub fn evaluate_tasks<M: NtgBased>(
    model: &M,
    obs: ObsKind,
    failures: bool,
    camera: env_blocks::Camera,
    tasks: &[StackTask],
    seeds: Seeds,
    variant: Variant,
) -> anyhow::Result<EvalResult> {
    let mut model = model.clone();
    let ablation = variant.ablation_of(&model.ntg().config.ablation);
    model.ntg_mut().config.ablation = ablation;
    evaluate_on(
        &BlocksDomain::new(obs, failures).with_camera(camera),
        &model,
        variant.name(),
        tasks,
        seeds,
    )
}

/// Evaluates an NTP baseline on `tasks` with the given seeds, acting at the
/// primitive level (see [`BlocksDomain::at_primitive_level`]).
pub fn evaluate_ntp_tasks(
    model: &dyn crate::method::TrainedPolicy,
    obs: ObsKind,
    failures: bool,
    camera: env_blocks::Camera,
    tasks: &[StackTask],
    seeds: Seeds,
) -> anyhow::Result<EvalResult> {
    let domain = BlocksDomain::new(obs, failures)
        .with_camera(camera)
        .at_primitive_level();
    evaluate_on(&domain, model, "full", tasks, seeds)
}

/// The success of `run`'s model at the weights its training started from
/// (`initial/`, [`RunDir::initial_dir`]) on the first `test_tasks` test
/// tasks, with the demos, scenes and action level its trained model is
/// evaluated with: the value a series must beat to show that it learned.
pub fn evaluate_untrained(
    run: &RunDir,
    config: &BlocksRunConfig,
    test_tasks: usize,
    device: &Device,
) -> anyhow::Result<EvalResult> {
    let dir = run.initial_dir();
    let context = || format!("loading the untrained model of {}", run.root().display());
    let split = task_split(config.task_source())?;
    let tasks = test_tasks_of(&split, test_tasks)?;
    if config.method.is_ntg() {
        // As the trained model is evaluated (`TrainedBlocks::evaluate`).
        let model = load_ntg_from(&dir, device).with_context(context)?;
        model.evaluate_tasks(
            config.failures,
            config.camera(),
            tasks,
            Seeds::TEST,
            Variant::Full,
        )
    } else {
        let model = config.method.load(&dir, device).with_context(context)?;
        evaluate_ntp_tasks(
            model.as_ref(),
            config.obs,
            config.failures,
            config.camera(),
            tasks,
            Seeds::TEST,
        )
    }
}

/// Evaluates an NTP baseline on the first `test_tasks` test tasks of the
/// task set `tasks` (the tasks and seeds NTG is evaluated on).
pub fn evaluate_ntp(
    model: &dyn crate::method::TrainedPolicy,
    tasks: TaskSource<'_>,
    obs: ObsKind,
    failures: bool,
    camera: env_blocks::Camera,
    test_tasks: usize,
) -> anyhow::Result<EvalResult> {
    let split = task_split(tasks)?;
    evaluate_ntp_tasks(
        model,
        obs,
        failures,
        camera,
        test_tasks_of(&split, test_tasks)?,
        Seeds::TEST,
    )
}

/// One episode per task (conditioning demo and rollout seeded from
/// `seeds`), evaluated in `domain`.
fn evaluate_on(
    domain: &BlocksDomain,
    model: &dyn crate::method::TrainedPolicy,
    variant: &str,
    tasks: &[StackTask],
    seeds: Seeds,
) -> anyhow::Result<EvalResult> {
    let episodes: Vec<Episode<StackTask>> = tasks
        .iter()
        .enumerate()
        .map(|(i, task)| Episode {
            group: 0,
            index: i,
            task: task.clone(),
            demo_seed: seeds.demo + i as u64,
            rollout_seed: seeds.rollout + i as u64,
        })
        .collect();
    let records = domain::evaluate(domain, model, &episodes)?;
    Ok(EvalResult {
        variant: variant.to_owned(),
        success: domain::success_rate(&records),
        mean_goal_fraction: domain::mean_goal_fraction(&records),
        tasks: records,
    })
}

/// Block stacking's own `ntg train` flags.
#[derive(Debug, Clone, clap::Args)]
#[command(next_help_heading = "Block stacking (--domain blocks)")]
pub struct BlocksFlags {
    /// The training recipe the other options add to.
    #[arg(long, value_enum, default_value_t = Recipe::Recommended)]
    pub recipe: Recipe,
    /// Train and evaluate on this NTP task file (e.g. NTP's own
    /// `stack_2000.json`) instead of the generated stand-in set: its first
    /// 1000 tasks are the training pool, the rest the test tasks (the
    /// standard rule); validation tasks are drawn outside all of them.
    #[arg(long, value_name = "FILE", conflicts_with = "task_set")]
    pub tasks: Option<PathBuf>,
    /// The task set: `standard` (the generated stand-in for NTP's, split
    /// by the standard rule) or `structure` (the structure benchmark:
    /// training, validation and test tasks of structures that share none;
    /// `ntg eval --split taller` scores towers taller than any trained on)
    /// [default: standard].
    #[arg(long, value_enum, value_name = "SET")]
    pub task_set: Option<TaskSetKind>,
    /// Train the edge classifier on GCN embeddings of another demo of the
    /// same task than the one it imitates.
    #[arg(long)]
    pub gcn_from_other_demo: bool,
    /// Probability that the demo interpreter's decoder reads `<start>`
    /// instead of the previous action in training (0 = plain teacher forcing).
    #[arg(long, value_parser = crate::spec::parse::rate, default_value_t = 0.0)]
    pub token_dropout: f32,
    /// The localizer's and edge classifier's state encoders also read every
    /// pairwise difference of cube positions.
    #[arg(long)]
    pub pairwise: bool,
    /// --method ntg: where the policy takes its current node from:
    /// `localizer`, the node localizer's reading of the observation (the
    /// paper's policy), or `executed`, the last action the agent executed
    /// (not in the paper) [default: executed on video with --recipe
    /// recommended, else localizer].
    #[arg(long, value_enum, value_name = "SOURCE")]
    pub node_source: Option<NodeSource>,
    /// --method ntg: the policy may choose `<end>` only once every action
    /// of the demo's transcription has been executed (a symbolic rule;
    /// not in the paper) [default: true in the recommended recipe on
    /// states, false otherwise; `--end-after-demo false` turns it off].
    #[arg(long, value_name = "BOOL", num_args = 0..=1, default_missing_value = "true")]
    pub end_after_demo: Option<bool>,
    /// State runs: the state encoders read heights only as far as this
    /// many metres (a cube is 0.05 m; not in the paper) [default: no clamp].
    #[arg(long, value_name = "METRES", allow_negative_numbers = true)]
    pub state_height_clamp: Option<f32>,
    /// Hidden layers of the localizer's and edge classifier's state encoder
    /// MLPs (state observations only; the demo interpreter keeps one)
    /// [default: 3 with --recipe recommended, else 1].
    #[arg(long, value_parser = crate::spec::parse::positive)]
    pub state_hidden_layers: Option<usize>,
    /// Held-out validation tasks scored after every epoch; the epoch that
    /// scores best is the run's result (`best/`). 0 = keep the last epoch.
    #[arg(long, default_value_t = 100)]
    pub validation_tasks: usize,
    /// Score the validation tasks after every this many epochs (and after
    /// the last).
    #[arg(long, default_value_t = 1)]
    pub validate_every: usize,
    /// Train on demos whose cubes are renamed by a random permutation per
    /// demo and step (state observations; not in the paper).
    #[arg(long)]
    pub permute_objects: bool,
    /// Hidden width of a fusion layer between the edge classifier's inputs
    /// and its query (0 = the paper's linear W; not in the paper)
    /// [default: 256 with --recipe recommended, else 0].
    #[arg(long)]
    pub edge_fusion_hidden: Option<usize>,
    /// Weight of recovery steps (the next action repeats one already taken)
    /// in the edge classifier's loss (0 or 1 = unweighted; not in the
    /// paper) [default: the recipe's, unweighted].
    #[arg(long, value_parser = crate::spec::parse::non_negative)]
    pub retry_weight: Option<f32>,
    /// Keep the edge classifier's loss out of the GCN, which then learns
    /// only to complete task graphs (not in the paper).
    #[arg(long)]
    pub detach_gcn_from_edges: bool,
    /// Weigh edges by the completed graph's probabilities instead of
    /// cutting them to the graph thresholded at 0.5 (trained the same way).
    #[arg(long)]
    pub soft_edges: bool,
    /// Turn stochastic grasp/drop failures off (they are on by default).
    #[arg(long)]
    pub no_failures: bool,
    /// --obs vid: the demo interpreter reads the demo video's frames
    /// averaged in windows of this many (1 = every frame) [default: 4 in
    /// the recommended recipe, 1 in the paper's].
    #[arg(long, value_name = "K", value_parser = crate::spec::parse::positive)]
    pub interpreter_frame_pool: Option<usize>,
    /// --obs vid, --method ntg: the node localizer reads the frame of the
    /// agent's previous decision beside the current one (temporal context;
    /// not in the paper). Needs the localizer to choose the node: with
    /// --recipe recommended, add --node-source localizer.
    #[arg(long)]
    pub localizer_previous_frame: bool,
    /// --obs vid: side in pixels of the camera's square frames, a multiple
    /// of 8 from 8 to 512 (the same framing: a cube spans about side/13
    /// pixels) [default: 64].
    #[arg(long, value_name = "PIXELS", value_parser = crate::spec::parse::positive)]
    pub camera_size: Option<usize>,
    /// --obs vid: cube renaming for frames (not in the paper): each task's
    /// demos are recorded in groups of this many, the first group on the
    /// task itself, every other group on the task with its cubes renamed
    /// (a cube's colour follows its name; never onto a held-out
    /// configuration); 0 = no renaming [default: 4 in the recommended
    /// recipe, 0 in the paper's].
    #[arg(long, value_name = "K")]
    pub video_renaming_group: Option<usize>,
    /// --obs vid, --method ntp or ntp-flat: what the frame encoder (stage
    /// A) is trained to tell apart: NTG's flat actions on every frame of
    /// the demo videos (`flat`, stage A as NTG's) or NTP's primitives on
    /// the frames NTP acts on (`primitive`) [default: flat].
    #[arg(long, value_enum)]
    pub encoder_labels: Option<FrameLabels>,
    /// --method ntp, ntp-flat or ntp-detector: NTP's core network: the
    /// feed-forward core of the design's default (`reactive`), or a GRU
    /// state carried through each program call's decisions (`gru`, the
    /// original NTP's recurrent variant) [default: reactive].
    #[arg(long, value_enum)]
    pub ntp_core: Option<NtpCoreKind>,
    /// --method ntp-detector: primitive-level expert episodes of the
    /// training tasks whose rendered frames train the detector [default:
    /// 2000].
    #[arg(long, value_parser = crate::spec::parse::positive)]
    pub detector_episodes: Option<usize>,
    /// --method ntp-detector: the detector's training epochs [default: 15].
    #[arg(long, value_parser = crate::spec::parse::positive)]
    pub detector_epochs: Option<usize>,
    /// --method ntp-detector: train NTP on the simulator's true states of
    /// its training episodes instead of the detector's estimates of their
    /// frames (the rows it is fed when it acts; the default).
    #[arg(long)]
    pub ntp_on_true_states: bool,
}

/// The run configuration `ntg train --domain blocks` asks for: the recipe,
/// with the boolean flags added and the numbers overridden.
pub fn train_config(flags: &TrainFlags, own: &BlocksFlags) -> BlocksRunConfig {
    let base = own.recipe.for_method(
        own.recipe.config(
            flags.obs,
            flags.train_tasks,
            flags.demos_per_task,
            flags.epochs,
            flags.seed,
        ),
        flags.method,
    );
    let video = base.video.clone().map(|mut v| {
        flags.apply_encoder_flags(&mut v.encoder);
        v.interpreter_frame_pool = own
            .interpreter_frame_pool
            .unwrap_or(v.interpreter_frame_pool);
        v.demos_per_renaming = own.video_renaming_group.unwrap_or(v.demos_per_renaming);
        v.localizer_previous_frame |= own.localizer_previous_frame;
        v.executed_node = match own.node_source {
            Some(source) => source == NodeSource::Executed,
            None => v.executed_node,
        };
        v.encoder_labels = own.encoder_labels.unwrap_or(v.encoder_labels);
        if let Some(size) = own.camera_size {
            v.camera = env_blocks::Camera::of_size(u32::try_from(size).unwrap_or(u32::MAX));
        }
        v
    });
    BlocksRunConfig {
        video,
        detector: base.detector.clone().map(|d| DetectorSettings {
            episodes: own.detector_episodes.unwrap_or(d.episodes),
            epochs: own.detector_epochs.unwrap_or(d.epochs),
            ntp_on_estimates: d.ntp_on_estimates && !own.ntp_on_true_states,
            camera: own.camera_size.map_or(d.camera, |size| {
                env_blocks::Camera::of_size(u32::try_from(size).unwrap_or(u32::MAX))
            }),
            stem: flags.encoder_stem.filter(|&c| c > 0).or(d.stem),
            ..d
        }),
        failures: !own.no_failures,
        state_hidden_layers: own.state_hidden_layers.unwrap_or(base.state_hidden_layers),
        pairwise: base.pairwise || own.pairwise,
        validation_tasks: own.validation_tasks,
        validate_every: own.validate_every,
        permute_objects: base.permute_objects || own.permute_objects,
        // Renamed demos never show a held-out task (new runs always).
        exclude_held_out_renamings: base.permute_objects || own.permute_objects,
        edge_fusion_hidden: own.edge_fusion_hidden.unwrap_or(base.edge_fusion_hidden),
        retry_weight: own.retry_weight.unwrap_or(base.retry_weight),
        detach_gcn_from_edges: base.detach_gcn_from_edges || own.detach_gcn_from_edges,
        soft_edges: base.soft_edges || own.soft_edges,
        ablation: flags.ablation,
        ntp_core: own.ntp_core.unwrap_or(base.ntp_core),
        tasks: own.tasks.clone(),
        structure_benchmark: own.task_set == Some(TaskSetKind::Structure),
        // The state runs' switch; a video run's is `video.executed_node`.
        executed_node: match (&base.video, own.node_source) {
            (None, Some(source)) => source == NodeSource::Executed,
            _ => base.executed_node,
        },
        state_height_clamp: own.state_height_clamp.or(base.state_height_clamp),
        memory: base.memory || flags.memory,
        end_after_demo: own.end_after_demo.unwrap_or(base.end_after_demo),
        // `--interpreter` replaces the recipe's interpreter, and the step
        // prior that goes with it.
        interpreter: flags.interpreter.map_or(base.interpreter, |kind| {
            Some(kind).filter(|&k| k != crate::method::ntg::InterpreterKind::Luong)
        }),
        location_step_prior: match (flags.location_step_prior, flags.interpreter) {
            (Some(0.0), _) => None,
            (Some(w), _) => Some(w),
            (None, Some(kind)) => kind.step_prior(),
            (None, None) => base.location_step_prior,
        },
        optim: OptimConfig {
            batch_size: flags.batch_size,
            learning_rate: flags.lr.unwrap_or(base.optim.learning_rate),
            token_dropout: own.token_dropout,
            cosine_decay: base.optim.cosine_decay || flags.cosine_decay,
            gcn_from_other_demo: base.optim.gcn_from_other_demo || own.gcn_from_other_demo,
            shards: flags.shards,
            ..base.optim
        },
        ..base
    }
}

/// The methods block stacking's evaluation (`ntg eval`, the experiments)
/// reads: NTG, at the level of its demos, and the NTP family, at the
/// primitive level.
pub const EVALUATED_METHODS: &[MethodId] = &[
    MethodId::Ntg,
    MethodId::Ntp,
    MethodId::NtpFlat,
    MethodId::NtpDetector,
];

/// Block stacking in the domain registry (`ntg train --domain blocks`,
/// `ntg eval` on its runs).
pub struct Blocks;

impl DomainRuns for Blocks {
    fn name(&self) -> &'static str {
        "blocks"
    }

    fn train(&self, flags: &TrainFlags, own: &DomainFlags) -> anyhow::Result<()> {
        let own = &own.blocks;
        let config = train_config(flags, own);
        // Checked before the run folder exists, so a corrected command is
        // not refused as "already exists".
        let method = config.method.method();
        let vid = config.obs == ObsKind::Vid;
        // Each method-specific flag is accepted only for a method that reads
        // its option (`Method::reads`).
        if config.permute_objects && vid && !method.reads("permute_objects") {
            bail!(
                "--permute-objects renames cubes in state observations; with --obs vid {} reads none (--video-renaming-group renames cubes in demo videos)",
                method.legend()
            );
        }
        flags.check_encoder_flags()?;
        // NTP (Detector) reads its frames through a detector, which takes
        // --encoder-stem (and --camera-size) and no other encoder flag.
        let encoder_flags_but_stem = match &config.detector {
            Some(_) => TrainFlags {
                encoder_stem: None,
                ..flags.clone()
            }
            .sets_the_frame_encoder(),
            None => flags.sets_the_frame_encoder(),
        };
        if config.video.is_none() && encoder_flags_but_stem {
            bail!(
                "--encoder-* flags set the frame encoder of a run from demo videos; {} reads no demo video",
                method.legend()
            );
        }
        let detector_flags = own.detector_episodes.is_some()
            || own.detector_epochs.is_some()
            || own.ntp_on_true_states;
        if detector_flags && !method.reads("detector") {
            bail!(
                "--detector-episodes, --detector-epochs and --ntp-on-true-states train a detector stage; {} has none (--method ntp-detector has)",
                method.legend()
            );
        }
        if own.video_renaming_group.is_some() && config.video.is_none() {
            bail!("--video-renaming-group renames cubes in demo videos: it needs --obs vid");
        }
        if own.camera_size.is_some() {
            if !vid {
                bail!("--camera-size sets the frames of a run on video: it needs --obs vid");
            }
            config
                .camera()
                .validate()
                .map_err(|e| anyhow::anyhow!("--camera-size: {e}"))?;
        }
        if let Some(video) = &config.video {
            video
                .encoder
                .net_config(flat_vocabulary().len(), video.camera.size as usize, 0)
                .validate()
                .map_err(|e| anyhow::anyhow!("--camera-size and --encoder-*: {e}"))?;
        }
        if own.interpreter_frame_pool.is_some()
            && !(vid && method.reads("video.interpreter_frame_pool"))
        {
            bail!(
                "--interpreter-frame-pool sets NTG's demo interpreter on videos: it needs --obs vid and --method ntg"
            );
        }
        if own.localizer_previous_frame && !(vid && method.reads("video.localizer_previous_frame"))
        {
            bail!(
                "--localizer-previous-frame sets NTG's node localizer on videos: it needs --obs vid and --method ntg"
            );
        }
        if own.encoder_labels.is_some() && !(vid && method.reads("video.encoder_labels")) {
            bail!(
                "--encoder-labels sets the frame encoder NTP and NTP Flat read videos through: it needs --obs vid and --method ntp or ntp-flat"
            );
        }
        if own.ntp_core.is_some() && !method.reads("ntp_core") {
            bail!(
                "--ntp-core sets NTP's core network: it needs --method ntp, ntp-flat or ntp-detector"
            );
        }
        if !EVALUATED_METHODS.contains(&config.method) {
            bail!(
                "--method {}: block stacking trains and evaluates ntg, ntp, ntp-flat or ntp-detector",
                config.method.name()
            );
        }
        if own.node_source.is_some() && !method.reads("executed_node") {
            bail!(
                "--node-source chooses where NTG's policy takes its current node; {} has no node localizer",
                config.method.legend()
            );
        }
        check_executed_node(&config).context("--node-source")?;
        check_state_height_clamp(&config).context("--state-height-clamp")?;
        check_memory(&config).context("--memory")?;
        check_end_after_demo(&config).context("--end-after-demo")?;
        check_interpreter_input(&config).context("--interpreter")?;
        if (config.interpreter.is_some() || config.location_step_prior.is_some())
            && !config.method.method().reads("interpreter")
        {
            bail!(
                "--interpreter and --location-step-prior choose NTG's demo interpreter; {} has none",
                config.method.legend()
            );
        }
        config
            .method
            .method()
            .check(&serde_json::to_value(&config)?)?;
        task_split(config.task_source())
            .with_context(|| "--tasks")?
            .train(config.train_tasks)
            .with_context(|| format!("--train-tasks {}", config.train_tasks))?;
        let run = RunDir::start_or_resume(
            &flags.out,
            &config,
            flags.resume,
            "runs started before --recipe existed need --recipe paper; ",
        )?;
        let device = crate::spec::device().autodiff();
        eprintln!(
            "training {} ({:?} observations) on {} tasks x {} demos for {} epochs -> {}",
            config.method.legend(),
            config.obs,
            config.train_tasks,
            config.demos_per_task,
            config.optim.epochs,
            run.root().display()
        );
        train_model(&run, &config, &device, |r| eprintln!("{r}"))?;
        match crate::fit::selected_epoch(&run)? {
            Some(best) => println!(
                "done: epoch {} scored best on the validation tasks (success {:.3}, goals met {:.3}); its weights are in {}",
                best.epoch,
                best.score.success,
                best.score.goal_fraction,
                run.best_dir().display()
            ),
            None => println!("done: weights in {}", run.checkpoint_dir().display()),
        }
        Ok(())
    }

    fn owns(&self, config: &serde_json::Value) -> bool {
        // Block-stacking configurations predate the `domain` field.
        config.get("domain").is_none()
    }

    fn evaluate(&self, run: &RunDir, flags: &EvalFlags) -> anyhow::Result<()> {
        if flags.decisions {
            return evaluate_decisions(run, flags);
        }
        let (name, result) = evaluate_run(run, flags)?;
        write_eval(run, &name, &result)
    }
    fn trained(&self, run: &RunDir) -> anyhow::Result<super::TrainedRun> {
        let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
        let dir = crate::fit::trained_dir(run)?;
        let model = config
            .method
            .load(&dir, &crate::spec::device())
            .with_context(|| format!("loading the trained model of {}", run.root().display()))?;
        crate::method::on_frames::check_model_obs(&dir, config.obs, &run.config_path())?;
        Ok(super::TrainedRun {
            model,
            dir,
            method: config.method.name(),
        })
    }
}

/// `ntg eval --decisions`: the NTP baseline of `run` checked decision by
/// decision along the expert's traces of the split's first `--test-tasks`
/// tasks; prints the table and writes `eval/PREFIXdecisions-N.json`.
fn evaluate_decisions(run: &RunDir, flags: &EvalFlags) -> anyhow::Result<()> {
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    if !config.method.is_ntp() {
        bail!(
            "--decisions checks an NTP baseline's decisions along expert traces; {} is a {} run",
            run.root().display(),
            config.method.legend()
        );
    }
    if flags.variant != Variant::Full || flags.edge_threshold.is_some() {
        bail!("--variant and --edge-threshold choose NTG's policy; --decisions checks NTP's");
    }
    let device = crate::spec::device();
    let (prefix, tasks, seeds) = eval_split(flags, &config)?;
    let model = load_baseline(run, &config, &device)?;
    let report = ntp_decisions(model.as_ref(), &config, &tasks, seeds, &device)?;
    let recorded = super::record_eval(
        run,
        &format!("{prefix}decisions-{}.json", tasks.len()),
        &report,
    );
    print!("{}", report.table());
    println!("{recorded}");
    Ok(())
}

/// An NTP baseline (`model`, trained as `config` says) checked decision by
/// decision along the expert's trace of each of `tasks` in the scene of its
/// rollout (task `i`'s rollout seed), conditioned on the expert's demo with
/// its demo seed (`seeds`), both at the primitive level, read as the model
/// reads observations (states; frames through its frozen encoder or its
/// detector).
pub fn ntp_decisions(
    model: &dyn crate::method::TrainedPolicy,
    config: &BlocksRunConfig,
    tasks: &[StackTask],
    seeds: Seeds,
    device: &Device,
) -> anyhow::Result<crate::method::ntp::DecisionReport> {
    use crate::method::ntp::{CheckedEpisode, DecisionReport, NtpKind, NtpModel, check_episodes};
    type Front<'a> = Box<dyn Fn(&[Vec<f32>]) -> anyhow::Result<Vec<Vec<f32>>> + 'a>;
    let kind = NtpKind::of(config.method.method());
    let any = model.as_any();
    let (net, front): (&ntg_model::NtpNet, Front<'_>) =
        if let Some(model) = any.downcast_ref::<NtpModel>() {
            (&model.net, Box::new(|rows: &[Vec<f32>]| Ok(rows.to_vec())))
        } else if let Some(m) = any.downcast_ref::<crate::method::on_frames::OnFrames<NtpModel>>() {
            (
                &m.policy.net,
                Box::new(|rows: &[Vec<f32>]| m.encode_rows(rows)),
            )
        } else if let Some(m) = any.downcast_ref::<crate::method::ntp_detector::NtpOnDetector>() {
            (
                &m.ntp.net,
                Box::new(|rows: &[Vec<f32>]| Ok(m.detector.predict_rows(rows)?)),
            )
        } else {
            bail!("{} is not an NTP network", config.method.legend());
        };
    let env = env_config(config.obs, config.failures).with_camera(config.camera());
    let mut report = DecisionReport::new();
    let bar = crate::dataset::progress_bar(tasks.len() as u64, "checking decisions");
    let indices: Vec<usize> = (0..tasks.len()).collect();
    for chunk in indices.chunks(32) {
        use rayon::prelude::*;
        let recorded = chunk
            .par_iter()
            .map(|&i| {
                let task = env_blocks::BlocksTask::Stack(tasks[i].clone());
                let record = |seed: u64| {
                    env_blocks::record_ntp_demo(&task, env, seed)
                        .with_context(|| format!("NTP demo of task {} (seed {seed})", tasks[i].id))
                };
                Ok((
                    record(seeds.demo + i as u64)?,
                    record(seeds.rollout + i as u64)?,
                ))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let mut episodes = Vec::with_capacity(recorded.len());
        for (spec, episode) in recorded {
            let rows = |d: &env_blocks::NtpDemo| -> Vec<Vec<f32>> {
                d.observations
                    .iter()
                    .map(|o| featurize(o, config.obs))
                    .collect()
            };
            episodes.push(CheckedEpisode {
                spec_rows: front(&rows(&spec))?,
                spec: spec.root,
                rows: front(&rows(&episode))?,
                trace: episode.root,
            });
        }
        check_episodes(net, kind, &episodes, &mut report, device)?;
        bar.inc(chunk.len() as u64);
    }
    bar.finish_and_clear();
    Ok(report)
}

/// Evaluates the block-stacking run `run` (NTG or an NTP baseline) as
/// `ntg eval` with `flags` does, without writing: its result and the name
/// of its file under `eval/` (without `.json`).
pub fn evaluate_run(run: &RunDir, flags: &EvalFlags) -> anyhow::Result<(String, EvalResult)> {
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let device = crate::spec::device();
    let (prefix, tasks, seeds) = eval_split(flags, &config)?;
    if config.method.is_ntp() {
        if flags.variant != Variant::Full || flags.edge_threshold.is_some() {
            bail!(
                "--variant and --edge-threshold choose NTG's policy; {} is a {} run",
                run.root().display(),
                config.method.legend()
            );
        }
        let model = load_baseline(run, &config, &device)?;
        let name = format!("{prefix}{}-{}", config.method.name(), tasks.len());
        let result = evaluate_ntp_tasks(
            model.as_ref(),
            config.obs,
            config.failures,
            config.camera(),
            &tasks,
            seeds,
        )?;
        return Ok((name, result));
    }
    let model = load_trained(run, flags.edge_threshold, &device)?;
    let mut name = format!("{prefix}{}-{}", flags.variant.name(), tasks.len());
    if let Some(t) = flags.edge_threshold {
        name.push_str(&format!("-threshold{t}"));
    }
    let result = model.evaluate_tasks(
        config.failures,
        config.camera(),
        &tasks,
        seeds,
        flags.variant,
    )?;
    Ok((name, result))
}

/// The tasks and seeds `ntg eval --split` asks for (the first
/// `--test-tasks` of the split), and the prefix of the result's file name.
fn eval_split(
    flags: &EvalFlags,
    config: &BlocksRunConfig,
) -> anyhow::Result<(String, Vec<StackTask>, Seeds)> {
    let tasks = config.task_source();
    let split = task_split(tasks)?;
    if let Some(file) = &flags.tasks {
        let (prefix, chosen) = tasks_of_file(file, flags.test_tasks, &split, config)?;
        return Ok((prefix, chosen, Seeds::TEST));
    }
    Ok(match flags.split {
        crate::domain::EvalSplit::Test => (
            String::new(),
            test_tasks_of(&split, flags.test_tasks)?.to_vec(),
            Seeds::TEST,
        ),
        crate::domain::EvalSplit::Validation => (
            "validation-".into(),
            validation_tasks_of(tasks, flags.test_tasks)?,
            Seeds::VALIDATION,
        ),
        crate::domain::EvalSplit::Seen => {
            if flags.test_tasks > config.train_tasks {
                bail!(
                    "--split seen --test-tasks {}: the run trained on {} tasks",
                    flags.test_tasks,
                    config.train_tasks
                );
            }
            (
                "seen-".into(),
                split.train(flags.test_tasks)?.to_vec(),
                Seeds::SEEN,
            )
        }
        crate::domain::EvalSplit::Structure if config.structure_benchmark => bail!(
            "--split structure is the standard task set's split by structure (the earlier protocol); {} trains on the structure benchmark, whose new structures are --split test (heights seen in training) and --split taller",
            config.task_source_name()
        ),
        crate::domain::EvalSplit::Taller => {
            if !config.structure_benchmark {
                bail!(
                    "--split taller scores the structure benchmark's towers taller than any trained on; this run trains on the {} (--task-set structure trains on the benchmark)",
                    config.task_source_name()
                );
            }
            (
                "taller-".into(),
                taller_tasks(flags.test_tasks)?,
                Seeds::STRUCTURE,
            )
        }
        crate::domain::EvalSplit::Structure => (
            "structure-".into(),
            env_blocks::structure_test_tasks(
                &split.train_pool,
                flags.test_tasks,
                env_blocks::STRUCTURE_SEED,
            )?,
            Seeds::STRUCTURE,
        ),
    })
}

/// `ntg eval --tasks FILE`: the first `count` tasks of the NTP-format
/// `file` (all if it has fewer), and the prefix of the result's file name
/// (`tasks-STEM-`). Prints how many of them end in the configuration of one
/// of the run's training tasks (those are not unseen tasks for it).
fn tasks_of_file(
    file: &std::path::Path,
    count: usize,
    split: &env_blocks::StandardSplit,
    config: &BlocksRunConfig,
) -> anyhow::Result<(String, Vec<StackTask>)> {
    let mut tasks =
        env_blocks::read_ntp_tasks(file).with_context(|| format!("--tasks {}", file.display()))?;
    if tasks.is_empty() {
        bail!("--tasks {}: the file holds no tasks", file.display());
    }
    if tasks.len() < count {
        println!(
            "--tasks {}: {} tasks (fewer than --test-tasks {count}): evaluating them all",
            file.display(),
            tasks.len()
        );
    }
    tasks.truncate(count);
    let trained: std::collections::HashSet<Vec<Vec<usize>>> = split
        .train(config.train_tasks)?
        .iter()
        .map(StackTask::configuration_key)
        .collect();
    let seen: Vec<&str> = tasks
        .iter()
        .filter(|t| trained.contains(&t.configuration_key()))
        .map(|t| t.id.as_str())
        .collect();
    if seen.is_empty() {
        println!(
            "--tasks {}: none of its {} tasks is a training task of this run (end configurations compared)",
            file.display(),
            tasks.len()
        );
    } else {
        println!(
            "--tasks {}: {} of its {} tasks end as a training task of this run does, so they are not unseen: {}",
            file.display(),
            seen.len(),
            tasks.len(),
            seen.join(", ")
        );
    }
    let stem = file
        .file_stem()
        .map_or("tasks".into(), |s| s.to_string_lossy().into_owned());
    Ok((format!("tasks-{stem}-"), tasks))
}

/// A stacking task in words, for `meta/tasks.jsonl`: `stack B on A, C on
/// B` (cubes by letter, as everywhere in `ntg`).
pub fn stack_words(task: &StackTask) -> String {
    let goals: Vec<String> = task
        .describe()
        .split(' ')
        .filter_map(|g| g.split_once('>'))
        .map(|(src, target)| format!("{src} on {target}"))
        .collect();
    format!("stack {}", goals.join(", "))
}

/// Writes `result` to the run's `eval/NAME.json` and prints its rates.
fn write_eval(run: &RunDir, name: &str, result: &EvalResult) -> anyhow::Result<()> {
    let recorded = super::record_eval(run, &format!("{name}.json"), result);
    let s = result.success;
    println!(
        "{}: success {}/{} = {:.3} (95% CI {:.3}-{:.3}); goals met {:.3}{}; {recorded}",
        result.variant,
        s.successes,
        s.trials,
        s.rate,
        s.ci_low,
        s.ci_high,
        result.mean_goal_fraction,
        result.transcribed_note(),
    );
    Ok(())
}

/// Loads the trained model of an NTP baseline's `run` (configuration
/// `config`): the epoch selected on validation tasks if there is one, else
/// the last checkpoint.
pub fn load_baseline(
    run: &RunDir,
    config: &BlocksRunConfig,
    device: &Device,
) -> anyhow::Result<Model> {
    let dir = match crate::fit::selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    config
        .method
        .load(&dir, device)
        .with_context(|| format!("loading the trained model of {}", run.root().display()))
}

/// The NTG model saved in `dir`: on frames if it holds a frame encoder,
/// else on state rows.
fn load_ntg_from(dir: &Path, device: &Device) -> anyhow::Result<TrainedBlocks> {
    Ok(if crate::method::on_frames::is_video_model(dir) {
        TrainedBlocks::Video(<VideoNtgModel as crate::fit::TrainedModel>::load_from(
            dir, device,
        )?)
    } else {
        TrainedBlocks::State(NtgModel::load(dir, device)?)
    })
}

/// Loads the trained model of `run` (the epoch selected on validation
/// tasks if there is one, else the last checkpoint), with its edge
/// threshold overridden when `edge_threshold` is given (checked to lie in
/// [0, 1]).
pub fn load_trained(
    run: &RunDir,
    edge_threshold: Option<f32>,
    device: &burn::tensor::Device,
) -> anyhow::Result<TrainedBlocks> {
    let dir = match crate::fit::selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    let context = || format!("loading the trained model of {}", run.root().display());
    let mut model = load_ntg_from(&dir, device).with_context(context)?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    crate::method::on_frames::check_model_obs(&dir, config.obs, &run.config_path())?;
    if let Some(t) = edge_threshold {
        if !(0.0..=1.0).contains(&t) {
            bail!("--edge-threshold must be in [0, 1], got {t}");
        }
        model.ntg_mut().config.edge_threshold = t;
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ctg_graph::Ctg;

    #[test]
    fn held_out_configurations_catch_a_training_task_renamed_into_a_test_task() {
        let split = env_blocks::standard_split().unwrap();
        let held_out = HeldOutConfigurations::new(TaskSource::Standard).unwrap();
        let identity: Vec<usize> = (0..env_blocks::world::NUM_OBJECTS).collect();
        // Unrenamed, no training task is held out, and every test task is.
        for task in &split.train_pool {
            assert_eq!(
                renamed_configuration(task, &identity),
                task.configuration_key()
            );
            assert!(!held_out.contains_renamed(task, &identity));
        }
        assert!(
            split
                .test
                .iter()
                .all(|t| held_out.contains_renamed(t, &identity))
        );
        // A training task and a test task whose towers have the same
        // shape: the renaming that maps one onto the other is caught.
        let shape = |t: &StackTask| -> Vec<usize> {
            let mut lens: Vec<usize> = t.towers().iter().map(Vec::len).collect();
            lens.sort();
            lens
        };
        let (train, test) = split
            .train_pool
            .iter()
            .find_map(|a| {
                split
                    .test
                    .iter()
                    .find(|b| shape(a) == shape(b))
                    .map(|b| (a, b))
            })
            .expect("some training and test task share a tower shape");
        let (mut from, mut to) = (train.towers(), test.towers());
        from.sort_by_key(Vec::len);
        to.sort_by_key(Vec::len);
        let mut perm = vec![usize::MAX; env_blocks::world::NUM_OBJECTS];
        for (a, b) in from.iter().zip(&to) {
            for (&x, &y) in a.iter().zip(b) {
                perm[x] = y;
            }
        }
        // Cubes in no tower go to the cubes the test task leaves free.
        let used: std::collections::HashSet<usize> = perm.iter().copied().collect();
        let mut free = (0..env_blocks::world::NUM_OBJECTS).filter(|c| !used.contains(c));
        for p in perm.iter_mut().filter(|p| **p == usize::MAX) {
            *p = free.next().unwrap();
        }
        assert_eq!(
            renamed_configuration(train, &perm),
            test.configuration_key()
        );
        assert!(held_out.contains_renamed(train, &perm));
    }

    #[test]
    fn renaming_cubes_moves_columns_actions_and_graph_edges_together() {
        let sym = object_symmetry();
        let vocab = flat_vocabulary();
        let n = vocab.len();
        sym.validate(n, env_blocks::STATE_DIM).unwrap();
        // A -> C, B -> A, C -> B, the rest fixed.
        let mut perm: Vec<usize> = (0..env_blocks::world::NUM_OBJECTS).collect();
        perm[..3].copy_from_slice(&[2, 0, 1]);
        let r = sym.relabeling(perm, n);
        let id = |name: &str| vocab.id(name).unwrap();
        assert_eq!(r.action(id("pick(A)")), id("pick(C)"));
        assert_eq!(r.action(id("place(B)")), id("place(A)"));
        assert_eq!(r.action(id("pick(H)")), id("pick(H)"));
        assert_eq!(
            r.action(ctg_graph::Vocabulary::END),
            ctg_graph::Vocabulary::END
        );

        let row: Vec<f32> = (0..env_blocks::STATE_DIM).map(|i| i as f32).collect();
        let renamed = sym.apply_to_row(&r, &row);
        assert_eq!(
            &renamed[6..9],
            &row[0..3],
            "cube A's position is now cube C's"
        );
        assert_eq!(
            &renamed[0..3],
            &row[3..6],
            "cube B's position is now cube A's"
        );
        assert_eq!(&renamed[9..], &row[9..], "other cubes and the gripper stay");

        let path = vocab
            .parse_sequence("pick(A) place(B) pick(C) place(A)")
            .unwrap();
        let graph = Ctg::from_path(n, &path).unwrap();
        let renamed_graph = r.graph(&graph).unwrap();
        let expected = Ctg::from_path(n, &r.sequence(&path)).unwrap();
        assert_eq!(renamed_graph, expected);
        assert_eq!(
            vocab.format_sequence(&r.sequence(&path)),
            "pick(C) place(A) pick(B) place(C)"
        );
    }

    #[test]
    fn a_primitive_video_is_the_frames_ntp_acts_on_labelled_with_its_primitives() {
        let task = env_blocks::standard_split().unwrap().train_pool[3].clone();
        let video =
            record_primitive_video(task.clone(), true, env_blocks::Camera::default(), 11).unwrap();
        let demo = env_blocks::record_ntp_demo(
            &env_blocks::BlocksTask::Stack(task),
            env_config(ObsKind::Vid, true),
            11,
        )
        .unwrap();
        // One frame per segment: every frame is a keyframe, the scene
        // before each primitive and the last.
        assert_eq!(video.actions(), demo.actions.as_slice());
        assert_eq!(video.num_frames(), demo.actions.len() + 1);
        let keyframes = video.keyframes();
        assert_eq!(keyframes.observations().len(), video.num_frames());
        // The same rows NTP's video dataset encodes.
        for (frame, obs) in keyframes.observations().iter().zip(&demo.observations) {
            assert_eq!(frame, &featurize(obs, ObsKind::Vid));
        }
        // Carrying a cube above its target and having let it go are two
        // labels: every `move` of a `place` is followed by a `drop`.
        let vocab = primitive_vocabulary();
        let names: Vec<String> = demo
            .actions
            .iter()
            .map(|&a| vocab.format_sequence(&[a]))
            .collect();
        let drops = names.iter().filter(|n| *n == "drop").count();
        assert!(drops > 0, "{names:?}");
        for (i, n) in names.iter().enumerate() {
            if n == "drop" {
                assert!(names[i - 1].starts_with("move("), "{names:?}");
            }
        }
    }

    #[test]
    fn only_ntp_and_ntp_flat_take_primitive_frame_labels() {
        let mut config = Recipe::Paper.config(ObsKind::Vid, 5, 2, 1, 0);
        config.video.as_mut().unwrap().encoder_labels = FrameLabels::Primitive;
        for (method, ok) in [
            (MethodId::Ntg, false),
            (MethodId::NtpDetector, false),
            (MethodId::Ntp, true),
            (MethodId::NtpFlat, true),
        ] {
            config.method = method;
            assert_eq!(check_encoder_labels(&config).is_ok(), ok, "{method:?}");
        }
        // Saved without the field when flat: older run folders still match.
        config.video.as_mut().unwrap().encoder_labels = FrameLabels::Flat;
        let json = serde_json::to_string(&config).unwrap();
        assert!(!json.contains("encoder_labels"), "{json}");
    }

    #[test]
    fn a_state_run_takes_its_node_from_the_executed_actions_when_asked() {
        let mut config = Recipe::Paper.config(ObsKind::State, 5, 2, 1, 0);
        let json = serde_json::to_string(&config).unwrap();
        assert!(!json.contains("executed_node"), "absent when off: {json}");
        let model = new_model(&config, &ntg_model::cpu_device()).unwrap();
        assert_eq!(model.config.ablation.executed_node, None);
        config.executed_node = true;
        check_executed_node(&config).unwrap();
        let model = new_model(&config, &ntg_model::cpu_device()).unwrap();
        assert_eq!(model.config.ablation.executed_node, Some(true));
        assert!(
            additions(&config)
                .iter()
                .any(|a| a == "executed node (not the localizer)"),
            "{:?}",
            additions(&config)
        );
        config.method = MethodId::Ntp;
        assert!(check_executed_node(&config).is_err());
        let mut video = Recipe::Paper.config(ObsKind::Vid, 5, 2, 1, 0);
        video.executed_node = true;
        let e = check_executed_node(&video).unwrap_err().to_string();
        assert!(e.contains("video.executed_node"), "{e}");
    }

    #[test]
    fn a_height_clamp_reaches_the_encoders_that_judge_a_state_and_its_row_names_it() {
        let mut config = Recipe::Recommended.config(ObsKind::State, 5, 2, 1, 0);
        let json = serde_json::to_string(&config).unwrap();
        assert!(
            !json.contains("state_height_clamp"),
            "absent when off: {json}"
        );
        config.state_height_clamp = Some(0.075);
        check_state_height_clamp(&config).unwrap();
        let model = new_model(&config, &ntg_model::cpu_device()).unwrap();
        let clamp = |e: &ntg_model::EncoderConfig| match e {
            ntg_model::EncoderConfig::State(s) => (s.height_clamp, s.clamped_objects),
            other => panic!("a state encoder expected, got {other:?}"),
        };
        let clamped = (Some(0.075), Some(env_blocks::world::NUM_OBJECTS));
        assert_eq!(clamp(&model.config.localizer.encoder), clamped);
        assert_eq!(clamp(&model.config.edge.encoder), clamped);
        // The demo interpreter reads heights as they are.
        assert_eq!(clamp(&model.config.interpreter.encoder), (None, None));
        assert!(
            additions(&config)
                .iter()
                .any(|a| a == "heights read to 0.075 m"),
            "{:?}",
            additions(&config)
        );
        // A baseline's state encoder reads them clamped too.
        config.method = MethodId::Ntp;
        assert_eq!(clamp(&observation_encoder(&config)), clamped);
        for bad in [0.0, -0.1, f32::NAN] {
            config.state_height_clamp = Some(bad);
            assert!(check_state_height_clamp(&config).is_err(), "{bad}");
        }
        let mut video = Recipe::Paper.config(ObsKind::Vid, 5, 2, 1, 0);
        video.state_height_clamp = Some(0.075);
        let e = check_state_height_clamp(&video).unwrap_err().to_string();
        assert!(e.contains("frames"), "{e}");
        video.state_height_clamp = None;
        assert!(matches!(
            observation_encoder(&video),
            ntg_model::EncoderConfig::State(s) if s.height_clamp.is_none()
        ));
    }

    #[test]
    fn an_execution_memory_is_ntg_s_and_its_row_names_it() {
        let mut config = Recipe::Recommended.config(ObsKind::State, 5, 2, 1, 0);
        let json = serde_json::to_string(&config).unwrap();
        assert!(!json.contains("memory"), "absent when off: {json}");
        assert_eq!(
            new_model(&config, &ntg_model::cpu_device())
                .unwrap()
                .edges
                .memory_dim,
            0
        );
        config.memory = true;
        check_memory(&config).unwrap();
        let model = new_model(&config, &ntg_model::cpu_device()).unwrap();
        assert_eq!(model.edges.memory_dim, flat_vocabulary().len());
        assert!(
            additions(&config).iter().any(|a| a == "execution memory"),
            "{:?}",
            additions(&config)
        );
        config.method = MethodId::Ntp;
        let e = check_memory(&config).unwrap_err().to_string();
        assert!(e.contains("no edge classifier"), "{e}");
    }

    #[test]
    fn the_end_rule_is_ntg_s_and_its_row_names_it() {
        let mut config = Recipe::Paper.config(ObsKind::State, 5, 2, 1, 0);
        let json = serde_json::to_string(&config).unwrap();
        assert!(!json.contains("end_after_demo"), "absent when off: {json}");
        let device = ntg_model::cpu_device();
        let model = new_model(&config, &device).unwrap();
        assert_eq!(model.config.ablation.end_after_demo, None);
        config.end_after_demo = true;
        check_end_after_demo(&config).unwrap();
        let model = new_model(&config, &device).unwrap();
        assert_eq!(model.config.ablation.end_after_demo, Some(true));
        assert!(
            additions(&config)
                .iter()
                .any(|a| a == "ends only after the demo's actions"),
            "{:?}",
            additions(&config)
        );
        config.method = MethodId::Ntp;
        let e = check_end_after_demo(&config).unwrap_err().to_string();
        assert!(e.contains("no demo interpreter"), "{e}");
    }

    #[test]
    fn the_aligned_interpreter_reads_state_demos_only_and_its_row_names_it() {
        use crate::method::ntg::InterpreterKind;
        let mut config = Recipe::Recommended.config(ObsKind::State, 5, 2, 1, 0);
        config.interpreter = Some(InterpreterKind::SteppingAligned);
        config.location_step_prior = Some(0.3);
        check_interpreter_input(&config).unwrap();
        let model = new_model(&config, &ntg_model::cpu_device()).unwrap();
        assert_eq!(model.config.interpreter.aligned_attention, Some(true));
        assert!(model.interpreter.aligned);
        assert!(
            additions(&config)
                .iter()
                .any(|a| a == "stepping interpreter, attention taught one demo row per action"),
            "{:?}",
            additions(&config)
        );
        let mut video = Recipe::Recommended.config(ObsKind::Vid, 5, 2, 1, 0);
        video.interpreter = Some(InterpreterKind::SteppingAligned);
        let e = check_interpreter_input(&video).unwrap_err().to_string();
        assert!(e.contains("stepping-aligned") && e.contains("video"), "{e}");
        video.interpreter = Some(InterpreterKind::Stepping);
        check_interpreter_input(&video).unwrap();
        // On video, the stepping-video interpreter taught the frame each
        // action ends on, over the recipe's pooled frames.
        video.interpreter = Some(InterpreterKind::SteppingVideoAligned);
        video.location_step_prior = Some(0.3);
        check_interpreter_input(&video).unwrap();
        let model = new_model(&video, &ntg_model::cpu_device()).unwrap();
        let interpreter = &model.config.interpreter;
        assert_eq!(interpreter.aligned_attention, Some(true));
        assert_eq!(interpreter.frame_pool, Some(4));
        assert_eq!(
            interpreter.location_max_shift,
            Some(crate::method::ntg::VIDEO_MAX_SHIFT)
        );
        assert!(
            additions(&video).iter().any(
                |a| a == "stepping interpreter, attention taught the frame each action ends on"
            ),
            "{:?}",
            additions(&video)
        );
    }

    #[test]
    fn only_the_ntp_family_takes_a_recurrent_core_and_its_rows_name_it() {
        let mut config = Recipe::Paper.config(ObsKind::State, 5, 2, 1, 0);
        config.ntp_core = NtpCoreKind::Gru;
        for (method, ok) in [
            (MethodId::Ntg, false),
            (MethodId::NtpDetector, true),
            (MethodId::Ntp, true),
            (MethodId::NtpFlat, true),
        ] {
            config.method = method;
            assert_eq!(check_ntp_core(&config).is_ok(), ok, "{method:?}");
        }
        let json = serde_json::to_string(&config).unwrap();
        assert!(json.contains(r#""ntp_core":"gru""#), "{json}");
        assert_eq!(
            addition_name("ntp_core", &"gru".into()),
            "recurrent (GRU) core"
        );
        // Saved without the field when reactive: older run folders match.
        config.ntp_core = NtpCoreKind::Reactive;
        let json = serde_json::to_string(&config).unwrap();
        assert!(!json.contains("ntp_core"), "{json}");
    }

    #[test]
    fn a_panel_pins_the_paper_s_interpreter_as_the_absent_field() {
        // The recommended recipe on states sets the taught stepping
        // interpreter; `interpreter = "luong"` and `location_step_prior =
        // 0.0` give back the configuration without them, field for field.
        let recipe = Recipe::Recommended.config(ObsKind::State, 5, 2, 1, 0);
        assert!(recipe.interpreter.is_some() && recipe.location_step_prior.is_some());
        let pins: toml::Table = toml::from_str(
            "interpreter = \"luong\"\nlocation_step_prior = 0.0\nexecuted_node = false\nend_after_demo = false",
        )
        .unwrap();
        let pinned = crate::experiment::with_overrides(&recipe, &pins, "test").unwrap();
        let mut expected = recipe.clone();
        expected.interpreter = None;
        expected.location_step_prior = None;
        expected.executed_node = false;
        expected.end_after_demo = false;
        // (The shard count is not saved: it reads back as 0.)
        expected.optim.shards = pinned.optim.shards;
        assert_eq!(pinned, expected);
        let json = serde_json::to_string(&pinned).unwrap();
        assert!(!json.contains("interpreter") && !json.contains("location_step_prior"));
        // Any other interpreter reads as itself.
        let pins: toml::Table = toml::from_str("interpreter = \"stepping\"").unwrap();
        let stepping = crate::experiment::with_overrides(&recipe, &pins, "test").unwrap();
        assert_eq!(
            stepping.interpreter,
            Some(crate::method::ntg::InterpreterKind::Stepping)
        );
    }
}
