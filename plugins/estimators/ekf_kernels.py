"""Block C's whole tick compiled with numba (the optional ``fast`` extra): the same arithmetic as
the numpy reference in :mod:`ekf_math` and ``HomographyEKF._tick_state``, fused into one call.

Why by hand: a tick is ~15k flops on 15x15 matrices, where numpy spends its time in call
overhead (about 60 small operations, ~250 us); one compiled function over fixed loops does it in
a few microseconds. What it exploits (paper eq. ekf_velocity_1 and the partial updates):

- F is the identity on the 9 homography rows, so F P F^T only recomputes the 4 corner rows and
  the derivative rows (``_predict``);
- the measurements select state entries (4 corners, 9 homography entries): the Joseph form
  (I - K E) P (I - K E)^T + K R K^T is expanded into products with K and the selected rows,
  P - K B - B^T K^T + K S K^T with B = E P and S = E P E^T + R (``_joseph_block``);
- only upper triangles are computed where the result is symmetrised anyway.

Equal to the numpy path to rounding (tests/test_ekf_kernels.py: 1e-9 px over seeded ticks of
both presets, the gate memory exactly). Besides the algebra, the tick's policy is here, each a
twin of its readable Python in ``HomographyEKF``: the state-dependent tests (front of camera,
tau_sigma, chi2 inflation), q_adapt's innovation average, and block A's confidence gate with
the relative gate's history (``_gate``; its memory is one vector g per state, read as a
GateState through ``PackedGate``), which in Python cost as much as the algebra. Only the
composition of several motions in one tick stays in Python.

Compiling takes 12 to 17 CPU-s here, once: the cache (``cache=True``) sits next to this file in a
source checkout, in mata-eval's cache folder (``$MATA_EVAL_CACHE`` or ``~/.cache/mata-eval``,
``numba/``) for an installed package (inside site-packages, ``pip uninstall`` left it behind),
and a later process loads it in about 0.3 s. Where no location is writable, each process
compiles it once, quietly. ``NUMBA_CACHE_DIR`` overrides both.
"""

from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np



def _cache_dir() -> str | None:
    """Where this module's compiled functions are cached: mata-eval's cache folder for an
    installed package; None (numba's choice: beside this file) in a source checkout, or when
    ``NUMBA_CACHE_DIR`` is set or no home folder can be found."""
    if os.environ.get("NUMBA_CACHE_DIR") or not {"site-packages", "dist-packages"} & set(Path(__file__).parts):
        return None
    from mata_eval.data.datasets.synthetic import cache_root

    try:
        return str(cache_root() / "numba")
    except RuntimeError:   # no home folder (a container user without a passwd entry)
        return None

# The HomographyEKF parameters this kernel implements. A parameter added to the filter later is
# not here until the kernel implements it: the filter then runs its numpy path (backend auto).
IMPLEMENTS = frozenset({
    "preset", "model", "camera", "gating", "gate", "alpha_ewma", "tau_ewma", "tau_diff", "chi2_gate",
    "tau_sigma", "delay", "history_s", "follow_prior", "velocity_decay_s", "h_update", "box_motion",
    "r_box", "r_box_rel", "r_confidence", "r_h_floor", "q_box", "q_box_rel", "q_h", "q_v", "q_a", "q_j",
    "p0_box", "p0_h", "p0_v", "p0_a", "p0_j",
    "q_adapt", "follow_consistent", "feedback_shift", "feedback_carry", "feedback_hold", "repeat_hold", "fresh_output"})  # the feedback ones act in step(), outside the tick

# cfg: the filter's constant parameters, one float vector (numba's dispatch costs per argument):
# the scalars below, then the 9 floors of the homography R (C_FLOOR) and the Q rates (C_Q, one
# per state entry)
(C_NDERIV, C_CENTRE, C_H_BEFORE, C_GATING, C_TAU_SIGMA, C_CHI2, C_R_BOX, C_R_BOX_REL,
 C_R_CONF, C_Q_BOX_REL, C_FOLLOW, C_DECAY, C_P0_V, C_Q_ADAPT, C_ALPHA, C_RELATIVE, C_TAU_EWMA,
 C_TAU_DIFF, C_FOLLOW_CONSISTENT) = range(19)
C_FLOOR = 19
C_Q = C_FLOOR + 9
# the motion input of a tick
MOTION_NONE, MOTION_H, MOTION_H_COV = 0, 1, 2
# a box input (one row of ``dets``): its x, y, w, h and the tracker's confidence
D_X, D_Y, D_W, D_H, D_CONF = range(5)
N_DET = 5
#: one row of ``dets`` (float64, C order) for struct.pack_into(DET_ROW, dets, i * DET_SIZE, x, y, w,
#: h, confidence): a quarter of the time of numpy's ``dets[i] = x, y, w, h, confidence``, the same
#: values (a format string, not a Struct, which would not pickle with the filter)
DET_ROW = f"={N_DET}d"
DET_SIZE = struct.calcsize(DET_ROW)
# the gate memory (HomographyEKF.GateState packed in one float vector g): the EWMA (NaN before
# the first confidence), boxes used, q_adapt's innovation average, the number m of accepted
# confidences kept, whether the previous box was used (1.0) or not (0.0), the relative
# confidence at which the tick's last box was used (0.0: not used, or no box), then the last m
# accepted confidences (oldest first, from G_ACCEPTED) and the same in increasing order (from
# G_ACCEPTED + history); history = (len(g) - G_ACCEPTED) // 2
G_EWMA, G_N_USED, G_NIS, G_N_ACC, G_FOLLOWING, G_USED_RELATIVE, G_ACCEPTED = range(7)


def config(*, n_deriv: int, centre: bool, h_before: bool, gating: bool, tau_sigma: float, chi2: float,
           r_box: float, r_box_rel: float, r_conf: bool, q_box_rel: float, follow: float, decay: float,
           p0_v: float, q_adapt: bool, alpha: float, relative: bool, tau_ewma: float, tau_diff: float,
           follow_consistent: bool, floor: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The ``cfg`` vector of :func:`tick` (HomographyEKF's resolved parameters)."""
    scalars = [n_deriv, centre, h_before, gating, tau_sigma, chi2, r_box, r_box_rel, r_conf, q_box_rel,
               follow, decay, p0_v, q_adapt, alpha, relative, tau_ewma, tau_diff, follow_consistent]
    assert len(scalars) == C_FLOOR and len(floor) == 9
    return np.concatenate([np.asarray(scalars, float), floor, q])


def load() -> None:
    """Compile :func:`tick` now, or load it from the cache (0.3 s; 12 to 17 s to compile), with
    the argument types of every later call: the filter calls this when it is built, so that the
    cost never lands in a timed tick (it was the first frame's estimator time, and kept a
    run's estimator rate at a sixth of the numpy path's). A no-op once done in a process."""
    if tick.signatures:
        return
    n = 15
    cfg = config(n_deriv=1, centre=True, h_before=False, gating=True, tau_sigma=0.0, chi2=0.0, r_box=1.0,
                 r_box_rel=0.0, r_conf=False, q_box_rel=0.0, follow=0.0, decay=0.0, p0_v=1.0, q_adapt=False,
                 alpha=0.3, relative=False, tau_ewma=0.0, tau_diff=1.0, follow_consistent=False,
                 floor=np.zeros(9), q=np.zeros(n))
    tick(cfg, np.zeros(n), np.eye(n), new_gate(1), 0.0, np.eye(3), np.zeros((9, 9)), MOTION_NONE,
         np.zeros((1, N_DET)), 0)


def new_gate(history: int) -> np.ndarray:
    """The gate memory g of a filter's first state (GateState()): keeps ``history`` confidences."""
    g = np.zeros(G_ACCEPTED + 2 * history)
    g[G_EWMA], g[G_NIS] = np.nan, 1.0
    return g


class PackedGate(NamedTuple):
    """The compiled path's gate memory, read as a GateState (same fields, same values)."""

    g: np.ndarray

    @property
    def ewma(self) -> float | None:
        v = float(self.g[G_EWMA])
        return None if v != v else v

    @property
    def n_used(self) -> int:
        return int(self.g.item(G_N_USED))

    @property
    def nis(self) -> float:
        return float(self.g[G_NIS])

    @property
    def following(self) -> bool:
        return bool(self.g[G_FOLLOWING])

    @property
    def used_relative(self) -> float:
        return float(self.g[G_USED_RELATIVE])

    @property
    def accepted(self) -> tuple[float, ...]:
        return tuple(self.g[G_ACCEPTED:G_ACCEPTED + int(self.g[G_N_ACC])].tolist())

    @property
    def ranked(self) -> tuple[float, ...]:
        start = G_ACCEPTED + (len(self.g) - G_ACCEPTED) // 2
        return tuple(self.g[start:start + int(self.g[G_N_ACC])].tolist())


class PackedState(NamedTuple):
    """The compiled path's FilterState: x, P and the gate memory as its packed vector g, which
    ``gate`` reads as a GateState (one record fewer to build per tick than a FilterState
    holding a PackedGate)."""

    x: np.ndarray
    P: np.ndarray
    g: np.ndarray

    @property
    def gate(self) -> PackedGate:
        return PackedGate(self.g)

    @property
    def ewma(self) -> float | None:
        return self.gate.ewma

    @property
    def n_used(self) -> int:
        return int(self.g.item(G_N_USED))

    @property
    def used_relative(self) -> float:
        return self.g.item(G_USED_RELATIVE)



def _njit(fn):
    """numba.njit with IEEE semantics (no fastmath; x / 0 gives inf or nan, as numpy does) and
    an on-disk cache; without a writable cache location, compiled per process, quietly."""
    opts = dict(nogil=True, error_model="numpy")
    before, where = numba.config.CACHE_DIR, _cache_dir()
    try:
        if where:   # numba's setting is process-wide: only while these functions choose their cache
            numba.config.CACHE_DIR = where
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return numba.njit(cache=True, **opts)(fn)
    except RuntimeError:  # "no locator available": no writable cache directory
        return numba.njit(**opts)(fn)
    finally:
        numba.config.CACHE_DIR = before


# --- the homography projection g (ekf_math._uvw, _jp, _jh, _jpt) ------------------------------

@_njit
def _uvw(h, x, y):
    w = h[6] * x + h[7] * y + h[8]
    return (h[0] * x + h[1] * y + h[2]) / w, (h[3] * x + h[4] * y + h[5]) / w, w


@_njit
def _jp(h, u, v, w, out):
    """out (2x2) = J_g at the point with image (u, v, w)."""
    out[0, 0] = (h[0] - u * h[6]) / w
    out[0, 1] = (h[1] - u * h[7]) / w
    out[1, 0] = (h[3] - v * h[6]) / w
    out[1, 1] = (h[4] - v * h[7]) / w


@_njit
def _jh(x, y, u, v, w, out):
    """out (2x9) = dg/dh at (x, y)."""
    a, b, c = x / w, y / w, 1.0 / w
    for k in range(9):
        out[0, k] = 0.0
        out[1, k] = 0.0
    out[0, 0], out[0, 1], out[0, 2] = a, b, c
    out[1, 3], out[1, 4], out[1, 5] = a, b, c
    out[0, 6], out[0, 7], out[0, 8] = -u * a, -u * b, -u * c
    out[1, 6], out[1, 7], out[1, 8] = -v * a, -v * b, -v * c


@_njit
def _jpt(h, x, y, e0, e1, u, v, w, J, out):
    """out (2x12) = [m | dm/dp | dm/dh] of m = J_g(p) e (ekf_math._jpt); J = J_g(p)."""
    m0 = J[0, 0] * e0 + J[0, 1] * e1
    m1 = J[1, 0] * e0 + J[1, 1] * e1
    s = (h[6] * e0 + h[7] * e1) / w
    g0, g1 = h[6] / w, h[7] / w
    out[0, 0], out[1, 0] = m0, m1
    out[0, 1] = -s * J[0, 0] - m0 * g0
    out[0, 2] = -s * J[0, 1] - m0 * g1
    out[1, 1] = -s * J[1, 0] - m1 * g0
    out[1, 2] = -s * J[1, 1] - m1 * g1
    r0, r1, r2 = (e0 - s * x) / w, (e1 - s * y) / w, -s / w
    k0, k1 = (u * s - m0) / w, (v * s - m1) / w
    for k in range(3, 12):
        out[0, k] = 0.0
        out[1, k] = 0.0
    out[0, 3], out[0, 4], out[0, 5] = r0, r1, r2
    out[1, 6], out[1, 7], out[1, 8] = r0, r1, r2
    out[0, 9], out[0, 10], out[0, 11] = k0 * x - u * e0 / w, k0 * y - u * e1 / w, k0
    out[1, 9], out[1, 10], out[1, 11] = k1 * x - v * e0 / w, k1 * y - v * e1 / w, k1


@_njit
def _box_side(x):
    w, h = x[2] - x[0], x[3] - x[1]
    return np.sqrt(max(w, 0.0)) * np.sqrt(max(h, 0.0))


# --- small dense algebra ------------------------------------------------------------------------

@_njit
def _solve_in_place(S, out):
    """out = S^-1 out (S m x m, out m x k) by LU with partial pivoting, as LAPACK's gesv does;
    a zero pivot gives inf / nan (held by the tick) where numpy would raise. Each column of
    ``out`` is solved on its own (the same operations, so the same bits, as alone); the loops
    run over whole rows (independent sums, which the compiler vectorises)."""
    m, k = S.shape[0], out.shape[1]
    A = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            A[i, j] = S[i, j]
    for c in range(m):
        p = c
        for r in range(c + 1, m):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if p != c:
            for j in range(m):
                t = A[c, j]
                A[c, j] = A[p, j]
                A[p, j] = t
            for j in range(k):
                t = out[c, j]
                out[c, j] = out[p, j]
                out[p, j] = t
        for r in range(c + 1, m):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for j in range(c + 1, m):
                    A[r, j] -= f * A[c, j]
                for j in range(k):
                    out[r, j] -= f * out[c, j]
    for c in range(m - 1, -1, -1):
        d = A[c, c]
        for j in range(k):
            out[c, j] /= d
        for r in range(c):
            f = A[r, c]
            for j in range(k):
                out[r, j] -= f * out[c, j]


@_njit
def _gain(B, s, R, f, nu, S, Kt):
    """S = B E^T + f R and K^T = S^-1 B (B = E P, the measured rows s.. of P), written into S
    and Kt's first n columns; Kt's last column is S^-1 nu (nu: the innovation). Returns the
    squared Mahalanobis innovation nu^T S^-1 nu."""
    m, n = B.shape
    for a in range(m):
        for b in range(m):
            S[a, b] = B[a, s + b] + f * R[a, b]
        for j in range(n):
            Kt[a, j] = B[a, j]
        Kt[a, n] = nu[a]
    _solve_in_place(S, Kt)              # S symmetric: K^T = S^-1 B
    d2 = 0.0
    for a in range(m):
        d2 += nu[a] * Kt[a, n]
    return d2


@_njit
def _joseph_block(x, P, z, s, R, chi2):
    """ekf_math.joseph_update_block in place for the state entries s .. s+m-1 (m = len(z)),
    with R inflated by d2 / chi2 where the innovation's squared Mahalanobis distance d2 under R
    exceeds chi2 > 0 (ekf_math.robust_noise). Returns d2 (under R, before inflation).

    With B = E P (the measured rows), S = B E^T + R and K^T = S^-1 B, the Joseph form is
    P - K B - B^T K^T + K S K^T = P + T + T^T with T = (K S / 2 - B^T) K^T, symmetrised. K^T
    carries one more column, S^-1 nu, which gives d2 from the same solve; for 15 states its rows
    are 16 wide, a multiple of the vector width, so the vector loops over rows (independent sums,
    which the compiler vectorises) have no scalar remainder. W^T and T carry that column along,
    unread."""
    n, m = x.shape[0], z.shape[0]
    nw = n + 1                          # the row width of K^T, W^T and T
    B = P[s:s + m]                      # E P: the measured rows (a view: P is written last)
    nu = np.empty(m)
    for a in range(m):
        nu[a] = z[a] - x[s + a]
    S = np.empty((m, m))
    Kt = np.empty((m, nw))
    d2 = _gain(B, s, R, 1.0, nu, S, Kt)
    if chi2 > 0.0 and d2 > chi2:
        _gain(B, s, R, d2 / chi2, nu, S, Kt)
    Wt = np.empty((m, nw))              # (K S / 2 - B^T)^T = S^T K^T / 2 - B
    for a in range(m):
        for j in range(n):
            Wt[a, j] = -B[a, j]
        Wt[a, n] = 0.0
        for b in range(m):
            f = 0.5 * S[b, a]
            for j in range(nw):
                Wt[a, j] += f * Kt[b, j]
    dx = np.zeros(n)
    for a in range(m):
        r = nu[a]
        for j in range(n):
            dx[j] += Kt[a, j] * r
    T = np.zeros((n, nw))
    for i in range(n):
        for a in range(m):
            f = Wt[a, i]
            for j in range(nw):
                T[i, j] += f * Kt[a, j]
    for i in range(n):
        x[i] += dx[i]
        for j in range(i, n):
            P[i, j] = P[j, i] = 0.5 * (P[i, j] + P[j, i]) + (T[i, j] + T[j, i])
    return d2


@_njit
def _mahalanobis2(nu, S):
    m = nu.shape[0]
    y = np.empty((m, 1))
    for a in range(m):
        y[a, 0] = nu[a]
    _solve_in_place(S, y)
    acc = 0.0
    for a in range(m):
        acc += nu[a] * y[a, 0]
    return acc


# --- the stages of a tick ---------------------------------------------------------------------

@_njit
def _valid_motion(H, C, mode):
    """Finite H with h33 != 0 (and a finite C): HomographyEKF._motion_measurement's tests."""
    for i in range(3):
        for j in range(3):
            if not np.isfinite(H[i, j]):
                return False
    if abs(H[2, 2]) < 1e-12:
        return False
    if mode == MOTION_H_COV:
        for i in range(9):
            for j in range(9):
                if not np.isfinite(C[i, j]):
                    return False
    return True


@_njit
def _update_motion(x, P, cfg, floor, H, C, mode):
    """HomographyEKF._update_motion after the validity tests: front-of-camera and tau_sigma
    gates, then the 9-value update with R = floored(C)."""
    h33 = H[2, 2]
    h = np.empty(9)
    for k in range(9):
        h[k] = H[k // 3, k % 3] / h33
    for c in range(2):
        if h[6] * x[2 * c] + h[7] * x[2 * c + 1] + h[8] <= 1e-6:
            return
    if cfg[C_GATING] != 0.0 and mode == MOTION_H_COV:      # ekf_math.transferred_sigma
        cx, cy = 0.5 * (x[0] + x[2]), 0.5 * (x[1] + x[3])
        u, v, w = _uvw(h, cx, cy)
        G = np.empty((2, 9))
        _jh(cx, cy, u, v, w, G)
        GC = np.zeros((2, 9))           # G C (no BLAS call for 2 x 9)
        for r in range(2):
            for k in range(9):
                f = G[r, k]
                for j in range(9):
                    GC[r, j] += f * C[k, j]
        a = b = c = 0.0
        for k in range(9):
            a += GC[0, k] * G[0, k]
            b += 0.5 * (GC[0, k] * G[1, k] + GC[1, k] * G[0, k])
            c += GC[1, k] * G[1, k]
        top = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
        if not np.sqrt(max(top, 0.0)) <= cfg[C_TAU_SIGMA]:
            return
    R = np.zeros((9, 9))                                    # ekf_math.floored
    for i in range(9):
        if mode == MOTION_H_COV:
            for j in range(9):
                R[i, j] = 0.5 * (C[i, j] + C[j, i])
        R[i, i] += max(floor[i] - R[i, i], 0.0)
    _joseph_block(x, P, h, 4, R, 0.0)


@_njit
def _velocity_prior(x, P, cfg, dt, n_used):
    """HomographyEKF._velocity_prior: the follow prior until the first box, then the relaxation
    towards 'still in the image' (ekf_math.image_static_velocity, velocity_mixture,
    relax_velocity)."""
    follow, tau = cfg[C_FOLLOW], cfg[C_DECAY]
    if follow == 0.0 and tau == 0.0:
        return
    mix = n_used < 1 and follow > 0.0
    relax = n_used >= 1 and tau > 0.0
    if not (mix or relax):
        return
    h = x[4:13]                         # a view: only the velocity entries are written below
    cx, cy = 0.5 * (x[0] + x[2]), 0.5 * (x[1] + x[3])
    u, v, w = _uvw(h, cx, cy)
    J = np.empty((2, 2))
    _jp(h, u, v, w, J)
    r0, r1 = cx - u, cy - v
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    v0 = (J[1, 1] * r0 - J[0, 1] * r1) / det / dt
    v1 = (J[0, 0] * r1 - J[1, 0] * r0) / det / dt
    n = x.shape[0]
    if mix:
        x[13], x[14] = follow * v0, follow * v1
        for i in range(n):
            P[13, i] = P[14, i] = P[i, 13] = P[i, 14] = 0.0
        k = follow * (1.0 - follow)
        P[13, 13] = cfg[C_P0_V] + k * (v0 * v0)
        P[13, 14] = P[14, 13] = k * (v0 * v1)
        P[14, 14] = cfg[C_P0_V] + k * (v1 * v1)
    else:
        a = np.exp(-dt / tau)
        x[13] = v0 + a * (x[13] - v0)
        x[14] = v1 + a * (x[14] - v1)
        for i in range(n):
            for j in (13, 14):
                P[i, j] *= a
                P[j, i] *= a     # the velocity block twice: a^2, as A P A^T


@_njit
def _local_scale(h, x, y, w, ds_dh):
    """ekf_math._local_scale: s = sqrt|det H / w^3| and ds/dp; ds/dh written into ds_dh."""
    c00 = h[4] * h[8] - h[5] * h[7]
    c01 = h[5] * h[6] - h[3] * h[8]
    c02 = h[3] * h[7] - h[4] * h[6]
    det = h[0] * c00 + h[1] * c01 + h[2] * c02
    s = np.sqrt(abs(det) / abs(w) ** 3)
    # d ln|det H| / dH = H^-T = cofactor matrix / det
    c10, c11, c12 = h[2] * h[7] - h[1] * h[8], h[0] * h[8] - h[2] * h[6], h[1] * h[6] - h[0] * h[7]
    c20, c21, c22 = h[1] * h[5] - h[2] * h[4], h[2] * h[3] - h[0] * h[5], h[0] * h[4] - h[1] * h[3]
    ds_dh[0], ds_dh[1], ds_dh[2] = s * (0.5 * (c00 / det)), s * (0.5 * (c01 / det)), s * (0.5 * (c02 / det))
    ds_dh[3], ds_dh[4], ds_dh[5] = s * (0.5 * (c10 / det)), s * (0.5 * (c11 / det)), s * (0.5 * (c12 / det))
    ds_dh[6] = s * (0.5 * (c20 / det) - 1.5 * (x / w))
    ds_dh[7] = s * (0.5 * (c21 / det) - 1.5 * (y / w))
    ds_dh[8] = s * (0.5 * (c22 / det) - 1.5 * (1.0 / w))
    return s, -1.5 * s / w * h[6], -1.5 * s / w * h[7]


@_njit
def _predict(x, P, cfg, q, dt, nis):
    """ekf_math.transition (f and F) and predict_cov with Q = diag(q(x)) dt, in place; ``nis``:
    the boxes' average normalised innovation squared (q_adapt)."""
    n = x.shape[0]
    nd = int(cfg[C_NDERIV])
    h = x[4:13]                         # a view: x is written last
    x1, y1, x2, y2 = x[0], x[1], x[2], x[3]
    cx, cy = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    wdisp = np.empty(nd)                # ekf_math.taylor
    T = np.zeros((nd, nd))
    fact = 1.0
    for i in range(nd):
        fact *= i + 1
        wdisp[i] = dt ** (i + 1) / fact
    for j in range(nd):
        f = 1.0
        for i in range(j, nd):
            if i > j:
                f *= i - j
            T[j, i] = dt ** (i - j) / f
    uc, vc, wc = _uvw(h, cx, cy)
    Jc = np.empty((2, 2))
    _jp(h, uc, vc, wc, Jc)
    M = np.empty((nd, 2, 12))
    for i in range(nd):
        _jpt(h, cx, cy, x[13 + 2 * i], x[14 + 2 * i], uc, vc, wc, Jc, M[i])
    disp = np.zeros((2, 12))
    ndv = np.zeros((nd, 2, 12))
    for i in range(nd):
        for r in range(2):
            for k in range(12):
                disp[r, k] += wdisp[i] * M[i, r, k]
                for j in range(nd):
                    ndv[j, r, k] += T[j, i] * M[i, r, k]
    # Q rates, from the state before the transition (HomographyEKF._process_noise)
    qd = np.empty(n)
    for i in range(n):
        qd[i] = q[i] * dt
    adapt = cfg[C_Q_ADAPT] != 0.0
    if cfg[C_Q_BOX_REL] != 0.0 or (adapt and nis > 1.0):
        extra = (cfg[C_Q_BOX_REL] * _box_side(x)) ** 2
        for i in range(4):
            qd[i] = ((q[i] + extra) * max(nis, 1.0) if adapt else q[i] + extra) * dt

    F = np.zeros((n, n))
    fx = np.empty(n)
    Jh = np.empty((2, 9))
    if cfg[C_CENTRE] == 0.0:            # ekf_math._corners_through_h
        Jp = np.empty((2, 2))
        for c in range(2):
            px, py = x[2 * c], x[2 * c + 1]
            u, v, w = _uvw(h, px, py)
            fx[2 * c], fx[2 * c + 1] = u + disp[0, 0], v + disp[1, 0]
            _jp(h, u, v, w, Jp)
            _jh(px, py, u, v, w, Jh)
            for r in range(2):
                for k in range(2):
                    F[2 * c + r, 2 * c + k] = Jp[r, k]
                    for cc in range(2):
                        F[2 * c + r, 2 * cc + k] += 0.5 * disp[r, 1 + k]
                for k in range(9):
                    F[2 * c + r, 4 + k] = Jh[r, k] + disp[r, 3 + k]
    else:                               # ekf_math._centre_through_h
        ds_dh = np.empty(9)
        s, ds0, ds1 = _local_scale(h, cx, cy, wc, ds_dh)
        e0, e1 = 0.5 * (x2 - x1), 0.5 * (y2 - y1)
        c0, c1 = uc + disp[0, 0], vc + disp[1, 0]
        fx[0], fx[1] = c0 - s * e0, c1 - s * e1
        fx[2], fx[3] = c0 + s * e0, c1 + s * e1
        _jh(cx, cy, uc, vc, wc, Jh)
        for r in range(2):
            er = e0 if r == 0 else e1
            for k in range(2):
                dc = Jc[r, k] + disp[r, 1 + k]
                de = er * (ds0 if k == 0 else ds1)
                sI = s if r == k else 0.0
                F[r, k] = 0.5 * (dc - de) + 0.5 * sI
                F[r, 2 + k] = 0.5 * (dc - de) - 0.5 * sI
                F[2 + r, k] = 0.5 * (dc + de) - 0.5 * sI
                F[2 + r, 2 + k] = 0.5 * (dc + de) + 0.5 * sI
            for k in range(9):
                dch = Jh[r, k] + disp[r, 3 + k]
                deh = er * ds_dh[k]
                F[r, 4 + k] = dch - deh
                F[2 + r, 4 + k] = dch + deh
    for k in range(9):
        fx[4 + k] = h[k]
        F[4 + k, 4 + k] = 1.0
    for j in range(nd):
        fx[13 + 2 * j], fx[14 + 2 * j] = ndv[j, 0, 0], ndv[j, 1, 0]
    for i in range(nd):
        for r in range(2):
            for k in range(2):
                F[r, 13 + 2 * i + k] = F[2 + r, 13 + 2 * i + k] = wdisp[i] * Jc[r, k]
    for j in range(nd):
        for r in range(2):
            for k in range(2):
                F[13 + 2 * j + r, k] = F[13 + 2 * j + r, 2 + k] = 0.5 * ndv[j, r, 1 + k]
            for k in range(9):
                F[13 + 2 * j + r, 4 + k] = ndv[j, r, 3 + k]
            for i in range(j, nd):
                for k in range(2):
                    F[13 + 2 * j + r, 13 + 2 * i + k] = T[j, i] * Jc[r, k]

    # P = F P F^T + Q, symmetrised. F is the identity on the homography rows 4..12, so only the
    # rows of the corners and derivatives ("moving") change: with Y = F P on those rows,
    # entry (moving i, homography h) is Y_ih (= (F P F^T)_hi term by term, P symmetric).
    nm = n - 9
    moving = np.empty(nm, np.int64)
    for a in range(nm):
        moving[a] = a if a < 4 else 9 + a
    Y = np.zeros((nm, n))
    for a in range(nm):
        for k in range(n):
            f = F[moving[a], k]
            for j in range(n):
                Y[a, j] += f * P[k, j]
    Ft = np.empty((n, nm))
    for b in range(nm):
        for k in range(n):
            Ft[k, b] = F[moving[b], k]
    Z = np.zeros((nm, nm))
    for a in range(nm):
        for k in range(n):
            f = Y[a, k]
            for b in range(nm):
                Z[a, b] += f * Ft[k, b]
    for a in range(nm):
        i = moving[a]
        for h in range(4, 13):
            P[i, h] = P[h, i] = Y[a, h]
        for b in range(a, nm):
            j = moving[b]
            P[i, j] = P[j, i] = 0.5 * (Z[a, b] + Z[b, a])
    for i in range(n):
        P[i, i] += qd[i]
    for i in range(n):
        x[i] = fx[i]


@_njit
def _box_r(x, cfg, conf):
    """HomographyEKF._box_noise: the variance of each corner of a box at relative confidence conf."""
    r = cfg[C_R_BOX] + (cfg[C_R_BOX_REL] * _box_side(x)) ** 2
    if cfg[C_R_CONF] != 0.0:
        r = r / max(conf, 0.1) ** 2
    return r


@_njit
def _consistent(x, P, cfg, z):
    """follow_consistent: the box z's squared Mahalanobis innovation, under the R of a box at the
    tracker's typical confidence, is at most chi2_gate (HomographyEKF._update_detection)."""
    r = _box_r(x, cfg, 1.0)
    nu = np.empty(4)
    S = np.empty((4, 4))
    for a in range(4):
        nu[a] = z[a] - x[a]
        for b in range(4):
            S[a, b] = P[a, b] + (r if a == b else 0.0)
    return _mahalanobis2(nu, S) <= cfg[C_CHI2]


@_njit
def _update_box(x, P, cfg, z, conf):
    """HomographyEKF._box_noise, the chi2 inflation (ekf_math.robust_noise) and the 4-corner
    update. Returns the squared Mahalanobis innovation d2 under the box's R before inflation."""
    r = _box_r(x, cfg, conf)
    R = np.zeros((4, 4))
    for a in range(4):
        R[a, a] = r
    inflate = cfg[C_GATING] != 0.0 and cfg[C_CHI2] != 0.0
    return _joseph_block(x, P, z, 0, R, cfg[C_CHI2] if inflate else 0.0)


@_njit
def _innovation_average(nis, d2, cfg):
    """ekf_math.normalised_innovation_average over the 4 corners, capped at chi2_gate (if set)."""
    if np.isnan(d2):
        return nis
    term = (d2 if cfg[C_CHI2] == 0.0 else min(d2, cfg[C_CHI2])) / 4.0
    if not np.isfinite(term):
        return nis
    return cfg[C_ALPHA] * term + (1.0 - cfg[C_ALPHA]) * nis


# --- block A's confidence gate (HomographyEKF._gate_detection) -----------------------------------

@_njit
def _bisect(a, n, x, right):
    """bisect.bisect_right (``right``) or bisect_left of x in a[:n]: the same comparisons, so the
    same index whatever the values (NaN included)."""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if (x < a[mid]) if right else not (a[mid] < x):
            hi = mid
        else:
            lo = mid + 1
    return lo


@_njit
def _relative_confidence(ranked, n, confidence):
    """homography_ekf.relative_confidence of the n ranked confidences ranked[:n]."""
    if not np.isfinite(confidence) or confidence <= 0:
        return 0.0
    if n == 0:
        return 1.0
    i = n // 2
    median = ranked[i] if n % 2 else (ranked[i - 1] + ranked[i]) / 2
    if median <= 0:
        return 1.0
    r = confidence / median
    return r if r < 1.0 else 1.0          # min(1.0, r), NaN included


@_njit
def _valid_box(det):
    """Box.is_valid of a box row: finite corner, positive finite size."""
    w, h = det[D_W], det[D_H]
    return 0 < w < np.inf and 0 < h < np.inf and np.isfinite(det[D_X]) and np.isfinite(det[D_Y])


@_njit
def _gate(cfg, g, det, x, P, z):
    """HomographyEKF._gate_detection (with confidence_gate) on the gate memory g, in place:
    returns whether the box is used and the confidence its noise uses, and records the box's
    relative confidence in G_USED_RELATIVE when it is used (0 otherwise). The consistency of
    follow_consistent (with the predicted x, P and the box corners z) is computed only where the
    level test fails (HomographyEKF._update_detection computes it first; the same decision)."""
    m = (g.shape[0] - G_ACCEPTED) // 2
    accepted, ranked = g[G_ACCEPTED:G_ACCEPTED + m], g[G_ACCEPTED + m:]
    n = int(g[G_N_ACC])
    raw = det[D_CONF]
    rel = _relative_confidence(ranked, n, raw)
    relative = cfg[C_RELATIVE] != 0.0
    conf = rel if relative else raw
    accept = False
    if np.isfinite(conf):                  # confidence_gate
        a = cfg[C_ALPHA]
        s = conf if np.isnan(g[G_EWMA]) else a * conf + (1.0 - a) * g[G_EWMA]
        g[G_EWMA] = s
        level = s >= cfg[C_TAU_EWMA]
        if (not level and cfg[C_FOLLOW_CONSISTENT] != 0.0 and g[G_FOLLOWING] != 0.0
                and cfg[C_CHI2] != 0.0 and _valid_box(det)):
            level = _consistent(x, P, cfg, z)
        accept = level and s - conf <= cfg[C_TAU_DIFF]
    if relative and conf <= 0:
        accept = False
    if not _valid_box(det) or (cfg[C_GATING] != 0.0 and not accept):
        g[G_FOLLOWING] = g[G_USED_RELATIVE] = 0.0
        return False, 0.0
    g[G_N_USED] += 1
    g[G_FOLLOWING] = 1.0
    g[G_USED_RELATIVE] = rel
    if relative:
        if n == m:                         # the oldest one leaves
            i = _bisect(ranked, n, accepted[0], False)
            for j in range(i, n - 1):
                ranked[j] = ranked[j + 1]
            for j in range(n - 1):
                accepted[j] = accepted[j + 1]
            n -= 1
        i = _bisect(ranked, n, raw, True)
        for j in range(n, i, -1):
            ranked[j] = ranked[j - 1]
        ranked[i] = raw
        accepted[n] = raw
        g[G_N_ACC] = n + 1
    return True, conf


@_njit
def tick(cfg, x, P, g, dt, H, C, motion, dets, n_dets):
    """One tick (HomographyEKF._tick_state): motion update (before or after the prediction),
    velocity prior and prediction when dt > 0, then each box dets[:n_dets] (rows D_*, in capture
    order) through the confidence gate and, when used, its update. Updates the state x, P and
    gate memory g in place (copies of the previous state's); returns False when the result is
    not finite (the caller then holds the previous state)."""
    n = x.shape[0]
    g[G_USED_RELATIVE] = 0.0
    floor, q = cfg[C_FLOOR:C_Q], cfg[C_Q:]
    use_h = motion != MOTION_NONE and _valid_motion(H, C, motion)
    before = cfg[C_H_BEFORE] != 0.0
    if use_h and before:
        _update_motion(x, P, cfg, floor, H, C, motion)
    if dt > 0:
        _velocity_prior(x, P, cfg, dt, g[G_N_USED])
        _predict(x, P, cfg, q, dt, g[G_NIS])
    if use_h and not before:
        _update_motion(x, P, cfg, floor, H, C, motion)
    z = np.empty(4)
    for b in range(n_dets):
        det = dets[b]
        z[0], z[1] = det[D_X], det[D_Y]
        z[2], z[3] = det[D_X] + det[D_W], det[D_Y] + det[D_H]
        used, conf = _gate(cfg, g, det, x, P, z)
        if not used:
            continue
        d2 = _update_box(x, P, cfg, z, conf)
        if cfg[C_Q_ADAPT] != 0.0:
            g[G_NIS] = _innovation_average(g[G_NIS], d2, cfg)
    for i in range(n):
        if not np.isfinite(x[i]):
            return False
        for j in range(n):
            if not np.isfinite(P[i, j]):
                return False
    return True
