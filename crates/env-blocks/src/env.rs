//! The environment: a task, a world, and the flat or primitive action level.

use ctg_graph::{ActionId, CtgError, Environment, Result, Step, Vocabulary};
use glam::Vec3;
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::STATE_DIM;
use crate::render::{CATEGORY_COLOURS, CUBE_COLOURS, Camera, Renderer};
use crate::sorting::{NUM_BINS, SORTING_GRID_YS, SortTask, category_of, standard_bins};
use crate::task::{StackTask, cube_letter};
use crate::world::{
    CUBE_HALF, Failure, FailureConfig, GRID_SPACING, NUM_OBJECTS, Outcome, Primitive, Support,
    Target, WORKSPACE_HALF, World,
};

/// A task of either domain.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BlocksTask {
    /// Block stacking.
    Stack(StackTask),
    /// Object sorting.
    Sort(SortTask),
}

impl BlocksTask {
    /// The task's id.
    pub fn id(&self) -> &str {
        match self {
            BlocksTask::Stack(t) => &t.id,
            BlocksTask::Sort(t) => &t.id,
        }
    }
}

/// Which actions the agent takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionLevel {
    /// NTG's flat actions: `pick(X)` and `place(Y)` (each runs as its
    /// primitives).
    #[default]
    Flat,
    /// NTP's primitives: `move(X)`, `grasp`, `drop`.
    Primitive,
}

/// How an environment behaves.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvConfig {
    /// Stochastic failures (on by default).
    pub failures: FailureConfig,
    /// Whether observations carry a rendered 64×64 frame.
    pub render: bool,
    /// Whether `info` carries a frame after every primitive (needs `render`).
    pub primitive_frames: bool,
    /// Step limit; `None` means 40 flat actions or 100 primitives.
    pub max_steps: Option<usize>,
    /// The action level.
    pub level: ActionLevel,
    /// The camera frames are rendered with (its side in pixels; missing
    /// in JSON: the standard 64×64).
    #[serde(default)]
    pub camera: Camera,
}

impl Default for EnvConfig {
    /// Failures on, rendering on, flat actions, default step limit, the
    /// standard camera.
    fn default() -> Self {
        EnvConfig {
            failures: FailureConfig::default(),
            render: true,
            primitive_frames: false,
            max_steps: None,
            level: ActionLevel::Flat,
            camera: Camera::default(),
        }
    }
}

impl EnvConfig {
    /// State only (no rendering), failures on: fast training.
    pub fn state_only() -> Self {
        EnvConfig {
            render: false,
            ..Self::default()
        }
    }

    /// The same configuration with frames from `camera`.
    pub fn with_camera(self, camera: Camera) -> Self {
        EnvConfig { camera, ..self }
    }

    /// The same configuration without stochastic failures.
    pub fn without_failures(self) -> Self {
        EnvConfig {
            failures: FailureConfig::none(),
            ..self
        }
    }

    /// The effective step limit.
    pub fn step_limit(&self) -> usize {
        self.max_steps.unwrap_or(match self.level {
            ActionLevel::Flat => 40,
            ActionLevel::Primitive => 100,
        })
    }
}

/// What the agent sees: the 26-number state and, with rendering on, the
/// 64×64 frame.
#[derive(Debug, Clone, PartialEq)]
pub struct BlocksObservation {
    state: [f32; STATE_DIM],
    frame: Option<RgbImage>,
}

impl BlocksObservation {
    /// Each cube's centre relative to the gripper (x, y, z per cube in cube
    /// order), then the gripper one-hot `[open, closed]`.
    pub fn state(&self) -> &[f32] {
        &self.state
    }

    /// The rendered frame, when rendering is on.
    pub fn frame(&self) -> Option<&RgbImage> {
        self.frame.as_ref()
    }
}

/// One primitive the last step ran, with its outcome.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PrimitiveEvent {
    /// The primitive.
    pub primitive: Primitive,
    /// What happened.
    pub outcome: Outcome,
}

/// Per-step information.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BlocksInfo {
    /// The primitives run by this step (empty for `reset` and `<end>`).
    pub primitives: Vec<PrimitiveEvent>,
    /// Why the action did not do what it is for, if it did not.
    pub failure: Option<Failure>,
    /// Whether the task is satisfied after the step.
    pub success: bool,
    /// A frame after each primitive (when `primitive_frames` and `render`).
    pub primitive_frames: Vec<RgbImage>,
}

/// A decoded action of a [`BlocksEnv`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlocksAction {
    /// `<end>`.
    End,
    /// `pick(object)`.
    Pick(usize),
    /// `place(target)`.
    Place(Target),
    /// A primitive.
    Primitive(Primitive),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum EpisodeState {
    NotReset,
    Running,
    Over,
}

/// Name of a target in action names: cube letter, or `bin1`..`bin4`.
pub fn target_name(t: Target) -> String {
    match t {
        Target::Object(i) => cube_letter(i).to_string(),
        Target::Bin(b) => format!("bin{}", b + 1),
    }
}

/// The decoded actions of a domain and level, in vocabulary order (after
/// `<start>` and `<end>`).
fn action_table(sorting: bool, level: ActionLevel) -> Vec<BlocksAction> {
    let objects = (0..NUM_OBJECTS).map(Target::Object);
    let targets: Vec<Target> = if sorting {
        (0..NUM_BINS).map(Target::Bin).collect()
    } else {
        objects.clone().collect()
    };
    match level {
        ActionLevel::Flat => (0..NUM_OBJECTS)
            .map(BlocksAction::Pick)
            .chain(targets.into_iter().map(BlocksAction::Place))
            .collect(),
        ActionLevel::Primitive => {
            let mut all: Vec<Target> = objects.collect();
            if sorting {
                all.extend((0..NUM_BINS).map(Target::Bin));
            }
            all.into_iter()
                .map(|t| BlocksAction::Primitive(Primitive::Move(t)))
                .chain([
                    BlocksAction::Primitive(Primitive::Grasp),
                    BlocksAction::Primitive(Primitive::Drop),
                ])
                .collect()
        }
    }
}

/// The name of an action, e.g. `pick(A)`, `place(bin2)`, `move(C)`, `grasp`.
pub fn action_name(a: BlocksAction) -> String {
    match a {
        BlocksAction::End => Vocabulary::END_NAME.to_owned(),
        BlocksAction::Pick(i) => format!("pick({})", cube_letter(i)),
        BlocksAction::Place(t) => format!("place({})", target_name(t)),
        BlocksAction::Primitive(Primitive::Move(t)) => format!("move({})", target_name(t)),
        BlocksAction::Primitive(Primitive::Grasp) => "grasp".to_owned(),
        BlocksAction::Primitive(Primitive::Drop) => "drop".to_owned(),
    }
}

/// The vocabulary of a domain (`sorting` or stacking) at a level: stacking
/// flat is `pick(A)`..`pick(H)`, `place(A)`..`place(H)` (18 nodes with
/// `<start>`/`<end>`); sorting flat is `pick(A)`..`pick(H)`,
/// `place(bin1)`..`place(bin4)` (14 nodes); the primitive levels are
/// `move(..)` per target, `grasp`, `drop`.
pub fn vocabulary(sorting: bool, level: ActionLevel) -> Vocabulary {
    let names: Vec<String> = action_table(sorting, level)
        .into_iter()
        .map(action_name)
        .collect();
    // The names are generated unique and non-empty.
    Vocabulary::new(names).unwrap_or_else(|e| unreachable!("generated vocabulary invalid: {e}"))
}

/// The block-stacking / object-sorting environment (Gymnasium style).
///
/// `Send + Clone`; the renderer is a shared immutable camera.
#[derive(Debug, Clone)]
pub struct BlocksEnv {
    task: BlocksTask,
    config: EnvConfig,
    vocab: Vocabulary,
    actions: Vec<BlocksAction>,
    world: World,
    rng: ChaCha8Rng,
    state: EpisodeState,
    steps: usize,
}

impl BlocksEnv {
    /// An environment for `task`. Errors on an invalid failure
    /// configuration.
    pub fn new(task: BlocksTask, config: EnvConfig) -> Result<Self> {
        config.failures.validate().map_err(CtgError::Environment)?;
        config.camera.validate().map_err(CtgError::Environment)?;
        let sorting = matches!(task, BlocksTask::Sort(_));
        let actions = action_table(sorting, config.level);
        let vocab = vocabulary(sorting, config.level);
        let world = World::new(Vec::new(), Vec::new());
        Ok(BlocksEnv {
            task,
            config,
            vocab,
            actions,
            world,
            rng: ChaCha8Rng::seed_from_u64(0),
            state: EpisodeState::NotReset,
            steps: 0,
        })
    }

    /// A stacking environment.
    pub fn stacking(task: StackTask, config: EnvConfig) -> Result<Self> {
        Self::new(BlocksTask::Stack(task), config)
    }

    /// A sorting environment.
    pub fn sorting(task: SortTask, config: EnvConfig) -> Result<Self> {
        Self::new(BlocksTask::Sort(task), config)
    }

    /// The task.
    pub fn task(&self) -> &BlocksTask {
        &self.task
    }

    /// The configuration.
    pub fn config(&self) -> &EnvConfig {
        &self.config
    }

    /// The current world (privileged state, for experts and tests).
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Number of steps taken in this episode.
    pub fn steps_taken(&self) -> usize {
        self.steps
    }

    /// Decodes an action id (`None` if out of range or `<start>`).
    pub fn decode(&self, id: ActionId) -> Option<BlocksAction> {
        match id {
            Vocabulary::START => None,
            Vocabulary::END => Some(BlocksAction::End),
            _ => self.actions.get(id.index().checked_sub(2)?).copied(),
        }
    }

    /// The id of an action of this environment's vocabulary.
    pub fn encode(&self, action: BlocksAction) -> Option<ActionId> {
        if action == BlocksAction::End {
            return Some(Vocabulary::END);
        }
        self.actions
            .iter()
            .position(|&a| a == action)
            .map(|k| ActionId::new(k + 2))
    }

    /// The colours the cubes are drawn in.
    pub fn colours(&self) -> [[f32; 3]; NUM_OBJECTS] {
        match self.task {
            BlocksTask::Stack(_) => CUBE_COLOURS,
            BlocksTask::Sort(_) => std::array::from_fn(|i| {
                let c = CATEGORY_COLOURS[category_of(i) % CATEGORY_COLOURS.len()];
                let k = if i % 2 == 0 { 1.0 } else { 0.6 };
                [c[0] * k, c[1] * k, c[2] * k]
            }),
        }
    }

    /// Renders the current world.
    pub fn render(&self) -> RgbImage {
        Renderer::of(self.config.camera).render_world(&self.world, &self.colours())
    }

    fn observe(&self) -> BlocksObservation {
        BlocksObservation {
            state: self.world.state(),
            frame: self.config.render.then(|| self.render()),
        }
    }

    /// Whether the task holds in `world`.
    pub fn task_holds(task: &BlocksTask, world: &World) -> bool {
        match task {
            BlocksTask::Stack(t) => t.goals.iter().all(|g| world.on_top(g.src, g.target)),
            BlocksTask::Sort(t) => (0..world.objects().len()).all(|i| world.in_bin(i, t.bin_of(i))),
        }
    }

    /// Builds the start scene for `seed` (same seed, same scene).
    fn start_world(&self, rng: &mut ChaCha8Rng) -> World {
        match &self.task {
            BlocksTask::Stack(_) => {
                let ys: Vec<f32> = (0..5)
                    .map(|i| -WORKSPACE_HALF + GRID_SPACING * i as f32)
                    .collect();
                World::random_start(rng, &ys, Vec::new())
            }
            BlocksTask::Sort(t) => {
                let mut world = World::random_start(rng, &SORTING_GRID_YS, standard_bins());
                // Presorted objects go into their bins' slots, in order.
                let bins = standard_bins();
                let mut filled = [0usize; NUM_BINS];
                for &o in &t.presorted {
                    let b = t.bin_of(o);
                    let slot = filled[b] % 4;
                    let level = filled[b] / 4;
                    filled[b] += 1;
                    let xy = bins[b].slots()[slot];
                    let z = bins[b].top() + CUBE_HALF + level as f32 * 2.0 * CUBE_HALF;
                    world.set_object(o, Vec3::new(xy.x, xy.y, z));
                }
                world
            }
        }
    }

    /// Runs one primitive (validated), recording it and optionally a frame.
    fn run_primitive(&mut self, p: Primitive, info: &mut BlocksInfo) -> Outcome {
        let outcome = self.world.apply(p, &self.config.failures, &mut self.rng);
        info.primitives.push(PrimitiveEvent {
            primitive: p,
            outcome,
        });
        if self.config.render && self.config.primitive_frames {
            info.primitive_frames.push(self.render());
        }
        outcome
    }

    fn execute(&mut self, action: BlocksAction, info: &mut BlocksInfo) {
        match action {
            BlocksAction::End => {}
            BlocksAction::Pick(i) => {
                let moved = self.run_primitive(Primitive::Move(Target::Object(i)), info);
                info.failure = moved.failure();
                if info.failure.is_none() {
                    info.failure = self.run_primitive(Primitive::Grasp, info).failure();
                }
            }
            BlocksAction::Place(t) => {
                let moved = self.run_primitive(Primitive::Move(t), info);
                info.failure = moved.failure();
                if info.failure.is_none() {
                    let dropped = self.run_primitive(Primitive::Drop, info);
                    info.failure = match dropped {
                        Outcome::Failed(f) => Some(f),
                        Outcome::Dropped {
                            object, landed_on, ..
                        } => {
                            let hit = match (t, landed_on) {
                                (Target::Object(i), Support::Object(j)) => i == j,
                                (Target::Bin(b), _) => self.world.in_bin(object, b),
                                _ => false,
                            };
                            (!hit).then_some(Failure::Missed {
                                object,
                                intended: t,
                                landed_on,
                            })
                        }
                        _ => None,
                    };
                }
            }
            BlocksAction::Primitive(p) => {
                info.failure = self.run_primitive(p, info).failure();
            }
        }
    }
}

impl Environment for BlocksEnv {
    type Observation = BlocksObservation;
    type Info = BlocksInfo;

    fn vocabulary(&self) -> &Vocabulary {
        &self.vocab
    }

    /// Starts an episode: the scene and every stochastic failure derive from
    /// `seed`.
    fn reset(&mut self, seed: u64) -> Result<(BlocksObservation, BlocksInfo)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        self.world = self.start_world(&mut rng);
        self.rng = rng;
        self.state = EpisodeState::Running;
        self.steps = 0;
        let info = BlocksInfo {
            success: self.is_success(),
            ..BlocksInfo::default()
        };
        Ok((self.observe(), info))
    }

    fn step(&mut self, action: ActionId) -> Result<Step<BlocksObservation, BlocksInfo>> {
        match self.state {
            EpisodeState::NotReset => return Err(CtgError::NotReset),
            EpisodeState::Over => return Err(CtgError::EpisodeOver),
            EpisodeState::Running => {}
        }
        self.vocab.check(action)?;
        let Some(decoded) = self.decode(action) else {
            return Err(CtgError::InvalidAction {
                action: Vocabulary::START_NAME.to_owned(),
                reason: "<start> is not an action".into(),
            });
        };
        let mut info = BlocksInfo::default();
        self.execute(decoded, &mut info);
        info.success = self.is_success();
        let terminated = decoded == BlocksAction::End;
        if !terminated {
            self.steps += 1;
        }
        let truncated = !terminated && self.steps >= self.config.step_limit();
        if terminated || truncated {
            self.state = EpisodeState::Over;
        }
        Ok(Step {
            observation: self.observe(),
            // As every environment here: 1 for ending the episode in success.
            reward: if terminated && info.success { 1.0 } else { 0.0 },
            terminated,
            truncated,
            info,
        })
    }

    fn is_success(&self) -> bool {
        Self::task_holds(&self.task, &self.world)
    }

    fn max_episode_steps(&self) -> usize {
        self.config.step_limit()
    }
}
