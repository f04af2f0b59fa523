//! Video demonstrations: keyframes are the one-frame demo's frames byte for
//! byte, recording does not change the episode, determinism, varying
//! lengths, real motion between keyframes, failures, config validation and
//! the frames-per-action distribution.

use ctg_graph::{Environment, record_demonstration};
use env_collect::export::{video_captions, video_contact_sheet, write_video_contact_sheet};
use env_collect::{
    Action, Category, CollectConfig, CollectEnv, CollectError, CollectExpert, Failure, FrameRange,
    Place, Task, TaskSplitter, VideoConfig, VideoRecorder, generate_video_demos, jobs_for_tasks,
    record_video_demo,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn sample_task(n: usize, seed: u64) -> Task {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    TaskSplitter::default().sample(n, None, &mut rng).unwrap()
}

fn video(task: &Task, seed: u64) -> ctg_graph::VideoDemonstration<image::RgbImage> {
    record_video_demo(
        task.clone(),
        CollectConfig::default(),
        seed,
        &VideoConfig::default(),
    )
    .unwrap()
}

#[test]
fn keyframes_are_the_one_frame_demos_frames() {
    for n in 1..=env_collect::domain::MAX_OBJECTS {
        for seed in [0, 3, 17, 1234] {
            let task = sample_task(n, seed + 100);
            let config = CollectConfig::default();
            let mut env = CollectEnv::new(task.clone(), config).unwrap();
            let demo = record_demonstration(&mut env, &mut CollectExpert, seed).unwrap();
            let v = video(&task, seed);
            assert_eq!(v.actions(), demo.actions(), "N = {n}, seed {seed}");
            let frames: Vec<_> = demo
                .observations()
                .iter()
                .map(|o| o.frame.clone().unwrap())
                .collect();
            let keys = v.keyframes();
            assert_eq!(keys.observations(), &frames[..], "N = {n}, seed {seed}");
            assert!(v.num_frames() > frames.len());
        }
    }
}

#[test]
fn keyframes_only_config_gives_the_one_frame_demo() {
    let task = sample_task(3, 5);
    let v = record_video_demo(
        task.clone(),
        CollectConfig::default(),
        9,
        &VideoConfig::keyframes_only(),
    )
    .unwrap();
    let demo = env_collect::record_demo(&task, 9, &CollectConfig::default()).unwrap();
    assert!(v.segment_lengths().iter().all(|&l| l == 1));
    let frames: Vec<_> = demo
        .observations()
        .iter()
        .map(|o| o.frame.clone().unwrap())
        .collect();
    assert_eq!(v.frames(), &frames[..]);
}

type State = (
    Option<Place>,
    Option<Category>,
    Vec<Category>,
    usize,
    usize,
    bool,
);

fn state(env: &CollectEnv) -> State {
    (
        env.place(),
        env.held(),
        env.visible(),
        env.delivered(),
        env.steps_taken(),
        env.is_over(),
    )
}

#[test]
fn recording_does_not_change_the_episode() {
    // Stepping the same actions with and without the recorder gives the
    // same observations, rewards, infos and hidden state.
    let task = sample_task(4, 8);
    let config = CollectConfig::default();
    let mut plain = CollectEnv::new(task.clone(), config).unwrap();
    let demo = record_demonstration(&mut plain, &mut CollectExpert, 21).unwrap();
    let mut env = CollectEnv::new(task, config).unwrap();
    let mut recorder = VideoRecorder::new(VideoConfig::default()).unwrap();
    let (first, _, seg0) = recorder.reset(&mut env, 21).unwrap();
    assert_eq!(&first, &demo.observations()[0]);
    assert_eq!(seg0.last(), first.frame.as_ref());
    plain.reset(21).unwrap();
    for &a in demo.actions() {
        let expected = plain.step(a).unwrap();
        let (step, frames) = recorder.step(&mut env, a).unwrap();
        assert_eq!(step, expected);
        assert_eq!(frames.last(), step.observation.frame.as_ref());
        assert_eq!(state(&env), state(&plain));
    }
}

#[test]
fn deterministic_and_lengths_vary_across_seeds() {
    let task = sample_task(3, 2);
    assert_eq!(video(&task, 5), video(&task, 5));
    let lengths: Vec<Vec<usize>> = (0..6).map(|s| video(&task, s).segment_lengths()).collect();
    for (i, a) in lengths.iter().enumerate() {
        for b in &lengths[i + 1..] {
            assert_ne!(a, b);
        }
    }
    // Per segment, for one action sequence: same actions, other timing.
    let a = video(&task, 5);
    let symbolic = CollectConfig {
        render: false,
        ..CollectConfig::default()
    };
    let actions = |s| {
        env_collect::record_demo(&task, s, &symbolic)
            .unwrap()
            .actions()
            .to_vec()
    };
    let demo_seed = (0..200)
        .find(|&s| s != 5 && actions(s) == a.actions())
        .expect("another seed with the same actions");
    let b = video(&task, demo_seed);
    assert_ne!(a.segment_lengths(), b.segment_lengths());
}

#[test]
fn intermediate_frames_show_motion() {
    let task = sample_task(4, 6);
    for seed in 0..4 {
        let v = video(&task, seed);
        let keys = v.keyframe_indices();
        for (s, range) in v.segments().enumerate() {
            let key = &v.frames()[range.end - 1];
            let mut previous: Option<&image::RgbImage> = None;
            for i in range.clone() {
                let frame = &v.frames()[i];
                if i != range.end - 1 {
                    assert!(!keys.contains(&i));
                    let differing = frame
                        .pixels()
                        .zip(key.pixels())
                        .filter(|(p, q)| p.0.iter().zip(q.0).any(|(&a, b)| a.abs_diff(b) > 12))
                        .count();
                    // More than sensor noise: a real change of the picture.
                    assert!(differing > 40, "segment {s}, frame {i}: {differing} pixels");
                }
                if let Some(p) = previous {
                    assert_ne!(p, frame, "segment {s}: frame {i} repeats");
                }
                previous = Some(frame);
            }
        }
    }
}

#[test]
fn search_pans_and_pickup_ends_with_the_object_in_hand() {
    let task = sample_task(2, 4);
    let config = VideoConfig {
        search: FrameRange::fixed(3),
        reach: FrameRange::fixed(2),
        lift: FrameRange::fixed(3),
        ..VideoConfig::default()
    };
    let v = record_video_demo(task, CollectConfig::default(), 3, &config).unwrap();
    for (s, range) in v.segments().enumerate().skip(1) {
        match Action::from_id(v.actions()[s - 1]).unwrap() {
            Action::Search => assert_eq!(range.len(), 3),
            Action::Pickup(_) => assert_eq!(range.len(), 5),
            Action::Dropoff(_) => assert!((5..=9).contains(&range.len())),
        }
    }
    // Half-way through a pan, the left half of the frame is the right half
    // of the previous place (up to noise).
    let search = v
        .actions()
        .iter()
        .position(|&a| a == Action::Search.id())
        .unwrap();
    let range = v.segments().nth(search + 1).unwrap();
    let before = &v.frames()[range.start - 1];
    let mid = &v.frames()[range.start]; // t = 1/3: shifted by 21 pixels
    let mut close = 0;
    for y in 0..40 {
        for x in 0..40 {
            let (p, q) = (mid.get_pixel(x, y).0, before.get_pixel(x + 21, y).0);
            if p.iter().zip(q).all(|(&a, b)| a.abs_diff(b) <= 12) {
                close += 1;
            }
        }
    }
    assert!(
        close > 1500,
        "{close} of 1600 pixels match the shifted view"
    );
}

#[test]
fn a_failed_pickup_reaches_and_keeps_an_empty_hand() {
    let task = sample_task(2, 9);
    let mut env = CollectEnv::new(task.clone(), CollectConfig::default()).unwrap();
    let config = VideoConfig {
        reach: FrameRange::fixed(2),
        lift: FrameRange::fixed(2),
        ..VideoConfig::default()
    };
    let mut recorder = VideoRecorder::new(config).unwrap();
    recorder.reset(&mut env, 1).unwrap();
    let (_, seg) = recorder.step(&mut env, Action::Search.id()).unwrap();
    let arrived = seg.last().unwrap().clone();
    // A category that is not visible here.
    let missing = Category::ALL
        .into_iter()
        .find(|c| !env.visible().contains(c))
        .unwrap();
    let (step, frames) = recorder
        .step(&mut env, Action::Pickup(missing).id())
        .unwrap();
    assert_eq!(step.info.failure, Some(Failure::NotVisible(missing)));
    assert_eq!(env.held(), None);
    assert_eq!(frames.len(), 4); // reach 2, pull back 1, keyframe
    // The hand inset stays empty (dark) in every frame.
    for f in &frames {
        let p = f.get_pixel(54, 54).0;
        assert!(p.iter().all(|&v| v < 45), "{p:?}");
    }
    // The arm is visible while reaching (skin-coloured pixels).
    let skin = |f: &image::RgbImage| {
        f.pixels()
            .filter(|p| {
                p.0[0] > 200 && (150..=200).contains(&p.0[1]) && (115..=165).contains(&p.0[2])
            })
            .count()
    };
    assert!(skin(&frames[1]) > skin(&arrived) + 30);
    // The keyframe is the place as it was (only the noise differs, same
    // place: identical frame).
    assert_eq!(frames.last(), Some(&arrived));
    assert!(matches!(env.place(), Some(Place::Location(0))));
}

#[test]
fn a_dropoff_with_an_empty_hand_still_renders() {
    let task = sample_task(1, 2);
    let mut env = CollectEnv::new(task, CollectConfig::default()).unwrap();
    let mut recorder = VideoRecorder::new(VideoConfig::default()).unwrap();
    recorder.reset(&mut env, 4).unwrap();
    let r = env_collect::Receptacle::Sink;
    let (step, frames) = recorder.step(&mut env, Action::Dropoff(r).id()).unwrap();
    assert_eq!(step.info.failure, Some(Failure::HandsEmpty));
    assert!(frames.len() >= 5);
    assert_eq!(frames.last(), step.observation.frame.as_ref());
    // <end> gets its keyframe only.
    let (step, frames) = recorder.step(&mut env, ctg_graph::Vocabulary::END).unwrap();
    assert!(step.terminated);
    assert_eq!(frames.len(), 1);
}

#[test]
fn validate_refuses_bad_configs() {
    assert!(VideoConfig::default().validate().is_ok());
    assert!(VideoConfig::keyframes_only().validate().is_ok());
    let bad = |config: VideoConfig| match config.validate() {
        Err(CollectError::InvalidConfig(msg)) => msg,
        other => panic!("{other:?}"),
    };
    let msg = bad(VideoConfig {
        search: FrameRange::new(4, 2),
        ..VideoConfig::default()
    });
    assert_eq!(msg, "video phase `search`: min 4 > max 2");
    let msg = bad(VideoConfig {
        lift: FrameRange::fixed(0),
        ..VideoConfig::default()
    });
    assert!(msg.contains("`lift`: 0 frames"), "{msg}");
    let msg = bad(VideoConfig {
        start: FrameRange::new(0, 2),
        ..VideoConfig::default()
    });
    assert!(msg.contains("`start`: 0 frames"), "{msg}");
    let msg = bad(VideoConfig {
        drop: FrameRange::new(1, 1000),
        ..VideoConfig::default()
    });
    assert!(msg.contains("`drop`: max 1000 > 64"), "{msg}");
    // The recorder and record_video_demo check too.
    let invalid = VideoConfig {
        open: FrameRange::new(2, 1),
        ..VideoConfig::default()
    };
    assert!(VideoRecorder::new(invalid.clone()).is_err());
    assert!(record_video_demo(sample_task(1, 1), CollectConfig::default(), 0, &invalid).is_err());
    // No frames, no video.
    let off = CollectConfig {
        render: false,
        ..CollectConfig::default()
    };
    let err = record_video_demo(sample_task(1, 1), off, 0, &VideoConfig::default()).unwrap_err();
    assert!(err.to_string().contains("render"), "{err}");
    // Round trip through JSON.
    let json = serde_json::to_string(&VideoConfig::default()).unwrap();
    let back: VideoConfig = serde_json::from_str(&json).unwrap();
    assert_eq!(back, VideoConfig::default());
}

fn quantiles(mut v: Vec<usize>) -> (usize, usize, usize) {
    v.sort_unstable();
    (v[0], v[v.len() / 2], v[v.len() - 1])
}

#[test]
fn median_frames_per_action_is_at_least_three() {
    let config = VideoConfig::default();
    for n in [2, 4] {
        let tasks = TaskSplitter::default()
            .sample_distinct(n, 10, None, n as u64)
            .unwrap();
        let jobs = jobs_for_tasks(&tasks, 5, 77);
        let videos = generate_video_demos(&jobs, &CollectConfig::default(), &config).unwrap();
        assert_eq!(videos.len(), 50);
        let mut per_action = Vec::new();
        let mut per_demo = Vec::new();
        let mut by_kind = [Vec::new(), Vec::new(), Vec::new()];
        for v in &videos {
            per_demo.push(v.num_frames());
            for (a, len) in v.actions().iter().zip(&v.segment_lengths()[1..]) {
                per_action.push(*len);
                let action = Action::from_id(*a).unwrap();
                assert!(config.frames_per_action(action).contains(len));
                let kind = match action {
                    Action::Search => 0,
                    Action::Pickup(_) => 1,
                    Action::Dropoff(_) => 2,
                };
                by_kind[kind].push(*len);
            }
        }
        let (lo, med, hi) = quantiles(per_action.clone());
        let (dlo, dmed, dhi) = quantiles(per_demo);
        let mean = per_action.iter().sum::<usize>() as f64 / per_action.len() as f64;
        println!(
            "N = {n}: frames per action min {lo} median {med} max {hi} (mean {mean:.2}, {} actions); \
             frames per demo min {dlo} median {dmed} max {dhi}",
            per_action.len()
        );
        for (name, lens) in ["search", "pickup", "dropoff"].iter().zip(by_kind) {
            let (a, b, c) = quantiles(lens);
            println!("  {name}: min {a} median {b} max {c}");
        }
        assert!(med >= 3, "N = {n}: median {med}");
        // Parallel equals one by one.
        assert_eq!(
            videos[7],
            record_video_demo(
                jobs[7].task.clone(),
                CollectConfig::default(),
                jobs[7].seed,
                &config
            )
            .unwrap()
        );
    }
}

#[test]
fn contact_sheet_has_one_captioned_cell_per_frame() {
    let task = sample_task(1, 3);
    let v = video(&task, 2);
    let captions = video_captions(&v);
    assert_eq!(captions.len(), v.num_frames());
    assert!(captions[0].starts_with("0.1/") && captions[0].ends_with("<start>"));
    let last = captions.last().unwrap();
    let n = v.segment_lengths()[v.len()];
    assert!(
        last.starts_with(&format!("{}.{n}/{n} dropoff(", v.len())),
        "{last}"
    );
    let sheet = video_contact_sheet(&v);
    let rows = v.num_frames().div_ceil(8) as u32;
    assert_eq!(sheet.width(), 4 + 8 * (128 + 4));
    assert_eq!(sheet.height(), 4 + rows * (128 + 9 + 4));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("video.png");
    write_video_contact_sheet(&path, &v).unwrap();
    assert_eq!(image::open(&path).unwrap().to_rgb8(), sheet);
    if let Ok(out) = std::env::var("COLLECT_VIDEO_SHEET") {
        let big = video(&sample_task(2, 4), 3);
        write_video_contact_sheet(std::path::Path::new(&out), &big).unwrap();
    }
}

#[test]
fn env_unchanged_by_reset_through_the_recorder() {
    let task = sample_task(2, 1);
    let mut a = CollectEnv::new(task.clone(), CollectConfig::default()).unwrap();
    let mut b = CollectEnv::new(task, CollectConfig::default()).unwrap();
    let mut recorder = VideoRecorder::new(VideoConfig::default()).unwrap();
    recorder.reset(&mut a, 11).unwrap();
    b.reset(11).unwrap();
    assert_eq!(a.scene(), b.scene());
}
