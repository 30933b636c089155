"""Speed of the metric core: score 123 sequences x 1000 frames (the size of UAV123) with every
metric and aggregate them, against a plain per-frame Python loop measured in the same run.

    python benchmarks/metrics_speed.py [--sequences 123] [--frames 1000] [--repeat 3] [--seed 0]

Target (issue 2): well under a second for the vectorised path. Both paths must agree."""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from mata_eval.score import metrics


def synthetic_results(n_seq: int, n_frames: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Random-walk targets, a tracker that drifts and sometimes jumps away; 2 % NaN GT rows."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_seq):
        xy = 300 + np.cumsum(rng.normal(0, 3, (n_frames, 2)), axis=0)
        wh = np.clip(40 + np.cumsum(rng.normal(0, 0.5, (n_frames, 2)), axis=0), 5, None)
        gt = np.c_[xy, wh]
        pred = gt + np.c_[rng.normal(0, 4, (n_frames, 2)), rng.normal(0, 2, (n_frames, 2))]
        lost = rng.integers(n_frames // 4, n_frames * 2)
        pred[lost:, :2] += 200
        gt[rng.random(n_frames) < 0.02] = np.nan
        out.append((pred, gt))
    return out


def loop_score(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float, float, float, float]:
    """Baseline: the default profile frame by frame in plain Python."""
    thr_iou = metrics.PYSOT_IOU_GRID
    succ = [0] * len(thr_iou)
    prec = [0] * 51
    nprec = [0] * 51
    n = 0
    t_f = None
    for p, g in zip(pred.tolist(), gt.tolist()):
        if any(math.isnan(v) for v in g) or g[2] <= 0 or g[3] <= 0:
            continue
        iw = min(p[0] + max(p[2], 0), g[0] + g[2]) - max(p[0], g[0])
        ih = min(p[1] + max(p[3], 0), g[1] + g[3]) - max(p[1], g[1])
        inter = max(iw, 0) * max(ih, 0)
        union = max(p[2], 0) * max(p[3], 0) + g[2] * g[3] - inter
        o = inter / union if union > 0 else 0.0
        dx = (p[0] + p[2] / 2) - (g[0] + g[2] / 2)
        dy = (p[1] + p[3] / 2) - (g[1] + g[3] / 2)
        d = math.hypot(dx, dy)
        nd = math.hypot(dx / g[2], dy / g[3])
        for i, t in enumerate(thr_iou):
            succ[i] += o > t
        for i in range(51):
            prec[i] += d <= i
            nprec[i] += nd <= i / 100
        if t_f is None and o <= 0:
            t_f = n
        n += 1
    if n == 0:
        return (math.nan,) * 5
    return (succ[10] / n, sum(succ) / len(succ) / n, nprec[20] / n, prec[20] / n,
            (n if t_f is None else t_f) / n)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", type=int, default=123)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    data = synthetic_results(args.sequences, args.frames, args.seed)

    def vectorised():
        items = [(metrics.score_sequence(p, g), ("FM",)) for p, g in data]
        return items, metrics.aggregate(items)

    def loop():
        return [loop_score(p, g) for p, g in data]

    best_vec = best_loop = math.inf
    for _ in range(args.repeat):
        t = time.perf_counter()
        items, agg = vectorised()
        best_vec = min(best_vec, time.perf_counter() - t)
        t = time.perf_counter()
        ref = loop()
        best_loop = min(best_loop, time.perf_counter() - t)

    got = np.array([[s.sr, s.msr, s.pr, s.precision20, s.nt2f] for s, _ in items])
    if not np.allclose(got, np.array(ref), equal_nan=True):
        raise SystemExit("vectorised and loop results differ")
    n = args.sequences * args.frames
    print(f"scored {args.sequences} sequences x {args.frames} frames ({n} frames), all metrics + aggregate")
    print(f"vectorised: {best_vec * 1e3:.1f} ms   (best of {args.repeat}; {n / best_vec / 1e6:.2f} M frames/s)")
    print(f"per-frame python loop: {best_loop * 1e3:.1f} ms")
    print(f"speed-up: {best_loop / best_vec:.1f}x   mean MSR {agg.overall.msr:.4f}, mean NT2F {agg.overall.nt2f:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
