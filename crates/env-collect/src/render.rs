//! The 64×64 software renderer: search-location surfaces, receptacles,
//! objects with per-instance size, tint and variant, the "hand" inset, and
//! contact sheets with a tiny bitmap font for captions.
//!
//! Every category has a shape-and-colour signature that survives its
//! variations (an outline one shade darker than its body keeps it visible on
//! every surface):
//!
//! | category | signature |
//! |---|---|
//! | Apple | red disc, brown stem, green leaf |
//! | Bread | brown loaf (flat bottom, domed top) with dark score marks |
//! | Egg | cream egg shape, narrower at the top |
//! | Lettuce | green disc of alternating light/dark rings |
//! | Mug | blue upright body with a ring handle (left or right) |
//! | Potato | tan wide ellipse with dark eyes |
//! | Knife | long silver blade with a black handle, at one of four angles |
//! | Bowl | yellow half-disc with a dark elliptic opening |
//!
//! The bottom-right 19×19 pixels of every frame are the hand inset: a white
//! frame around a dark square, showing the held object, if any.

use image::{Rgb, RgbImage};
use serde::{Deserialize, Serialize};

use crate::domain::{Category, Receptacle, Surface};
use crate::splitmix64;

/// Side of a rendered frame in pixels.
pub const FRAME_SIZE: u32 = 64;
/// First pixel (x and y) of the hand inset in the bottom-right corner.
pub const HAND_INSET_START: u32 = 45;
/// Size of an object drawn in the hand inset.
pub const HAND_OBJECT_SIZE: f32 = 13.0;
/// Size of an object drawn inside a receptacle.
pub const RECEPTACLE_OBJECT_SIZE: f32 = 11.0;

/// How one object instance looks: fixed for an episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Appearance {
    /// Nominal size in pixels on a search surface (about its width).
    pub size: f32,
    /// Per-channel multiplier of the category's base colour.
    pub tint: [f32; 3],
    /// Shape variant: knife angle (`variant % 4`), mug handle side
    /// (`variant % 2`), potato eye pattern.
    pub variant: u8,
}

/// How one place (search location, receptacle, start) looks in an episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Backdrop {
    /// Per-channel multiplier of the place's base colours.
    pub tint: [f32; 3],
    /// Offset of stripes, boards and checks.
    pub phase: u32,
    /// Seed of the texture and the sensor noise.
    pub salt: u64,
}

type Color = [f32; 3];

fn tinted(c: Color, t: [f32; 3]) -> Color {
    [c[0] * t[0], c[1] * t[1], c[2] * t[2]]
}

fn scaled(c: Color, k: f32) -> Color {
    [c[0] * k, c[1] * k, c[2] * k]
}

fn to_rgb(c: Color) -> Rgb<u8> {
    // `as u8` saturates on floats: clamping is implicit.
    Rgb([c[0] as u8, c[1] as u8, c[2] as u8])
}

/// Fills the ellipse centred at `(cx, cy)` with radii `(rx, ry)` (both
/// positive) with `color`.
fn fill_ellipse(img: &mut RgbImage, color: Color, (cx, cy): (f32, f32), (rx, ry): (f32, f32)) {
    let bbox = [cx - rx, cy - ry, cx + rx, cy + ry];
    fill(img, bbox, color, |x, y| in_ellipse(x, y, cx, cy, rx, ry));
}

/// Fills the axis-aligned rectangle `[x0, y0, x1, y1)` (pixel centres
/// inside it) with `color`.
fn fill_rect(img: &mut RgbImage, color: Color, [x0, y0, x1, y1]: [f32; 4]) {
    let inside = move |x: f32, y: f32| x >= x0 && x < x1 && y >= y0 && y < y1;
    fill(img, [0.0, 0.0, 64.0, 64.0], color, inside);
}

/// Fills every pixel whose centre is in `bbox` (x0, y0, x1, y1) and inside
/// the shape.
fn fill(img: &mut RgbImage, bbox: [f32; 4], color: Color, inside: impl Fn(f32, f32) -> bool) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let x0 = (bbox[0].floor() as i64).clamp(0, w);
    let y0 = (bbox[1].floor() as i64).clamp(0, h);
    let x1 = (bbox[2].ceil() as i64 + 1).clamp(0, w);
    let y1 = (bbox[3].ceil() as i64 + 1).clamp(0, h);
    let rgb = to_rgb(color);
    for y in y0..y1 {
        for x in x0..x1 {
            if inside(x as f32 + 0.5, y as f32 + 0.5) {
                img.put_pixel(x as u32, y as u32, rgb);
            }
        }
    }
}

/// A shape given by `inside(x, y, grow)`: `grow` widens it by that many
/// pixels (used for the outline).
fn outlined(
    img: &mut RgbImage,
    bbox: [f32; 4],
    color: Color,
    inside: impl Fn(f32, f32, f32) -> bool,
) {
    let grown = [bbox[0] - 1.5, bbox[1] - 1.5, bbox[2] + 1.5, bbox[3] + 1.5];
    fill(img, grown, scaled(color, 0.4), |x, y| inside(x, y, 1.1));
    fill(img, bbox, color, |x, y| inside(x, y, 0.0));
}

fn in_ellipse(x: f32, y: f32, cx: f32, cy: f32, rx: f32, ry: f32) -> bool {
    let (dx, dy) = ((x - cx) / rx.max(0.5), (y - cy) / ry.max(0.5));
    dx * dx + dy * dy <= 1.0
}

fn segment_distance(x: f32, y: f32, p0: (f32, f32), p1: (f32, f32)) -> f32 {
    let (vx, vy) = (p1.0 - p0.0, p1.1 - p0.1);
    let len2 = vx * vx + vy * vy;
    let t = if len2 > 0.0 {
        (((x - p0.0) * vx + (y - p0.1) * vy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (dx, dy) = (x - p0.0 - t * vx, y - p0.1 - t * vy);
    (dx * dx + dy * dy).sqrt()
}

fn capsule_bbox(p0: (f32, f32), p1: (f32, f32), r: f32) -> [f32; 4] {
    [
        p0.0.min(p1.0) - r,
        p0.1.min(p1.1) - r,
        p0.0.max(p1.0) + r,
        p0.1.max(p1.1) + r,
    ]
}

fn square_bbox(cx: f32, cy: f32, r: f32) -> [f32; 4] {
    [cx - r, cy - r, cx + r, cy + r]
}

/// Base colour of a category's body.
pub fn base_color(category: Category) -> [u8; 3] {
    let c = base(category);
    [c[0] as u8, c[1] as u8, c[2] as u8]
}

fn base(category: Category) -> Color {
    match category {
        Category::Apple => [205.0, 32.0, 36.0],
        Category::Bread => [196.0, 132.0, 62.0],
        Category::Egg => [246.0, 236.0, 206.0],
        Category::Lettuce => [84.0, 172.0, 56.0],
        Category::Mug => [44.0, 96.0, 210.0],
        Category::Potato => [172.0, 134.0, 84.0],
        Category::Knife => [206.0, 210.0, 220.0],
        Category::Bowl => [244.0, 204.0, 36.0],
    }
}

/// Draws one object centred at (`cx`, `cy`) with nominal size `size`.
pub fn draw_object(
    img: &mut RgbImage,
    category: Category,
    cx: f32,
    cy: f32,
    size: f32,
    look: &Appearance,
) {
    let s = size;
    let body = tinted(base(category), look.tint);
    match category {
        Category::Apple => {
            let (ay, r) = (cy + 0.06 * s, 0.42 * s);
            let stem0 = (cx, ay - 0.3 * s);
            let stem1 = (cx + 0.1 * s, cy - 0.5 * s);
            let sr = (0.06 * s).max(0.9);
            fill(
                img,
                capsule_bbox(stem0, stem1, sr + 1.0),
                [70.0, 40.0, 16.0],
                |x, y| segment_distance(x, y, stem0, stem1) <= sr,
            );
            outlined(img, square_bbox(cx, ay, r), body, |x, y, g| {
                in_ellipse(x, y, cx, ay, r + g, r + g)
            });
            let (lx, ly) = (cx + 0.22 * s, cy - 0.42 * s);
            let leaf = tinted([60.0, 156.0, 44.0], look.tint);
            outlined(img, square_bbox(lx, ly, 0.18 * s), leaf, |x, y, g| {
                in_ellipse(x, y, lx, ly, 0.18 * s + g, 0.08 * s + g)
            });
            let highlight = (cx - 0.16 * s, ay - 0.14 * s);
            fill_ellipse(img, scaled(body, 1.5), highlight, (0.09 * s, 0.09 * s));
        }
        Category::Bread => {
            let (hw, top, bottom, dome) = (0.5 * s, cy - 0.3 * s, cy + 0.28 * s, 0.3 * s);
            let mid = top + dome;
            outlined(img, [cx - hw, top, cx + hw, bottom], body, |x, y, g| {
                let in_rect = (x - cx).abs() <= hw + g && y >= mid && y <= bottom + g;
                in_rect || (y < mid && in_ellipse(x, y, cx, mid, hw + g, dome + g))
            });
            let crust = scaled(body, 0.55);
            for k in [-1.0f32, 0.0, 1.0] {
                let p0 = (cx + k * 0.28 * s - 0.08 * s, mid + 0.08 * s);
                let p1 = (cx + k * 0.28 * s + 0.08 * s, mid - 0.14 * s);
                fill(img, capsule_bbox(p0, p1, 1.0), crust, |x, y| {
                    segment_distance(x, y, p0, p1) <= 0.7
                });
            }
        }
        Category::Egg => {
            let rx = 0.34 * s;
            let (up, down) = (0.5 * s, 0.36 * s);
            let ey = cy + 0.05 * s;
            outlined(
                img,
                [cx - rx, ey - up, cx + rx, ey + down],
                body,
                |x, y, g| {
                    let ry = if y < ey { up } else { down };
                    in_ellipse(x, y, cx, ey, rx + g, ry + g)
                },
            );
            let highlight = (cx - 0.12 * s, ey - 0.18 * s);
            fill_ellipse(img, scaled(body, 1.2), highlight, (0.06 * s, 0.1 * s));
        }
        Category::Lettuce => {
            let r = 0.48 * s;
            let light = tinted([176.0, 222.0, 120.0], look.tint);
            let band = (0.13 * s).max(1.5);
            outlined(img, square_bbox(cx, cy, r), body, |x, y, g| {
                in_ellipse(x, y, cx, cy, r + g, r + g)
            });
            fill(img, square_bbox(cx, cy, r), light, |x, y| {
                let d = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
                d < r - 0.5 && (d / band) as u32 % 2 == 1
            });
        }
        Category::Mug => {
            let side = if look.variant.is_multiple_of(2) {
                1.0
            } else {
                -1.0
            };
            let (hx, hy, ro, ri) = (cx + side * 0.3 * s, cy, 0.22 * s, 0.11 * s);
            outlined(img, square_bbox(hx, hy, ro), body, |x, y, g| {
                let d = ((x - hx).powi(2) + (y - hy).powi(2)).sqrt();
                d <= ro + g && d >= ri - g
            });
            let (bx0, bx1) = (
                cx - 0.3 * s - side * 0.08 * s,
                cx + 0.3 * s - side * 0.08 * s,
            );
            let (by0, by1) = (cy - 0.38 * s, cy + 0.38 * s);
            outlined(img, [bx0, by0, bx1, by1], body, |x, y, g| {
                x >= bx0 - g && x <= bx1 + g && y >= by0 - g && y <= by1 + g
            });
            fill(
                img,
                [bx0, by0, bx1, by0 + 1.5],
                [235.0, 235.0, 240.0],
                |x, y| x >= bx0 && x <= bx1 && y >= by0 && y <= by0 + 1.5,
            );
        }
        Category::Potato => {
            let (rx, ry) = (0.5 * s, 0.3 * s);
            outlined(
                img,
                [cx - rx, cy - ry, cx + rx, cy + ry],
                body,
                |x, y, g| in_ellipse(x, y, cx, cy, rx + g, ry + g),
            );
            let eye = scaled(body, 0.45);
            let flip = if look.variant.is_multiple_of(2) {
                1.0
            } else {
                -1.0
            };
            for (ex, ey) in [(-0.25, -0.08), (0.05, 0.12), (0.28, -0.1)] {
                let (px, py) = (cx + ex * s, cy + flip * ey * s);
                fill(img, square_bbox(px, py, 1.5), eye, |x, y| {
                    in_ellipse(x, y, px, py, 0.9, 0.9)
                });
            }
        }
        Category::Knife => {
            let angle = [0.0f32, 0.5, -0.5, 1.2][usize::from(look.variant % 4)];
            let (dx, dy) = (angle.cos(), angle.sin());
            let tip = (cx - dx * 0.6 * s, cy - dy * 0.6 * s);
            let guard = (cx + dx * 0.18 * s, cy + dy * 0.18 * s);
            let end = (cx + dx * 0.62 * s, cy + dy * 0.62 * s);
            let br = (0.1 * s).max(1.3);
            let hr = (0.13 * s).max(1.6);
            outlined(img, capsule_bbox(tip, guard, br), body, |x, y, g| {
                segment_distance(x, y, tip, guard) <= br + g
            });
            outlined(
                img,
                capsule_bbox(guard, end, hr),
                [36.0, 30.0, 28.0],
                |x, y, g| segment_distance(x, y, guard, end) <= hr + g,
            );
        }
        Category::Bowl => {
            let (rx, ry, rim) = (0.5 * s, 0.42 * s, 0.13 * s);
            let top = cy - 0.12 * s;
            outlined(
                img,
                [cx - rx, top - rim, cx + rx, top + ry],
                body,
                |x, y, g| {
                    (y >= top && in_ellipse(x, y, cx, top, rx + g, ry + g))
                        || in_ellipse(x, y, cx, top, rx + g, rim + g)
                },
            );
            fill(
                img,
                [cx - rx, top - rim, cx + rx, top + rim],
                scaled(body, 0.55),
                |x, y| in_ellipse(x, y, cx, top, rx - 1.5, rim - 0.8),
            );
        }
    }
}

/// A well-mixed hash of a pixel: the SplitMix64 stream of `salt` at the
/// pixel's index (one mixing round per pixel).
fn pixel_hash(salt: u64, x: u32, y: u32) -> u64 {
    let index = u64::from(y) * 4096 + u64::from(x);
    splitmix64(salt.wrapping_add(index.wrapping_mul(0x9E37_79B9_7F4A_7C15)))
}

/// Fills the frame with a search location's surface.
pub fn draw_surface(img: &mut RgbImage, surface: Surface, backdrop: &Backdrop) {
    let t = backdrop.tint;
    let p = backdrop.phase;
    for (x, y, px) in img.enumerate_pixels_mut() {
        let c = match surface {
            Surface::CounterTop => {
                let base = [192.0, 192.0, 198.0];
                match pixel_hash(backdrop.salt, x, y) % 100 {
                    0..12 => scaled(base, 0.72),
                    12..18 => scaled(base, 1.12),
                    _ => base,
                }
            }
            Surface::TableTop => {
                let row = (y + p) % 13;
                let plank = (y + p) / 13;
                let base = [162.0, 110.0, 64.0];
                if row == 0 {
                    scaled(base, 0.55)
                } else {
                    let grain = 1.0 + 0.07 * (x as f32 * 0.35 + plank as f32 * 2.1).sin();
                    scaled(base, grain)
                }
            }
            Surface::Shelf => {
                if !(3..FRAME_SIZE - 3).contains(&x) || (y + p) % 21 < 2 {
                    [126.0, 92.0, 54.0]
                } else {
                    [228.0, 214.0, 178.0]
                }
            }
            Surface::DiningTable => {
                if ((x + p) / 8 + (y + p) / 8).is_multiple_of(2) {
                    [214.0, 198.0, 232.0]
                } else {
                    [246.0, 242.0, 250.0]
                }
            }
            Surface::Drawer => {
                if x < 5 || y < 5 || x >= FRAME_SIZE - 5 || y >= FRAME_SIZE - 5 {
                    [206.0, 172.0, 122.0]
                } else if x < 7 || y < 7 {
                    [40.0, 40.0, 44.0]
                } else {
                    [74.0, 74.0, 80.0]
                }
            }
        };
        *px = to_rgb(tinted(c, t));
    }
}

/// The area (x0, y0, x1, y1) of a receptacle frame where its contents are
/// drawn.
fn content_area(receptacle: Receptacle) -> [f32; 4] {
    match receptacle {
        Receptacle::Fridge => [13.0, 16.0, 51.0, 60.0],
        Receptacle::Sink => [8.0, 26.0, 56.0, 56.0],
        Receptacle::Cabinet => [10.0, 8.0, 54.0, 56.0],
        Receptacle::Microwave => [7.0, 15.0, 43.0, 49.0],
        Receptacle::GarbageCan => [12.0, 4.0, 52.0, 28.0],
    }
}

/// Fills the frame with a receptacle seen from in front of it.
pub fn draw_receptacle(img: &mut RgbImage, receptacle: Receptacle, backdrop: &Backdrop) {
    let t = backdrop.tint;
    let wall = tinted([214.0, 206.0, 190.0], t);
    let floor = tinted([150.0, 140.0, 125.0], t);
    for (_, y, px) in img.enumerate_pixels_mut() {
        *px = to_rgb(if y < 56 { wall } else { floor });
    }
    let all = [0.0, 0.0, 64.0, 64.0];
    match receptacle {
        Receptacle::Fridge => {
            fill_rect(
                img,
                tinted([150.0, 152.0, 158.0], t),
                [7.0, 0.0, 57.0, 64.0],
            );
            fill_rect(
                img,
                tinted([242.0, 244.0, 248.0], t),
                [8.0, 0.0, 56.0, 64.0],
            );
            fill_rect(
                img,
                tinted([160.0, 162.0, 168.0], t),
                [8.0, 12.0, 56.0, 13.0],
            );
            fill_rect(img, [60.0, 60.0, 66.0], [42.0, 5.0, 52.0, 7.0]);
            fill_rect(
                img,
                tinted([196.0, 222.0, 242.0], t),
                [12.0, 15.0, 52.0, 61.0],
            );
            for sy in [30.0, 45.0] {
                fill_rect(
                    img,
                    tinted([160.0, 184.0, 204.0], t),
                    [12.0, sy, 52.0, sy + 1.0],
                );
            }
        }
        Receptacle::Sink => {
            for (x, y, px) in img.enumerate_pixels_mut() {
                if y < 18 && (x % 8 == 0 || y % 8 == 0) {
                    *px = to_rgb(tinted([176.0, 170.0, 160.0], t));
                }
            }
            fill_rect(
                img,
                tinted([172.0, 178.0, 186.0], t),
                [0.0, 18.0, 64.0, 64.0],
            );
            fill(img, all, tinted([88.0, 95.0, 108.0], t), |x, y| {
                in_ellipse(x, y, 31.0, 40.0, 25.0, 15.0)
            });
            let silver = tinted([210.0, 214.0, 222.0], t);
            fill(img, all, silver, |x, y| {
                segment_distance(x, y, (31.0, 6.0), (31.0, 20.0)) <= 1.8
            });
            fill(img, all, silver, |x, y| {
                segment_distance(x, y, (31.0, 6.0), (39.0, 6.0)) <= 1.6
            });
        }
        Receptacle::Cabinet => {
            fill_rect(img, tinted([122.0, 78.0, 42.0], t), [4.0, 2.0, 60.0, 62.0]);
            fill_rect(img, tinted([62.0, 40.0, 24.0], t), [9.0, 7.0, 55.0, 57.0]);
            fill_rect(img, tinted([140.0, 92.0, 52.0], t), [9.0, 31.0, 55.0, 33.0]);
            let knob = tinted([214.0, 186.0, 90.0], t);
            for ky in [18.0, 44.0] {
                fill(img, all, knob, |x, y| in_ellipse(x, y, 6.5, ky, 1.6, 1.6));
            }
        }
        Receptacle::Microwave => {
            fill_rect(img, tinted([52.0, 52.0, 58.0], t), [2.0, 10.0, 62.0, 54.0]);
            fill_rect(img, [20.0, 20.0, 22.0], [5.0, 13.0, 45.0, 51.0]);
            fill_rect(
                img,
                tinted([238.0, 206.0, 118.0], t),
                [6.0, 14.0, 44.0, 50.0],
            );
            fill_rect(img, [80.0, 210.0, 120.0], [48.0, 14.0, 59.0, 19.0]);
            for by in [24.0, 30.0, 36.0] {
                for bx in [50.5, 56.5] {
                    fill(img, all, [150.0, 150.0, 156.0], |x, y| {
                        in_ellipse(x, y, bx, by, 1.5, 1.5)
                    });
                }
            }
        }
        Receptacle::GarbageCan => {
            let green = tinted([46.0, 112.0, 64.0], t);
            fill(img, all, scaled(green, 0.5), |x, y| {
                let half = 21.0 - (y - 16.0) * 0.12;
                (16.0..62.0).contains(&y) && (x - 32.0).abs() <= half + 1.0
            });
            fill(img, all, green, |x, y| {
                let half = 20.0 - (y - 16.0) * 0.12;
                (16.0..61.0).contains(&y) && (x - 32.0).abs() <= half
            });
            for lx in [22.0, 32.0, 42.0] {
                fill_rect(img, scaled(green, 0.7), [lx, 24.0, lx + 1.0, 56.0]);
            }
            fill(img, all, tinted([26.0, 44.0, 32.0], t), |x, y| {
                in_ellipse(x, y, 32.0, 16.0, 20.0, 5.0)
            });
        }
    }
}

/// Draws the receptacle's door (lid, cover) over its content area, `open`
/// in [0, 1]: closed at 0, swung towards its hinge on the left as it opens,
/// gone at 1 (the frame then equals the open receptacle).
pub fn draw_receptacle_door(
    img: &mut RgbImage,
    receptacle: Receptacle,
    backdrop: &Backdrop,
    open: f32,
) {
    let [x0, y0, x1, y1] = content_area(receptacle);
    let (x0, y0, x1, y1) = (x0 - 1.0, y0 - 1.0, x1 + 1.0, y1 + 1.0);
    let width = (1.0 - open.clamp(0.0, 1.0)) * (x1 - x0);
    if width < 0.5 {
        return;
    }
    let color = tinted(
        match receptacle {
            Receptacle::Fridge => [236.0, 238.0, 244.0],
            Receptacle::Sink => [150.0, 112.0, 70.0],
            Receptacle::Cabinet => [140.0, 92.0, 52.0],
            Receptacle::Microwave => [44.0, 46.0, 54.0],
            Receptacle::GarbageCan => [36.0, 84.0, 50.0],
        },
        backdrop.tint,
    );
    let right = x0 + width;
    fill_rect(img, scaled(color, 0.6), [x0, y0, right, y1]);
    fill_rect(img, color, [x0 + 1.0, y0 + 1.0, right - 1.0, y1 - 1.0]);
    if width > 5.0 {
        let (hx, hy) = (right - 3.0, (y0 + y1) / 2.0);
        fill_rect(
            img,
            scaled(color, 0.35),
            [hx - 1.0, hy - 3.0, hx + 1.0, hy + 3.0],
        );
    }
}

/// Draws the agent's arm reaching from `from` (usually below the frame) to
/// `to`, where its hand is.
pub fn draw_arm(img: &mut RgbImage, from: (f32, f32), to: (f32, f32)) {
    let skin = [226.0, 176.0, 140.0];
    let r = 2.6;
    outlined(img, capsule_bbox(from, to, r), skin, |x, y, g| {
        segment_distance(x, y, from, to) <= r + g
    });
    let hand = 3.4;
    outlined(img, square_bbox(to.0, to.1, hand), skin, |x, y, g| {
        in_ellipse(x, y, to.0, to.1, hand + g, hand + g)
    });
}

/// Where the `i`-th object in a receptacle is drawn (centre), laid out in
/// rows across the receptacle's content area, skipping the hand inset;
/// past the last free cell the layout starts over (objects overlap).
pub fn receptacle_slot(receptacle: Receptacle, i: usize) -> (f32, f32) {
    let [x0, y0, x1, y1] = content_area(receptacle);
    let cell = RECEPTACLE_OBJECT_SIZE + 1.0;
    let cols = (((x1 - x0) / cell) as usize).max(1);
    let rows = (((y1 - y0) / cell) as usize).max(1);
    let inset = HAND_INSET_START as f32 - 1.0;
    let free: Vec<(f32, f32)> = (0..rows * cols)
        .map(|k| {
            let (r, c) = (k / cols, k % cols);
            (
                x0 + cell * (c as f32 + 0.5),
                y1 - cell * (r as f32 + 0.5), // bottom row first
            )
        })
        .filter(|&(x, y)| !(x + cell / 2.0 > inset && y + cell / 2.0 > inset))
        .collect();
    if free.is_empty() {
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    }
    free[i % free.len()]
}

/// Fills the frame with the start view: a corridor wall with a door.
pub fn draw_start(img: &mut RgbImage, backdrop: &Backdrop) {
    let t = backdrop.tint;
    for (x, y, px) in img.enumerate_pixels_mut() {
        let c = if y >= 40 {
            [96.0, 84.0, 70.0]
        } else if (24..40).contains(&x) && y >= 10 {
            if x == 37 && y == 26 {
                [220.0, 200.0, 90.0]
            } else {
                [70.0, 56.0, 48.0]
            }
        } else {
            [122.0, 130.0, 142.0]
        };
        *px = to_rgb(tinted(c, t));
    }
}

/// Draws the hand inset: a white frame around a dark square, with the held
/// object (if any) in it.
pub fn draw_hand(img: &mut RgbImage, held: Option<(Category, &Appearance)>) {
    let s = HAND_INSET_START;
    for y in s..FRAME_SIZE {
        for x in s..FRAME_SIZE {
            let border = x == s || y == s || x == FRAME_SIZE - 1 || y == FRAME_SIZE - 1;
            let c = if border {
                [250, 250, 250]
            } else {
                [26, 26, 30]
            };
            img.put_pixel(x, y, Rgb(c));
        }
    }
    if let Some((category, look)) = held {
        let c = (s as f32 + FRAME_SIZE as f32) / 2.0;
        draw_object(img, category, c, c, HAND_OBJECT_SIZE, look);
    }
}

/// Adds per-pixel sensor noise in [-6, 6] per channel, fixed by `salt`.
pub fn add_noise(img: &mut RgbImage, salt: u64) {
    for (x, y, px) in img.enumerate_pixels_mut() {
        let h = pixel_hash(salt ^ 0x9E37_79B9_7F4A_7C15, x, y);
        for (k, v) in px.0.iter_mut().enumerate() {
            let n = ((h >> (16 * k)) % 13) as i16 - 6;
            *v = (i16::from(*v) + n).clamp(0, 255) as u8;
        }
    }
}

/// 3×5 glyphs, row-major from the top, bit 14 = top-left.
fn glyph(c: char) -> u16 {
    match c.to_ascii_uppercase() {
        'A' => 0b010_101_111_101_101,
        'B' => 0b110_101_110_101_110,
        'C' => 0b011_100_100_100_011,
        'D' => 0b110_101_101_101_110,
        'E' => 0b111_100_110_100_111,
        'F' => 0b111_100_110_100_100,
        'G' => 0b011_100_101_101_011,
        'H' => 0b101_101_111_101_101,
        'I' => 0b111_010_010_010_111,
        'J' => 0b001_001_001_101_010,
        'K' => 0b101_101_110_101_101,
        'L' => 0b100_100_100_100_111,
        'M' => 0b101_111_111_101_101,
        'N' => 0b110_101_101_101_101,
        'O' => 0b010_101_101_101_010,
        'P' => 0b110_101_110_100_100,
        'Q' => 0b010_101_101_110_011,
        'R' => 0b110_101_110_101_101,
        'S' => 0b011_100_010_001_110,
        'T' => 0b111_010_010_010_010,
        'U' => 0b101_101_101_101_111,
        'V' => 0b101_101_101_101_010,
        'W' => 0b101_101_111_111_101,
        'X' => 0b101_101_010_101_101,
        'Y' => 0b101_101_010_010_010,
        'Z' => 0b111_001_010_100_111,
        '0' => 0b111_101_101_101_111,
        '1' => 0b010_110_010_010_111,
        '2' => 0b110_001_010_100_111,
        '3' => 0b110_001_010_001_110,
        '4' => 0b101_101_111_001_001,
        '5' => 0b111_100_110_001_110,
        '6' => 0b011_100_111_101_111,
        '7' => 0b111_001_010_010_010,
        '8' => 0b111_101_111_101_111,
        '9' => 0b111_101_111_001_110,
        '(' => 0b001_010_010_010_001,
        ')' => 0b100_010_010_010_100,
        '<' => 0b001_010_100_010_001,
        '>' => 0b100_010_001_010_100,
        '-' => 0b000_000_111_000_000,
        '_' => 0b000_000_000_000_111,
        ':' => 0b000_010_000_010_000,
        '.' => 0b000_000_000_000_010,
        '!' => 0b010_010_010_000_010,
        '/' => 0b001_001_010_100_100,
        ' ' => 0,
        _ => 0b111_111_111_111_111,
    }
}

/// Draws `text` with the built-in 3×5 font (upper case), `scale` pixels per
/// font pixel (clamped to 1..=16), top-left at (`x`, `y`); clipped at the
/// image border.
pub fn draw_text(img: &mut RgbImage, text: &str, x: u32, y: u32, scale: u32, color: [u8; 3]) {
    let scale = scale.clamp(1, 16);
    for (i, ch) in text.chars().enumerate() {
        let bits = glyph(ch);
        let gx = x as u64 + i as u64 * 4 * u64::from(scale);
        for row in 0..5u32 {
            for col in 0..3u32 {
                if bits >> (14 - (row * 3 + col)) & 1 == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let px = gx + u64::from(col * scale + dx);
                        let py = u64::from(y) + u64::from(row * scale + dy);
                        if px < u64::from(img.width()) && py < u64::from(img.height()) {
                            img.put_pixel(px as u32, py as u32, Rgb(color));
                        }
                    }
                }
            }
        }
    }
}

/// A grid of frames, each magnified `scale` times (nearest neighbour) with
/// its caption (may be empty) under it, `columns` per row, on a dark
/// background. Frames may have any size; cells take the largest. `scale` is
/// clamped to 1..=8; meant for frame-sized images (a sheet larger than
/// `u32` pixels a side cannot be built).
pub fn contact_sheet(frames: &[(&RgbImage, String)], columns: usize, scale: u32) -> RgbImage {
    let columns = columns.max(1);
    let scale = scale.clamp(1, 8);
    let fw = frames.iter().map(|(f, _)| f.width()).max().unwrap_or(0) * scale;
    let fh = frames.iter().map(|(f, _)| f.height()).max().unwrap_or(0) * scale;
    let (gap, caption) = (4u32, 9u32);
    let rows = frames.len().div_ceil(columns) as u32;
    let cols = columns.min(frames.len().max(1)) as u32;
    let width = gap + cols * (fw + gap);
    let height = gap + rows * (fh + caption + gap);
    let mut sheet = RgbImage::from_pixel(width, height, Rgb([24, 24, 28]));
    for (i, (frame, text)) in frames.iter().enumerate() {
        let (c, r) = ((i % columns) as u32, (i / columns) as u32);
        let (x0, y0) = (gap + c * (fw + gap), gap + r * (fh + caption + gap));
        for (x, y, px) in frame.enumerate_pixels() {
            for dy in 0..scale {
                for dx in 0..scale {
                    sheet.put_pixel(x0 + x * scale + dx, y0 + y * scale + dy, *px);
                }
            }
        }
        draw_text(&mut sheet, text, x0, y0 + fh + 2, 1, [230, 230, 230]);
    }
    sheet
}

/// Every category at three sizes and tints on each surface kind, one
/// category per row: a visual check of the category signatures.
pub fn category_gallery(seed: u64) -> RgbImage {
    let mut frames = Vec::new();
    let mut h = splitmix64(seed);
    let mut next = || {
        h = splitmix64(h);
        (h >> 40) as f32 / (1u64 << 24) as f32
    };
    for category in Category::ALL {
        for (k, surface) in Surface::ALL.into_iter().enumerate() {
            let mut img = RgbImage::new(FRAME_SIZE, FRAME_SIZE);
            let backdrop = Backdrop {
                tint: [0.9 + 0.2 * next(), 0.9 + 0.2 * next(), 0.9 + 0.2 * next()],
                phase: (next() * 13.0) as u32,
                salt: k as u64,
            };
            draw_surface(&mut img, surface, &backdrop);
            for (j, (x, y)) in [(14.0, 14.0), (40.0, 18.0), (20.0, 42.0)]
                .into_iter()
                .enumerate()
            {
                let look = Appearance {
                    size: 12.0 + 3.0 * j as f32,
                    tint: [0.8 + 0.4 * next(), 0.8 + 0.4 * next(), 0.8 + 0.4 * next()],
                    variant: (next() * 4.0) as u8,
                };
                draw_object(&mut img, category, x, y, look.size, &look);
            }
            draw_hand(&mut img, None);
            frames.push((
                img,
                if k == 0 {
                    category.name().to_owned()
                } else {
                    String::new()
                },
            ));
        }
    }
    let refs: Vec<(&RgbImage, String)> = frames.iter().map(|(f, s)| (f, s.clone())).collect();
    contact_sheet(&refs, Surface::ALL.len(), 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn look() -> Appearance {
        Appearance {
            size: 15.0,
            tint: [1.0; 3],
            variant: 0,
        }
    }

    #[test]
    fn every_category_draws_inside_its_box_and_changes_pixels() {
        for category in Category::ALL {
            let mut img = RgbImage::from_pixel(64, 64, Rgb([0, 0, 0]));
            draw_object(&mut img, category, 32.0, 32.0, 15.0, &look());
            let painted: Vec<(u32, u32)> = img
                .enumerate_pixels()
                .filter(|(_, _, p)| p.0 != [0, 0, 0])
                .map(|(x, y, _)| (x, y))
                .collect();
            assert!(painted.len() > 40, "{category}: {} pixels", painted.len());
            for (x, y) in painted {
                assert!(
                    x.abs_diff(32) <= 12 && y.abs_diff(32) <= 12,
                    "{category} at {x},{y}"
                );
            }
        }
    }

    #[test]
    fn categories_have_distinct_mean_colours() {
        let mean = |c: Category| {
            let mut img = RgbImage::from_pixel(64, 64, Rgb([0, 0, 0]));
            draw_object(&mut img, c, 32.0, 32.0, 16.0, &look());
            let mut sum = [0f32; 3];
            let mut n = 0.0;
            for p in img.pixels().filter(|p| p.0 != [0, 0, 0]) {
                for (acc, &v) in sum.iter_mut().zip(&p.0) {
                    *acc += f32::from(v);
                }
                n += 1.0;
            }
            sum.map(|s| s / n)
        };
        let means: Vec<[f32; 3]> = Category::ALL.into_iter().map(mean).collect();
        for i in 0..means.len() {
            for j in i + 1..means.len() {
                let d: f32 = (0..3).map(|k| (means[i][k] - means[j][k]).powi(2)).sum();
                assert!(
                    d.sqrt() > 20.0,
                    "{:?} vs {:?}",
                    Category::ALL[i],
                    Category::ALL[j]
                );
            }
        }
    }

    #[test]
    fn receptacle_slots_avoid_the_hand_and_stay_in_frame() {
        for r in Receptacle::ALL {
            for i in 0..10 {
                let (x, y) = receptacle_slot(r, i);
                let h = RECEPTACLE_OBJECT_SIZE / 2.0;
                assert!(x - h >= 0.0 && y - h >= 0.0 && x + h <= 64.0 && y + h <= 64.0);
                assert!(!(x + h > 44.0 && y + h > 44.0), "{r} slot {i} at {x},{y}");
            }
            assert_ne!(receptacle_slot(r, 0), receptacle_slot(r, 1));
        }
    }

    #[test]
    fn text_and_sheets_have_the_expected_size() {
        let frame = RgbImage::new(64, 64);
        let sheet = contact_sheet(
            &[
                (&frame, "SEARCH".into()),
                (&frame, "PICKUP(EGG)".into()),
                (&frame, String::new()),
            ],
            2,
            2,
        );
        assert_eq!(sheet.width(), 4 + 2 * (128 + 4));
        assert_eq!(sheet.height(), 4 + 2 * (128 + 9 + 4));
        let mut img = RgbImage::new(10, 10);
        draw_text(&mut img, "a very long caption", 0, 0, 1, [255, 255, 255]);
        assert!(img.pixels().any(|p| p.0 == [255, 255, 255]));
        assert_eq!(contact_sheet(&[], 3, 2).dimensions(), (8, 4));
        // Extreme positions and scales clip instead of overflowing.
        draw_text(&mut img, "x", u32::MAX, u32::MAX, u32::MAX, [1, 2, 3]);
        let big = contact_sheet(&[(&frame, "X".into())], 1, u32::MAX);
        assert_eq!(big.width(), 4 + 64 * 8 + 4);
    }
}
