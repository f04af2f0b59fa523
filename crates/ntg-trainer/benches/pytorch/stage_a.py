"""PyTorch twin of stage A (the shared frame encoder), for throughput side by
side with `cargo bench -p ntg-trainer --bench stages -- stage_a`.

The same network as `ntg_model::FrameStageNet` with block stacking's
settings: three 3x3 convolutions of stride 2 and padding 1 (3 -> 32 -> 64 ->
64 channels, 64x64 -> 8x8) with ReLU, a linear layer to 128, the
localizer's node embeddings NE_loc [18, 128] (logits Enc(o) . NE_loc(n)),
and the edge head (W [Enc(o); NE(n)] . NE_loc(a), masked to the task
graph's successors), both cross-entropy losses, Adam. Like the Rust bench:

- train: one step (forward, backward, Adam) on 64 frames;
- encode: the encoder alone over 256 frames, no gradients.

With `--keypoints` the encoder is block stacking's: the third convolution
keeps its input's side (stride 1) and the linear layer reads its channels'
spatial-softmax expected coordinates (`stage_a_keypoints_64` in the Rust
bench); `--image-size 128 --stem 16` adds a 3x3 stride-2 convolution of 16
channels in front, for 128x128 frames (`stage_a_keypoints_128_stem16`).

Prints one JSON object: median milliseconds per call and frames per second.

    python stage_a.py [--threads 2] [--repeats 30] [--keypoints] [--image-size S] [--stem C]
"""
import argparse
import json
import statistics
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

NODES = 18  # 16 flat actions + <start> + <end>
HIDDEN = 128
TRAIN_BATCH = 64
ENCODE_BATCH = 256


def expected_coordinates(maps):
    """Spatial softmax: per channel, the expected x then y (from -1 to 1)."""
    b, c, h, w = maps.shape
    p = F.softmax(maps.flatten(2), dim=2)
    xs = torch.linspace(-1.0, 1.0, w).repeat(h)
    ys = torch.linspace(-1.0, 1.0, h).repeat_interleave(w)
    return torch.cat([(p * xs).sum(2), (p * ys).sum(2)], 1)


class FrameStageNet(nn.Module):
    def __init__(self, image_size=64, stem=0, keypoints=False):
        super().__init__()
        self.stem = nn.Conv2d(3, stem, 3, 2, 1) if stem > 0 else None
        c0 = stem if stem > 0 else 3
        side = image_size // 2 if stem > 0 else image_size
        self.keypoints = keypoints
        self.c1 = nn.Conv2d(c0, 32, 3, 2, 1)
        self.c2 = nn.Conv2d(32, 64, 3, 2, 1)
        self.c3 = nn.Conv2d(64, 64, 3, 1 if keypoints else 2, 1)
        flat = 2 * 64 if keypoints else 64 * (side // 8) ** 2
        self.fc = nn.Linear(flat, HIDDEN)
        self.loc_nodes = nn.Parameter(torch.randn(NODES, HIDDEN) / HIDDEN**0.5)
        self.edge_nodes = nn.Parameter(torch.randn(NODES, HIDDEN) / HIDDEN**0.5)
        self.w = nn.Linear(2 * HIDDEN, HIDDEN)

    def encode(self, x):
        x = x - 0.5
        if self.stem is not None:
            x = F.relu(self.stem(x))
        x = F.relu(self.c1(x))
        x = F.relu(self.c2(x))
        x = F.relu(self.c3(x))
        if self.keypoints:
            return self.fc(expected_coordinates(x))
        return self.fc(x.flatten(1))

    def loss(self, frames, labels, nxt, successors):
        enc = self.encode(frames)
        loc_logits = enc @ self.loc_nodes.t()
        query = self.w(torch.cat([enc, self.edge_nodes[labels]], 1))
        edge_logits = (query @ self.loc_nodes.t()).masked_fill(~successors, -1e9)
        return F.cross_entropy(loc_logits, labels) + F.cross_entropy(edge_logits, nxt)


def median_ms(fn, repeats, warmup=3):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--image-size", type=int, default=64)
    ap.add_argument("--stem", type=int, default=0)
    ap.add_argument("--keypoints", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    s = args.image_size
    net = FrameStageNet(s, args.stem, args.keypoints)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    frames = torch.rand(TRAIN_BATCH, 3, s, s)
    labels = torch.randint(0, NODES, (TRAIN_BATCH,))
    nxt = torch.randint(0, NODES, (TRAIN_BATCH,))
    successors = torch.rand(TRAIN_BATCH, NODES) < 0.3
    successors[torch.arange(TRAIN_BATCH), nxt] = True

    def train_step():
        opt.zero_grad()
        net.loss(frames, labels, nxt, successors).backward()
        opt.step()

    many = torch.rand(ENCODE_BATCH, 3, s, s)

    def encode():
        with torch.no_grad():
            net.encode(many)

    train = median_ms(train_step, args.repeats)
    enc = median_ms(encode, args.repeats)
    print(json.dumps({
        "torch": torch.__version__,
        "threads": args.threads,
        "image_size": s,
        "stem": args.stem,
        "keypoints": args.keypoints,
        "train_ms": round(train, 3),
        "train_frames_per_s": round(TRAIN_BATCH / train * 1e3, 1),
        "encode_ms": round(enc, 3),
        "encode_frames_per_s": round(ENCODE_BATCH / enc * 1e3, 1),
    }))


if __name__ == "__main__":
    main()
