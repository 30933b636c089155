"""Microseconds per EKF predict + update (15-state homography EKF), against filterpy's
ExtendedKalmanFilter measured in the same run.

    python benchmarks/ekf.py [--n 2000] [--repeat 5]

Prints, best of ``repeat`` runs of ``n`` iterations each:
- algebra: P = F P F^T + Q then a Joseph-form corner update, F given (ours vs filterpy);
- predict + update including f(x) and its analytic Jacobian (both sides use ours for F);
- one full plugin tick (homography update, prediction, gated corner update).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators import ekf_math as em
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF

DT = 1 / 30


class _Fpy(ExtendedKalmanFilter):
    fx = None

    def predict_x(self, u=0):
        if self.fx is not None:
            self.x = self.fx


def best_us(fn, n: int, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="iterations per run")
    ap.add_argument("--repeat", type=int, default=5, help="runs; the best is reported")
    args = ap.parse_args(argv)

    est = HomographyEKF()
    est.initialize(Box(300.0, 200.0, 40.0, 30.0), 0.0)
    x0, P0 = est.state.x.copy(), est.state.P.copy()
    n = x0.size
    Hb = em.selector(n, em.CORNERS)
    R, Q = est._box_noise(x0, 1.0), np.diag(est._process_noise(x0) * DT)
    H = np.array([[1.001, 0.002, 3.0], [-0.002, 1.001, -1.0], [1e-7, 0.0, 1.0]])
    x0[em.HOM] = H.reshape(9)
    z = np.array([301.0, 201.0, 341.0, 231.0])
    _, F = em.transition(x0, DT, 1)

    def ours_algebra():
        P = em.predict_cov(P0, F, Q)
        em.joseph_update_block(x0, P, z, em.CORNERS, R)

    ref = _Fpy(dim_x=n, dim_z=4)

    def fpy_algebra():
        ref.x, ref.P, ref.F, ref.Q = x0, P0, F, Q
        ref.predict()
        ref.update(z, lambda x: Hb, lambda x: Hb @ x, R=R)

    def ours_full():
        fx, F1 = em.transition(x0, DT, 1)
        P = em.predict_cov(P0, F1, Q)
        em.joseph_update_block(fx, P, z, em.CORNERS, R)

    def fpy_full():
        ref.fx, ref.F = em.transition(x0, DT, 1)
        ref.x, ref.P, ref.Q = x0, P0, Q
        ref.predict()
        ref.update(z, lambda x: Hb, lambda x: Hb @ x, R=R)

    cov = np.diag([1e-8, 1e-8, 1e-4, 1e-8, 1e-8, 1e-4, 1e-14, 1e-14, 0.0])
    tick = [0]

    def plugin_tick():
        tick[0] += 1
        t = tick[0] * DT
        det = TrackerOutput(Box(300.0, 200.0, 40.0, 30.0), 0.9)
        est.step(t, [Stamped(Motion(H, cov), t, t)], [Stamped(det, t, t)])

    def us(fn):
        return best_us(fn, args.n, args.repeat)

    rows = [("predict + update, F given", us(ours_algebra), us(fpy_algebra)),
            ("predict + update with f(x), Jacobian", us(ours_full), us(fpy_full))]
    for name, ours, theirs in rows:
        print(f"{name:40s} ours {ours:7.1f} us   filterpy {theirs:7.1f} us   ratio filterpy/ours {theirs / ours:5.2f}")
    full = us(plugin_tick)
    print(f"{'plugin tick (H + predict + box update)':40s} ours {full:7.1f} us   "
          f"= {1e6 / full:,.0f} ticks/s (a 30 Hz estimator uses {full * 30 / 1e4:.3f} % of a core)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
