"""Scheduler benchmark (one command: ``python benchmarks/scheduler.py``).

1. Overhead per frame with no-op blocks (tracker + egomotion + estimator under LTP and EOP@10Hz),
   against a plain loop calling the same no-op blocks in the same run.
2. Wall time of EOP@10Hz against LTP with a real tracker (``kcf`` when installed, otherwise a
   tracker that sleeps a fixed time) on the same synthetic sequences: EOP runs the tracker on a
   third of the frames, so it should cost about a third.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from mata_eval.run.scheduler import run_sequence
from mata_eval.core.sequence import Sequence
from mata_eval.types import Estimate, Motion, TrackerOutput


class NoOpTracker:
    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        return TrackerOutput(self.box, 1.0)


class NoOpEgoMotion:
    def initialize(self, image):
        pass

    def estimate(self, image):
        return Motion.identity()


class NoOpEstimator:
    def initialize(self, box, t):
        self.est = Estimate(box)
        return self.est

    def step(self, t, motions=(), detections=()):
        return self.est


class SleepTracker:
    """Stands in for a real tracker when ``kcf`` is not installed: a fixed cost per call."""

    def __init__(self, seconds: float):
        self.seconds = seconds

    def initialize(self, image, box):
        self.box = box
        time.sleep(self.seconds)

    def track(self, image, prior=None):
        time.sleep(self.seconds)
        return TrackerOutput(self.box, 1.0)


def constant_sequence(n: int) -> Sequence:
    img = np.zeros((8, 8, 3), np.uint8)
    gt = np.tile([1.0, 1.0, 4.0, 4.0], (n, 1))
    return Sequence("noop", gt, 30.0, loader=lambda k: img)


def moving_target_sequence(seed: int, n: int, w: int = 320, h: int = 240) -> Sequence:
    """A textured background under a drifting camera with a bright textured target: used only
    when ``mata_eval.data.synth`` is not available."""
    rng = np.random.default_rng(seed)
    bg = (rng.random((h + 200, w + 200, 3)) * 255).astype(np.uint8)
    target = (rng.random((30, 40, 3)) * 127 + 128).astype(np.uint8)
    pos = np.cumsum(rng.normal(0, 1.5, (n, 2)), axis=0) + [w / 2 - 20, h / 2 - 15]
    pos = np.clip(pos, 0, [w - 41, h - 31])
    cam = np.cumsum(rng.normal(0, 0.7, (n, 2)), axis=0).clip(-99, 99).astype(int) + 100
    gt = np.column_stack([pos, np.full(n, 40.0), np.full(n, 30.0)])

    def loader(k):
        img = bg[cam[k, 1]:cam[k, 1] + h, cam[k, 0]:cam[k, 0] + w].copy()
        x, y = int(pos[k, 0]), int(pos[k, 1])
        img[y:y + 30, x:x + 40] = target
        return img

    return Sequence(f"moving{seed}", gt, 30.0, loader=loader)


def synthetic_sequences(count: int, n: int) -> tuple[list[Sequence], str]:
    try:
        from mata_eval.data import synth

        seqs = []
        for s in range(count):
            frames, gt, *_ = synth.render_sequence(s, n, 320, 240)
            frames = list(frames)
            seqs.append(Sequence(f"synth{s}", np.asarray(gt, float), 30.0, loader=lambda k, f=frames: f[k]))
        return seqs, "mata_eval.data.synth.render_sequence"
    except Exception as exc:  # synth not written yet, or another API
        return [moving_target_sequence(s, n) for s in range(count)], f"built-in moving target ({type(exc).__name__} from synth)"


def make_tracker():
    try:
        from mata_eval.params import build_params
        from mata_eval.core.registry import load_registry

        entry = load_registry().get("tracker", "kcf")
        return (lambda: entry.cls(build_params(entry.cls.Params, {}))), "kcf"
    except KeyError:
        return (lambda: SleepTracker(0.004)), "sleep 4 ms (kcf not installed)"


def best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    from mata_eval_plugins.protocols.eop import EOP
    from mata_eval_plugins.protocols.ltp import LTP

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=3000, help="frames of the no-op sequence")
    ap.add_argument("--sequences", type=int, default=3, help="synthetic sequences for the tracker benchmark")
    ap.add_argument("--seq-frames", type=int, default=150, help="frames per synthetic sequence")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    # 1. Overhead with no-op blocks.
    n = args.frames
    seq = constant_sequence(n)

    def plain_loop():
        tr, eg, es = NoOpTracker(), NoOpEgoMotion(), NoOpEstimator()
        tr.initialize(seq.image(0), seq.init_box)
        eg.initialize(seq.image(0))
        es.initialize(seq.init_box, 0.0)
        out = np.empty((n, 4))
        for k in range(1, n):
            img = seq.image(k)
            m = eg.estimate(img)
            d = tr.track(img, None)
            out[k] = es.step(k / 30.0, [m], [d]).box.as_array()

    def sched(proto):
        return lambda: run_sequence(seq, NoOpTracker(), NoOpEgoMotion(), NoOpEstimator(), proto,
                                    np.random.default_rng(0))

    t_loop = best_of(plain_loop, args.repeats)
    t_ltp = best_of(sched(LTP()), args.repeats)
    t_eop = best_of(sched(EOP(EOP.Params(tracker_hz=10.0))), args.repeats)
    print(f"no-op blocks, {n} frames (best of {args.repeats}):")
    print(f"  plain loop            {1e6 * t_loop / n:8.1f} us/frame")
    print(f"  scheduler LTP (MATA)  {1e6 * t_ltp / n:8.1f} us/frame  overhead {1e6 * (t_ltp - t_loop) / n:6.1f} us/frame"
          f"  ratio {t_ltp / t_loop:5.1f}x")
    print(f"  scheduler EOP@10Hz    {1e6 * t_eop / n:8.1f} us/frame  overhead {1e6 * (t_eop - t_loop) / n:6.1f} us/frame")

    # 2. EOP@10Hz against LTP with a real tracker on the same sequences.
    seqs, source = synthetic_sequences(args.sequences, args.seq_frames)
    factory, tname = make_tracker()
    for s in seqs:  # render / cache frames outside the timing
        for k in range(len(s)):
            s.image(k)

    def run_all(proto):
        for s in seqs:
            run_sequence(s, factory(), None, None, proto, np.random.default_rng(0))

    t_l = best_of(lambda: run_all(LTP()), args.repeats)
    t_e = best_of(lambda: run_all(EOP(EOP.Params(tracker_hz=10.0))), args.repeats)
    frames = sum(len(s) for s in seqs)
    print(f"tracker {tname}, {len(seqs)} sequences x {args.seq_frames} frames from {source}:")
    print(f"  LTP        {t_l:7.3f} s  ({1e3 * t_l / frames:6.2f} ms/frame)")
    print(f"  EOP@10Hz   {t_e:7.3f} s  ({1e3 * t_e / frames:6.2f} ms/frame)")
    print(f"  EOP/LTP wall-time ratio {t_e / t_l:.3f} (expected about 1/3 = 0.333: the tracker runs on frames 0, 3, 6, ...)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
