//! Demonstration videos: keyframes equal the flat demo's frames, timing is
//! seeded and varies, slips are visible, sorting works, configs validate.

use ctg_graph::Vocabulary;
use env_blocks::world::Outcome;
use env_blocks::{
    ActionLevel, BlocksError, BlocksTask, EnvConfig, Failure, FrameRange, VideoConfig, expert_demo,
    generate_sort_tasks, generate_video_demos, record_rich_demo, record_video_demo, standard_tasks,
    video_segment_lengths, vocabulary,
};
use image::RgbImage;

fn stack_tasks(n: usize) -> Vec<BlocksTask> {
    standard_tasks()
        .unwrap()
        .into_iter()
        .take(n)
        .map(BlocksTask::Stack)
        .collect()
}

fn sort_tasks(n: usize) -> Vec<BlocksTask> {
    generate_sort_tasks(5, n)
        .unwrap()
        .into_iter()
        .map(BlocksTask::Sort)
        .collect()
}

/// Asserts the video's keyframes and actions are the flat demo's, byte for
/// byte.
fn assert_keyframes_match(task: &BlocksTask, seed: u64) {
    let config = EnvConfig::default();
    let video = record_video_demo(task.clone(), config, seed, &VideoConfig::default()).unwrap();
    let demo = expert_demo(task, config, seed).unwrap();
    assert_eq!(video.actions(), demo.actions(), "{} seed {seed}", task.id());
    let keys = video.keyframes();
    let flat: Vec<&RgbImage> = demo
        .observations()
        .iter()
        .map(|o| o.frame().unwrap())
        .collect();
    assert_eq!(keys.observations().len(), flat.len());
    for (k, (a, b)) in keys.observations().iter().zip(flat).enumerate() {
        assert!(
            a.as_raw() == b.as_raw(),
            "{} seed {seed}: keyframe {k} differs from the flat demo's frame",
            task.id()
        );
    }
    assert!(video.segment_lengths().iter().all(|&n| n >= 1));
}

/// Seeds (from 0) whose demo of `task` has a flat step matching `pred`.
fn seeds_with(task: &BlocksTask, count: usize, pred: impl Fn(&Outcome) -> bool) -> Vec<u64> {
    (0..200u64)
        .filter(|&s| {
            record_rich_demo(task.clone(), EnvConfig::state_only(), s)
                .unwrap()
                .steps
                .iter()
                .any(|st| st.primitives.iter().any(|e| pred(&e.outcome)))
        })
        .take(count)
        .collect()
}

#[test]
fn keyframes_equal_the_flat_demo_frames_with_failures_on() {
    for task in stack_tasks(3) {
        for seed in [0, 7] {
            assert_keyframes_match(&task, seed);
        }
    }
    for task in sort_tasks(2) {
        assert_keyframes_match(&task, 3);
    }
    // Demos with a slipped grasp and with an off-centre drop.
    let task = stack_tasks(1).remove(0);
    let slips = seeds_with(&task, 2, |o| {
        matches!(o, Outcome::Failed(Failure::Slipped { .. }))
    });
    let off = seeds_with(&task, 2, |o| {
        matches!(
            o,
            Outcome::Dropped {
                off_centre: true,
                ..
            }
        )
    });
    assert!(!slips.is_empty() && !off.is_empty());
    for seed in slips.into_iter().chain(off) {
        assert_keyframes_match(&task, seed);
    }
}

#[test]
fn same_seed_same_video_and_timing_varies_between_seeds() {
    let task = stack_tasks(2).remove(1);
    let config = EnvConfig::default();
    let video = VideoConfig::default();
    let a = record_video_demo(task.clone(), config, 4, &video).unwrap();
    let b = record_video_demo(task.clone(), config, 4, &video).unwrap();
    assert_eq!(a, b);
    let c = record_video_demo(task.clone(), config, 5, &video).unwrap();
    assert_ne!(a.segment_lengths(), c.segment_lengths());
    // Without failures the two seeds' expert demos of one task differ only
    // in the scene and plan order; the lengths differ as well.
    let no_fail = EnvConfig::default().without_failures();
    let d = record_video_demo(task.clone(), no_fail, 4, &video).unwrap();
    let e = record_video_demo(task, no_fail, 5, &video).unwrap();
    assert_ne!(d.segment_lengths(), e.segment_lengths());
}

#[test]
fn parallel_generation_equals_one_by_one() {
    let tasks = stack_tasks(2);
    let pairs = [(0, 1), (1, 2), (0, 3)];
    let video = VideoConfig::default();
    let all = generate_video_demos(&tasks, &pairs, EnvConfig::default(), &video);
    for (&(i, s), got) in pairs.iter().zip(all) {
        let want = record_video_demo(tasks[i].clone(), EnvConfig::default(), s, &video).unwrap();
        assert_eq!(got.unwrap(), want);
    }
    let bad = generate_video_demos(&tasks, &[(9, 0)], EnvConfig::default(), &video);
    assert!(matches!(bad[0], Err(BlocksError::Invalid(_))));
}

fn median(v: &mut [usize]) -> usize {
    v.sort_unstable();
    v[v.len() / 2]
}

#[test]
fn frames_per_flat_action_distribution() {
    let tasks = stack_tasks(50);
    let (config, video) = (EnvConfig::default(), VideoConfig::default());
    let mut per_action = Vec::new();
    let mut per_demo = Vec::new();
    let mut actions = Vec::new();
    let mut start = Vec::new();
    for (k, task) in tasks.iter().enumerate() {
        let lengths = video_segment_lengths(task.clone(), config, 100 + k as u64, &video).unwrap();
        start.push(lengths[0]);
        per_action.extend_from_slice(&lengths[1..]);
        per_demo.push(lengths.iter().sum::<usize>());
        actions.push(lengths.len() - 1);
    }
    // The lengths are those of the rendered videos.
    for k in [0, 17] {
        let v = record_video_demo(tasks[k].clone(), config, 100 + k as u64, &video).unwrap();
        let lengths = video_segment_lengths(tasks[k].clone(), config, 100 + k as u64, &video);
        assert_eq!(v.segment_lengths(), lengths.unwrap());
    }
    let (n_actions, n_demos) = (per_action.len(), per_demo.len());
    let m_action = median(&mut per_action);
    let m_demo = median(&mut per_demo);
    let m_len = median(&mut actions);
    eprintln!(
        "50 stacking video demos: {n_actions} flat actions; frames per flat action \
         min {} median {m_action} max {} mean {:.2}; frames per demo min {} median {m_demo} \
         max {}; flat actions per demo median {m_len}; start frames {}..={}",
        per_action[0],
        per_action[n_actions - 1],
        per_action.iter().sum::<usize>() as f64 / n_actions as f64,
        per_demo[0],
        per_demo[n_demos - 1],
        start.iter().min().unwrap(),
        start.iter().max().unwrap(),
    );
    assert!(m_action >= 3, "median frames per flat action {m_action}");
    assert!(per_action[0] >= 3 && per_action[n_actions - 1] <= 9);
    assert!(start.iter().all(|&s| (1..=2).contains(&s)));
}

#[test]
fn a_slipped_grasp_is_visible() {
    let task = stack_tasks(1).remove(0);
    let seed = seeds_with(&task, 1, |o| {
        matches!(o, Outcome::Failed(Failure::Slipped { .. }))
    })[0];
    let rich = record_rich_demo(task.clone(), EnvConfig::state_only(), seed).unwrap();
    let video =
        record_video_demo(task, EnvConfig::default(), seed, &VideoConfig::default()).unwrap();
    let segments: Vec<_> = video.segments().collect();
    for (k, step) in rich.steps.iter().enumerate() {
        if !matches!(step.failure, Some(Failure::Slipped { .. })) {
            continue;
        }
        let seg = segments[k + 1].clone();
        let frames = &video.frames()[seg.clone()];
        // travel (>= 2) + descend + close + lift (>= 1 each).
        assert!(
            frames.len() >= 5,
            "slipped pick has {} frames",
            frames.len()
        );
        let distinct = frames
            .iter()
            .enumerate()
            .filter(|(i, f)| *i == 0 || frames[i - 1].as_raw() != f.as_raw())
            .count();
        assert!(
            distinct >= 3,
            "the slipped grasp shows {distinct} distinct frames"
        );
        return;
    }
    panic!("seed {seed} has no slipped pick");
}

#[test]
fn sorting_videos_use_the_sorting_vocabulary() {
    let task = sort_tasks(1).remove(0);
    let video = record_video_demo(
        task.clone(),
        EnvConfig::default(),
        2,
        &VideoConfig::default(),
    )
    .unwrap();
    let vocab = vocabulary(true, ActionLevel::Flat);
    let names = vocab.format_sequence(video.actions());
    assert!(names.contains("place(bin"), "{names}");
    assert!(video.actions().iter().all(|&a| !Vocabulary::is_reserved(a)));
    assert_eq!(
        video.keyframes().len(),
        expert_demo(&task, EnvConfig::state_only(), 2)
            .unwrap()
            .len()
    );
    assert!(video.num_frames() >= 3 * video.len());
    // Part-done scenes too.
    if let BlocksTask::Sort(t) = &task {
        let part = BlocksTask::Sort(t.with_random_presorted(5, 1));
        assert_keyframes_match(&part, 9);
    }
}

#[test]
fn frame_counts_follow_the_config() {
    let task = stack_tasks(1).remove(0);
    let one = record_video_demo(
        task.clone(),
        EnvConfig::default().without_failures(),
        1,
        &VideoConfig::one_per_phase(),
    )
    .unwrap();
    let lengths = one.segment_lengths();
    assert_eq!(lengths[0], 1);
    // pick = travel + descend + close + lift = 4, place = travel + open + fall = 3.
    let vocab = vocabulary(false, ActionLevel::Flat);
    for (&a, &n) in one.actions().iter().zip(&lengths[1..]) {
        let name = vocab.name(a).unwrap();
        let want = if name.starts_with("pick") { 4 } else { 3 };
        assert_eq!(n, want, "{name}");
    }
}

#[test]
fn invalid_video_configs_are_refused() {
    let task = stack_tasks(1).remove(0);
    let zero = VideoConfig {
        travel: FrameRange::new(0, 2),
        ..VideoConfig::default()
    };
    let msg = zero.validate().unwrap_err().to_string();
    assert!(msg.contains("travel") && msg.contains("0 frames"), "{msg}");
    let inverted = VideoConfig {
        fall: FrameRange::new(3, 2),
        ..VideoConfig::default()
    };
    let msg = inverted.validate().unwrap_err().to_string();
    assert!(
        msg.contains("fall") && msg.contains("min 3 > max 2"),
        "{msg}"
    );
    assert!(matches!(
        record_video_demo(task, EnvConfig::default(), 0, &inverted),
        Err(BlocksError::Invalid(_))
    ));
}
