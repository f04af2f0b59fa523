//! Criterion benchmarks: rendered frames, env steps, expert demos and
//! demonstration videos.
//!
//! `cargo bench -p env-blocks`. Throughput is reported per element (frames,
//! steps, demos).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ctg_graph::Environment;
use env_blocks::render::CUBE_COLOURS;
use env_blocks::{
    BlocksEnv, BlocksTask, EnvConfig, Renderer, VideoConfig, generate_demos, record_video_demo,
    standard_tasks,
};

fn render(c: &mut Criterion) {
    let task = standard_tasks().unwrap().remove(0);
    let mut env = BlocksEnv::stacking(task, EnvConfig::default()).unwrap();
    env.reset(0).unwrap();
    let world = env.world().clone();
    let r = Renderer::standard();
    let mut g = c.benchmark_group("render");
    g.throughput(Throughput::Elements(1));
    g.bench_function("frame_64x64", |b| {
        b.iter(|| black_box(r.render_world(black_box(&world), &CUBE_COLOURS)))
    });
    g.finish();
}

fn steps(c: &mut Criterion) {
    let tasks = standard_tasks().unwrap();
    let mut g = c.benchmark_group("env_steps");
    for (name, config) in [
        ("state_only", EnvConfig::state_only()),
        ("rendered", EnvConfig::default()),
    ] {
        let mut env = BlocksEnv::stacking(tasks[0].clone(), config).unwrap();
        let actions: Vec<_> = env.vocabulary().actions().collect();
        // 20 random-ish flat actions per iteration, from a reset.
        g.throughput(Throughput::Elements(20));
        g.bench_function(name, |b| {
            let mut seed = 0;
            b.iter(|| {
                seed += 1;
                env.reset(seed).unwrap();
                for k in 0..20 {
                    black_box(
                        env.step(actions[(k * 7 + seed as usize) % actions.len()])
                            .unwrap(),
                    );
                }
            })
        });
    }
    g.finish();
}

fn demos(c: &mut Criterion) {
    // 1 -> 2 thread scaling of demo generation. A state-only demo costs ~8 us,
    // so that case gets 16x more demos per iteration to amortise rayon's
    // fork/join overhead; rendered demos cost ~0.4 ms each.
    let tasks: Vec<BlocksTask> = standard_tasks()
        .unwrap()
        .into_iter()
        .take(64)
        .map(BlocksTask::Stack)
        .collect();
    let mut g = c.benchmark_group("expert_demos");
    g.sample_size(20);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        for (name, config, demos_per_iter) in [
            ("rendered", EnvConfig::default(), 64),
            ("state_only", EnvConfig::state_only(), 1024),
        ] {
            let pairs: Vec<(usize, u64)> = (0..demos_per_iter)
                .map(|k| (k % tasks.len(), k as u64))
                .collect();
            g.throughput(Throughput::Elements(pairs.len() as u64));
            g.bench_function(format!("{name}_{threads}_threads"), |b| {
                b.iter(|| pool.install(|| black_box(generate_demos(&tasks, &pairs, config))))
            });
        }
    }
    g.finish();
}

fn videos(c: &mut Criterion) {
    // Video demos of one standard stacking task (failures on, default
    // timing), 8 seeds per iteration on one thread; the same work is
    // reported per demo and per frame.
    let task = BlocksTask::Stack(standard_tasks().unwrap().remove(0));
    let config = EnvConfig::default();
    let video = VideoConfig::default();
    let seeds: Vec<u64> = (0..8).collect();
    let record_all = || {
        seeds
            .iter()
            .map(|&s| record_video_demo(task.clone(), config, s, &video).unwrap())
            .collect::<Vec<_>>()
    };
    let frames: usize = record_all().iter().map(|v| v.num_frames()).sum();
    let mut g = c.benchmark_group("video_demos");
    g.sample_size(10);
    for (name, elements) in [("demos", seeds.len()), ("frames", frames)] {
        g.throughput(Throughput::Elements(elements as u64));
        g.bench_function(format!("stack_task0_{name}"), |b| {
            b.iter(|| black_box(record_all()))
        });
    }
    g.finish();
}

criterion_group!(benches, render, steps, demos, videos);
criterion_main!(benches);
