//! Demonstration videos: the expert's demonstration rendered along each
//! primitive's motion, several frames per flat action.
//!
//! [`record_video_demo`] runs the same expert in the same environment as
//! [`expert_demo`](crate::expert_demo) and
//! [`record_rich_demo`](crate::record_rich_demo) with the same seed (same
//! scene, same actions, same slips and off-centre drops: the state
//! trajectory does not depend on the frames), and renders between each
//! flat action's start and end world the motion of its primitives:
//!
//! - `move(t)`: the gripper travels on an arc (whose top clears every
//!   resting cube) from where it is to above `t`, carrying a held cube;
//! - `grasp`: the gripper descends around the cube, closes on it and lifts
//!   it; a slipped grasp closes on nothing and rises without the cube;
//! - `drop`: the gripper opens and the cube falls to where the world says
//!   it lands (off-centre, or toppled off its support, when it does).
//!
//! How many frames each phase gets is drawn from [`VideoConfig`]'s ranges by
//! an RNG of its own (seeded from the episode's seed and a constant), never
//! from the environment's, so the keyframes (the last frame of each
//! segment) are exactly the frames of the one-frame-per-action demo.

use ctg_graph::{ActionId, CtgError, Environment, Expert, VideoDemonstration, Vocabulary};
use glam::Vec3;
use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::{ActionLevel, BlocksEnv, BlocksTask, EnvConfig, PrimitiveEvent};
use crate::error::BlocksError;
use crate::expert::BlocksExpert;
use crate::render::{Fingers, Renderer};
use crate::world::{CUBE_HALF, Failure, FailureConfig, HOVER_GAP, Outcome, Primitive, World};

/// Mixed into the episode's seed for the timing RNG, so that frame counts
/// are independent of the scene's, the failures' and the expert's streams.
const VIDEO_STREAM: u64 = 0x2545_f491_4f6c_dd1d;

/// An inclusive range of frame counts, drawn uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameRange {
    /// Fewest frames (at least 1).
    pub min: usize,
    /// Most frames (at least `min`).
    pub max: usize,
}

impl FrameRange {
    /// `min..=max` frames.
    pub const fn new(min: usize, max: usize) -> Self {
        FrameRange { min, max }
    }

    /// Exactly `n` frames.
    pub const fn exactly(n: usize) -> Self {
        FrameRange { min: n, max: n }
    }

    fn sample(&self, rng: &mut impl Rng) -> usize {
        if self.max > self.min {
            rng.random_range(self.min..=self.max)
        } else {
            self.min
        }
    }
}

/// How many frames each phase of a primitive's motion gets (seeded uniform
/// counts in inclusive ranges).
///
/// A flat `pick(X)` is `move(X)` (travel) then `grasp` (descend, close,
/// lift); a `place(Y)` is `move(Y)` (travel) then `drop` (open, fall). The
/// default gives 5 to 9 frames per pick and 4 to 7 per place (median 6 per
/// flat action), and 1 or 2 still frames of the starting scene. Missing
/// fields read from JSON take their defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct VideoConfig {
    /// Still frames of the starting scene (segment 0).
    pub start: FrameRange,
    /// Frames of a `move`'s travel.
    pub travel: FrameRange,
    /// Frames of a `grasp`'s descent around the cube.
    pub descend: FrameRange,
    /// Frames of the fingers closed at the bottom of a `grasp`.
    pub close: FrameRange,
    /// Frames of a `grasp`'s lift (the last one is the world after it).
    pub lift: FrameRange,
    /// Frames of a `drop`'s opening, the cube not yet falling.
    pub open: FrameRange,
    /// Frames of the dropped cube's fall (the last one is where it lands).
    pub fall: FrameRange,
}

impl Default for VideoConfig {
    /// Start 1–2, travel 2–4, descend 1–2, close 1, lift 1–2, open 1,
    /// fall 1–2 frames.
    fn default() -> Self {
        VideoConfig {
            start: FrameRange::new(1, 2),
            travel: FrameRange::new(2, 4),
            descend: FrameRange::new(1, 2),
            close: FrameRange::exactly(1),
            lift: FrameRange::new(1, 2),
            open: FrameRange::exactly(1),
            fall: FrameRange::new(1, 2),
        }
    }
}

impl VideoConfig {
    /// One frame per phase and per start: the shortest video with every
    /// phase shown (3 or 4 frames per pick, 3 per place).
    pub fn one_per_phase() -> Self {
        let one = FrameRange::exactly(1);
        VideoConfig {
            start: one,
            travel: one,
            descend: one,
            close: one,
            lift: one,
            open: one,
            fall: one,
        }
    }

    fn ranges(&self) -> [(&'static str, FrameRange); 7] {
        [
            ("start", self.start),
            ("travel", self.travel),
            ("descend", self.descend),
            ("close", self.close),
            ("lift", self.lift),
            ("open", self.open),
            ("fall", self.fall),
        ]
    }

    /// Whether every range is usable: at least 1 frame, `min <= max`.
    pub fn validate(&self) -> Result<(), BlocksError> {
        for (name, r) in self.ranges() {
            if r.min == 0 {
                return Err(BlocksError::Invalid(format!(
                    "video config: `{name}` allows 0 frames (min must be at least 1)"
                )));
            }
            if r.min > r.max {
                return Err(BlocksError::Invalid(format!(
                    "video config: `{name}` has min {} > max {}",
                    r.min, r.max
                )));
            }
        }
        Ok(())
    }
}

/// A scene between two worlds: cube centres, the gripper's grasp point and
/// its fingers (the bins never move).
#[derive(Debug, Clone, PartialEq)]
struct Pose {
    objects: Vec<Vec3>,
    gripper: Vec3,
    fingers: Fingers,
}

impl Pose {
    fn of(world: &World) -> Pose {
        Pose {
            objects: world.objects().to_vec(),
            gripper: world.gripper(),
            fingers: Fingers::of(world),
        }
    }

    /// The same pose with the gripper at `g`, carrying `held` with it.
    fn with_gripper(&self, g: Vec3, held: Option<usize>, fingers: Fingers) -> Pose {
        let mut pose = self.clone();
        pose.gripper = g;
        pose.fingers = fingers;
        if let Some(h) = held
            && let Some(p) = pose.objects.get_mut(h)
        {
            *p = g;
        }
        pose
    }
}

/// `k / n` for the frames `k = 1..=n` of a phase (exactly 1 for the last).
fn phase_times(n: usize) -> impl Iterator<Item = f32> {
    (1..=n).map(move |k| if k == n { 1.0 } else { k as f32 / n as f32 })
}

fn lerp(a: Vec3, b: Vec3, t: f32) -> Vec3 {
    if t >= 1.0 { b } else { a + (b - a) * t }
}

/// Height of the grasp point that keeps a carried cube (and the fingers)
/// `HOVER_GAP` above every resting cube and bin.
fn clearance(world: &World) -> f32 {
    let mut top = world.bins().iter().map(|b| b.top()).fold(0.0, f32::max);
    for (j, q) in world.objects().iter().enumerate() {
        if Some(j) != world.held() {
            top = top.max(q.z + CUBE_HALF);
        }
    }
    top + CUBE_HALF + HOVER_GAP
}

/// Turns one flat step (the world before it, the world after it, and the
/// primitives it ran) into poses, the last one the world after it.
struct Animator<'a> {
    video: &'a VideoConfig,
    rng: ChaCha8Rng,
}

impl Animator<'_> {
    fn step(&mut self, before: &World, after: &World, events: &[PrimitiveEvent]) -> Vec<Pose> {
        let mut poses = Vec::new();
        let mut sim = before.clone();
        let mut pose = Pose::of(before);
        for event in events {
            match (event.primitive, event.outcome) {
                (Primitive::Move(t), Outcome::Moved { .. }) => {
                    // A move draws nothing from the RNG: replaying it on the
                    // world before gives the world in between.
                    let mut next = sim.clone();
                    let mut unused = ChaCha8Rng::seed_from_u64(0);
                    let replayed =
                        next.apply(Primitive::Move(t), &FailureConfig::none(), &mut unused);
                    debug_assert_eq!(replayed, event.outcome);
                    self.travel(
                        &pose,
                        next.gripper(),
                        sim.held(),
                        clearance(&sim),
                        &mut poses,
                    );
                    sim = next;
                    pose = Pose::of(&sim);
                }
                (Primitive::Grasp, Outcome::Grasped { object }) => {
                    self.grasp(&pose, object, after.gripper(), true, &mut poses);
                    sim = after.clone();
                    pose = Pose::of(&sim);
                }
                (Primitive::Grasp, Outcome::Failed(Failure::Slipped { object })) => {
                    self.grasp(&pose, object, after.gripper(), false, &mut poses);
                    sim = after.clone();
                    pose = Pose::of(&sim);
                }
                (Primitive::Drop, Outcome::Dropped { object, .. }) => {
                    let landed = after.objects().get(object).copied();
                    self.drop(&pose, object, landed, &mut poses);
                    sim = after.clone();
                    pose = Pose::of(&sim);
                }
                // A failed primitive leaves the world as it was: one still
                // frame.
                _ => poses.push(pose.clone()),
            }
        }
        // The last pose is the world after the step: rendered as the
        // environment renders that world (its keyframe).
        match poses.last_mut() {
            Some(last) => *last = Pose::of(after),
            None => poses.push(Pose::of(after)),
        }
        poses
    }

    /// The gripper from `from.gripper` to `to` on an arc whose top clears
    /// `clear`, carrying `held`.
    fn travel(
        &mut self,
        from: &Pose,
        to: Vec3,
        held: Option<usize>,
        clear: f32,
        poses: &mut Vec<Pose>,
    ) {
        let g0 = from.gripper;
        let bump = (clear.max(g0.z).max(to.z) - (g0.z + to.z) / 2.0).max(0.0);
        for t in phase_times(self.video.travel.sample(&mut self.rng)) {
            let mut g = lerp(g0, to, t);
            if t < 1.0 {
                g.z += bump * 4.0 * t * (1.0 - t);
            }
            poses.push(from.with_gripper(g, held, from.fingers));
        }
    }

    /// Descend around cube `object`, close (on it, or on nothing when it
    /// slips), rise to `top` (with the cube when `holds`).
    fn grasp(&mut self, from: &Pose, object: usize, top: Vec3, holds: bool, poses: &mut Vec<Pose>) {
        let Some(&cube) = from.objects.get(object) else {
            poses.push(from.clone());
            return;
        };
        let g0 = from.gripper;
        for t in phase_times(self.video.descend.sample(&mut self.rng)) {
            poses.push(from.with_gripper(lerp(g0, cube, t), None, Fingers::Open));
        }
        let (fingers, held) = if holds {
            (Fingers::OnCube, Some(object))
        } else {
            (Fingers::ClosedEmpty, None)
        };
        let closed = from.with_gripper(cube, held, fingers);
        for _ in 0..self.video.close.sample(&mut self.rng) {
            poses.push(closed.clone());
        }
        for t in phase_times(self.video.lift.sample(&mut self.rng)) {
            poses.push(closed.with_gripper(lerp(cube, top, t), held, fingers));
        }
    }

    /// Open the fingers, then let cube `object` fall to `landed` (falling
    /// faster as it goes, sliding sideways if it lands off-centre).
    fn drop(&mut self, from: &Pose, object: usize, landed: Option<Vec3>, poses: &mut Vec<Pose>) {
        let opened = from.with_gripper(from.gripper, None, Fingers::Open);
        for _ in 0..self.video.open.sample(&mut self.rng) {
            poses.push(opened.clone());
        }
        let (Some(&start), Some(end)) = (opened.objects.get(object), landed) else {
            return;
        };
        for t in phase_times(self.video.fall.sample(&mut self.rng)) {
            let mut p = lerp(start, end, t);
            if t < 1.0 {
                p.z = start.z + (end.z - start.z) * t * t;
            }
            let mut pose = opened.clone();
            pose.objects[object] = p;
            poses.push(pose);
        }
    }
}

/// The poses of a video demonstration, segment by segment, with its actions
/// and the environment at its end.
struct PoseVideo {
    segments: Vec<Vec<Pose>>,
    actions: Vec<ActionId>,
    env: BlocksEnv,
}

/// Runs the expert's episode and turns each flat step into poses.
fn record_poses(
    task: BlocksTask,
    config: EnvConfig,
    seed: u64,
    video: &VideoConfig,
) -> Result<PoseVideo, BlocksError> {
    video.validate()?;
    let config = EnvConfig {
        level: ActionLevel::Flat,
        render: false,
        primitive_frames: false,
        ..config
    };
    let mut env = BlocksEnv::new(task, config)?;
    let mut expert = BlocksExpert::new();
    env.reset(seed)?;
    expert.reset(&env, seed);
    let mut animator = Animator {
        video,
        rng: ChaCha8Rng::seed_from_u64(seed ^ VIDEO_STREAM),
    };
    let still = Pose::of(env.world());
    let mut segments = vec![vec![still; video.start.sample(&mut animator.rng)]];
    let mut actions = Vec::new();
    loop {
        let id = expert.next_action(&env)?;
        if id == Vocabulary::END {
            break;
        }
        let before = env.world().clone();
        let step = env.step(id)?;
        segments.push(animator.step(&before, env.world(), &step.info.primitives));
        actions.push(id);
        if step.truncated {
            return Err(CtgError::ExpertFailed(format!(
                "hit the step limit ({}) before finishing (task {}, seed {seed})",
                env.max_episode_steps(),
                env.task().id()
            ))
            .into());
        }
    }
    if actions.is_empty() {
        return Err(CtgError::ExpertFailed(format!(
            "task {} already holds at the start (seed {seed}); nothing to demonstrate",
            env.task().id()
        ))
        .into());
    }
    Ok(PoseVideo {
        segments,
        actions,
        env,
    })
}

/// Records the expert's demonstration of `task` with `seed` as a video: the
/// same episode as [`expert_demo`](crate::expert_demo) and
/// [`record_rich_demo`](crate::record_rich_demo) with the same seed (flat
/// level; `config.render` and `config.primitive_frames` are ignored, frames
/// are always rendered), with each flat action's primitives rendered along
/// their motion (see the [module docs](self)).
///
/// Segment 0 holds 1 or more still frames of the starting scene; segment
/// `i + 1` the motion of flat action `i`, ending with exactly the frame the
/// environment renders once that action is done (same renderer, same
/// colours, same world), so `keyframes()` equals the flat demo's frames
/// byte for byte. Frame counts are drawn from `video`'s ranges by a timing
/// RNG seeded from `seed`.
///
/// Errors on an invalid `video` or failure configuration, or when the
/// expert fails (step limit, nothing to demonstrate).
pub fn record_video_demo(
    task: BlocksTask,
    config: EnvConfig,
    seed: u64,
    video: &VideoConfig,
) -> Result<VideoDemonstration<RgbImage>, BlocksError> {
    let PoseVideo {
        segments,
        actions,
        env,
    } = record_poses(task, config, seed, video)?;
    let colours = env.colours();
    let bins = env.world().bins();
    let renderer = Renderer::of(config.camera);
    let render = |pose: &Pose| {
        renderer.render_boxes(&Renderer::pose_boxes(
            &pose.objects,
            bins,
            pose.gripper,
            pose.fingers,
            &colours,
        ))
    };
    // A pose equal to the one before it (still frames) is rendered once.
    let mut last: Option<(&Pose, RgbImage)> = None;
    let mut frames = Vec::with_capacity(segments.len());
    for poses in &segments {
        let mut segment = Vec::with_capacity(poses.len());
        for pose in poses {
            let frame = match &last {
                Some((prev, frame)) if *prev == pose => frame.clone(),
                _ => render(pose),
            };
            last = Some((pose, frame.clone()));
            segment.push(frame);
        }
        frames.push(segment);
    }
    Ok(VideoDemonstration::from_segments(
        frames,
        actions,
        env.vocabulary(),
    )?)
}

/// The segment lengths (frames per segment, segment 0 first) of
/// [`record_video_demo`]'s video for the same arguments, without rendering
/// a frame: for statistics and memory planning (a frame is 64×64×3 bytes).
pub fn video_segment_lengths(
    task: BlocksTask,
    config: EnvConfig,
    seed: u64,
    video: &VideoConfig,
) -> Result<Vec<usize>, BlocksError> {
    Ok(record_poses(task, config, seed, video)?
        .segments
        .iter()
        .map(Vec::len)
        .collect())
}

/// Video demos for each `(task index, seed)` pair, in parallel on rayon's
/// current pool, in the order of `pairs` (each as [`record_video_demo`]).
pub fn generate_video_demos(
    tasks: &[BlocksTask],
    pairs: &[(usize, u64)],
    config: EnvConfig,
    video: &VideoConfig,
) -> Vec<Result<VideoDemonstration<RgbImage>, BlocksError>> {
    pairs
        .par_iter()
        .map(|&(index, seed)| {
            let task = tasks.get(index).ok_or_else(|| {
                BlocksError::Invalid(format!(
                    "task index {index} out of range ({} tasks)",
                    tasks.len()
                ))
            })?;
            record_video_demo(task.clone(), config, seed, video)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phase_times_end_exactly_at_one() {
        assert_eq!(phase_times(1).collect::<Vec<_>>(), [1.0]);
        assert_eq!(phase_times(4).collect::<Vec<_>>(), [0.25, 0.5, 0.75, 1.0]);
    }

    #[test]
    fn default_config_is_valid_and_reads_partial_json() {
        VideoConfig::default().validate().unwrap();
        VideoConfig::one_per_phase().validate().unwrap();
        let c: VideoConfig = serde_json::from_str(r#"{"travel": {"min": 3, "max": 5}}"#).unwrap();
        assert_eq!(c.travel, FrameRange::new(3, 5));
        assert_eq!(c.fall, VideoConfig::default().fall);
        let back: VideoConfig = serde_json::from_str(&serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }
}
