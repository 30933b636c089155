"""The paper's PMF window confidence score (section 2.1, eq. score) and its 2-D extension.

1-D (MixFormerV2 corner PMFs): the window is centred on the mode ``k*`` and spans
``2 * round(alpha * N / 2) + 1`` bins; near an edge it is *truncated* to the valid bin range
(the paper's min/max in k_min/k_max are swapped; DESIGN.md and MODELS.md 1.9 fix the intent:
clamp to [0, N-1]). The score is the probability mass inside the window.

2-D (score maps such as VitTrack's 16x16): the last paragraph of section 2.1 replaces the linear
window with a square window over the grid. The map is normalised to a PMF (non-negative, sums to
one), the square of side ``2 * round(alpha * N / 2) + 1`` cells (N = the larger grid side) is
centred on the peak and truncated at the borders, and the score is the mass inside it.
"""

from __future__ import annotations

import numpy as np


def window_half_width(n_bins: int, alpha: float) -> int:
    """Half-width ``r = round(alpha * N / 2)`` in bins; the window has ``2r + 1`` bins.

    Python's ``round`` rounds half to even; ``alpha * N / 2`` is rarely exactly x.5, and for the
    paper's alpha = 0.03 with N = 96 it is 1.44, so r = 1 (3 bins).
    """
    if n_bins < 1:
        raise ValueError(f"a PMF needs at least one bin, got N={n_bins}")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must lie in [0, 1], got {alpha}")
    return int(round(alpha * n_bins / 2.0))


def check_window_alpha(tracker: str, alpha: float, over: str) -> None:
    """A tracker's ``window_alpha`` in [0, 1] (the window's share of ``over``), checked when the
    experiment is loaded: a ValueError naming the tracker and the key."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"{tracker}: window_alpha: expected a number in [0, 1] (the window's share of {over}), "
                         f"got {alpha!r}")


def _as_pmf(values: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(values, dtype=np.float64)
    if p.size == 0:
        raise ValueError(f"{what} is empty")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what} holds non-finite values")
    if np.any(p < 0):
        raise ValueError(f"{what} holds negative values; pass probabilities or a non-negative map")
    total = p.sum()
    if total <= 0:
        raise ValueError(f"{what} sums to zero; it cannot be normalised to a PMF")
    return p / total


def pmf_window_score(pmf: np.ndarray, alpha: float = 0.03) -> float:
    """Mass of a 1-D PMF inside the truncated window around its mode (paper eq. score).

    ``pmf`` is normalised to sum to one first (a softmax output already does). Ties for the mode
    go to the lowest index (``numpy.argmax``).
    """
    p = _as_pmf(np.ravel(pmf), "pmf")
    n = p.size
    r = window_half_width(n, alpha)
    k = int(np.argmax(p))
    lo, hi = max(k - r, 0), min(k + r, n - 1)
    return float(min(1.0, p[lo:hi + 1].sum()))


def pmf_window_score_min(pmfs: np.ndarray, alpha: float = 0.03) -> float:
    """``S = min_i S_i`` over the rows of ``pmfs`` (the four box coordinates, paper 2.1)."""
    rows = np.atleast_2d(np.asarray(pmfs, dtype=np.float64))
    return min(pmf_window_score(row, alpha) for row in rows)


def map_window_score(score_map: np.ndarray, alpha: float = 0.03) -> float:
    """Square-window score of a 2-D map (paper section 2.1, last paragraph).

    The map is normalised to a PMF; the window side is ``2 * round(alpha * N / 2) + 1`` cells with
    N the larger side of the grid, centred on the peak (first in row-major order on ties) and
    truncated at the borders. Returns the mass inside the window, in [0, 1].
    """
    m = np.asarray(score_map, dtype=np.float64)
    m = np.squeeze(m)
    if m.ndim != 2:
        raise ValueError(f"score_map must be 2-D (H, W) after squeezing, got shape {np.shape(score_map)}")
    p = _as_pmf(m, "score_map")
    r = window_half_width(max(p.shape), alpha)
    iy, ix = np.unravel_index(int(np.argmax(p)), p.shape)
    y0, y1 = max(iy - r, 0), min(iy + r, p.shape[0] - 1)
    x0, x1 = max(ix - r, 0), min(ix + r, p.shape[1] - 1)
    return float(min(1.0, p[y0:y1 + 1, x0:x1 + 1].sum()))
