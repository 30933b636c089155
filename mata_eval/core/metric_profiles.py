"""Metric profiles (paper section 3.3; ``docs/metrics.md``): the threshold grids and the
policies in which toolkits (pysot, pysot-toolkit, got10k, pytracking, mmtracking) disagree on
the same results. A profile is plain data: the experiment file names one (``metrics.profile``)
and :mod:`mata_eval.score.metrics` applies it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

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
    """The policies that make toolkits disagree on the same results (``docs/metrics.md``).

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
    #: NT2F (eq. nt2f; no toolkit has it). ``sequence``: as the paper, ``T_f`` is the frame index
    #: of the first failure and ``N`` the sequence length; ``valid``: both count only the scored,
    #: annotated frames with valid ground truth. Frames without a valid target never fail.
    nt2f_frames: Literal["sequence", "valid"] = "sequence"


PROFILES: dict[str, Profile] = {
    p.name: p
    for p in (
        Profile(
            "default",
            "mata-eval: frames with NaN or zero-size ground truth are skipped by every metric "
            "(and counted); frame 0 scored as predicted",
        ),
        Profile(
            "nt2f-valid",
            "as default, but NT2F's T_f and N count only the scored frames with valid ground truth "
            "(frames without a target skipped in time, not only for the failure)",
            nt2f_frames="valid",
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
            "got10k ExperimentOTB/UAV123/DTB70: NaN GT rows removed, every other row scored as written "
            "(DTB70's 0,0,0,0 = failure); frame 0 replaced by GT; normalised error divided by "
            "max(1, w), max(1, h)",
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

