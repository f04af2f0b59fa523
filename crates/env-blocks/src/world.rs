//! The kinematic world: cubes, bins, the gripper and the three primitives
//! (`move`, `grasp`, `drop`), with parry3d shape casts for landing.
//!
//! The physics is kinematic but honest about support:
//! - `move(t)` carries the gripper (and whatever it holds) above target `t`,
//!   clearing whatever is stacked there;
//! - `grasp` closes on the object the gripper was last moved to; it fails if
//!   something rests on that object, if the gripper already holds one, or
//!   (stochastically) when the grasp slips;
//! - `drop` releases the held cube, which falls straight down (optionally
//!   off-centre) onto the first thing under it (a parry3d shape cast against
//!   every other cube, every bin pad and the table). A cube whose centre is not
//!   above its supports topples off them and falls again from there.
//!
//! Cubes stay axis-aligned; stacks are not checked for the combined centre
//! of mass, only each cube against what it rests on.

use glam::{Vec2, Vec3};
use parry3d::math::Pose;
use parry3d::query::{ShapeCastOptions, cast_shapes};
use parry3d::shape::Cuboid;
use rand::Rng;

/// Edge length of a cube (m).
pub const CUBE_SIZE: f32 = 0.05;
/// Half the edge length of a cube (m).
pub const CUBE_HALF: f32 = CUBE_SIZE / 2.0;
/// Number of objects (cubes) in every scene.
pub const NUM_OBJECTS: usize = 8;
/// The workspace is x, y ∈ [-WORKSPACE_HALF, WORKSPACE_HALF] (m).
pub const WORKSPACE_HALF: f32 = 0.2;
/// Spacing of the start-position grid (m).
pub const GRID_SPACING: f32 = 0.1;
/// Maximal start-position jitter around a grid point, per axis (m).
pub const START_JITTER: f32 = 0.03;
/// Minimal gap between two cubes' footprints at the start (m).
pub const START_GAP: f32 = 0.005;
/// Gap between the bottom of a carried cube (or the fingertips) and the top
/// of whatever is under the gripper after a `move` (m).
pub const HOVER_GAP: f32 = 0.02;
/// Where the gripper waits at the start of an episode.
pub const GRIPPER_HOME: Vec3 = Vec3::new(0.0, 0.0, 0.15);
/// Half-extent of a sorting bin's square pad (m).
pub const BIN_HALF: f32 = 0.055;
/// Thickness of a bin pad (m).
pub const BIN_THICKNESS: f32 = 0.005;
/// Gap left between a toppled cube and the supports it slid off (m).
const TOPPLE_GAP: f32 = 0.002;
/// Lateral shrink of a falling cube, so that side-by-side faces at zero
/// distance do not count as a landing (m).
const CAST_SHRINK: f32 = 1e-3;
/// Tolerance for "resting at the same height" (m).
const LEVEL_EPS: f32 = 1e-4;
/// How many times a falling cube may topple off a support and fall again.
const MAX_TOPPLES: usize = 8;

/// A sorting bin: a thin square pad on the table with four slots.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bin {
    /// Centre of the pad's top face footprint (z is ignored; the pad lies on
    /// the table).
    pub centre: Vec2,
}

impl Bin {
    /// Top surface height of the pad.
    pub const fn top(&self) -> f32 {
        BIN_THICKNESS
    }

    /// Whether the point `p` (xy) lies over the pad (inclusive).
    pub fn contains(&self, p: Vec2) -> bool {
        (p - self.centre).abs().max_element() <= BIN_HALF
    }

    /// The four slot centres, in the order `move(bin)` fills them.
    pub fn slots(&self) -> [Vec2; 4] {
        let o = CUBE_HALF + 0.0025;
        [
            self.centre + Vec2::new(-o, -o),
            self.centre + Vec2::new(o, -o),
            self.centre + Vec2::new(-o, o),
            self.centre + Vec2::new(o, o),
        ]
    }
}

/// What a `move` goes to: an object (cube) or a bin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// Cube `i`.
    Object(usize),
    /// Bin `b` (sorting only).
    Bin(usize),
}

/// NTP's primitive actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Primitive {
    /// Move the gripper above a target.
    Move(Target),
    /// Close the gripper on the object it was moved to.
    Grasp,
    /// Open the gripper and let the held cube fall.
    Drop,
}

/// What a cube came to rest on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Support {
    /// The table.
    Table,
    /// Another cube (the highest one under its centre when it rests on two).
    Object(usize),
    /// A bin pad.
    Bin(usize),
}

/// Why a primitive (or a flat action) did not do what it was meant to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Failure {
    /// `move` to the cube the gripper is holding.
    MoveToHeld {
        /// The held cube.
        object: usize,
    },
    /// `grasp` with no object to grasp (no `move` yet, or moved to a bin).
    NothingToGrasp,
    /// `grasp` while already holding a cube.
    AlreadyHolding {
        /// The held cube.
        object: usize,
    },
    /// `grasp` of a cube that another cube rests on.
    Covered {
        /// The cube the grasp was meant for.
        object: usize,
        /// A cube resting on it.
        by: usize,
    },
    /// The grasp slipped (stochastic failure); the cube stays where it was.
    Slipped {
        /// The cube that slipped.
        object: usize,
    },
    /// `drop` with nothing held.
    NothingHeld,
    /// A `place` whose cube came to rest somewhere other than on its target
    /// (it toppled off, landed off-centre on a neighbour, or the target was
    /// covered).
    Missed {
        /// The dropped cube.
        object: usize,
        /// Where it was meant to go.
        intended: Target,
        /// Where it came to rest.
        landed_on: Support,
    },
}

impl std::fmt::Display for Failure {
    /// What went wrong, naming cubes by letter as the action names do:
    /// `the drop of C missed B: it landed on the table`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::env::target_name;
        use crate::task::cube_letter;
        match *self {
            Failure::MoveToHeld { object } => {
                write!(
                    f,
                    "move to {}, which the gripper holds",
                    cube_letter(object)
                )
            }
            Failure::NothingToGrasp => write!(f, "grasp with nothing under the gripper"),
            Failure::AlreadyHolding { object } => {
                write!(f, "grasp while holding {}", cube_letter(object))
            }
            Failure::Covered { object, by } => write!(
                f,
                "grasp of {}, which {} rests on",
                cube_letter(object),
                cube_letter(by)
            ),
            Failure::Slipped { object } => {
                write!(f, "the grasp of {} slipped", cube_letter(object))
            }
            Failure::NothingHeld => write!(f, "drop with nothing held"),
            Failure::Missed {
                object,
                intended,
                landed_on,
            } => {
                let landed = match landed_on {
                    Support::Table => "the table".to_owned(),
                    Support::Object(i) => cube_letter(i).to_string(),
                    Support::Bin(b) => format!("bin{}", b + 1),
                };
                write!(
                    f,
                    "the drop of {} missed {}: it landed on {landed}",
                    cube_letter(object),
                    target_name(intended)
                )
            }
        }
    }
}

/// The result of one primitive.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Outcome {
    /// The gripper moved above the target.
    Moved {
        /// Where it moved.
        to: Target,
    },
    /// The gripper holds the object.
    Grasped {
        /// The grasped cube.
        object: usize,
    },
    /// The held cube was released and came to rest.
    Dropped {
        /// The released cube.
        object: usize,
        /// What it rests on.
        landed_on: Support,
        /// Whether the release was perturbed off-centre (stochastic failure).
        off_centre: bool,
        /// Whether it toppled off at least one support on the way.
        toppled: bool,
    },
    /// The primitive failed; the world is as described by the failure.
    Failed(Failure),
}

impl Outcome {
    /// The failure, if the primitive failed.
    pub fn failure(&self) -> Option<Failure> {
        match self {
            Outcome::Failed(f) => Some(*f),
            _ => None,
        }
    }
}

/// Probabilities and magnitudes of the stochastic failures.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FailureConfig {
    /// Probability that a physically possible `grasp` slips.
    pub grasp_slip: f64,
    /// Probability that a `drop` is released off-centre.
    pub drop_off_centre: f64,
    /// Smallest off-centre displacement (m).
    pub off_centre_min: f32,
    /// Largest off-centre displacement (m); beyond half a cube the cube
    /// topples off its support.
    pub off_centre_max: f32,
}

impl FailureConfig {
    /// No stochastic failures: every possible action succeeds.
    pub const fn none() -> Self {
        FailureConfig {
            grasp_slip: 0.0,
            drop_off_centre: 0.0,
            off_centre_min: 0.01,
            off_centre_max: 0.045,
        }
    }

    /// The failures used in experiments: 10% of grasps slip, 10% of drops
    /// are released 1 to 4.5 cm off-centre (about half of those topple).
    pub const fn experiment() -> Self {
        FailureConfig {
            grasp_slip: 0.1,
            drop_off_centre: 0.1,
            ..Self::none()
        }
    }

    /// Whether the configuration is usable (probabilities in [0, 1],
    /// 0 ≤ min ≤ max displacement, all finite).
    pub fn validate(&self) -> Result<(), String> {
        for (name, p) in [
            ("grasp_slip", self.grasp_slip),
            ("drop_off_centre", self.drop_off_centre),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("{name} = {p} is not a probability in [0, 1]"));
            }
        }
        if !(self.off_centre_min.is_finite()
            && self.off_centre_max.is_finite()
            && 0.0 <= self.off_centre_min
            && self.off_centre_min <= self.off_centre_max)
        {
            return Err(format!(
                "off-centre displacement range [{}, {}] is invalid",
                self.off_centre_min, self.off_centre_max
            ));
        }
        Ok(())
    }
}

impl Default for FailureConfig {
    /// [`FailureConfig::experiment`]: failures are on by default.
    fn default() -> Self {
        Self::experiment()
    }
}

/// The state of the scene: cube centres, bins, gripper.
#[derive(Debug, Clone, PartialEq)]
pub struct World {
    objects: Vec<Vec3>,
    bins: Vec<Bin>,
    gripper: Vec3,
    held: Option<usize>,
    closed: bool,
    move_target: Option<Target>,
}

fn footprints_overlap(a: Vec2, b: Vec2, reach: f32) -> bool {
    let d = (a - b).abs();
    d.x < reach && d.y < reach
}

impl World {
    /// A world with cubes at the given centres (resting, not validated
    /// physically) and the given bins, the gripper open at its home.
    pub fn new(objects: Vec<Vec3>, bins: Vec<Bin>) -> Self {
        World {
            objects,
            bins,
            gripper: GRIPPER_HOME,
            held: None,
            closed: false,
            move_target: None,
        }
    }

    /// Eight cubes on random distinct cells of the start grid (restricted to
    /// `rows` of y grid values, all five x values), each jittered by up to
    /// ±3 cm with no two footprints closer than [`START_GAP`].
    pub fn random_start(rng: &mut impl Rng, grid_ys: &[f32], bins: Vec<Bin>) -> Self {
        let xs: Vec<f32> = (0..5)
            .map(|i| -WORKSPACE_HALF + GRID_SPACING * i as f32)
            .collect();
        let mut cells: Vec<Vec2> = grid_ys
            .iter()
            .flat_map(|&y| xs.iter().map(move |&x| Vec2::new(x, y)))
            .collect();
        // Partial Fisher-Yates: the first NUM_OBJECTS cells are a uniform sample.
        let n = NUM_OBJECTS.min(cells.len());
        for i in 0..n {
            let j = rng.random_range(i..cells.len());
            cells.swap(i, j);
        }
        let mut placed: Vec<Vec2> = Vec::with_capacity(n);
        for cell in &cells[..n] {
            // Rejection sampling of the jitter; a grid cell alone is always
            // valid (neighbours are 10 cm apart), so after enough tries fall
            // back to the cell centre only if every try collided. With 5 cm
            // cubes and ±3 cm jitter a try succeeds with probability > 1/4.
            let mut pos = *cell;
            for _ in 0..64 {
                let jitter = Vec2::new(
                    rng.random_range(-START_JITTER..=START_JITTER),
                    rng.random_range(-START_JITTER..=START_JITTER),
                );
                let candidate = *cell + jitter;
                if placed
                    .iter()
                    .all(|p| !footprints_overlap(*p, candidate, CUBE_SIZE + START_GAP))
                {
                    pos = candidate;
                    break;
                }
            }
            placed.push(pos);
        }
        let objects = placed
            .into_iter()
            .map(|p| Vec3::new(p.x, p.y, CUBE_HALF))
            .collect();
        World::new(objects, bins)
    }

    /// Cube centres.
    pub fn objects(&self) -> &[Vec3] {
        &self.objects
    }

    /// The bins (empty in stacking).
    pub fn bins(&self) -> &[Bin] {
        &self.bins
    }

    /// The gripper's grasp point (where a held cube's centre is).
    pub fn gripper(&self) -> Vec3 {
        self.gripper
    }

    /// The held cube, if any.
    pub fn held(&self) -> Option<usize> {
        self.held
    }

    /// Whether the gripper is closed (it is closed exactly while holding).
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// What the gripper was last moved to.
    pub fn move_target(&self) -> Option<Target> {
        self.move_target
    }

    /// Moves cube `i` to `centre` (for building scenes by hand). Out-of-range
    /// indices are ignored and reported as `false`.
    pub fn set_object(&mut self, i: usize, centre: Vec3) -> bool {
        match self.objects.get_mut(i) {
            Some(p) => {
                *p = centre;
                true
            }
            None => false,
        }
    }

    /// Whether `t` names an existing object or bin.
    pub fn has_target(&self, t: Target) -> bool {
        match t {
            Target::Object(i) => i < self.objects.len(),
            Target::Bin(b) => b < self.bins.len(),
        }
    }

    /// A cube resting on cube `i` (its footprint overlaps and it sits
    /// higher), the highest such if several. `None` if `i` is uncovered.
    pub fn covered_by(&self, i: usize) -> Option<usize> {
        let p = *self.objects.get(i)?;
        self.objects
            .iter()
            .enumerate()
            .filter(|&(j, q)| {
                j != i
                    && Some(j) != self.held
                    && q.z > p.z + LEVEL_EPS
                    && footprints_overlap(p.truncate(), q.truncate(), CUBE_SIZE - CAST_SHRINK)
            })
            .max_by(|a, b| a.1.z.total_cmp(&b.1.z))
            .map(|(j, _)| j)
    }

    /// Top height of everything (except the held cube) whose footprint
    /// overlaps a cube footprint centred at `xy`; 0 for bare table.
    pub fn column_top(&self, xy: Vec2) -> f32 {
        let mut top: f32 = 0.0;
        for (j, q) in self.objects.iter().enumerate() {
            if Some(j) != self.held && footprints_overlap(xy, q.truncate(), CUBE_SIZE) {
                top = top.max(q.z + CUBE_HALF);
            }
        }
        for bin in &self.bins {
            if footprints_overlap(xy, bin.centre, CUBE_HALF + BIN_HALF) {
                top = top.max(bin.top());
            }
        }
        top
    }

    /// Highest top of any resting cube or bin, 0 for an empty table.
    fn highest_top(&self) -> f32 {
        let mut top = self.bins.iter().map(|b| b.top()).fold(0.0, f32::max);
        for (j, q) in self.objects.iter().enumerate() {
            if Some(j) != self.held {
                top = top.max(q.z + CUBE_HALF);
            }
        }
        top
    }

    /// The xy point `move(t)` goes to: the cube's centre, or the least-filled
    /// slot of the bin (first in slot order on ties).
    fn move_point(&self, t: Target) -> Option<Vec2> {
        match t {
            Target::Object(i) => self.objects.get(i).map(|p| p.truncate()),
            Target::Bin(b) => {
                let bin = self.bins.get(b)?;
                // The first slot among the lowest columns. A cube resting
                // across slots can overlap all four, so that a cube dropped
                // at any of them lands on its overhang and topples off,
                // every time: then the lowest place, a slot or the centre of
                // a cube in the bin, where the held cube would rest without
                // toppling.
                let mut slots: Vec<(Vec2, f32)> = bin
                    .slots()
                    .into_iter()
                    .map(|slot| (slot, self.column_top(slot)))
                    .collect();
                let mut best: Option<(Vec2, f32)> = None;
                for &(slot, h) in &slots {
                    if best.is_none_or(|(_, bh)| h < bh - LEVEL_EPS) {
                        best = Some((slot, h));
                    }
                }
                let (first, _) = best?;
                let Some(held) = self.held else {
                    return Some(first);
                };
                if !self.fall(held, first).2 {
                    return Some(first);
                }
                // Then the cubes resting in the bin: a cube dropped centred
                // on one rests on it.
                let centre = bin.centre;
                slots.extend(
                    self.objects
                        .iter()
                        .enumerate()
                        .filter(|&(j, q)| {
                            j != held && footprints_overlap(q.truncate(), centre, BIN_HALF)
                        })
                        .map(|(_, q)| (q.truncate(), q.z + CUBE_HALF)),
                );
                slots.sort_by(|a, b| a.1.total_cmp(&b.1));
                Some(
                    slots
                        .into_iter()
                        .map(|(slot, _)| slot)
                        .find(|&slot| !self.fall(held, slot).2)
                        .unwrap_or(first),
                )
            }
        }
    }

    /// Applies one primitive. Unknown targets are the caller's to reject
    /// (see [`World::has_target`]); here they fail as
    /// [`Failure::NothingToGrasp`] would, without moving anything.
    pub fn apply(
        &mut self,
        primitive: Primitive,
        failures: &FailureConfig,
        rng: &mut impl Rng,
    ) -> Outcome {
        match primitive {
            Primitive::Move(t) => self.do_move(t),
            Primitive::Grasp => self.do_grasp(failures, rng),
            Primitive::Drop => self.do_drop(failures, rng),
        }
    }

    fn do_move(&mut self, t: Target) -> Outcome {
        if let (Target::Object(i), Some(h)) = (t, self.held)
            && i == h
        {
            return Outcome::Failed(Failure::MoveToHeld { object: h });
        }
        let Some(xy) = self.move_point(t) else {
            return Outcome::Failed(Failure::NothingToGrasp);
        };
        let z = self.column_top(xy) + CUBE_HALF + HOVER_GAP;
        self.gripper = Vec3::new(xy.x, xy.y, z);
        if let Some(h) = self.held {
            self.objects[h] = self.gripper;
        }
        self.move_target = Some(t);
        Outcome::Moved { to: t }
    }

    fn do_grasp(&mut self, failures: &FailureConfig, rng: &mut impl Rng) -> Outcome {
        if let Some(h) = self.held {
            return Outcome::Failed(Failure::AlreadyHolding { object: h });
        }
        let Some(Target::Object(i)) = self.move_target else {
            return Outcome::Failed(Failure::NothingToGrasp);
        };
        if i >= self.objects.len() {
            return Outcome::Failed(Failure::NothingToGrasp);
        }
        if let Some(by) = self.covered_by(i) {
            return Outcome::Failed(Failure::Covered { object: i, by });
        }
        if failures.grasp_slip > 0.0 && rng.random_bool(failures.grasp_slip) {
            return Outcome::Failed(Failure::Slipped { object: i });
        }
        // Descend, close, lift back to the hover height over the column that
        // remains once the cube is lifted.
        self.held = Some(i);
        self.closed = true;
        let xy = self.objects[i].truncate();
        let z = self.column_top(xy) + CUBE_HALF + HOVER_GAP;
        self.gripper = Vec3::new(xy.x, xy.y, z);
        self.objects[i] = self.gripper;
        Outcome::Grasped { object: i }
    }

    fn do_drop(&mut self, failures: &FailureConfig, rng: &mut impl Rng) -> Outcome {
        let Some(h) = self.held else {
            return Outcome::Failed(Failure::NothingHeld);
        };
        let mut xy = self.objects[h].truncate();
        let off_centre =
            failures.drop_off_centre > 0.0 && rng.random_bool(failures.drop_off_centre);
        if off_centre {
            let angle = rng.random_range(0.0..std::f32::consts::TAU);
            let radius = if failures.off_centre_max > failures.off_centre_min {
                rng.random_range(failures.off_centre_min..failures.off_centre_max)
            } else {
                failures.off_centre_min
            };
            xy += Vec2::new(angle.cos(), angle.sin()) * radius;
        }
        self.held = None;
        self.closed = false;
        let (centre, landed_on, toppled) = self.fall(h, xy);
        self.objects[h] = centre;
        Outcome::Dropped {
            object: h,
            landed_on,
            off_centre,
            toppled,
        }
    }

    /// Lets cube `h` fall from a height above everything at `xy`; returns its
    /// resting centre, its support and whether it toppled on the way.
    fn fall(&self, h: usize, mut xy: Vec2) -> (Vec3, Support, bool) {
        let start_z = self.highest_top() + CUBE_HALF + 0.01;
        let falling = Cuboid::new(Vec3::new(
            CUBE_HALF - CAST_SHRINK,
            CUBE_HALF - CAST_SHRINK,
            CUBE_HALF,
        ));
        let cube = Cuboid::new(Vec3::splat(CUBE_HALF));
        let pad = Cuboid::new(Vec3::new(BIN_HALF, BIN_HALF, BIN_THICKNESS / 2.0));
        let down = Vec3::new(0.0, 0.0, -1.0);
        let mut toppled = false;
        for attempt in 0..=MAX_TOPPLES {
            let start = Pose::from_translation(Vec3::new(xy.x, xy.y, start_z));
            // The table: the cube's bottom reaches z = 0. Each cube and pad
            // whose footprint overlaps the falling cube's is shape-cast
            // against; the cube rests on the highest top hit, snapped to
            // that top exactly (the cast's own tolerance is ~1e-4 m).
            let max_toi = start_z - CUBE_HALF;
            let options = ShapeCastOptions::with_max_time_of_impact(max_toi);
            let mut level: f32 = 0.0;
            for (j, q) in self.objects.iter().enumerate() {
                if j == h || !footprints_overlap(xy, q.truncate(), CUBE_SIZE - CAST_SHRINK) {
                    continue;
                }
                let pose = Pose::from_translation(*q);
                if let Ok(Some(_)) =
                    cast_shapes(&start, down, &falling, &pose, Vec3::ZERO, &cube, options)
                {
                    level = level.max(q.z + CUBE_HALF);
                }
            }
            for bin in &self.bins {
                if !footprints_overlap(xy, bin.centre, CUBE_HALF + BIN_HALF - CAST_SHRINK) {
                    continue;
                }
                let pose = Pose::from_translation(Vec3::new(
                    bin.centre.x,
                    bin.centre.y,
                    BIN_THICKNESS / 2.0,
                ));
                if let Ok(Some(_)) =
                    cast_shapes(&start, down, &falling, &pose, Vec3::ZERO, &pad, options)
                {
                    level = level.max(bin.top());
                }
            }
            let z = level + CUBE_HALF;
            let bottom = level;
            if bottom <= LEVEL_EPS {
                let xy = self.settle(h, xy, CUBE_HALF);
                return (Vec3::new(xy.x, xy.y, CUBE_HALF), Support::Table, toppled);
            }
            // Supports: everything whose top is at the cube's bottom under
            // its footprint. Their footprints' bounding box must contain the
            // cube's centre, else it topples off.
            let mut lo = Vec2::splat(f32::INFINITY);
            let mut hi = Vec2::splat(f32::NEG_INFINITY);
            let mut main: Option<(Support, f32)> = None;
            for (j, q) in self.objects.iter().enumerate() {
                if j != h
                    && (q.z + CUBE_HALF - bottom).abs() <= LEVEL_EPS
                    && footprints_overlap(xy, q.truncate(), CUBE_SIZE - CAST_SHRINK)
                {
                    lo = lo.min(q.truncate() - CUBE_HALF);
                    hi = hi.max(q.truncate() + CUBE_HALF);
                    let d = (q.truncate() - xy).length();
                    if main.is_none_or(|(_, md)| d < md) {
                        main = Some((Support::Object(j), d));
                    }
                }
            }
            for (b, bin) in self.bins.iter().enumerate() {
                if (bin.top() - bottom).abs() <= LEVEL_EPS
                    && footprints_overlap(xy, bin.centre, CUBE_HALF + BIN_HALF - CAST_SHRINK)
                {
                    lo = lo.min(bin.centre - BIN_HALF);
                    hi = hi.max(bin.centre + BIN_HALF);
                    let d = (bin.centre - xy).length();
                    if main.is_none_or(|(_, md)| d < md) {
                        main = Some((Support::Bin(b), d));
                    }
                }
            }
            let Some((support, _)) = main else {
                // Numerical corner: nothing found at that level; treat the
                // landing as resting where the cast stopped.
                return (Vec3::new(xy.x, xy.y, z), Support::Table, toppled);
            };
            let stable = xy.cmpge(lo).all() && xy.cmple(hi).all();
            if stable || attempt == MAX_TOPPLES {
                let xy = self.settle(h, xy, z);
                return (Vec3::new(xy.x, xy.y, z), support, toppled);
            }
            // Topple: slide off along the axis of the largest overhang until
            // the footprint clears the supports, then fall again.
            toppled = true;
            let over = Vec2::new(
                (xy.x - hi.x).max(lo.x - xy.x),
                (xy.y - hi.y).max(lo.y - xy.y),
            );
            if over.x >= over.y {
                xy.x = if xy.x > hi.x {
                    hi.x + CUBE_HALF + TOPPLE_GAP
                } else {
                    lo.x - CUBE_HALF - TOPPLE_GAP
                };
            } else {
                xy.y = if xy.y > hi.y {
                    hi.y + CUBE_HALF + TOPPLE_GAP
                } else {
                    lo.y - CUBE_HALF - TOPPLE_GAP
                };
            }
        }
        unreachable!("the loop returns on its last attempt")
    }

    /// A cube that fell past a neighbour within the cast's lateral
    /// tolerance (under 1 mm of overlap) is pushed out to touch it instead.
    fn settle(&self, h: usize, mut xy: Vec2, z: f32) -> Vec2 {
        for (j, q) in self.objects.iter().enumerate() {
            if j == h || Some(j) == self.held || (q.z - z).abs() >= CUBE_SIZE - LEVEL_EPS {
                continue;
            }
            let d = xy - q.truncate();
            if d.x.abs() < CUBE_SIZE && d.y.abs() < CUBE_SIZE {
                if d.x.abs() >= d.y.abs() {
                    xy.x = q.x + CUBE_SIZE.copysign(d.x);
                } else {
                    xy.y = q.y + CUBE_SIZE.copysign(d.y);
                }
            }
        }
        xy
    }

    /// The 26-number state: each cube's centre relative to the gripper
    /// (x, y, z per cube, in cube order), then the gripper one-hot
    /// `[open, closed]`.
    pub fn state(&self) -> [f32; crate::STATE_DIM] {
        let mut s = [0.0; crate::STATE_DIM];
        for (i, p) in self.objects.iter().take(NUM_OBJECTS).enumerate() {
            let r = *p - self.gripper;
            s[3 * i] = r.x;
            s[3 * i + 1] = r.y;
            s[3 * i + 2] = r.z;
        }
        s[3 * NUM_OBJECTS] = if self.closed { 0.0 } else { 1.0 };
        s[3 * NUM_OBJECTS + 1] = if self.closed { 1.0 } else { 0.0 };
        s
    }

    /// NTP's `on_top(src, target)`: the xy distance between the centres is
    /// at most one cube (5 cm) and `src` is above `target` (its centre higher
    /// by more than half a cube). A cube in the gripper is on top of nothing
    /// (NTP checks constraints on resting scenes; without this a cube carried
    /// over its target would count). Out-of-range ids are never on top.
    pub fn on_top(&self, src: usize, target: usize) -> bool {
        match (self.objects.get(src), self.objects.get(target)) {
            (Some(s), Some(t)) => {
                src != target
                    && self.held != Some(src)
                    && (s.truncate() - t.truncate()).length() <= CUBE_SIZE + 1e-6
                    && s.z > t.z + CUBE_HALF
            }
            _ => false,
        }
    }

    /// Whether cube `i` rests inside bin `b` (centre over the pad, not held).
    pub fn in_bin(&self, i: usize, b: usize) -> bool {
        match (self.objects.get(i), self.bins.get(b)) {
            (Some(p), Some(bin)) => self.held != Some(i) && bin.contains(p.truncate()),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failures_name_cubes_by_letter() {
        let missed = Failure::Missed {
            object: 2,
            intended: Target::Object(1),
            landed_on: Support::Table,
        };
        assert_eq!(
            missed.to_string(),
            "the drop of C missed B: it landed on the table"
        );
        assert_eq!(
            Failure::Covered { object: 0, by: 7 }.to_string(),
            "grasp of A, which H rests on"
        );
        assert_eq!(
            Failure::Slipped { object: 3 }.to_string(),
            "the grasp of D slipped"
        );
    }

    #[test]
    fn bin_slots_lie_inside_the_pad_without_overlap() {
        let bin = Bin {
            centre: Vec2::new(0.1, 0.2),
        };
        let slots = bin.slots();
        for (i, s) in slots.iter().enumerate() {
            assert!(bin.contains(*s));
            assert!((*s - bin.centre).abs().max_element() + CUBE_HALF <= BIN_HALF + 1e-6);
            for t in &slots[i + 1..] {
                assert!(!footprints_overlap(*s, *t, CUBE_SIZE));
            }
        }
        assert!(!bin.contains(Vec2::new(0.1 + BIN_HALF + 0.001, 0.2)));
    }

    #[test]
    fn move_to_a_bin_fills_the_lowest_slot() {
        let bin = Bin { centre: Vec2::ZERO };
        let s0 = bin.slots()[0];
        let mut w = World::new(
            vec![Vec3::new(s0.x, s0.y, BIN_THICKNESS + CUBE_HALF)],
            vec![bin],
        );
        let out = w.apply(
            Primitive::Move(Target::Bin(0)),
            &FailureConfig::none(),
            &mut <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0),
        );
        assert_eq!(out, Outcome::Moved { to: Target::Bin(0) });
        assert_eq!(w.gripper().truncate(), bin.slots()[1]);
    }

    #[test]
    fn state_is_relative_to_the_gripper() {
        let w = World::new(vec![Vec3::new(0.1, 0.0, CUBE_HALF)], Vec::new());
        let s = w.state();
        assert_eq!(s[0], 0.1 - GRIPPER_HOME.x);
        assert_eq!(s[2], CUBE_HALF - GRIPPER_HOME.z);
        assert_eq!(&s[24..], &[1.0, 0.0]);
    }
}
