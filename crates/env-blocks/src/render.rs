//! A deterministic ray-casting renderer for square RGB frames (64×64 by
//! default; [`Camera`] sets the side).
//!
//! The camera is fixed: it looks down at the table at 45° from
//! [`CAMERA_EYE`] with a narrow field of view (21.5°) and up vector
//! (1, 0, 0), like NTP's, so that the stacking order of every tower shows
//! (the side faces of its cubes) and a 5 cm cube spans about 5 pixels.
//! NTP's own camera (74° down from 0.55 m, 60° field of view) hides a
//! tower's lower cubes under its top one; on validation-task videos (stage
//! A, 3000 videos, 4 epochs) this camera raises held-out keyframe
//! localization from 0.659 to 0.892 (`docs/results/video-2026-11-24.md`).
//! That standard framing holds towers up to five cubes; the tall one
//! ([`Framing::Tall`]: the same eye, a wider view) holds the tallest tower
//! the world can build and the gripper above it.
//!
//! Every pixel's primary ray is fixed, so the table (a plane at z = 0) is
//! rendered once into a background. Per frame, each shape (cubes, bin pads,
//! gripper fingers and palm) is projected to its screen-space bounding box
//! and only the rays inside it are cast against the shape with parry3d's
//! `cast_ray_and_get_normal`, keeping the nearest hit per pixel. Shading is
//! Lambertian with one directional light plus ambient.

use std::sync::OnceLock;

use glam::Vec3;
use image::RgbImage;
use parry3d::math::Pose;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::Cuboid;

use crate::world::{BIN_HALF, BIN_THICKNESS, Bin, CUBE_HALF, WORKSPACE_HALF, World};

/// Frame width and height in pixels of the standard camera.
pub const FRAME_SIZE: u32 = 64;

/// The camera's image: its side in pixels and its framing (eye, target
/// and field of view). A framing holds the workspace edge to edge, so a
/// larger side shows the same scene with more pixels per cube: with the
/// standard framing a 5 cm cube spans about `size / 13` pixels (5 at 64,
/// 7.5 at 96, 10 at 128), with the tall one about `size / 15.7` (10 at
/// 160).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Camera {
    /// Frame width and height in pixels: a multiple of 8 from 8 to
    /// [`Camera::MAX_SIZE`].
    pub size: u32,
    /// What the frame holds (default: the standard framing, left out of
    /// serialised configurations so that theirs read as before).
    #[serde(skip_serializing_if = "Framing::is_standard")]
    pub framing: Framing,
}

/// What a camera's frame holds.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum Framing {
    /// Every reachable cube position with towers up to 0.25 m (five
    /// cubes), seen 45° down: [`CAMERA_EYE`], [`CAMERA_TARGET`],
    /// [`FIELD_OF_VIEW_DEG`]. A taller tower near the workspace's far
    /// edge leaves the frame (its top, and the gripper placing on it).
    #[default]
    Standard,
    /// Every reachable cube position (grid ±0.2 m, jitter ±3 cm, a cube's
    /// half) with anything up to 0.5 m above the table: the tallest tower
    /// the world can build (eight cubes, 0.4 m) and the gripper holding a
    /// cube above it. The same eye, looking 40° down at [`TALL_TARGET`]
    /// with a field of view of [`TALL_FIELD_OF_VIEW_DEG`].
    Tall,
}

impl Framing {
    /// Whether this is the standard framing.
    pub fn is_standard(&self) -> bool {
        *self == Framing::Standard
    }

    /// Its eye, target and vertical (and horizontal) field of view in
    /// degrees; the up vector is [`CAMERA_UP`] for both.
    pub fn view(self) -> (Vec3, Vec3, f32) {
        match self {
            Framing::Standard => (CAMERA_EYE, CAMERA_TARGET, FIELD_OF_VIEW_DEG),
            Framing::Tall => (CAMERA_EYE, TALL_TARGET, TALL_FIELD_OF_VIEW_DEG),
        }
    }
}

impl Default for Camera {
    /// The standard 64×64 camera.
    fn default() -> Self {
        Camera {
            size: FRAME_SIZE,
            framing: Framing::Standard,
        }
    }
}

impl Camera {
    /// The largest side accepted.
    pub const MAX_SIZE: u32 = 512;

    /// A camera of `size`×`size` pixels with the standard framing.
    pub const fn of_size(size: u32) -> Self {
        Camera {
            size,
            framing: Framing::Standard,
        }
    }

    /// This camera with `framing`.
    pub const fn with_framing(self, framing: Framing) -> Self {
        Camera { framing, ..self }
    }

    /// Values per frame row (RGB, CHW): `3·size²`.
    pub const fn frame_dim(&self) -> usize {
        3 * (self.size as usize) * (self.size as usize)
    }

    /// Checks the side: a multiple of 8 (the frame encoders halve it three
    /// times) from 8 to [`Camera::MAX_SIZE`].
    pub fn validate(&self) -> Result<(), String> {
        if self.size < 8 || self.size > Self::MAX_SIZE || !self.size.is_multiple_of(8) {
            return Err(format!(
                "camera size must be a multiple of 8 from 8 to {}, got {}",
                Self::MAX_SIZE,
                self.size
            ));
        }
        Ok(())
    }
}
/// Vertical (and horizontal) field of view in degrees.
pub const FIELD_OF_VIEW_DEG: f32 = 21.5;
/// The camera position: 1.5 m from the scene, looking down at 45°, so that
/// a cube's side faces show (5 cm of height is about 3.6 pixels anywhere on
/// the table) and the stacking order of a tower can be read off a frame.
/// Seen from NTP's steeper angle (74°), a tower near the camera hid every
/// cube under its top one. The frame holds every reachable cube position
/// (grid ±0.2 m, jitter ±3 cm) with towers up to 0.25 m.
pub const CAMERA_EYE: Vec3 = Vec3::new(0.0, -1.20066, 1.25066);
/// The point the camera looks at (centres the workspace and its towers in
/// the frame).
pub const CAMERA_TARGET: Vec3 = Vec3::new(0.0, -0.14, 0.19);
/// The camera's up vector, as in NTP.
pub const CAMERA_UP: Vec3 = Vec3::new(1.0, 0.0, 0.0);
/// The tall framing's target ([`Framing::Tall`]): from [`CAMERA_EYE`], 40.1°
/// down, at the standard target's distance. With
/// [`TALL_FIELD_OF_VIEW_DEG`] the frame holds the box |x|, |y| ≤ 0.255 m,
/// 0 ≤ z ≤ 0.5 m (25.63° would be just enough).
pub const TALL_TARGET: Vec3 = Vec3::new(0.0, -0.05314, 0.28463);
/// The tall framing's field of view in degrees.
pub const TALL_FIELD_OF_VIEW_DEG: f32 = 26.0;

/// Colours of cubes A–H in stacking (distinct, saturated).
pub const CUBE_COLOURS: [[f32; 3]; 8] = [
    [0.90, 0.10, 0.10], // A red
    [0.10, 0.75, 0.15], // B green
    [0.15, 0.25, 0.95], // C blue
    [0.95, 0.85, 0.10], // D yellow
    [0.90, 0.15, 0.85], // E magenta
    [0.10, 0.85, 0.90], // F cyan
    [1.00, 0.55, 0.05], // G orange
    [0.50, 0.20, 0.75], // H purple
];

/// Colours of the four sorting categories; the two objects of a category
/// differ in brightness.
pub const CATEGORY_COLOURS: [[f32; 3]; 4] = [
    [0.90, 0.10, 0.10],
    [0.10, 0.75, 0.15],
    [0.15, 0.25, 0.95],
    [0.95, 0.85, 0.10],
];

/// Colours of the four bin pads.
pub const BIN_COLOURS: [[f32; 3]; 4] = [
    [0.45, 0.30, 0.20],
    [0.20, 0.40, 0.40],
    [0.40, 0.40, 0.15],
    [0.35, 0.22, 0.40],
];

const TABLE_INSIDE: [f32; 3] = [0.82, 0.80, 0.74];
const TABLE_OUTSIDE: [f32; 3] = [0.62, 0.60, 0.56];
const GRIPPER_COLOUR: [f32; 3] = [0.22, 0.22, 0.25];
const AMBIENT: f32 = 0.35;

/// One box to draw: a centre, half extents and a colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrawBox {
    /// Centre (m).
    pub centre: Vec3,
    /// Half extents (m).
    pub half: Vec3,
    /// Linear RGB in [0, 1].
    pub colour: [f32; 3],
}

/// How the gripper's fingers are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fingers {
    /// Open wide (around a cube, without touching it).
    Open,
    /// Closed on a cube (touching its sides).
    OnCube,
    /// Closed on nothing.
    ClosedEmpty,
}

impl Fingers {
    /// The fingers of a world's gripper: open, or closed on the held cube,
    /// or closed empty.
    pub fn of(world: &World) -> Fingers {
        match (world.is_closed(), world.held()) {
            (false, _) => Fingers::Open,
            (true, Some(_)) => Fingers::OnCube,
            (true, None) => Fingers::ClosedEmpty,
        }
    }
}

/// The fixed camera with its precomputed rays and table background.
#[derive(Debug, Clone)]
pub struct Renderer {
    eye: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    tan_half: f32,
    size: usize,
    dirs: Vec<Vec3>,
    background: Vec<u8>,
    table_depth: Vec<f32>,
    light: Vec3,
}

fn shade(colour: [f32; 3], normal: Vec3, light: Vec3) -> [u8; 3] {
    let k = AMBIENT + (1.0 - AMBIENT) * normal.dot(light).max(0.0);
    let q = |c: f32| ((c * k).clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(colour[0]), q(colour[1]), q(colour[2])]
}

impl Renderer {
    /// The standard camera (shared, built once).
    pub fn standard() -> &'static Renderer {
        static RENDERER: OnceLock<Renderer> = OnceLock::new();
        RENDERER.get_or_init(|| Renderer::new(CAMERA_EYE, CAMERA_TARGET, CAMERA_UP))
    }

    /// The renderer of `camera`: its framing at its side (shared, each
    /// camera built once per process). An invalid camera (see
    /// [`Camera::validate`]) gets the standard renderer; environments and
    /// videos validate their camera before rendering.
    pub fn of(camera: Camera) -> &'static Renderer {
        if camera == Camera::default() || camera.validate().is_err() {
            return Self::standard();
        }
        static RENDERERS: OnceLock<std::sync::Mutex<Vec<(Camera, &'static Renderer)>>> =
            OnceLock::new();
        let mut built = RENDERERS
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, r)) = built.iter().find(|(c, _)| *c == camera) {
            return r;
        }
        // A few cameras per process at most: leaking each one keeps the
        // shared reference as cheap as the standard camera's.
        let (eye, target, fov) = camera.framing.view();
        let r: &'static Renderer = Box::leak(Box::new(Renderer::with_view(
            eye,
            target,
            CAMERA_UP,
            camera.size as usize,
            fov,
        )));
        built.push((camera, r));
        r
    }

    /// A camera at `eye` looking at `target` with the given up vector, the
    /// standard field of view ([`FIELD_OF_VIEW_DEG`]), 64×64 pixels.
    pub fn new(eye: Vec3, target: Vec3, up_hint: Vec3) -> Renderer {
        Self::with_size(eye, target, up_hint, FRAME_SIZE as usize)
    }

    /// [`Renderer::new`] with frames of `size`×`size` pixels.
    pub fn with_size(eye: Vec3, target: Vec3, up_hint: Vec3, size: usize) -> Renderer {
        Self::with_view(eye, target, up_hint, size, FIELD_OF_VIEW_DEG)
    }

    /// [`Renderer::with_size`] with a field of view of `fov_deg` degrees.
    pub fn with_view(
        eye: Vec3,
        target: Vec3,
        up_hint: Vec3,
        size: usize,
        fov_deg: f32,
    ) -> Renderer {
        let forward = (target - eye).normalize();
        let right = forward.cross(up_hint).normalize();
        let up = right.cross(forward);
        let tan_half = (fov_deg.to_radians() / 2.0).tan();
        let n = size.max(1);
        let light = Vec3::new(0.4, -0.6, 1.0).normalize();
        let mut dirs = Vec::with_capacity(n * n);
        let mut background = Vec::with_capacity(n * n * 3);
        let mut table_depth = Vec::with_capacity(n * n);
        for py in 0..n {
            for px in 0..n {
                let sx = (2.0 * (px as f32 + 0.5) / n as f32 - 1.0) * tan_half;
                let sy = (1.0 - 2.0 * (py as f32 + 0.5) / n as f32) * tan_half;
                let dir = (forward + right * sx + up * sy).normalize();
                dirs.push(dir);
                // The table: the plane z = 0, lighter over the workspace.
                if dir.z < 0.0 {
                    let t = -eye.z / dir.z;
                    let p = eye + dir * t;
                    let inside = p.x.abs() <= WORKSPACE_HALF + CUBE_HALF
                        && p.y.abs() <= WORKSPACE_HALF + CUBE_HALF;
                    let c = if inside { TABLE_INSIDE } else { TABLE_OUTSIDE };
                    background.extend_from_slice(&shade(c, Vec3::Z, light));
                    table_depth.push(t);
                } else {
                    background.extend_from_slice(&[0, 0, 0]);
                    table_depth.push(f32::INFINITY);
                }
            }
        }
        Renderer {
            eye,
            right,
            up,
            forward,
            tan_half,
            size: n,
            dirs,
            background,
            table_depth,
            light,
        }
    }

    /// Frame width and height in pixels.
    pub fn size(&self) -> u32 {
        self.size as u32
    }

    /// Where a world point lands in the frame, in pixel coordinates (x to
    /// the right, y down; pixel centres at +0.5), or `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32)> {
        let d = p - self.eye;
        let z = d.dot(self.forward);
        if z <= 1e-4 {
            return None;
        }
        let n = self.size as f32;
        let sx = d.dot(self.right) / (z * self.tan_half);
        let sy = d.dot(self.up) / (z * self.tan_half);
        Some(((sx + 1.0) * n / 2.0, (1.0 - sy) * n / 2.0))
    }

    /// The boxes making up a world: cubes (coloured by `colours`, one per
    /// cube), bin pads, and the gripper (two fingers and a palm, fingers
    /// open wide, closed on a cube, or closed empty).
    pub fn scene_boxes(world: &World, colours: &[[f32; 3]]) -> Vec<DrawBox> {
        Self::pose_boxes(
            world.objects(),
            world.bins(),
            world.gripper(),
            Fingers::of(world),
            colours,
        )
    }

    /// The boxes of a scene given piece by piece: cubes at `objects`
    /// (coloured by `colours`, one per cube), the `bins`' pads, and the
    /// gripper at `gripper` (its grasp point) with its `fingers`. For a
    /// world's own pieces this is [`Renderer::scene_boxes`]; videos use it
    /// for the poses between two worlds.
    pub fn pose_boxes(
        objects: &[Vec3],
        bins: &[Bin],
        gripper: Vec3,
        fingers: Fingers,
        colours: &[[f32; 3]],
    ) -> Vec<DrawBox> {
        let mut boxes = Vec::with_capacity(objects.len() + bins.len() + 3);
        for (b, bin) in bins.iter().enumerate() {
            boxes.push(DrawBox {
                centre: Vec3::new(bin.centre.x, bin.centre.y, BIN_THICKNESS / 2.0),
                half: Vec3::new(BIN_HALF, BIN_HALF, BIN_THICKNESS / 2.0),
                colour: BIN_COLOURS[b % BIN_COLOURS.len()],
            });
        }
        for (i, p) in objects.iter().enumerate() {
            boxes.push(DrawBox {
                centre: *p,
                half: Vec3::splat(CUBE_HALF),
                colour: colours.get(i).copied().unwrap_or([0.5, 0.5, 0.5]),
            });
        }
        let g = gripper;
        let finger_half = Vec3::new(0.008, 0.005, 0.022);
        let spread = match fingers {
            Fingers::Open => CUBE_HALF + 0.02,
            Fingers::OnCube => CUBE_HALF + finger_half.y,
            Fingers::ClosedEmpty => 0.01,
        };
        for side in [-1.0, 1.0] {
            boxes.push(DrawBox {
                centre: g + Vec3::new(0.0, side * spread, 0.005),
                half: finger_half,
                colour: GRIPPER_COLOUR,
            });
        }
        boxes.push(DrawBox {
            centre: g + Vec3::new(0.0, 0.0, 0.005 + finger_half.z + 0.004),
            half: Vec3::new(0.006, spread + finger_half.y, 0.004),
            colour: GRIPPER_COLOUR,
        });
        boxes
    }

    /// Renders the world with the given cube colours.
    pub fn render_world(&self, world: &World, colours: &[[f32; 3]]) -> RgbImage {
        self.render_boxes(&Self::scene_boxes(world, colours))
    }

    /// Renders boxes on the table.
    pub fn render_boxes(&self, boxes: &[DrawBox]) -> RgbImage {
        let n = self.size;
        let mut pixels = self.background.clone();
        let mut depth = self.table_depth.clone();
        for b in boxes {
            let (x0, x1, y0, y1) = self.screen_bounds(b);
            if x0 > x1 || y0 > y1 {
                continue;
            }
            let shape = Cuboid::new(b.half);
            let pose = Pose::from_translation(b.centre);
            for py in y0..=y1 {
                for px in x0..=x1 {
                    let k = py * n + px;
                    let ray = Ray::new(self.eye, self.dirs[k]);
                    if let Some(hit) = shape.cast_ray_and_get_normal(&pose, &ray, depth[k], true)
                        && hit.time_of_impact < depth[k]
                    {
                        depth[k] = hit.time_of_impact;
                        pixels[3 * k..3 * k + 3]
                            .copy_from_slice(&shade(b.colour, hit.normal, self.light));
                    }
                }
            }
        }
        let side = self.size();
        RgbImage::from_raw(side, side, pixels).unwrap_or_else(|| RgbImage::new(side, side))
    }

    /// Inclusive pixel bounds `(x0, x1, y0, y1)` covering the box's
    /// projection (the whole frame if a corner is behind the camera).
    fn screen_bounds(&self, b: &DrawBox) -> (usize, usize, usize, usize) {
        let last = self.size - 1;
        let mut lo = (f32::INFINITY, f32::INFINITY);
        let mut hi = (f32::NEG_INFINITY, f32::NEG_INFINITY);
        for corner in 0..8 {
            let s = Vec3::new(
                if corner & 1 == 0 { -1.0 } else { 1.0 },
                if corner & 2 == 0 { -1.0 } else { 1.0 },
                if corner & 4 == 0 { -1.0 } else { 1.0 },
            );
            let Some((x, y)) = self.project(b.centre + b.half * s) else {
                return (0, last, 0, last);
            };
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        let n = self.size as f32;
        if hi.0 < 0.0 || hi.1 < 0.0 || lo.0 > n || lo.1 > n {
            return (1, 0, 1, 0); // empty
        }
        // Pixel px covers [px, px + 1); its ray passes through px + 0.5.
        let clamp = |v: f32| (v.max(0.0) as usize).min(last);
        (
            clamp(lo.0 - 0.5),
            clamp(hi.0 + 0.5),
            clamp(lo.1 - 0.5),
            clamp(hi.1 + 0.5),
        )
    }
}
