"""Search/template crops and the map back to image pixels (MODELS.md section 1.6).

These follow the crop shared by the OSTrack/MixFormerV2 family (``sample_target``,
``map_box_back``, ``clip_box`` in their ``lib/`` folders): a square of side
``ceil(sqrt(w h) * factor)`` centred on the box (or on a given centre, the MATA prior), padded
with zeros outside the image and resized to ``output_size`` with bilinear interpolation.
"""

from __future__ import annotations

import math
from typing import Sequence

import cv2
import numpy as np

from mata_eval.types import Box, within_image


def _xywh(box: Box | Sequence[float]) -> tuple[float, float, float, float]:
    if isinstance(box, Box):
        return box.x, box.y, box.w, box.h
    x, y, w, h = (float(v) for v in np.asarray(box, dtype=float).reshape(4))
    return x, y, w, h


def crop_square(image: np.ndarray, x1: int, y1: int, size: int, output_size: int,
                border_value: float | Sequence[float] = 0.0) -> np.ndarray:
    """The square ``[x1, x1 + size) x [y1, y1 + size)`` of ``image`` (parts outside the image
    filled with ``border_value``), resized to ``output_size`` x ``output_size`` (bilinear)."""
    if size < 1:
        raise ValueError(f"crop size must be >= 1 pixel, got {size}")
    h, w = image.shape[:2]
    x2, y2 = x1 + size, y1 + size
    left, top = max(0, -x1), max(0, -y1)
    right, bottom = max(0, x2 - w), max(0, y2 - h)
    # ends clamped at 0 too: a negative end would index from the far side of the image
    inside = image[max(y1, 0):max(min(y2, h), 0), max(x1, 0):max(min(x2, w), 0)]
    if inside.size == 0:  # the square lies entirely outside the image
        channels = image.shape[2] if image.ndim == 3 else 1
        value = np.broadcast_to(np.asarray(border_value, dtype=float).ravel()[:channels], (channels,))
        patch = np.empty((size, size) + image.shape[2:], dtype=image.dtype)
        patch[...] = value if image.ndim == 3 else value[0]
    elif left or top or right or bottom:
        if np.ndim(border_value) == 0:
            border = (float(border_value),) * 4
        else:
            border = tuple(float(v) for v in border_value) + (0.0,) * (4 - len(border_value))
        patch = cv2.copyMakeBorder(inside, top, bottom, left, right, cv2.BORDER_CONSTANT, value=border)
    else:
        patch = inside
    if size != output_size:
        patch = cv2.resize(patch, (output_size, output_size), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(patch)


def sample_target(image: np.ndarray, box: Box | Sequence[float], factor: float, output_size: int,
                  center: tuple[float, float] | None = None) -> tuple[np.ndarray, float]:
    """Crop a square of side ``crop_sz = ceil(sqrt(w h) * factor)`` around the box centre (or
    around ``center``, e.g. the MATA prior) and resize it to ``output_size``.

    ``x1 = round(cx - crop_sz / 2)``, same for y; out-of-image parts are black (zeros).
    Returns ``(patch, resize_factor)`` with ``resize_factor = output_size / crop_sz``.
    """
    x1, y1, crop_sz = crop_window(box, factor, center)
    patch = crop_square(image, x1, y1, crop_sz, int(output_size))
    return patch, output_size / crop_sz


def check_crop_factors(tracker: str, params: object) -> None:
    """A tracker's ``search_factor`` and ``template_factor``: positive finite numbers (an infinite
    one overflows the crop), checked when the experiment is loaded."""
    for key in ("search_factor", "template_factor"):
        v = getattr(params, key)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{tracker}: {key}: expected a positive finite number, got {v!r}")


def crop_window(box: Box | Sequence[float], factor: float,
                center: tuple[float, float] | None = None) -> tuple[int, int, int]:
    """The square :func:`sample_target` crops, in image pixels: ``(x1, y1, crop_sz)``."""
    x, y, w, h = _xywh(box)
    if not (w > 0 and h > 0 and math.isfinite(w * h)):
        raise ValueError(f"sample_target needs a box with positive finite size, got {(x, y, w, h)}")
    crop_sz = math.ceil(math.sqrt(w * h) * factor)
    if crop_sz < 1:
        raise ValueError(f"box {(x, y, w, h)} with factor {factor} gives an empty crop")
    cx, cy = (x + 0.5 * w, y + 0.5 * h) if center is None else (float(center[0]), float(center[1]))
    return int(round(cx - 0.5 * crop_sz)), int(round(cy - 0.5 * crop_sz)), int(crop_sz)


def search_region(box: Box | Sequence[float], factor: float,
                  center: tuple[float, float] | None = None) -> dict[str, float]:
    """The ``extra`` keys ``search_x, search_y, search_w, search_h`` of that square (a run's
    frames.csv records them)."""
    x1, y1, side = crop_window(box, factor, center)
    return {"search_x": float(x1), "search_y": float(y1), "search_w": float(side), "search_h": float(side)}


def map_box_back(pred_box: Sequence[float], prev_center: tuple[float, float], search_size: int,
                 resize_factor: float) -> Box:
    """Map a predicted ``(cx, cy, w, h)`` from search-crop coordinates to the image.

    ``pred_box`` is in crop pixels already divided by ``resize_factor`` (i.e. image scale, origin
    at the crop's top-left corner): ``pred_norm * search_size / resize_factor``. The crop is taken
    to be centred exactly on ``prev_center`` (the centre given to :func:`sample_target`), so the
    integer rounding of its corner is ignored (a sub-pixel bias of up to 0.5 px, as upstream).
    """
    cx, cy, w, h = (float(v) for v in np.asarray(pred_box, dtype=float).reshape(4))
    half = 0.5 * search_size / resize_factor
    cx_img = cx + (prev_center[0] - half)
    cy_img = cy + (prev_center[1] - half)
    return Box(cx_img - 0.5 * w, cy_img - 0.5 * h, w, h)


def usable_prior(prior: Sequence[float] | None, w: float, h: float, height: int, width: int,
                 margin: float = 0.5) -> tuple[float, float] | None:
    """The MATA search centre a tracker may use (any prior, from any estimator, must be
    survivable): None (keep the tracker's own centre) when missing or not finite, otherwise the
    centre clamped to the image grown by ``margin`` times the box size on each side (the default
    keeps the box within half a box of the image)."""
    if prior is None:
        return None
    try:
        cx, cy = (float(v) for v in prior)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(cx) and math.isfinite(cy)):
        return None
    return within_image((cx, cy), float(w), float(h), width, height, margin)


def clip_box(box: Box | Sequence[float], height: int, width: int, margin: float = 0) -> Box:
    """Clamp a box into a ``width`` x ``height`` image keeping at least ``margin`` pixels of
    width and height (upstream ``clip_box``; the trackers call it with margin 10)."""
    x1, y1, w, h = _xywh(box)
    x2, y2 = x1 + w, y1 + h
    x1 = min(max(0.0, x1), width - margin)
    x2 = min(max(float(margin), x2), float(width))
    y1 = min(max(0.0, y1), height - margin)
    y2 = min(max(float(margin), y2), float(height))
    return Box(float(x1), float(y1), float(max(margin, x2 - x1)), float(max(margin, y2 - y1)))
