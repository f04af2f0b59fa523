"""Linear read-outs of the block-stacking state from frame-encoder
embeddings (the files `encoder_probe.rs` writes): ridge regression fitted
on the keyframes of 80% of the validation tasks, R^2 on the other 20%.
Diagnostic only: the state never trains the encoder.

    python3 encoder_probe.py OUT
"""
import json
import sys
from pathlib import Path

import numpy as np


def load(out, name, cols, dtype=np.float32):
    return np.fromfile(out / name, dtype=dtype).reshape(-1, cols)


def ridge_r2(x, y, train, test, alpha):
    """R^2 per output column of a ridge fit (dual form when wide)."""
    mx, my = x[train].mean(0), y[train].mean(0)
    xt, yt = x[train] - mx, y[train] - my
    if xt.shape[1] > xt.shape[0]:
        k = xt @ xt.T
        a = np.linalg.solve(k + alpha * np.eye(len(k)), yt)
        w = xt.T @ a
    else:
        w = np.linalg.solve(xt.T @ xt + alpha * np.eye(xt.shape[1]), xt.T @ yt)
    pred = (x[test] - mx) @ w + my
    resid = ((y[test] - pred) ** 2).sum(0)
    total = ((y[test] - y[test].mean(0)) ** 2).sum(0)
    return 1 - resid / np.maximum(total, 1e-12)


def main():
    out = Path(sys.argv[1])
    shapes = json.loads((out / "shapes.json").read_text())
    state = load(out, "state.f32", shapes["state"]).astype(np.float64)
    task = np.fromfile(out / "task.u32", dtype=np.uint32)
    tasks = np.unique(task)
    rng = np.random.default_rng(0)
    held = set(rng.choice(tasks, size=len(tasks) // 5, replace=False).tolist())
    test = np.array([t in held for t in task])
    train = ~test
    varying = state[train].std(0) > 1e-6
    print(f"{len(state)} keyframes, {len(tasks)} tasks; {test.sum()} held-out rows; "
          f"{varying.sum()} of {state.shape[1]} state values vary")
    for name in ["embedding", "random", "pixels"]:
        x = load(out, f"{name}.f32", shapes[name]).astype(np.float64)
        best = None
        for alpha in [1e-2, 1e-1, 1, 10, 100, 1000]:
            # alpha chosen on a split of the training tasks, not on `test`.
            inner_tasks = np.unique(task[train])
            inner_held = set(inner_tasks[: len(inner_tasks) // 5].tolist())
            inner_test = train & np.array([t in inner_held for t in task])
            inner_train = train & ~inner_test
            r2 = ridge_r2(x, state, inner_train, inner_test, alpha)[varying].mean()
            if best is None or r2 > best[0]:
                best = (r2, alpha)
        r2 = ridge_r2(x, state, train, test, best[1])[varying]
        print(f"{name:>9} ({x.shape[1]} values): mean R^2 {r2.mean():.3f} "
              f"(min {r2.min():.3f}, alpha {best[1]:g}); per value {np.round(r2, 2).tolist()}")


if __name__ == "__main__":
    main()
