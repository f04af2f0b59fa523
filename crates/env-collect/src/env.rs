//! The environment: scenes, episode state, observations and the step rules.

use ctg_graph::{ActionId, CtgError, Environment, Step, Vocabulary};
use image::RgbImage;
use rand::seq::{SliceRandom, index};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::domain::{
    Action, Category, NUM_CATEGORIES, NUM_RECEPTACLES, Receptacle, Surface, vocabulary,
};
use crate::render::{
    self, Appearance, Backdrop, FRAME_SIZE, HAND_INSET_START, RECEPTACLE_OBJECT_SIZE,
};
use crate::{CollectError, Task, splitmix64};

/// Length of [`CollectObservation::state`].
pub const STATE_LEN: usize = 2 + NUM_RECEPTACLES + 2 * NUM_CATEGORIES + 1;
const AT_START: usize = 0;
const AT_LOCATION: usize = 1;
const AT_RECEPTACLE: usize = 2;
const VISIBLE: usize = AT_RECEPTACLE + NUM_RECEPTACLES;
const HELD: usize = VISIBLE + NUM_CATEGORIES;
const FAILED: usize = HELD + NUM_CATEGORIES;

/// Names of the entries of the symbolic state vector, in order:
/// `at_start`, `at_search_location`, `at_<Receptacle>` (5), `visible_<Category>`
/// (8, the number of such objects visible at the current place: on the
/// location's surface or inside the receptacle), `held_<Category>` (8, one-hot;
/// all zero when the hand is empty), `last_action_failed`.
///
/// It holds exactly what the frame shows (plus the failure flag, which the
/// frame does not show): no task information and nothing about other places.
pub fn state_layout() -> Vec<String> {
    let mut names = vec!["at_start".to_owned(), "at_search_location".to_owned()];
    names.extend(Receptacle::ALL.iter().map(|r| format!("at_{r}")));
    names.extend(Category::ALL.iter().map(|c| format!("visible_{c}")));
    names.extend(Category::ALL.iter().map(|c| format!("held_{c}")));
    names.push("last_action_failed".to_owned());
    names
}

/// Episode settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct CollectConfig {
    /// Step limit (truncation); `None`: [`CollectConfig::default_max_steps`]
    /// of the task's N.
    pub max_steps: Option<usize>,
    /// Render frames; when false, [`CollectObservation::frame`] is `None`
    /// (much faster, for symbolic training and tests).
    pub render: bool,
    /// Most distractor objects in a scene (at least 1 when positive, drawn
    /// uniformly up to `min(max_distractors, 8 − N)`).
    pub max_distractors: usize,
}

impl Default for CollectConfig {
    /// Default step limit, rendering on, up to 3 distractors.
    fn default() -> Self {
        CollectConfig {
            max_steps: None,
            render: true,
            max_distractors: 3,
        }
    }
}

impl CollectConfig {
    /// The default step limit for N targets: twice the expert's worst case
    /// (N + 3 searches, N pickups, N drop-offs), i.e. 2 · (3N + 3).
    pub fn default_max_steps(num_objects: usize) -> usize {
        2 * (3 * num_objects + 3)
    }
}

/// What the agent sees after each reset or step.
#[derive(Debug, Clone, PartialEq)]
pub struct CollectObservation {
    /// 64×64 RGB view of the current place with the hand inset
    /// (bottom-right); `None` when rendering is off.
    pub frame: Option<RgbImage>,
    /// The symbolic state ([`STATE_LEN`] values, see [`state_layout`]).
    pub state: Vec<f32>,
}

/// Length of a frame as a feature vector: 3 · 64 · 64.
pub const FRAME_DIM: usize = 3 * (FRAME_SIZE as usize) * (FRAME_SIZE as usize);

/// A frame as a feature vector in CHW order (all red values row by row, then
/// green, then blue), each `byte / 255`, so exactly representable as bytes.
pub fn frame_to_chw(frame: &RgbImage) -> Vec<f32> {
    let plane = (frame.width() * frame.height()) as usize;
    let mut out = vec![0.0; 3 * plane];
    for (i, px) in frame.pixels().enumerate() {
        for (c, &v) in px.0.iter().enumerate() {
            out[c * plane + i] = f32::from(v) / 255.0;
        }
    }
    out
}

impl CollectObservation {
    /// The frame as [`frame_to_chw`] features ([`FRAME_DIM`] values), or
    /// `None` when rendering is off.
    pub fn frame_chw(&self) -> Option<Vec<f32>> {
        self.frame.as_ref().map(frame_to_chw)
    }
}

/// Why an action failed (the action still counts as a step).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Failure {
    /// `pickup` of a category with no such object visible at the current
    /// place.
    NotVisible(Category),
    /// `pickup` while already holding an object.
    HandsFull,
    /// `dropoff` with nothing in the hand (the agent still went there).
    HandsEmpty,
}

/// Per-step information.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct CollectInfo {
    /// The action just taken (`None` after reset and for `<end>`).
    pub action: Option<Action>,
    /// Why that action failed, if it did.
    pub failure: Option<Failure>,
    /// Targets now in their designated receptacle.
    pub delivered: usize,
    /// Targets in the task.
    pub num_targets: usize,
}

/// Where the agent is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Place {
    /// At the start, before the first move.
    Start,
    /// At the search location with this index (in visiting order).
    Location(usize),
    /// In front of a receptacle.
    Receptacle(Receptacle),
}

/// One search location of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneLocation {
    /// What kind of surface it is.
    pub surface: Surface,
    /// How it looks in this episode.
    pub backdrop: Backdrop,
}

/// One object of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneObject {
    /// Its category.
    pub category: Category,
    /// Whether it is one of the task's targets.
    pub is_target: bool,
    /// The search location it starts at.
    pub location: usize,
    /// Its centre on that location's frame, in pixels.
    pub position: (f32, f32),
    /// How it looks.
    pub appearance: Appearance,
}

/// The hidden layout of one episode, drawn from the reset seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// The M = N + 3 search locations, in the order `search` visits them.
    pub locations: Vec<SceneLocation>,
    /// Targets first (in task order), then distractors.
    pub objects: Vec<SceneObject>,
    /// How each receptacle looks (index = [`Receptacle::index`]).
    pub receptacles: Vec<Backdrop>,
    /// How the start view looks.
    pub start: Backdrop,
}

fn random_tint(rng: &mut ChaCha8Rng, brightness: f32, channel: f32) -> [f32; 3] {
    let b = 1.0 + rng.random_range(-brightness..=brightness);
    [(); 3].map(|()| b * (1.0 + rng.random_range(-channel..=channel)))
}

fn random_backdrop(rng: &mut ChaCha8Rng) -> Backdrop {
    Backdrop {
        tint: random_tint(rng, 0.14, 0.07),
        phase: rng.random_range(0..21),
        salt: rng.random(),
    }
}

impl Scene {
    /// Draws a scene for `task` from `rng`.
    fn generate(task: &Task, max_distractors: usize, rng: &mut ChaCha8Rng) -> Scene {
        let m = task.num_locations();
        let locations = (0..m)
            .map(|_| SceneLocation {
                surface: Surface::ALL[rng.random_range(0..Surface::ALL.len())],
                backdrop: random_backdrop(rng),
            })
            .collect();
        let receptacles = (0..NUM_RECEPTACLES).map(|_| random_backdrop(rng)).collect();
        let start = random_backdrop(rng);

        // Targets at distinct locations; distractors anywhere.
        let mut placed: Vec<(Category, bool, usize)> = index::sample(rng, m, task.num_objects())
            .into_iter()
            .zip(task.targets())
            .map(|(loc, t)| (t.category, true, loc))
            .collect();
        let mut others: Vec<Category> = Category::ALL
            .into_iter()
            .filter(|&c| !task.is_target(c))
            .collect();
        others.shuffle(rng);
        let most = max_distractors.min(others.len());
        let count = if most == 0 {
            0
        } else {
            rng.random_range(1..=most)
        };
        for &c in &others[..count] {
            placed.push((c, false, rng.random_range(0..m)));
        }

        let mut objects: Vec<SceneObject> = Vec::with_capacity(placed.len());
        for (category, is_target, location) in placed {
            let appearance = Appearance {
                size: rng.random_range(11.0..=17.0),
                tint: random_tint(rng, 0.13, 0.1),
                variant: rng.random_range(0..4),
            };
            let neighbours: Vec<((f32, f32), f32)> = objects
                .iter()
                .filter(|o| o.location == location)
                .map(|o| (o.position, o.appearance.size))
                .collect();
            let position = place_object(rng, appearance.size, &neighbours);
            objects.push(SceneObject {
                category,
                is_target,
                location,
                position,
                appearance,
            });
        }
        Scene {
            locations,
            objects,
            receptacles,
            start,
        }
    }
}

/// A centre for an object of `size` inside the frame, clear of the hand
/// inset and (if it can be found in 200 tries) of the other objects.
fn place_object(rng: &mut ChaCha8Rng, size: f32, others: &[((f32, f32), f32)]) -> (f32, f32) {
    let half = 0.65 * size + 1.0;
    let hi = FRAME_SIZE as f32 - half;
    let inset = HAND_INSET_START as f32 - 1.0;
    let mut candidate = (half, half);
    for _ in 0..200 {
        candidate = (rng.random_range(half..hi), rng.random_range(half..hi));
        let (x, y) = candidate;
        if x + half > inset && y + half > inset {
            continue;
        }
        let clear = others.iter().all(|&((ox, oy), os)| {
            let d = ((x - ox).powi(2) + (y - oy).powi(2)).sqrt();
            d >= 0.6 * (size + os) + 1.0
        });
        if clear {
            return candidate;
        }
    }
    if candidate.0 + half > inset && candidate.1 + half > inset {
        candidate.0 = half;
    }
    candidate
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Whereabouts {
    AtLocation,
    Held,
    In(Receptacle),
}

#[derive(Debug, Clone)]
struct Episode {
    seed: u64,
    scene: Scene,
    whereabouts: Vec<Whereabouts>,
    /// Objects in each receptacle, in the order they were put there.
    contents: [Vec<usize>; NUM_RECEPTACLES],
    place: Place,
    /// Index of the last search location visited.
    cursor: Option<usize>,
    held: Option<usize>,
    steps: usize,
    over: bool,
    last_failure: Option<Failure>,
}

impl Episode {
    fn visible(&self) -> Vec<usize> {
        match self.place {
            Place::Start => Vec::new(),
            Place::Location(i) => (0..self.scene.objects.len())
                .filter(|&k| {
                    self.scene.objects[k].location == i
                        && self.whereabouts[k] == Whereabouts::AtLocation
                })
                .collect(),
            Place::Receptacle(r) => self.contents[r.index()].clone(),
        }
    }
}

/// The Object Collection environment for one task (Gymnasium-style, see
/// [`ctg_graph::Environment`]).
///
/// Built from a [`Task`] and a [`CollectConfig`]; each `reset(seed)` draws a
/// new scene (the seed is mixed with the task's code, so two tasks with the
/// same seed get unrelated scenes). `Send + Clone`: clone one per thread.
///
/// Every real action counts as a step, failed ones included; the step that
/// reaches the limit is truncated. The reward is 1 on the step that ends the
/// episode (`<end>`, or truncation) if the task is then complete, else 0.
/// Besides the trait, it offers privileged read access to the hidden state
/// ([`CollectEnv::scene`], [`CollectEnv::held`], …) for the expert and tests.
#[derive(Debug, Clone)]
pub struct CollectEnv {
    task: Task,
    config: CollectConfig,
    max_steps: usize,
    episode: Option<Episode>,
}

impl CollectEnv {
    /// An environment for `task`; errors if the step limit is zero.
    pub fn new(task: Task, config: CollectConfig) -> Result<Self, CollectError> {
        let max_steps = config
            .max_steps
            .unwrap_or_else(|| CollectConfig::default_max_steps(task.num_objects()));
        if max_steps == 0 {
            return Err(CollectError::InvalidConfig(
                "max_steps must be at least 1".into(),
            ));
        }
        Ok(CollectEnv {
            task,
            config,
            max_steps,
            episode: None,
        })
    }

    /// The task.
    pub fn task(&self) -> &Task {
        &self.task
    }

    /// The configuration.
    pub fn config(&self) -> &CollectConfig {
        &self.config
    }

    /// The current episode's scene (`None` before the first reset).
    pub fn scene(&self) -> Option<&Scene> {
        self.episode.as_ref().map(|e| &e.scene)
    }

    /// The seed of the current episode.
    pub fn seed(&self) -> Option<u64> {
        self.episode.as_ref().map(|e| e.seed)
    }

    /// Where the agent is (`None` before the first reset).
    pub fn place(&self) -> Option<Place> {
        self.episode.as_ref().map(|e| e.place)
    }

    /// Category of the held object, if any.
    pub fn held(&self) -> Option<Category> {
        let e = self.episode.as_ref()?;
        e.held.map(|k| e.scene.objects[k].category)
    }

    /// Categories of the objects visible at the current place (on the
    /// location's surface or inside the receptacle), in drawing order.
    pub fn visible(&self) -> Vec<Category> {
        self.episode.as_ref().map_or_else(Vec::new, |e| {
            e.visible()
                .into_iter()
                .map(|k| e.scene.objects[k].category)
                .collect()
        })
    }

    /// Whether the target of `category` is in its designated receptacle.
    pub fn is_delivered(&self, category: Category) -> bool {
        let (Some(e), Some(r)) = (&self.episode, self.task.receptacle_of(category)) else {
            return false;
        };
        e.scene
            .objects
            .iter()
            .zip(&e.whereabouts)
            .any(|(o, &w)| o.is_target && o.category == category && w == Whereabouts::In(r))
    }

    /// Number of targets in their designated receptacle.
    pub fn delivered(&self) -> usize {
        self.task
            .targets()
            .iter()
            .filter(|t| self.is_delivered(t.category))
            .count()
    }

    /// Real actions taken in this episode.
    pub fn steps_taken(&self) -> usize {
        self.episode.as_ref().map_or(0, |e| e.steps)
    }

    /// Whether the episode is over (terminated or truncated).
    pub fn is_over(&self) -> bool {
        self.episode.as_ref().is_some_and(|e| e.over)
    }

    fn info(&self, action: Option<Action>, failure: Option<Failure>) -> CollectInfo {
        CollectInfo {
            action,
            failure,
            delivered: self.delivered(),
            num_targets: self.task.num_objects(),
        }
    }

    fn observe(&self) -> CollectObservation {
        let Some(e) = &self.episode else {
            return CollectObservation {
                frame: None,
                state: vec![0.0; STATE_LEN],
            };
        };
        let visible = e.visible();
        let mut state = vec![0.0; STATE_LEN];
        match e.place {
            Place::Start => state[AT_START] = 1.0,
            Place::Location(_) => state[AT_LOCATION] = 1.0,
            Place::Receptacle(r) => state[AT_RECEPTACLE + r.index()] = 1.0,
        }
        for &k in &visible {
            state[VISIBLE + e.scene.objects[k].category.index()] += 1.0;
        }
        if let Some(k) = e.held {
            state[HELD + e.scene.objects[k].category.index()] = 1.0;
        }
        if e.last_failure.is_some() {
            state[FAILED] = 1.0;
        }
        let frame = self.config.render.then(|| render_frame(e, &visible));
        CollectObservation { frame, state }
    }
}

fn render_frame(e: &Episode, visible: &[usize]) -> RgbImage {
    let mut img = RgbImage::new(FRAME_SIZE, FRAME_SIZE);
    let salt = draw_place(&mut img, &e.scene, e.place, visible, None);
    draw_hand_of(&mut img, &e.scene, e.held);
    render::add_noise(&mut img, salt);
    img
}

/// Draws `place` of `scene` with the objects `visible` there (indices into
/// [`Scene::objects`], in drawing order; inside a receptacle the `i`-th
/// takes slot `i`), leaving out `skip` but keeping the others' slots; no
/// hand inset, no noise. Returns the place's noise salt.
pub(crate) fn draw_place(
    img: &mut RgbImage,
    scene: &Scene,
    place: Place,
    visible: &[usize],
    skip: Option<usize>,
) -> u64 {
    let shown = visible
        .iter()
        .enumerate()
        .filter(|&(_, &k)| Some(k) != skip);
    match place {
        Place::Start => {
            render::draw_start(img, &scene.start);
            scene.start.salt
        }
        Place::Location(i) => {
            let loc = &scene.locations[i];
            render::draw_surface(img, loc.surface, &loc.backdrop);
            for (_, &k) in shown {
                let (x, y, size) = object_pose(scene, place, visible, k);
                let o = &scene.objects[k];
                render::draw_object(img, o.category, x, y, size, &o.appearance);
            }
            loc.backdrop.salt
        }
        Place::Receptacle(r) => {
            let backdrop = &scene.receptacles[r.index()];
            render::draw_receptacle(img, r, backdrop);
            for (slot, &k) in shown {
                let o = &scene.objects[k];
                let (x, y) = render::receptacle_slot(r, slot);
                render::draw_object(img, o.category, x, y, RECEPTACLE_OBJECT_SIZE, &o.appearance);
            }
            backdrop.salt
        }
    }
}

/// Where object `k` (one of `visible` at `place`) is drawn: centre and size.
pub(crate) fn object_pose(
    scene: &Scene,
    place: Place,
    visible: &[usize],
    k: usize,
) -> (f32, f32, f32) {
    let o = &scene.objects[k];
    match place {
        Place::Receptacle(r) => {
            let slot = visible.iter().position(|&j| j == k).unwrap_or(0);
            let (x, y) = render::receptacle_slot(r, slot);
            (x, y, RECEPTACLE_OBJECT_SIZE)
        }
        Place::Start | Place::Location(_) => (o.position.0, o.position.1, o.appearance.size),
    }
}

/// Draws the hand inset holding object `held` of `scene`, if any.
pub(crate) fn draw_hand_of(img: &mut RgbImage, scene: &Scene, held: Option<usize>) {
    let held = held.map(|k| (scene.objects[k].category, &scene.objects[k].appearance));
    render::draw_hand(img, held);
}

/// What the agent sees, as object indices: the crate's view of one moment
/// of an episode, for rendering frames between observations.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Snapshot {
    /// Where the agent is.
    pub(crate) place: Place,
    /// Objects visible there, in drawing order.
    pub(crate) visible: Vec<usize>,
    /// The held object.
    pub(crate) held: Option<usize>,
}

impl CollectEnv {
    /// The current moment as object indices (`None` before the first reset).
    pub(crate) fn snapshot(&self) -> Option<Snapshot> {
        self.episode.as_ref().map(|e| Snapshot {
            place: e.place,
            visible: e.visible(),
            held: e.held,
        })
    }
}

impl Environment for CollectEnv {
    type Observation = CollectObservation;
    type Info = CollectInfo;

    fn vocabulary(&self) -> &Vocabulary {
        vocabulary()
    }

    fn reset(&mut self, seed: u64) -> ctg_graph::Result<(CollectObservation, CollectInfo)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ splitmix64(u64::from(self.task.code())));
        let scene = Scene::generate(&self.task, self.config.max_distractors, &mut rng);
        self.episode = Some(Episode {
            seed,
            whereabouts: vec![Whereabouts::AtLocation; scene.objects.len()],
            scene,
            contents: Default::default(),
            place: Place::Start,
            cursor: None,
            held: None,
            steps: 0,
            over: false,
            last_failure: None,
        });
        Ok((self.observe(), self.info(None, None)))
    }

    fn step(
        &mut self,
        action: ActionId,
    ) -> ctg_graph::Result<Step<CollectObservation, CollectInfo>> {
        let max_steps = self.max_steps;
        let e = self.episode.as_mut().ok_or(CtgError::NotReset)?;
        if e.over {
            return Err(CtgError::EpisodeOver);
        }
        vocabulary().check(action)?;
        if action == Vocabulary::END {
            e.over = true;
            let success = self.is_success();
            return Ok(Step {
                observation: self.observe(),
                reward: if success { 1.0 } else { 0.0 },
                terminated: true,
                truncated: false,
                info: self.info(None, None),
            });
        }
        let typed = Action::from_id(action).ok_or_else(|| CtgError::InvalidAction {
            action: vocabulary().name(action).unwrap_or("?").to_owned(),
            reason: "<start> is not an action".into(),
        })?;
        let failure = match typed {
            Action::Search => {
                let m = e.scene.locations.len();
                let next = e.cursor.map_or(0, |c| (c + 1) % m);
                e.cursor = Some(next);
                e.place = Place::Location(next);
                None
            }
            Action::Pickup(category) => {
                if e.held.is_some() {
                    Some(Failure::HandsFull)
                } else if let Some(k) = e
                    .visible()
                    .into_iter()
                    .find(|&k| e.scene.objects[k].category == category)
                {
                    if let Place::Receptacle(r) = e.place {
                        e.contents[r.index()].retain(|&j| j != k);
                    }
                    e.whereabouts[k] = Whereabouts::Held;
                    e.held = Some(k);
                    None
                } else {
                    Some(Failure::NotVisible(category))
                }
            }
            Action::Dropoff(r) => {
                e.place = Place::Receptacle(r);
                match e.held.take() {
                    Some(k) => {
                        e.whereabouts[k] = Whereabouts::In(r);
                        e.contents[r.index()].push(k);
                        None
                    }
                    None => Some(Failure::HandsEmpty),
                }
            }
        };
        e.last_failure = failure;
        e.steps += 1;
        let truncated = e.steps >= max_steps;
        if truncated {
            e.over = true;
        }
        let reward = if truncated && self.is_success() {
            1.0
        } else {
            0.0
        };
        Ok(Step {
            observation: self.observe(),
            reward,
            terminated: false,
            truncated,
            info: self.info(Some(typed), failure),
        })
    }

    /// Every target is in its designated receptacle.
    fn is_success(&self) -> bool {
        self.episode.is_some() && self.delivered() == self.task.num_objects()
    }

    fn max_episode_steps(&self) -> usize {
        self.max_steps
    }
}
