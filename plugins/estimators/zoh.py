"""Zero-order hold: the baseline estimator. Its estimate is the newest usable tracker box,
held unchanged until the next one (no motion model, no camera compensation)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from mata_eval.hooks import hookimpl
from mata_eval.types import Box, Estimate, Motion, Stamped, TrackerOutput


class ZeroOrderHold:
    """Zero-order hold: hold the tracker's newest box (baseline for block C)."""

    name = "zoh"
    baseline = True  # reports: a run with this estimator is a baseline, not MATA

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()
        self._box: Box | None = None
        self._t_capture = float("-inf")

    def initialize(self, box: Box, t: float) -> Estimate:
        if not box.is_valid:
            raise ValueError(f"zoh: initial box must be finite with positive size, got {box}")
        self._box, self._t_capture = box, float(t)
        return Estimate(box)

    def step(self, t: float, motions: Sequence[Stamped[Motion]] = (),
             detections: Sequence[Stamped[TrackerOutput]] = ()) -> Estimate:
        """Hold the box of the newest detection by capture time (an older one arriving late
        never replaces a newer one); a non-finite or empty box is skipped."""
        if self._box is None:
            raise RuntimeError("zoh: step() called before initialize()")
        for det in detections:
            if det.value.box.is_valid and det.t_capture >= self._t_capture:
                self._box, self._t_capture = det.value.box, det.t_capture
        return Estimate(self._box)


@hookimpl
def mata_eval_estimators():
    return [ZeroOrderHold]
