"""Crop, map-back and clip helpers (MODELS.md 1.6) against hand-computed pixel positions."""

import math

import numpy as np
import pytest

from mata_eval.types import Box
from mata_eval_plugins.trackers.crop import clip_box, crop_square, map_box_back, sample_target


def coordinate_image(h=60, w=80):
    """Pixel (y, x) holds (x, y, 7): every crop pixel says where it came from."""
    ys, xs = np.mgrid[0:h, 0:w]
    return np.dstack([xs, ys, np.full_like(xs, 7)]).astype(np.uint8)


def test_sample_target_geometry_without_resize():
    img = coordinate_image()
    box = Box(30.0, 20.0, 4.0, 9.0)           # sqrt(36) = 6, factor 2 -> crop 12
    patch, rf = sample_target(img, box, factor=2.0, output_size=12)
    assert rf == pytest.approx(1.0)
    # centre (32, 24.5): x1 = round(32 - 6) = 26, y1 = round(18.5) = 18 (half to even)
    assert patch[0, 0, 0] == 26 and patch[0, 0, 1] == 18
    assert patch[11, 11, 0] == 37 and patch[11, 11, 1] == 29


def test_sample_target_pads_with_zeros_and_reports_resize_factor():
    img = coordinate_image()
    patch, rf = sample_target(img, Box(0.0, 0.0, 4.0, 4.0), factor=3.0, output_size=12)
    # crop 12 centred on (2, 2): x1 = y1 = -4 -> 4 rows/cols of zero padding
    assert rf == pytest.approx(1.0)
    assert np.all(patch[:4] == 0) and np.all(patch[:, :4] == 0)
    assert tuple(patch[4, 4]) == (0, 0, 7)
    patch, rf = sample_target(img, Box(10.0, 10.0, 10.0, 10.0), factor=2.0, output_size=40)
    assert patch.shape == (40, 40, 3) and rf == pytest.approx(2.0)


def test_sample_target_prior_moves_the_crop():
    img = coordinate_image()
    patch, _ = sample_target(img, Box(30.0, 20.0, 4.0, 9.0), 2.0, 12, center=(50.0, 40.0))
    assert patch[0, 0, 0] == 44 and patch[0, 0, 1] == 34


def test_crop_fully_outside_is_border():
    img = coordinate_image()
    patch = crop_square(img, 200, 200, 10, 10, border_value=(1, 2, 3))
    assert patch.shape == (10, 10, 3) and np.all(patch == (1, 2, 3))


def test_map_back_round_trip():
    img = coordinate_image(200, 300)
    target = Box(120.0, 80.0, 20.0, 30.0)
    search_size, factor = 64, 4.0
    crop_sz = math.ceil(math.sqrt(20 * 30) * factor)
    _, rf = sample_target(img, target, factor, search_size)
    assert rf == pytest.approx(search_size / crop_sz)
    # a prediction 5 px right / 3 px down of the target, expressed in crop coordinates
    true = Box(125.0, 83.0, 22.0, 28.0)
    x0 = target.cx - crop_sz / 2
    y0 = target.cy - crop_sz / 2
    pred_norm = np.array([(true.cx - x0) * rf, (true.cy - y0) * rf, true.w * rf, true.h * rf]) / search_size
    back = map_box_back(pred_norm * search_size / rf, target.center, search_size, rf)
    assert back.as_array() == pytest.approx(true.as_array())


def test_clip_box_hand_values():
    assert clip_box(Box(-5, -5, 20, 20), 100, 100).as_array() == pytest.approx([0, 0, 15, 15])
    assert clip_box(Box(95, 50, 20, 20), 100, 100, margin=10).as_array() == pytest.approx([90, 50, 10, 20])
    assert clip_box([10, 10, 2, 3], 100, 100, margin=10).as_array() == pytest.approx([10, 10, 10, 10])
    assert clip_box(Box(200, 200, 5, 5), 100, 100, margin=10).as_array() == pytest.approx([90, 90, 10, 10])


def test_sample_target_rejects_empty_box():
    with pytest.raises(ValueError, match="positive"):
        sample_target(coordinate_image(), Box(1, 1, 0, 5), 2.0, 16)
