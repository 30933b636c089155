"""Core value types: what a valid box is."""

from __future__ import annotations

import numpy as np

from mata_eval.types import Box


def test_a_box_is_valid_when_finite_with_positive_sides():
    nan, inf = float("nan"), float("inf")
    assert Box(0.0, -5.0, 1e-9, 3.0).is_valid          # anywhere, however small
    assert Box(np.float64(1.0), 2, 3, np.float32(4.0)).is_valid   # numpy scalars and ints
    for bad in [(nan, 0, 1, 1), (0, -inf, 1, 1), (0, 0, 0, 1), (0, 0, 1, -1), (0, 0, inf, 1),
                (0, 0, 1, nan), (0, 0, -inf, 1), (inf, 0, 1, 1)]:
        assert not Box(*bad).is_valid, bad
