//! Learning tests: each network learns something real from small synthetic
//! data with a fixed seed, and is scored on held-out data it never saw.
//!
//! Run on `flex` by default, and on burn-ndarray with `--features ndarray`
//! or `NTG_TEST_BACKEND=ndarray` (tests always link it: see the
//! dev-dependencies).

use std::collections::HashSet;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Device;
use ctg_graph::{ActionId, Ctg, Demonstration, Vocabulary};
use ntg_model::*;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// flex, or burn-ndarray when `NTG_TEST_BACKEND=ndarray` in a build with
/// the `ndarray` feature (see `src/tests.rs`).
fn device() -> Device {
    match std::env::var("NTG_TEST_BACKEND").as_deref() {
        Ok("ndarray") => BackendKind::NdArray.device().expect(
            "NTG_TEST_BACKEND=ndarray needs the `ndarray` feature: cargo test -p ntg-model --features ndarray",
        ),
        Ok("flex") | Err(_) => BackendKind::Flex.device().unwrap(),
        Ok(other) => panic!("NTG_TEST_BACKEND={other}: expected flex or ndarray"),
    }
}

fn noisy_one_hot(rng: &mut ChaCha8Rng, dim: usize, hot: &[usize], noise: f32) -> Vec<f32> {
    let mut v: Vec<f32> = (0..dim).map(|_| rng.random_range(-noise..noise)).collect();
    for &i in hot {
        v[i] += 1.0;
    }
    v
}

/// The demo interpreter transcribes synthetic demonstrations (random
/// action sequences rendered as noisy one-hot frames, one per CTG node
/// visited) and decodes held-out sequences greedily with ≥ 95% token
/// accuracy (position by position, `<end>` included; a missing or extra
/// token counts as wrong).
#[test]
fn demo_interpreter_transcribes_held_out_demos() {
    const ACTIONS: usize = 8;
    const N: usize = ACTIONS + 2;
    const D: usize = N + 4; // four distractor dimensions of pure noise
    let dev = device();
    let ad = dev.clone().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(20);
    let vocab = Vocabulary::new((0..ACTIONS).map(|i| format!("a{i}"))).unwrap();
    let make_demo = |rng: &mut ChaCha8Rng| {
        let len = rng.random_range(2..=8);
        let actions: Vec<ActionId> = (0..len)
            .map(|_| ActionId::new(rng.random_range(2..N)))
            .collect();
        let obs = std::iter::once(Vocabulary::START)
            .chain(actions.iter().copied())
            .map(|node| noisy_one_hot(rng, D, &[node.index()], 0.3))
            .collect();
        Demonstration::new(obs, actions, &vocab).unwrap()
    };
    let train: Vec<_> = (0..512).map(|_| make_demo(&mut rng)).collect();
    let seen: HashSet<Vec<ActionId>> = train.iter().map(|d| d.actions().to_vec()).collect();
    let mut test = Vec::new();
    while test.len() < 200 {
        let d = make_demo(&mut rng);
        if !seen.contains(d.actions()) {
            test.push(d);
        }
    }

    let enc = EncoderConfig::State(StateEncoderConfig::new(D).with_hidden(64).with_out_dim(64));
    let config = DemoInterpreterConfig::new(N, enc)
        .with_hidden(64)
        .with_token_embed(32)
        .with_max_decode_len(16);
    let mut model = config.init(20, &ad).unwrap();
    let mut optim = AdamConfig::new().init();
    let mut order: Vec<usize> = (0..train.len()).collect();
    let mut last_train_acc = 0.0;
    for step in 0..400 {
        if step % (train.len() / 32) == 0 {
            order.shuffle(&mut rng);
        }
        let start = (step % (train.len() / 32)) * 32;
        let batch: Vec<&Demonstration<Vec<f32>>> = order[start..start + 32]
            .iter()
            .map(|&i| &train[i])
            .collect();
        let batch = DemoBatch::from_demonstrations(&batch, D, N, &ad).unwrap();
        let out = model.loss(&batch).unwrap();
        last_train_acc = out.accuracy;
        let grads = GradientsParams::from_grads(out.loss.backward(), &model);
        model = optim.step(3e-3, model, grads);
    }

    let model = model.valid();
    let obs: Vec<&[Vec<f32>]> = test.iter().map(|d| d.observations()).collect();
    let decoded = model.decode_batch(&obs).unwrap();
    let (mut correct, mut total) = (0usize, 0usize);
    for (d, got) in test.iter().zip(&decoded) {
        let want: Vec<ActionId> = d.next_actions(); // actions then <end>
        let got: Vec<ActionId> = got.iter().copied().chain([Vocabulary::END]).collect();
        total += want.len().max(got.len());
        correct += want.iter().zip(&got).filter(|(a, b)| a == b).count();
    }
    let accuracy = correct as f32 / total as f32;
    println!(
        "demo interpreter: teacher-forced train accuracy {last_train_acc:.3}, \
         greedy held-out token accuracy {accuracy:.3} ({correct}/{total})"
    );
    assert!(accuracy >= 0.95, "held-out token accuracy {accuracy}");
    let _ = dev;
}

/// Ground truth for the GCN test: the path plus every path obtained by
/// swapping two consecutive interchangeable actions.
fn swap_closure(path: &[ActionId], n: usize, interchangeable: impl Fn(ActionId) -> bool) -> Ctg {
    let mut g = Ctg::from_path(n, path).unwrap();
    for i in 0..path.len().saturating_sub(1) {
        if interchangeable(path[i]) && interchangeable(path[i + 1]) {
            let mut swapped = path.to_vec();
            swapped.swap(i, i + 1);
            g.add_path(&swapped).unwrap();
        }
    }
    g
}

/// The GCN learns "any two consecutive interchangeable actions may swap":
/// from a demo path it adds the edges of the swapped orders, with edge
/// F1 ≥ 0.9 on held-out graphs, and ≥ 0.8 F1 on the added edges alone
/// (copying the input scores 0 there).
#[test]
fn gcn_learns_to_add_swap_edges() {
    const ACTIONS: usize = 10;
    const N: usize = ACTIONS + 2;
    let interchangeable = |a: ActionId| (2..7).contains(&a.index()); // 5 of the 10 actions
    let dev = device();
    let ad = dev.clone().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(30);
    let make = |rng: &mut ChaCha8Rng| {
        let mut pool: Vec<ActionId> = (2..N).map(ActionId::new).collect();
        pool.shuffle(rng);
        let len = rng.random_range(4..=8);
        let path = pool[..len].to_vec();
        let initial = Ctg::from_path(N, &path).unwrap();
        let target = swap_closure(&path, N, interchangeable);
        (path, initial, target)
    };
    let train: Vec<_> = (0..1024).map(|_| make(&mut rng)).collect();
    let seen: HashSet<Vec<ActionId>> = train.iter().map(|t| t.0.clone()).collect();
    let mut test = Vec::new();
    while test.len() < 200 {
        let t = make(&mut rng);
        if !seen.contains(&t.0) {
            test.push(t);
        }
    }
    let added_in_test: usize = test.iter().map(|t| t.2.num_edges() - t.1.num_edges()).sum();
    assert!(
        added_in_test > 100,
        "the rule must add edges to test graphs"
    );

    let config = GraphCompletionConfig::new(N)
        .with_hidden(64)
        .with_mlp_hidden(32)
        .with_iterations(3)
        .with_pos_weight(3.0);
    let mut gcn = config.init(30, &ad).unwrap();
    let mut optim = AdamConfig::new().init();
    for step in 0..600 {
        let start = (step * 32) % train.len();
        let batch = &train[start..start + 32];
        let initial: Vec<&Ctg> = batch.iter().map(|t| &t.1).collect();
        let target: Vec<&Ctg> = batch.iter().map(|t| &t.2).collect();
        let out = gcn
            .forward(adjacency_tensor(&initial, N, &ad).unwrap())
            .unwrap();
        let loss = gcn
            .loss(&out, adjacency_tensor(&target, N, &ad).unwrap())
            .unwrap();
        let grads = GradientsParams::from_grads(loss.backward(), &gcn);
        gcn = optim.step(3e-3, gcn, grads);
    }

    let gcn = gcn.valid();
    let initial: Vec<&Ctg> = test.iter().map(|t| &t.1).collect();
    let target: Vec<&Ctg> = test.iter().map(|t| &t.2).collect();
    let out = gcn
        .forward(adjacency_tensor(&initial, N, &dev).unwrap())
        .unwrap();
    let predicted = nn::to_vec(out.adjacency).unwrap();
    let mut all = EdgeCounts::default();
    let mut added = EdgeCounts::default();
    let mut copy = EdgeCounts::default();
    for (b, (init, tgt)) in initial.iter().zip(&target).enumerate() {
        let p = &predicted[b * N * N..(b + 1) * N * N];
        all += EdgeCounts::count(p, tgt.adjacency(), 0.5).unwrap();
        copy += EdgeCounts::count(init.adjacency(), tgt.adjacency(), 0.5).unwrap();
        // Only the entries the input lacks: can the net add the right edges?
        let absent: Vec<usize> = (0..N * N).filter(|&i| init.adjacency()[i] == 0.0).collect();
        let p_abs: Vec<f32> = absent.iter().map(|&i| p[i]).collect();
        let t_abs: Vec<f32> = absent.iter().map(|&i| tgt.adjacency()[i]).collect();
        added += EdgeCounts::count(&p_abs, &t_abs, 0.5).unwrap();
    }
    println!(
        "gcn: held-out edge F1 {:.3} (copying the input: {:.3}); added edges F1 {:.3} \
         (precision {:.3}, recall {:.3})",
        all.f1(),
        copy.f1(),
        added.f1(),
        added.precision(),
        added.recall()
    );
    assert!(all.f1() >= 0.9, "edge F1 {}", all.f1());
    assert!(added.f1() >= 0.8, "added-edge F1 {}", added.f1());
}

/// One hub-and-spokes task: visit the hub, do the lowest undone spoke,
/// return to the hub, …: `h s1 h s2 … h sm` (spokes ascending). The hub is
/// revisited, and which edge leaves it depends on what has been done.
fn hub_task(rng: &mut ChaCha8Rng, n: usize) -> Vec<ActionId> {
    let mut pool: Vec<usize> = (2..n).collect();
    pool.shuffle(rng);
    let m = rng.random_range(2..=4);
    let hub = pool[0];
    let mut spokes = pool[1..=m].to_vec();
    spokes.sort_unstable();
    spokes
        .into_iter()
        .flat_map(|s| [ActionId::new(hub), ActionId::new(s)])
        .collect()
}

/// Observation before each step of `path`: a noisy one-hot of the current
/// node (the last action, `<start>` first) next to noisy "done" bits of
/// every action taken so far.
fn hub_observations(rng: &mut ChaCha8Rng, path: &[ActionId], n: usize) -> Vec<Vec<f32>> {
    let mut done: Vec<usize> = Vec::new();
    let mut node = Vocabulary::START.index();
    let mut out = Vec::new();
    for step in 0..=path.len() {
        let mut hot = vec![node];
        hot.extend(done.iter().map(|&d| n + d));
        out.push(noisy_one_hot(rng, 2 * n, &hot, 0.2));
        if let Some(a) = path.get(step) {
            node = a.index();
            if !done.contains(&node) {
                done.push(node);
            }
        }
    }
    out
}

/// The node localizer and edge classifier, trained together, replay
/// held-out paths through graphs with a revisited node (the hub) whose
/// right outgoing edge depends on the observation: ≥ 95% of steps pick the
/// demonstrated action through the full policy (π(a|o) ∝ Σ_n ε ℓ on the
/// path's CTG).
#[test]
fn localizer_and_edge_classifier_replay_paths_with_revisits() {
    const ACTIONS: usize = 10;
    const N: usize = ACTIONS + 2;
    const D: usize = 2 * N;
    let dev = device();
    let ad = dev.clone().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(40);
    let vocab = Vocabulary::new((0..ACTIONS).map(|i| format!("a{i}"))).unwrap();
    let make = |rng: &mut ChaCha8Rng| {
        let path = hub_task(rng, N);
        let obs = hub_observations(rng, &path, N);
        Demonstration::new(obs, path, &vocab).unwrap()
    };
    let train: Vec<_> = (0..300).map(|_| make(&mut rng)).collect();
    let seen: HashSet<Vec<ActionId>> = train.iter().map(|d| d.actions().to_vec()).collect();
    let mut test = Vec::new();
    while test.len() < 100 {
        let d = make(&mut rng);
        if !seen.contains(d.actions()) {
            test.push(d);
        }
    }

    // One row per (demo, step): observation, node, next action, graph.
    let graphs: Vec<Ctg> = train
        .iter()
        .map(|d| d.path_graph(&vocab).unwrap())
        .collect();
    let mut rows: Vec<(usize, usize)> = train
        .iter()
        .enumerate()
        .flat_map(|(i, d)| (0..d.observations().len()).map(move |s| (i, s)))
        .collect();

    let enc = EncoderConfig::State(StateEncoderConfig::new(D).with_hidden(64).with_out_dim(32));
    let mut config = NtgConfig::for_domain(N, enc);
    config.gcn.hidden = 16;
    config.edge.gcn_dim = 16;
    config.ablation.gcn = false; // the demo path as is; NE_gcn = N⁰
    config.seed = 40;
    let mut model = NtgModel::new(config, &ad).unwrap();
    let mut optim = AdamConfig::new().init();
    let batch_size = 64;
    let per_epoch = rows.len() / batch_size;
    for step in 0..600 {
        if step % per_epoch == 0 {
            rows.shuffle(&mut rng);
        }
        let batch = &rows[(step % per_epoch) * batch_size..][..batch_size];
        let obs: Vec<&[f32]> = batch
            .iter()
            .map(|&(i, s)| train[i].observations()[s].as_slice())
            .collect();
        let nodes: Vec<ActionId> = batch
            .iter()
            .map(|&(i, s)| train[i].node_labels()[s])
            .collect();
        let next: Vec<ActionId> = batch
            .iter()
            .map(|&(i, s)| train[i].next_actions()[s])
            .collect();
        let batch_graphs: Vec<&Ctg> = batch.iter().map(|&(i, _)| &graphs[i]).collect();

        let obs = rows_tensor(&obs, D, &ad).unwrap();
        let node_ids = ids_tensor(&nodes, N, &ad).unwrap();
        let next_ids = ids_tensor(&next, N, &ad).unwrap();
        let mask = successor_mask(&batch_graphs, &nodes, Some(&next), N, &ad).unwrap();
        let ne_gcn = model.graph_embeddings(&batch_graphs).unwrap();

        let node_logits = model.localizer.forward(obs.clone()).unwrap();
        let loc = model.localizer.loss(node_logits, node_ids.clone()).unwrap();
        let edge_logits = model
            .edges
            .forward(
                obs,
                node_ids,
                ne_gcn,
                model.localizer.node_embeddings(),
                mask,
                None,
            )
            .unwrap();
        let edge = model.edges.loss(edge_logits, next_ids).unwrap();
        let grads = GradientsParams::from_grads((loc.loss + edge.loss).backward(), &model);
        model = optim.step(3e-3, model, grads);
    }

    let model = model.valid();
    let (mut correct, mut total, mut hub_correct, mut hub_total) = (0, 0, 0, 0);
    for d in &test {
        let policy = NtgPolicy::from_actions(&model, d.actions()).unwrap();
        let hub = d.actions()[0];
        for ((obs, next), node) in d
            .observations()
            .iter()
            .zip(d.next_actions())
            .zip(d.node_labels())
        {
            let dist = policy.action_distribution(obs).unwrap();
            let ok = dist.most_likely() == next;
            correct += usize::from(ok);
            total += 1;
            if node == hub {
                hub_correct += usize::from(ok);
                hub_total += 1;
            }
        }
    }
    let accuracy = correct as f32 / total as f32;
    let hub_accuracy = hub_correct as f32 / hub_total as f32;
    println!(
        "executor: held-out replay {accuracy:.3} of {total} steps; \
         at the revisited hub {hub_accuracy:.3} of {hub_total}"
    );
    assert!(accuracy >= 0.95, "replay accuracy {accuracy}");
    assert!(
        hub_accuracy >= 0.9,
        "accuracy at the revisited node {hub_accuracy}"
    );
}
