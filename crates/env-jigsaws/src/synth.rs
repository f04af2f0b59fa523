//! A seeded **synthetic stand-in** for JIGSAWS, written in the real layout.
//!
//! The real dataset is distributed by JHU on request and is not available
//! here. This generator produces data with the same *structure* — the same
//! trial inventory (Suturing 39 + the kinematics-only `Suturing_H002`,
//! Needle Passing 28, Knot Tying 36), the same file formats, meta rows with
//! the surgeons' real self-rated skill levels — but **none of its numbers
//! come from real surgery**: gesture sequences come from hand-written
//! per-task grammars and kinematics from a simple scripted two-arm model.
//! Results obtained on it say how the code behaves, not how NTG does on
//! JIGSAWS. The reader ([`Dataset::load`]) is the same code for both.
//!
//! # What is modelled
//!
//! - **Grammars** following the gestures' meaning (DATA.md). Suturing and
//!   Needle Passing: `G1`, usually `G5`, then 3–5 throws of
//!   (`G8`) `G2` `G3` `G6` (Suturing: sometimes `G9`, `G10`) `G4`, where a
//!   failed positioning (`G2`) or push (`G3`) goes back to `G8` or `G2`
//!   (Needle Passing mostly re-orients, `G8`), ending with `G11`. Knot
//!   Tying: `G1`, then 1–3 loops of `G12` `G13` `G14` `G15` with failed loops
//!   (`G13` again, or `G14` back to `G13`), ending with `G11`.
//! - **Skill** (from the surgeon letter: D, E expert; C, F intermediate;
//!   B, G, H, I novice): novices retry more (22 % per attempt vs 12 % and
//!   5 %), are slower (×1.3 vs ×1.0 and ×0.8) and shakier (tremor ×1.6 vs
//!   ×1.0 and ×0.6).
//! - **Durations**: per-gesture base durations of 1.5–2.8 s, scaled by
//!   skill and a log-normal factor, clamped to 1–5 s; a lead-in and tail of
//!   unlabelled frames and occasional unlabelled gaps between segments.
//! - **Kinematics** at 30 Hz: each patient-side arm moves on minimum-jerk
//!   paths towards gesture-specific targets (needle, tissue entry points or
//!   rings, centre, pull points, end points; a circle around the right tool
//!   for `G13`) with tremor; orientations rotate by gesture-specific
//!   rotations, so every rotation matrix is orthonormal with determinant 1
//!   (to the written precision, 1e-6); the gripper angle opens (0.9 rad) and
//!   closes (0.05 rad) when the gesture grasps or releases. The master arms
//!   are the patient-side motion scaled by [`MASTER_SCALE`] around a fixed
//!   offset, same orientation and gripper angle. Linear velocities are the
//!   **forward differences** of the written positions × 30
//!   (`v[t] = (p[t+1] − p[t])·30`, the last row repeating `v[T−2]`), and
//!   angular velocities the forward differences of the rotations,
//!   `log(R[t+1]·R[t]ᵀ)·30`, likewise. All values are rounded to 1e-6.
//! - **No videos** are written (`video/` is absent).
//!
//! Every trial is generated from its own RNG seeded by the dataset seed and
//! the trial id, so a subset is identical to the same trials of the full set
//! and the same seed always gives the same bytes.
//!
//! [`Dataset::load`]: crate::Dataset::load

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::dataset::{Dataset, Trial, kinematics_path, write_file};
use crate::error::{JigsawsError, Result};
use crate::kinematics::{ARM_COLUMNS, Arm, ArmState, KINEMATICS_COLUMNS, Kinematics};
use crate::transcription::{MetaRecord, Segment};
use crate::{FRAME_RATE, Gesture, Skill, Task, TrialId};

/// Master-side motion is patient-side motion times this (the console scales
/// the surgeon's hand motion down by this factor).
pub const MASTER_SCALE: f64 = 3.0;
/// Patient-side gripper angle when open (radians).
pub const GRIP_OPEN: f64 = 0.9;
/// Patient-side gripper angle when closed on needle or suture (radians).
pub const GRIP_CLOSED: f64 = 0.05;

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    /// The seed; the same seed gives the same dataset.
    pub seed: u64,
    /// Tasks to generate (default: all three).
    pub tasks: Vec<Task>,
    /// Keep only the first `n` trials of each task's inventory (default: all).
    pub max_trials_per_task: Option<usize>,
    /// Multiplies every duration (default 1; smaller gives smaller files, for
    /// tests).
    pub duration_scale: f64,
}

impl SynthConfig {
    /// The full inventory with this seed.
    pub fn new(seed: u64) -> SynthConfig {
        SynthConfig {
            seed,
            tasks: Task::ALL.to_vec(),
            max_trials_per_task: None,
            duration_scale: 1.0,
        }
    }
}

/// A generated dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticJigsaws {
    /// The complete trials.
    pub dataset: Dataset,
    /// Trials written with kinematics only (no transcription, no meta row),
    /// as `Suturing_H002` in the real dataset; the reader skips them with a
    /// warning.
    pub kinematics_only: Vec<(TrialId, Kinematics)>,
}

/// Generates the dataset in memory.
pub fn generate(config: &SynthConfig) -> Result<SyntheticJigsaws> {
    if !(config.duration_scale.is_finite() && config.duration_scale > 0.0) {
        return Err(JigsawsError::Config(format!(
            "duration_scale must be a positive number, got {}",
            config.duration_scale
        )));
    }
    let mut trials = Vec::new();
    let mut kinematics_only = Vec::new();
    for &task in &config.tasks {
        let limit = config.max_trials_per_task.unwrap_or(usize::MAX);
        for (surgeon, number) in task.inventory().into_iter().take(limit) {
            let id = TrialId::new(task, surgeon, number);
            let (meta, segments, kin) = generate_trial(config.seed, id, config.duration_scale);
            trials.push(Trial::new(meta, segments, kin)?);
        }
        if config.max_trials_per_task.is_none() {
            for &(surgeon, number) in task.kinematics_only_trials() {
                let id = TrialId::new(task, surgeon, number);
                let (_, _, kin) = generate_trial(config.seed, id, config.duration_scale);
                kinematics_only.push((id, kin));
            }
        }
    }
    Ok(SyntheticJigsaws {
        dataset: Dataset::from_trials(&config.tasks, trials),
        kinematics_only,
    })
}

/// Generates the dataset and writes it in the real layout under `out`
/// (created if needed). Refuses to write into a folder that already has one
/// of the task folders, so a real copy is never overwritten.
pub fn write_synthetic(config: &SynthConfig, out: &Path) -> Result<SyntheticJigsaws> {
    for task in &config.tasks {
        let folder = out.join(task.folder_name());
        if folder.exists() {
            return Err(JigsawsError::OutputExists { path: folder });
        }
    }
    let synth = generate(config)?;
    synth.dataset.write(out)?;
    for (id, kin) in &synth.kinematics_only {
        let folder = out.join(id.task.folder_name());
        write_file(&kinematics_path(&folder, *id), kin.to_text().as_bytes())?;
    }
    Ok(synth)
}

/// The seed of one trial's RNG.
pub fn trial_seed(seed: u64, id: TrialId) -> u64 {
    let task = Task::ALL.iter().position(|&t| t == id.task).unwrap_or(0) as u64;
    let key = (task << 40) | (u64::from(id.surgeon as u32) << 16) | u64::from(id.number);
    splitmix64(seed ^ splitmix64(key))
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Skill-dependent behaviour.
#[derive(Debug, Clone, Copy)]
struct SkillParams {
    retry: f64,
    slow: f64,
    tremor: f64,
    base_score: i32,
}

fn skill_params(skill: Skill) -> SkillParams {
    match skill {
        Skill::Expert => SkillParams {
            retry: 0.05,
            slow: 0.8,
            tremor: 0.6,
            base_score: 4,
        },
        Skill::Intermediate => SkillParams {
            retry: 0.12,
            slow: 1.0,
            tremor: 1.0,
            base_score: 3,
        },
        Skill::Novice => SkillParams {
            retry: 0.22,
            slow: 1.3,
            tremor: 1.6,
            base_score: 2,
        },
    }
}

/// A gesture sequence drawn from `task`'s grammar for a surgeon of `skill`,
/// with the throw (or loop) index of each step.
pub fn sample_gestures(task: Task, skill: Skill, rng: &mut impl Rng) -> Vec<(Gesture, usize)> {
    let p = skill_params(skill);
    let mut seq = Vec::new();
    match task {
        Task::Suturing | Task::NeedlePassing => {
            let np = task == Task::NeedlePassing;
            seq.push((Gesture::G1, 0));
            if rng.random_bool(0.85) {
                seq.push((Gesture::G5, 0));
            }
            let throws = match rng.random::<f64>() {
                x if x < 0.15 => 3,
                x if x < (if np { 0.9 } else { 0.8 }) => 4,
                _ => 5,
            };
            // Needle Passing re-orients after a failure; Suturing mostly
            // re-positions.
            let back_to_orient = if np { 0.75 } else { 0.35 };
            for k in 0..throws {
                let orient = if k == 0 { 0.7 } else { 0.4 } + if np { 0.1 } else { 0.0 };
                if rng.random_bool(orient) {
                    seq.push((Gesture::G8, k));
                }
                let mut attempts = 0;
                loop {
                    attempts += 1;
                    seq.push((Gesture::G2, k));
                    if attempts < 4 && rng.random_bool(p.retry) {
                        if rng.random_bool(back_to_orient) {
                            seq.push((Gesture::G8, k));
                        }
                        continue;
                    }
                    seq.push((Gesture::G3, k));
                    if attempts < 4 && rng.random_bool(p.retry * 0.7) {
                        if rng.random_bool(back_to_orient) {
                            seq.push((Gesture::G8, k));
                        }
                        continue;
                    }
                    break;
                }
                seq.push((Gesture::G6, k));
                if !np {
                    if rng.random_bool(0.3) {
                        seq.push((Gesture::G9, k));
                    }
                    if rng.random_bool(0.1 + p.retry * 0.3) {
                        seq.push((Gesture::G10, k));
                        seq.push((Gesture::G6, k));
                    }
                }
                let last = k + 1 == throws;
                if !last || rng.random_bool(0.3) {
                    seq.push((Gesture::G4, k));
                }
            }
            seq.push((Gesture::G11, throws));
        }
        Task::KnotTying => {
            if rng.random_bool(0.85) {
                seq.push((Gesture::G1, 0));
            }
            let loops = match rng.random::<f64>() {
                x if x < 0.1 => 1,
                x if x < 0.7 => 2,
                _ => 3,
            };
            for k in 0..loops {
                if k == 0 || rng.random_bool(0.9) {
                    seq.push((Gesture::G12, k));
                }
                let mut attempts = 0;
                loop {
                    attempts += 1;
                    seq.push((Gesture::G13, k));
                    if attempts < 4 && rng.random_bool(p.retry) {
                        continue;
                    }
                    seq.push((Gesture::G14, k));
                    if attempts < 4 && rng.random_bool(p.retry * 0.8) {
                        continue;
                    }
                    break;
                }
                seq.push((Gesture::G15, k));
            }
            seq.push((Gesture::G11, loops));
        }
    }
    seq
}

/// Base duration of a gesture in seconds.
fn base_duration(g: Gesture) -> f64 {
    match g.number() {
        1 => 1.6,
        2 => 2.2,
        3 => 2.8,
        4 => 2.0,
        5 => 1.8,
        6 => 2.6,
        7 => 2.0,
        8 => 2.0,
        9 => 1.8,
        10 => 1.5,
        11 => 2.2,
        12 => 1.6,
        13 => 2.6,
        14 => 1.6,
        _ => 2.4,
    }
}

/// A standard normal sample (Box–Muller).
fn normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

type V3 = [f64; 3];
type M3 = [[f64; 3]; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn lerp(a: V3, b: V3, s: f64) -> V3 {
    add(a, scale(sub(b, a), s))
}
fn normalise(a: V3) -> V3 {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if n < 1e-12 {
        [0.0, 0.0, 1.0]
    } else {
        scale(a, 1.0 / n)
    }
}
fn matmul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}
fn transpose(a: &M3) -> M3 {
    let mut t = [[0.0; 3]; 3];
    for (i, row) in a.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            t[j][i] = *v;
        }
    }
    t
}

/// Rotation by `angle` about the unit `axis` (Rodrigues).
fn exp_so3(axis: V3, angle: f64) -> M3 {
    let [x, y, z] = axis;
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]
}

/// The rotation vector of a rotation matrix (inverse of [`exp_so3`] for
/// angles below π).
fn log_so3(r: &M3) -> V3 {
    let cos = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
    let angle = cos.acos();
    let v = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]];
    if angle < 1e-9 {
        return scale(v, 0.5);
    }
    scale(v, angle / (2.0 * angle.sin()))
}

/// Smooth 0→1 step over `[0, 1]` (minimum jerk).
fn min_jerk(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
}

/// Where things are, in the patient-side frame (metres), jittered per trial.
struct Scene {
    needle: V3,
    center: V3,
    entries: Vec<V3>,
    left_pull: V3,
    right_pull: V3,
    end_left: V3,
    end_right: V3,
    knot: V3,
}

fn scene(task: Task, rng: &mut impl Rng) -> Scene {
    let mut jitter = |v: V3| {
        add(
            v,
            [
                normal(rng) * 0.003,
                normal(rng) * 0.003,
                normal(rng) * 0.002,
            ],
        )
    };
    let entries = (0..8)
        .map(|k| match task {
            Task::NeedlePassing => {
                let phi = (150.0 - 35.0 * k as f64).to_radians();
                [0.035 * phi.cos(), 0.015 + 0.02 * phi.sin(), 0.005]
            }
            _ => [-0.015 + 0.01 * k as f64, 0.0, -0.01],
        })
        .map(&mut jitter)
        .collect();
    Scene {
        needle: jitter([0.02, -0.03, 0.0]),
        center: jitter([0.0, 0.0, 0.01]),
        entries,
        left_pull: jitter([-0.06, 0.03, 0.03]),
        right_pull: jitter([0.06, 0.03, 0.03]),
        end_left: jitter([-0.07, 0.05, 0.04]),
        end_right: jitter([0.07, 0.05, 0.04]),
        knot: jitter([0.0, 0.0, -0.005]),
    }
}

/// What one arm does during a gesture.
#[derive(Default)]
struct ArmMotion {
    /// Where it ends up (`None`: stays).
    target: Option<V3>,
    /// Rotation applied over the gesture: (axis, angle).
    rotation: Option<(V3, f64)>,
    /// Gripper changes: (angle, fraction of the gesture where it happens).
    grip: Vec<(f64, f64)>,
    /// Radius of a loop traced on the way (G13).
    loop_radius: Option<f64>,
}

/// The two patient-side arms' motions for gesture `g` of throw `k`.
fn gesture_motion(g: Gesture, k: usize, sc: &Scene, right: V3) -> (ArmMotion, ArmMotion) {
    let entry = sc.entries[k.min(sc.entries.len() - 1)];
    let (o, c) = (GRIP_OPEN, GRIP_CLOSED);
    let mut l = ArmMotion::default();
    let mut r = ArmMotion::default();
    match g.number() {
        1 => {
            r.target = Some(add(sc.needle, [0.0, 0.0, 0.004]));
            r.rotation = Some(([0.0, 0.0, 1.0], 0.3));
            r.grip = vec![(o, 0.1), (c, 0.85)];
        }
        2 => {
            r.target = Some(add(entry, [0.0, -0.006, 0.006]));
            r.rotation = Some(([1.0, 0.0, 0.0], 0.35));
            r.grip = vec![(c, 0.0)];
        }
        3 => {
            r.target = Some(add(entry, [0.0, 0.008, -0.002]));
            r.rotation = Some(([0.0, 1.0, 0.0], 1.4));
            r.grip = vec![(c, 0.0)];
        }
        4 => {
            let meet = add(sc.center, [0.0, 0.005, 0.01]);
            l.target = Some(add(meet, [-0.006, 0.0, 0.0]));
            r.target = Some(add(meet, [0.006, 0.0, 0.0]));
            l.grip = vec![(c, 0.0), (o, 0.8)];
            r.grip = vec![(o, 0.05), (c, 0.55)];
            r.rotation = Some(([0.0, 0.0, 1.0], -0.4));
        }
        5 => {
            r.target = Some(sc.center);
            l.target = Some(add(sc.center, [-0.02, 0.0, 0.005]));
            r.grip = vec![(c, 0.0)];
            r.rotation = Some(([0.0, 0.0, 1.0], 0.2));
        }
        6 => {
            l.target = Some(sc.left_pull);
            l.grip = vec![(o, 0.0), (c, 0.15)];
            l.rotation = Some(([1.0, 0.0, 0.0], -0.5));
            r.target = Some(add(right, [0.01, -0.005, 0.005]));
            r.grip = vec![(o, 0.05)];
        }
        7 => {
            r.target = Some(sc.right_pull);
            r.grip = vec![(c, 0.1)];
        }
        8 => {
            l.target = Some(add(sc.center, [-0.008, 0.0, 0.008]));
            r.target = Some(add(sc.center, [0.008, 0.0, 0.008]));
            l.grip = vec![(c, 0.05)];
            r.grip = vec![(o, 0.2), (c, 0.7)];
            r.rotation = Some((normalise([0.3, 0.2, 0.93]), 0.9));
        }
        9 => {
            r.target = Some(lerp(right, sc.right_pull, 0.6));
            r.grip = vec![(c, 0.2)];
        }
        10 => {
            l.target = Some(lerp(sc.left_pull, sc.center, 0.5));
            l.grip = vec![(c, 0.0)];
        }
        11 => {
            l.target = Some(sc.end_left);
            r.target = Some(sc.end_right);
            l.grip = vec![(o, 0.1)];
            r.grip = vec![(o, 0.1)];
        }
        12 => {
            l.target = Some(add(sc.knot, [-0.015, -0.01, 0.0]));
            l.grip = vec![(o, 0.05), (c, 0.85)];
        }
        13 => {
            l.target = Some(add(right, [-0.01, 0.0, 0.005]));
            l.loop_radius = Some(0.012);
            l.rotation = Some(([0.0, 1.0, 0.0], 2.0));
            l.grip = vec![(c, 0.0)];
            r.grip = vec![(o, 0.1)];
        }
        14 => {
            r.target = Some(add(sc.knot, [0.015, -0.01, 0.0]));
            r.grip = vec![(o, 0.05), (c, 0.85)];
        }
        _ => {
            l.target = Some(sc.left_pull);
            r.target = Some(sc.right_pull);
            l.grip = vec![(c, 0.0)];
            r.grip = vec![(c, 0.0)];
        }
    }
    (l, r)
}

/// One patient-side arm's state.
#[derive(Clone, Copy)]
struct Pose {
    p: V3,
    r: M3,
    grip: f64,
}

/// Generates one trial: meta row, segments, kinematics.
fn generate_trial(
    seed: u64,
    id: TrialId,
    duration_scale: f64,
) -> (MetaRecord, Vec<Segment>, Kinematics) {
    let mut rng = ChaCha8Rng::seed_from_u64(trial_seed(seed, id));
    let skill = Skill::of_surgeon(id.surgeon).unwrap_or(Skill::Intermediate);
    let p = skill_params(skill);

    let mut grs = [0u8; 6];
    for g in &mut grs {
        let v = p.base_score + rng.random_range(-1..=1);
        *g = v.clamp(1, 5) as u8;
    }
    let meta = MetaRecord {
        trial: id,
        skill,
        grs_total: grs.iter().sum(),
        grs,
    };

    let plan = sample_gestures(id.task, skill, &mut rng);
    let sc = scene(id.task, &mut rng);
    let frames = |seconds: f64| ((seconds * FRAME_RATE * duration_scale).round() as usize).max(2);

    let base_r = exp_so3([1.0, 0.0, 0.0], -0.7);
    let mut arms = [
        Pose {
            p: [-0.04, 0.0, 0.02],
            r: matmul(&exp_so3([0.0, 0.0, 1.0], -0.35), &base_r),
            grip: GRIP_OPEN,
        },
        Pose {
            p: [0.04, 0.0, 0.02],
            r: matmul(&exp_so3([0.0, 0.0, 1.0], 0.35), &base_r),
            grip: GRIP_OPEN,
        },
    ];
    let mut track: [Vec<Pose>; 2] = [Vec::new(), Vec::new()];
    let idle = |track: &mut [Vec<Pose>; 2], arms: &[Pose; 2], n: usize| {
        for (t, a) in track.iter_mut().zip(arms) {
            t.extend(std::iter::repeat_n(*a, n));
        }
    };

    idle(&mut track, &arms, frames(rng.random_range(0.4..1.4)));
    let mut segments = Vec::with_capacity(plan.len());
    for (i, &(g, k)) in plan.iter().enumerate() {
        if i > 0 && rng.random_bool((0.15 * p.slow).min(1.0)) {
            let gap = ((rng.random_range(1..=8) as f64 * duration_scale).round() as usize).max(1);
            idle(&mut track, &arms, gap);
        }
        let seconds = (base_duration(g) * p.slow * (0.2 * normal(&mut rng)).exp()).clamp(1.0, 5.0);
        let d = frames(seconds);
        let (ml, mr) = gesture_motion(g, k, &sc, arms[1].p);
        let start_row = track[0].len();
        for (a, m) in [(0, ml), (1, mr)] {
            let start = arms[a];
            let target = m.target.map(|t| {
                add(
                    t,
                    [
                        normal(&mut rng) * 0.002 * p.tremor,
                        normal(&mut rng) * 0.002 * p.tremor,
                        normal(&mut rng) * 0.0015 * p.tremor,
                    ],
                )
            });
            let rotation = m
                .rotation
                .map(|(axis, angle)| (axis, angle * (1.0 + 0.1 * p.tremor * normal(&mut rng))));
            let mut pose = start;
            for f in 0..d {
                let tau = (f + 1) as f64 / d as f64;
                let s = min_jerk(tau);
                pose.p = match target {
                    Some(t) => lerp(start.p, t, s),
                    None => start.p,
                };
                if let Some(radius) = m.loop_radius {
                    let phase = std::f64::consts::TAU * s;
                    pose.p = add(
                        pose.p,
                        [radius * phase.sin(), 0.0, radius * (1.0 - phase.cos())],
                    );
                }
                if let Some((axis, angle)) = rotation {
                    pose.r = matmul(&exp_so3(axis, angle * s), &start.r);
                }
                let mut grip = start.grip;
                for &(value, at) in &m.grip {
                    let w = ((tau - at) / 0.12).clamp(0.0, 1.0);
                    grip += (value - grip) * w * w * (3.0 - 2.0 * w);
                }
                pose.grip = grip;
                track[a].push(pose);
            }
            arms[a] = pose;
        }
        segments.push(Segment {
            start_frame: start_row as u32 + 1,
            end_frame: (start_row + d) as u32,
            gesture: g,
        });
    }
    idle(&mut track, &arms, frames(rng.random_range(0.2..1.0)));

    // Tremor: two slow sinusoids per axis and arm, skill-scaled.
    let mut tremor = [[[(0.0f64, 0.0f64, 0.0f64); 2]; 3]; 2];
    for arm in &mut tremor {
        for axis in arm.iter_mut() {
            for wave in axis.iter_mut() {
                *wave = (
                    0.0004 * p.tremor * rng.random_range(0.5..1.0),
                    std::f64::consts::TAU * rng.random_range(0.3..2.5) / FRAME_RATE,
                    rng.random_range(0.0..std::f64::consts::TAU),
                );
            }
        }
    }
    let rows = track[0].len();
    for (a, t) in track.iter_mut().enumerate() {
        for (f, pose) in t.iter_mut().enumerate() {
            for (axis, waves) in tremor[a].iter().enumerate() {
                pose.p[axis] += waves
                    .iter()
                    .map(|(amp, w, phi)| amp * (w * f as f64 + phi).sin())
                    .sum::<f64>();
            }
        }
    }

    let mut data = vec![0f32; rows * KINEMATICS_COLUMNS];
    let offsets = [[-0.15, 0.0, 0.0], [0.15, 0.0, 0.0]];
    for (a, t) in track.iter().enumerate() {
        let master: Vec<Pose> = t
            .iter()
            .map(|pose| Pose {
                p: add(offsets[a], scale(pose.p, MASTER_SCALE)),
                ..*pose
            })
            .collect();
        let (patient_arm, master_arm) = if a == 0 {
            (Arm::PatientLeft, Arm::MasterLeft)
        } else {
            (Arm::PatientRight, Arm::MasterRight)
        };
        write_arm(&mut data, t, patient_arm);
        write_arm(&mut data, &master, master_arm);
    }
    let kin = Kinematics::from_flat(data).expect("rows × 76 values");
    (meta, segments, kin)
}

fn round6(x: f64) -> f32 {
    ((x * 1e6).round() / 1e6) as f32
}

/// Writes one arm's poses into the row-major data, with velocities as
/// forward differences of the written positions and of the rotations.
fn write_arm(data: &mut [f32], poses: &[Pose], arm: Arm) {
    let n = poses.len();
    let positions: Vec<[f32; 3]> = poses
        .iter()
        .map(|q| [round6(q.p[0]), round6(q.p[1]), round6(q.p[2])])
        .collect();
    for (f, pose) in poses.iter().enumerate() {
        let next = if f + 1 < n { f + 1 } else { f };
        let prev = if f + 1 < n { f } else { f.saturating_sub(1) };
        let lin = std::array::from_fn(|i| {
            round6((f64::from(positions[next][i]) - f64::from(positions[prev][i])) * FRAME_RATE)
        });
        let w = log_so3(&matmul(&poses[next].r, &transpose(&poses[prev].r)));
        let state = ArmState {
            position: positions[f],
            rotation: std::array::from_fn(|i| std::array::from_fn(|j| round6(pose.r[i][j]))),
            linear_velocity: lin,
            angular_velocity: std::array::from_fn(|i| round6(w[i] * FRAME_RATE)),
            gripper_angle: round6(pose.grip),
        };
        let start = f * KINEMATICS_COLUMNS + arm.offset();
        state.write_to(&mut data[start..start + ARM_COLUMNS]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn so3_log_inverts_exp() {
        let axis = normalise([0.3, -0.5, 0.8]);
        let w = log_so3(&exp_so3(axis, 0.7));
        for i in 0..3 {
            assert!((w[i] - axis[i] * 0.7).abs() < 1e-12);
        }
        assert_eq!(log_so3(&exp_so3(axis, 0.0)), [0.0; 3]);
    }

    #[test]
    fn grammars_use_exactly_the_task_gestures() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for task in Task::ALL {
            let mut seen = std::collections::BTreeSet::new();
            for i in 0..200 {
                let skill = [Skill::Novice, Skill::Intermediate, Skill::Expert][i % 3];
                let seq = sample_gestures(task, skill, &mut rng);
                assert_eq!(seq.last().unwrap().0, Gesture::G11, "{task}");
                seen.extend(seq.iter().map(|s| s.0));
            }
            assert_eq!(
                seen.into_iter().collect::<Vec<_>>(),
                task.gestures(),
                "{task}"
            );
        }
    }

    #[test]
    fn novices_retry_more_than_experts() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mean_len = |skill, rng: &mut ChaCha8Rng| {
            (0..300)
                .map(|_| sample_gestures(Task::Suturing, skill, rng).len())
                .sum::<usize>() as f64
                / 300.0
        };
        let novice = mean_len(Skill::Novice, &mut rng);
        let expert = mean_len(Skill::Expert, &mut rng);
        assert!(novice > expert + 1.0, "novice {novice}, expert {expert}");
    }
}
