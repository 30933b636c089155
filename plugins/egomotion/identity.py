"""No ego-motion compensation (the ablation's "without block B"): every frame is assumed to be
seen from the same camera pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.types import Motion


class IdentityMotion:
    """No camera-motion compensation: the identity homography, no covariance (ablation)."""

    name = "identity"

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()

    def initialize(self, image: np.ndarray) -> None:
        pass

    def estimate(self, image: np.ndarray) -> Motion:
        """The identity, valid, with ``cov = None`` (nothing was measured, so no uncertainty is
        claimed; an estimator then uses its own floor)."""
        return Motion.identity()


@hookimpl
def mata_eval_egomotion():
    return [IdentityMotion]
