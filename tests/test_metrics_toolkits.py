"""Each compatibility profile against a reference written the way that toolkit computes, from the
formal definitions in EVAL_TOOLKITS.md: sentinel values (-1 for invalid frames) counted against
the thresholds and divided by the toolkit's denominator, one frame at a time. Random sequences
with NaN rows, boxes touching the left/top border, zero-size predictions and a noisy frame 0."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mata_eval.score import metrics as M

IOU_GRID = [i * 0.05 for i in range(21)]


def box_iou(p, g, toolkit: str) -> float:
    if toolkit == "pytracking":  # inclusive pixel corners, no clipping
        iw = min(p[0] + p[2] - 1, g[0] + g[2] - 1) - max(p[0], g[0]) + 1
        ih = min(p[1] + p[3] - 1, g[1] + g[3] - 1) - max(p[1], g[1]) + 1
        inter = max(iw, 0.0) * max(ih, 0.0)
        return inter / (p[2] * p[3] + g[2] * g[3] - inter)
    iw = min(p[0] + p[2], g[0] + g[2]) - max(p[0], g[0])
    ih = min(p[1] + p[3], g[1] + g[3]) - max(p[1], g[1])
    inter = max(iw, 0.0) * max(ih, 0.0)
    union = p[2] * p[3] + g[2] * g[3] - inter
    return min(1.0, inter / union) if union > 0 else 0.0  # pysot and got10k clip to [0, 1]


def reference(pred: np.ndarray, gt: np.ndarray, toolkit: str) -> tuple[float, float, float]:
    """(AUC, P@20, NP@0.2) per EVAL_TOOLKITS.md's table, frame by frame."""
    pred = pred.copy()
    gt = gt.copy()
    if toolkit in ("got10k", "pytracking"):
        pred[0] = gt[0]
    if toolkit == "pytracking":
        for i in range(1, len(pred)):
            if (pred[i, 2] == 0 or pred[i, 3] == 0) and not np.isnan(gt[i]).any():
                pred[i] = pred[i - 1]
    if toolkit == "got10k":  # UAV123 experiment: NaN rows removed
        keep = ~np.isnan(gt).any(axis=1)
        pred, gt = pred[keep], gt[keep]
    n = len(gt)
    ious, dists, ndists = [], [], []
    for p, g in zip(pred.tolist(), gt.tolist()):
        legacy = toolkit != "mmtracking"
        off = 1.0 if legacy else 0.0
        cg = (g[0] + (g[2] - off) / 2, g[1] + (g[3] - off) / 2)
        cp = (p[0] + (p[2] - off) / 2, p[1] + (p[3] - off) / 2)
        nan = any(math.isnan(v) for v in g)
        if toolkit == "pysot":
            s_ok = not nan and g[2] > 0 and g[3] > 0
            p_ok = not nan and cg[0] > 0 and cg[1] > 0
        elif toolkit == "pysot-toolkit":
            s_ok = not nan and all(v > 0 for v in g)
            p_ok = not nan and cg[0] > 0 and cg[1] > 0
        elif toolkit == "mmtracking":
            s_ok = not nan and g[2] > 0 and g[3] > 0
            p_ok = not nan and cg[0] > 0 and cg[1] > 0
        elif toolkit == "pytracking":
            s_ok = p_ok = not nan and all(v > 0 for v in g)
        else:  # got10k: everything left is valid
            s_ok = p_ok = True
        ious.append(box_iou(p, g, toolkit) if s_ok else -1.0)
        if p_ok:
            dx, dy = cp[0] - cg[0], cp[1] - cg[1]
            sx, sy = (max(1.0, g[2]), max(1.0, g[3])) if toolkit == "got10k" else (g[2], g[3])
            dists.append(math.hypot(dx, dy))
            ndists.append(math.hypot(dx / sx, dy / sy))
        else:  # distance -1: below every threshold, a hit
            dists.append(-1.0)
            ndists.append(-1.0)
    auc = sum(sum(o > t for o in ious) for t in IOU_GRID) / (len(IOU_GRID) * n)
    p20 = sum(d <= 20 for d in dists) / n
    np20 = sum(d <= 0.2 for d in ndists) / n
    return auc, p20, np20


def random_case(seed: int, n: int = 80) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xy = 40 + np.cumsum(rng.normal(0, 2, (n, 2)), axis=0)
    gt = np.c_[xy, rng.uniform(8, 30, (n, 2))]
    border = rng.choice(np.arange(1, n // 2), 3, replace=False)
    gt[border, 0] = 0.0                                             # GT touching the left border
    pred = gt + rng.normal(0, 4, (n, 4))
    pred[:, 2:] = np.abs(pred[:, 2:]) + 1
    pred[0] += [6, -3, 0, 0]                                        # frame 0 not exactly the GT
    pred[rng.integers(n // 2, n):, :2] += 60                        # lost for the rest
    gt[rng.choice(np.arange(1, n), 5, replace=False)] = np.nan      # absent target
    pred[rng.choice(np.arange(1, n), 2, replace=False), 2:] = 0.0   # zero-size predictions
    return pred, gt


@pytest.mark.parametrize("toolkit", ["pysot", "pysot-toolkit", "got10k", "pytracking", "mmtracking"])
@pytest.mark.parametrize("seed", range(5))
def test_profile_matches_toolkit_reference(toolkit, seed):
    pred, gt = random_case(seed)
    s = M.score_sequence(pred, gt, profile=toolkit)
    auc, p20, np20 = reference(pred, gt, toolkit)
    assert s.msr == pytest.approx(auc, abs=1e-12)
    assert s.precision20 == pytest.approx(p20, abs=1e-12)
    if toolkit != "got10k":
        assert s.pr == pytest.approx(np20, abs=1e-12)


def test_profiles_disagree_as_the_toolkits_do():
    """The differences users keep asking about, on one sequence: pysot-toolkit <= pysot (border
    GT fails), got10k >= pysot (NaN rows removed, frame 0 := GT), mmtracking == pysot here."""
    pred, gt = random_case(3)
    auc = {p: M.score_sequence(pred, gt, profile=p).msr for p in M.PROFILES}
    assert auc["pysot-toolkit"] < auc["pysot"] == pytest.approx(auc["mmtracking"])
    assert auc["got10k"] > auc["pysot"]
    assert auc["default"] > auc["pysot"]  # NaN frames excluded instead of failed
