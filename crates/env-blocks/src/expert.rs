//! The scripted expert, NTP's hierarchical trace, rich demos for the CLI,
//! and parallel demo generation.

use ctg_graph::{
    ActionId, CtgError, Demonstration, Environment, Expert, Result, Vocabulary,
    record_demonstration,
};
use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use crate::env::{
    ActionLevel, BlocksAction, BlocksEnv, BlocksObservation, BlocksTask, EnvConfig, PrimitiveEvent,
    action_name, target_name,
};
use crate::task::{Goal, cube_letter};
use crate::world::{Failure, Primitive, Target, World};

/// Mixed into the expert's seed so its choices are independent of the
/// scene's and the failures' random stream.
const EXPERT_STREAM: u64 = 0x9e37_79b9_7f4a_7c15;

/// The scripted expert for both domains and both action levels.
///
/// It plans once per episode (stacking: the task's towers in a random
/// order, each bottom-up; sorting: the objects in a random order) and then
/// acts on the world's state: it repeats a grasp that slipped, picks a cube
/// again after a drop that missed, and clears (parks on a cube no pending
/// goal needs) any cube that covers one it needs.
#[derive(Debug, Clone, Default)]
pub struct BlocksExpert {
    plan: Vec<Goal>,
    order: Vec<usize>,
    clearing: Option<usize>,
}

/// The flat decision with the NTP goal it serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Decision {
    action: BlocksAction,
}

fn top_of(world: &World, mut c: usize) -> usize {
    for _ in 0..world.objects().len() {
        match world.covered_by(c) {
            Some(x) => c = x,
            None => break,
        }
    }
    c
}

impl BlocksExpert {
    /// A fresh expert (planned on `reset`).
    pub fn new() -> Self {
        Self::default()
    }

    fn plan_for(&mut self, task: &BlocksTask, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ EXPERT_STREAM);
        self.plan.clear();
        self.order.clear();
        self.clearing = None;
        match task {
            BlocksTask::Stack(t) => {
                let mut towers = t.goals_by_tower();
                for i in 0..towers.len() {
                    let j = rng.random_range(i..towers.len());
                    towers.swap(i, j);
                }
                self.plan = towers.concat();
            }
            BlocksTask::Sort(_) => {
                let mut order: Vec<usize> = (0..crate::world::NUM_OBJECTS).collect();
                for i in 0..order.len() {
                    let j = rng.random_range(i..order.len());
                    order.swap(i, j);
                }
                self.order = order;
            }
        }
    }

    fn decide(&mut self, env: &BlocksEnv) -> Result<Decision> {
        let world = env.world();
        let action = match env.task() {
            BlocksTask::Stack(_) => self.decide_stack(world)?,
            BlocksTask::Sort(t) => {
                let pending: Vec<usize> = self
                    .order
                    .iter()
                    .copied()
                    .filter(|&o| !world.in_bin(o, t.bin_of(o)))
                    .collect();
                match (world.held(), pending.first()) {
                    (Some(h), _) => BlocksAction::Place(Target::Bin(t.bin_of(h))),
                    (None, None) => BlocksAction::End,
                    (None, Some(&o)) => BlocksAction::Pick(top_of(world, o)),
                }
            }
        };
        Ok(Decision { action })
    }

    fn decide_stack(&mut self, world: &World) -> Result<BlocksAction> {
        let pending: Vec<Goal> = self
            .plan
            .iter()
            .copied()
            .filter(|g| !world.on_top(g.src, g.target))
            .collect();
        // Keep exposing the cube being cleared until nothing covers it, even
        // if that undoes goals: redoing them first would cover it again.
        if let Some(c) = self.clearing
            && world.covered_by(c).is_none()
        {
            self.clearing = None;
        }
        if self.clearing.is_none()
            && world.held().is_none()
            && let Some(&g) = pending.first()
        {
            if world.covered_by(g.src).is_some() {
                self.clearing = Some(g.src);
            } else if world.covered_by(g.target).is_some() {
                self.clearing = Some(g.target);
            }
        }
        let current = pending.first().copied();
        if let Some(c) = self.clearing {
            return Ok(match world.held() {
                Some(h) => BlocksAction::Place(Target::Object(self.parking(
                    world,
                    h,
                    &pending,
                    current,
                    Some(c),
                )?)),
                None => BlocksAction::Pick(top_of(world, c)),
            });
        }
        let Some(g) = current else {
            return Ok(match world.held() {
                // Only reachable when a policy, not this expert, picked up a
                // cube; put it down on a cube no goal involves.
                Some(h) => BlocksAction::Place(Target::Object(
                    self.parking(world, h, &pending, None, None)?,
                )),
                None => BlocksAction::End,
            });
        };
        Ok(match world.held() {
            Some(h) if h == g.src && world.covered_by(g.target).is_none() => {
                BlocksAction::Place(Target::Object(g.target))
            }
            Some(h) => BlocksAction::Place(Target::Object(self.parking(
                world,
                h,
                &pending,
                Some(g),
                None,
            )?)),
            None => BlocksAction::Pick(g.src),
        })
    }

    /// A cube to put the held cube `h` on while clearing: uncovered, not
    /// `h`, not the current goal's cubes, not over the cube being cleared;
    /// preferably in no pending goal, else the one whose first pending goal
    /// comes last.
    fn parking(
        &self,
        world: &World,
        h: usize,
        pending: &[Goal],
        current: Option<Goal>,
        clearing: Option<usize>,
    ) -> Result<usize> {
        let first_use = |c: usize| {
            pending
                .iter()
                .position(|g| g.src == c || g.target == c)
                .unwrap_or(usize::MAX)
        };
        let over = |y: usize, c: usize| {
            let (a, b) = (world.objects()[y], world.objects()[c]);
            y == c || ((a - b).truncate().abs().max_element() < crate::world::CUBE_SIZE)
        };
        (0..world.objects().len())
            .filter(|&y| {
                y != h
                    && world.covered_by(y).is_none()
                    && current.is_none_or(|g| y != g.src && y != g.target)
                    && clearing.is_none_or(|c| !over(y, c))
            })
            .max_by_key(|&y| (first_use(y), std::cmp::Reverse(y)))
            .ok_or_else(|| {
                CtgError::ExpertFailed(format!("no cube to park cube {} on", cube_letter(h)))
            })
    }

    /// The next action at the environment's level.
    fn next(&mut self, env: &BlocksEnv) -> Result<BlocksAction> {
        self.next_with_decision(env).map(|(action, _)| action)
    }

    /// The next action at the environment's level, with the flat decision
    /// (`pick(X)`, `place(Y)` or `<end>`) it serves: a primitive-level
    /// action is one primitive of that flat action.
    pub(crate) fn next_with_decision(
        &mut self,
        env: &BlocksEnv,
    ) -> Result<(BlocksAction, BlocksAction)> {
        let flat = self.decide(env)?.action;
        if env.config().level == ActionLevel::Flat {
            return Ok((flat, flat));
        }
        let world = env.world();
        let action = match flat {
            BlocksAction::End => BlocksAction::End,
            BlocksAction::Pick(i) => {
                if world.move_target() == Some(Target::Object(i)) && world.held().is_none() {
                    BlocksAction::Primitive(Primitive::Grasp)
                } else {
                    BlocksAction::Primitive(Primitive::Move(Target::Object(i)))
                }
            }
            BlocksAction::Place(t) => {
                if world.move_target() == Some(t) {
                    BlocksAction::Primitive(Primitive::Drop)
                } else {
                    BlocksAction::Primitive(Primitive::Move(t))
                }
            }
            p @ BlocksAction::Primitive(_) => p,
        };
        Ok((action, flat))
    }
}

impl Expert<BlocksEnv> for BlocksExpert {
    fn reset(&mut self, env: &BlocksEnv, seed: u64) {
        self.plan_for(env.task(), seed);
    }

    fn next_action(&mut self, env: &BlocksEnv) -> Result<ActionId> {
        let action = self.next(env)?;
        env.encode(action).ok_or_else(|| {
            CtgError::ExpertFailed(format!(
                "action {} is not in the vocabulary",
                action_name(action)
            ))
        })
    }
}

// ---------------------------------------------------------------------------
// NTP's hierarchical trace.

/// One call in NTP's program hierarchy: `stack` / `sort` → `pick_place(X,Y)`
/// → `pick(X)` / `place(Y)` → `move(X)`, `grasp`, `drop`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TraceNode {
    /// The program with its arguments, e.g. `pick_place(B,A)`.
    pub program: String,
    /// The calls it made, in order (empty for primitives).
    pub children: Vec<TraceNode>,
}

impl TraceNode {
    fn leaf(program: String) -> Self {
        TraceNode {
            program,
            children: Vec::new(),
        }
    }

    /// The primitives under this node, in execution order (NTP Flat's
    /// action sequence).
    pub fn primitives(&self) -> Vec<String> {
        if self.children.is_empty() {
            return vec![self.program.clone()];
        }
        self.children.iter().flat_map(|c| c.primitives()).collect()
    }

    /// Depth of the hierarchy (a primitive is 1).
    pub fn depth(&self) -> usize {
        1 + self
            .children
            .iter()
            .map(TraceNode::depth)
            .max()
            .unwrap_or(0)
    }
}

fn primitive_name(p: Primitive) -> String {
    action_name(BlocksAction::Primitive(p))
}

/// Builds the NTP trace from flat steps: each `place` closes a
/// `pick_place(X,Y)` with the `pick` attempts of `X` before it (slipped
/// grasps included); steps after the last place form an unfinished
/// `pick_place(X,?)`.
pub fn build_trace(root: &str, steps: &[StepRecord]) -> TraceNode {
    let mut children = Vec::new();
    let mut open: Vec<TraceNode> = Vec::new();
    let mut picked: Option<String> = None;
    for s in steps {
        let prims: Vec<TraceNode> = s
            .primitives
            .iter()
            .map(|e| TraceNode::leaf(primitive_name(e.primitive)))
            .collect();
        let node = TraceNode {
            program: s.action.clone(),
            children: prims,
        };
        match s.decoded {
            BlocksAction::Pick(i) => {
                picked = Some(cube_letter(i).to_string());
                open.push(node);
            }
            BlocksAction::Place(t) => {
                open.push(node);
                children.push(TraceNode {
                    program: format!(
                        "pick_place({},{})",
                        picked.take().unwrap_or_else(|| "?".into()),
                        target_name(t)
                    ),
                    children: std::mem::take(&mut open),
                });
            }
            _ => open.push(node),
        }
    }
    if !open.is_empty() {
        children.push(TraceNode {
            program: format!("pick_place({},?)", picked.unwrap_or_else(|| "?".into())),
            children: open,
        });
    }
    TraceNode {
        program: root.to_owned(),
        children,
    }
}

// ---------------------------------------------------------------------------
// Rich demos.

/// One flat step of a rich demo.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepRecord {
    /// The action's name.
    pub action: String,
    /// The action's id in the flat vocabulary.
    pub action_id: usize,
    #[serde(skip)]
    decoded: BlocksAction,
    /// The primitives it ran and their outcomes.
    pub primitives: Vec<PrimitiveEvent>,
    /// Why it failed, if it did.
    pub failure: Option<Failure>,
    /// Whether the task held after it.
    pub success: bool,
}

/// A demonstration with everything the CLI writes: flat actions, states,
/// per-step primitive outcomes, NTP's trace, and the frames (after each flat
/// action and after each primitive).
#[derive(Debug, Clone, Serialize)]
pub struct RichDemo {
    /// The task.
    pub task: BlocksTask,
    /// The seed of the episode and the expert.
    pub seed: u64,
    /// The environment configuration (level is always flat).
    pub config: EnvConfig,
    /// The flat vocabulary's action names (ids from 2).
    pub vocabulary: Vec<String>,
    /// The flat steps.
    pub steps: Vec<StepRecord>,
    /// The state before the first action and after each.
    pub states: Vec<Vec<f32>>,
    /// NTP's hierarchical trace.
    pub trace: TraceNode,
    /// Whether the task holds at the end.
    pub success: bool,
    /// The frame before the first action and after each (when rendering).
    #[serde(skip)]
    pub frames: Vec<RgbImage>,
    /// Per flat step, a frame after each of its primitives (when rendering).
    #[serde(skip)]
    pub primitive_frames: Vec<Vec<RgbImage>>,
    #[serde(skip)]
    observations: Vec<BlocksObservation>,
    #[serde(skip)]
    action_ids: Vec<ActionId>,
}

impl RichDemo {
    /// The flat demonstration (equal to what `record_demonstration` gives
    /// for the same task, configuration and seed).
    pub fn demonstration(&self, vocab: &Vocabulary) -> Result<Demonstration<BlocksObservation>> {
        Demonstration::new(self.observations.clone(), self.action_ids.clone(), vocab)
    }

    /// The flat action names, space-separated (parseable by the vocabulary).
    pub fn action_sequence(&self) -> String {
        self.steps
            .iter()
            .map(|s| s.action.as_str())
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// Records the expert's demo of `task` with `seed` at the flat level, with
/// primitive frames when `config.render` is on.
pub fn record_rich_demo(task: BlocksTask, config: EnvConfig, seed: u64) -> Result<RichDemo> {
    let config = EnvConfig {
        level: ActionLevel::Flat,
        primitive_frames: config.render,
        ..config
    };
    let (mut env, mut expert, first) = start_episode(&task, config, seed)?;
    let mut observations = vec![first];
    let mut steps = Vec::new();
    let mut primitive_frames = Vec::new();
    let mut action_ids = Vec::new();
    loop {
        let id = expert.next_action(&env)?;
        if id == Vocabulary::END {
            break;
        }
        let decoded = env
            .decode(id)
            .ok_or_else(|| CtgError::ExpertFailed("expert chose <start>".into()))?;
        let step = env.step(id)?;
        steps.push(StepRecord {
            action: action_name(decoded),
            action_id: id.index(),
            decoded,
            primitives: step.info.primitives.clone(),
            failure: step.info.failure,
            success: step.info.success,
        });
        primitive_frames.push(step.info.primitive_frames);
        observations.push(step.observation);
        action_ids.push(id);
        if step.truncated {
            return Err(step_limit_hit(&env, seed));
        }
    }
    if steps.is_empty() {
        return Err(nothing_to_demonstrate(&task, seed));
    }
    let root = match task {
        BlocksTask::Stack(_) => "stack",
        BlocksTask::Sort(_) => "sort",
    };
    Ok(RichDemo {
        trace: build_trace(root, &steps),
        success: env.is_success(),
        vocabulary: env.vocabulary().action_names().map(str::to_owned).collect(),
        states: observations.iter().map(|o| o.state().to_vec()).collect(),
        frames: observations
            .iter()
            .filter_map(|o| o.frame().cloned())
            .collect(),
        primitive_frames,
        observations,
        action_ids,
        task,
        seed,
        config,
        steps,
    })
}

/// An environment for `task` reset with `seed`, the expert reset for it,
/// and the first observation.
pub(crate) fn start_episode(
    task: &BlocksTask,
    config: EnvConfig,
    seed: u64,
) -> Result<(BlocksEnv, BlocksExpert, BlocksObservation)> {
    let mut env = BlocksEnv::new(task.clone(), config)?;
    let mut expert = BlocksExpert::new();
    let (first, _) = env.reset(seed)?;
    expert.reset(&env, seed);
    Ok((env, expert, first))
}

/// The expert's error when an episode of `env` hit its step limit.
pub(crate) fn step_limit_hit(env: &BlocksEnv, seed: u64) -> CtgError {
    CtgError::ExpertFailed(format!(
        "hit the step limit ({}) before finishing (task {}, seed {seed})",
        env.max_episode_steps(),
        env.task().id()
    ))
}

/// The expert's error when `task` already holds at the start.
pub(crate) fn nothing_to_demonstrate(task: &BlocksTask, seed: u64) -> CtgError {
    CtgError::ExpertFailed(format!(
        "task {} already holds at the start (seed {seed}); nothing to demonstrate",
        task.id()
    ))
}

// ---------------------------------------------------------------------------
// Batch generation.

/// The expert's flat demonstration of `task` with `seed`.
pub fn expert_demo(
    task: &BlocksTask,
    config: EnvConfig,
    seed: u64,
) -> Result<Demonstration<BlocksObservation>> {
    let mut env = BlocksEnv::new(task.clone(), config)?;
    record_demonstration(&mut env, &mut BlocksExpert::new(), seed)
}

fn demo_for(
    tasks: &[BlocksTask],
    config: EnvConfig,
    &(index, seed): &(usize, u64),
) -> Result<Demonstration<BlocksObservation>> {
    let task = tasks.get(index).ok_or_else(|| {
        CtgError::Environment(format!(
            "task index {index} out of range ({} tasks)",
            tasks.len()
        ))
    })?;
    expert_demo(task, config, seed)
}

/// Expert demos for each `(task index, seed)` pair, one after another.
pub fn generate_demos_sequential(
    tasks: &[BlocksTask],
    pairs: &[(usize, u64)],
    config: EnvConfig,
) -> Vec<Result<Demonstration<BlocksObservation>>> {
    pairs.iter().map(|p| demo_for(tasks, config, p)).collect()
}

/// Expert demos for each `(task index, seed)` pair, in parallel on rayon's
/// current pool; the result (order included) equals
/// [`generate_demos_sequential`].
pub fn generate_demos(
    tasks: &[BlocksTask],
    pairs: &[(usize, u64)],
    config: EnvConfig,
) -> Vec<Result<Demonstration<BlocksObservation>>> {
    pairs
        .par_iter()
        .map(|p| demo_for(tasks, config, p))
        .collect()
}

/// How often the expert succeeds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayStats {
    /// Episodes run.
    pub episodes: usize,
    /// Episodes that ended with the task satisfied.
    pub successes: usize,
    /// Mean number of flat actions per successful episode.
    pub mean_actions: f64,
    /// The first failures (task id, seed, error), at most 10.
    pub failures: Vec<(String, u64, String)>,
}

impl ReplayStats {
    /// Successes / episodes.
    pub fn success_rate(&self) -> f64 {
        if self.episodes == 0 {
            0.0
        } else {
            self.successes as f64 / self.episodes as f64
        }
    }
}

/// Runs the expert once on every task (seed = `seed` + task index), in
/// parallel, state only, and counts successes.
pub fn expert_success(tasks: &[BlocksTask], config: EnvConfig, seed: u64) -> ReplayStats {
    let config = EnvConfig {
        render: false,
        ..config
    };
    let pairs: Vec<(usize, u64)> = (0..tasks.len()).map(|i| (i, seed + i as u64)).collect();
    let results: Vec<Result<(bool, usize)>> = pairs
        .par_iter()
        .map(|&(i, s)| {
            let mut env = BlocksEnv::new(tasks[i].clone(), config)?;
            let demo = record_demonstration(&mut env, &mut BlocksExpert::new(), s)?;
            Ok((env.is_success(), demo.len()))
        })
        .collect();
    let mut stats = ReplayStats {
        episodes: tasks.len(),
        successes: 0,
        mean_actions: 0.0,
        failures: Vec::new(),
    };
    let mut total = 0usize;
    for ((i, s), r) in pairs.iter().zip(results) {
        match r {
            Ok((true, len)) => {
                stats.successes += 1;
                total += len;
            }
            Ok((false, _)) => {
                if stats.failures.len() < 10 {
                    stats.failures.push((
                        tasks[*i].id().to_owned(),
                        *s,
                        "ended without success".into(),
                    ));
                }
            }
            Err(e) => {
                if stats.failures.len() < 10 {
                    stats
                        .failures
                        .push((tasks[*i].id().to_owned(), *s, e.to_string()));
                }
            }
        }
    }
    if stats.successes > 0 {
        stats.mean_actions = total as f64 / stats.successes as f64;
    }
    stats
}
