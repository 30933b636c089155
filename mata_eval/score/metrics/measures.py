"""Measures of one sequence (paper section 3.3; DESIGN.md "Metrics"): per-frame IoU and centre
errors, and the sequence's SR, MSR, PR, P@20 and NT2F under a metric profile.

Definitions (``default`` profile; ``docs/metrics.md`` has the full table):

- IoU per frame, continuous formula on ``x, y, w, h`` boxes (:func:`iou`).
- Frames whose ground truth is missing (NaN) or degenerate (width or height <= 0) are skipped by
  every metric; their number is reported as ``n_excluded``.
- SR: fraction of frames with IoU > 0.5. MSR: mean of the success curve over the 21 thresholds
  ``np.arange(0, 1.05, 0.05)`` with ``IoU > t`` (a perfect tracker scores 20/21, as everywhere).
- PR: normalised precision at 0.2, the centre error divided per axis by the ground-truth size.
  ``precision20``: fraction of frames with centre error <= 20 px.
- NT2F (eq. nt2f): ``T_f / N`` with ``T_f`` the index of the first frame with IoU <= tau
  (tau = 0), ``N`` if none, and ``N`` the sequence length; frames that are not scored or have no
  valid ground truth cannot fail (profile ``nt2f-valid``: they do not count in time either).

Everything is vectorised numpy: one sequence costs a handful of array operations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, Mapping, Sequence

import numpy as np

from ...core.metric_profiles import (NORM_GRID, P20_INDEX, PIXEL_GRID, SR_INDEX, InvalidAction, Profile,
                                     Validity, get_profile)


# --- per-frame measures ----------------------------------------------------------------------


def _as_boxes(a: np.ndarray | Sequence, what: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1 and arr.size == 4:
        arr = arr.reshape(1, 4)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{what}: expected an (N, 4) array of x, y, w, h boxes, got shape {arr.shape}")
    return arr


def iou(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-frame intersection over union of ``x, y, w, h`` boxes, ``(N,)`` in [0, 1].

    Continuous formula (paper 3.3; equals the ``+1``-pixel formula of pytracking). Boxes with a
    negative width or height are empty; a non-finite box or an empty union gives 0, so a missing
    prediction can never count as a success."""
    p = _as_boxes(pred, "pred")
    g = _as_boxes(gt, "gt")
    if p.shape != g.shape:
        raise ValueError(f"iou: pred has {len(p)} boxes, gt has {len(g)}")
    pw, ph = np.maximum(p[:, 2], 0.0), np.maximum(p[:, 3], 0.0)
    gw, gh = np.maximum(g[:, 2], 0.0), np.maximum(g[:, 3], 0.0)
    iw = np.minimum(p[:, 0] + pw, g[:, 0] + gw) - np.maximum(p[:, 0], g[:, 0])
    ih = np.minimum(p[:, 1] + ph, g[:, 1] + gh) - np.maximum(p[:, 1], g[:, 1])
    inter = np.maximum(iw, 0.0) * np.maximum(ih, 0.0)
    union = pw * ph + gw * gh - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = inter / union
    out[~np.isfinite(out) | ~(union > 0)] = 0.0
    return np.clip(out, 0.0, 1.0)


def iou_pixel_inclusive(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """pytracking's IoU: corners ``x + w - 1``, sizes ``br - tl + 1``, no clipping. Equal to
    :func:`iou` up to float rounding (which it keeps, as pytracking does); non-finite -> 0."""
    p = _as_boxes(pred, "pred")
    g = _as_boxes(gt, "gt")
    tl = np.maximum(p[:, :2], g[:, :2])
    br = np.minimum(p[:, :2] + p[:, 2:] - 1.0, g[:, :2] + g[:, 2:] - 1.0)
    inter = np.prod(np.maximum(br - tl + 1.0, 0.0), axis=1)
    union = np.prod(p[:, 2:], axis=1) + np.prod(g[:, 2:], axis=1) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = inter / union
    out[~np.isfinite(out)] = 0.0
    return out


def centers(boxes: np.ndarray, convention: Literal["continuous", "legacy"] = "continuous") -> np.ndarray:
    """Box centres ``(N, 2)``: ``x + w/2`` or the MATLAB-legacy ``x + (w - 1)/2``."""
    b = _as_boxes(boxes, "boxes")
    off = 0.0 if convention == "continuous" else 1.0
    return b[:, :2] + (b[:, 2:] - off) / 2.0


def valid_ground_truth(gt: np.ndarray) -> np.ndarray:
    """The default validity mask: finite, width > 0 and height > 0 (DESIGN.md "Metrics")."""
    g = _as_boxes(gt, "gt")
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(g), axis=1) & (g[:, 2] > 0) & (g[:, 3] > 0)


def _validity(kind: Validity, g: np.ndarray, center: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        if kind == "finite":
            return ~np.any(np.isnan(g), axis=1)
        if kind == "wh":
            return np.all(np.isfinite(g), axis=1) & (g[:, 2] > 0) & (g[:, 3] > 0)
        if kind == "xywh":
            return np.all(g > 0, axis=1)
        if kind == "center":
            return np.all(center > 0, axis=1)
    raise ValueError(f"unknown validity rule {kind!r}")


def _curve(values: np.ndarray, valid: np.ndarray, action: InvalidAction, thresholds: np.ndarray,
           above: bool) -> np.ndarray:
    """Fraction of frames passing each threshold (``value > t`` if ``above`` else ``<=``), with
    invalid frames excluded, failed or hit as ``action`` says. NaN values never pass."""
    if action == "exclude":
        values, extra, denom = values[valid], 0, int(valid.sum())
    else:
        values, extra, denom = values[valid], (int((~valid).sum()) if action == "hit" else 0), len(valid)
    if denom == 0:
        return np.full(len(thresholds), np.nan)
    with np.errstate(invalid="ignore"):
        passed = values[:, None] > thresholds[None, :] if above else values[:, None] <= thresholds[None, :]
    return (passed.sum(axis=0) + extra) / float(denom)


def first_failure(ious: np.ndarray, tau: float = 0.0) -> int:
    """``T_f`` of eq. nt2f: index of the first IoU <= tau, ``len(ious)`` if none."""
    fails = np.flatnonzero(~(np.asarray(ious, dtype=float) > tau))
    return int(fails[0]) if fails.size else int(len(ious))


def nt2f(ious: np.ndarray, tau: float = 0.0) -> float:
    """Normalised time to failure, eq. nt2f: ``T_f / N`` (NaN for an empty sequence)."""
    n = len(ious)
    return first_failure(ious, tau) / n if n else float("nan")


# --- one sequence ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SequenceScores:
    """Metrics of one sequence. Curves are over the profile's thresholds (success: 21 IoU
    thresholds; precision: 0..50 px; normalised precision: 0..0.5). Values are fractions in
    [0, 1]; NaN where no frame could be scored.

    ``n_frames``: length of the sequence; ``n_scored``: frames the protocol scored and that are
    annotated (the frames any metric looks at); ``n_excluded``: of those, frames left out of the
    success denominator because of their ground truth (profile policy; with ``default`` every
    NaN / zero-size ground-truth frame); ``n_invalid_gt``: of those, frames with NaN or zero-size
    ground truth whatever the profile does with them; ``failure_frame``: the frame index (in the
    sequence) of the NT2F failure, None if the tracker never failed.
    """

    sr: float
    msr: float
    pr: float
    precision20: float
    nt2f: float
    n_frames: int
    n_scored: int
    n_excluded: int
    success_curve: np.ndarray
    precision_curve: np.ndarray
    norm_precision_curve: np.ndarray
    n_invalid_gt: int = 0
    failure_frame: int | None = None

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            d[k] = [json_float(v) for v in d[k]]
        for k in ("sr", "msr", "pr", "precision20", "nt2f"):
            d[k] = json_float(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "SequenceScores":
        kw = dict(d)
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            kw[k] = np.array([np.nan if v is None else v for v in kw[k]], dtype=float)
        for k in ("sr", "msr", "pr", "precision20", "nt2f"):
            kw[k] = float("nan") if kw[k] is None else float(kw[k])
        return cls(**kw)


def json_float(v: float) -> float | None:
    v = float(v)
    return None if not np.isfinite(v) else v


def _fit_length(pred: np.ndarray, n: int, policy: str) -> np.ndarray:
    if len(pred) == n:
        return pred
    if policy == "error":
        raise ValueError(f"predictions have {len(pred)} rows but the ground truth has {n} frames")
    if len(pred) > n:
        return pred[:n]
    if policy == "pad":
        return np.vstack([pred, np.zeros((n - len(pred), 4))])
    return pred  # truncate: the caller cuts the ground truth


def _bool_mask(mask: np.ndarray | None, n: int, what: str) -> np.ndarray:
    if mask is None:
        return np.ones(n, dtype=bool)
    m = np.asarray(mask, dtype=bool).reshape(-1)
    if len(m) != n:
        raise ValueError(f"{what} mask has {len(m)} entries, the sequence has {n} frames")
    return m


def prepare_predictions(pred: np.ndarray, gt: np.ndarray, profile: Profile) -> tuple[np.ndarray, np.ndarray]:
    """Apply the profile's length, frame-0 and zero-size policies; returns (pred, gt)."""
    pred = _as_boxes(pred, "pred").copy()
    if profile.zero_size_prediction == "previous" and len(pred):
        # before any padding, as pytracking does; sequential on purpose: a run of zero-size
        # boxes carries the last good one forward
        m = min(len(pred), len(gt))
        zero = np.any(pred[:m, 2:] == 0.0, axis=1) & ~np.any(np.isnan(gt[:m]), axis=1)
        for i in np.flatnonzero(zero):
            if i > 0:
                pred[i] = pred[i - 1]
    pred = _fit_length(pred, len(gt), profile.length_mismatch)
    if len(pred) < len(gt):  # truncate policy
        gt = gt[: len(pred)]
    if profile.frame0 == "ground_truth" and len(pred):
        pred[0] = gt[0]
    return pred, gt


def score_sequence(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    profile: str | Profile = "default",
    scored: np.ndarray | None = None,
    annotated: np.ndarray | None = None,
    tau: float = 0.0,
) -> SequenceScores:
    """Score one sequence (paper 3.3). ``scored``: the protocol's scored frames (DSP keeps every
    n-th frame); ``annotated``: the sparse-annotation mask (VTUAV: every 10th frame). Only frames
    in both enter any metric. NT2F's failure is the first of those frames that also has valid
    ground truth (finite, w, h > 0) and IoU <= tau, whatever the profile: a frame without a
    target can neither fail nor succeed. ``T_f`` is that frame's index and ``N`` the sequence
    length (eq. nt2f), or both count only those frames (``nt2f_frames = "valid"``;
    ``docs/decisions/metrics.md``)."""
    prof = get_profile(profile)
    g = _as_boxes(gt, "gt")
    n_frames = len(g)
    pred, g = prepare_predictions(pred, g, prof)
    keep = _bool_mask(scored, n_frames, "scored")[: len(g)] & _bool_mask(annotated, n_frames, "annotated")[: len(g)]
    frame_index = np.flatnonzero(keep)
    p, g = pred[keep], g[keep]

    overlaps = iou(p, g) if prof.iou_formula == "continuous" else iou_pixel_inclusive(p, g)
    c_gt, c_pred = centers(g, prof.center), centers(p, prof.center)
    with np.errstate(invalid="ignore", divide="ignore"):
        dist = np.linalg.norm(c_pred - c_gt, axis=1)
        size = g[:, 2:] if prof.norm_size_floor <= 0 else np.maximum(prof.norm_size_floor, g[:, 2:])
        norm_dist = np.linalg.norm((c_pred - c_gt) / size, axis=1)

    s_valid = _validity(prof.success_valid, g, c_gt)
    success = _curve(overlaps, s_valid, prof.invalid_success, np.asarray(prof.iou_thresholds), above=True)
    precision = _curve(dist, _validity(prof.precision_valid, g, c_gt), prof.invalid_precision,
                       np.asarray(PIXEL_GRID), above=False)
    norm_precision = _curve(norm_dist, _validity(prof.norm_precision_valid, g, c_gt),
                            prof.invalid_norm_precision, np.asarray(NORM_GRID), above=False)

    valid = valid_ground_truth(g)
    nt2f_ious = overlaps[valid]
    t_f = first_failure(nt2f_ious, tau)
    failure_frame = int(frame_index[np.flatnonzero(valid)[t_f]]) if t_f < len(nt2f_ious) else None
    if prof.nt2f_frames == "valid" or not len(nt2f_ious):
        nt2f_value = nt2f(nt2f_ious, tau)
    else:  # eq. nt2f: T_f a frame of the sequence, N its length
        nt2f_value = (n_frames if failure_frame is None else failure_frame) / n_frames
    return SequenceScores(
        sr=float(success[SR_INDEX]),
        msr=float(np.mean(success)),
        pr=float(norm_precision[P20_INDEX]),
        precision20=float(precision[P20_INDEX]),
        nt2f=nt2f_value,
        n_frames=n_frames,
        n_scored=int(keep.sum()),
        n_excluded=int((~s_valid).sum()) if prof.invalid_success == "exclude" else 0,
        success_curve=success,
        precision_curve=precision,
        norm_precision_curve=norm_precision,
        n_invalid_gt=int((~valid).sum()),
        failure_frame=failure_frame,
    )

