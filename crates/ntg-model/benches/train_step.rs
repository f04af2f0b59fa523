//! Training-step (forward, backward, Adam) and policy-step benchmarks of
//! the four NTG networks, batch 32, with the state and the frame encoder,
//! on every backend compiled in (`flex`; add `--features ndarray` for
//! burn-ndarray, `wgpu`/`cuda` for a GPU).
//!
//! `cargo bench -p ntg-model --bench train_step [--features ndarray]`;
//! filter with e.g. `-- flex/frame`.

use std::hint::black_box;
use std::time::Duration;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Int, Tensor, TensorData};
use criterion::{Criterion, criterion_group, criterion_main};
use ctg_graph::{ActionId, Ctg};
use ntg_model::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const BATCH: usize = 32;
/// Block stacking with 8 cubes: `<start>`, `<end>`, pick(i), place(i).
const N: usize = 18;
/// Demo length of the interpreter workload (as STACK.md's prototype): 30
/// frames in, 20 tokens out.
const DEMO_FRAMES: usize = 30;
const DEMO_TOKENS: usize = 20;

fn random(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(0.0f32..1.0)).collect()
}

fn random_ids(rng: &mut ChaCha8Rng, n: usize, lo: usize) -> Vec<ActionId> {
    (0..n)
        .map(|_| ActionId::new(rng.random_range(lo..N)))
        .collect()
}

/// One Adam step of `model` on `loss`.
fn step(model: NtgModel, optim: &mut ModuleOptimizer, loss: Tensor<1>, dev: &Device) -> NtgModel {
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    let model = optim.step(1e-3, model, grads);
    dev.sync().expect("device sync");
    model
}

fn backends() -> Vec<BackendKind> {
    BackendKind::available()
}

fn encoders() -> Vec<(&'static str, EncoderConfig)> {
    vec![
        ("state", EncoderConfig::state(26)),
        ("frame", EncoderConfig::frame()),
        (
            "frame_k4",
            EncoderConfig::Frame(FrameEncoderConfig::new().with_kernel(4)),
        ),
    ]
}

fn train_steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("train_step");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(2))
        .measurement_time(Duration::from_secs(8));
    for backend in backends() {
        let dev = backend.device().expect("backend").autodiff();
        for (enc_name, enc) in encoders() {
            let config = NtgConfig::for_domain(N, enc);
            let d = config.obs_dim();
            let mut rng = ChaCha8Rng::seed_from_u64(1);

            // Node localizer: Enc + ℓ + cross-entropy.
            let obs_rows: Vec<Vec<f32>> = (0..BATCH).map(|_| random(&mut rng, d)).collect();
            let obs = rows_tensor(&obs_rows, d, &dev).unwrap();
            let nodes = random_ids(&mut rng, BATCH, 0);
            let node_ids = ids_tensor(&nodes, N, &dev).unwrap();
            let mut slot = Some(NtgModel::new(config.clone(), &dev).unwrap());
            let mut optim = AdamConfig::new().init();
            group.bench_function(format!("{backend}/{enc_name}/localizer"), |b| {
                b.iter(|| {
                    let model = slot.take().unwrap();
                    let logits = model.localizer.forward(obs.clone()).unwrap();
                    let out = model.localizer.loss(logits, node_ids.clone()).unwrap();
                    slot = Some(step(model, &mut optim, out.loss, &dev));
                })
            });

            // Edge classifier: Enc + W[Enc, NE_gcn] + masked cross-entropy
            // (NE_gcn given, as from a GCN pass over the batch's graphs).
            let paths: Vec<Vec<ActionId>> =
                (0..BATCH).map(|_| random_ids(&mut rng, 16, 2)).collect();
            let graphs: Vec<Ctg> = paths
                .iter()
                .map(|p| Ctg::from_path(N, p).unwrap())
                .collect();
            let graph_refs: Vec<&Ctg> = graphs.iter().collect();
            let here: Vec<ActionId> = paths.iter().map(|p| p[3]).collect();
            let next: Vec<ActionId> = paths.iter().map(|p| p[4]).collect();
            let mask = successor_mask(&graph_refs, &here, Some(&next), N, &dev).unwrap();
            let here_ids = ids_tensor(&here, N, &dev).unwrap();
            let next_ids = ids_tensor(&next, N, &dev).unwrap();
            let mut slot = Some(NtgModel::new(config.clone(), &dev).unwrap());
            let ne_gcn = slot
                .as_ref()
                .unwrap()
                .valid()
                .graph_embeddings(&graph_refs)
                .unwrap();
            let ne_gcn = Tensor::<3>::from_data(ne_gcn.into_data(), &dev);
            let mut optim = AdamConfig::new().init();
            group.bench_function(format!("{backend}/{enc_name}/edge_classifier"), |b| {
                b.iter(|| {
                    let model = slot.take().unwrap();
                    let logits = model
                        .edges
                        .forward(
                            obs.clone(),
                            here_ids.clone(),
                            ne_gcn.clone(),
                            model.localizer.node_embeddings().detach(),
                            mask.clone(),
                            None,
                        )
                        .unwrap();
                    let out = model.edges.loss(logits, next_ids.clone()).unwrap();
                    slot = Some(step(model, &mut optim, out.loss, &dev));
                })
            });

            // Forward pass of the encoder alone (inference), for scale.
            let plain = backend.device().expect("backend");
            let encoder = config.localizer.encoder.init(1, &plain).unwrap();
            let plain_obs = rows_tensor(&obs_rows, d, &plain).unwrap();
            group.bench_function(format!("{backend}/{enc_name}/encoder_forward_only"), |b| {
                b.iter(|| {
                    let out = encoder.forward(plain_obs.clone()).unwrap();
                    plain.sync().expect("device sync");
                    black_box(out)
                })
            });
            if enc_name == "frame_k4" {
                continue;
            }

            // Demo interpreter: 32 demos of 30 frames → 20 tokens (960
            // frames a step: skipped for frames on burn-ndarray, whose
            // convolutions would take minutes per sample).
            if enc_name != "state" && backend == BackendKind::NdArray {
                continue;
            }
            let frames = Tensor::<3>::from_data(
                TensorData::new(
                    random(&mut rng, BATCH * DEMO_FRAMES * d),
                    [BATCH, DEMO_FRAMES, d],
                ),
                &dev,
            );
            let batch = DemoBatch {
                frames,
                frame_mask: Tensor::ones([BATCH, DEMO_FRAMES], &dev),
                targets: Tensor::<2, Int>::from_data(
                    TensorData::new(
                        (0..BATCH * DEMO_TOKENS)
                            .map(|_| rng.random_range(1..N as i64))
                            .collect::<Vec<_>>(),
                        [BATCH, DEMO_TOKENS],
                    ),
                    &dev,
                ),
                target_mask: Tensor::ones([BATCH, DEMO_TOKENS], &dev),
                aligned_rows: None,
            };
            let mut slot = Some(NtgModel::new(config.clone(), &dev).unwrap());
            let mut optim = AdamConfig::new().init();
            group.bench_function(format!("{backend}/{enc_name}/demo_interpreter"), |b| {
                b.iter(|| {
                    let model = slot.take().unwrap();
                    let out = model.interpreter.loss(&batch).unwrap();
                    slot = Some(step(model, &mut optim, out.loss, &dev));
                })
            });
        }

        // GCN (no encoder): batch of 32 path graphs over 18 nodes, default
        // sizes (hidden 64, 3 iterations) …
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let config = NtgConfig::for_domain(N, EncoderConfig::state(26));
        let paths: Vec<Vec<ActionId>> = (0..BATCH).map(|_| random_ids(&mut rng, 16, 2)).collect();
        let graphs: Vec<Ctg> = paths
            .iter()
            .map(|p| Ctg::from_path(N, p).unwrap())
            .collect();
        let refs: Vec<&Ctg> = graphs.iter().collect();
        let adjacency = adjacency_tensor(&refs, N, &dev).unwrap();
        let mut slot = Some(NtgModel::new(config, &dev).unwrap());
        let mut optim = AdamConfig::new().init();
        group.bench_function(format!("{backend}/gcn"), |b| {
            b.iter(|| {
                let model = slot.take().unwrap();
                let out = model.gcn.forward(adjacency.clone()).unwrap();
                let loss = model.gcn.loss(&out, adjacency.clone()).unwrap();
                slot = Some(step(model, &mut optim, loss, &dev));
            })
        });
        // … and STACK.md's prototype shape: one graph, 40 nodes, dim 128,
        // 5 iterations.
        let n = 40;
        let mut config = NtgConfig::for_domain(n, EncoderConfig::state(26));
        config.gcn = GraphCompletionConfig::new(n)
            .with_hidden(128)
            .with_mlp_hidden(128)
            .with_iterations(5);
        config.edge.gcn_dim = 128;
        let path: Vec<ActionId> = (0..30)
            .map(|_| ActionId::new(rng.random_range(2..n)))
            .collect();
        let graph = Ctg::from_path(n, &path).unwrap();
        let adjacency = adjacency_tensor(&[&graph], n, &dev).unwrap();
        let mut slot = Some(NtgModel::new(config, &dev).unwrap());
        let mut optim = AdamConfig::new().init();
        group.bench_function(format!("{backend}/gcn_40x128x5"), |b| {
            b.iter(|| {
                let model = slot.take().unwrap();
                let out = model.gcn.forward(adjacency.clone()).unwrap();
                let loss = model.gcn.loss(&out, adjacency.clone()).unwrap();
                slot = Some(step(model, &mut optim, loss, &dev));
            })
        });
    }
    group.finish();
}

fn policy_steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("policy_step");
    group
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for backend in backends() {
        let dev = backend.device().expect("backend");
        for (enc_name, enc) in encoders() {
            let config = NtgConfig::for_domain(N, enc);
            let d = config.obs_dim();
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let model = NtgModel::new(config, &dev).unwrap();
            let path = random_ids(&mut rng, 16, 2);
            let policy = NtgPolicy::from_actions(&model, &path).unwrap();
            // Two observations in turn, so the encoding cache never hits.
            let obs = [random(&mut rng, d), random(&mut rng, d)];
            let mut i = 0;
            group.bench_function(format!("{backend}/{enc_name}/policy_step"), |b| {
                b.iter(|| {
                    i += 1;
                    black_box(policy.action_distribution(&obs[i % 2]).unwrap())
                })
            });
            // Building a policy from a 17-frame demo (interpreter, GCN).
            let demo: Vec<Vec<f32>> = (0..17).map(|_| random(&mut rng, d)).collect();
            let vocab = ctg_graph::Vocabulary::new((2..N).map(|i| format!("a{i}"))).unwrap();
            group.bench_function(format!("{backend}/{enc_name}/policy_from_demo"), |b| {
                b.iter(|| black_box(NtgPolicy::from_demo(&model, &demo, &vocab).unwrap()))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, train_steps, policy_steps);
criterion_main!(benches);
