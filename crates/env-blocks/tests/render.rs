//! The renderer: framing, determinism, visibility.

use ctg_graph::Environment;
use env_blocks::render::{CUBE_COLOURS, Renderer};
use env_blocks::world::{CUBE_HALF, World};
use env_blocks::{BlocksEnv, EnvConfig, standard_tasks};
use glam::Vec3;
use image::RgbImage;

#[test]
fn workspace_fills_the_frame_and_a_cube_spans_about_six_pixels() {
    let r = Renderer::standard();
    // Every reachable cube corner (grid ±0.2, jitter ±0.03, half a cube,
    // towers up to 4 cubes near the middle) projects inside the frame.
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for z in [0.0, 0.05] {
                let (x, y) = r.project(Vec3::new(sx * 0.255, sy * 0.255, z)).unwrap();
                assert!(
                    (0.0..=64.0).contains(&x) && (0.0..=64.0).contains(&y),
                    "({x}, {y})"
                );
            }
        }
    }
    // The workspace (cube centres ±0.2 m plus half a cube) spans most of
    // the frame: over 2/3 of it in both directions through the centre.
    let (a, _) = r.project(Vec3::new(0.0, -0.225, 0.0)).unwrap();
    let (b, _) = r.project(Vec3::new(0.0, 0.225, 0.0)).unwrap();
    assert!((a - b).abs() > 42.0, "{a} {b}");
    let (_, c) = r.project(Vec3::new(-0.225, 0.0, 0.0)).unwrap();
    let (_, d) = r.project(Vec3::new(0.225, 0.0, 0.0)).unwrap();
    assert!((c - d).abs() > 42.0, "{c} {d}");
    // A cube's top face at the centre spans 5 to 7 pixels.
    let (x0, _) = r.project(Vec3::new(0.0, -CUBE_HALF, 0.05)).unwrap();
    let (x1, _) = r.project(Vec3::new(0.0, CUBE_HALF, 0.05)).unwrap();
    let span = (x0 - x1).abs();
    assert!((5.0..=7.0).contains(&span), "{span}");
}

fn count_colour(img: &RgbImage, colour: [f32; 3]) -> usize {
    // Pixels whose hue matches the cube colour (shading scales all channels).
    img.pixels()
        .filter(|p| {
            let c = [p[0] as f32, p[1] as f32, p[2] as f32];
            let m = c.iter().cloned().fold(0.0, f32::max);
            m > 20.0
                && (0..3).all(|k| {
                    (c[k] / m - colour[k] / colour.iter().cloned().fold(0.0, f32::max)).abs() < 0.08
                })
        })
        .count()
}

#[test]
fn every_cube_and_the_gripper_are_visible() {
    let task = standard_tasks().unwrap().remove(0);
    let mut env = BlocksEnv::stacking(task, EnvConfig::default()).unwrap();
    for seed in 0..10 {
        let (obs, _) = env.reset(seed).unwrap();
        let img = obs.frame().unwrap();
        for (i, c) in CUBE_COLOURS.iter().enumerate() {
            let n = count_colour(img, *c);
            assert!(n >= 16, "seed {seed}: cube {i} shows {n} pixels");
        }
        let dark = img
            .pixels()
            .filter(|p| p[0] < 70 && p[1] < 70 && p[2] < 80)
            .count();
        assert!(dark >= 8, "seed {seed}: gripper shows {dark} pixels");
    }
}

#[test]
fn rendering_is_deterministic_and_follows_the_world() {
    let ys = [-0.2, -0.1, 0.0, 0.1, 0.2];
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(4);
    let w = World::random_start(&mut rng, &ys, Vec::new());
    let r = Renderer::standard();
    let a = r.render_world(&w, &CUBE_COLOURS);
    assert_eq!(a, r.render_world(&w, &CUBE_COLOURS));
    // A fresh renderer gives the same pixels.
    let fresh = Renderer::new(
        env_blocks::render::CAMERA_EYE,
        env_blocks::render::CAMERA_TARGET,
        env_blocks::render::CAMERA_UP,
    );
    assert_eq!(a, fresh.render_world(&w, &CUBE_COLOURS));
    let mut moved = w.clone();
    moved.set_object(0, w.objects()[0] + Vec3::new(0.02, 0.0, 0.0));
    assert_ne!(a, r.render_world(&moved, &CUBE_COLOURS));
}

#[test]
fn shading_distinguishes_faces() {
    let mut w = World::new(vec![Vec3::new(0.0, 0.0, CUBE_HALF)], Vec::new());
    w.set_object(0, Vec3::new(0.0, -0.05, CUBE_HALF));
    let img = Renderer::standard().render_world(&w, &[[0.9, 0.1, 0.1]]);
    let mut reds: Vec<u8> = img
        .pixels()
        .filter(|p| p[0] > 60 && p[1] < 40 && p[2] < 40)
        .map(|p| p[0])
        .collect();
    reds.sort_unstable();
    reds.dedup();
    assert!(
        reds.len() >= 2,
        "top and side faces should differ in brightness: {reds:?}"
    );
}
