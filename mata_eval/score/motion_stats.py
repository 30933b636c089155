"""How fast targets and cameras move in a dataset: the statistics that decide what latency costs
a tracker (docs/decisions/data.md "Motion statistics"; issue 15).

Target motion, from ground truth alone (any dataset with boxes):

- *displacement over a lag* ``d``: distance between the box centres of frames ``k`` and
  ``k + d`` divided by the target size ``sqrt(w h)`` at frame ``k``, pooled over every pair of
  annotated frames of every sequence; reported as median and 90th percentile for d = 1, 3, 10;
- *scale change over a lag*: ``|log(s_{k+d} / s_k)|`` with ``s = sqrt(w h)``, median and p90;
- *IoU < 0.5*: fraction of the pairs ``(k, k + d)`` whose boxes overlap with IoU below 0.5 (how
  often a box ``d`` frames old already misses the target).

Camera motion, from inter-frame homographies ``H_k`` (frame k-1 to k; estimated by block B on
real footage, exact on synthetic sequences): each ``H_k`` is linearised at the image centre,
``H(c + u) ~ H(c) + J u``, and read as a similarity: *translation* ``|H(c) - c|`` in image widths
per second, *rotation* ``atan2(J10 - J01, J00 + J11)`` in degrees per second, *zoom*
``|log sqrt(|det J|)|`` per second, and *jerk*, the change of the centre's image velocity
between consecutive frames (image widths per second squared: abrupt, handheld-like motion).
Rates are per second so that 10 fps and 30 fps footage compare.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

from .metrics import iou

#: Frame lags of the target statistics (1 frame, 0.1 s and 0.33 s at 30 fps).
LAGS = (1, 3, 10)


@dataclass(frozen=True)
class LagStats:
    """Target motion between frames ``k`` and ``k + lag``, pooled over all pairs."""

    lag: int
    n_pairs: int
    displacement_median: float   # centre distance / sqrt(w h) of frame k
    displacement_p90: float
    scale_median: float          # |log(size_{k+lag} / size_k)|, size = sqrt(w h)
    scale_p90: float
    iou_below_half: float        # fraction of pairs with IoU(box_k, box_{k+lag}) < 0.5


@dataclass(frozen=True)
class TargetMotion:
    """Target motion statistics of a set of sequences (one :class:`LagStats` per lag)."""

    n_sequences: int
    lags: tuple[LagStats, ...]

    def at(self, lag: int) -> LagStats:
        for s in self.lags:
            if s.lag == lag:
                return s
        raise KeyError(f"no statistics for lag {lag}; lags: {[s.lag for s in self.lags]}")


def _valid(boxes: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(boxes), axis=1) & (boxes[:, 2] > 0) & (boxes[:, 3] > 0)


def on_annotation_grid(boxes: np.ndarray, width: int, annotated_width: int = 1280) -> np.ndarray:
    """``x, y, w, h`` boxes of a ``width``-wide frame as UAV123's annotations write them on a
    frame ``annotated_width`` pixels wide: each of ``x, y, w, h`` rounded to a whole pixel of
    that frame, returned in the units of ``width``; NaN rows stay NaN. For comparing exact
    synthetic ground truth with integer annotations like for like, at any render size.
    (Rounding ``x, y, w, h`` each, rather than the box's edges: UAV123's 1-frame changes of
    position and of size are nearly uncorrelated, -0.08, as they are for ``x, y, w, h``
    rounding, -0.07 on the default synthetic suite, and unlike edge rounding, -0.27;
    docs/decisions/data.md.)"""
    s = annotated_width / float(width)
    return np.round(np.asarray(boxes, dtype=float).reshape(-1, 4) * s) / s


def box_pairs(groundtruth: np.ndarray, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """The boxes ``(a, b)`` of frames ``k`` and ``k + lag`` for every ``k`` where both are valid
    (finite, positive size)."""
    g = np.asarray(groundtruth, dtype=float).reshape(-1, 4)
    if lag < 1:
        raise ValueError(f"lag must be >= 1 frame, got {lag}")
    a, b = g[:-lag], g[lag:]
    ok = _valid(a) & _valid(b)
    return a[ok], b[ok]


def target_motion(groundtruths: Iterable[np.ndarray], lags: Sequence[int] = LAGS) -> TargetMotion:
    """Target motion statistics of sequences given as (N, 4) ``x, y, w, h`` ground truths (NaN
    rows, absent targets, are skipped with the pairs they belong to)."""
    gts = [np.asarray(g, dtype=float).reshape(-1, 4) for g in groundtruths]
    out = []
    for lag in lags:
        pairs = [box_pairs(g, lag) for g in gts]
        a = np.concatenate([p[0] for p in pairs]) if pairs else np.empty((0, 4))
        b = np.concatenate([p[1] for p in pairs]) if pairs else np.empty((0, 4))
        size_a = np.sqrt(a[:, 2] * a[:, 3])
        size_b = np.sqrt(b[:, 2] * b[:, 3])
        disp = np.linalg.norm((b[:, :2] + b[:, 2:] / 2) - (a[:, :2] + a[:, 2:] / 2), axis=1) / size_a
        scale = np.abs(np.log(size_b / size_a))
        out.append(LagStats(
            lag=int(lag), n_pairs=len(a),
            displacement_median=_q(disp, 50), displacement_p90=_q(disp, 90),
            scale_median=_q(scale, 50), scale_p90=_q(scale, 90),
            iou_below_half=float(np.mean(iou(a, b) < 0.5)) if len(a) else float("nan")))
    return TargetMotion(len(gts), tuple(out))


def _q(x: np.ndarray, pct: float) -> float:
    return float(np.percentile(x, pct)) if len(x) else float("nan")


# --- camera motion --------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraMotion:
    """Camera motion statistics: medians and 90th percentiles of per-frame rates (per second)."""

    n_frames: int                  # inter-frame homographies used
    fps: float
    translation_median: float      # image widths / s
    translation_p90: float
    rotation_median: float         # deg / s
    rotation_p90: float
    zoom_median: float             # |log scale| / s
    zoom_p90: float
    jerk_median: float             # image widths / s^2
    jerk_p90: float


def similarity_parts(H: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float, float]:
    """An inter-frame homography linearised at the image centre ``c``: the centre's
    displacement ``H(c) - c`` (px), the rotation (rad) and the log scale of the Jacobian."""
    H = np.asarray(H, dtype=float)
    c = np.array([width / 2.0, height / 2.0, 1.0])
    p = H @ c
    moved = p[:2] / p[2]
    # d/du of (H[:2] (c + u)) / (H[2] (c + u)) at u = 0
    J = (H[:2, :2] - np.outer(moved, H[2, :2])) / p[2]
    rotation = float(np.arctan2(J[1, 0] - J[0, 1], J[0, 0] + J[1, 1]))
    log_scale = 0.5 * float(np.log(abs(np.linalg.det(J))))
    return moved - c[:2], rotation, log_scale


def camera_rates(homographies: Iterable[np.ndarray | None], width: int, height: int, fps: float) -> np.ndarray:
    """(n, 4) per-frame rates of a sequence's inter-frame homographies (frame k-1 -> k,
    consecutive): translation (image widths / s), rotation (deg / s), zoom (|log scale| / s),
    jerk (image widths / s^2; NaN where the previous homography is missing). None or
    non-finite entries (failed estimates) are skipped."""
    rows = []
    prev = None
    for H in homographies:
        if H is None or not np.all(np.isfinite(H)):
            prev = None
            continue
        t, r, z = similarity_parts(H, width, height)
        v = t / width * fps
        jerk = np.linalg.norm(v - prev) * fps if prev is not None else np.nan
        rows.append((np.linalg.norm(v), abs(np.degrees(r)) * fps, abs(z) * fps, jerk))
        prev = v
    return np.asarray(rows, dtype=float).reshape(-1, 4)


def camera_motion(rates: Iterable[np.ndarray], fps: float) -> CameraMotion:
    """Statistics of the :func:`camera_rates` of one or more sequences, pooled (``fps``: the
    camera rate they were measured at, reported as is)."""
    a = np.concatenate([np.asarray(r, dtype=float).reshape(-1, 4) for r in rates] or [np.empty((0, 4))])
    j = a[np.isfinite(a[:, 3]), 3]
    return CameraMotion(len(a), float(fps), _q(a[:, 0], 50), _q(a[:, 0], 90), _q(a[:, 1], 50), _q(a[:, 1], 90),
                        _q(a[:, 2], 50), _q(a[:, 2], 90), _q(j, 50), _q(j, 90))


def estimate_homographies(images: Iterator[np.ndarray], egomotion) -> list[np.ndarray | None]:
    """Inter-frame homographies of a frame stream by an egomotion block (``initialize(image)``,
    ``estimate(image) -> Motion``): one per frame after the first, None where it failed."""
    it = iter(images)
    egomotion.initialize(next(it))
    out = []
    for img in it:
        m = egomotion.estimate(img)
        out.append(np.asarray(m.H, dtype=float) if m.valid else None)
    return out
