//! The renderer: framing, determinism, visibility.

use ctg_graph::Environment;
use env_blocks::render::{CUBE_COLOURS, Renderer};
use env_blocks::world::{CUBE_HALF, World};
use env_blocks::{BlocksEnv, EnvConfig, standard_tasks};
use glam::Vec3;
use image::RgbImage;

#[test]
fn workspace_and_towers_fit_the_frame_and_stacking_order_shows() {
    let r = Renderer::standard();
    let at = |x: f32, y: f32, z: f32| r.project(Vec3::new(x, y, z)).unwrap();
    let dist = |a: (f32, f32), b: (f32, f32)| (a.0 - b.0).hypot(a.1 - b.1);
    // Every reachable cube corner (grid ±0.2, jitter ±0.03, half a cube)
    // projects inside the frame, on the table and atop a 5-cube tower.
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for z in [0.0, 0.25] {
                let (x, y) = at(sx * 0.255, sy * 0.255, z);
                assert!(
                    (0.0..=64.0).contains(&x) && (0.0..=64.0).contains(&y),
                    "({x}, {y})"
                );
            }
        }
    }
    // The workspace (cube centres ±0.2 m plus half a cube) spans most of
    // the frame across (world x), and is foreshortened in depth (world y).
    assert!(dist(at(-0.225, 0.0, 0.0), at(0.225, 0.0, 0.0)) > 40.0);
    assert!(dist(at(0.0, -0.225, 0.0), at(0.0, 0.225, 0.0)) > 28.0);
    // Anywhere on the table, a cube spans 4 to 6 pixels across, and 5 cm
    // of height at least 3 pixels: the side faces of a tower's cubes show,
    // so its stacking order can be read off a frame.
    for x in [-0.23, 0.0, 0.23] {
        for y in [-0.23, 0.0, 0.23] {
            let across = dist(at(x - CUBE_HALF, y, 0.05), at(x + CUBE_HALF, y, 0.05));
            assert!((4.0..=6.0).contains(&across), "({x}, {y}): {across}");
            let height = dist(at(x, y, 0.05), at(x, y, 0.10));
            assert!(height >= 3.0, "({x}, {y}): 5 cm of height is {height} px");
        }
    }
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
        // A cube is about 5 pixels across: its top and a side face make
        // 20 to 30 pixels, of which at least 10 match its hue closely.
        for (i, c) in CUBE_COLOURS.iter().enumerate() {
            let n = count_colour(img, *c);
            assert!(n >= 10, "seed {seed}: cube {i} shows {n} pixels");
        }
        let dark = img
            .pixels()
            .filter(|p| p[0] < 70 && p[1] < 70 && p[2] < 80)
            .count();
        assert!(dark >= 8, "seed {seed}: gripper shows {dark} pixels");
    }
}

#[test]
fn every_cube_of_a_tower_shows_anywhere_on_the_table() {
    // Four cubes stacked at the near edge, the centre and the far edge of
    // the table: each one's colour covers pixels (the top cube hides the
    // others' tops, so what shows of them is their side faces).
    for y in [-0.2, 0.0, 0.2] {
        let tower: Vec<Vec3> = (0..4)
            .map(|k| Vec3::new(0.0, y, CUBE_HALF + 2.0 * CUBE_HALF * k as f32))
            .collect();
        let w = World::new(tower, Vec::new());
        let img = Renderer::standard().render_world(&w, &CUBE_COLOURS[..4]);
        for (k, c) in CUBE_COLOURS[..4].iter().enumerate() {
            let n = count_colour(&img, *c);
            assert!(n >= 6, "tower at y = {y}: cube {k} shows {n} pixels");
        }
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

#[test]
fn a_larger_camera_shows_the_same_framing_with_more_pixels_per_cube() {
    use env_blocks::Camera;
    let standard = Renderer::standard();
    let big = Renderer::of(Camera::of_size(128));
    assert_eq!(big.size(), 128);
    // The same point lands at twice the pixel coordinates.
    for p in [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.2, -0.2, 0.1),
        Vec3::new(-0.23, 0.23, 0.25),
    ] {
        let (x, y) = standard.project(p).unwrap();
        let (bx, by) = big.project(p).unwrap();
        assert!((bx - 2.0 * x).abs() < 1e-3 && (by - 2.0 * y).abs() < 1e-3);
    }
    // A cube spans about 10 pixels across at 128 (4 to 6 at 64).
    let at = |x: f32| big.project(Vec3::new(x, 0.0, 0.05)).unwrap();
    let across = (at(CUBE_HALF).0 - at(-CUBE_HALF).0).hypot(at(CUBE_HALF).1 - at(-CUBE_HALF).1);
    assert!((8.0..=12.0).contains(&across), "{across}");
    // Renderers are shared per side, and the standard camera is the default.
    assert!(std::ptr::eq(big, Renderer::of(Camera::of_size(128))));
    assert!(std::ptr::eq(standard, Renderer::of(Camera::default())));
    assert_eq!(Camera::of_size(96).frame_dim(), 3 * 96 * 96);

    // The environment renders with its configuration's camera.
    let task = standard_tasks().unwrap().remove(0);
    let config = EnvConfig::default().with_camera(Camera::of_size(96));
    let mut env = BlocksEnv::stacking(task.clone(), config).unwrap();
    let (obs, _) = env.reset(3).unwrap();
    let frame = obs.frame().unwrap();
    assert_eq!(frame.dimensions(), (96, 96));
    // A side that the encoders cannot halve three times is refused.
    for bad in [0, 60, 1024] {
        let config = EnvConfig::default().with_camera(Camera::of_size(bad));
        let err = BlocksEnv::stacking(task.clone(), config).err().unwrap();
        assert!(err.to_string().contains("camera size"), "{err}");
    }
}

#[test]
fn a_camera_missing_from_an_old_configuration_reads_as_the_standard_one() {
    let mut json = serde_json::to_value(EnvConfig::default()).unwrap();
    json.as_object_mut().unwrap().remove("camera");
    let config: EnvConfig = serde_json::from_value(json).unwrap();
    assert_eq!(config.camera, env_blocks::Camera::default());
    assert!(
        serde_json::from_str::<env_blocks::Camera>(r#"{"size": 64, "zoom": 2}"#).is_err(),
        "unknown camera fields are refused"
    );
}

#[test]
fn the_tall_framing_holds_an_eight_cube_tower_anywhere_where_the_standard_one_does_not() {
    use env_blocks::{Camera, Framing};
    let standard = Renderer::of(Camera::of_size(160));
    let tall = Renderer::of(Camera::of_size(160).with_framing(Framing::Tall));
    assert!(!std::ptr::eq(standard, tall), "one renderer per camera");
    let inside = |r: &Renderer, p: Vec3| {
        let (x, y) = r.project(p).unwrap();
        (0.0..=160.0).contains(&x) && (0.0..=160.0).contains(&y)
    };
    // Every reachable cube corner up to 0.5 m: the top of an eight-cube
    // tower (0.4 m) and a cube held above it.
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for z in [0.0, 0.25, 0.4, 0.5] {
                let p = Vec3::new(sx * 0.255, sy * 0.255, z);
                assert!(inside(tall, p), "{p}");
            }
        }
    }
    // The standard framing loses an eight-cube tower's top at a corner.
    assert!(!inside(standard, Vec3::new(-0.255, 0.255, 0.4)));
    // A cube spans about 10 pixels at 160 (as at 128 in the standard one).
    let at = |x: f32| tall.project(Vec3::new(x, 0.0, 0.05)).unwrap();
    let across = (at(CUBE_HALF).0 - at(-CUBE_HALF).0).hypot(at(CUBE_HALF).1 - at(-CUBE_HALF).1);
    assert!((8.5..=12.0).contains(&across), "{across}");
    // It serialises by name; the standard framing is left out.
    let json = serde_json::to_string(&Camera::of_size(160).with_framing(Framing::Tall)).unwrap();
    assert_eq!(json, r#"{"size":160,"framing":"tall"}"#);
    assert_eq!(
        serde_json::to_string(&Camera::of_size(128)).unwrap(),
        r#"{"size":128}"#
    );
    let back: Camera = serde_json::from_str(&json).unwrap();
    assert_eq!(back.framing, Framing::Tall);
}
