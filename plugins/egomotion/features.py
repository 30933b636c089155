"""Feature-based ego-motion, the peer of grid_lk: Shi-Tomasi corners detected in every frame,
tracked by pyramidal Lucas-Kanade into the next one, RANSAC similarity. This is the
``sparseOptFlow`` camera-motion module of BoT-SORT (``tracker/gmc.py``: downscale 2,
``goodFeaturesToTrack(maxCorners=1000, qualityLevel=0.01, minDistance=1, blockSize=3)``,
``calcOpticalFlowPyrLK`` with OpenCV defaults, ``estimateAffinePartial2D`` RANSAC with a 3 px
threshold in the shrunk image), sharing grid_lk's back end: least-squares refit on the inliers
and the first-order covariance, so the two differ only in where the points come from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Motion

from .grid_lk import flag_unchanged, normalised_gray, prepare_gray, robust_fit, to_full_resolution


class FeatureLK:
    """Corners every frame + LK + RANSAC similarity (BoT-SORT camera-motion module; peer of grid_lk)."""

    name = "features"

    @dataclass(frozen=True)
    class Params:
        downscale: float = param(2.0, "divide the image size by this before detection and LK")
        model: Literal["homography", "affine", "similarity", "translation"] = param(
            "similarity", "motion model (BoT-SORT: similarity)")
        normalise: bool = param(False, "normalise each image's global gain and offset (BoT-SORT: no)")
        max_corners: int = param(1000, "goodFeaturesToTrack maxCorners")
        quality_level: float = param(0.01, "goodFeaturesToTrack qualityLevel")
        min_distance: float = param(1.0, "goodFeaturesToTrack minDistance (px of the shrunk image)")
        block_size: int = param(3, "goodFeaturesToTrack blockSize")
        ransac_threshold: float = param(3.0, "RANSAC inlier threshold (px of the shrunk image, as BoT-SORT)")
        ransac_iters: int = param(2000, "RANSAC iterations at most")
        ransac_confidence: float = param(0.99, "RANSAC confidence (estimateAffinePartial2D default)")
        min_inliers: int = param(20, "fewer inliers than this gives an invalid motion")

        def __post_init__(self) -> None:
            if not self.downscale >= 1.0:
                raise ValueError(f"downscale must be >= 1, got {self.downscale}")
            if self.max_corners < 1 or not 0 < self.quality_level < 1 or self.block_size < 1:
                raise ValueError("max_corners must be >= 1, 0 < quality_level < 1, block_size >= 1")
            if not self.min_distance >= 0 or not self.ransac_threshold > 0:
                raise ValueError("min_distance must be >= 0 and ransac_threshold > 0")
            if self.ransac_iters < 1 or not 0 < self.ransac_confidence < 1 or self.min_inliers < 1:
                raise ValueError("ransac_iters >= 1, 0 < ransac_confidence < 1, min_inliers >= 1 required")

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()
        self._prev: np.ndarray | None = None
        self._prev_plain: np.ndarray | None = None  # ``_prev`` without the intensity normalisation
        self._prev_corners: np.ndarray | None = None
        self._full_shape: tuple[int, ...] = ()

    def initialize(self, image: np.ndarray) -> None:
        self._take(image)

    def estimate(self, image: np.ndarray) -> Motion:
        """Motion from the previous image to this one (``unchanged`` when they show the same
        picture: grid_lk.flag_unchanged); corners of this image are detected for the next call."""
        prev, prev_plain, corners, prev_full = self._prev, self._prev_plain, self._prev_corners, self._full_shape
        cur = self._take(image)
        if (prev is None or cur is None or corners is None or prev.shape != cur.shape
                or prev_full != self._full_shape):
            return Motion.invalid()
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev, cur, corners, None)
        good = status.reshape(-1) == 1
        src = to_full_resolution(corners[good], cur.shape, self._full_shape)
        dst = to_full_resolution(nxt[good], cur.shape, self._full_shape)
        finite = np.all(np.isfinite(dst), axis=1)
        scale = self._full_shape[1] / cur.shape[1]
        p = self.params
        motion = robust_fit(src[finite], dst[finite], p.model, p.ransac_threshold * scale, p.min_inliers,
                            p.ransac_iters, p.ransac_confidence,
                            image_size=(self._full_shape[1], self._full_shape[0]))
        return flag_unchanged(motion, prev_plain, self._prev_plain, p.downscale)

    def _take(self, image: object) -> np.ndarray | None:
        p = self.params
        plain = prepare_gray(image, p.downscale)   # flag_unchanged compares these
        gray = normalised_gray(image, plain) if plain is not None and p.normalise else plain
        corners = None
        if gray is not None:
            corners = cv2.goodFeaturesToTrack(gray, p.max_corners, p.quality_level, p.min_distance,
                                              blockSize=p.block_size, useHarrisDetector=False, k=0.04)
        self._prev, self._prev_plain, self._prev_corners = gray, plain, corners
        self._full_shape = tuple(image.shape[:2]) if gray is not None else ()  # type: ignore[union-attr]
        return gray


@hookimpl
def mata_eval_egomotion():
    return [FeatureLK]
