//! Criterion benchmarks: rendered frames, env steps and expert demos.
//!
//! `cargo bench -p env-blocks`. Throughput is reported per element (frames,
//! steps, demos).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ctg_graph::Environment;
use env_blocks::render::CUBE_COLOURS;
use env_blocks::{BlocksEnv, BlocksTask, EnvConfig, Renderer, generate_demos, standard_tasks};

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

criterion_group!(benches, render, steps, demos);
criterion_main!(benches);
