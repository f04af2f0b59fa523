"""PyTorch twin of ntg-model's four NTG networks (state input), numerically
cross-checked against the Rust model.

The same networks as `ntg_model::NtgModel` with block stacking's
recommended recipe (see `crates/ntg-model/examples/twin_export.rs`):

- demo interpreter: state MLP (26 -> 128 -> 128), encoder GRU (128),
  token embeddings (18 x 64), decoder GRU (128) started from the encoder's
  last state, Luong "general" attention (score h_t . W_a h_s, padding frames
  masked with -1e9), h~ = tanh(W_c [c; h]), logits W_o h~; teacher forcing,
  masked token cross-entropy;
- graph completion net: node embeddings N0 (18 x 64), 3 iterations of the
  edge update C' = ((1 - C) f_set + C f_reset) * allowed and the GRU node
  update from messages C f_f(N) + C^T f_b(N); weighted binary
  cross-entropy (p clamped to [1e-6, 1 - 1e-6]);
- node localizer: relational state MLP (26 + 3 * 8 * 8 pairwise
  differences -> 3 x 128 -> 128), logits Enc(o) . NE_loc;
- edge classifier: its own relational MLP, fusion layer
  relu(W1 [Enc(o); NE_gcn(n)]) (256), query W2 (128), logits query . NE_loc
  (NE_loc attached), masked to the fully connected graph, plus ln C of the
  completed graph (detached, floored at 1e-6) (soft edges); NE_gcn
  detached.

The total loss is interpreter + localizer + GCN + edge, as the trainer's
`NtgStep` sums it.

Cross-check (the default): reads the JSON file written by the Rust example,
copies the weights, runs the same batch, backpropagates the total loss, and
compares every output, loss and parameter gradient by max abs error. Prints
a table; exits 1 if an output or loss differs by more than --tol (1e-4), or
a gradient by more than --tol times its tensor's largest magnitude.

    cargo run --release -p ntg-model --example twin_export -- /tmp/ntg_twin.json
    python3 crates/ntg-model/benches/pytorch/twin.py /tmp/ntg_twin.json

With `--weights DIR/model.safetensors` (a trained run's `ntg export`), the
twin takes its weights from that file instead, in PyTorch's layout, and
checks that they are the weights the reference outputs were computed with
(ntg-trainer's `export` test writes such a JSON file from a trained run).

Bench: times one training step (forward, backward, Adam with burn's
defaults: betas 0.9/0.999, eps 1e-5, lr 3e-3) on a deterministic synthetic
batch of 32 demos (12, 14 or 16 actions each, so 13 to 17 state rows; the
GCN reads another demo's path), PyTorch's default initialisation (or the
weights of FILE if given). Prints one JSON line with the median
milliseconds.

    python3 crates/ntg-model/benches/pytorch/twin.py --bench --threads 2 [--repeats 30]

`--bench ROW` (or `ROW,ROW`, or `all`) times the rows of `cargo xtask
bench`, one JSON line each, on exactly the batches and sizes of the burn
side (`crates/ntg-model/benches/twin_bench.rs`, whose doc gives the batch
recipe): state_step (the above), frame_step (stage A's frame network, 64
frames), interpreter_step and gcn_step (those networks alone on the same
batch), policy_step (one executor decision, inference: localizer, edge
classifier over every node with soft edges, pi = sum_n ell(n) eps(.|n);
repeated max(10 x repeats, 100) times).
"""
import argparse
import json
import statistics
import sys
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

START, END = 0, 1  # reserved CTG nodes
MASKED_LOGIT = -1.0e9
GCN_EPS = 1e-6

# Block stacking's recommended sizes (what twin_export.rs writes in `dims`).
DEFAULT_DIMS = {
    "num_nodes": 18,
    "obs_dim": 26,
    "interpreter": {
        "encoder": {"input_dim": 26, "hidden": 128, "hidden_layers": 1,
                    "pairwise_objects": 0, "out_dim": 128},
        "hidden": 128,
        "token_embed": 64,
    },
    "gcn": {"hidden": 64, "mlp_hidden": 64, "iterations": 3, "pos_weight": 1.0},
    "localizer": {
        "encoder": {"input_dim": 26, "hidden": 128, "hidden_layers": 3,
                    "pairwise_objects": 8, "out_dim": 128},
    },
    "edges": {
        "encoder": {"input_dim": 26, "hidden": 128, "hidden_layers": 3,
                    "pairwise_objects": 8, "out_dim": 128},
        "gcn_dim": 64,
        "loc_dim": 128,
        "fusion_hidden": 256,
    },
    "soft_edges": True,
    "soft_edge_floor": 1e-6,
    "detach_gcn_from_edges": True,
}


# ----------------------------------------------------------------- networks


class StateEncoder(nn.Module):
    """relu MLP over the state row (optionally followed by every pairwise
    difference p_i - p_j of the first K xyz positions), then a linear layer."""

    def __init__(self, d):
        super().__init__()
        self.k = d["pairwise_objects"]
        d_in = d["input_dim"] + 3 * self.k * self.k
        self.fc1 = nn.Linear(d_in, d["hidden"])
        self.mid = nn.ModuleList(
            nn.Linear(d["hidden"], d["hidden"]) for _ in range(d["hidden_layers"] - 1))
        self.fc2 = nn.Linear(d["hidden"], d["out_dim"])

    def forward(self, x):
        k = self.k
        if k > 0:
            p = x[..., : 3 * k].reshape(*x.shape[:-1], k, 3)
            diff = p.unsqueeze(-2) - p.unsqueeze(-3)  # [..., k, k, 3]: p_i - p_j
            x = torch.cat([x, diff.flatten(-3)], -1)
        h = F.relu(self.fc1(x))
        for layer in self.mid:
            h = F.relu(layer(h))
        return self.fc2(h)


class DemoInterpreter(nn.Module):
    def __init__(self, dims):
        super().__init__()
        d = dims["interpreter"]
        n, h = dims["num_nodes"], d["hidden"]
        self.encoder = StateEncoder(d["encoder"])
        self.enc_gru = nn.GRU(d["encoder"]["out_dim"], h, batch_first=True)
        self.tokens = nn.Embedding(n, d["token_embed"])
        self.dec_gru = nn.GRU(d["token_embed"], h, batch_first=True)
        self.attn = nn.Linear(h, h, bias=False)
        self.combine = nn.Linear(2 * h, h)
        self.out = nn.Linear(h, n)

    def forward(self, frames, frame_mask, targets):
        """Teacher-forced pass: logits [B, L, N] and attention [B, L, T]."""
        b = frames.shape[0]
        states, _ = self.enc_gru(self.encoder(frames))  # [B, T, H]
        # Padding is at the end of each demo; the Rust GRU carries the state
        # through it, so its final state is the state after the last frame.
        # (States at padding positions differ here, but get zero attention.)
        last = states[torch.arange(b), frame_mask.sum(1).long() - 1]  # [B, H]
        start = torch.full((b, 1), START, dtype=targets.dtype)
        inputs = torch.cat([start, targets[:, :-1]], 1)
        dec, _ = self.dec_gru(self.tokens(inputs), last.unsqueeze(0))  # [B, L, H]
        keys = self.attn(states)
        scores = dec @ keys.transpose(1, 2)  # [B, L, T]
        scores = scores.masked_fill((frame_mask < 0.5).unsqueeze(1), MASKED_LOGIT)
        alpha = torch.softmax(scores, 2)
        context = alpha @ states
        combined = torch.tanh(self.combine(torch.cat([context, dec], 2)))
        return self.out(combined), alpha


class PairMlp(nn.Module):
    """f(N_i, N_j) = sigmoid(w_o . relu(U N_i + V N_j + b) + b_o), all pairs."""

    def __init__(self, h, m):
        super().__init__()
        self.source = nn.Linear(h, m)
        self.target = nn.Linear(h, m, bias=False)
        self.out = nn.Linear(m, 1)

    def forward(self, nodes):  # [B, N, H] -> [B, N, N]
        pair = F.relu(self.source(nodes).unsqueeze(2) + self.target(nodes).unsqueeze(1))
        return torch.sigmoid(self.out(pair).squeeze(-1))


class GraphCompletionNet(nn.Module):
    def __init__(self, dims):
        super().__init__()
        d = dims["gcn"]
        n, h, m = dims["num_nodes"], d["hidden"], d["mlp_hidden"]
        self.iterations = d["iterations"]
        self.pos_weight = d["pos_weight"]
        self.nodes = nn.Parameter(torch.empty(n, h).uniform_(-1.0, 1.0))
        self.f_set = PairMlp(h, m)
        self.f_reset = PairMlp(h, m)
        self.f_forward = nn.Linear(h, h)
        self.f_backward = nn.Linear(h, h)
        self.rnn = nn.GRUCell(h, h)
        allowed = torch.ones(n, n)
        allowed[END, :] = 0.0  # nothing out of <end>
        allowed[:, START] = 0.0  # nothing into <start>
        self.register_buffer("allowed", allowed)

    def forward(self, c):
        """Completed adjacency [B, N, N] and node embeddings [B, N, H]."""
        b, n, _ = c.shape
        h = self.nodes.shape[1]
        nodes = self.nodes.unsqueeze(0).expand(b, n, h)
        for _ in range(self.iterations):
            c_next = ((1.0 - c) * self.f_set(nodes) + c * self.f_reset(nodes)) * self.allowed
            messages = c @ self.f_forward(nodes) + c.transpose(1, 2) @ self.f_backward(nodes)
            nodes = self.rnn(messages.reshape(b * n, h), nodes.reshape(b * n, h)).reshape(b, n, h)
            c = c_next
        return c, nodes

    def loss(self, adjacency, target):
        p = adjacency.clamp(GCN_EPS, 1.0 - GCN_EPS)
        pos = target * p.log() * self.pos_weight
        neg = (1.0 - target) * (1.0 - p).log()
        return -(pos + neg).mean()


class NodeLocalizer(nn.Module):
    def __init__(self, dims):
        super().__init__()
        d = dims["localizer"]["encoder"]
        self.encoder = StateEncoder(d)
        h = d["out_dim"]
        self.nodes = nn.Parameter(torch.empty(dims["num_nodes"], h).uniform_(-h**-0.5, h**-0.5))

    def forward(self, obs):
        return self.encoder(obs) @ self.nodes.t()


class EdgeClassifier(nn.Module):
    def __init__(self, dims):
        super().__init__()
        d = dims["edges"]
        self.encoder = StateEncoder(d["encoder"])
        joint = d["encoder"]["out_dim"] + d["gcn_dim"]
        if d["fusion_hidden"] > 0:
            self.fusion = nn.Linear(joint, d["fusion_hidden"])
            joint = d["fusion_hidden"]
        else:
            self.fusion = None
        self.w = nn.Linear(joint, d["loc_dim"])

    def forward(self, obs, node_gcn, ne_loc, allowed):
        """Masked logits [R, N] for observations [R, D], the GCN embedding of
        each row's node [R, H], NE_loc [N, H_loc], allowed [R, N] (bool)."""
        joint = torch.cat([self.encoder(obs), node_gcn], 1)
        if self.fusion is not None:
            joint = F.relu(self.fusion(joint))
        logits = self.w(joint) @ ne_loc.t()
        return logits.masked_fill(~allowed, MASKED_LOGIT)


def masked_cross_entropy(logits, targets, weights):
    """-sum_m w_m log softmax(logits_m)[t_m] / max(sum_m w_m, 1)."""
    picked = torch.log_softmax(logits, 1).gather(1, targets.unsqueeze(1)).squeeze(1)
    return -(picked * weights).sum() / weights.sum().clamp_min(1.0)


class NtgTwin(nn.Module):
    def __init__(self, dims):
        super().__init__()
        self.dims = dims
        self.interpreter = DemoInterpreter(dims)
        self.gcn = GraphCompletionNet(dims)
        self.localizer = NodeLocalizer(dims)
        self.edges = EdgeClassifier(dims)

    def forward(self, x):
        """Every output and loss of one training step on batch `x`."""
        out = {}
        n = self.dims["num_nodes"]
        logits, attention = self.interpreter(x["frames"], x["frame_mask"], x["targets"])
        out["interpreter.logits"], out["interpreter.attention"] = logits, attention
        out["interpreter.loss"] = masked_cross_entropy(
            logits.reshape(-1, n), x["targets"].reshape(-1), x["target_mask"].reshape(-1))

        adjacency, embeddings = self.gcn(x["gcn_input"])
        out["gcn.adjacency"], out["gcn.embeddings"] = adjacency, embeddings
        out["gcn.loss"] = self.gcn.loss(adjacency, x["gcn_target"])

        loc_logits = self.localizer(x["obs"])
        out["localizer.logits"] = loc_logits
        out["localizer.loss"] = F.cross_entropy(loc_logits, x["nodes"])

        ne_gcn = embeddings.detach() if self.dims["detach_gcn_from_edges"] else embeddings
        node_gcn = ne_gcn[x["row_demo"], x["nodes"]]
        edge_logits = self.edges(x["obs"], node_gcn, self.localizer.nodes, x["edge_mask"])
        if self.dims["soft_edges"]:
            c = torch.maximum(adjacency.detach(), x["gcn_input"])
            c_rows = c[x["row_demo"], x["nodes"]]  # [R, N]
            edge_logits = edge_logits + c_rows.clamp(self.dims["soft_edge_floor"], 1.0).log()
        out["edges.logits"] = edge_logits
        out["edges.loss"] = F.cross_entropy(edge_logits, x["next"])

        out["total_loss"] = (out["interpreter.loss"] + out["localizer.loss"]
                             + out["gcn.loss"] + out["edges.loss"])
        return out


# ------------------------------------------------------------ weight import


def parameter_map(twin):
    """(burn name, PyTorch parameter, to_burn) for every parameter, where
    to_burn turns a PyTorch tensor (value or gradient) into burn's layout."""
    same = lambda t: t  # noqa: E731
    tr = lambda t: t.t()  # noqa: E731
    entries = []

    def linear(m, name):
        entries.append((f"{name}.weight", m.weight, tr))
        if m.bias is not None:
            entries.append((f"{name}.bias", m.bias, same))

    def gru(m, name, suffix=""):
        entries.append((f"{name}.input.weight", getattr(m, f"weight_ih{suffix}"), tr))
        entries.append((f"{name}.input.bias", getattr(m, f"bias_ih{suffix}"), same))
        entries.append((f"{name}.hidden.weight", getattr(m, f"weight_hh{suffix}"), tr))
        entries.append((f"{name}.hidden.bias", getattr(m, f"bias_hh{suffix}"), same))

    def encoder(e, name):
        linear(e.fc1, f"{name}.fc1")
        for i, layer in enumerate(e.mid):
            linear(layer, f"{name}.mid.{i}")
        linear(e.fc2, f"{name}.fc2")

    i = twin.interpreter
    encoder(i.encoder, "interpreter.encoder")
    gru(i.enc_gru, "interpreter.enc_gru", "_l0")
    entries.append(("interpreter.tokens", i.tokens.weight, same))
    gru(i.dec_gru, "interpreter.dec_gru", "_l0")
    linear(i.attn, "interpreter.attn")
    linear(i.combine, "interpreter.combine")
    linear(i.out, "interpreter.out")
    g = twin.gcn
    entries.append(("gcn.nodes", g.nodes, same))
    for name, pair in (("gcn.f_set", g.f_set), ("gcn.f_reset", g.f_reset)):
        linear(pair.source, f"{name}.source")
        linear(pair.target, f"{name}.target")
        linear(pair.out, f"{name}.out")
    linear(g.f_forward, "gcn.f_forward")
    linear(g.f_backward, "gcn.f_backward")
    gru(g.rnn, "gcn.rnn")
    encoder(twin.localizer.encoder, "localizer.encoder")
    entries.append(("localizer.nodes", twin.localizer.nodes, same))
    e = twin.edges
    encoder(e.encoder, "edges.encoder")
    if e.fusion is not None:
        linear(e.fusion, "edges.fusion")
    linear(e.w, "edges.w")
    return entries


def load_weights(twin, params):
    """Copies burn-layout tensors `params` into `twin`; every parameter on
    both sides must be used exactly once, with matching shapes."""
    entries = parameter_map(twin)
    names = [name for name, _, _ in entries]
    missing = sorted(set(names) - set(params))
    extra = sorted(set(params) - set(names))
    if missing or extra:
        raise SystemExit(f"parameter names differ: missing {missing}, not used {extra}")
    covered = {id(p) for _, p, _ in entries}
    if covered != {id(p) for p in twin.parameters()} or len(covered) != len(entries):
        raise SystemExit("the parameter map does not cover the twin exactly once")
    with torch.no_grad():
        for name, p, to_burn in entries:
            src = params[name]
            if tuple(to_burn(p).shape) != tuple(src.shape):
                raise SystemExit(f"{name}: shape {tuple(src.shape)} in the file, "
                                 f"{tuple(to_burn(p).shape)} in the twin (burn layout)")
            to_burn(p).copy_(src)


def load_safetensors(twin, path):
    """Copies the weights of an `ntg export` file (PyTorch's layout: every
    tensor has the shape of the twin's parameter, Linear and GRU weights
    already transposed) into `twin`; every parameter on both sides must be
    used exactly once, with matching shapes. Returns the file's tensors."""
    from safetensors.torch import load_file

    tensors = load_file(path)
    entries = parameter_map(twin)
    names = [name for name, _, _ in entries]
    missing = sorted(set(names) - set(tensors))
    extra = sorted(set(tensors) - set(names))
    if missing or extra:
        raise SystemExit(f"{path}: tensor names differ from the twin's: missing {missing}, "
                         f"not used {extra}")
    with torch.no_grad():
        for name, p, _ in entries:
            src = tensors[name]
            if tuple(p.shape) != tuple(src.shape):
                raise SystemExit(f"{path}: {name} has shape {tuple(src.shape)}, the twin's "
                                 f"parameter {tuple(p.shape)}")
            p.copy_(src)
    return tensors


# -------------------------------------------------------------- file input


def same_dims(a, b):
    """Equal sizes, floats compared as float32 (the file holds f32 values)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_dims(a[k], b[k]) for k in a)
    if isinstance(a, float) or isinstance(b, float):
        return np.float32(a) == np.float32(b)
    return a == b


def _tensor(v, dtype):
    return torch.from_numpy(np.asarray(v["data"], dtype=dtype).reshape(v["shape"]))


def read_export(path):
    with open(path) as f:
        doc = json.load(f)
    if doc.get("format") != "ntg-twin/1":
        raise SystemExit(f"{path}: not an ntg-twin/1 file")
    params = {k: _tensor(v, np.float32) for k, v in doc["params"].items()}
    grads = {k: _tensor(v, np.float32) for k, v in doc["grads"].items()}
    ints = {"targets", "nodes", "next", "row_demo", "edge_mask"}
    inputs = {}
    for k, v in doc["inputs"].items():
        inputs[k] = _tensor(v, np.int64 if k in ints else np.float32)
    inputs["edge_mask"] = inputs["edge_mask"] != 0
    outputs = {k: _tensor(v, np.float32) for k, v in doc["outputs"].items()}
    return doc["dims"], params, grads, inputs, outputs


# --------------------------------------------------------------- check mode


def check(path, tol, weights=None):
    dims, params, grads, inputs, expected = read_export(path)
    if not same_dims(dims, DEFAULT_DIMS):
        print("note: the exported model's sizes differ from DEFAULT_DIMS, which --bench "
              f"uses without a FILE:\n  exported {dims}\n  default  {DEFAULT_DIMS}")
    torch.manual_seed(0)
    twin = NtgTwin(dims)
    if weights is None:
        load_weights(twin, params)
    else:
        # The weights come from the safetensors file alone; the JSON's copy
        # (burn's layout) only says that they are the weights the reference
        # outputs were computed with.
        load_safetensors(twin, weights)
        worst = max((to_burn(p.detach()) - params[name]).abs().max().item()
                    for name, p, to_burn in parameter_map(twin))
        print(f"weights read from {weights}; largest difference from the reference's "
              f"weights {worst:.3e}")
        if worst != 0.0:
            print("FAILED: the safetensors file does not hold the reference's weights")
            return 1
    out = twin(inputs)
    out["total_loss"].backward()

    # (kind, name, shape, max abs error, max |reference|, limit). Outputs
    # and losses must agree to `tol` absolutely; a gradient to `tol` times
    # its tensor's largest magnitude (gradients here are 1e-5 to 1e-1, so
    # an absolute 1e-4 would let a wrong one through).
    rows = []
    for name, ref in expected.items():
        scale = ref.abs().max().item()
        if name not in out:
            rows.append(("output", name, tuple(ref.shape), float("inf"), scale, tol))
            continue
        got = out[name].detach().reshape(ref.shape)
        rows.append(("output", name, tuple(ref.shape), (got - ref).abs().max().item(), scale, tol))
    missing_outputs = sorted(set(out) - set(expected))
    for name, p, to_burn in parameter_map(twin):
        ref = grads[name]
        g = to_burn(p.grad) if p.grad is not None else torch.zeros_like(ref)
        scale = ref.abs().max().item()
        rows.append(("grad", name, tuple(ref.shape), (g - ref).abs().max().item(), scale,
                     tol * scale))

    width = max(len(r[1]) for r in rows)
    print(f"{'kind':<6}  {'name':<{width}}  {'shape':<16}  {'max |ref|':>10}  "
          f"{'max abs err':>11}  {'limit':>9}  ok")
    for kind, name, shape, err, scale, limit in rows:
        ok = "ok" if err <= limit else "FAIL"
        print(f"{kind:<6}  {name:<{width}}  {str(list(shape)):<16}  {scale:>10.4g}  "
              f"{err:>11.3e}  {limit:>9.2e}  {ok}")
    failed = [r for r in rows if not r[3] <= r[5]]
    worst_out = max(r[3] for r in rows if r[0] == "output")
    worst_grad = max((r[3] / r[4] if r[4] > 0 else r[3]) for r in rows if r[0] == "grad")
    print(f"\n{len(rows)} compared ({sum(r[0] == 'output' for r in rows)} outputs and losses, "
          f"{sum(r[0] == 'grad' for r in rows)} gradients); worst output max abs error "
          f"{worst_out:.3e} (limit {tol:g}); worst gradient error relative to its scale "
          f"{worst_grad:.3e} (limit {tol:g}); torch {torch.__version__}")
    if missing_outputs:
        print(f"twin outputs not in the file (not compared): {missing_outputs}")
    if failed:
        print(f"FAILED: {len(failed)} above tolerance: {[r[1] for r in failed]}")
        return 1
    print("all within tolerance")
    return 0


# --------------------------------------------------------------- bench mode

# The rows of `cargo xtask bench` this side times, in its order; the burn
# side is `crates/ntg-model/benches/twin_bench.rs`, with the same names,
# sizes and batches.
BENCH_ROWS = ("state_step", "frame_step", "interpreter_step", "gcn_step", "policy_step")
FRAMES = 64  # stage A batch (the trainer's default)
FRAME_SIDE = 64
LR = 3e-3


def unit(k):
    """(k * 2654435761 mod 2^32) / 2^32 for an array of ints, in [0, 1):
    the deterministic "random" values both sides build their batches from."""
    k = np.asarray(k, dtype=np.uint64)
    return ((k * np.uint64(2654435761)) & np.uint64(0xFFFFFFFF)).astype(np.float64) / 4294967296.0


def demo_actions(b, n):
    """Demo b: 6 + b % 3 moves, move k picks cube (b + 3k) % K and places it
    on cube (b + 5k + 1) % K (K = (n - 2) / 2 cubes)."""
    k_obj = (n - 2) // 2
    seq = []
    for k in range(6 + b % 3):
        seq += [2 + (b + 3 * k) % k_obj, 2 + k_obj + (b + 5 * k + 1) % k_obj]
    return seq


def demo_rows(b, actions, d):
    """The actions + 1 state rows of demo b: value i of row t is
    -0.4 + 0.8 u((64 b + t) 64 + i)."""
    t = np.arange(actions + 1)[:, None]
    i = np.arange(d)[None, :]
    return (-0.4 + 0.8 * unit((64 * b + t) * 64 + i)).astype(np.float32)


def synthetic_batch(dims, batch):
    """A batch shaped like block stacking's, identical to twin_bench.rs's:
    `batch` demos of 12, 14 or 16 actions (pick/place alternating) with one
    state row per CTG node, the GCN completing demo b ^ 1's path into the
    union of both paths (see demo_actions and demo_rows)."""
    n, d = dims["num_nodes"], dims["obs_dim"]
    actions = [demo_actions(b, n) for b in range(batch)]
    t_max = max(len(a) + 1 for a in actions)
    l_max = max(len(a) + 1 for a in actions)
    frames = np.zeros((batch, t_max, d), np.float32)
    frame_mask = np.zeros((batch, t_max), np.float32)
    targets = np.full((batch, l_max), END, np.int64)
    target_mask = np.zeros((batch, l_max), np.float32)

    def path(seq):
        a = np.zeros((n, n), np.float32)
        nodes = [START] + seq + [END]
        for u, v in zip(nodes, nodes[1:]):
            a[u, v] = 1.0
        return a

    gcn_input = np.zeros((batch, n, n), np.float32)
    gcn_target = np.zeros((batch, n, n), np.float32)
    obs, nodes, nxt, row_demo = [], [], [], []
    for b, seq in enumerate(actions):
        rows = demo_rows(b, len(seq), d)
        frames[b, : len(rows)] = rows
        frame_mask[b, : len(rows)] = 1.0
        targets[b, : len(seq) + 1] = seq + [END]
        target_mask[b, : len(seq) + 1] = 1.0
        other = b ^ 1 if (b ^ 1) < batch else b
        gcn_input[b] = path(actions[other])
        gcn_target[b] = np.maximum(path(seq), path(actions[other]))
        obs.append(rows)
        nodes += [START] + seq
        nxt += seq + [END]
        row_demo += [b] * len(rows)
    allowed = np.ones((n, n), bool)
    allowed[END, :] = False
    allowed[:, START] = False
    nodes = np.asarray(nodes, np.int64)
    return {
        "frames": torch.from_numpy(frames),
        "frame_mask": torch.from_numpy(frame_mask),
        "targets": torch.from_numpy(targets),
        "target_mask": torch.from_numpy(target_mask),
        "gcn_input": torch.from_numpy(gcn_input),
        "gcn_target": torch.from_numpy(gcn_target),
        "obs": torch.from_numpy(np.concatenate(obs)),
        "nodes": torch.from_numpy(nodes),
        "next": torch.from_numpy(np.asarray(nxt, np.int64)),
        "row_demo": torch.from_numpy(np.asarray(row_demo, np.int64)),
        "edge_mask": torch.from_numpy(allowed[nodes]),
    }


def batch_shape(x):
    return (f"batch {x['frames'].shape[0]}, rows {x['obs'].shape[0]}, "
            f"frames {x['frames'].shape[1]}, tokens {x['targets'].shape[1]}")


class FrameStageTwin(nn.Module):
    """ntg_model::FrameStageNet at the trainer's default stage A settings:
    three 3x3 convolutions of stride 2, padding 1 (3 -> 32 -> 64 -> 64
    channels, 64x64 -> 8x8) with ReLU, a linear layer to 128 (Enc(o)),
    NE_loc and NE [N, 128], the edge head W [Enc(o); NE(n)] (256 -> 128),
    localizer and masked edge cross-entropies summed."""

    def __init__(self, n, hidden=128):
        super().__init__()
        self.c1 = nn.Conv2d(3, 32, 3, 2, 1)
        self.c2 = nn.Conv2d(32, 64, 3, 2, 1)
        self.c3 = nn.Conv2d(64, 64, 3, 2, 1)
        self.fc = nn.Linear(64 * 8 * 8, hidden)
        bound = hidden**-0.5
        self.loc_nodes = nn.Parameter(torch.empty(n, hidden).uniform_(-bound, bound))
        self.edge_nodes = nn.Parameter(torch.empty(n, hidden).uniform_(-bound, bound))
        self.w = nn.Linear(2 * hidden, hidden)

    def loss(self, frames, labels, nxt, successors):
        x = frames.reshape(-1, 3, FRAME_SIDE, FRAME_SIDE)
        x = F.relu(self.c1(x))
        x = F.relu(self.c2(x))
        x = F.relu(self.c3(x))
        enc = self.fc(x.flatten(1))
        loc_logits = enc @ self.loc_nodes.t()
        query = self.w(torch.cat([enc, self.edge_nodes[labels]], 1))
        edge_logits = (query @ self.loc_nodes.t()).masked_fill(~successors, MASKED_LOGIT)
        return F.cross_entropy(loc_logits, labels) + F.cross_entropy(edge_logits, nxt)


def frame_batch(n):
    """Stage A's 64 frames, identical to twin_bench.rs's: pixel i of frame f
    u(1e9 + 12288 f + i), label 2 + f % 16, next 2 + (f + 1) % 16,
    successors a where (7 f + 3 a) % 10 < 3, and the next action."""
    dim = 3 * FRAME_SIDE * FRAME_SIDE
    frames = unit(1_000_000_000 + np.arange(FRAMES * dim)).astype(np.float32).reshape(FRAMES, dim)
    labels = 2 + np.arange(FRAMES) % 16
    nxt = 2 + (np.arange(FRAMES) + 1) % 16
    f, a = np.meshgrid(np.arange(FRAMES), np.arange(n), indexing="ij")
    successors = ((7 * f + 3 * a) % 10 < 3) | (a == nxt[:, None])
    return (torch.from_numpy(frames), torch.from_numpy(labels.astype(np.int64)),
            torch.from_numpy(nxt.astype(np.int64)), torch.from_numpy(successors))


class PolicyTwin:
    """One executor decision of ntg_model::NtgPolicy with soft edges and the
    marginal node selection, for the policy built from `actions` (its path
    graph completed by the GCN once, as NtgPolicy::from_actions does):
    ell(n|o) = softmax of the localizer's logits; eps(a|n,o) a softmax of the
    edge logits raised by ln C over the fully connected graph's successors,
    C the completed graph's probabilities with the demo's edges at 1,
    floored at soft_edge_floor; pi(a|o) = sum_n ell(n|o) eps(a|n,o) over the
    nodes with successors, normalised."""

    def __init__(self, twin, actions):
        dims = twin.dims
        n = dims["num_nodes"]
        self.twin = twin
        nodes = [START] + actions + [END]
        path = torch.zeros(n, n)
        for u, v in zip(nodes, nodes[1:]):
            path[u, v] = 1.0
        with torch.no_grad():
            adjacency, embeddings = twin.gcn(path[None])
            allowed = twin.gcn.allowed > 0.5
            weights = torch.maximum(adjacency[0].clamp(0.0, 1.0), path)
            weights = weights.clamp(dims["soft_edge_floor"], 1.0)
            self.log_weights = torch.where(allowed, weights.log(), torch.tensor(float("-inf")))
            self.has_successor = allowed.any(1)
            self.ne_gcn = embeddings[0]  # [N, H]
        self.n = n

    def action_distribution(self, observation):
        """pi(.|o) for one observation row (a numpy float32 array)."""
        t = self.twin
        with torch.no_grad():
            x = torch.from_numpy(observation)[None]
            node_p = torch.softmax(t.localizer(x)[0], 0)
            enc = t.edges.encoder(x).expand(self.n, -1)
            joint = torch.cat([enc, self.ne_gcn], 1)
            if t.edges.fusion is not None:
                joint = F.relu(t.edges.fusion(joint))
            logits = t.edges.w(joint) @ t.localizer.nodes.t()  # [N, N]
            keep = self.has_successor
            rows = torch.softmax(logits[keep] + self.log_weights[keep], 1)
            p = (node_p[keep, None] * rows).sum(0)
            return (p / p.sum()).numpy()


def median_ms(fn, repeats, warmup):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(max(repeats, 1)):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), min(times), len(times)


def bench_row(row, dims, params, batch, repeats, warmup):
    """Times `row`: (median ms, min ms, repeats, shape, extra fields)."""
    torch.manual_seed(0)
    twin = NtgTwin(dims)
    if params is not None:
        load_weights(twin, params)
    extra = {}
    if row in ("state_step", "interpreter_step", "gcn_step"):
        x = synthetic_batch(dims, batch)
        n = dims["num_nodes"]
        if row == "state_step":
            trained = twin

            def loss():
                return twin(x)["total_loss"]
            extra = {
                "bench": "ntg_twin_train_step",
                "obs": "state",
                "batch": batch,
                "rows": int(x["obs"].shape[0]),
                "frames": int(x["frames"].shape[1]),
                "tokens": int(x["targets"].shape[1]),
                "params": sum(p.numel() for p in twin.parameters()),
            }
            shape = batch_shape(x)
        elif row == "interpreter_step":
            trained = twin.interpreter

            def loss():
                logits, _ = twin.interpreter(x["frames"], x["frame_mask"], x["targets"])
                return masked_cross_entropy(logits.reshape(-1, n), x["targets"].reshape(-1),
                                            x["target_mask"].reshape(-1))
            shape = batch_shape(x)
        else:
            trained = twin.gcn

            def loss():
                adjacency, _ = twin.gcn(x["gcn_input"])
                return twin.gcn.loss(adjacency, x["gcn_target"])
            shape = f"graphs {batch}, nodes {n}"
        # burn's Adam defaults: betas 0.9/0.999, eps 1e-5.
        opt = torch.optim.Adam(trained.parameters(), lr=LR, betas=(0.9, 0.999), eps=1e-5)

        def step():
            opt.zero_grad(set_to_none=True)
            loss().backward()
            opt.step()
        return (*median_ms(step, repeats, warmup), shape, extra)
    if row == "frame_step":
        net = FrameStageTwin(dims["num_nodes"])
        frames, labels, nxt, successors = frame_batch(dims["num_nodes"])
        opt = torch.optim.Adam(net.parameters(), lr=LR, betas=(0.9, 0.999), eps=1e-5)

        def step():
            opt.zero_grad(set_to_none=True)
            net.loss(frames, labels, nxt, successors).backward()
            opt.step()
        return (*median_ms(step, repeats, warmup), f"frames {FRAMES}, 3x64x64", extra)
    if row == "policy_step":
        n, d = dims["num_nodes"], dims["obs_dim"]
        actions = demo_actions(0, n)
        rows = demo_rows(0, len(actions), d)
        policy = PolicyTwin(twin, actions)
        calls = [0]

        def step():
            calls[0] += 1
            policy.action_distribution(rows[calls[0] % 2])
        return (*median_ms(step, max(10 * repeats, 100), max(warmup, 2)),
                f"obs 1x{d}, nodes {n}", extra)
    raise SystemExit(f"unknown bench row {row!r} (rows: {', '.join(BENCH_ROWS)}, all)")


def bench(path, rows, batch, threads, repeats, warmup):
    torch.set_num_threads(threads)
    dims = DEFAULT_DIMS
    params = None
    if path:
        dims, params, _, _, _ = read_export(path)
    for row in rows:
        median, low, count, shape, extra = bench_row(row, dims, params, batch, repeats, warmup)
        print(json.dumps({
            "row": row,
            **extra,
            "threads": threads,
            "repeats": count,
            "median_ms": round(median, 3),
            "min_ms": round(low, 3),
            "shape": shape,
            "torch": torch.__version__,
        }), flush=True)
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file", nargs="?", help="JSON file written by the twin_export example")
    ap.add_argument("--tol", type=float, default=1e-4, help="max abs error allowed (check mode)")
    ap.add_argument("--weights", metavar="SAFETENSORS",
                    help="check mode: take the weights from this file of `ntg export` "
                         "(model.safetensors) instead of the JSON file's copy")
    ap.add_argument("--bench", nargs="?", const="state_step", metavar="ROW",
                    help="time ROW instead (default state_step; 'all' or ROW,ROW: "
                         f"{', '.join(BENCH_ROWS)})")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=3)
    args = ap.parse_args()
    if args.bench:
        rows = BENCH_ROWS if args.bench == "all" else args.bench.split(",")
        for row in rows:
            if row not in BENCH_ROWS:
                ap.error(f"unknown bench row {row!r} (rows: {', '.join(BENCH_ROWS)}, all)")
        return bench(args.file, rows, args.batch, args.threads, args.repeats, args.warmup)
    if not args.file:
        ap.error("give the exported FILE (or --bench)")
    torch.set_num_threads(args.threads)
    return check(args.file, args.tol, args.weights)


if __name__ == "__main__":
    sys.exit(main())
