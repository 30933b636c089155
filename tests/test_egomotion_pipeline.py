"""Block B in the MATA loop: grid_lk's motions drive the homography EKF (block C) through the
scheduler, on a synthetic sequence whose inter-frame homographies are exact."""

from __future__ import annotations

import numpy as np
import pytest

from mata_eval.data import synth
from mata_eval.core.registry import load_registry
from mata_eval.run.scheduler import run_sequence
from mata_eval.core.sequence import Sequence
from mata_eval.types import Box, TrackerOutput
from mata_eval_plugins.egomotion import homography_covariance as hc
from mata_eval_plugins.egomotion.grid_lk import GridLK
from mata_eval_plugins.egomotion.identity import IdentityMotion

W, H = 480, 270


class BlindTracker:
    """A tracker that has lost its target: it repeats the initial box with zero confidence, so the
    estimator's confidence gate rejects every output and only the camera motion moves the box."""

    def initialize(self, image, box: Box) -> None:
        self.box = box

    def track(self, image, prior=None) -> TrackerOutput:
        return TrackerOutput(self.box, 0.0)


@pytest.fixture(scope="module", params=[("manoeuvre", 2), ("occlusion", 2)])
def sequence(request) -> tuple[Sequence, np.ndarray]:
    scenario, seed = request.param
    # a busy camera operator (pace and pan-count quantiles 0.95): the camera moves the ground
    r = synth.render_sequence(synth.make_spec(seed, 30, W, H, scenario=scenario, quantiles=(0.95, 0.95, 0.5)))
    box0 = Box(220.0, 120.0, 40.0, 30.0)  # a patch of ground near the centre
    G = np.eye(3)
    centres = [np.array(box0.center)]
    for k in range(1, len(r.frames)):
        G = r.homographies[k] @ G
        centres.append(hc.project(G, [box0.center])[0])
    centres = np.array(centres)
    gt = np.column_stack([centres - [20.0, 15.0], np.full((len(centres), 2), [40.0, 30.0])])
    return Sequence("synthetic_ground_patch", gt, 30.0, loader=lambda k: r.frames[k]), centres


def _centre_error(sequence, egomotion) -> np.ndarray:
    seq, centres = sequence
    reg = load_registry()
    cls = reg.get("estimator", "homography_ekf").cls
    ekf = cls(cls.Params(follow_prior=0.0))  # a ground patch: still in the world, not in the image
    ltp = reg.get("protocol", "ltp").cls()
    run = run_sequence(seq, BlindTracker(), egomotion, ekf, ltp, np.random.default_rng(0))
    c = run.boxes[:, :2] + run.boxes[:, 2:] / 2
    return np.linalg.norm(c - centres, axis=1)


def test_grid_lk_motions_carry_a_ground_box_through_the_ekf(sequence) -> None:
    moved = np.linalg.norm(sequence[1][-1] - sequence[1][0])
    assert moved > 40, f"the camera should move the patch (moved {moved:.1f} px)"
    err = _centre_error(sequence, GridLK())
    assert err.max() < 1.5, err.round(2)
    # without compensation the box stays where it was while the ground moves away
    no_comp = _centre_error(sequence, IdentityMotion())
    assert no_comp[-1] > 10 * max(err[-1], 0.1)
