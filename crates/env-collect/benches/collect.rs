//! Speed of the environment: steps/s without rendering, steps/s with a frame
//! rendered per step (= frames/s), parallel demonstration generation, and
//! video demonstrations (frames/s; demos/s = 8 / time per iteration) next
//! to one-frame demonstrations of the same 8 episodes.
//!
//! `cargo bench -p env-collect --bench collect`

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ctg_graph::{ActionId, Environment, record_demonstration};
use env_collect::{
    CollectConfig, CollectEnv, CollectExpert, Task, TaskSplitter, VideoConfig, generate_demos,
    jobs_for_tasks, record_demo, record_video_demo,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn task(n: usize) -> Task {
    TaskSplitter::default()
        .sample(n, None, &mut ChaCha8Rng::seed_from_u64(n as u64))
        .expect("valid N")
}

/// Replays a fixed expert action sequence: reset plus `actions.len()` steps.
fn episode(env: &mut CollectEnv, seed: u64, actions: &[ActionId]) {
    black_box(env.reset(seed).expect("reset"));
    for &a in actions {
        black_box(env.step(a).expect("step"));
    }
}

fn steps(c: &mut Criterion) {
    let t = task(3);
    let mut group = c.benchmark_group("env_steps");
    for render in [false, true] {
        let config = CollectConfig {
            render,
            ..CollectConfig::default()
        };
        let mut env = CollectEnv::new(t.clone(), config).expect("config");
        let demo = record_demonstration(&mut env, &mut CollectExpert, 1).expect("demo");
        let actions = demo.actions().to_vec();
        // Every step (and the reset) returns one observation, with a frame
        // when rendering: elements = observations.
        group.throughput(Throughput::Elements(actions.len() as u64 + 1));
        let name = if render { "render_on" } else { "render_off" };
        group.bench_function(name, |b| b.iter(|| episode(&mut env, 1, &actions)));
    }
    group.finish();
}

fn demos(c: &mut Criterion) {
    let splitter = TaskSplitter::default();
    let mut tasks = splitter.sample_distinct(2, 8, None, 1).expect("tasks");
    tasks.extend(splitter.sample_distinct(4, 8, None, 2).expect("tasks"));
    let jobs = jobs_for_tasks(&tasks, 4, 0);
    let config = CollectConfig::default();
    let frames: usize = generate_demos(&jobs, &config)
        .expect("demos")
        .iter()
        .map(|d| d.observations().len())
        .sum();
    let mut group = c.benchmark_group("generate_demos");
    group.sample_size(20);
    group.throughput(Throughput::Elements(frames as u64));
    group.bench_function("64_demos_n2_n4_rendered", |b| {
        b.iter(|| black_box(generate_demos(&jobs, &config).expect("demos")))
    });
    group.finish();
}

fn videos(c: &mut Criterion) {
    let t = task(4);
    let config = CollectConfig::default();
    let video = VideoConfig::default();
    let seeds: Vec<u64> = (0..8).collect();
    let record = || {
        seeds
            .iter()
            .map(|&s| record_video_demo(t.clone(), config, s, &video).expect("video"))
            .collect::<Vec<_>>()
    };
    let frames: usize = record().iter().map(|v| v.num_frames()).sum();
    let keyframes: usize = record().iter().map(|v| v.len() + 1).sum();
    let mut group = c.benchmark_group("video_demos_n4");
    group.sample_size(20);
    // Elements = frames: frames/s; 8 demos per iteration.
    group.throughput(Throughput::Elements(frames as u64));
    group.bench_function("8_videos", |b| b.iter(|| black_box(record())));
    group.throughput(Throughput::Elements(keyframes as u64));
    group.bench_function("8_one_frame_demos", |b| {
        b.iter(|| {
            for &s in &seeds {
                black_box(record_demo(&t, s, &config).expect("demo"));
            }
        })
    });
    group.finish();
}

criterion_group!(benches, steps, demos, videos);
criterion_main!(benches);
