"""The 12 UAV123 attribute flags of a generated sequence, from what was generated (thresholds in
``docs/decisions/data.md``)."""

from __future__ import annotations

import numpy as np

#: UAV123 attribute flag order (``anno/UAV123/att/<seq>.txt``).
UAV123_ATTRIBUTES = ("SV", "ARC", "LR", "FM", "FOC", "POC", "OV", "BC", "IV", "VC", "CM", "SOB")


#: a target with less than this fraction of its area visible (in the image and not occluded) is
#: "fully out of view / fully occluded": its ground-truth row is NaN, as in UAV123.
ABSENT_BELOW = 0.05


def attribute_flags(gt: np.ndarray, gt_full: np.ndarray, visible: np.ndarray, in_image: np.ndarray,
                    occluded: np.ndarray, homographies: np.ndarray, gain: np.ndarray,
                    distractor_in: np.ndarray, contrast: np.ndarray, angle: np.ndarray,
                    W: int, H: int, s: float = 1.0) -> tuple[int, ...]:
    """The 12 UAV123 flags (order :data:`UAV123_ATTRIBUTES`) from generated facts, with the
    UAV123 paper's definitions; pixel thresholds scale with ``s = width / 1280``."""
    ok = np.all(np.isfinite(gt), axis=1)
    full = gt_full[ok]
    area = full[:, 2] * full[:, 3]
    aspect = full[:, 2] / np.maximum(full[:, 3], 1e-9)
    a0, r0 = area[0], aspect[0]
    sv = bool(np.any((area / a0 < 0.5) | (area / a0 > 2.0)))
    arc = bool(np.any((aspect / r0 < 0.5) | (aspect / r0 > 2.0)))
    lr = bool(np.any(area < 400 * s * s))
    c = gt[:, :2] + gt[:, 2:] / 2
    step = np.linalg.norm(np.diff(c, axis=0), axis=1)
    fm = bool(np.any(step[np.isfinite(step)] > 20 * s))
    foc = bool(np.any((occluded >= 0.95) & (in_image > 0.05)))
    poc = bool(np.any((occluded >= 0.1) & (occluded < 0.95) & (in_image > 0.05)))
    ov = bool(np.any(in_image < 0.95))
    sampled = contrast[np.isfinite(contrast)]
    bc = bool(np.mean(sampled < 40.0) > 0.3) if len(sampled) else False
    iv = bool(gain.max() / max(gain.min(), 1e-9) > 1.3)
    rel = np.unwrap(angle[ok]) if ok.any() else np.zeros(1)
    vc = bool(np.abs(rel - rel[0]).max() > np.deg2rad(60))
    # CM: an abrupt change of the image motion (a jerk of more than 6 px/frame at the image
    # centre or a corner between consecutive inter-frame homographies).
    pts = np.array([[W / 2, H / 2, 1], [0, 0, 1], [W, 0, 1], [0, H, 1], [W, H, 1]], float)
    moved = np.einsum("nij,pj->npi", homographies, pts)
    disp = moved[..., :2] / moved[..., 2:] - pts[None, :, :2]
    jerk = np.linalg.norm(np.diff(disp[1:], axis=0), axis=2) if len(disp) > 2 else np.zeros((1, 5))
    cm = bool(np.any(jerk > 6 * s))
    sob = bool(np.any((distractor_in >= 0.5) & (visible >= ABSENT_BELOW)))
    return tuple(int(v) for v in (sv, arc, lr, fm, foc, poc, ov, bc, iv, vc, cm, sob))
