//! Demonstration videos: many frames per action, of varying number.
//!
//! A one-frame-per-action demonstration ([`ctg_graph::record_demonstration`])
//! shows the scene once each action is done. A video demonstration
//! ([`record_video_demo`]) shows the motion too, in one segment of frames
//! per action (plus segment 0, the starting view), each ending on exactly
//! the frame the environment observes once that action is done:
//!
//! - `search`: walking to the next search location, the view panning
//!   horizontally from the previous place to the new one;
//! - `pickup(category)`: the arm reaching for the object, then the object
//!   lifting off the surface towards the hand inset (a failed pickup reaches
//!   into empty space and pulls back, the hand staying as it was);
//! - `dropoff(receptacle)`: walking up to the receptacle (the previous view
//!   zooming in and fading into the receptacle, its door closed), opening
//!   its door, and the held object dropping from the hand into its slot.
//!
//! How many frames each phase gets is drawn uniformly from the ranges of a
//! [`VideoConfig`] by the recorder's own RNG, seeded from the episode seed
//! (never from the environment's): recording frames does not change what
//! happens, and the keyframes of a video are byte for byte the frames of
//! the one-frame demonstration with the same seed. Every frame has the
//! environment's sensor noise ([`render::add_noise`]); intermediate frames
//! get a fresh noise pattern each.
//!
//! [`VideoRecorder`] renders the segment of any step (a policy's rollout
//! too); [`record_video_demo`] records the expert with it, and
//! [`generate_video_demos`] records many in parallel.

use std::ops::RangeInclusive;

use ctg_graph::{ActionId, CtgError, Environment, Expert, Step, VideoDemonstration, Vocabulary};
use image::{Rgb, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::{
    CollectConfig, CollectEnv, CollectInfo, CollectObservation, Place, Scene, Snapshot,
    draw_hand_of, draw_place, object_pose,
};
use crate::render::{self, FRAME_SIZE, HAND_INSET_START, HAND_OBJECT_SIZE};
use crate::{Action, CollectError, CollectExpert, DemoJob, Task, splitmix64};

/// Most frames one phase may get ([`VideoConfig::validate`]).
pub const MAX_PHASE_FRAMES: usize = 64;

/// Mixed into the episode seed to seed the timing RNG.
const TIMING_SALT: u64 = 0x7669_6465_6f5f_7431;

/// A number of frames drawn uniformly from `min..=max`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameRange {
    /// Fewest frames (at least 1).
    pub min: usize,
    /// Most frames (at least `min`, at most [`MAX_PHASE_FRAMES`]).
    pub max: usize,
}

impl FrameRange {
    /// `min..=max` frames.
    pub const fn new(min: usize, max: usize) -> Self {
        FrameRange { min, max }
    }

    /// Exactly `n` frames.
    pub const fn fixed(n: usize) -> Self {
        FrameRange { min: n, max: n }
    }

    fn sample(self, rng: &mut ChaCha8Rng) -> usize {
        rng.random_range(self.min..=self.max)
    }
}

/// How many frames each phase of an action gets, drawn per action from
/// these ranges. The last phase of each action ends on its keyframe (the
/// environment's observation), which its count includes, so a `search`
/// segment has `search` frames, a `pickup` segment `reach + lift`, a
/// `dropoff` segment `approach + open + drop`, and segment 0 `start`.
///
/// The default gives 2–4 frames per `search`, 3–5 per `pickup` and 5–9 per
/// `dropoff`: a median of 3 or more frames per action, varying from demo
/// to demo.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VideoConfig {
    /// Segment 0: the starting view, zooming in to rest (default 1–2).
    pub start: FrameRange,
    /// `search`: walking to the next location, a horizontal pan from the
    /// previous place to the new one (default 2–4).
    pub search: FrameRange,
    /// `pickup`: the arm reaching for the object (default 1–2).
    pub reach: FrameRange,
    /// `pickup`: the object lifting into the hand, ending on the keyframe
    /// (default 2–3; a failed pickup pulls the empty hand back instead).
    pub lift: FrameRange,
    /// `dropoff`: walking up to the closed receptacle (default 2–4).
    pub approach: FrameRange,
    /// `dropoff`: opening its door (default 1–2).
    pub open: FrameRange,
    /// `dropoff`: the object dropping in, ending on the keyframe (default
    /// 2–3).
    pub drop: FrameRange,
}

impl Default for VideoConfig {
    fn default() -> Self {
        VideoConfig {
            start: FrameRange::new(1, 2),
            search: FrameRange::new(2, 4),
            reach: FrameRange::new(1, 2),
            lift: FrameRange::new(2, 3),
            approach: FrameRange::new(2, 4),
            open: FrameRange::new(1, 2),
            drop: FrameRange::new(2, 3),
        }
    }
}

impl VideoConfig {
    /// One frame per action and for the start: the video is exactly the
    /// one-frame demonstration.
    pub fn keyframes_only() -> Self {
        let one = FrameRange::fixed(1);
        VideoConfig {
            start: one,
            search: one,
            reach: FrameRange::fixed(0),
            lift: one,
            approach: FrameRange::fixed(0),
            open: FrameRange::fixed(0),
            drop: one,
        }
    }

    /// Every phase with its name, in drawing order.
    fn phases(&self) -> [(&'static str, FrameRange); 7] {
        [
            ("start", self.start),
            ("search", self.search),
            ("reach", self.reach),
            ("lift", self.lift),
            ("approach", self.approach),
            ("open", self.open),
            ("drop", self.drop),
        ]
    }

    /// Checks every range: `min <= max <= MAX_PHASE_FRAMES`, and at least
    /// one frame for the phases that end on a keyframe (`start`, `search`,
    /// `lift`, `drop`); the others may be 0 (skipped).
    pub fn validate(&self) -> Result<(), CollectError> {
        for (name, range) in self.phases() {
            let keyframe = matches!(name, "start" | "search" | "lift" | "drop");
            let problem = if range.min > range.max {
                Some(format!("min {} > max {}", range.min, range.max))
            } else if keyframe && range.min == 0 {
                Some("0 frames (this phase ends on the keyframe: at least 1)".to_owned())
            } else if range.max > MAX_PHASE_FRAMES {
                Some(format!("max {} > {MAX_PHASE_FRAMES}", range.max))
            } else {
                None
            };
            if let Some(problem) = problem {
                return Err(CollectError::InvalidConfig(format!(
                    "video phase `{name}`: {problem}"
                )));
            }
        }
        Ok(())
    }

    /// How many frames a segment of `action` may have.
    pub fn frames_per_action(&self, action: Action) -> RangeInclusive<usize> {
        let phases: &[FrameRange] = match action {
            Action::Search => &[self.search],
            Action::Pickup(_) => &[self.reach, self.lift],
            Action::Dropoff(_) => &[self.approach, self.open, self.drop],
        };
        phases.iter().map(|r| r.min).sum()..=phases.iter().map(|r| r.max).sum()
    }
}

/// Where the agent's arm comes from: below the frame, left of the hand
/// inset.
const SHOULDER: (f32, f32) = (36.0, 72.0);
/// Where a failed pickup reaches.
const EMPTY_REACH: (f32, f32) = (30.0, 28.0);
/// Centre of the hand inset.
const INSET_CENTRE: (f32, f32) = (
    (HAND_INSET_START + FRAME_SIZE) as f32 / 2.0,
    (HAND_INSET_START + FRAME_SIZE) as f32 / 2.0,
);

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

fn lerp_point(a: (f32, f32), b: (f32, f32), t: f32) -> (f32, f32) {
    (lerp(a.0, b.0, t), lerp(a.1, b.1, t))
}

/// Fraction `j / n` (for `n > 0`).
fn frac(j: usize, n: usize) -> f32 {
    j as f32 / n as f32
}

/// A place as seen at one moment, without hand inset and noise.
fn view(scene: &Scene, place: Place, visible: &[usize], skip: Option<usize>) -> RgbImage {
    let mut img = RgbImage::new(FRAME_SIZE, FRAME_SIZE);
    draw_place(&mut img, scene, place, visible, skip);
    img
}

/// The view turning right by `t` of a frame width: `from` slides out to
/// the left while `to` slides in from the right.
fn pan(from: &RgbImage, to: &RgbImage, t: f32) -> RgbImage {
    let w = FRAME_SIZE;
    let offset = (t.clamp(0.0, 1.0) * w as f32).round() as u32;
    RgbImage::from_fn(w, w, |x, y| {
        let sx = x + offset;
        if sx < w {
            *from.get_pixel(sx, y)
        } else {
            *to.get_pixel(sx - w, y)
        }
    })
}

/// `img` magnified `scale` times about its centre (nearest pixel; below 1
/// the border pixels extend outwards).
fn zoom(img: &RgbImage, scale: f32) -> RgbImage {
    let w = FRAME_SIZE;
    let c = w as f32 / 2.0;
    let source = |v: u32| {
        (((v as f32 + 0.5 - c) / scale + c).floor() as i64).clamp(0, i64::from(w) - 1) as u32
    };
    RgbImage::from_fn(w, w, |x, y| *img.get_pixel(source(x), source(y)))
}

/// `(1 − t) · a + t · b`, per channel.
fn blend(a: &RgbImage, b: &RgbImage, t: f32) -> RgbImage {
    RgbImage::from_fn(a.width(), a.height(), |x, y| {
        let (p, q) = (a.get_pixel(x, y).0, b.get_pixel(x, y).0);
        Rgb([0, 1, 2].map(|c| lerp(f32::from(p[c]), f32::from(q[c]), t).round() as u8))
    })
}

/// Records the frames between an environment's observations: segment 0 at
/// [`reset`](VideoRecorder::reset), one segment per
/// [`step`](VideoRecorder::step), each ending on the step's observed frame.
///
/// Works for any action sequence (a policy's rollout too): failed actions
/// get their own motion (a pickup reaching into empty space, a drop-off
/// with an empty hand opening the receptacle and dropping nothing). The
/// environment must render frames ([`CollectConfig::render`]).
#[derive(Debug, Clone)]
pub struct VideoRecorder {
    config: VideoConfig,
    rng: ChaCha8Rng,
    noise: u64,
    frames: u64,
}

impl VideoRecorder {
    /// A recorder with these phase lengths (checked by
    /// [`VideoConfig::validate`]).
    pub fn new(config: VideoConfig) -> Result<Self, CollectError> {
        config.validate()?;
        Ok(VideoRecorder {
            config,
            rng: ChaCha8Rng::seed_from_u64(TIMING_SALT),
            noise: 0,
            frames: 0,
        })
    }

    /// The phase lengths.
    pub fn config(&self) -> &VideoConfig {
        &self.config
    }

    fn check_render(env: &CollectEnv) -> Result<(), CollectError> {
        if env.config().render {
            Ok(())
        } else {
            Err(CollectError::InvalidConfig(
                "a video needs rendered frames: CollectConfig::render is false".into(),
            ))
        }
    }

    fn keyframe(observation: &CollectObservation) -> Result<RgbImage, CollectError> {
        observation
            .frame
            .clone()
            .ok_or_else(|| CollectError::InvalidConfig("the environment returned no frame".into()))
    }

    /// Resets `env` with `seed` and the timing RNG with a hash of `seed`;
    /// returns the observation, its info and segment 0 (ending on the
    /// observation's frame).
    pub fn reset(
        &mut self,
        env: &mut CollectEnv,
        seed: u64,
    ) -> Result<(CollectObservation, CollectInfo, Vec<RgbImage>), CollectError> {
        Self::check_render(env)?;
        self.rng = ChaCha8Rng::seed_from_u64(splitmix64(seed ^ TIMING_SALT));
        self.noise = self.rng.random();
        self.frames = 0;
        let (observation, info) = env.reset(seed)?;
        let n = self.config.start.sample(&mut self.rng);
        let (scene, now) = Self::moment(env)?;
        let rest = view(scene, now.place, &now.visible, None);
        let mut frames: Vec<RgbImage> = (1..n)
            .map(|j| {
                let img = zoom(&rest, lerp(0.75, 1.0, frac(j, n)));
                self.finish(img, scene, now.held, |_| {})
            })
            .collect();
        frames.push(Self::keyframe(&observation)?);
        Ok((observation, info, frames))
    }

    /// Takes `action` in `env`; returns the step and its segment (ending on
    /// the observation's frame). `<end>` gets that frame only.
    pub fn step(
        &mut self,
        env: &mut CollectEnv,
        action: ActionId,
    ) -> Result<(Step<CollectObservation, CollectInfo>, Vec<RgbImage>), CollectError> {
        Self::check_render(env)?;
        let (_, before) = Self::moment(env)?;
        let step = env.step(action)?;
        let (scene, after) = Self::moment(env)?;
        let mut frames = match step.info.action {
            Some(Action::Search) => self.search(scene, &before, &after),
            Some(Action::Pickup(_)) => self.pickup(scene, &before, &after),
            Some(Action::Dropoff(_)) => self.dropoff(scene, &before, &after),
            None => Vec::new(),
        };
        frames.push(Self::keyframe(&step.observation)?);
        Ok((step, frames))
    }

    fn moment(env: &CollectEnv) -> Result<(&Scene, Snapshot), CollectError> {
        match (env.scene(), env.snapshot()) {
            (Some(scene), Some(now)) => Ok((scene, now)),
            _ => Err(CtgError::NotReset.into()),
        }
    }

    /// Adds the hand inset, `overlay` (drawn over it) and fresh noise.
    fn finish(
        &mut self,
        mut img: RgbImage,
        scene: &Scene,
        held: Option<usize>,
        overlay: impl FnOnce(&mut RgbImage),
    ) -> RgbImage {
        draw_hand_of(&mut img, scene, held);
        overlay(&mut img);
        self.frames += 1;
        render::add_noise(&mut img, splitmix64(self.noise ^ self.frames));
        img
    }

    /// The frames of a `search` before its keyframe.
    fn search(&mut self, scene: &Scene, before: &Snapshot, after: &Snapshot) -> Vec<RgbImage> {
        let n = self.config.search.sample(&mut self.rng);
        let from = view(scene, before.place, &before.visible, None);
        let to = view(scene, after.place, &after.visible, None);
        (1..n)
            .map(|j| self.finish(pan(&from, &to, frac(j, n)), scene, before.held, |_| {}))
            .collect()
    }

    /// The frames of a `pickup` before its keyframe.
    fn pickup(&mut self, scene: &Scene, before: &Snapshot, after: &Snapshot) -> Vec<RgbImage> {
        let reach = self.config.reach.sample(&mut self.rng);
        let lift = self.config.lift.sample(&mut self.rng);
        let picked = match (before.held, after.held) {
            (None, Some(k)) => Some(k),
            _ => None,
        };
        let base = view(scene, before.place, &before.visible, picked);
        let mut frames = Vec::with_capacity(reach + lift);
        let Some(k) = picked else {
            // Failed: reach into empty space and pull the hand back.
            let extent = (1..=reach)
                .map(|j| frac(j, reach))
                .chain((1..lift).map(|j| 1.0 - frac(j, lift)));
            for t in extent {
                let hand = lerp_point(SHOULDER, EMPTY_REACH, t);
                let arm = |img: &mut RgbImage| render::draw_arm(img, SHOULDER, hand);
                frames.push(self.finish(base.clone(), scene, before.held, arm));
            }
            return frames;
        };
        let o = &scene.objects[k];
        let (x, y, size) = object_pose(scene, before.place, &before.visible, k);
        let draw = |img: &mut RgbImage, (cx, cy): (f32, f32), s: f32| {
            render::draw_object(img, o.category, cx, cy, s, &o.appearance);
        };
        for j in 1..=reach {
            let hand = lerp_point(SHOULDER, (x, y), frac(j, reach));
            frames.push(self.finish(base.clone(), scene, None, |img| {
                draw(img, (x, y), size);
                render::draw_arm(img, SHOULDER, hand);
            }));
        }
        for j in 1..lift {
            let t = frac(j, lift);
            let (px, py) = lerp_point((x, y), INSET_CENTRE, t);
            let at = (px, py - 10.0 * (std::f32::consts::PI * t).sin());
            let s = lerp(size, HAND_OBJECT_SIZE, t);
            frames.push(self.finish(base.clone(), scene, None, |img| {
                render::draw_arm(img, SHOULDER, at);
                draw(img, at, s);
            }));
        }
        frames
    }

    /// The frames of a `dropoff` before its keyframe.
    fn dropoff(&mut self, scene: &Scene, before: &Snapshot, after: &Snapshot) -> Vec<RgbImage> {
        let approach = self.config.approach.sample(&mut self.rng);
        let open = self.config.open.sample(&mut self.rng);
        let drop = self.config.drop.sample(&mut self.rng);
        let Place::Receptacle(r) = after.place else {
            return Vec::new(); // a drop-off always ends at its receptacle
        };
        let dropped = match (before.held, after.held) {
            (Some(k), None) => Some(k),
            _ => None,
        };
        let backdrop = &scene.receptacles[r.index()];
        let from = view(scene, before.place, &before.visible, None);
        let inside = view(scene, after.place, &after.visible, dropped);
        let door = |open: f32| {
            let mut img = inside.clone();
            render::draw_receptacle_door(&mut img, r, backdrop, open);
            img
        };
        let closed = door(0.0);
        let mut frames = Vec::with_capacity(approach + open + drop);
        for j in 1..=approach {
            let t = frac(j, approach);
            let img = blend(&zoom(&from, 1.0 + t), &zoom(&closed, lerp(0.5, 1.0, t)), t);
            frames.push(self.finish(img, scene, before.held, |_| {}));
        }
        for j in 1..=open {
            let img = door(frac(j, open + 1));
            frames.push(self.finish(img, scene, before.held, |_| {}));
        }
        for j in 1..drop {
            let frame = match dropped {
                Some(k) => {
                    let o = &scene.objects[k];
                    let (x, y, size) = object_pose(scene, after.place, &after.visible, k);
                    let t = frac(j, drop);
                    let (cx, cy) = lerp_point(INSET_CENTRE, (x, y), t);
                    let s = lerp(HAND_OBJECT_SIZE, size, t);
                    self.finish(inside.clone(), scene, None, |img| {
                        render::draw_object(img, o.category, cx, cy, s, &o.appearance);
                    })
                }
                None => self.finish(inside.clone(), scene, before.held, |_| {}),
            };
            frames.push(frame);
        }
        frames
    }
}

/// Records the expert's ([`CollectExpert`]) demonstration of `task` in the
/// scene of `seed` as a video: the same actions, failures and scene as
/// `ctg_graph::record_demonstration(&mut CollectEnv::new(task, config)?,
/// &mut CollectExpert, seed)`, whose observed frames are the video's
/// keyframes, with each action's motion rendered before its keyframe
/// (phase lengths from `video`, drawn by an RNG seeded from `seed`).
///
/// Errors if `config.render` is false, `video` is invalid, or the expert
/// does not finish within the step limit.
///
/// ```
/// use env_collect::{CollectConfig, Task, TaskSplitter, VideoConfig, record_video_demo};
/// use rand::SeedableRng;
///
/// let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
/// let task = TaskSplitter::default().sample(2, None, &mut rng).unwrap();
/// let video =
///     record_video_demo(task, CollectConfig::default(), 7, &VideoConfig::default()).unwrap();
/// assert!(video.num_frames() >= 3 * video.len());
/// assert_eq!(video.frames()[0].dimensions(), (64, 64));
/// ```
pub fn record_video_demo(
    task: Task,
    config: CollectConfig,
    seed: u64,
    video: &VideoConfig,
) -> Result<VideoDemonstration<RgbImage>, CollectError> {
    let mut env = CollectEnv::new(task, config)?;
    let mut recorder = VideoRecorder::new(video.clone())?;
    let mut expert = CollectExpert;
    let (_, _, first) = recorder.reset(&mut env, seed)?;
    expert.reset(&env, seed);
    let mut segments = vec![first];
    let mut actions = Vec::new();
    loop {
        let action = expert.next_action(&env)?;
        if action == Vocabulary::END {
            break;
        }
        let (step, frames) = recorder.step(&mut env, action)?;
        actions.push(action);
        segments.push(frames);
        if step.terminated {
            break;
        }
        if step.truncated {
            return Err(CtgError::ExpertFailed(format!(
                "hit the step limit ({}) before finishing (seed {seed})",
                env.max_episode_steps()
            ))
            .into());
        }
    }
    Ok(VideoDemonstration::from_segments(
        segments,
        actions,
        env.vocabulary(),
    )?)
}

/// Records every job's video in parallel (rayon), in job order; each
/// depends only on its own task and seed, so the result equals recording
/// them one by one. The first error (in job order) is returned.
pub fn generate_video_demos(
    jobs: &[DemoJob],
    config: &CollectConfig,
    video: &VideoConfig,
) -> Result<Vec<VideoDemonstration<RgbImage>>, CollectError> {
    jobs.par_iter()
        .map(|job| record_video_demo(job.task.clone(), *config, job.seed, video))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(k: u8) -> RgbImage {
        RgbImage::from_fn(FRAME_SIZE, FRAME_SIZE, |x, y| {
            Rgb([x as u8 * 4, y as u8 * 4, k])
        })
    }

    #[test]
    fn pan_zoom_and_blend_meet_their_ends() {
        let (a, b) = (gradient(10), gradient(200));
        assert_eq!(pan(&a, &b, 0.0), a);
        assert_eq!(pan(&a, &b, 1.0), b);
        let half = pan(&a, &b, 0.5);
        assert_eq!(half.get_pixel(0, 5), a.get_pixel(32, 5));
        assert_eq!(half.get_pixel(40, 5), b.get_pixel(8, 5));
        assert_eq!(zoom(&a, 1.0), a);
        // Magnified 2×: the centre pixel stays, a corner comes from nearer
        // the centre.
        let z = zoom(&a, 2.0);
        assert_eq!(z.get_pixel(32, 32), a.get_pixel(32, 32));
        assert_eq!(z.get_pixel(0, 0), a.get_pixel(16, 16));
        assert_eq!(blend(&a, &b, 0.0), a);
        assert_eq!(blend(&a, &b, 1.0), b);
        assert_eq!(blend(&a, &b, 0.5).get_pixel(3, 3).0[2], 105);
    }

    #[test]
    fn frames_per_action_adds_the_phases() {
        let c = VideoConfig::default();
        assert_eq!(c.frames_per_action(Action::Search), 2..=4);
        assert_eq!(
            c.frames_per_action(Action::Pickup(crate::Category::Egg)),
            3..=5
        );
        assert_eq!(
            c.frames_per_action(Action::Dropoff(crate::Receptacle::Sink)),
            5..=9
        );
        let k = VideoConfig::keyframes_only();
        for a in Action::all() {
            assert_eq!(k.frames_per_action(a), 1..=1);
        }
    }
}
