"""Tracking metrics (paper section 3.3; DESIGN.md "Metrics"): SR, MSR, PR, P@20 and NT2F per
sequence, their means per dataset and per attribute / challenge subset, block frequencies, and
named compatibility profiles that reproduce what pysot, pysot-toolkit, got10k, pytracking and
mmtracking report for the same results.

Definitions (``default`` profile; ``docs/metrics.md`` has the full table):

- IoU per frame, continuous formula on ``x, y, w, h`` boxes (:func:`iou`).
- Frames whose ground truth is missing (NaN) or degenerate (width or height <= 0) are skipped by
  every metric; their number is reported as ``n_excluded``.
- SR: fraction of frames with IoU > 0.5. MSR: mean of the success curve over the 21 thresholds
  ``np.arange(0, 1.05, 0.05)`` with ``IoU > t`` (a perfect tracker scores 20/21, as everywhere).
- PR: normalised precision at 0.2, the centre error divided per axis by the ground-truth size.
  ``precision20``: fraction of frames with centre error <= 20 px.
- NT2F (eq. nt2f): ``T_f / N`` with ``T_f`` the first frame with IoU <= tau (tau = 0), ``N`` if
  none, counted over the frames that are scored and have valid ground truth.

Everything is vectorised numpy: one sequence costs a handful of array operations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Iterable, Literal, Mapping, Sequence

import numpy as np

# --- threshold grids -------------------------------------------------------------------------

#: Success thresholds of pysot / pysot-toolkit / mmtracking / ours: ``np.arange(0, 1.05, 0.05)``
#: (its float noise included: t[6] = 0.30000000000000004; t[10] == 0.5 exactly).
PYSOT_IOU_GRID = tuple(float(t) for t in np.arange(0, 1.05, 0.05))
#: got10k builds its grid with ``np.linspace(0, 1, 21)``: the same 21 doubles.
GOT10K_IOU_GRID = tuple(float(t) for t in np.linspace(0, 1, 21))
#: pytracking builds it with ``torch.arange(0, 1.05, 0.05, dtype=float64)``, which differs from
#: numpy's by one ulp at 0.65 and 0.75 (written out here so the core does not need torch).
PYTRACKING_IOU_GRID = tuple(
    float(np.nextafter(t, 1.0)) if i in (13, 15) else t for i, t in enumerate(PYSOT_IOU_GRID))
#: Precision thresholds in pixels (``<=``), value reported at 20 px (index 20).
PIXEL_GRID = tuple(float(t) for t in np.arange(0, 51))
#: Normalised-precision thresholds (``<=``), value reported at 0.2 (index 20).
NORM_GRID = tuple(float(t) for t in np.arange(0, 51) / 100.0)
SR_INDEX = 10  # IoU > 0.5
P20_INDEX = 20  # 20 px, or 0.2 of the target size

Validity = Literal["finite", "wh", "xywh", "center"]
InvalidAction = Literal["exclude", "fail", "hit"]


@dataclass(frozen=True)
class Profile:
    """The policies that make toolkits disagree on the same results (EVAL_TOOLKITS.md).

    Validity of a ground-truth row (``*_valid``): ``finite`` = no NaN; ``wh`` = finite with
    w > 0 and h > 0; ``xywh`` = all four values > 0 (a box touching the left/top border is
    invalid); ``center`` = both centre coordinates > 0. What an invalid scored frame does
    (``invalid_*``): ``exclude`` = left out of numerator and denominator; ``fail`` = kept in the
    denominator and never a success; ``hit`` = kept and counted as a success at every threshold
    (what the distance = -1 trick of pysot / pytracking-uav / mmtracking does).
    """

    name: str
    description: str
    iou_thresholds: tuple[float, ...] = PYSOT_IOU_GRID
    success_valid: Validity = "wh"
    invalid_success: InvalidAction = "exclude"
    precision_valid: Validity = "wh"
    invalid_precision: InvalidAction = "exclude"
    norm_precision_valid: Validity = "wh"
    invalid_norm_precision: InvalidAction = "exclude"
    #: ``continuous``: :func:`iou`, clipped to [0, 1]; ``pixel_inclusive``: pytracking's
    #: ``br = x + w - 1``, ``sz = br - tl + 1`` without clipping, where float rounding can put
    #: the IoU of identical boxes a hair above 1 (then it passes the last threshold).
    iou_formula: Literal["continuous", "pixel_inclusive"] = "continuous"
    #: ``continuous``: centre ``x + w/2``; ``legacy``: ``x + (w - 1)/2`` (MATLAB heritage).
    #: The two only differ in the ``center`` validity mask, distances are the same.
    center: Literal["continuous", "legacy"] = "continuous"
    #: the normalised error divides by ``max(floor, w_gt)`` per axis (got10k: 1; others: none).
    norm_size_floor: float = 0.0
    #: ``ground_truth``: the prediction of frame 0 is replaced by its ground truth (got10k,
    #: pytracking); ``as_is``: scored as it is in the file.
    frame0: Literal["as_is", "ground_truth"] = "as_is"
    #: ``previous``: a prediction with zero width or height is replaced by the previous one
    #: (pytracking, only where the ground truth is not NaN).
    zero_size_prediction: Literal["as_is", "previous"] = "as_is"
    #: predictions longer / shorter than the ground truth: ``error``; ``truncate`` to the shorter
    #: of the two (got10k); ``pad`` with zero boxes or truncate (pytracking).
    length_mismatch: Literal["error", "truncate", "pad"] = "error"


PROFILES: dict[str, Profile] = {
    p.name: p
    for p in (
        Profile(
            "default",
            "mata-eval: frames with NaN or zero-size ground truth are skipped by every metric "
            "(and counted); frame 0 scored as predicted",
        ),
        Profile(
            "pysot",
            "STVIR/pysot toolkit: invalid GT (w or h <= 0, NaN) is a failure for success and a hit "
            "for (normalised) precision; denominator = all frames",
            success_valid="wh", invalid_success="fail",
            precision_valid="center", invalid_precision="hit",
            norm_precision_valid="center", invalid_norm_precision="hit", center="legacy",
        ),
        Profile(
            "pysot-toolkit",
            "StrangerZhang/pysot-toolkit: as pysot, but success needs all of x, y, w, h > 0 "
            "(GT touching the left/top border is a failure)",
            success_valid="xywh", invalid_success="fail",
            precision_valid="center", invalid_precision="hit",
            norm_precision_valid="center", invalid_norm_precision="hit", center="legacy",
        ),
        Profile(
            "got10k",
            "got10k ExperimentUAV123: NaN GT rows removed; frame 0 replaced by GT; normalised error "
            "divided by max(1, w), max(1, h)",
            iou_thresholds=GOT10K_IOU_GRID,
            success_valid="finite", invalid_success="exclude",
            precision_valid="finite", invalid_precision="exclude",
            norm_precision_valid="finite", invalid_norm_precision="exclude", center="legacy",
            norm_size_floor=1.0, frame0="ground_truth", length_mismatch="truncate",
        ),
        Profile(
            "pytracking",
            "pytracking (dataset 'uav'): GT valid if x, y, w, h > 0; invalid = failure for success, "
            "hit for (normalised) precision; frame 0 replaced by GT; zero-size predictions held",
            iou_thresholds=PYTRACKING_IOU_GRID,
            success_valid="xywh", invalid_success="fail",
            precision_valid="xywh", invalid_precision="hit",
            norm_precision_valid="xywh", invalid_norm_precision="hit", center="legacy",
            frame0="ground_truth", zero_size_prediction="previous", length_mismatch="pad",
            iou_formula="pixel_inclusive",
        ),
        Profile(
            "mmtracking",
            "mmtracking eval_sot_ope: success needs w, h > 0 (else failure); precision needs centre "
            "x + w/2, y + h/2 > 0 (else hit); denominator = all frames",
            success_valid="wh", invalid_success="fail",
            precision_valid="center", invalid_precision="hit",
            norm_precision_valid="center", invalid_norm_precision="hit", center="continuous",
        ),
    )
}


def get_profile(profile: str | Profile) -> Profile:
    """A profile by name (KeyError lists the names) or the profile itself."""
    if isinstance(profile, Profile):
        return profile
    try:
        return PROFILES[profile]
    except KeyError:
        raise KeyError(f"unknown metric profile {profile!r}; available: {', '.join(PROFILES)}") from None


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
            d[k] = [_json_float(v) for v in d[k]]
        for k in ("sr", "msr", "pr", "precision20", "nt2f"):
            d[k] = _json_float(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "SequenceScores":
        kw = dict(d)
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            kw[k] = np.array([np.nan if v is None else v for v in kw[k]], dtype=float)
        for k in ("sr", "msr", "pr", "precision20", "nt2f"):
            kw[k] = float("nan") if kw[k] is None else float(kw[k])
        return cls(**kw)


def _json_float(v: float) -> float | None:
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
    in both enter any metric. NT2F is computed over those frames that also have valid ground
    truth (finite, w, h > 0) whatever the profile: frames without a target can neither fail nor
    succeed, so they are skipped in time (``docs/decisions/metrics.md``)."""
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
    return SequenceScores(
        sr=float(success[SR_INDEX]),
        msr=float(np.mean(success)),
        pr=float(norm_precision[P20_INDEX]),
        precision20=float(precision[P20_INDEX]),
        nt2f=nt2f(nt2f_ious, tau),
        n_frames=n_frames,
        n_scored=int(keep.sum()),
        n_excluded=int((~s_valid).sum()) if prof.invalid_success == "exclude" else 0,
        success_curve=success,
        precision_curve=precision,
        norm_precision_curve=norm_precision,
        n_invalid_gt=int((~valid).sum()),
        failure_frame=failure_frame,
    )


# --- datasets and subsets --------------------------------------------------------------------

METRIC_NAMES = ("sr", "msr", "pr", "precision20", "nt2f")

#: DESIGN.md challenge groups, each "any of" these sequence attributes (compared upper-case).
#: UAV123: FOC / POC (full / partial occlusion), SOB (similar object), FM (fast motion), OV;
#: AOC marks a sequence with augmented occlusion events (set by the occlusion augmentation).
#: The same concepts in DTB70 (OCC, SOA) and UAVDT (LO, large occlusion) are included; they
#: change nothing on UAV123, whose attribute names differ.
DEFAULT_GROUPS: dict[str, tuple[str, ...]] = {
    "occlusion": ("FOC", "POC", "AOC", "OCC", "LO"),
    "distractor": ("SOB", "SOA"),
    "high dynamic": ("FM",),
    "out of view": ("OV",),
}


@dataclass(frozen=True, eq=False)
class Summary:
    """Means over the sequences of a set (every toolkit averages per sequence first). Sequences
    where a metric is NaN (nothing could be scored) are left out of that metric's mean."""

    n_sequences: int
    sr: float
    msr: float
    pr: float
    precision20: float
    nt2f: float
    success_curve: np.ndarray
    precision_curve: np.ndarray
    norm_precision_curve: np.ndarray
    n_frames: int
    n_scored: int
    n_excluded: int
    n_invalid_gt: int

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            d[k] = [_json_float(v) for v in d[k]]
        for k in METRIC_NAMES:
            d[k] = _json_float(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "Summary":
        kw = dict(d)
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            kw[k] = np.array([np.nan if v is None else v for v in kw[k]], dtype=float)
        for k in METRIC_NAMES:
            kw[k] = float("nan") if kw[k] is None else float(kw[k])
        return cls(**kw)


def _nanmean_rows(rows: list[np.ndarray], width: int) -> np.ndarray:
    if not rows:
        return np.full(width, np.nan)
    a = np.vstack(rows)
    ok = np.isfinite(a)
    counts = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, np.where(ok, a, 0.0).sum(axis=0) / counts, np.nan)


def summarize(scores: Iterable[SequenceScores]) -> Summary:
    """Per-dataset means of a set of sequences."""
    scores = list(scores)
    scorable = [s for s in scores if np.isfinite(s.msr) or np.isfinite(s.nt2f)]

    def mean(name: str) -> float:
        vals = np.array([getattr(s, name) for s in scores], dtype=float)
        vals = vals[np.isfinite(vals)]
        return float(vals.mean()) if vals.size else float("nan")

    return Summary(
        n_sequences=len(scorable),
        **{m: mean(m) for m in METRIC_NAMES},
        success_curve=_nanmean_rows([s.success_curve for s in scores], len(PYSOT_IOU_GRID)),
        precision_curve=_nanmean_rows([s.precision_curve for s in scores], len(PIXEL_GRID)),
        norm_precision_curve=_nanmean_rows([s.norm_precision_curve for s in scores], len(NORM_GRID)),
        n_frames=sum(s.n_frames for s in scores),
        n_scored=sum(s.n_scored for s in scores),
        n_excluded=sum(s.n_excluded for s in scores),
        n_invalid_gt=sum(s.n_invalid_gt for s in scores),
    )


@dataclass(frozen=True, eq=False)
class Aggregate:
    """Dataset-level means, per attribute (every attribute present) and per challenge group
    (every configured group, possibly empty: ``n_sequences == 0`` and NaN values)."""

    overall: Summary
    attributes: dict[str, Summary]
    groups: dict[str, Summary]
    group_definitions: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: means over the frames an augmented occluder covers (sequences with occluded frames only)
    occluded_frames: Summary | None = None

    def to_dict(self) -> dict:
        return {
            "overall": self.overall.to_dict(),
            "attributes": {k: v.to_dict() for k, v in self.attributes.items()},
            "groups": {k: v.to_dict() for k, v in self.groups.items()},
            "group_definitions": {k: list(v) for k, v in self.group_definitions.items()},
            "occluded_frames": None if self.occluded_frames is None else self.occluded_frames.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Aggregate":
        return cls(
            overall=Summary.from_dict(d["overall"]),
            attributes={k: Summary.from_dict(v) for k, v in d["attributes"].items()},
            groups={k: Summary.from_dict(v) for k, v in d["groups"].items()},
            group_definitions={k: tuple(v) for k, v in d.get("group_definitions", {}).items()},
            occluded_frames=Summary.from_dict(d["occluded_frames"]) if d.get("occluded_frames") else None,
        )


def aggregate(
    items: Iterable[tuple[SequenceScores, Iterable[str]]],
    groups: Mapping[str, Iterable[str]] | None = None,
) -> Aggregate:
    """Means over sequences, per attribute and per challenge group. ``items``: (scores,
    attributes of the sequence). ``groups``: name -> attributes, a sequence belongs to the group
    if it has any of them (case-insensitive); default :data:`DEFAULT_GROUPS`."""
    items = [(s, frozenset(attrs)) for s, attrs in items]
    defs = {k: tuple(v) for k, v in (DEFAULT_GROUPS if groups is None else groups).items()}
    present = sorted(set().union(*(a for _, a in items))) if items else []

    def in_group(attrs: frozenset[str], members: Iterable[str]) -> bool:
        return bool({a.upper() for a in attrs} & {m.upper() for m in members})

    return Aggregate(
        overall=summarize(s for s, _ in items),
        attributes={a: summarize(s for s, attrs in items if a in attrs) for a in present},
        groups={name: summarize(s for s, attrs in items if in_group(attrs, members))
                for name, members in defs.items()},
        group_definitions=defs,
    )


# --- block frequencies -----------------------------------------------------------------------


@dataclass(frozen=True)
class BlockFrequency:
    """How often a block ran. ``scheduled_hz``: starts per second of camera time (what the
    protocol made it do, paper "Freq."); ``wall_hz``: 1 / mean wall-clock time of a call (how
    fast it could go on this machine); NaN where unknown."""

    starts: int
    camera_seconds: float
    total_ms: float

    @property
    def scheduled_hz(self) -> float:
        return self.starts / self.camera_seconds if self.camera_seconds > 0 else float("nan")

    @property
    def wall_hz(self) -> float:
        return 1000.0 * self.starts / self.total_ms if self.total_ms > 0 else float("nan")

    def __add__(self, other: "BlockFrequency") -> "BlockFrequency":
        return BlockFrequency(self.starts + other.starts, self.camera_seconds + other.camera_seconds,
                              self.total_ms + other.total_ms)

    def to_dict(self) -> dict:
        return {"starts": self.starts, "camera_seconds": self.camera_seconds, "total_ms": self.total_ms,
                "scheduled_hz": _json_float(self.scheduled_hz), "wall_hz": _json_float(self.wall_hz)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "BlockFrequency":
        return cls(int(d["starts"]), float(d["camera_seconds"]), float(d["total_ms"]))


def block_frequencies(wall_ms: Mapping[str, np.ndarray], n_frames: int, fps: float) -> dict[str, BlockFrequency]:
    """Frequencies of each block of one sequence from its per-frame wall times in ms (NaN where
    the block did not start at that frame; architecture.md ``<seq>.frames.csv``). The camera
    time of a sequence of ``n_frames`` frames is ``n_frames / fps``."""
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    out = {}
    for block, ms in wall_ms.items():
        ms = np.asarray(ms, dtype=float)
        started = np.isfinite(ms)
        out[block] = BlockFrequency(int(started.sum()), n_frames / fps, float(ms[started].sum()))
    return out


def combine_frequencies(per_sequence: Iterable[Mapping[str, BlockFrequency]]) -> dict[str, BlockFrequency]:
    """Dataset-level frequencies: starts and times summed over sequences (time-weighted)."""
    out: dict[str, BlockFrequency] = {}
    for seq in per_sequence:
        for block, f in seq.items():
            out[block] = out[block] + f if block in out else f
    return out
