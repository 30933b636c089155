"""A short, deterministic block C scenario used to pin ``preset: paper`` to the filter as it was
before the improved default (commit 3e1713c): rotating, zooming camera with measured
covariances, detections every 3rd tick with varying confidence (some rejected by the paper's
EWMA gate), a one-tick latency, an invalid motion and a NaN box. The outputs of the old filter
on it are stored in tests/data/ekf_paper_reference.npz (regenerate only on purpose:
``python tests/ekf_reference_scenario.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mata_eval.types import Box, Motion, Stamped, TrackerOutput

REFERENCE = Path(__file__).with_name("data") / "ekf_paper_reference.npz"
FPS = 30.0
N = 60


def scenario(seed: int = 3):
    """Per tick k = 1..N-1: (t, motions, detections) lists of Stamped values."""
    rng = np.random.default_rng(seed)
    ticks = []
    pending = []
    box = np.array([300.0, 200.0, 340.0, 230.0])
    for k in range(1, N):
        t = k / FPS
        a = 0.02 * np.sin(k / 7.0)                      # roll of up to ~1 degree per frame
        s = 1.0 + 0.004 * np.cos(k / 5.0)
        H = np.array([[s * np.cos(a), -s * np.sin(a), rng.normal(4.0, 2.0)],
                      [s * np.sin(a), s * np.cos(a), rng.normal(-2.0, 2.0)],
                      [rng.normal(0, 1e-6), rng.normal(0, 1e-6), 1.0]])
        cov = np.diag(np.abs(rng.normal(0, [1e-7, 1e-7, 1e-2, 1e-7, 1e-7, 1e-2, 1e-13, 1e-13, 0.0])))
        motions = [Stamped(Motion(H, cov, valid=(k != 20)), t, t)]
        box = box + np.array([H[0, 2], H[1, 2], H[0, 2], H[1, 2]]) + rng.normal(0, 0.5, 4)
        if k % 3 == 0:
            conf = float(np.clip(0.7 + 0.2 * rng.normal() - (0.6 if 30 <= k < 40 else 0.0), 0, 1))
            z = box + rng.normal(0, 2.0, 4)
            if k == 45:
                z = np.full(4, np.nan)
            pending.append(Stamped(TrackerOutput(Box.from_corners(*z), conf), t, t + 1 / FPS))
        dets = [d for d in pending if d.t_publish <= t + 1e-9]
        pending = [d for d in pending if d.t_publish > t + 1e-9]
        ticks.append((t, motions, dets))
    return ticks


def run(estimator) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (N, 4) and covariance diagonals (N, n) of ``estimator`` over the scenario."""
    out = [estimator.initialize(Box(300.0, 200.0, 40.0, 30.0), 0.0)]
    for t, motions, dets in scenario():
        out.append(estimator.step(t, motions, dets))
    return np.array([e.box.as_array() for e in out]), np.array([np.diag(e.cov) for e in out])


CONFIGS = {"ignore": {}, "compensate": {"delay": "compensate"}, "after": {"h_update": "after_predict"},
           "ca": {"model": "ca"}, "nogate": {"gating": False}}

if __name__ == "__main__":  # writes the reference from the filter as it is now
    from mata_eval_plugins.estimators.homography_ekf import HomographyEKF

    arrays = {}
    for name, kw in CONFIGS.items():
        boxes, covs = run(HomographyEKF(HomographyEKF.Params(**kw)))
        arrays[f"{name}_boxes"], arrays[f"{name}_covs"] = boxes, covs
    np.savez_compressed(REFERENCE, **arrays)
    print(f"wrote {REFERENCE}")
