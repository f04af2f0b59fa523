//! The staged video training against the state path, on the CPU backend:
//!
//! - `stage_b/state_step` and `stage_b/embedding_step`: one NTG training
//!   step (forward, backward, Adam) of block stacking's recommended recipe,
//!   32 demos, on state rows (one per action) and on frame embeddings (every
//!   frame of a demo video, as stage B trains). The target: the
//!   second at most 1.5x the first. `stage_b/embedding_step_pool_K`: the
//!   same with the demo interpreter reading the frames averaged in windows
//!   of K (`--interpreter-frame-pool K`).
//! - `stage_a/train`: one stage A step on 64 frames (the shared encoder
//!   with the localizer's and edge head's losses), throughput in frames.
//!   `benches/pytorch/stage_a.py` (its own `requirements.txt`) times the
//!   same network, losses and batch in PyTorch: run it right after this
//!   bench on the same quiet machine.
//!   `stage_a/train_2_shards`: the same step split into 2 data-parallel
//!   shards, as `ntg train` runs stage A by default.
//! - `stage_a/encode`: the frozen encoder over 256 frames (stage B's cache
//!   and every policy step), throughput in frames; `stage_a/record`:
//!   recording one demo video (the expert's poses rendered), throughput in
//!   its frames. Stage B's cache costs both per frame.
//! - `stage_a_keypoints_64/…` and `stage_a_keypoints_128_stem16/…`: the
//!   same two with block stacking's encoder (He initialisation, centred
//!   frames, spatial-softmax keypoints) on the standard 64×64 camera and
//!   on 128×128 frames through a 16-channel stem; `stage_a.py
//!   --keypoints [--image-size 128 --stem 16]` is its PyTorch twin.
//!
//! `cargo bench -p ntg-trainer --bench stages`

/// The allocator of the `ntg` binary (see `ntg_trainer::allocator`).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::hint::black_box;
use std::time::Duration;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, Criterion, Throughput, criterion_group, criterion_main};
use ctg_graph::Vocabulary;
use ntg_model::FrameStageNet;
use ntg_trainer::blocks::{self, BlocksDomain, Recipe};
use ntg_trainer::dataset::DemoDataset;
use ntg_trainer::domain::record_demos;
use ntg_trainer::fit::{StepContext, TrainStep, TrainedModel};
use ntg_trainer::method::ntg::{GcnSource, NtgStep, NtgTraining};
use ntg_trainer::spec::ObsKind;
use ntg_trainer::video::{EncoderStage, FrameStageStep, embedding_dataset, frame_dataset};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const TASKS: usize = 16;
const DEMOS_PER_TASK: usize = 4;
const BATCH: usize = 32;

/// Demo `j` of task `t` is recorded with seed `1000 t + j`.
fn pairs() -> Vec<(usize, u64)> {
    ntg_trainer::video::spread_pairs(TASKS, DEMOS_PER_TASK, 0)
}

fn record_video(t: usize, seed: u64) -> anyhow::Result<ctg_graph::VideoDemonstration<Vec<f32>>> {
    record_video_with(env_blocks::Camera::default(), t, seed)
}

fn record_video_with(
    camera: env_blocks::Camera,
    t: usize,
    seed: u64,
) -> anyhow::Result<ctg_graph::VideoDemonstration<Vec<f32>>> {
    let task = env_blocks::standard_tasks()?.swap_remove(t);
    let v = env_blocks::record_video_demo(
        env_blocks::BlocksTask::Stack(task),
        blocks::env_config(ObsKind::Vid, true).with_camera(camera),
        seed,
        &env_blocks::VideoConfig::default(),
    )?;
    Ok(v.map_frames(|f| env_collect::frame_to_chw(&f)))
}

/// Stage A's training step on 64 frames and its encoder over 256 frames,
/// with `stage`'s network on frames of `camera`, as the group `name`.
fn stage_a_bench(c: &mut Criterion, name: &str, stage: &EncoderStage, camera: env_blocks::Camera) {
    let vocab: Vocabulary = blocks::flat_vocabulary();
    let device = ntg_model::cpu_device().autodiff();
    let net: FrameStageNet = stage
        .net_config(vocab.len(), camera.size as usize, 0)
        .init(&device)
        .expect("stage A net");
    let record = |t: usize, seed: u64| record_video_with(camera, t, seed);
    let frames =
        frame_dataset(&vocab, &pairs()[..8], &record, camera.frame_dim(), 1.0).expect("frames");
    let step = FrameStageStep::new(&frames, &device).expect("stage A step");
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(2))
        .measurement_time(Duration::from_secs(10));
    group.throughput(Throughput::Elements(stage.batch_size as u64));
    bench_train_step(&mut group, "train", net.clone(), &step, stage.batch_size);
    bench_train_step_2_shards(&mut group, net.clone(), &step, stage.batch_size);
    let rows: Vec<Vec<f32>> = (0..256)
        .map(|i| frames.row(i % frames.num_rows()))
        .collect();
    let frozen = net.valid();
    group.throughput(Throughput::Elements(rows.len() as u64));
    group.bench_function("encode", |b| {
        b.iter(|| black_box(ntg_trainer::video::encode_rows(&frozen, &rows).expect("encode")))
    });
    // Stage B's other cost per frame: recording a demo video (the expert's
    // poses, rendered, as CHW rows), throughput in its frames.
    let frames_per_video = record(0, 0).expect("video").num_frames();
    group.throughput(Throughput::Elements(frames_per_video as u64));
    group.bench_function("record", |b| {
        b.iter(|| black_box(record(0, 0).expect("video")))
    });
    group.finish();
}

fn ntg_step_bench(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    obs: ObsKind,
    dataset: &DemoDataset,
    frame_pool: usize,
) {
    let device = ntg_model::cpu_device().autodiff();
    let mut config = Recipe::Recommended.config(obs, TASKS, DEMOS_PER_TASK, 1, 0);
    if let Some(video) = config.video.as_mut() {
        video.interpreter_frame_pool = frame_pool;
    }
    let model = blocks::new_model(&config, &device).expect("model");
    let training = NtgTraining {
        gcn_source: GcnSource::OtherSeeded,
        detach_gcn_from_edges: true,
        ..NtgTraining::default()
    };
    let step = NtgStep::new(&model, dataset, training, &device).expect("step");
    bench_train_step(group, name, model, &step, BATCH);
}

/// Times one training step of `model` with `step` on its first `batch`
/// examples: the loss, its gradients and Adam's update.
fn bench_train_step<M: TrainedModel, S: TrainStep<M>>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    model: M,
    step: &S,
    batch: usize,
) {
    let batch: Vec<usize> = (0..batch).collect();
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut slot = Some(model);
    group.bench_function(name, |b| {
        b.iter(|| {
            let model = slot.take().expect("model");
            let ctx = StepContext {
                epoch: 0,
                step: 0,
                seed: 0,
                rng: &mut rng,
            };
            let report = step.step(&model, &batch, ctx).expect("step");
            let grads = GradientsParams::from_grads(report.loss.backward(), &model);
            slot = Some(black_box(optimizer.step(1e-3, model, grads)));
        })
    });
}

/// [`bench_train_step`] as `ntg train` runs stage A by default: the batch
/// split into 2 data-parallel shards, each shard's forward and backward
/// pass a task of rayon's pool over its own replica, the gradients summed
/// (`ntg_model::sharded_gradients`), then one Adam update. Named
/// `train_2_shards`.
fn bench_train_step_2_shards<M: TrainedModel, S: TrainStep<M> + Sync>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    model: M,
    step: &S,
    batch: usize,
) {
    let batch: Vec<usize> = (0..batch).collect();
    let (first, second) = batch.split_at(batch.len() / 2);
    let parts = [first, second];
    let total = batch.len() as f32;
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
    let mut slot = Some(model);
    group.bench_function("train_2_shards", |b| {
        b.iter(|| {
            let model = slot.take().expect("model");
            let (grads, _) = ntg_model::sharded_gradients(&model, 2, |replica, i| {
                let mut rng = ChaCha8Rng::seed_from_u64(i as u64);
                let ctx = StepContext {
                    epoch: 0,
                    step: 0,
                    seed: 0,
                    rng: &mut rng,
                };
                let report = step.step(replica, parts[i], ctx)?;
                let weight = parts[i].len() as f32 / total;
                Ok::<_, anyhow::Error>((report.loss.mul_scalar(weight), ()))
            })
            .expect("sharded step");
            slot = Some(black_box(optimizer.step(1e-3, model, grads)));
        })
    });
}

fn stages(c: &mut Criterion) {
    // Freed pages kept for the next tensors, as `ntg` keeps them.
    ntg_trainer::allocator::keep_freed_memory();
    let tasks = &env_blocks::standard_tasks().expect("tasks")[..TASKS];
    let state = record_demos(
        &BlocksDomain::new(ObsKind::State, true),
        tasks,
        DEMOS_PER_TASK,
        0,
    )
    .expect("state demos");
    let vocab: Vocabulary = blocks::flat_vocabulary();
    let device = ntg_model::cpu_device().autodiff();
    let stage = EncoderStage::default();
    let net: FrameStageNet = stage
        .net_config(vocab.len(), env_blocks::FRAME_SIZE as usize, 0)
        .init(&device)
        .expect("stage A net");
    let embeddings =
        embedding_dataset(&vocab, &pairs(), &record_video, &net).expect("embedding demos");
    eprintln!(
        "state: {} rows for {} demos; embeddings: {} rows (frames) for {} demos",
        state.num_rows(),
        state.demos().len(),
        embeddings.num_rows(),
        embeddings.demos().len()
    );

    let mut group = c.benchmark_group("stage_b");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_secs(2))
        .measurement_time(Duration::from_secs(10));
    ntg_step_bench(&mut group, "state_step", ObsKind::State, &state, 1);
    ntg_step_bench(&mut group, "embedding_step", ObsKind::Vid, &embeddings, 1);
    for pool in [2, 4] {
        let name = format!("embedding_step_pool_{pool}");
        ntg_step_bench(&mut group, &name, ObsKind::Vid, &embeddings, pool);
    }
    group.finish();

    stage_a_bench(c, "stage_a", &stage, env_blocks::Camera::default());
    let keypoints = EncoderStage {
        he_init: true,
        centre_input: true,
        spatial_softmax: true,
        ..EncoderStage::default()
    };
    stage_a_bench(
        c,
        "stage_a_keypoints_64",
        &keypoints,
        env_blocks::Camera::default(),
    );
    let stem = EncoderStage {
        stem: 16,
        ..keypoints
    };
    stage_a_bench(
        c,
        "stage_a_keypoints_128_stem16",
        &stem,
        env_blocks::Camera::of_size(128),
    );
}

criterion_group!(benches, stages);
criterion_main!(benches);
