"""A coasting estimate does not run away (issue 14): the scheduler and the live runtime keep
every estimate, and so the prior handed to the tracker, within half a box of the image
(``Estimate.within``). Checked on hand-built timelines: a world-still target that a panning
camera carries off the image while the tracker finds nothing, whose coasting position is known
in closed form, and the same timeline on an image large enough that nothing changes."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mata_eval.core.sequence import Sequence
from mata_eval.run.live import run_live
from mata_eval.run.scheduler import run_sequence
from mata_eval.types import Box, Estimate, Motion, TrackerOutput
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF
from mata_eval_plugins.protocols.ltp import LTP

BOX = Box(90.0, 95.0, 20.0, 10.0)  # centre (100, 100), 20 x 10 px
FPS = 30.0
PAN = 15.0  # px per frame, to the right: a world-still target moves 15 px per frame in the image


def test_within_clamps_centres_to_the_image_grown_by_half_a_box():
    # 640x480 image, 20x10 box: centres are kept in [-10, 650] x [-5, 485].
    far = Estimate(Box(-50.0, -40.0, 20.0, 10.0), cov=np.eye(8), search=(700.0, 100.0))
    got = far.within(640, 480)
    assert (got.box.x, got.box.y, got.box.w, got.box.h) == (-20.0, -10.0, 20.0, 10.0)  # centre (-10, -5)
    assert got.search == (650.0, 100.0) and got.prior == (650.0, 100.0)
    assert got.cov is far.cov and got.feedback
    right = Estimate(Box(645.0, 470.0, 20.0, 10.0)).within(640, 480)  # centre (655, 475): x only
    assert (right.box.x, right.box.y) == (640.0, 470.0)
    assert Estimate(Box(-50.0, 0.0, 20.0, 10.0), feedback=False).within(640, 480).prior is None
    inside = Estimate(Box(-9.9, 474.9, 20.0, 10.0))  # centre (0.1, 479.9): within the bounds
    assert inside.within(640, 480) is inside


class PanEgoMotion:
    """The camera pans ``PAN`` px in x between consecutive frames (a pure translation)."""

    def initialize(self, image):
        pass

    def estimate(self, image):
        H = np.eye(3)
        H[0, 2] = PAN
        return Motion(H, cov=np.eye(9) * 1e-12)


class BlindTracker:
    """Finds nothing (confidence 0, its initial box, as a lost tracker reports); logs its priors."""

    def __init__(self):
        self.priors = []

    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        self.priors.append(prior)
        return TrackerOutput(self.box, confidence=0.0)


class Recorded:
    """The estimator, with the box it returned itself (before the runtime bounds it) at the
    last call of each frame (a tick is split around the tracker: two calls at one time)."""

    def __init__(self, estimator):
        self.estimator, self.boxes = estimator, {}

    def initialize(self, box, t):
        return self._keep(t, self.estimator.initialize(box, t))

    def step(self, t, motions=(), detections=()):
        return self._keep(t, self.estimator.step(t, motions, detections))

    def _keep(self, t, out):
        self.boxes[round(t * FPS)] = out.box.as_array()
        return out


def coast(width, height, n=12):
    """LTP run of the paper's block C (own velocity zero: it coasts with the camera) over ``n``
    frames of a ``width`` x ``height`` image; (scored boxes, tracker priors, the estimator's own
    boxes)."""
    seq = Sequence("pan", np.tile(BOX.as_array(), (n, 1)), fps=FPS,
                   loader=lambda k: np.zeros((height, width, 3), np.uint8))
    tracker, est = BlindTracker(), Recorded(HomographyEKF(HomographyEKF.Params(preset="paper")))
    run = run_sequence(seq, tracker, PanEgoMotion(), est, LTP(), np.random.default_rng(0))
    return run.boxes, tracker.priors, np.array([est.boxes[k] for k in range(n)])


def test_a_target_carried_off_the_image_is_held_at_half_a_box_outside():
    # Frame k's estimate is the world-still target after k pans: centre x 100 + 15 k, which
    # passes 160 + 10 (half the 20 px box outside the 160 px image) at frame 5; y stays at 100.
    boxes, priors, own = coast(160, 120)
    k = np.arange(len(boxes))
    assert own[:, 0] + own[:, 2] / 2 == pytest.approx(100.0 + PAN * k, abs=1e-3)  # it coasts away...
    want = np.minimum(100.0 + PAN * k, 170.0)
    assert boxes[:, 0] + boxes[:, 2] / 2 == pytest.approx(want, abs=1e-3)  # ...its estimate stays
    assert boxes[:, 1] + boxes[:, 3] / 2 == pytest.approx(100.0, abs=1e-6)
    assert boxes[:, 2:] == pytest.approx(own[:, 2:])  # the size is the estimator's
    # the tracker's prior at frame k (k >= 1) is the estimate of frame k (the first half of
    # its tick; the tracker's box then reaches the second, which rejects it)
    assert [p[0] for p in priors] == pytest.approx(want[1:], abs=1e-3)


def test_an_estimate_inside_the_image_is_untouched():
    # The same run on a 1280x720 image: the target ends at x 265, inside; the scored boxes are
    # the estimator's own, bit for bit, and so are the priors.
    boxes, priors, own = coast(1280, 720)
    assert np.array_equal(boxes, own)
    assert priors == [tuple(b[:2] + b[2:] / 2) for b in own[1:]]


def test_the_live_runtime_bounds_the_estimate_too():
    class FarEstimator:  # jumps 1000 px left of the image at every tick
        def initialize(self, box, t):
            return Estimate(box)

        def step(self, t, motions=(), detections=()):
            time.sleep(0.01)
            return Estimate(Box(-1000.0, 100.0, 20.0, 10.0))

    seq = Sequence("toy", np.tile(BOX.as_array(), (4, 1)), fps=5.0,
                   loader=lambda k: np.zeros((120, 160, 3), np.uint8))
    tracker = BlindTracker()
    run = run_live(seq, tracker, None, FarEstimator(), warmup=0)
    moved = run.source_frame > 0
    assert moved.any()
    assert (run.boxes[moved] == [-20.0, 100.0, 20.0, 10.0]).all()  # centre -10: half a box out
    # the tracker's first prior may be the initial estimate; every later one is bounded
    assert tracker.priors[-1] == (-10.0, 105.0)
    assert all(p in (BOX.center, (-10.0, 105.0)) for p in tracker.priors)
