"""MATA's cost on top of its tracker: CPU of a MATA run (KCF + grid_lk + homography_ekf) against
the baseline run (KCF alone) under LTP, measured in the same process, interleaved.

    OMP_NUM_THREADS=1 python benchmarks/mata_overhead.py [--frames 60] [--repeat 5] [--decode]
        [--grid-lk KEY=VALUE]...

Frames of the real 1280x720 and 1024x540 sequences of ``$MATA_SHARED_DATA/sequences/aerial30``
are decoded once, before any timing (decoding costs both runs the same), or with ``--decode`` in
each run, as ``mata-eval run`` does; ``--grid-lk`` sets a parameter of MATA's block B (to weigh a
cheaper setting, e.g. ``--grid-lk grid_cols=12 --grid-lk grid_rows=12``). Each repetition runs
the baseline then MATA over every sequence, OpenCV on one thread. Prints, min and median over
the repetitions:
- CPU seconds of the baseline run and of the MATA run, and their ratio (target <= 1.25), and
  the CPU seconds of each block in them (where MATA's extra time goes);
- per-frame CPU milliseconds of each block call as the scheduler timed them (its clock set to
  the process CPU time; min and median over the frames of the MATA runs): the egomotion block at 1280x720 (target <= 3 ms) and the estimator tick.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from mata_eval.core.sequence import Sequence
from mata_eval.params import build_params, parse_key_values
from mata_eval.run.scheduler import run_sequence
from mata_eval_plugins.egomotion.grid_lk import GridLK
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF
from mata_eval_plugins.protocols.ltp import LTP
from mata_eval_plugins.trackers.kcf import KCFTracker as KCF

SEQUENCES = ("MountainBike6", "Surfing06", "S0310", "S0601")


def load(root: Path, name: str, frames: int, decode: bool) -> Sequence:
    folder = root / name
    gt = np.loadtxt(folder / "groundtruth_rect.txt", delimiter=",")[:frames]
    paths = tuple(str(p) for p in sorted((folder / "img").iterdir())[:len(gt)])
    if decode:  # each run reads its frames, as `mata-eval run` does
        return Sequence(name, gt, fps=30.0, frame_paths=paths)
    images = [cv2.imread(p) for p in paths]
    return Sequence(name, gt, fps=30.0, loader=images.__getitem__)


def one_run(seq: Sequence, mata: bool, grid_lk: dict | None = None):
    c0 = time.process_time()
    run = run_sequence(seq, KCF(KCF.Params()), GridLK(GridLK.Params(**(grid_lk or {}))) if mata else None,
                       HomographyEKF(HomographyEKF.Params()) if mata else None, LTP(), np.random.default_rng(0),
                       clock=time.process_time)
    return time.process_time() - c0, run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--decode", action="store_true", help="decode the JPEG frames in each run (counted on both sides)")
    ap.add_argument("--grid-lk", action="append", default=[], metavar="KEY=VALUE",
                    help="a grid_lk parameter of the MATA run (repeatable; value in YAML)")
    args = ap.parse_args(argv)
    try:
        grid_lk = parse_key_values(args.grid_lk)
        build_params(GridLK.Params, grid_lk)
    except ValueError as exc:
        ap.error(f"--grid-lk: {exc}")
    cv2.setNumThreads(1)
    root = Path(os.environ.get("MATA_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    root = root / "sequences" / "aerial30"
    names = [n for n in SEQUENCES if (root / n).is_dir()]
    if not names:
        print(f"no sequences under {root}: set MATA_SHARED_DATA")
        return 1
    seqs = [load(root, n, args.frames, args.decode) for n in names]
    one_run(seqs[0], True, grid_lk)  # untimed: loads block C's compiled tick (once per process)
    base_cpu, mata_cpu, ego_ms, est_ms = [], [], {}, []
    blocks: dict[str, list[float]] = {}  # CPU s of each block over the sequences, per repetition
    for _ in range(args.repeat):
        b = m = 0.0
        sums: dict[str, float] = {}
        for seq in seqs:
            cpu, run = one_run(seq, False)
            b += cpu
            sums["baseline tracker"] = sums.get("baseline tracker", 0.0) + np.nansum(run.wall_ms["tracker"]) / 1e3
            cpu, run = one_run(seq, True, grid_lk)
            m += cpu
            for block, ms in run.wall_ms.items():
                sums[f"MATA {block}"] = sums.get(f"MATA {block}", 0.0) + np.nansum(ms) / 1e3
            size = seq.image(0).shape[1::-1]
            ego_ms.setdefault(size, []).extend(run.wall_ms["egomotion"][1:].tolist())
            est_ms.extend(run.wall_ms["estimator"][1:].tolist())
        base_cpu.append(b)
        mata_cpu.append(m)
        for block, cpu in sums.items():
            blocks.setdefault(block, []).append(cpu)
    n_frames = sum(len(s) for s in seqs)
    ratio = np.array(mata_cpu) / np.array(base_cpu)
    print(f"{len(seqs)} sequences ({', '.join(names)}), {n_frames} frames, LTP, KCF, {args.repeat} repetitions, "
          f"OpenCV threads 1, frames {'decoded in each run' if args.decode else 'decoded before timing'}"
          + (f", grid_lk {grid_lk}" if grid_lk else ""))
    print(f"  baseline run (KCF)           CPU s  min {min(base_cpu):.3f}  median {np.median(base_cpu):.3f}")
    print(f"  MATA run (KCF+grid_lk+EKF)   CPU s  min {min(mata_cpu):.3f}  median {np.median(mata_cpu):.3f}")
    print(f"  ratio MATA / baseline (per repetition)  min {ratio.min():.3f}  median {np.median(ratio):.3f}  "
          f"(target <= 1.25)")
    print("  per block, CPU s over the sequences  " + "  ".join(
        f"{block} {min(v):.3f} / {np.median(v):.3f}" for block, v in blocks.items()))
    for (w, h), ms in ego_ms.items():
        ms = np.array(ms)
        print(f"  egomotion block {w}x{h}  CPU ms per frame  min {ms.min():.2f}  median {np.median(ms):.2f}"
              + ("  (target <= 3 at 1280x720)" if (w, h) == (1280, 720) else ""))
    est = np.array(est_ms)
    print(f"  estimator tick  CPU us per frame  min {1e3 * est.min():.0f}  median {1e3 * np.median(est):.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
