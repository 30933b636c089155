"""Block C's whole tick against filterpy doing the same algebra, measured in the same run.

    OMP_NUM_THREADS=1 python benchmarks/ekf_tick.py [--n 1000] [--repeat 7] [--preset mata|paper]
        [--backend numba|numpy] [--param KEY=VALUE]... [--cold]

- ours: one ``HomographyEKF.step()`` with one motion (9-value homography update, gated) and one
  detection (4 corners, EWMA gate), 15 states, constant velocity: the tick's bookkeeping, the
  transition with its Jacobian, both updates, the Estimate it returns. The inputs (Stamped
  Motion and TrackerOutput) are built before the clock starts, as filterpy's are;
  ``--backend`` (default numba when installed): the compiled tick or the numpy reference;
  ``--param``: a homography_ekf parameter (value in YAML), e.g. ``--param feedback_hold=false``;
- anchor: filterpy's ``KalmanFilter`` on the same 15 states: ``predict()`` with the same F and Q,
  then ``update()`` with a 9-value and a 4-value measurement (selector H), i.e. the algebra alone.
Prints microseconds per tick (min and median over ``repeat`` runs of ``n`` ticks, one thread) and
the ratio filterpy / ours (issue 18 target: >= 3 and a tick <= 20 us).

``--cold``: each tick (ours and filterpy's alike) runs after a 1280x720 Gaussian blur, outside the
clock, as block C runs in a MATA pipeline between blocks B and A, whose image work evicts the
code and data the tick needs from the caches; prints each tick's CPU time, min and median over
``n`` x ``repeat`` ticks, and the ratio of the medians. On board this is what a tick costs.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time

import cv2
import numpy as np
from filterpy.kalman import KalmanFilter

from mata_eval.params import build_params, parse_key_values
from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators import ekf_math as em
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF

DT = 1 / 30
H_MEAS = np.array([[1.001, 0.002, 3.0], [-0.002, 1.001, -1.0], [1e-7, 0.0, 1.0]])
C_MEAS = np.diag([1e-8, 1e-8, 1e-4, 1e-8, 1e-8, 1e-4, 1e-14, 1e-14, 0.0])


def per_tick_us(fn, n: int, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn(n)
        out.append((time.process_time() - t0) / n * 1e6)
    return out


def cold_ticks_us(ours, reference, n: int) -> tuple[list[float], list[float]]:
    """CPU microseconds of each of ``n`` calls of ``ours`` and of ``reference``, alternated, each
    after a 1280x720 Gaussian blur (OpenCV, one thread) that evicts the caches (``--cold``)."""
    image = np.random.default_rng(0).integers(0, 256, (720, 1280, 3), np.uint8)
    cv2.setNumThreads(1)
    out: tuple[list[float], list[float]] = ([], [])
    for _ in range(n):
        for fn, times in ((ours, out[0]), (reference, out[1])):
            cv2.GaussianBlur(image, (5, 5), 1.0)
            t0 = time.process_time()
            fn(1)
            times.append((time.process_time() - t0) * 1e6)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="ticks per run")
    ap.add_argument("--repeat", type=int, default=7, help="runs (min and median reported)")
    ap.add_argument("--preset", choices=("mata", "paper"), default=None, help="block C preset (default: the plugin's)")
    ap.add_argument("--backend", choices=("numba", "numpy"), default=None,
                    help="block C backend (default: numba when installed, else numpy)")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="a homography_ekf parameter (repeatable; value in YAML)")
    ap.add_argument("--cold", action="store_true",
                    help="each tick after a 1280x720 image filter (caches evicted, as between MATA's blocks)")
    args = ap.parse_args(argv)
    backend = args.backend or ("numba" if importlib.util.find_spec("numba") else "numpy")
    try:
        params = build_params(HomographyEKF.Params, {**({} if args.preset is None else {"preset": args.preset}),
                                                     **parse_key_values(args.param)})
    except ValueError as exc:
        ap.error(f"--param: {exc}")
    t0 = time.process_time()
    est = HomographyEKF(params, backend=backend)   # loads (or compiles) the numba kernel
    first_call_s = time.process_time() - t0
    est.initialize(Box(300.0, 200.0, 40.0, 30.0), 0.0)
    clock = [0]

    def inputs(k: int):
        t = k * DT
        det = TrackerOutput(Box(300.0, 200.0, 40.0, 30.0), 0.9)
        return t, [Stamped(Motion(H_MEAS, C_MEAS), t, t)], [Stamped(det, t, t)]

    est.step(*inputs(0))
    ticks = [inputs(k) for k in range(1, args.n * (args.repeat + 1) + 1)]

    def ours(n: int) -> None:
        for k in range(clock[0], clock[0] + n):
            est.step(*ticks[k])
        clock[0] += n

    ours(args.n)                    # warm-up: the confidence history fills up

    x0 = est.state.x.copy()
    dim = x0.size
    _, F = em.transition(x0, DT, 1)
    kf = KalmanFilter(dim_x=dim, dim_z=4)
    kf.x, kf.P, kf.F = x0.copy(), est.state.P.copy(), F
    kf.Q = np.diag(np.linspace(1e-3, 1.0, dim))
    H9, H4 = em.selector(dim, em.HOM), em.selector(dim, em.CORNERS)
    R9, R4 = np.diag(np.diag(C_MEAS) + 1e-10), 4.0 * np.eye(4)
    z9, z4 = H_MEAS.reshape(9), np.array([300.0, 200.0, 340.0, 230.0])
    P0 = kf.P.copy()

    def filterpy(n: int) -> None:
        for _ in range(n):
            kf.P = P0  # keep the numbers in range over many ticks
            kf.predict()
            kf.update(z9, R=R9, H=H9)
            kf.update(z4, R=R4, H=H4)

    setup = f"15 states, preset {est.params.preset}{''.join(f', {p}' for p in args.param)}, backend {backend}, "
    if args.cold:
        ours_us, ref_us = cold_ticks_us(ours, filterpy, args.n * args.repeat)
        print(setup + f"{args.n * args.repeat} ticks, each after a 1280x720 Gaussian blur (cold caches), "
                      "CPU time, one thread")
        ratio_line = f"ratio of the medians filterpy / ours  {np.median(ref_us) / np.median(ours_us):.2f}"
    else:
        ours_us, ref_us = [], []
        for _ in range(args.repeat):  # interleaved: load changes hit both alike
            ours_us += per_tick_us(ours, args.n, 1)
            ref_us += per_tick_us(filterpy, args.n, 1)
        ratio = np.array(ref_us) / np.array(ours_us)
        print(setup + f"{args.n} ticks x {args.repeat} runs, CPU time, one thread; "
                      f"filter built in {first_call_s * 1e3:.0f} ms"
                      + (" (numba: cache load or compile)" if backend == "numba" else ""))
        ratio_line = (f"ratio filterpy / ours  min {ratio.min():.2f}  median {np.median(ratio):.2f}   "
                      "(target >= 3, tick <= 20 us)")
    print(f"  filterpy predict + 9-value + 4-value update (anchor)  us  min {min(ref_us):7.1f}  median {np.median(ref_us):7.1f}")
    print(f"  HomographyEKF.step(), one motion + one detection      us  min {min(ours_us):7.1f}  median {np.median(ours_us):7.1f}")
    print("  " + ratio_line)
    return 0

if __name__ == "__main__":
    sys.exit(main())
