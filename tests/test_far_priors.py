"""A diverged estimate can put the tracker's search centre far outside the image: the trackers
must stay cheap and keep the crop sizes their networks expect (found by the paper experiments)."""

import numpy as np
import pytest

from mata_eval.core.registry import load_registry
from mata_eval.types import Box
from mata_eval_plugins.trackers.crop import crop_square


@pytest.mark.parametrize("x1, y1", [(-2000, -2000), (-2000, 10), (10, -2000), (5000, 5000), (-1e6, 30)])
def test_crop_square_outside_the_image_has_the_requested_size(x1, y1):
    image = np.full((720, 1280, 3), 7, np.uint8)
    patch = crop_square(image, int(x1), int(y1), 1500, 1500)
    assert patch.shape == (1500, 1500, 3)
    assert (patch == 0).all()  # nothing of the image falls inside: all border


def test_crop_square_straddling_the_top_left_corner():
    image = np.arange(100 * 100, dtype=np.uint8).reshape(100, 100)[:, :, None].repeat(3, 2)
    patch = crop_square(image, -5, -5, 10, 10)
    assert patch.shape == (10, 10, 3)
    assert (patch[:5] == 0).all() and (patch[:, :5] == 0).all()
    np.testing.assert_array_equal(patch[5:, 5:], image[:5, :5])


def test_kcf_with_a_prior_far_outside_the_image():
    reg = load_registry()
    entry = reg.get("tracker", "kcf")
    tracker = entry.cls(entry.cls.Params())
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    tracker.initialize(image, Box(100, 80, 40, 30))
    for prior in [(1e6, 1e6), (-1e7, 50.0), (160.0, -5e6)]:
        out = tracker.track(image, prior)  # would have allocated tens of GB of border before
        assert np.isfinite(out.box.as_array()).all() and 0.0 <= out.confidence <= 1.0
