//! Turning Rust data (observation rows, action ids, graphs) into validated
//! tensors.
//!
//! Everything here checks its input and returns [`ModelError`] on a bad
//! length or id, so the networks' forward passes never see a malformed
//! batch.

use burn::tensor::{Bool, Device, Int, Tensor, TensorData};
use ctg_graph::{ActionId, Ctg, Demonstration, Vocabulary};

use crate::{ModelError, Result};

/// A `[B, D]` tensor of observation rows, each of length `dim`.
pub fn rows_tensor<R: AsRef<[f32]>>(rows: &[R], dim: usize, device: &Device) -> Result<Tensor<2>> {
    if rows.is_empty() {
        return Err(ModelError::Input("empty batch of observations".into()));
    }
    let mut flat = Vec::with_capacity(rows.len() * dim);
    for (i, row) in rows.iter().enumerate() {
        let row = row.as_ref();
        if row.len() != dim {
            return Err(ModelError::Shape {
                what: "observation row",
                expected: format!("{dim} values"),
                got: format!("{} values in row {i}", row.len()),
            });
        }
        flat.extend_from_slice(row);
    }
    Ok(Tensor::from_data(
        TensorData::new(flat, [rows.len(), dim]),
        device,
    ))
}

/// A `[B]` tensor of node ids, each checked to be below `num_nodes`.
pub fn ids_tensor(ids: &[ActionId], num_nodes: usize, device: &Device) -> Result<Tensor<1, Int>> {
    if ids.is_empty() {
        return Err(ModelError::Input("empty batch of node ids".into()));
    }
    let values = ids
        .iter()
        .map(|id| check_id(*id, num_nodes).map(|i| i as i64))
        .collect::<Result<Vec<_>>>()?;
    Ok(Tensor::from_data(
        TensorData::new(values, [ids.len()]),
        device,
    ))
}

pub(crate) fn check_id(id: ActionId, num_nodes: usize) -> Result<usize> {
    if id.index() < num_nodes {
        Ok(id.index())
    } else {
        Err(ModelError::Input(format!(
            "node id {} is outside the {num_nodes} nodes of the model",
            id.index()
        )))
    }
}

/// Batched `[B, N, N]` adjacency matrices of `graphs` (row = from).
pub fn adjacency_tensor(graphs: &[&Ctg], num_nodes: usize, device: &Device) -> Result<Tensor<3>> {
    if graphs.is_empty() {
        return Err(ModelError::Input("empty batch of graphs".into()));
    }
    let mut flat = Vec::with_capacity(graphs.len() * num_nodes * num_nodes);
    for g in graphs {
        if g.num_nodes() != num_nodes {
            return Err(ModelError::shape(
                "graph",
                format!("{num_nodes} nodes"),
                g.num_nodes(),
            ));
        }
        flat.extend_from_slice(g.adjacency());
    }
    Ok(Tensor::from_data(
        TensorData::new(flat, [graphs.len(), num_nodes, num_nodes]),
        device,
    ))
}

/// The `[B, N]` successor masks for the edge classifier: row `b` is true at
/// the CTG successors of `nodes[b]` in `graphs[b]`.
///
/// When `targets` is given, each `targets[b]` must be one of those
/// successors (otherwise the masked cross-entropy could not be minimised):
/// a missing edge is an error naming the row.
pub fn successor_mask(
    graphs: &[&Ctg],
    nodes: &[ActionId],
    targets: Option<&[ActionId]>,
    num_nodes: usize,
    device: &Device,
) -> Result<Tensor<2, Bool>> {
    if graphs.len() != nodes.len() || graphs.is_empty() {
        return Err(ModelError::Input(format!(
            "successor mask needs one graph per node and at least one row, got {} graphs and {} nodes",
            graphs.len(),
            nodes.len()
        )));
    }
    if let Some(t) = targets
        && t.len() != nodes.len()
    {
        return Err(ModelError::Input(format!(
            "successor mask: {} targets for {} rows",
            t.len(),
            nodes.len()
        )));
    }
    let mut flat = Vec::with_capacity(nodes.len() * num_nodes);
    for (b, (&g, &node)) in graphs.iter().zip(nodes).enumerate() {
        if g.num_nodes() != num_nodes {
            return Err(ModelError::shape(
                "graph",
                format!("{num_nodes} nodes"),
                g.num_nodes(),
            ));
        }
        check_id(node, num_nodes)?;
        let row = &g.adjacency()[node.index() * num_nodes..(node.index() + 1) * num_nodes];
        if let Some(t) = targets {
            let target = check_id(t[b], num_nodes)?;
            if row[target] <= 0.0 {
                return Err(ModelError::Input(format!(
                    "row {b}: target {} is not a CTG successor of node {}",
                    t[b].index(),
                    node.index()
                )));
            }
        }
        flat.extend(row.iter().map(|&w| w > 0.0));
    }
    Ok(Tensor::from_data(
        TensorData::new(flat, [nodes.len(), num_nodes]),
        device,
    ))
}

/// A padded batch of demonstrations for the [`DemoInterpreter`](crate::DemoInterpreter).
///
/// Demo `b` has `T_b` observation rows and `K_b` actions; its target
/// tokens are the `K_b` actions followed by `<end>`. Shorter demos are
/// padded (frames with zeros, tokens with `<end>`) and masked.
#[derive(Debug, Clone)]
pub struct DemoBatch {
    /// Observation rows `[B, T, D]`.
    pub frames: Tensor<3>,
    /// `[B, T]`: 1 for a real frame, 0 for padding.
    pub frame_mask: Tensor<2>,
    /// Target tokens `[B, L]`: the actions, then `<end>`, then padding.
    pub targets: Tensor<2, Int>,
    /// `[B, L]`: 1 for a real token, 0 for padding.
    pub target_mask: Tensor<2>,
    /// Where each token's attention belongs, for aligned attention
    /// ([`DemoInterpreterConfig::aligned_attention`](crate::DemoInterpreterConfig::aligned_attention)):
    /// per demo, one row per token (its actions, then `<end>`), counted in
    /// the demo's own rows, before any frame pooling. `None` means the
    /// state-demo rule: token `t` onto row `t + 1`, `<end>` onto the last
    /// row. Set by [`DemoBatch::with_aligned_rows`].
    pub aligned_rows: Option<Vec<Vec<usize>>>,
}

impl DemoBatch {
    /// Builds a batch from `(observations, actions)` pairs; every
    /// observation row has `obs_dim` values and every action is a real
    /// action below `num_nodes`.
    pub fn new<R: AsRef<[f32]>>(
        demos: &[(&[R], &[ActionId])],
        obs_dim: usize,
        num_nodes: usize,
        device: &Device,
    ) -> Result<Self> {
        if demos.is_empty() {
            return Err(ModelError::Input("empty batch of demonstrations".into()));
        }
        let batch = demos.len();
        let max_frames = demos.iter().map(|d| d.0.len()).max().unwrap_or(0);
        let max_tokens = demos.iter().map(|d| d.1.len() + 1).max().unwrap_or(1);
        let mut frames = vec![0.0f32; batch * max_frames * obs_dim];
        let mut frame_mask = vec![0.0f32; batch * max_frames];
        let mut targets = vec![Vocabulary::END.index() as i64; batch * max_tokens];
        let mut target_mask = vec![0.0f32; batch * max_tokens];
        for (b, (obs, actions)) in demos.iter().enumerate() {
            if obs.is_empty() {
                return Err(ModelError::Input(format!(
                    "demonstration {b} has no observations"
                )));
            }
            for (t, row) in obs.iter().enumerate() {
                let row = row.as_ref();
                if row.len() != obs_dim {
                    return Err(ModelError::Shape {
                        what: "demonstration frame",
                        expected: format!("{obs_dim} values"),
                        got: format!("{} values in demo {b}, frame {t}", row.len()),
                    });
                }
                let start = (b * max_frames + t) * obs_dim;
                frames[start..start + obs_dim].copy_from_slice(row);
                frame_mask[b * max_frames + t] = 1.0;
            }
            for (k, &a) in actions
                .iter()
                .chain(std::iter::once(&Vocabulary::END))
                .enumerate()
            {
                let i = check_id(a, num_nodes)?;
                if a == Vocabulary::START || (a == Vocabulary::END && k < actions.len()) {
                    return Err(ModelError::Input(format!(
                        "demonstration {b}: action {k} is a reserved node"
                    )));
                }
                targets[b * max_tokens + k] = i as i64;
                target_mask[b * max_tokens + k] = 1.0;
            }
        }
        Ok(DemoBatch {
            frames: Tensor::from_data(
                TensorData::new(frames, [batch, max_frames, obs_dim]),
                device,
            ),
            frame_mask: Tensor::from_data(TensorData::new(frame_mask, [batch, max_frames]), device),
            targets: Tensor::from_data(TensorData::new(targets, [batch, max_tokens]), device),
            target_mask: Tensor::from_data(
                TensorData::new(target_mask, [batch, max_tokens]),
                device,
            ),
            aligned_rows: None,
        })
    }

    /// The batch with each token's aligned row given (see
    /// [`DemoBatch::aligned_rows`]): for demo `b`, one row index per token,
    /// its actions then `<end>`, each below the demo's number of rows and
    /// never before the one of the token before (the demo is read in
    /// order). For a video, the keyframe each action ends on and, for
    /// `<end>`, the last keyframe. An input error names the demo otherwise.
    pub fn with_aligned_rows(mut self, rows: Vec<Vec<usize>>) -> Result<Self> {
        let frames = crate::nn::to_vec(self.frame_mask.clone().sum_dim(1))?;
        let tokens = crate::nn::to_vec(self.target_mask.clone().sum_dim(1))?;
        if rows.len() != frames.len() {
            return Err(ModelError::Input(format!(
                "aligned rows: {} demos given for a batch of {}",
                rows.len(),
                frames.len()
            )));
        }
        for (b, ((demo, &frames), &tokens)) in rows.iter().zip(&frames).zip(&tokens).enumerate() {
            let (frames, tokens) = (frames.round() as usize, tokens.round() as usize);
            if demo.len() != tokens {
                return Err(ModelError::Input(format!(
                    "aligned rows: demo {b} has {} rows given for its {tokens} tokens (actions and <end>)",
                    demo.len()
                )));
            }
            if let Some(&r) = demo.iter().find(|&&r| r >= frames) {
                return Err(ModelError::Input(format!(
                    "aligned rows: demo {b} has {frames} rows; row {r} is past its end"
                )));
            }
            if demo.windows(2).any(|w| w[1] < w[0]) {
                return Err(ModelError::Input(format!(
                    "aligned rows: demo {b}'s rows go backwards ({demo:?})"
                )));
            }
        }
        self.aligned_rows = Some(rows);
        Ok(self)
    }

    /// Builds a batch from validated demonstrations.
    pub fn from_demonstrations(
        demos: &[&Demonstration<Vec<f32>>],
        obs_dim: usize,
        num_nodes: usize,
        device: &Device,
    ) -> Result<Self> {
        let pairs: Vec<(&[Vec<f32>], &[ActionId])> = demos
            .iter()
            .map(|d| (d.observations(), d.actions()))
            .collect();
        Self::new(&pairs, obs_dim, num_nodes, device)
    }

    /// Number of demonstrations `B`.
    pub fn len(&self) -> usize {
        self.frames.dims()[0]
    }

    /// Whether the batch is empty (never, by construction).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
