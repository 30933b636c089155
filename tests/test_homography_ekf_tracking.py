"""Homography EKF on synthetic scenarios with an independent ground truth: a target moving at
constant velocity on a ground plane, seen by a camera whose world-to-image homography A_k is
known. Block B reports H_k = A_k A_{k-1}^-1; block A reports the true box plus noise, every 3rd
tick (EOP with the tracker at 10 Hz on a 30 Hz stream), optionally through a latency."""

from __future__ import annotations

import numpy as np
import pytest

from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators import ekf_math as em
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF
from mata_eval_plugins.estimators.zoh import ZeroOrderHold

FPS = 30.0


def P(**kw):
    """The filter for a camera that does NOT follow its target (these scenarios): the default
    velocity priors of preset mata assume one that does (docs/mata.md), so they are off here."""
    return HomographyEKF.Params(**{"follow_prior": 0.0, "velocity_decay_s": 0.0, **kw})
H_COV = np.diag([1e-8, 1e-8, 1e-4, 1e-8, 1e-8, 1e-4, 1e-14, 1e-14, 0.0])


def smooth_camera(k: int) -> np.ndarray:
    """World plane -> image k: drifting, rotating, zooming camera with a little perspective."""
    th, s = 0.003 * k, 1.0 + 0.003 * k
    tx, ty = -4.0 * k + 20.0 * np.sin(k / 15.0), 2.0 * k
    A = np.array([[s * np.cos(th), -s * np.sin(th), tx],
                  [s * np.sin(th), s * np.cos(th), ty],
                  [2e-6 * np.sin(k / 20.0), 1e-7 * k, 1.0]])
    return A / A[2, 2]


def shaky_camera(seed: int):
    """A hand-held-like camera: independent random jumps of ~8 px and small rotations per frame
    (what a constant-velocity model without camera compensation cannot predict)."""
    rng = np.random.default_rng(seed)
    steps = [np.eye(3)]
    for _ in range(400):
        a = rng.normal(0.0, 0.004)
        S = np.array([[np.cos(a), -np.sin(a), rng.normal(0, 8.0)],
                      [np.sin(a), np.cos(a), rng.normal(0, 8.0)], [0, 0, 1.0]])
        steps.append(S @ steps[-1])
    return lambda k: steps[k]


def truth_box(camera, k: int, v=(90.0, -45.0)) -> Box:
    """The target: a 40x30 box moving at v px/s on the world plane, seen through camera(k)."""
    tl = np.array([600.0, 350.0]) + np.asarray(v) * k / FPS
    A = camera(k)
    return Box.from_corners(*em.project(A, tl), *em.project(A, tl + [40.0, 30.0]))


def simulate(est, camera=smooth_camera, n=150, every=3, latency=0, noise=1.0, seed=0):
    """Run ``est`` over the scenario; per tick from tick 30 on: centre error (px) and the
    signed error along the target's image motion (negative = lagging behind)."""
    rng = np.random.default_rng(seed)
    est.initialize(truth_box(camera, 0), 0.0)
    pending: list[Stamped[TrackerOutput]] = []
    err, along = [], []
    for k in range(1, n):
        t = k / FPS
        H = camera(k) @ np.linalg.inv(camera(k - 1))
        motions = [Stamped(Motion(H / H[2, 2], H_COV), t, t)]
        if k % every == 0:
            z = np.array(truth_box(camera, k).corners()) + rng.normal(0.0, noise, 4)
            pending.append(Stamped(TrackerOutput(Box.from_corners(*z), 0.9), t, (k + latency) / FPS))
        dets = [d for d in pending if d.t_publish <= t + 1e-9]
        pending = [d for d in pending if d.t_publish > t + 1e-9]
        e = est.step(t, motions, dets)
        c = np.array(truth_box(camera, k).center)
        motion = c - np.array(truth_box(camera, k - 1).center)
        d = np.array(e.box.center) - c
        err.append(float(np.hypot(*d)))
        along.append(float(d @ motion / np.linalg.norm(motion)))
    return np.array(err[29:]), np.array(along[29:])


def test_constant_velocity_target_under_a_moving_camera_is_tracked_with_detections_every_3rd_tick():
    err, _ = simulate(HomographyEKF(P()))
    hold, _ = simulate(ZeroOrderHold())
    assert err.mean() < 1.5          # detections have 1 px noise per corner
    assert err.max() < 4.0
    assert hold.mean() > 4 * err.mean()   # the held box is off by up to 3 ticks of motion


@pytest.mark.parametrize("model", ["ca", "cj"])
def test_higher_order_models_also_track(model):
    err, _ = simulate(HomographyEKF(P(model=model)))
    assert err.mean() < 2.0


def test_compensating_a_two_tick_latency_removes_the_lag():
    """The image speed of the target is ~5 px per tick here, so a measurement used 2 ticks late
    lags by ~10 px (computed from the ground truth below); compensation removes it."""
    lag = np.mean([np.hypot(*np.subtract(truth_box(smooth_camera, k).center,
                                         truth_box(smooth_camera, k - 2).center)) for k in range(30, 150)])
    assert lag > 5.0
    on_time, _ = simulate(HomographyEKF(P(delay="compensate")))
    ignore, ignore_along = simulate(HomographyEKF(P(delay="ignore")), latency=2)
    comp, comp_along = simulate(HomographyEKF(P(delay="compensate")), latency=2)
    assert ignore_along.mean() < -0.6 * lag          # lagging behind by most of 2 ticks of motion
    assert abs(comp_along.mean()) < 0.05 * lag       # no lag left
    assert comp.mean() < 1.5 * on_time.mean() + 0.2  # as good as without latency, up to the
    assert comp.mean() < 0.25 * ignore.mean()        # 2 ticks of prediction before each arrival


def test_latency_without_compensation_matches_on_time_when_there_is_no_latency():
    """With no latency, both delay modes process the same measurements identically."""
    a, _ = simulate(HomographyEKF(P(delay="ignore")))
    b, _ = simulate(HomographyEKF(P(delay="compensate")))
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)


def test_camera_compensation_matters_under_a_shaky_camera():
    """Ablation config 4 in miniature: without H the filter cannot follow random camera jumps."""
    cam = shaky_camera(5)
    with_h, _ = simulate(HomographyEKF(P()), camera=cam, n=120)
    without, _ = simulate(HomographyEKF(P(camera=False)), camera=cam, n=120)
    assert with_h.mean() < 1.5
    assert without.mean() > 3 * with_h.mean()


# --- end to end through the scheduler (EOP, tracker at 10 Hz, one-period latency, feedback) -------

def _frame(k: int) -> np.ndarray:
    """A 1280x720 image (it bounds the estimates) that carries its own frame index (the fake
    blocks below read it back)."""
    img = np.zeros((720, 1280, 3), np.uint8)
    img[0, 0, 0], img[0, 0, 1] = k % 256, k // 256
    return img


def _index(img: np.ndarray) -> int:
    return int(img[0, 0, 0]) + 256 * int(img[0, 0, 1])


class _SearchTracker:
    """Finds the true box (1 px noise, confidence 0.9) only within ``radius`` px of its search
    centre (the prior, or its own last box); otherwise reports a box there with confidence 0.05."""

    def __init__(self, camera, radius: float, seed: int):
        self.camera, self.radius, self.rng = camera, radius, np.random.default_rng(seed)

    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        c = np.array(prior if prior is not None else self.box.center)
        b = truth_box(self.camera, _index(image))
        if np.hypot(*(np.array(b.center) - c)) <= self.radius:
            self.box = Box.from_corners(*(np.array(b.corners()) + self.rng.normal(0.0, 1.0, 4)))
            return TrackerOutput(self.box, 0.9)
        self.box = Box.from_center(c[0], c[1], self.box.w, self.box.h)
        return TrackerOutput(self.box, 0.05)


class _OracleEgomotion:
    """Block B with the true inter-frame homography."""

    def __init__(self, camera):
        self.camera = camera

    def initialize(self, image):
        self.k = _index(image)

    def estimate(self, image):
        k = _index(image)
        H = self.camera(k) @ np.linalg.inv(self.camera(self.k))
        self.k = k
        return Motion(H / H[2, 2], H_COV)


def _run_eop(estimator, camera, n=120, seed=0):
    from mata_eval.core.registry import load_registry
    from mata_eval.run.scheduler import run_sequence
    from mata_eval.core.sequence import Sequence

    eop = load_registry().get("protocol", "eop").cls
    gt = np.array([truth_box(camera, k).as_array() for k in range(n)])
    seq = Sequence("synthetic", gt, FPS, loader=_frame)
    run = run_sequence(seq, _SearchTracker(camera, 25.0, seed),
                       _OracleEgomotion(camera) if estimator is not None else None, estimator,
                       eop(eop.Params(tracker_hz=10)), np.random.default_rng(seed))
    c = run.boxes[:, :2] + run.boxes[:, 2:] / 2
    return np.hypot(*(c - (gt[:, :2] + gt[:, 2:] / 2)).T)


def test_feedback_keeps_the_lock_under_eop_with_a_shaky_camera():
    """Tracker at 10 Hz with a 25 px search radius, camera jumping ~8 px per frame: alone it loses
    the target; the EKF estimate fed back as search centre, with the one-period latency
    compensated, keeps it. (The first 6 frames carry the unknown initial velocity.) The target
    starts 150 px lower than in the tests above, so that its walk stays in the 1280x720 image
    (estimates are kept within half a box of it; from the top-left start it leaves the top)."""
    shaky, down = shaky_camera(1), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 150.0], [0.0, 0.0, 1.0]])
    cam = lambda k: shaky(k) @ down  # noqa: E731
    alone = _run_eop(None, cam)
    mata = _run_eop(HomographyEKF(P(delay="compensate")), cam)
    ignore = _run_eop(HomographyEKF(P(delay="ignore")), cam)
    assert mata[6:].max() < 5.0 and mata[6:].mean() < 2.0
    assert alone[6:].mean() > 20 * mata[6:].mean()
    assert ignore[6:].mean() > 5 * mata[6:].mean()  # a 3-frame-old box used as current misleads
