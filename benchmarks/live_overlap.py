"""Do MATA's blocks overlap when the live protocol runs them in threads? (one command:
``python benchmarks/live_overlap.py [--tracker vittrack] [--calls 40]``, needs ../shared/data)

Each block (the tracker, ``grid_lk`` ego-motion, the ``homography_ekf`` estimator) is called
``--calls`` times on real frames: first one block after the other in this thread (the sequential
baseline), then the three at once in three threads (what ``protocol: live`` does), then in
three processes (no GIL at all). Overlap = sequential wall time / concurrent wall time: up to
the number of free cores when the blocks release the GIL; threads close to processes means the
GIL is not what limits them. The machine's load average is printed beside the figures (on a
shared machine other processes take the cores the blocks would overlap on).
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing as mp
import os
import sys
import threading
import time
from pathlib import Path

from mata_eval.core.registry import load_registry
from mata_eval.core.types import Stamped

BLOCKS = ("tracker", "egomotion", "estimator")


def shared_data() -> Path:
    root = Path(os.environ.get("MATA_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    if not (root / "sequences" / "aerial30").is_dir():
        sys.exit(f"live_overlap: needs the real sequences in {root}/sequences/aerial30 (set MATA_SHARED_DATA)")
    return root


def make_calls(tracker: str, n: int):
    """One zero-argument-per-call function per block, on frames of a real 30 fps sequence."""
    from mata_eval.data.datasets.folder import FolderDataset

    root = shared_data()
    seq = FolderDataset(FolderDataset.Params(root=str(root / "sequences" / "aerial30"), sequences=["S0310"])).sequences()[0]
    images = [seq.image(k) for k in range(min(n + 1, len(seq)))]
    reg = load_registry()
    models = root / "models"
    kw = {"kcf": {}, "vittrack": {"model": str(models / "vittrack" / "object_tracking_vittrack_2023sep.onnx")},
          "nanotrack": {"backbone": str(models / "nanotrack" / "v2" / "nanotrack_backbone_sim.onnx"),
                        "head": str(models / "nanotrack" / "v2" / "nanotrack_head_sim.onnx")}}[tracker]

    def build(kind, name, **params):
        entry = reg.get(kind, name)
        return entry.cls(entry.cls.Params(**params))

    frame = lambda i: images[1 + i % (len(images) - 1)]  # noqa: E731
    trk = build("tracker", tracker, **kw)
    trk.initialize(images[0], seq.init_box)
    det = trk.track(images[1])
    ego = build("egomotion", "grid_lk")
    ego.initialize(images[0])
    motion = ego.estimate(images[1])
    est = build("estimator", "homography_ekf")
    est.initialize(seq.init_box, 0.0)
    ticks = itertools.count(1)

    def step(i):
        t = next(ticks) / seq.fps
        est.step(t, [Stamped(motion, t, t)], [Stamped(det, t, t)])

    return {"tracker": lambda i: trk.track(frame(i)), "egomotion": lambda i: ego.estimate(frame(i)),
            "estimator": step}


def loop(fn, n, barrier=None) -> float:
    if barrier is not None:
        barrier.wait()
    t0 = time.perf_counter()
    for i in range(n):
        fn(i)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracker", default="vittrack", choices=["kcf", "vittrack", "nanotrack"])
    ap.add_argument("--calls", type=int, default=40)
    args = ap.parse_args(argv)
    fns = make_calls(args.tracker, args.calls)
    for fn in fns.values():  # warm-up
        loop(fn, 3)
    cpu0 = time.process_time()
    alone = {b: loop(fns[b], args.calls) for b in BLOCKS}
    sequential = sum(alone.values())

    in_threads: dict[str, float] = {}
    barrier = threading.Barrier(len(BLOCKS))
    threads = [threading.Thread(target=lambda b=b: in_threads.__setitem__(b, loop(fns[b], args.calls, barrier)))
               for b in BLOCKS]
    t0 = time.perf_counter()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    threaded = time.perf_counter() - t0

    ctx = mp.get_context("fork")  # the children inherit the built blocks
    pbarrier, queue = ctx.Barrier(len(BLOCKS)), ctx.Queue()
    procs = [ctx.Process(target=lambda b=b: queue.put((b, loop(fns[b], args.calls, pbarrier)))) for b in BLOCKS]
    t0 = time.perf_counter()
    for p in procs:
        p.start()
    in_procs = dict(queue.get() for _ in BLOCKS)
    for p in procs:
        p.join()
    processes = time.perf_counter() - t0

    print(f"{args.tracker} + grid_lk + homography_ekf, {args.calls} calls each; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}; parent CPU {time.process_time() - cpu0:.2f} s")
    print(f"{'block':<10} {'alone ms':>9} {'threads ms':>11} {'processes ms':>13}   (per call)")
    for b in BLOCKS:
        print(f"{b:<10} {1e3 * alone[b] / args.calls:9.2f} {1e3 * in_threads[b] / args.calls:11.2f} "
              f"{1e3 * in_procs[b] / args.calls:13.2f}")
    print(f"sequential {sequential:.3f} s | threads {threaded:.3f} s: overlap {sequential / threaded:.2f}x | "
          f"processes {processes:.3f} s: overlap {sequential / processes:.2f}x | threads / processes "
          f"{processes / threaded:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
