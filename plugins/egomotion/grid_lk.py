"""MATA block B (paper section 2.2): points on a regular grid tracked by pyramidal Lucas-Kanade
from frame k-1 to frame k, low-contrast points dropped (minimum eigenvalue of the LK gradient
matrix), an optional forward-backward check, RANSAC for the inlier set, a least-squares refit on
the inliers (optional for the homography: ``refit``), and the first-order covariance of the
homography (H&Z Result 5.10)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Motion, derived

from . import homography_covariance as hc


_TARGET_MEAN, _TARGET_STD, _MAX_GAIN = 128.0, 48.0, 4.0

#: A frame repeats the previous picture when no UNCHANGED_CELL x UNCHANGED_CELL px block of the
#: full image differs from it by more than UNCHANGED_GREY grey levels on average: above the block
#: noise of re-encoding a frame as JPEG at quality 70-75 (up to 3.5) and of MountainBike6's
#: repeated frames (3.1), below every new frame of aerial30 (5.8 and more; docs/mata.md)
UNCHANGED_CELL, UNCHANGED_GREY = 16, 4.0
#: ... unless the fitted motion moves an image corner by this much or more (px, full resolution):
#: on a repeated picture LK finds no flow and the fit is the identity to rounding, so the block
#: test is skipped where it cannot pass (0.14 ms a 640 x 360 frame pair; the same flags on every
#: frame of aerial30, uav123_10fps and the quick synthetic pair)
UNCHANGED_MOVE = 1.0


def normalise_intensity(gray: np.ndarray) -> np.ndarray:
    """Global gain and offset taken out (mean 128, std 48, saturated to uint8): Lucas-Kanade
    assumes brightness constancy, which auto-exposure and illumination changes break. A constant
    image is returned unchanged; the gain is capped at 4 so that sensor noise on a nearly
    uniform image is not blown up into texture."""
    mean, std = cv2.meanStdDev(gray)
    std = float(std.ravel()[0])
    if std < 1e-6:
        return gray
    gain = min(_TARGET_STD / std, _MAX_GAIN)
    lut = np.clip(np.arange(256) * gain + (_TARGET_MEAN - gain * float(mean.ravel()[0])), 0, 255)
    return cv2.LUT(gray, np.rint(lut).astype(np.uint8))


def prepare_gray(image: object, downscale: float, normalise: bool = False) -> np.ndarray | None:
    """Grey uint8 image shrunk by ``downscale`` (area interpolation), optionally with its global
    gain and offset normalised, or None for input that is not an image (wrong type, dtype,
    shape, empty). On a scheduler frame (:class:`~mata_eval.types.FrameImage`) the grey image
    and the shrunk one are computed once per frame and shared with every block that asks."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.size == 0:
        return None
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3, 4))):
        return None
    gray = derived(image, "gray", to_gray)
    if downscale > 1.0:
        h, w = gray.shape
        size = (max(1, round(w / downscale)), max(1, round(h / downscale)))
        gray = derived(image, ("gray", size), lambda _: cv2.resize(gray, size, interpolation=cv2.INTER_AREA))
    return normalised_gray(image, gray) if normalise else gray


def normalised_gray(image: object, gray: np.ndarray) -> np.ndarray:
    """:func:`normalise_intensity` of ``gray``, a grey image :func:`prepare_gray` made of
    ``image``; on a scheduler frame computed once per frame and shared."""
    return derived(image, ("gray", gray.shape, "normalised"), lambda _: normalise_intensity(gray))


def to_gray(image: np.ndarray) -> np.ndarray:
    """Full-resolution grey uint8 image of a BGR, BGRA or one-channel image (OpenCV's weights)."""
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    return np.ascontiguousarray(image.reshape(image.shape[:2]))


def to_full_resolution(pts: np.ndarray, small_shape: tuple[int, ...], full_shape: tuple[int, ...]) -> np.ndarray:
    """Pixel coordinates in the shrunk image to the full image, with OpenCV's resize convention
    (pixel centres at integers): ``x = s (x_small + 0.5) - 0.5``, ``s = W / w``."""
    sx = full_shape[1] / small_shape[1]
    sy = full_shape[0] / small_shape[0]
    out = np.asarray(pts, dtype=float).reshape(-1, 2).copy()
    out[:, 0] = sx * (out[:, 0] + 0.5) - 0.5
    out[:, 1] = sy * (out[:, 1] + 0.5) - 0.5
    return out


def unchanged(prev: np.ndarray, cur: np.ndarray, cell: float) -> bool:
    """Whether two grey images of one shape show the same picture within compression noise:
    the mean absolute difference over every ``cell`` x ``cell`` block (area averages) is at most
    UNCHANGED_GREY. Blocks, not the whole image, so that a target moving in a still scene
    changes its block."""
    h, w = cur.shape[:2]
    size = (max(1, round(w / cell)), max(1, round(h / cell)))
    d = cv2.resize(cv2.absdiff(prev, cur).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    return bool(d.max() <= UNCHANGED_GREY)


def flag_unchanged(motion: Motion, prev: np.ndarray, cur: np.ndarray, downscale: float) -> Motion:
    """``motion`` with ``unchanged`` set when the grey images ``prev`` and ``cur`` (shrunk by
    ``downscale``, before intensity normalisation, which would scale their noise) show the
    same picture (:func:`unchanged`); a valid motion that moves an image corner by
    UNCHANGED_MOVE px or more is not tested."""
    if motion.valid:
        h, w = cur.shape[0] * downscale, cur.shape[1] * downscale
        corners = np.array([[0.0, 0.0], [w - 1, 0.0], [w - 1, h - 1], [0.0, h - 1]])
        if np.abs(hc.project(motion.H, corners) - corners).max() >= UNCHANGED_MOVE:
            return motion
    if unchanged(prev, cur, UNCHANGED_CELL / downscale):
        return dataclasses.replace(motion, unchanged=True)
    return motion


def grid_points(width: int, height: int, cols: int, rows: int) -> np.ndarray:
    """(cols * rows, 1, 2) float32 cell centres ``((i + 0.5) W / cols, (j + 0.5) H / rows)``."""
    xs = (np.arange(cols) + 0.5) * width / cols
    ys = (np.arange(rows) + 0.5) * height / rows
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2).astype(np.float32)


#: OpenCV's robust estimators that ``ransac_method`` names: classic RANSAC, and two of its USAC
#: framework (SPRT verification, local optimisation; USAC_MAGSAC scores by MAGSAC++), which
#: OpenCV offers for the homography and the affine model only
RANSAC_METHODS = {"ransac": cv2.RANSAC, "usac_fast": cv2.USAC_FAST, "usac_magsac": cv2.USAC_MAGSAC}
USAC_MODELS = ("homography", "affine")


def _ransac(src: np.ndarray, dst: np.ndarray, model: str, threshold: float, max_iters: int,
            confidence: float, method: str = "ransac") -> tuple[np.ndarray | None, np.ndarray] | None:
    """OpenCV's robust estimator ``method`` (RANSAC_METHODS) for the model (its internal RNG has
    a fixed seed, so the result is deterministic): (the homography it fits, or None for the
    other models, whose estimate is not used; the inlier mask), or None when it fails. OpenCV's
    RANSAC homography is its final fit on all the inliers: a DLT refined by Levenberg-Marquardt
    on the reprojection error in the second image, the ML fit under destination noise that the
    covariance assumes."""
    s, d = src.astype(np.float32), dst.astype(np.float32)
    if model == "homography":
        H, mask = cv2.findHomography(s, d, RANSAC_METHODS[method], threshold, maxIters=max_iters,
                                     confidence=confidence)
        ok = H is not None
    else:
        estimator = {"affine": cv2.estimateAffine2D, "similarity": cv2.estimateAffinePartial2D,
                     "translation": cv2.estimateTranslation2D}[model]
        M, mask = estimator(s, d, method=RANSAC_METHODS[method], ransacReprojThreshold=threshold,
                            maxIters=max_iters, confidence=confidence)
        ok, H = M is not None, None
    if not ok or mask is None:
        return None
    return H, mask.reshape(-1).astype(bool)


def robust_fit(src: np.ndarray, dst: np.ndarray, model: str = "homography", threshold: float = 3.0,
               min_inliers: int = 20, max_iters: int = 2000, confidence: float = 0.995,
               image_size: tuple[int, int] | None = None, refit: bool = True,
               method: str = "ransac") -> Motion:
    """RANSAC inlier set, least-squares refit on the inliers (RANSAC's own output is not the
    converged ML fit the covariance formula assumes: reference notes section 4.3), residual
    noise and covariance. ``src`` are exact points, ``dst`` their tracked positions (pixels).
    ``refit=False``: the homography is RANSAC's own fit (:func:`_ransac`), one fit per frame,
    0.14 ms less at 1280x720 but not the default (docs/decisions/egomotion.md); the other
    models are always a least-squares solve on the inliers. ``method``: the robust estimator
    (RANSAC_METHODS; the USAC ones for the homography and the affine model only). Returns
    ``Motion.invalid()`` when there are too few points or inliers, the fit fails, the points
    are degenerate, or (with ``image_size = (W, H)``) an image corner maps to infinity."""
    src = np.asarray(src, dtype=float).reshape(-1, 2)
    dst = np.asarray(dst, dtype=float).reshape(-1, 2)
    need = max(int(min_inliers), hc.min_points(model) + 1)
    if len(src) < need:
        return Motion.invalid()
    try:
        fit = _ransac(src, dst, model, threshold, max_iters, confidence, method)
        if fit is None or fit[1].sum() < need:
            return Motion.invalid()
        H, inl = fit
        s, d = src[inl], dst[inl]
        if model != "homography":
            # OpenCV's inlier mask of these models comes from a minimal-sample fit, whose error at the
            # image's far points drops true inliers there (about 6 % of a 16 x 16 grid at 0.7 px
            # noise), and the covariance of a fit on such a noise-chosen subset was 2-3 times too
            # small (Monte Carlo): the inliers are chosen again under the least-squares fit until
            # they no longer change (at most 3 times)
            H = hc.fit_least_squares(s, d, model)
            for _ in range(3):
                again = np.linalg.norm(hc.project(H, src) - dst, axis=1) <= threshold
                if again.sum() < need or np.array_equal(again, inl):
                    break
                inl = again
                s, d = src[inl], dst[inl]
                H = hc.fit_least_squares(s, d, model)
        elif refit:
            H, _ = cv2.findHomography(s, d, 0)
            if H is None:
                return Motion.invalid()
        if not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
            return Motion.invalid()
        H = H / H[2, 2]
        if image_size is not None:
            w, h = image_size
            corners = np.array([[0, 0, 1], [w - 1, 0, 1], [w - 1, h - 1, 1], [0, h - 1, 1]], float)
            if np.any(corners @ H[2] <= 1e-6):
                return Motion.invalid()
        sigma = hc.residual_sigma(H, s, d, model)
        cov = hc.homography_covariance(H, s, sigma, model)
    except (cv2.error, np.linalg.LinAlgError):
        return Motion.invalid()
    if not (np.isfinite(sigma) and np.all(np.isfinite(cov))):
        return Motion.invalid()
    return Motion(H=H, cov=cov, inliers=int(inl.sum()), sigma=float(sigma), valid=True)


class GridLK:
    """Grid Lucas-Kanade + RANSAC homography with first-order covariance (MATA block B)."""

    name = "grid_lk"

    @dataclass(frozen=True)
    class Params:
        grid_cols: int = param(16, "grid points across the image")
        grid_rows: int = param(16, "grid points down the image")
        downscale: float = param(2.0, "divide the image size by this before LK (1 = full resolution)")
        model: Literal["homography", "affine", "similarity", "translation"] = param(
            "homography", "motion model fitted to the tracked points")
        win_size: int = param(11, "LK window side (pixels of the shrunk image; 11 at downscale 2 covers "
                                   "the scene area of OpenCV's 21-pixel default at full resolution)")
        max_level: int = param(3, "LK pyramid levels above the base image")
        max_iter: int = param(30, "LK iterations per pyramid level")
        epsilon: float = param(0.01, "LK stops when an update moves less than this (px)")
        min_eig: float = param(1e-3, "drop low-contrast points: LK's minEigThreshold (minimum eigenvalue "
                                     "of the 2x2 gradient matrix over the window area; OpenCV's default 1e-4)")
        normalise: bool = param(True, "normalise each image's global gain and offset before LK "
                                      "(illumination / auto-exposure changes)")
        fb_threshold: float | None = param(
            None, "forward-backward check: drop points whose backward track misses the start by "
                  "more than this (px of the shrunk image); null = no check")
        ransac_method: Literal["ransac", "usac_fast", "usac_magsac"] = param(
            "ransac", "robust estimator: OpenCV's RANSAC, or its USAC_FAST or USAC_MAGSAC (homography "
                      "and affine models; about as accurate, and bounded in cost where few points "
                      "are inliers: docs/decisions/egomotion.md)")
        ransac_threshold: float = param(3.0, "RANSAC inlier threshold (px, full resolution)")
        ransac_iters: int = param(2000, "RANSAC iterations at most")
        ransac_confidence: float = param(0.995, "RANSAC confidence")
        refit: bool = param(True, "fit the homography again by least squares on RANSAC's inliers "
                                  "(findHomography method 0); false = RANSAC's own fit, one fit per "
                                  "frame (0.14 ms less at 1280x720; docs/decisions/egomotion.md)")
        min_inliers: int = param(20, "fewer inliers than this gives an invalid motion")

        def __post_init__(self) -> None:
            if self.grid_cols < 2 or self.grid_rows < 2:
                raise ValueError(f"grid_cols and grid_rows must be >= 2, got {self.grid_cols}x{self.grid_rows}")
            if not self.downscale >= 1.0:
                raise ValueError(f"downscale must be >= 1, got {self.downscale}")
            if self.win_size < 3 or self.win_size % 2 == 0:
                raise ValueError(f"win_size must be an odd number >= 3, got {self.win_size}")
            if self.max_level < 0 or self.max_iter < 1 or not self.epsilon > 0:
                raise ValueError("max_level must be >= 0, max_iter >= 1 and epsilon > 0")
            if not self.min_eig >= 0:
                raise ValueError(f"min_eig must be >= 0, got {self.min_eig}")
            if self.fb_threshold is not None and not self.fb_threshold > 0:
                raise ValueError(f"fb_threshold must be > 0 or null, got {self.fb_threshold}")
            if not self.ransac_threshold > 0 or self.ransac_iters < 1 or not 0 < self.ransac_confidence < 1:
                raise ValueError("ransac_threshold must be > 0, ransac_iters >= 1, 0 < ransac_confidence < 1")
            if self.min_inliers < 1:
                raise ValueError(f"min_inliers must be >= 1, got {self.min_inliers}")
            if self.ransac_method != "ransac" and self.model not in USAC_MODELS:
                raise ValueError(f"ransac_method {self.ransac_method} needs model homography or affine "
                                 f"(OpenCV's USAC has no {self.model} estimator); use ransac")

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()
        self._prev: np.ndarray | None = None
        self._prev_plain: np.ndarray | None = None  # ``_prev`` without the intensity normalisation
        self._full_shape: tuple[int, ...] = ()
        self._grid_cache: tuple[tuple[int, ...], np.ndarray] | None = None

    def initialize(self, image: np.ndarray) -> None:
        self._take(image)

    def estimate(self, image: np.ndarray) -> Motion:
        """Motion from the previous image to this one (``unchanged`` when they show the same
        picture: :func:`flag_unchanged`); this image becomes the previous one."""
        prev, prev_plain, prev_full = self._prev, self._prev_plain, self._full_shape
        cur = self._take(image)
        if prev is None or cur is None or prev.shape != cur.shape or prev_full != self._full_shape:
            return Motion.invalid()
        p = self.params
        if cur.shape[1] < 2 * p.grid_cols or cur.shape[0] < 2 * p.grid_rows:
            return Motion.invalid()  # grid points closer than 2 px: repeated, not independent, tracks
        pts = self._grid(cur.shape)
        lk = dict(winSize=(p.win_size, p.win_size), maxLevel=p.max_level,
                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, p.max_iter, p.epsilon))
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts, None, minEigThreshold=p.min_eig, **lk)
        good = status.reshape(-1) == 1
        if p.fb_threshold is not None and good.any():
            back, st_b, _ = cv2.calcOpticalFlowPyrLK(cur, prev, nxt[good], None, **lk)
            fb_err = np.linalg.norm((back - pts[good]).reshape(-1, 2), axis=1)
            good[np.flatnonzero(good)] = (st_b.reshape(-1) == 1) & (fb_err < p.fb_threshold)
        src = to_full_resolution(pts[good], cur.shape, self._full_shape)
        dst = to_full_resolution(nxt[good], cur.shape, self._full_shape)
        finite = np.all(np.isfinite(dst), axis=1)
        motion = robust_fit(src[finite], dst[finite], p.model, p.ransac_threshold, p.min_inliers,
                            p.ransac_iters, p.ransac_confidence,
                            image_size=(self._full_shape[1], self._full_shape[0]), refit=p.refit,
                            method=p.ransac_method)
        return flag_unchanged(motion, prev_plain, self._prev_plain, p.downscale)

    def _take(self, image: object) -> np.ndarray | None:
        plain = prepare_gray(image, self.params.downscale)   # flag_unchanged compares these
        gray = normalised_gray(image, plain) if plain is not None and self.params.normalise else plain
        self._prev, self._prev_plain = gray, plain
        self._full_shape = tuple(image.shape[:2]) if gray is not None else ()  # type: ignore[union-attr]
        return gray

    def _grid(self, shape: tuple[int, ...]) -> np.ndarray:
        if self._grid_cache is None or self._grid_cache[0] != shape:
            p = self.params
            self._grid_cache = (shape, grid_points(shape[1], shape[0], p.grid_cols, p.grid_rows))
        return self._grid_cache[1]


@hookimpl
def mata_eval_egomotion():
    return [GridLK]
