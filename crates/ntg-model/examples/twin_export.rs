//! Exports one seeded NTG model, one seeded batch and the reference outputs
//! for the PyTorch twin (`crates/ntg-model/benches/pytorch/twin.py`), which
//! rebuilds the four networks in PyTorch, copies the weights and checks
//! that it computes the same outputs, losses and gradients.
//!
//! ```text
//! cargo run --release -p ntg-model --example twin_export -- /tmp/ntg_twin.json
//! python3 crates/ntg-model/benches/pytorch/twin.py /tmp/ntg_twin.json
//! ```
//!
//! The model is block stacking's (18 CTG nodes, 26-value state rows) with
//! the trainer's recommended recipe (`ntg_trainer::Recipe::Recommended`,
//! `ntg_trainer::blocks::new_model`) on state input: the demo interpreter
//! keeps the one-layer state MLP, the node localizer and the edge classifier
//! read the state through 3-layer MLPs that also see the pairwise
//! differences of the 8 cube positions, the edge classifier has a fusion
//! layer of 256, soft edges are on. The losses are assembled as the
//! trainer's `NtgStep` does with that recipe: the GCN completes another
//! demo's path of the same task into the task graph (the union of its
//! demos' paths), the edge classifier reads the GCN's embeddings detached
//! (`detach_gcn_from_edges`) and scores every node of the fully connected
//! graph, each logit raised by `ln C` of the completed graph (detached,
//! the input path's edges at 1, floored at `SOFT_EDGE_FLOOR`), and the
//! total is interpreter + localizer + GCN + edge. (The recipe's object
//! renaming is data augmentation and plays no part here.)
//!
//! The file is one JSON object:
//!
//! - `dims`: the sizes the twin builds its networks with;
//! - `config`: the `NtgConfig`, as saved in checkpoints;
//! - `params` and `grads`: every parameter and the gradient of the total
//!   loss with respect to it, by a stable name (`interpreter.enc_gru.input.weight`,
//!   ...), each `{"shape": [...], "data": [...]}` (row-major);
//! - `inputs`: the batch (float and int tensors in the same form);
//! - `outputs`: each network's outputs, each loss term and the total.
//!
//! Weight layout conventions (the twin converts):
//!
//! - a burn `Linear` stores `weight` as `[in, out]` and computes `x W + b`;
//!   PyTorch's `nn.Linear.weight` is `[out, in]` (`x Wᵀ + b`): transpose;
//! - a `GruCell` (`ntg_model::nn::GruCell`) is two `Linear`s, `input`
//!   `[d_in, 3H]` and `hidden` `[H, 3H]`, whose output columns are the gates
//!   in the order r (reset), z (update), n (new), reset-after
//!   (`n = tanh(W_in x + b_in + r ⊙ (W_hn h + b_hn))`): PyTorch's `GRU` /
//!   `GRUCell` use the same order and convention, so `weight_ih_l0 =
//!   input.weightᵀ`, `bias_ih_l0 = input.bias`, `weight_hh_l0 =
//!   hidden.weightᵀ`, `bias_hh_l0 = hidden.bias`;
//! - embeddings and node-embedding tables (`tokens`, `nodes`) are `[N, E]`
//!   in both.

use std::error::Error;
use std::path::Path;

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::{Device, Gradients, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg, Vocabulary};
use ntg_model::nn::{GruCell, to_vec, to_vec_int};
use ntg_model::{
    DemoBatch, Encoder, EncoderConfig, NtgConfig, NtgModel, SOFT_EDGE_FLOOR, StateEncoderConfig,
    adjacency_tensor, ids_tensor, rows_tensor, successor_mask,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Map, Value, json};

/// CTG nodes of block stacking: `<start>`, `<end>`, pick(A..H), place(A..H).
pub const NUM_NODES: usize = 18;
/// Values per state row: 8 cubes × xyz relative to the gripper, then the
/// gripper's open/closed one-hot.
pub const STATE_DIM: usize = 26;
/// Cubes, whose positions the relational state encoders compare.
pub const NUM_OBJECTS: usize = 8;
/// Hidden layers of the localizer's and edge classifier's state encoders.
pub const STATE_HIDDEN_LAYERS: usize = 3;
/// Width of the edge classifier's fusion layer.
pub const EDGE_FUSION_HIDDEN: usize = 256;
/// Seed of the model's weights.
pub const MODEL_SEED: u64 = 7;
/// Seed of the batch.
pub const BATCH_SEED: u64 = 11;

/// The recommended block-stacking configuration on state input (what
/// `ntg_trainer::blocks::new_model` builds for `Recipe::Recommended`).
pub fn recommended_config(seed: u64) -> NtgConfig {
    let mut config = NtgConfig::for_domain(NUM_NODES, EncoderConfig::state(STATE_DIM));
    let relational = EncoderConfig::State(
        StateEncoderConfig::new(STATE_DIM)
            .with_hidden_layers(STATE_HIDDEN_LAYERS)
            .with_pairwise_objects(NUM_OBJECTS),
    );
    config.localizer.encoder = relational.clone();
    config.edge.encoder = relational;
    config.edge.fusion_hidden = Some(EDGE_FUSION_HIDDEN);
    config.soft_edges = Some(true);
    config.seed = seed;
    config
}

/// One demonstration: its task, its actions and its `K + 1` state rows
/// (one per CTG node visited: before each action, and the final state).
struct Demo {
    task: usize,
    actions: Vec<ActionId>,
    rows: Vec<Vec<f32>>,
}

fn pick(cube: usize) -> ActionId {
    ActionId::new(2 + cube)
}

fn place(cube: usize) -> ActionId {
    ActionId::new(2 + NUM_OBJECTS + cube)
}

/// A demo moving `moves` `(cube, onto)` in order; `retry` repeats the
/// pick of that move (a failed grasp tried again).
fn demo(rng: &mut ChaCha8Rng, task: usize, moves: &[(usize, usize)], retry: Option<usize>) -> Demo {
    let mut actions = Vec::new();
    for (i, &(cube, onto)) in moves.iter().enumerate() {
        actions.push(pick(cube));
        if retry == Some(i) {
            actions.push(pick(cube));
        }
        actions.push(place(onto));
    }
    let mut holding = false;
    let mut rows = Vec::with_capacity(actions.len() + 1);
    for k in 0..=actions.len() {
        let mut row: Vec<f32> = (0..3 * NUM_OBJECTS)
            .map(|i| {
                if i % 3 == 2 {
                    rng.random_range(-0.2f32..0.1)
                } else {
                    rng.random_range(-0.4f32..0.4)
                }
            })
            .collect();
        row.extend(if holding { [0.0, 1.0] } else { [1.0, 0.0] });
        rows.push(row);
        if let Some(a) = actions.get(k) {
            holding = a.index() < 2 + NUM_OBJECTS;
        }
    }
    Demo {
        task,
        actions,
        rows,
    }
}

/// Four demos of two tasks (two demos each, in different orders, one with
/// a retry): 8 to 15 actions, so the batch is padded.
fn demos(seed: u64) -> Vec<Demo> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    vec![
        demo(
            &mut rng,
            0,
            &[(1, 0), (2, 1), (3, 2), (5, 4), (6, 5), (7, 6), (4, 3)],
            None,
        ),
        demo(
            &mut rng,
            0,
            &[(5, 4), (1, 0), (6, 5), (2, 1), (3, 2), (7, 6), (4, 3)],
            Some(2),
        ),
        demo(&mut rng, 1, &[(0, 3), (2, 0), (6, 7), (1, 6)], None),
        demo(&mut rng, 1, &[(6, 7), (0, 3), (1, 6), (2, 0)], Some(0)),
    ]
}

/// `{"shape", "data"}` of a float tensor.
fn float_json<const D: usize>(t: Tensor<D>) -> Result<Value, Box<dyn Error>> {
    let shape = t.dims().to_vec();
    Ok(json!({ "shape": shape, "data": to_vec(t)? }))
}

/// `{"shape", "data"}` of an int tensor.
fn int_json<const D: usize>(t: Tensor<D, Int>) -> Result<Value, Box<dyn Error>> {
    let shape = t.dims().to_vec();
    Ok(json!({ "shape": shape, "data": to_vec_int(t)? }))
}

/// Collects parameters and their gradients by name, in burn's layout.
struct Collector<'a> {
    grads: &'a Gradients,
    params: Map<String, Value>,
    param_grads: Map<String, Value>,
    count: usize,
}

impl Collector<'_> {
    fn tensor<const D: usize>(
        &mut self,
        name: &str,
        p: &Param<Tensor<D>>,
    ) -> Result<(), Box<dyn Error>> {
        let value = p.val();
        let grad = value
            .grad(self.grads)
            .unwrap_or_else(|| value.zeros_like().detach());
        self.count += value.dims().iter().product::<usize>();
        self.params
            .insert(name.to_owned(), float_json(value.detach())?);
        self.param_grads.insert(name.to_owned(), float_json(grad)?);
        Ok(())
    }

    /// `name.weight` `[in, out]` and `name.bias` `[out]` (if any).
    fn linear(&mut self, name: &str, l: &Linear) -> Result<(), Box<dyn Error>> {
        self.tensor(&format!("{name}.weight"), &l.weight)?;
        if let Some(b) = &l.bias {
            self.tensor(&format!("{name}.bias"), b)?;
        }
        Ok(())
    }

    /// `name.input.*` (`[d_in, 3H]`, gates r, z, n) and `name.hidden.*`
    /// (`[H, 3H]`).
    fn gru(&mut self, name: &str, g: &GruCell) -> Result<(), Box<dyn Error>> {
        self.linear(&format!("{name}.input"), &g.input)?;
        self.linear(&format!("{name}.hidden"), &g.hidden)
    }

    /// A state MLP: `name.fc1`, `name.mid.{i}`, `name.fc2`.
    fn encoder(&mut self, name: &str, e: &Encoder) -> Result<(), Box<dyn Error>> {
        let Encoder::State(s) = e else {
            return Err("the twin covers state encoders only".into());
        };
        self.linear(&format!("{name}.fc1"), &s.fc1)?;
        for (i, l) in s.mid.iter().enumerate() {
            self.linear(&format!("{name}.mid.{i}"), l)?;
        }
        self.linear(&format!("{name}.fc2"), &s.fc2)
    }

    fn model(&mut self, m: &NtgModel) -> Result<(), Box<dyn Error>> {
        let i = &m.interpreter;
        if i.bwd_gru.is_some() || i.merge.is_some() || i.location.is_some() || i.local.is_some() {
            return Err("the twin covers the default demo interpreter only".into());
        }
        if i.input_feeding || i.stateless {
            return Err("the twin covers the default demo interpreter only".into());
        }
        self.encoder("interpreter.encoder", &i.encoder)?;
        self.gru("interpreter.enc_gru", &i.enc_gru)?;
        self.tensor("interpreter.tokens", &i.tokens)?;
        self.gru("interpreter.dec_gru", &i.dec_gru)?;
        self.linear("interpreter.attn", &i.attn)?;
        self.linear("interpreter.combine", &i.combine)?;
        self.linear("interpreter.out", &i.out)?;

        let g = &m.gcn;
        self.tensor("gcn.nodes", &g.nodes)?;
        for (name, pair) in [("gcn.f_set", &g.f_set), ("gcn.f_reset", &g.f_reset)] {
            self.linear(&format!("{name}.source"), &pair.source)?;
            self.linear(&format!("{name}.target"), &pair.target)?;
            self.linear(&format!("{name}.out"), &pair.out)?;
        }
        self.linear("gcn.f_forward", &g.f_forward)?;
        self.linear("gcn.f_backward", &g.f_backward)?;
        self.gru("gcn.rnn", &g.rnn)?;

        self.encoder("localizer.encoder", &m.localizer.encoder)?;
        self.tensor("localizer.nodes", &m.localizer.nodes)?;

        let e = &m.edges;
        if e.memory_dim != 0 {
            return Err("the twin covers edge classifiers without memory only".into());
        }
        self.encoder("edges.encoder", &e.encoder)?;
        if let Some(f) = &e.fusion {
            self.linear("edges.fusion", f)?;
        }
        self.linear("edges.w", &e.w)
    }
}

/// The sizes of a state encoder, for the twin.
fn encoder_dims(encoder: &EncoderConfig) -> Result<Value, Box<dyn Error>> {
    let EncoderConfig::State(s) = encoder else {
        return Err("the twin covers state encoders only".into());
    };
    Ok(json!({
        "input_dim": s.input_dim,
        "hidden": s.hidden,
        "hidden_layers": s.hidden_layers,
        "pairwise_objects": s.pairwise_objects,
        "out_dim": s.out_dim,
    }))
}

/// Builds the model and batch, runs the forward pass, the losses and the
/// backward pass on the CPU (`flex`, autodiff), and writes everything to
/// `path` (see the module doc).
pub fn export(path: &Path) -> Result<(), Box<dyn Error>> {
    let device: Device = ntg_model::cpu_device().autodiff();
    let model = NtgModel::new(recommended_config(MODEL_SEED), &device)?;
    export_model(&model, &device, path)
}

/// Runs the batch through `model` (block stacking's sizes, on `device`, an
/// autodiff device) and writes the file as [`export`] does: how the
/// weights of a trained run are checked (`ntg export`'s round trip, in
/// ntg-trainer's tests).
pub fn export_model(model: &NtgModel, device: &Device, path: &Path) -> Result<(), Box<dyn Error>> {
    let device = device.clone();
    let config = model.config().clone();
    let (n, d) = (NUM_NODES, STATE_DIM);

    let demos = demos(BATCH_SEED);
    // The GCN of each demo reads the other demo of its task.
    let partner = |b: usize| {
        (0..demos.len())
            .find(|&j| j != b && demos[j].task == demos[b].task)
            .unwrap_or(b)
    };
    let mut task_graphs: Vec<Ctg> = Vec::new();
    for dm in &demos {
        if task_graphs.len() <= dm.task {
            task_graphs.resize_with(dm.task + 1, || Ctg::empty(n));
        }
        task_graphs[dm.task].add_path(&dm.actions)?;
    }

    // Demo interpreter.
    let pairs: Vec<(&[Vec<f32>], &[ActionId])> = demos
        .iter()
        .map(|dm| (dm.rows.as_slice(), dm.actions.as_slice()))
        .collect();
    let batch = DemoBatch::new(&pairs, d, n, &device)?;
    let interp_out = model.interpreter.forward(
        batch.frames.clone(),
        batch.frame_mask.clone(),
        batch.targets.clone(),
    )?;
    let interp = model.interpreter.loss(&batch)?;

    // GCN: another demo's path → the task graph.
    let paths: Vec<Ctg> = (0..demos.len())
        .map(|b| Ctg::from_path(n, &demos[partner(b)].actions))
        .collect::<Result<_, _>>()?;
    let path_refs: Vec<&Ctg> = paths.iter().collect();
    let target_refs: Vec<&Ctg> = demos.iter().map(|dm| &task_graphs[dm.task]).collect();
    let adjacency = adjacency_tensor(&path_refs, n, &device)?;
    let target_adj = adjacency_tensor(&target_refs, n, &device)?;
    let gcn_out = model.gcn.forward(adjacency.clone())?;
    let gcn_loss = model.gcn.loss(&gcn_out, target_adj.clone())?;

    // Localizer and edge classifier: every row, labelled with its node
    // (the last action taken) and its next action (`<end>` after the last).
    let (mut obs, mut nodes, mut nexts, mut row_demo) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (b, dm) in demos.iter().enumerate() {
        let labels = std::iter::once(Vocabulary::START).chain(dm.actions.iter().copied());
        let following = dm.actions.iter().copied().chain([Vocabulary::END]);
        for ((row, node), next) in dm.rows.iter().zip(labels).zip(following) {
            obs.push(row.clone());
            nodes.push(node);
            nexts.push(next);
            row_demo.push(b as i64);
        }
    }
    let r = obs.len();
    let obs_tensor = rows_tensor(&obs, d, &device)?;
    let node_ids = ids_tensor(&nodes, n, &device)?;
    let next_ids = ids_tensor(&nexts, n, &device)?;
    let index = Tensor::<1, Int>::from_data(TensorData::new(row_demo, [r]), &device);

    let loc_logits = model.localizer.forward(obs_tensor.clone())?;
    let loc = model.localizer.loss(loc_logits.clone(), node_ids.clone())?;

    // Soft edges: every node of the fully connected graph, raised by ln C.
    let soft = gcn_out
        .adjacency
        .clone()
        .detach()
        .max_pair(adjacency.clone());
    let full = Ctg::fully_connected(n);
    let mask = successor_mask(&vec![&full; r], &nodes, Some(&nexts), n, &device)?;
    let row_ne_gcn = gcn_out.embeddings.clone().detach().select(0, index.clone());
    let edge_logits = model.edges.forward(
        obs_tensor.clone(),
        node_ids.clone(),
        row_ne_gcn,
        model.localizer.node_embeddings(),
        mask.clone(),
        None,
    )?;
    let gather = node_ids.clone().reshape([r, 1, 1]).expand([r, 1, n]);
    let c_rows = soft
        .select(0, index.clone())
        .gather(1, gather)
        .reshape([r, n]);
    let edge_logits = edge_logits + c_rows.clamp(SOFT_EDGE_FLOOR, 1.0).log();
    let edge = model.edges.loss(edge_logits.clone(), next_ids.clone())?;

    let total = interp.loss.clone() + loc.loss.clone() + gcn_loss.clone() + edge.loss.clone();
    let grads = total.backward();

    let mut collector = Collector {
        grads: &grads,
        params: Map::new(),
        param_grads: Map::new(),
        count: 0,
    };
    collector.model(model)?;
    if collector.count != model.num_params() {
        return Err(format!(
            "exported {} parameter values, the model has {}",
            collector.count,
            model.num_params()
        )
        .into());
    }

    let dims = json!({
        "num_nodes": n,
        "obs_dim": d,
        "interpreter": {
            "encoder": encoder_dims(&config.interpreter.encoder)?,
            "hidden": config.interpreter.hidden,
            "token_embed": config.interpreter.token_embed,
        },
        "gcn": {
            "hidden": config.gcn.hidden,
            "mlp_hidden": config.gcn.mlp_hidden,
            "iterations": config.gcn.iterations,
            "pos_weight": config.gcn.pos_weight,
        },
        "localizer": { "encoder": encoder_dims(&config.localizer.encoder)? },
        "edges": {
            "encoder": encoder_dims(&config.edge.encoder)?,
            "gcn_dim": config.edge.gcn_dim,
            "loc_dim": config.edge.loc_dim,
            "fusion_hidden": config.edge.fusion_hidden.unwrap_or(0),
        },
        "soft_edges": config.uses_soft_edges(),
        "soft_edge_floor": SOFT_EDGE_FLOOR,
        "detach_gcn_from_edges": true,
    });

    let edge_mask = mask.int();
    let inputs = json!({
        "frames": float_json(batch.frames.clone())?,
        "frame_mask": float_json(batch.frame_mask.clone())?,
        "targets": int_json(batch.targets.clone())?,
        "target_mask": float_json(batch.target_mask.clone())?,
        "gcn_input": float_json(adjacency)?,
        "gcn_target": float_json(target_adj)?,
        "obs": float_json(obs_tensor)?,
        "nodes": int_json(node_ids)?,
        "next": int_json(next_ids)?,
        "row_demo": int_json(index)?,
        "edge_mask": int_json(edge_mask)?,
    });
    let outputs = json!({
        "interpreter.logits": float_json(interp_out.logits)?,
        "interpreter.attention": float_json(interp_out.attention)?,
        "interpreter.loss": float_json(interp.loss)?,
        "gcn.adjacency": float_json(gcn_out.adjacency)?,
        "gcn.embeddings": float_json(gcn_out.embeddings)?,
        "gcn.loss": float_json(gcn_loss)?,
        "localizer.logits": float_json(loc_logits)?,
        "localizer.loss": float_json(loc.loss)?,
        "edges.logits": float_json(edge_logits)?,
        "edges.loss": float_json(edge.loss)?,
        "total_loss": float_json(total)?,
    });
    let file = json!({
        "format": "ntg-twin/1",
        "backend": "flex",
        "dims": dims,
        "config": serde_json::to_value(&config)?,
        "params": Value::Object(collector.params),
        "grads": Value::Object(collector.param_grads),
        "inputs": inputs,
        "outputs": outputs,
    });
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, serde_json::to_vec(&file)?)?;
    Ok(())
}

fn main() -> Result<(), Box<dyn Error>> {
    let out = std::env::args_os()
        .nth(1)
        .ok_or("usage: twin_export FILE (the JSON file to write)")?;
    let path = Path::new(&out);
    export(path)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}
