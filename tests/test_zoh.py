"""Zero-order hold: the estimate is exactly the newest tracker box, held between outputs."""

from __future__ import annotations

import numpy as np
import pytest

from mata_eval.core.registry import load_registry
from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators.zoh import ZeroOrderHold


def det(box: Box, t_capture: float, t_publish: float, conf: float = 0.5) -> Stamped[TrackerOutput]:
    return Stamped(TrackerOutput(box, conf), t_capture, t_publish)


def test_holds_the_initial_box_then_each_detection_exactly():
    z = ZeroOrderHold()
    b0, b1, b2 = Box(10, 20, 30, 40), Box(11.25, 19.5, 31, 39), Box(50.125, 60, 20, 10)
    assert z.initialize(b0, 0.0).box == b0
    shift = Motion(np.array([[1.0, 0, 9.0], [0, 1, 0], [0, 0, 1]]))
    timeline = [  # (t, motions, detections, expected box): a 10 Hz tracker on a 30 Hz clock
        (1, [shift], [], b0),
        (2, [shift], [], b0),
        (3, [shift], [det(b1, 0, 3)], b1),
        (4, [shift], [], b1),
        (5, [], [], b1),
        (6, [shift], [det(Box(0, 0, 5, 5), 3, 6), det(b2, 3, 6)], b2),  # newest of two
        (7, [], [], b2),
    ]
    for k, motions, dets, want in timeline:
        e = z.step(k / 30, [Stamped(m, k / 30, k / 30) for m in motions], dets)
        assert e.box == want and e.cov is None


def test_skips_invalid_boxes_and_stale_detections():
    z = ZeroOrderHold()
    b0, b1 = Box(10, 20, 30, 40), Box(12, 22, 30, 40)
    z.initialize(b0, 0.0)
    assert z.step(0.1, detections=[det(Box(float("nan"), 0, 1, 1), 0.05, 0.1)]).box == b0
    assert z.step(0.2, detections=[det(Box(1, 1, 0, 5), 0.1, 0.2)]).box == b0
    assert z.step(0.3, detections=[det(b1, 0.25, 0.3)]).box == b1
    # an older measurement arriving late never replaces a newer one
    assert z.step(0.4, detections=[det(b0, 0.2, 0.4)]).box == b1


def test_errors_and_registration():
    with pytest.raises(RuntimeError, match="initialize"):
        ZeroOrderHold().step(0.0)
    with pytest.raises(ValueError, match="positive size"):
        ZeroOrderHold().initialize(Box(0, 0, -1, 5), 0.0)
    assert load_registry().get("estimator", "zoh").cls is ZeroOrderHold
