//! The object-collection experiment (the paper's fig. "thor_all" (b)):
//! train NTG and the Flat Policy on tasks with N = 2 and 4 target objects,
//! evaluate both on unseen tasks with N = 1..5.
//!
//! Tasks come from env-collect's fixed train/test split by task identity
//! ([`env_collect::TaskSplitter`]'s default): training tasks from the train side, test
//! tasks from the test side, so every evaluated task is unseen. Seeds:
//! training demo `j` of training task `i` is recorded with seed
//! `TRAIN_SEED_BASE + 1000 i + j`; test episode `i` with `N` objects uses
//! the conditioning demo seed `DEMO_SEED_BASE + 1000 N + i` and the rollout
//! seed `ROLLOUT_SEED_BASE + 1000 N + i`, so the policy acts in a scene
//! (object places, search order, appearances) it has not seen in the demo.
//!
//! Observations: the symbolic state vector (`--obs state`, what the
//! reproduce profiles use, because training the frame encoders is too slow
//! on 2 CPU cores for the profiles' budgets) or the rendered 64×64 frame
//! (`--obs vid`).

use anyhow::{Context, bail, ensure};
use burn::tensor::Device;

use env_collect::{CollectConfig, CollectEnv, CollectExpert, CollectObservation, Split, Task};
use ntg_model::EncoderConfig;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::DemoDataset;
use crate::domain::{
    self, Domain, DomainFlags, DomainRuns, Episode, EpisodeRecord, EvalFlags, TrainFlags,
};
use crate::fit::{OptimConfig, ValidationScore};
use crate::method::input::Validation;
use crate::method::{Demos, EpochReport, MethodId, Model, RowEncoders, TrainInput, TrainedPolicy};
use crate::run_dir::RunDir;
use crate::spec::ObsKind;
use crate::stats::SuccessRate;
use crate::video::{EncoderStage, VideoRun};

/// Seed base of training demonstrations.
pub const TRAIN_SEED_BASE: u64 = 40_000_000;
/// Seed base of the conditioning demonstration of each test episode.
pub const DEMO_SEED_BASE: u64 = 50_000_000;
/// Seed base of the rollout scene of each test episode.
pub const ROLLOUT_SEED_BASE: u64 = 60_000_000;
/// Seed of the draw of training tasks (with N added).
pub const TRAIN_TASK_SEED: u64 = 70_000;
/// Seed of the order of test tasks (with N added).
pub const TEST_TASK_SEED: u64 = 80_000;
/// Seed of the order of validation tasks (with N added).
pub const VALIDATION_TASK_SEED: u64 = 90_000;
/// Seed base of the demo videos of validation tasks.
pub const VALIDATION_SEED_BASE: u64 = 80_000_000;
/// Validation tasks per N whose demo videos score stage A of a video run.
pub const VALIDATION_TASKS_PER_N: usize = 25;
/// The numbers of objects evaluated.
pub const EVAL_OBJECTS: [usize; 5] = [1, 2, 3, 4, 5];

/// Values per observation row.
pub fn obs_dim(kind: ObsKind) -> usize {
    match kind {
        ObsKind::State => env_collect::STATE_LEN,
        ObsKind::Vid => env_collect::FRAME_DIM,
    }
}

/// The matching encoder.
pub fn encoder(kind: ObsKind) -> EncoderConfig {
    match kind {
        ObsKind::State => EncoderConfig::state(env_collect::STATE_LEN),
        ObsKind::Vid => EncoderConfig::frame(),
    }
}

/// The observation as a flat row: the state vector, or the frame in CHW
/// order scaled to `[0, 1]` (an empty row if the frame was not rendered,
/// which the models reject).
pub fn featurize(obs: &CollectObservation, kind: ObsKind) -> Vec<f32> {
    match kind {
        ObsKind::State => obs.state.clone(),
        ObsKind::Vid => obs.frame_chw().unwrap_or_default(),
    }
}

/// The environment configuration for `kind` (frames rendered only for `vid`).
pub fn env_config(kind: ObsKind) -> CollectConfig {
    CollectConfig {
        render: kind == ObsKind::Vid,
        ..CollectConfig::default()
    }
}

pub use crate::method::ntg::InterpreterKind;

/// Object collection's defaults for NTG's interpreter.
pub trait InterpreterDefaults: Sized {
    /// The interpreter new NTG runs on `obs` use: stepping on state
    /// sequences (one row per action, any length), stepping with the
    /// video window on demo videos. The stepping interpreter's
    /// location-aware attention moves −1..=2 frames per token, and a video
    /// has 2–9 frames per action: on videos its training token accuracy
    /// stalled at 0.76 (`docs/results/video-2026-11-24.md`); with shifts
    /// up to 10 it transcribed 46 of 50 validation demos with N = 6
    /// exactly, the paper's interpreter 12
    /// (`docs/results/interpreter-length-2026-12-06.md`).
    fn default_for(obs: ObsKind) -> Self;
    /// The initial weight of the location-aware attention's shift +1 that
    /// new runs of this kind start from ([`LOCATION_STEP_PRIOR`] for
    /// `Stepping`; the paper's interpreter has no location-aware attention).
    fn default_step_prior(self) -> Option<f32>;
}

impl InterpreterDefaults for InterpreterKind {
    fn default_for(obs: ObsKind) -> Self {
        match obs {
            ObsKind::State => InterpreterKind::Stepping,
            ObsKind::Vid => InterpreterKind::SteppingVideo,
        }
    }

    fn default_step_prior(self) -> Option<f32> {
        match self {
            InterpreterKind::Luong => None,
            InterpreterKind::Stepping
            | InterpreterKind::SteppingVideo
            | InterpreterKind::SteppingAligned
            | InterpreterKind::SteppingVideoAligned => Some(LOCATION_STEP_PRIOR),
        }
    }
}

/// The location step prior a new run of `method` with `interpreter`
/// starts from: the interpreter's, for a method that reads one.
pub fn default_step_prior(method: MethodId, interpreter: InterpreterKind) -> Option<f32> {
    let reads = method.method().reads("location_step_prior");
    reads.then(|| interpreter.default_step_prior()).flatten()
}

/// The initial weight `w₊₁` of the stepping interpreter's location-aware
/// attention for the frame after the one read last (see
/// `DemoInterpreterConfig::location_step_prior`): the attention starts
/// biased by `G·w₊₁` = 3 towards moving on one frame per token. Without it
/// (weights starting at 0), one of four seeds (1) never found the stepping
/// alignment: training token accuracy stalled at 0.89 (0.90 after 60
/// epochs) and NTG fell to 0.07 / 0.004 / 0 at N = 3 / 4 / 5; with it,
/// seeds 0–3 all reach 1.0 within 5 epochs (quick profile scale). Checked
/// on validation tasks (held-out train-side tasks, not test episodes) at
/// seeds 0 and 1: prior 0 left seed 1 at validation success 0.09, 0.3 and
/// 1.0 tied (`docs/results/thor_all-validation-2026-11-27.md`).
pub const LOCATION_STEP_PRIOR: f32 = 0.3;

/// Everything that defines an object-collection training run (`config.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CollectRunConfig {
    /// Always `"collect"` (tells `ntg eval` which domain a run is).
    pub domain: String,
    /// Which model.
    pub method: MethodId,
    /// Observation kind.
    pub obs: ObsKind,
    /// Numbers of target objects of the training tasks.
    pub train_objects: Vec<usize>,
    /// Distinct training tasks per number of objects.
    pub tasks_per_n: usize,
    /// Expert demonstrations per training task.
    pub demos_per_task: usize,
    /// NTG only: the demo interpreter also learns from one random
    /// contiguous stretch of each training demo (any stretch of a
    /// demonstration, with the actions inside it, is itself a
    /// demonstration), so it does not tie the number of cycles it writes
    /// to the lengths seen in training.
    pub segments: bool,
    /// Train the policy's final `<end>` decision (both methods). The frame
    /// after the last drop-off does not show whether every target has been
    /// delivered (only the current receptacle is visible), so this label
    /// cannot be predicted from the observation; without it, the policies
    /// never choose `<end>` and episodes end at the step limit, where
    /// success is judged the same way.
    pub learn_end: bool,
    /// Give both policies an execution memory, the agent's record of the
    /// actions it has taken so far in the episode (what a single
    /// observation cannot show: e.g. how many objects are delivered). The
    /// Flat Policy adds the set of actions taken to its attention query
    /// ([`ntg_model::executed_actions`]); NTG's edge classifier reads the
    /// nodes of its task graph not yet executed
    /// ([`ntg_model::pending_nodes`]). Absent in configurations saved
    /// before it: false.
    #[serde(default)]
    pub memory: bool,
    /// NTG only: the demo interpreter.
    pub interpreter: InterpreterKind,
    /// NTG with the stepping interpreter only: the initial weight of its
    /// location-aware attention's shift +1 ([`LOCATION_STEP_PRIOR`] in new
    /// runs; `None`, as in runs saved before it, starts it at 0).
    #[serde(default)]
    pub location_step_prior: Option<f32>,
    /// Seed of the initial weights.
    pub model_seed: u64,
    /// Optimisation; the learning rate follows
    /// [`OptimConfig::learning_rate_at`] (constant, or with `cosine_decay`
    /// a half cosine per step down to a tenth), as in block stacking.
    pub optim: OptimConfig,
    /// `--obs vid` from demo videos, trained in stages
    /// ([`crate::video`]): how the videos are timed and how the shared
    /// frame encoder trains. Absent (runs saved before it, or `obs` state):
    /// one frame per action, each network's CNN trained end to end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<CollectVideo>,
    /// Validation tasks per number of training objects
    /// ([`validation_tasks`]: train-side tasks the run does not train on,
    /// never test tasks), each rolled out once after every epoch from a
    /// demo of its own; the best epoch (success, then goals met) is kept
    /// in `best/` and is the one evaluated. 0, as in configurations saved
    /// before it: no validation, the last epoch is evaluated.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub validation_tasks_per_n: usize,
    /// Numbers of objects validated on besides the training ones, each
    /// with `validation_tasks_per_n` train-side tasks: lengths no test
    /// episode has (above every N of [`EVAL_OBJECTS`]), so that a setting
    /// that should carry to demos longer than any trained on is chosen on
    /// longer demos without looking at test episodes. Empty, as in
    /// configurations saved before it: the training numbers only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation_objects: Vec<usize>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// How an object-collection run on frames records its demo videos and
/// trains its shared frame encoder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct CollectVideo {
    /// Frames per phase of each action's motion.
    pub frames: env_collect::VideoConfig,
    /// Stage A: the shared frame encoder.
    pub encoder: EncoderStage,
}

impl CollectRunConfig {
    /// What `ntg train --domain collect --method METHOD` trains without
    /// other flags: `tasks_per_n` tasks per N in `train_objects` x
    /// `demos_per_task` demos, `epochs` epochs in batches of 32 at the
    /// paper's learning rate (constant), weights and shuffling seeded by
    /// `seed`; NTG with the interpreter of [`InterpreterKind::default_for`]
    /// `obs` (and the stepping one's location step prior), learning from
    /// random stretches of demos too; neither `<end>` nor a memory.
    pub fn new(
        method: MethodId,
        obs: ObsKind,
        train_objects: Vec<usize>,
        tasks_per_n: usize,
        demos_per_task: usize,
        epochs: usize,
        seed: u64,
    ) -> Self {
        let interpreter = InterpreterKind::default_for(obs);
        CollectRunConfig {
            domain: "collect".into(),
            method,
            obs,
            train_objects,
            tasks_per_n,
            demos_per_task,
            segments: true,
            learn_end: false,
            memory: false,
            interpreter,
            location_step_prior: default_step_prior(method, interpreter),
            model_seed: seed,
            optim: OptimConfig {
                epochs,
                batch_size: 32,
                learning_rate: crate::fit::PAPER_LEARNING_RATE,
                seed,
                token_dropout: 0.0,
                cosine_decay: false,
                shards: 1,
                gcn_from_other_demo: false,
            },
            video: (obs == ObsKind::Vid).then(CollectVideo::default),
            validation_tasks_per_n: 0,
            validation_objects: Vec::new(),
        }
    }

    /// Whether `other` records the same training and validation videos as
    /// this configuration and trains the same stage A encoder on them, so
    /// that its `stage_a/` and `embeddings/` are this run's too: what
    /// differs may only be the method and how stage B trains.
    pub fn same_videos(&self, other: &Self) -> bool {
        self.video.is_some()
            && self.obs == other.obs
            && self.train_objects == other.train_objects
            && self.tasks_per_n == other.tasks_per_n
            && self.demos_per_task == other.demos_per_task
            && self.video == other.video
            && self.model_seed == other.model_seed
    }

    /// Checks the values.
    pub fn validate(&self) -> anyhow::Result<()> {
        ensure!(self.domain == "collect", "domain must be \"collect\"");
        ensure!(
            !self.train_objects.is_empty()
                && self.train_objects.iter().all(|n| (1..=5).contains(n)),
            "training numbers of objects must be in 1..=5, got {:?}",
            self.train_objects
        );
        ensure!(
            self.tasks_per_n > 0 && self.demos_per_task > 0,
            "tasks per N and demos per task must be positive"
        );
        let longest_test = EVAL_OBJECTS.iter().copied().max().unwrap_or(0);
        ensure!(
            self.validation_objects
                .iter()
                .all(|&n| n > longest_test && n <= env_collect::domain::MAX_OBJECTS),
            "--validation-objects {:?}: validation lengths must be ones no test episode has, in {}..={}",
            self.validation_objects,
            longest_test + 1,
            env_collect::domain::MAX_OBJECTS
        );
        ensure!(
            self.validation_objects.is_empty() || self.validation_tasks_per_n > 0,
            "--validation-objects needs --validation-tasks-per-n above 0"
        );
        ensure!(
            self.demos_per_task >= 2,
            "training pairs each demo with another demo of its task: at least 2 demos per task are needed"
        );
        ensure!(self.optim.batch_size > 0, "batch size must be positive");
        ensure!(
            !(self.interpreter.states_only() && self.obs == ObsKind::Vid),
            "--interpreter {}: its attention is trained one demo row per action, as state demos have; a demo video spans several frames per action (--interpreter stepping-video reads them)",
            ntg_train::spec::Choice::name(self.interpreter)
        );
        if let Some(video) = &self.video {
            ensure!(
                self.obs == ObsKind::Vid,
                "demo video settings need --obs vid"
            );
            video.frames.validate()?;
        }
        // JSON has no NaN (it would be read back as no prior at all).
        if let Some(w) = self.location_step_prior {
            ensure!(
                w.is_finite(),
                "--location-step-prior must be finite, got {w}"
            );
        }
        // The method's own options (NTG's interpreter and step prior).
        self.method.method().check(&serde_json::to_value(self)?)?;
        Ok(())
    }
}

/// The training tasks of a run: `tasks_per_n` distinct train-side tasks for
/// each N, in order of `train_objects`.
pub fn training_tasks(config: &CollectRunConfig) -> anyhow::Result<Vec<Task>> {
    let splitter = env_collect::TaskSplitter::default();
    let mut tasks = Vec::new();
    for &n in &config.train_objects {
        tasks.extend(
            splitter
                .sample_distinct(
                    n,
                    config.tasks_per_n,
                    Some(Split::Train),
                    TRAIN_TASK_SEED + n as u64,
                )
                .with_context(|| format!("drawing training tasks with {n} objects"))?,
        );
    }
    Ok(tasks)
}

/// Up to `per_n` train-side tasks for each N in the run's training
/// numbers of objects, then in its `validation_objects`, that the run does
/// not train on (in a seeded order): held out from training, never from
/// the test side, so that settings are chosen without looking at test
/// tasks.
pub fn validation_tasks(config: &CollectRunConfig, per_n: usize) -> anyhow::Result<Vec<Task>> {
    let splitter = env_collect::TaskSplitter::default();
    let training = training_tasks(config)?;
    let mut tasks = Vec::new();
    for &n in config
        .train_objects
        .iter()
        .chain(&config.validation_objects)
    {
        let mut pool = splitter.tasks_with(n, Some(Split::Train))?;
        pool.shuffle(&mut ChaCha8Rng::seed_from_u64(
            VALIDATION_TASK_SEED + n as u64,
        ));
        tasks.extend(
            pool.into_iter()
                .filter(|t| !training.contains(t))
                .take(per_n),
        );
    }
    Ok(tasks)
}

/// Seed base of the conditioning demo and the rollout scene of each
/// validation episode (after [`VALIDATION_SEED_BASE`]'s stage-A videos).
pub const VALIDATION_EPISODE_SEED_BASE: u64 = 85_000_000;

/// The run's validation episodes: one per task of [`validation_tasks`]
/// (`config.validation_tasks_per_n` per N), grouped by N, each with its
/// own demo and scene seeds.
pub fn validation_episodes(config: &CollectRunConfig) -> anyhow::Result<Vec<Episode<Task>>> {
    let tasks = validation_tasks(config, config.validation_tasks_per_n)?;
    Ok(tasks
        .into_iter()
        .enumerate()
        .map(|(i, task)| Episode {
            group: task.num_objects(),
            index: i,
            task,
            demo_seed: VALIDATION_EPISODE_SEED_BASE + 2 * i as u64,
            rollout_seed: VALIDATION_EPISODE_SEED_BASE + 2 * i as u64 + 1,
        })
        .collect())
}

/// Records the training demonstrations of a run, in parallel.
pub fn build_dataset(config: &CollectRunConfig) -> anyhow::Result<DemoDataset> {
    let tasks = training_tasks(config)?;
    let domain = CollectDomain::new(config.obs);
    domain::record_demos(&domain, &tasks, config.demos_per_task, TRAIN_SEED_BASE)
}

/// Trains (or resumes) a run in `run` with the method its configuration
/// names, returning the model; `on_epoch` gets each epoch's report. Every
/// method imitates each training demo conditioned on *another* demo of its
/// task (the Flat Policy attends over it; NTG's GCN completes its path,
/// whose `NE_gcn` the edge classifier reads), as at test time: trained on
/// its own demo's path, NTG's edge classifier learns that the node before
/// `<end>` in *that* path ends the task, and at test time, in a scene where
/// objects are found in another order, ends the episode there.
pub fn train_run(
    run: &RunDir,
    config: &CollectRunConfig,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    // One writer from the first cache this run builds (demos, frame
    // embeddings, stages) to its last epoch, not only during epochs.
    let _writer = run.lock()?;
    config.validate()?;
    // On demo videos: stage A trains the shared encoder, stage B the
    // method on the frames' embeddings (see `crate::video`).
    let demos = || -> anyhow::Result<Demos> {
        let Some(video) = &config.video else {
            let dataset = DemoDataset::load_or_build(&run.dataset_dir(), || build_dataset(config))?;
            return Ok(Demos {
                dataset,
                frames: None,
            });
        };
        let tasks = training_tasks(config)?;
        let record = |t: usize, seed: u64| record_video_chw(&tasks[t], seed, &video.frames);
        let validation = validation_tasks(config, VALIDATION_TASKS_PER_N)?;
        let record_validation =
            |i: usize, seed: u64| record_video_chw(&validation[i], seed, &video.frames);
        let video_run = VideoRun {
            vocabulary: env_collect::vocabulary(),
            pairs: crate::video::spread_pairs(tasks.len(), config.demos_per_task, TRAIN_SEED_BASE),
            record: &record,
            frame_dim: env_collect::FRAME_DIM,
            encoder: &video.encoder,
            seed: config.model_seed,
            validation: Some(crate::video::ValidationVideos {
                pairs: (0..validation.len())
                    .map(|i| (i, VALIDATION_SEED_BASE + i as u64))
                    .collect(),
                record: &record_validation,
            }),
        };
        let frames = crate::video::train_encoder(run, &video_run, device)?;
        let dataset = crate::video::embeddings(run, &video_run, &frames)?;
        Ok(Demos {
            dataset,
            frames: Some(frames),
        })
    };
    let row_encoder = match &config.video {
        Some(video) => EncoderConfig::state(video.encoder.embedding_dim()),
        None => encoder(config.obs),
    };
    let episodes = validation_episodes(config)?;
    let domain = CollectDomain::for_run(config);
    let score = |model: &dyn TrainedPolicy| -> anyhow::Result<ValidationScore> {
        let records = domain::evaluate(&domain, model, &episodes)?;
        Ok(ValidationScore {
            success: domain::success_rate(&records).rate,
            goal_fraction: domain::mean_goal_fraction(&records),
        })
    };
    let input = TrainInput {
        vocabulary: env_collect::vocabulary(),
        demos: &demos,
        encoders: RowEncoders::same(row_encoder),
        renaming: None,
        validation: (!episodes.is_empty()).then_some(Validation {
            score: &score,
            every: 1,
        }),
        other_demo_each_epoch: true,
        model_seed: config.model_seed,
        optim: &config.optim,
        run,
        device,
        extension: None,
    };
    config
        .method
        .method()
        .train(input, &serde_json::to_value(config)?, &mut on_epoch)
}

/// The demo video of `task` recorded with `seed`, frames featurised.
fn record_video_chw(
    task: &Task,
    seed: u64,
    frames: &env_collect::VideoConfig,
) -> anyhow::Result<ctg_graph::VideoDemonstration<Vec<f32>>> {
    let v = env_collect::record_video_demo(task.clone(), env_config(ObsKind::Vid), seed, frames)?;
    Ok(v.map_frames(|f| env_collect::frame_to_chw(&f)))
}

/// Loads the trained model of a run (inference device).
pub fn load_model(run: &RunDir, config: &CollectRunConfig) -> anyhow::Result<Model> {
    let device = crate::spec::device();
    // The epoch validation selected, if the run validated.
    let dir = match crate::fit::selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    let model = config
        .method
        .load(&dir, &device)
        .with_context(|| format!("{} has no trained model yet", run.root().display()))?;
    crate::method::on_frames::check_model_obs(&dir, config.obs, &run.config_path())?;
    Ok(model)
}

/// Success at one N.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NPoint {
    /// Number of target objects.
    pub objects: usize,
    /// Success rate over the test episodes, with its 95% Wilson interval.
    pub success: SuccessRate,
    /// Episodes that ended by the policy choosing `<end>` (the others ran
    /// to the step limit). Absent in evaluations saved before it: 0.
    #[serde(default)]
    pub ended: usize,
}

/// The evaluation of one model on unseen tasks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CollectEval {
    /// Which method.
    pub method: MethodId,
    /// Success per N.
    pub points: Vec<NPoint>,
    /// Every episode.
    pub episodes: Vec<EpisodeRecord>,
}

/// The test episodes with `n` objects (group `n`); tasks cycle through the
/// test side's tasks with `n` objects in a seeded order (there are few with
/// N = 1, so those repeat with other scenes).
pub fn test_episodes(n: usize, episodes: usize) -> anyhow::Result<Vec<Episode<Task>>> {
    let splitter = env_collect::TaskSplitter::default();
    let mut pool = splitter.tasks_with(n, Some(Split::Test))?;
    ensure!(!pool.is_empty(), "no test task with {n} objects");
    pool.shuffle(&mut ChaCha8Rng::seed_from_u64(TEST_TASK_SEED + n as u64));
    Ok((0..episodes)
        .map(|i| {
            let k = 1000 * n as u64 + i as u64;
            Episode {
                group: n,
                index: i,
                task: pool[i % pool.len()].clone(),
                demo_seed: DEMO_SEED_BASE + k,
                rollout_seed: ROLLOUT_SEED_BASE + k,
            }
        })
        .collect())
}

/// Object collection as a [`Domain`], seen through an observation kind.
#[derive(Debug, Clone)]
pub struct CollectDomain {
    obs: ObsKind,
    /// Conditioning demos are videos timed by this (`--obs vid` runs
    /// trained in stages), else one row per action.
    video: Option<env_collect::VideoConfig>,
}

impl CollectDomain {
    /// The domain seen through `obs` (frames are rendered only for `vid`),
    /// one conditioning row per action.
    pub fn new(obs: ObsKind) -> Self {
        CollectDomain { obs, video: None }
    }

    /// The domain as `config`'s run sees it (demo videos for runs trained
    /// on them).
    pub fn for_run(config: &CollectRunConfig) -> Self {
        CollectDomain {
            obs: config.obs,
            video: config.video.as_ref().map(|v| v.frames.clone()),
        }
    }
}

impl Domain for CollectDomain {
    type Task = Task;
    type Env = CollectEnv;
    type Expert = CollectExpert;

    fn vocabulary(&self) -> &ctg_graph::Vocabulary {
        env_collect::vocabulary()
    }
    fn env(&self, task: &Task) -> anyhow::Result<CollectEnv> {
        Ok(CollectEnv::new(task.clone(), env_config(self.obs))?)
    }
    fn expert(&self) -> CollectExpert {
        CollectExpert
    }
    fn obs_kind(&self) -> ObsKind {
        self.obs
    }
    fn obs_dim(&self) -> usize {
        obs_dim(self.obs)
    }
    fn featurize(&self, observation: &CollectObservation) -> Vec<f32> {
        featurize(observation, self.obs)
    }
    fn task_name(&self, task: &Task) -> String {
        task.to_string()
    }
    fn goals(&self, task: &Task, env: &CollectEnv) -> (usize, usize) {
        (env.delivered(), task.num_objects())
    }
    fn record_demo(
        &self,
        env: &mut CollectEnv,
        task: &Task,
        seed: u64,
    ) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ctg_graph::ActionId>)> {
        let Some(video) = &self.video else {
            return domain::record_keyframes(self, env, seed);
        };
        let video =
            env_collect::record_video_demo(task.clone(), env_config(self.obs), seed, video)?;
        let rows = video
            .frames()
            .iter()
            .map(env_collect::frame_to_chw)
            .collect();
        Ok((rows, video.actions().to_vec()))
    }
}

/// Evaluates `model` on `episodes` unseen test episodes for each N in
/// `objects`, in parallel.
pub fn evaluate(
    model: &dyn TrainedPolicy,
    config: &CollectRunConfig,
    objects: &[usize],
    episodes: usize,
) -> anyhow::Result<CollectEval> {
    let mut all = Vec::new();
    for &n in objects {
        all.extend(test_episodes(n, episodes)?);
    }
    let records = domain::evaluate(&CollectDomain::for_run(config), model, &all)?;
    let method = config.method;
    let points = objects
        .iter()
        .map(|&n| NPoint {
            objects: n,
            success: domain::success_rate(records.iter().filter(|r| r.group == n)),
            ended: records
                .iter()
                .filter(|r| r.group == n && r.trace.last().map(String::as_str) == Some("<end>"))
                .count(),
        })
        .collect();
    Ok(CollectEval {
        method,
        points,
        episodes: records,
    })
}

/// Object collection's own `ntg train` flags.
#[derive(Debug, Clone, clap::Args)]
#[command(next_help_heading = "Object collection (--domain collect)")]
pub struct CollectFlags {
    /// Numbers of target objects of the training tasks (`2,4` or `2 4`).
    #[arg(long, value_delimiter = ',', num_args = 1.., default_values_t = [2, 4])]
    pub objects: Vec<usize>,
    /// NTG: train the demo interpreter on whole demos alone, without
    /// random stretches of them.
    #[arg(long)]
    pub no_segments: bool,
    /// Also train the final `<end>` decision, which the last frame cannot
    /// support (without it, episodes end at the step limit).
    #[arg(long)]
    pub learn_end: bool,
    /// Validation tasks per number of training objects: held-out
    /// train-side tasks (never test tasks) rolled out after every epoch;
    /// the best epoch is kept in best/ and is the one `ntg eval` scores.
    /// 0: no validation (the last epoch is scored).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub validation_tasks_per_n: usize,
    /// Also validate on tasks with these numbers of objects (lengths no
    /// test episode has: 6), to choose settings that carry to longer demos
    /// than any trained on without looking at test episodes.
    #[arg(long, value_delimiter = ',', num_args = 1.., value_name = "N")]
    pub validation_objects: Vec<usize>,
}

/// The interpreter of an object-collection run: `--interpreter`, else
/// [`InterpreterKind::default_for`] its `--obs`.
pub fn interpreter_of(flags: &TrainFlags) -> InterpreterKind {
    flags
        .interpreter
        .unwrap_or_else(|| InterpreterKind::default_for(flags.obs))
}

/// The location step prior of an object-collection run:
/// `--location-step-prior`, else the interpreter's default for NTG (none
/// for the Flat Policy). An explicit 0 is no prior, as in runs saved
/// before the option existed, so those resume with
/// `--location-step-prior 0`.
pub fn location_step_prior_of(flags: &TrainFlags) -> Option<f32> {
    match flags.location_step_prior {
        Some(0.0) => None,
        Some(w) => Some(w),
        None => default_step_prior(flags.method, interpreter_of(flags)),
    }
}

/// The methods object collection trains and evaluates: those that need
/// nothing but its demos (NTP's programs are block stacking's).
pub const EVALUATED_METHODS: &[MethodId] = &[MethodId::Ntg, MethodId::Flat];

/// Object collection in the domain registry (`ntg train --domain collect`,
/// `ntg eval` on its runs).
pub struct Collect;

impl DomainRuns for Collect {
    fn name(&self) -> &'static str {
        "collect"
    }

    fn train(&self, flags: &TrainFlags, own: &DomainFlags) -> anyhow::Result<()> {
        let c = &own.collect;
        if !flags.ablation.is_full() {
            bail!(
                "--ablation trains NTG without a part in block stacking and object sorting; object collection trains its models whole"
            );
        }
        if !EVALUATED_METHODS.contains(&flags.method) {
            bail!(
                "--method {}: object collection trains ntg or flat (NTP's programs are block stacking's)",
                flags.method.name()
            );
        }
        let mut config = CollectRunConfig::new(
            flags.method,
            flags.obs,
            c.objects.clone(),
            flags.train_tasks,
            flags.demos_per_task,
            flags.epochs,
            flags.seed,
        );
        config.segments = !c.no_segments;
        config.learn_end = c.learn_end;
        config.memory = flags.memory;
        config.interpreter = interpreter_of(flags);
        config.location_step_prior = location_step_prior_of(flags);
        config.validation_tasks_per_n = c.validation_tasks_per_n;
        config.validation_objects = c.validation_objects.clone();
        config.optim.batch_size = flags.batch_size;
        config.optim.learning_rate = flags.lr.unwrap_or(crate::fit::PAPER_LEARNING_RATE);
        config.optim.cosine_decay = flags.cosine_decay;
        config.optim.shards = flags.shards;
        flags.check_encoder_flags()?;
        if let Some(video) = config.video.as_mut() {
            flags.apply_encoder_flags(&mut video.encoder);
        }
        config.validate()?;
        // Before the run folder exists (see `blocks::Blocks::train`).
        training_tasks(&config)?;
        let run = RunDir::start_or_resume(&flags.out, &config, flags.resume, "")?;
        eprintln!(
            "training {} ({:?} observations) on N = {:?}, {} tasks per N x {} demos, {} epochs -> {}",
            config.method.name(),
            config.obs,
            config.train_objects,
            config.tasks_per_n,
            config.demos_per_task,
            config.optim.epochs,
            run.root().display()
        );
        let device = crate::spec::device().autodiff();
        train_run(&run, &config, &device, |r| eprintln!("{}", r.line))?;
        println!("done: weights in {}", run.checkpoint_dir().display());
        Ok(())
    }

    fn owns(&self, config: &serde_json::Value) -> bool {
        config.get("domain").and_then(serde_json::Value::as_str) == Some("collect")
    }

    fn evaluate(&self, run: &RunDir, flags: &EvalFlags) -> anyhow::Result<()> {
        let config: CollectRunConfig = RunDir::read_json(&run.config_path())?;
        anyhow::ensure!(
            flags.variant == crate::method::ntg::Variant::Full && flags.edge_threshold.is_none(),
            "--variant and --edge-threshold apply to block-stacking runs"
        );
        anyhow::ensure!(
            !flags.decisions,
            "--decisions checks an NTP baseline's decisions (block stacking); {} is not one",
            run.root().display()
        );
        if flags.tasks.is_some() {
            anyhow::bail!(
                "--tasks reads block-stacking tasks (NTP's format); {} is an object-collection run",
                run.root().display()
            );
        }
        if flags.split != crate::domain::EvalSplit::Test {
            anyhow::bail!(
                "--split {} is for block-stacking runs; object collection evaluates its test episodes (--split test)",
                flags.split.name()
            );
        }
        let model = load_model(run, &config)?;
        let result = evaluate(model.as_ref(), &config, &EVAL_OBJECTS, flags.test_tasks)?;
        let recorded =
            super::record_eval(run, &format!("collect-{}.json", flags.test_tasks), &result);
        for p in &result.points {
            let s = p.success;
            println!(
                "{} N = {}: success {}/{} = {:.3} (95% CI {:.3}-{:.3})",
                config.method.name(),
                p.objects,
                s.successes,
                s.trials,
                s.rate,
                s.ci_low,
                s.ci_high
            );
        }
        println!("{recorded}");
        Ok(())
    }
    fn trained(&self, run: &RunDir) -> anyhow::Result<super::TrainedRun> {
        let config: CollectRunConfig = RunDir::read_json(&run.config_path())?;
        Ok(super::TrainedRun {
            model: load_model(run, &config)?,
            dir: crate::fit::trained_dir(run)?,
            method: config.method.name(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ntg_model::nn::to_vec;

    fn config(method: MethodId, epochs: usize) -> CollectRunConfig {
        CollectRunConfig {
            domain: "collect".into(),
            method,
            obs: ObsKind::State,
            train_objects: vec![1, 2],
            tasks_per_n: 3,
            demos_per_task: 2,
            segments: true,
            learn_end: true,
            memory: true,
            interpreter: InterpreterKind::Stepping,
            location_step_prior: default_step_prior(method, InterpreterKind::Stepping),
            model_seed: 0,
            optim: OptimConfig {
                epochs,
                batch_size: 4,
                learning_rate: 3e-3,
                seed: 1,
                token_dropout: 0.0,
                // A per-step decay depends on the total epochs, which the
                // resume test changes between the two calls.
                cosine_decay: false,
                shards: 1,
                gcn_from_other_demo: false,
            },
            video: None,
            validation_tasks_per_n: 0,
            validation_objects: Vec::new(),
        }
    }

    fn weights(model: &Model) -> Vec<f32> {
        let any = model.as_any();
        match (
            any.downcast_ref::<ntg_model::NtgModel>(),
            any.downcast_ref::<ntg_model::FlatPolicy>(),
        ) {
            (Some(m), _) => to_vec(m.edges.w.weight.val()).unwrap(),
            (_, Some(p)) => to_vec(p.out.weight.val()).unwrap(),
            _ => panic!("a model of another method"),
        }
    }

    #[test]
    fn train_then_evaluate_both_methods_end_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [MethodId::Ntg, MethodId::Flat] {
            let config = config(method, 1);
            let run = RunDir::open_or_create(&dir.path().join(method.name()), &config).unwrap();
            let model = train_run(&run, &config, &device, |_| {}).unwrap();
            assert!(run.epoch_seconds().unwrap() > 0.0);
            let eval = evaluate(model.as_ref(), &config, &[1, 3], 2).unwrap();
            assert_eq!(eval.episodes.len(), 4);
            assert_eq!(eval.points.len(), 2);
            assert_eq!(eval.points[1].objects, 3);
            assert_eq!(eval.points[1].success.trials, 2);
            for e in &eval.episodes {
                assert!(e.steps >= 1 && e.steps == e.trace.len());
                assert!(!e.demo_actions.is_empty());
                assert_eq!(e.transcription.is_empty(), method == MethodId::Flat);
            }
            // The saved model is the trained one.
            let loaded = load_model(&run, &config).unwrap();
            assert_eq!(weights(&loaded), weights(&model));
            // Another configuration in the same folder is refused.
            let other = CollectRunConfig {
                tasks_per_n: 4,
                ..config.clone()
            };
            assert!(RunDir::open_or_create(run.root(), &other).is_err());
        }
    }

    #[test]
    fn validation_scores_every_epoch_on_held_out_train_side_tasks_and_keeps_the_best() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        let config = CollectRunConfig {
            validation_tasks_per_n: 2,
            validation_objects: Vec::new(),
            ..config(MethodId::Flat, 3)
        };
        // Two per N in 1 and 2, none a training task, none a test task.
        let episodes = validation_episodes(&config).unwrap();
        assert_eq!(episodes.len(), 4);
        // Validation lengths beyond the training ones add their own group,
        // from the train side too.
        let longer = CollectRunConfig {
            validation_objects: vec![6],
            ..config.clone()
        };
        longer.validate().unwrap();
        let with_six = validation_episodes(&longer).unwrap();
        assert_eq!(with_six[..4], episodes[..]);
        assert_eq!(with_six.len(), 6);
        for e in &with_six[4..] {
            assert_eq!((e.group, e.task.num_objects()), (6, 6));
            assert_eq!(
                env_collect::TaskSplitter::default().split_of(&e.task),
                Split::Train
            );
        }
        let training = training_tasks(&config).unwrap();
        let splitter = env_collect::TaskSplitter::default();
        for e in &episodes {
            assert!(!training.contains(&e.task));
            assert_eq!(e.group, e.task.num_objects());
            let train_side = splitter.tasks_with(e.group, Some(Split::Train)).unwrap();
            assert!(train_side.contains(&e.task), "{} is not train-side", e.task);
        }
        assert_eq!(episodes, validation_episodes(&config).unwrap(), "seeded");
        let run = RunDir::open_or_create(dir.path(), &config).unwrap();
        let model = train_run(&run, &config, &device, |_| {}).unwrap();
        let lines = std::fs::read_to_string(run.validation_path()).unwrap();
        assert_eq!(
            lines.lines().count(),
            3,
            "one validation per epoch: {lines}"
        );
        let selected = crate::fit::selected_epoch(&run)
            .unwrap()
            .expect("a selected epoch");
        assert!(selected.epoch < 3);
        // What train_run returns and ntg eval loads is the selected epoch.
        assert_eq!(
            weights(&load_model(&run, &config).unwrap()),
            weights(&model)
        );
        // Without validation the written configuration has no such field
        // (runs saved before it keep their config.json).
        let plain = serde_json::to_value(super::tests::config(MethodId::Flat, 3)).unwrap();
        assert!(plain.get("validation_tasks_per_n").is_none());
    }

    #[test]
    fn resuming_replays_the_same_steps() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [MethodId::Ntg, MethodId::Flat] {
            let straight =
                RunDir::open_or_create(&dir.path().join("a"), &config(method, 2)).unwrap();
            let a = train_run(&straight, &config(method, 2), &device, |_| {}).unwrap();
            // One epoch, then "resume" the same folder with two.
            let split = dir.path().join("b");
            let first = RunDir::open_or_create(&split, &config(method, 1)).unwrap();
            train_run(&first, &config(method, 1), &device, |_| {}).unwrap();
            let b = train_run(&first, &config(method, 2), &device, |_| {}).unwrap();
            assert_eq!(weights(&a), weights(&b), "{method:?}");
            std::fs::remove_dir_all(dir.path().join("a")).unwrap();
            std::fs::remove_dir_all(&split).unwrap();
        }
    }

    /// A kill leaves, at worst, the lines of an epoch logged whose
    /// checkpoint was never committed, a half-written `checkpoint.next`, or
    /// the old checkpoint parked as `checkpoint.old`: the resumed run redoes
    /// that epoch, logs it once, and ends with the weights of an
    /// uninterrupted run.
    #[test]
    fn runs_killed_between_logging_and_checkpointing_resume_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        let method = MethodId::Flat;
        let straight = RunDir::open_or_create(&dir.path().join("a"), &config(method, 2)).unwrap();
        let a = weights(&train_run(&straight, &config(method, 2), &device, |_| {}).unwrap());
        let copy = |from: &std::path::Path, to: &std::path::Path| {
            std::fs::create_dir_all(to).unwrap();
            for entry in std::fs::read_dir(from).unwrap() {
                let entry = entry.unwrap();
                std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
            }
        };
        for parked in [false, true] {
            let root = dir.path().join(format!("b{parked}"));
            let run = RunDir::open_or_create(&root, &config(method, 1)).unwrap();
            train_run(&run, &config(method, 1), &device, |_| {}).unwrap();
            let after_one = dir.path().join(format!("saved{parked}"));
            copy(&run.checkpoint_dir(), &after_one);
            train_run(&run, &config(method, 2), &device, |_| {}).unwrap();
            // Back to the state of a kill during epoch 1's checkpoint: its
            // metrics line is logged, the checkpoint holds one epoch.
            std::fs::remove_dir_all(run.checkpoint_dir()).unwrap();
            let next = root.join("checkpoint.next");
            std::fs::create_dir_all(&next).unwrap();
            std::fs::write(next.join("model.bpk"), b"half").unwrap();
            if parked {
                copy(&after_one, &root.join("checkpoint.old"));
            } else {
                copy(&after_one, &run.checkpoint_dir());
            }
            let b = train_run(&run, &config(method, 2), &device, |_| {}).unwrap();
            assert_eq!(weights(&b), a, "parked {parked}");
            let epochs: Vec<u64> =
                crate::run_dir::read_jsonl::<serde_json::Value>(&run.metrics_path())
                    .unwrap()
                    .iter()
                    .map(|v| v["epoch"].as_u64().unwrap())
                    .collect();
            assert_eq!(epochs, [0, 1]);
            assert!(!next.exists() && !root.join("checkpoint.old").exists());
        }
        // A checkpoint removed by hand is not silently retrained over.
        std::fs::remove_dir_all(straight.checkpoint_dir()).unwrap();
        let err = train_run(&straight, &config(method, 2), &device, |_| {})
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(err.contains("checkpoint was removed"), "{err}");
    }

    #[test]
    fn test_episodes_are_unseen_and_seeded() {
        let splitter = env_collect::TaskSplitter::default();
        let train: Vec<Task> = training_tasks(&CollectRunConfig {
            tasks_per_n: 50,
            train_objects: vec![2, 4],
            ..config(MethodId::Ntg, 1)
        })
        .unwrap();
        assert_eq!(train.len(), 100);
        for n in EVAL_OBJECTS {
            let eps = test_episodes(n, 30).unwrap();
            assert_eq!(eps, test_episodes(n, 30).unwrap());
            for e in &eps {
                assert_eq!((e.task.num_objects(), e.group), (n, n));
                assert_eq!(splitter.split_of(&e.task), Split::Test);
                assert!(!train.contains(&e.task));
                assert_ne!(e.demo_seed, e.rollout_seed);
            }
        }
        // Few test tasks with one object: they repeat, in other scenes.
        let ones = test_episodes(1, 30).unwrap();
        let distinct: std::collections::BTreeSet<u32> =
            ones.iter().map(|e| e.task.code()).collect();
        assert!(distinct.len() < 30);
    }

    #[test]
    fn bad_configurations_are_errors() {
        let mut c = config(MethodId::Flat, 1);
        c.location_step_prior = Some(0.3);
        assert!(c.validate().unwrap_err().to_string().contains("step prior"));
        let mut c = config(MethodId::Ntg, 1);
        c.interpreter = InterpreterKind::Luong;
        assert!(c.validate().unwrap_err().to_string().contains("step prior"));
        let mut c = config(MethodId::Ntg, 1);
        c.location_step_prior = Some(f32::NAN);
        assert!(c.validate().is_err());
        // The aligned interpreter reads state demos, not videos.
        let mut c = config(MethodId::Ntg, 1);
        c.interpreter = InterpreterKind::SteppingAligned;
        c.validate().unwrap();
        c.obs = ObsKind::Vid;
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("stepping-aligned")
        );
        let mut c = config(MethodId::Flat, 1);
        c.demos_per_task = 1;
        assert!(c.validate().unwrap_err().to_string().contains("2 demos"));
        let mut c = config(MethodId::Ntg, 1);
        c.train_objects = vec![6];
        assert!(c.validate().is_err());
        // Validation lengths are ones no test episode has, and need tasks.
        for bad in [vec![5], vec![7], vec![6, 2]] {
            let mut c = config(MethodId::Ntg, 1);
            c.validation_tasks_per_n = 2;
            c.validation_objects = bad.clone();
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains("--validation-objects"), "{bad:?}: {err}");
        }
        let mut c = config(MethodId::Ntg, 1);
        c.validation_objects = vec![6];
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("--validation-tasks-per-n")
        );
        let mut c = config(MethodId::Ntg, 1);
        c.domain = "blocks".into();
        assert!(c.validate().is_err());
        // Asking for more training tasks than the split has.
        let mut c = config(MethodId::Ntg, 1);
        c.train_objects = vec![1];
        c.tasks_per_n = 41;
        let err = format!("{:#}", training_tasks(&c).unwrap_err());
        assert!(err.contains("1 objects"), "{err}");
    }

    #[test]
    fn ntg_and_the_flat_policy_of_one_seed_record_the_same_videos() {
        let on_frames = |method, seed| {
            let mut c = CollectRunConfig::new(method, ObsKind::Vid, vec![2, 4], 10, 2, 3, seed);
            c.memory = method == MethodId::Ntg;
            c
        };
        let ntg = on_frames(MethodId::Ntg, 0);
        assert!(ntg.same_videos(&on_frames(MethodId::Flat, 0)));
        assert!(
            !ntg.same_videos(&on_frames(MethodId::Flat, 1)),
            "another seed"
        );
        let mut more = on_frames(MethodId::Flat, 0);
        more.demos_per_task = 3;
        assert!(!ntg.same_videos(&more), "other videos");
        let state = CollectRunConfig::new(MethodId::Ntg, ObsKind::State, vec![2, 4], 10, 2, 3, 0);
        assert!(!state.same_videos(&state), "no videos on the state input");
    }

    #[test]
    fn validation_tasks_are_train_side_tasks_the_run_does_not_train_on() {
        let config = config(MethodId::Ntg, 1);
        let training = training_tasks(&config).unwrap();
        let validation = validation_tasks(&config, 5).unwrap();
        assert_eq!(validation.len(), 10);
        let splitter = env_collect::TaskSplitter::default();
        for t in &validation {
            assert!(!training.contains(t), "{t} is a training task");
            assert_eq!(splitter.split_of(t), Split::Train, "{t}");
        }
        assert_eq!(validation, validation_tasks(&config, 5).unwrap(), "seeded");
    }

    #[test]
    fn both_methods_train_on_demo_videos_in_stages_and_act_on_frames() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [MethodId::Ntg, MethodId::Flat] {
            let mut video = CollectVideo::default();
            video.encoder.demos = 4;
            video.encoder.epochs = 1;
            let config = CollectRunConfig {
                obs: ObsKind::Vid,
                train_objects: vec![1],
                video: Some(video),
                ..config(method, 1)
            };
            let run = RunDir::open_or_create(&dir.path().join(method.name()), &config).unwrap();
            let model = train_run(&run, &config, &device, |_| {}).unwrap();
            // Stage A's run, the embedding cache, then the method on frames.
            assert!(
                run.root()
                    .join(crate::video::STAGE_A_DIR)
                    .join("metrics.jsonl")
                    .is_file()
            );
            let embeddings =
                DemoDataset::load(&run.root().join(crate::video::EMBEDDINGS_DIR)).unwrap();
            assert!(embeddings.is_video() && embeddings.num_rows() > 2 * embeddings.demos().len());
            assert!(crate::method::on_frames::is_video_model(
                &run.checkpoint_dir()
            ));
            let loaded = load_model(&run, &config).unwrap();
            let eval = evaluate(loaded.as_ref(), &config, &[1], 2).unwrap();
            assert_eq!(eval.episodes.len(), 2);
            let again = evaluate(model.as_ref(), &config, &[1], 2).unwrap();
            assert_eq!(
                again.episodes, eval.episodes,
                "{method:?}: the saved model acts as the trained one"
            );
        }
    }

    #[test]
    fn runs_without_memory_or_end_still_train_and_evaluate() {
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        for method in [MethodId::Ntg, MethodId::Flat] {
            let config = CollectRunConfig {
                learn_end: false,
                memory: false,
                ..config(method, 1)
            };
            let run = RunDir::open_or_create(&dir.path().join(method.name()), &config).unwrap();
            let model = train_run(&run, &config, &device, |_| {}).unwrap();
            let eval = evaluate(model.as_ref(), &config, &[2], 2).unwrap();
            assert_eq!(eval.episodes.len(), 2);
        }
    }

    #[test]
    fn configurations_saved_before_the_memory_load_without_it() {
        let mut json = serde_json::to_value(config(MethodId::Ntg, 1)).unwrap();
        json.as_object_mut().unwrap().remove("memory");
        let old: CollectRunConfig = serde_json::from_value(json).unwrap();
        assert!(!old.memory);
    }
}
