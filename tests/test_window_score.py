"""PMF window score (paper section 2.1, eq. score) and its 2-D square-window extension, on
hand-built PMFs and maps whose scores are computed by hand."""

import numpy as np
import pytest

from mata_eval_plugins.trackers.window_score import (
    map_window_score,
    pmf_window_score,
    pmf_window_score_min,
    window_half_width,
)


def test_window_width_rule():
    # 2 * round(alpha N / 2) + 1 bins: alpha = 0.03, N = 96 -> round(1.44) = 1 -> 3 bins
    assert window_half_width(96, 0.03) == 1
    assert window_half_width(200, 0.03) == 3  # round(3.0) -> 7 bins
    assert window_half_width(16, 0.03) == 0   # round(0.24) -> a single cell
    assert window_half_width(16, 0.125) == 1  # round(1.0) -> 3 cells


def test_delta_scores_one():
    p = np.zeros(96)
    p[40] = 1.0
    assert pmf_window_score(p) == pytest.approx(1.0)


def test_uniform_interior_and_tie_at_zero():
    n = 96
    p = np.full(n, 1.0 / n)
    # all bins tie: argmax is bin 0, the window is truncated to bins 0..1 -> 2/N
    assert pmf_window_score(p) == pytest.approx(2.0 / n)
    q = np.full(n, 1.0)
    q[50] = 1.0 + 1e-9  # interior mode: 3 bins of (almost) 1/N
    assert pmf_window_score(q) == pytest.approx(3.0 / n, rel=1e-6)


def test_two_equal_far_modes_give_one_half():
    p = np.zeros(96)
    p[20] = p[70] = 0.5
    assert pmf_window_score(p) == pytest.approx(0.5)


def test_edge_peak_is_truncated_not_shifted():
    p = np.zeros(96)
    p[0:4] = (0.5, 0.3, 0.15, 0.05)
    # truncated window = bins 0..1 -> 0.8 (a shifted window would give 0.95)
    assert pmf_window_score(p) == pytest.approx(0.8)
    p = p[::-1].copy()
    assert pmf_window_score(p) == pytest.approx(0.8)


def test_wider_window_and_normalisation():
    p = np.zeros(200)
    p[100] = 4.0
    p[97] = p[103] = 2.0     # inside the 7-bin window (r = 3)
    p[96] = p[104] = 1.0     # just outside
    # unnormalised input: total 10, inside 8
    assert pmf_window_score(p, alpha=0.03) == pytest.approx(0.8)


def test_min_over_coordinates():
    rows = np.zeros((4, 96))
    rows[:, 10] = 1.0
    rows[2] = 0.0
    rows[2, 30] = rows[2, 80] = 0.5
    assert pmf_window_score_min(rows) == pytest.approx(0.5)


def test_map_delta_uniform_two_modes():
    m = np.zeros((16, 16))
    m[5, 9] = 0.7
    assert map_window_score(m) == pytest.approx(1.0)
    u = np.ones((16, 16))
    u[8, 8] += 1e-9
    assert map_window_score(u, alpha=0.125) == pytest.approx(9 / 256, rel=1e-6)
    assert map_window_score(u, alpha=0.03) == pytest.approx(1 / 256, rel=1e-6)
    two = np.zeros((16, 16))
    two[2, 2] = two[12, 13] = 0.9
    assert map_window_score(two, alpha=0.125) == pytest.approx(0.5)


def test_map_corner_peak_truncated():
    m = np.full((16, 16), 0.01)
    m[0, 0] = 1.0
    total = 1.0 + 255 * 0.01
    # 3x3 window truncated to the 2x2 corner: the peak and three 0.01 cells
    assert map_window_score(m, alpha=0.125) == pytest.approx((1.0 + 3 * 0.01) / total)
    m2 = np.full((16, 16), 0.01)
    m2[7, 15] = 1.0  # right edge: 3x2 cells
    assert map_window_score(m2, alpha=0.125) == pytest.approx((1.0 + 5 * 0.01) / total)


def test_map_squeezes_network_layout():
    m = np.zeros((1, 1, 16, 16), dtype=np.float32)
    m[0, 0, 3, 3] = 0.6
    m[0, 0, 3, 4] = 0.2
    m[0, 0, 10, 10] = 0.2
    assert map_window_score(m, alpha=0.125) == pytest.approx(0.8)


@pytest.mark.parametrize("bad", [np.array([0.5, -0.1, 0.6]), np.zeros(5), np.array([np.nan, 1.0]), np.array([])])
def test_bad_pmf_raises(bad):
    with pytest.raises(ValueError):
        pmf_window_score(bad)


def test_bad_map_raises():
    with pytest.raises(ValueError, match="2-D"):
        map_window_score(np.ones((2, 3, 4)))
    with pytest.raises(ValueError, match="alpha"):
        map_window_score(np.ones((4, 4)), alpha=1.5)
