//! The burn side of `cargo xtask bench`: times the NTG networks on the
//! same synthetic batches as the PyTorch twin's `--bench`
//! (`crates/ntg-model/benches/pytorch/twin.py`), and prints one JSON line
//! per row with the median milliseconds.
//!
//! ```text
//! RAYON_NUM_THREADS=2 cargo bench -p ntg-model --bench twin_bench -- [--rows all|ROW,ROW] [--repeats 20] [--warmup 3]
//! ```
//!
//! Rows (the names the twin uses too):
//!
//! - `state_step`: one training step (forward, backward, Adam with lr 3e-3)
//!   of the whole model, block stacking's recommended recipe on state input,
//!   its losses assembled as in `twin_export` (interpreter + localizer +
//!   GCN + soft-edge edge classifier) on 32 demos;
//! - `state_step_2_shards`: the same step data-parallel, as `ntg train
//!   --shards 2` takes it: demos 0–15 and 16–31 each on their own thread
//!   ([`ntg_model::sharded_gradients`]), losses weighted by half, gradients
//!   summed, one Adam step (the twin has no such row: its `state_step`
//!   uses its threads inside each operation);
//! - `frame_step`: one stage A step (`FrameStageNet` at the trainer's
//!   default settings: 3×3 convolutions, no decoder) on 64 frames of
//!   3×64×64;
//! - `frame_step_2_shards`: the same step as stage A of `ntg train --obs
//!   vid` takes it (2 shards by default): frames 0–31 and 32–63 each on
//!   their own thread, losses weighted by half, one Adam step;
//! - `interpreter_step`: the demo interpreter alone on the same 32 demos;
//! - `gcn_step`: the GCN alone on the same 32 graphs;
//! - `data_parallel` (not in `all`; the twin has no such row): the
//!   `state_step` on a rayon pool of 1 thread and the
//!   `state_step_2_shards` step on a pool of 2, alternated step by step
//!   in one process, so that both see the same machine (this VM's speed
//!   drifts by 15% and more between runs a minute apart). As in `ntg`
//!   training on the whole machine, the pools' threads are pinned to cores
//!   and the Adam step is a `ParallelOptimizer` of one part per thread
//!   (both arms pinned, so the ratio is the shards' and the optimizer's,
//!   not the pinning's). Prints both
//!   medians and the speedup: the median over pairs of (1-thread time /
//!   2-shard time), samples per second of the 2-shard step over the
//!   1-thread one at the same batch;
//! - `part_parallel` (not in `all`; an experiment): as `data_parallel`,
//!   but the 2-thread step splits the work instead of the batch: the demo
//!   interpreter and node localizer on one thread, the GCN and edge
//!   classifier on the other, each over the whole batch (the state step's
//!   two halves share only the node embeddings);
//! - `policy_step`: one executor decision at rollout (inference): encode
//!   one observation row, localize it, classify the edges of every node
//!   (soft edges), combine them into π(·|o) (`NtgPolicy::action_distribution`,
//!   two observations in turn so its cache never hits). Repeated
//!   `max(10 × repeats, 100)` times.
//!
//! The batches are deterministic, not drawn from a random generator, so
//! that the twin builds exactly the same ones: demo `b` (of 32) makes
//! `6 + b mod 3` moves (12, 14 or 16 actions, one state row per CTG node
//! visited), move `k` picks cube `(b + 3k) mod 8` and places it on cube
//! `(b + 5k + 1) mod 8`; value `i` of row `t` of demo `b` is
//! `-0.4 + 0.8 u((64 b + t) 64 + i)`, where `u(k) = (k × 2654435761 mod
//! 2³²) / 2³²`. The GCN completes the path of demo `b xor 1` into the union
//! of both demos' paths. Stage A's frame `f` (of 64) has pixel value
//! `u(10⁹ + 12288 f + i)`, label `2 + f mod 16`, next action `2 + (f + 1)
//! mod 16`, and successors `a` where `(7 f + 3 a) mod 10 < 3` besides the
//! next action.
//!
//! Each row: `--warmup` untimed calls, then `--repeats` timed ones; the
//! JSON line has the median and minimum milliseconds, the repeats, the
//! threads (`RAYON_NUM_THREADS`, which sizes the rayon pool burn's `flex`
//! backend computes on) and a `shape` string the twin prints identically.

use std::error::Error;

/// The allocator of the `ntg` binary (see its `main.rs`).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;
use std::time::Instant;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bool, Device, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg, Vocabulary};
use ntg_model::{
    DemoBatch, EncoderConfig, FrameStageConfig, NtgModel, NtgPolicy, ParallelOptimizer,
    SOFT_EDGE_FLOOR, adjacency_tensor, ids_tensor, rows_tensor, successor_mask,
};
use serde_json::json;

#[path = "../examples/twin_export.rs"]
#[allow(dead_code)] // the example's `main` and export code
mod twin_export;

use twin_export::{MODEL_SEED, NUM_NODES, NUM_OBJECTS, STATE_DIM, recommended_config};

/// Demos in the batch of the state rows.
const BATCH: usize = 32;
/// Frames in a stage A step (the trainer's default batch).
const FRAMES: usize = 64;
/// Values of one 3×64×64 frame.
const FRAME_DIM: usize = 3 * 64 * 64;
/// Adam's learning rate (the twin's).
const LR: f64 = 3e-3;
/// Every row, in the table's order.
const ROWS: [&str; 7] = [
    "state_step",
    "state_step_2_shards",
    "frame_step",
    "frame_step_2_shards",
    "interpreter_step",
    "gcn_step",
    "policy_step",
];

/// `(k × 2654435761 mod 2³²) / 2³²`, in [0, 1).
fn unit(k: u64) -> f64 {
    (k.wrapping_mul(2_654_435_761) & 0xffff_ffff) as f64 / 4_294_967_296.0
}

/// The actions of demo `b`.
fn demo_actions(b: usize) -> Vec<ActionId> {
    let moves = 6 + b % 3;
    (0..moves)
        .flat_map(|k| {
            [
                ActionId::new(2 + (b + 3 * k) % NUM_OBJECTS),
                ActionId::new(2 + NUM_OBJECTS + (b + 5 * k + 1) % NUM_OBJECTS),
            ]
        })
        .collect()
}

/// The `actions + 1` state rows of demo `b`.
fn demo_rows(b: usize, actions: usize) -> Vec<Vec<f32>> {
    (0..=actions)
        .map(|t| {
            (0..STATE_DIM)
                .map(|i| (-0.4 + 0.8 * unit(((64 * b + t) * 64 + i) as u64)) as f32)
                .collect()
        })
        .collect()
}

/// Demos `range` of the 32: actions and state rows.
fn demos(range: std::ops::Range<usize>) -> Vec<(Vec<ActionId>, Vec<Vec<f32>>)> {
    range
        .map(|b| {
            let actions = demo_actions(b);
            let rows = demo_rows(b, actions.len());
            (actions, rows)
        })
        .collect()
}

/// Every tensor of one state training step (built once, as the twin does)
/// on demos `range` of the 32 (the GCN pairs demo `b` with `b xor 1`, so a
/// range of even length starting at an even demo is closed under it).
struct StateBatch {
    demo: DemoBatch,
    gcn_input: Tensor<3>,
    gcn_target: Tensor<3>,
    obs: Tensor<2>,
    nodes: Tensor<1, Int>,
    next: Tensor<1, Int>,
    row_demo: Tensor<1, Int>,
    edge_mask: Tensor<2, Bool>,
    shape: String,
}

impl StateBatch {
    fn new(range: std::ops::Range<usize>, device: &Device) -> Result<Self, Box<dyn Error>> {
        let n = NUM_NODES;
        let batch = range.len();
        let demos = demos(range);
        let pairs: Vec<(&[Vec<f32>], &[ActionId])> = demos
            .iter()
            .map(|(a, r)| (r.as_slice(), a.as_slice()))
            .collect();
        let demo = DemoBatch::new(&pairs, STATE_DIM, n, device)?;
        let partner = |b: usize| b ^ 1;
        let inputs: Vec<Ctg> = (0..batch)
            .map(|b| Ctg::from_path(n, &demos[partner(b)].0))
            .collect::<Result<_, _>>()?;
        let targets: Vec<Ctg> = (0..batch)
            .map(|b| Ctg::from_paths(n, [demos[b].0.as_slice(), demos[partner(b)].0.as_slice()]))
            .collect::<Result<_, _>>()?;
        let gcn_input = adjacency_tensor(&inputs.iter().collect::<Vec<_>>(), n, device)?;
        let gcn_target = adjacency_tensor(&targets.iter().collect::<Vec<_>>(), n, device)?;

        let (mut obs, mut nodes, mut nexts, mut row_demo) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (b, (actions, rows)) in demos.iter().enumerate() {
            let labels = std::iter::once(Vocabulary::START).chain(actions.iter().copied());
            let following = actions.iter().copied().chain([Vocabulary::END]);
            for ((row, node), next) in rows.iter().zip(labels).zip(following) {
                obs.push(row.clone());
                nodes.push(node);
                nexts.push(next);
                row_demo.push(b as i64);
            }
        }
        let r = obs.len();
        let full = Ctg::fully_connected(n);
        let edge_mask = successor_mask(&vec![&full; r], &nodes, Some(&nexts), n, device)?;
        let [_, frames, _] = demo.frames.dims();
        let [_, tokens] = demo.targets.dims();
        Ok(StateBatch {
            shape: format!("batch {batch}, rows {r}, frames {frames}, tokens {tokens}"),
            demo,
            gcn_input,
            gcn_target,
            obs: rows_tensor(&obs, STATE_DIM, device)?,
            nodes: ids_tensor(&nodes, n, device)?,
            next: ids_tensor(&nexts, n, device)?,
            row_demo: Tensor::from_data(TensorData::new(row_demo, [r]), device),
            edge_mask,
        })
    }
}

/// The total loss of one training step of `model` on `x`, assembled as
/// `twin_export` (and the trainer's `NtgStep`) does with the recommended
/// recipe.
fn state_loss(model: &NtgModel, x: &StateBatch) -> ntg_model::Result<Tensor<1>> {
    Ok(state_loss_part(model, x, 0)? + state_loss_part(model, x, 1)?)
}

/// One of the state step's two independent halves of work: part 0 the
/// demo interpreter's and the node localizer's losses, part 1 the GCN's
/// and the edge classifier's (which reads the GCN's detached output). Their
/// sum is [`state_loss`]; they share only the localizer's node embeddings
/// (which the edge classifier also reads), whose gradients add up.
fn state_loss_part(model: &NtgModel, x: &StateBatch, part: usize) -> ntg_model::Result<Tensor<1>> {
    if part == 0 {
        let interp = model.interpreter.loss(&x.demo)?;
        let loc_logits = model.localizer.forward(x.obs.clone())?;
        let loc = model.localizer.loss(loc_logits, x.nodes.clone())?;
        return Ok(interp.loss + loc.loss);
    }
    let n = NUM_NODES;
    let gcn_out = model.gcn.forward(x.gcn_input.clone())?;
    let gcn = model.gcn.loss(&gcn_out, x.gcn_target.clone())?;

    let r = x.obs.dims()[0];
    let soft = gcn_out
        .adjacency
        .clone()
        .detach()
        .max_pair(x.gcn_input.clone());
    let row_ne_gcn = gcn_out.embeddings.detach().select(0, x.row_demo.clone());
    let logits = model.edges.forward(
        x.obs.clone(),
        x.nodes.clone(),
        row_ne_gcn,
        model.localizer.node_embeddings(),
        x.edge_mask.clone(),
        None,
    )?;
    let gather = x.nodes.clone().reshape([r, 1, 1]).expand([r, 1, n]);
    let c_rows = soft
        .select(0, x.row_demo.clone())
        .gather(1, gather)
        .reshape([r, n]);
    let logits = logits + c_rows.clamp(SOFT_EDGE_FLOOR, 1.0).log();
    let edge = model.edges.loss(logits, x.next.clone())?;
    Ok(gcn + edge.loss)
}

/// Median and minimum of `repeats` timed calls of `f` (in ms), after
/// `warmup` untimed ones.
fn time<F: FnMut() -> Result<(), Box<dyn Error>>>(
    warmup: usize,
    repeats: usize,
    mut f: F,
) -> Result<(f64, f64), Box<dyn Error>> {
    for _ in 0..warmup {
        f()?;
    }
    let mut times = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        f()?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let mid = times.len() / 2;
    let median = if times.len() % 2 == 1 {
        times[mid]
    } else {
        0.5 * (times[mid - 1] + times[mid])
    };
    Ok((median, times[0]))
}

/// One Adam step of `module` on `loss`.
fn adam_step<M: Module>(module: M, optim: &mut ModuleOptimizer, loss: Tensor<1>) -> M {
    let grads = GradientsParams::from_grads(loss.backward(), &module);
    optim.step(LR, module, grads)
}

/// [`adam_step`] with the trainer's optimizer.
fn parallel_adam_step<M: Module>(module: M, optim: &mut ParallelOptimizer, loss: Tensor<1>) -> M {
    let grads = GradientsParams::from_grads(loss.backward(), &module);
    optim.step(LR, module, grads)
}

/// Times `row`; returns `(median ms, min ms, repeats, shape)`.
fn bench_row(
    row: &str,
    warmup: usize,
    repeats: usize,
) -> Result<(f64, f64, usize, String), Box<dyn Error>> {
    let plain = ntg_model::cpu_device();
    let device = plain.clone().autodiff();
    let config = recommended_config(MODEL_SEED);
    let sync = |d: &Device| d.sync().map_err(|e| format!("device sync: {e:?}"));
    match row {
        "state_step" | "interpreter_step" | "gcn_step" => {
            let x = StateBatch::new(0..BATCH, &device)?;
            let mut slot = Some(NtgModel::new(config, &device)?);
            let mut optim: ModuleOptimizer = AdamConfig::new().init();
            let (median, min) = time(warmup, repeats, || {
                let mut model = slot.take().ok_or("model")?;
                match row {
                    "state_step" => {
                        let loss = state_loss(&model, &x)?;
                        model = adam_step(model, &mut optim, loss);
                    }
                    "interpreter_step" => {
                        let loss = model.interpreter.loss(&x.demo)?.loss;
                        model.interpreter = adam_step(model.interpreter, &mut optim, loss);
                    }
                    _ => {
                        let out = model.gcn.forward(x.gcn_input.clone())?;
                        let loss = model.gcn.loss(&out, x.gcn_target.clone())?;
                        model.gcn = adam_step(model.gcn, &mut optim, loss);
                    }
                }
                sync(&device)?;
                slot = Some(model);
                Ok(())
            })?;
            let shape = if row == "gcn_step" {
                format!("graphs {BATCH}, nodes {NUM_NODES}")
            } else {
                x.shape.clone()
            };
            Ok((median, min, repeats, shape))
        }
        "state_step_2_shards" => {
            // `ntg train --shards 2`: each half of the batch on its own
            // thread (`ntg_model::sharded_gradients`, as the trainer's epoch
            // loop calls it), losses weighted by half, one Adam step.
            let halves = [
                StateBatch::new(0..BATCH / 2, &device)?,
                StateBatch::new(BATCH / 2..BATCH, &device)?,
            ];
            let shape = StateBatch::new(0..BATCH, &device)?.shape;
            let mut slot = Some(NtgModel::new(config, &device)?);
            let mut optim: ModuleOptimizer = AdamConfig::new().init();
            let (median, min) = time(warmup, repeats, || {
                let model = slot.take().ok_or("model")?;
                let (grads, _) = ntg_model::sharded_gradients(&model, 2, |m, i| {
                    Ok::<_, ntg_model::ModelError>((state_loss(m, &halves[i])?.mul_scalar(0.5), ()))
                })?;
                slot = Some(optim.step(LR, model, grads));
                sync(&device)?;
                Ok(())
            })?;
            Ok((median, min, repeats, shape))
        }
        "frame_step" | "frame_step_2_shards" => {
            let n = NUM_NODES;
            let pixels: Vec<f32> = (0..FRAMES * FRAME_DIM)
                .map(|i| unit(1_000_000_000 + i as u64) as f32)
                .collect();
            let frames =
                Tensor::<2>::from_data(TensorData::new(pixels, [FRAMES, FRAME_DIM]), &device);
            let labels: Vec<i64> = (0..FRAMES).map(|f| (2 + f % 16) as i64).collect();
            let next: Vec<i64> = (0..FRAMES).map(|f| (2 + (f + 1) % 16) as i64).collect();
            let successors: Vec<f32> = (0..FRAMES * n)
                .map(|k| {
                    let (f, a) = (k / n, k % n);
                    if a as i64 == next[f] || (7 * f + 3 * a) % 10 < 3 {
                        1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            let successors =
                Tensor::<2>::from_data(TensorData::new(successors, [FRAMES, n]), &device)
                    .greater_elem(0.5);
            let labels = Tensor::<1, Int>::from_data(TensorData::new(labels, [FRAMES]), &device);
            let next = Tensor::<1, Int>::from_data(TensorData::new(next, [FRAMES]), &device);
            // `ntg_trainer::video::EncoderStage::default().net_config(18, 0)`.
            let net = FrameStageConfig::new(n, EncoderConfig::frame())
                .with_seed(0)
                .init(&device)?;
            let mut slot = Some(net);
            let mut optim: ModuleOptimizer = AdamConfig::new().init();
            // The 2-shard row splits the 64 frames into halves, as stage A
            // of `ntg train --shards 2` does.
            let half = FRAMES / 2;
            let halves: Vec<_> = (0..2)
                .map(|i| {
                    (
                        frames.clone().narrow(0, i * half, half),
                        labels.clone().narrow(0, i * half, half),
                        next.clone().narrow(0, i * half, half),
                        successors.clone().narrow(0, i * half, half),
                    )
                })
                .collect();
            let (median, min) = time(warmup, repeats, || {
                let net = slot.take().ok_or("net")?;
                if row == "frame_step" {
                    let loss = net
                        .loss(
                            frames.clone(),
                            labels.clone(),
                            next.clone(),
                            successors.clone(),
                        )?
                        .loss;
                    slot = Some(adam_step(net, &mut optim, loss));
                } else {
                    let (grads, _) = ntg_model::sharded_gradients(&net, 2, |m, i| {
                        let (f, l, x, s) = &halves[i];
                        let loss = m.loss(f.clone(), l.clone(), x.clone(), s.clone())?.loss;
                        Ok::<_, ntg_model::ModelError>((loss.mul_scalar(0.5), ()))
                    })?;
                    slot = Some(optim.step(LR, net, grads));
                }
                sync(&device)?;
                Ok(())
            })?;
            Ok((median, min, repeats, format!("frames {FRAMES}, 3x64x64")))
        }
        "policy_step" => {
            let model = NtgModel::new(config, &plain)?;
            let actions = demo_actions(0);
            let rows = demo_rows(0, actions.len());
            let policy = NtgPolicy::from_actions(&model, &actions)?;
            let repeats = (10 * repeats).max(100);
            let mut i = 0;
            let (median, min) = time(warmup.max(2), repeats, || {
                i += 1;
                let d = policy.action_distribution(&rows[i % 2])?;
                std::hint::black_box(d);
                Ok(())
            })?;
            Ok((
                median,
                min,
                repeats,
                format!("obs 1x{STATE_DIM}, nodes {NUM_NODES}"),
            ))
        }
        other => Err(format!("unknown row {other:?} (rows: {})", ROWS.join(", ")).into()),
    }
}

/// The `data_parallel` row: `(1-thread median ms, 2-shard median ms,
/// median of the paired ratios)` over `repeats` alternating pairs.
fn data_parallel(
    warmup: usize,
    repeats: usize,
    by_parts: bool,
) -> Result<(f64, f64, f64), Box<dyn Error>> {
    let device = ntg_model::cpu_device().autodiff();
    let config = recommended_config(MODEL_SEED);
    let whole = StateBatch::new(0..BATCH, &device)?;
    let halves = [
        StateBatch::new(0..BATCH / 2, &device)?,
        StateBatch::new(BATCH / 2..BATCH, &device)?,
    ];
    // Both arms on pools whose threads are pinned to cores (as `ntg`'s pool
    // is when it takes the whole machine: `ntg_model::init_thread_pool`).
    let pool = |threads| ntg_model::pinned_pool_builder(threads).build();
    let (one, two) = (pool(1)?, pool(2)?);
    let (mut single, mut sharded) = (
        Some(NtgModel::new(config.clone(), &device)?),
        Some(NtgModel::new(config, &device)?),
    );
    // The trainer's optimizer: Adam, split over the pool's threads.
    let mut optim_single = ParallelOptimizer::new(1, || AdamConfig::new().init());
    let mut optim_sharded = ParallelOptimizer::new(2, || AdamConfig::new().init());
    let sync = |d: &Device| d.sync().map_err(|e| format!("device sync: {e:?}"));
    let mut step_single = || -> Result<f64, Box<dyn Error>> {
        let start = Instant::now();
        one.install(|| -> Result<(), String> {
            let model = single.take().ok_or("model")?;
            let loss = state_loss(&model, &whole).map_err(|e| e.to_string())?;
            single = Some(parallel_adam_step(model, &mut optim_single, loss));
            sync(&device)?;
            Ok(())
        })?;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    };
    let mut step_sharded = || -> Result<f64, Box<dyn Error>> {
        let start = Instant::now();
        two.install(|| -> Result<(), String> {
            let model = sharded.take().ok_or("model")?;
            let (grads, _) = ntg_model::sharded_gradients(&model, 2, |m, i| {
                let loss = if by_parts {
                    state_loss_part(m, &whole, i)?
                } else {
                    state_loss(m, &halves[i])?.mul_scalar(0.5)
                };
                Ok::<_, ntg_model::ModelError>((loss, ()))
            })
            .map_err(|e| e.to_string())?;
            sharded = Some(optim_sharded.step(LR, model, grads));
            sync(&device)?;
            Ok(())
        })?;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    };
    for _ in 0..warmup {
        step_single()?;
        step_sharded()?;
    }
    let (mut ones, mut twos, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats.max(1) {
        let (a, b) = (step_single()?, step_sharded()?);
        ones.push(a);
        twos.push(b);
        ratios.push(a / b);
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let mid = v.len() / 2;
        if v.len() % 2 == 1 {
            v[mid]
        } else {
            0.5 * (v[mid - 1] + v[mid])
        }
    };
    Ok((median(ones), median(twos), median(ratios)))
}

fn main() -> Result<(), Box<dyn Error>> {
    let mut rows: Vec<String> = ROWS.iter().map(|s| s.to_string()).collect();
    let (mut repeats, mut warmup) = (20usize, 3usize);
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--rows" => {
                let v = value()?;
                if v != "all" {
                    rows = v.split(',').map(str::to_owned).collect();
                }
            }
            "--repeats" => repeats = value()?.parse()?,
            "--warmup" => warmup = value()?.parse()?,
            // What `cargo bench` passes every bench target.
            "--bench" => {}
            "-h" | "--help" => {
                println!(
                    "usage: twin_bench [--rows all|ROW,ROW] [--repeats N] [--warmup N]; rows: {}, data_parallel, part_parallel",
                    ROWS.join(", ")
                );
                return Ok(());
            }
            other => return Err(format!("unknown argument {other:?}").into()),
        }
    }
    let threads = std::env::var("RAYON_NUM_THREADS").ok();
    for row in &rows {
        if row == "data_parallel" || row == "part_parallel" {
            let (one, two, speedup) = data_parallel(warmup, repeats, row == "part_parallel")?;
            println!(
                "{}",
                json!({
                    "row": row,
                    "backend": "flex",
                    "one_thread_median_ms": (one * 1e3).round() / 1e3,
                    "two_shards_median_ms": (two * 1e3).round() / 1e3,
                    "speedup": (speedup * 1e3).round() / 1e3,
                    "repeats": repeats,
                })
            );
            continue;
        }
        let (median, min, repeats, shape) = bench_row(row, warmup, repeats)?;
        println!(
            "{}",
            json!({
                "row": row,
                "backend": "flex",
                "median_ms": (median * 1e3).round() / 1e3,
                "min_ms": (min * 1e3).round() / 1e3,
                "repeats": repeats,
                "threads": threads,
                "shape": shape,
            })
        );
    }
    Ok(())
}
