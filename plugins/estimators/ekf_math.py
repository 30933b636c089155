"""Pure math of the homography EKF (paper section 2.3, eqs. homography, ekf_x_z, ekf_velocity_1).

State layout (``n_deriv`` = 1 constant velocity, 2 constant acceleration, 3 constant jerk)::

    x = [x_tl, y_tl, x_br, y_br, h11 .. h33 (row-major), v_x, v_y, (a_x, a_y, (j_x, j_y))]

Derivatives are of the box centre, in pixels per second (``dt`` is in seconds). The homography
``H`` maps the previous estimator tick's frame to the current one. Written by hand (a few lines
of algebra): no library offers the EKF transition of a box carried by a homography with its
analytic Jacobian; the generic filter algebra is checked against filterpy in the tests.
"""

from __future__ import annotations

import math
from math import factorial

import numpy as np

TL = slice(0, 2)
BR = slice(2, 4)
CORNERS = slice(0, 4)
HOM = slice(4, 13)
N_BASE = 13  # corners (4) + homography (9)


def state_dim(n_deriv: int) -> int:
    """15 for constant velocity (the paper), 17 for constant acceleration, 19 for constant jerk."""
    return N_BASE + 2 * n_deriv


def deriv_slice(i: int) -> slice:
    """State slice of the i-th centre derivative (0 velocity, 1 acceleration, 2 jerk)."""
    return slice(N_BASE + 2 * i, N_BASE + 2 * i + 2)


def box_side(x: np.ndarray) -> float:
    """sqrt(w h) of the box in the state (0 for a degenerate box): the scale of its noise."""
    w, h = float(x[2] - x[0]), float(x[3] - x[1])
    return float(np.sqrt(max(w, 0.0)) * np.sqrt(max(h, 0.0)))


# --- the homography projection g and its derivatives (eq. homography) --------------------------

def project(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """g(p): the point ``p = (x, y)`` mapped through ``H`` (dehomogenised)."""
    u, v, _ = _uvw(H.reshape(9).tolist(), float(p[0]), float(p[1]))
    return np.array([u, v])


def jac_point(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """J_g(p) = dg/dp (2x2), MODELS.md section 4.2 (J_p)."""
    h = H.reshape(9).tolist()
    return np.array(_jp(h, *_uvw(h, float(p[0]), float(p[1]))))


def jac_hom(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """dg/dh (2x9) over row-major vec(H), MODELS.md section 4.2 (J_i)."""
    x, y = float(p[0]), float(p[1])
    return np.array(_jh(x, y, *_uvw(H.reshape(9).tolist(), x, y)))


# Scalar kernels on a row-major list ``h`` of 9 floats (plain Python floats: for 2-vectors they
# are several times faster than numpy element access).

def _uvw(h: list, x: float, y: float) -> tuple[float, float, float]:
    w = h[6] * x + h[7] * y + h[8]
    return (h[0] * x + h[1] * y + h[2]) / w, (h[3] * x + h[4] * y + h[5]) / w, w


def _jp(h: list, u: float, v: float, w: float) -> list:
    return [[(h[0] - u * h[6]) / w, (h[1] - u * h[7]) / w],
            [(h[3] - v * h[6]) / w, (h[4] - v * h[7]) / w]]


def _jh(x: float, y: float, u: float, v: float, w: float) -> list:
    a, b, c = x / w, y / w, 1.0 / w
    return [[a, b, c, 0.0, 0.0, 0.0, -u * a, -u * b, -u * c],
            [0.0, 0.0, 0.0, a, b, c, -v * a, -v * b, -v * c]]


def _jpt(h: list, x: float, y: float, e0: float, e1: float, u: float, v: float, w: float):
    (j00, j01), (j10, j11) = _jp(h, u, v, w)
    m0, m1 = j00 * e0 + j01 * e1, j10 * e0 + j11 * e1
    s = (h[6] * e0 + h[7] * e1) / w
    g0, g1 = h[6] / w, h[7] / w
    mp = [[-s * j00 - m0 * g0, -s * j01 - m0 * g1],
          [-s * j10 - m1 * g0, -s * j11 - m1 * g1]]
    # dm/dh: rows of H multiply (e - s p~)/w; the last row adds ((u s - m) p~ - u e)/w
    r0, r1, r2 = (e0 - s * x) / w, (e1 - s * y) / w, -s / w
    k0, k1 = (u * s - m0) / w, (v * s - m1) / w
    mh = [[r0, r1, r2, 0.0, 0.0, 0.0, k0 * x - u * e0 / w, k0 * y - u * e1 / w, k0],
          [0.0, 0.0, 0.0, r0, r1, r2, k1 * x - v * e0 / w, k1 * y - v * e1 / w, k1]]
    return [m0, m1], mp, mh


# --- the transition f (eq. ekf_velocity_1, generalised to higher derivatives) --------------------

def taylor(dt: float, n_deriv: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights of a constant-(n_deriv)th-derivative model: ``disp[i] = dt^(i+1)/(i+1)!`` (corner
    displacement per derivative) and ``T[j, i] = dt^(i-j)/(i-j)!`` for i >= j (derivative j
    after dt)."""
    disp = np.array([dt ** (i + 1) / factorial(i + 1) for i in range(n_deriv)])
    T = np.zeros((n_deriv, n_deriv))
    for j in range(n_deriv):
        for i in range(j, n_deriv):
            T[j, i] = dt ** (i - j) / factorial(i - j)
    return disp, T


def transition(x: np.ndarray, dt: float, n_deriv: int,
               box: str = "corners") -> tuple[np.ndarray, np.ndarray]:
    """``f(x)`` and its analytic Jacobian ``F = df/dx``.

    Paper eq. ekf_velocity_1 for ``n_deriv = 1``: corners -> g(corner) + J_g(c) v dt, H held,
    v -> J_g(c) v, with J_g evaluated at the box centre c = (tl + br) / 2. Higher models add
    the Taylor terms (a dt^2/2, j dt^3/6) and map every derivative through J_g(c).

    ``box = "centre"`` (beyond the paper, rotation-safe): the centre goes through H,
    c -> g(c) + J_g(c) v dt, and the half-size is multiplied by the local scale
    s = sqrt|det J_g(c)| (:func:`local_scale`), so a roll or yaw of the camera keeps the box's
    width and height instead of shearing the two corners apart (paper L400-401 moves corners)."""
    n = state_dim(n_deriv)
    xs = x.tolist()
    h = xs[4:13]
    x1, y1, x2, y2 = xs[0:4]
    cx, cy = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    wdisp, T = taylor(dt, n_deriv)
    uvw_c = _uvw(h, cx, cy)
    Jc = np.array(_jp(h, *uvw_c))
    # m(e) = J_g(c) e is linear in e: map each derivative once, then combine with the weights
    M = np.empty((n_deriv, 2, 12))      # per derivative: [m | dm/dp | dm/dh] rows
    for i in range(n_deriv):
        m, mp, mh = _jpt(h, cx, cy, xs[N_BASE + 2 * i], xs[N_BASE + 2 * i + 1], *uvw_c)
        M[i, :, 0] = m
        M[i, :, 1:3] = mp
        M[i, :, 3:] = mh
    M = M.reshape(n_deriv, 24)
    disp = (wdisp @ M).reshape(2, 12)       # centre displacement over dt, in the new frame
    nd = (T @ M).reshape(n_deriv, 2, 12)    # derivative j after dt, in the new frame

    fx = np.empty(n)
    F = np.zeros((n, n))
    if box == "corners":
        _corners_through_h(fx, F, h, x1, y1, x2, y2, disp)
    elif box == "centre":
        _centre_through_h(fx, F, h, x1, y1, x2, y2, disp, uvw_c, Jc)
    else:
        raise ValueError(f"box must be 'corners' or 'centre', got {box!r}")
    fx[HOM] = x[HOM]
    fx[N_BASE:] = nd[:, :, 0].reshape(-1)
    F[HOM, HOM] = np.eye(9)
    for i in range(n_deriv):
        F[TL, deriv_slice(i)] = F[BR, deriv_slice(i)] = wdisp[i] * Jc
    for j in range(n_deriv):
        sj = deriv_slice(j)
        F[sj, TL] = F[sj, BR] = 0.5 * nd[j, :, 1:3]
        F[sj, HOM] = nd[j, :, 3:]
        for i in range(j, n_deriv):
            F[sj, deriv_slice(i)] = T[j, i] * Jc
    return fx, F


def _corners_through_h(fx, F, h, x1, y1, x2, y2, disp) -> None:
    """Paper: each corner through g, plus the centre displacement (rows TL, BR of f and F)."""
    uvw_tl, uvw_br = _uvw(h, x1, y1), _uvw(h, x2, y2)
    d0, d1 = disp[:, 0].tolist()
    fx[0:4] = (uvw_tl[0] + d0, uvw_tl[1] + d1, uvw_br[0] + d0, uvw_br[1] + d1)
    half = 0.5 * disp[:, 1:3]
    F[TL, TL] = np.array(_jp(h, *uvw_tl)) + half
    F[TL, BR] = half
    F[BR, TL] = half
    F[BR, BR] = np.array(_jp(h, *uvw_br)) + half
    F[TL, HOM] = np.array(_jh(x1, y1, *uvw_tl)) + disp[:, 3:]
    F[BR, HOM] = np.array(_jh(x2, y2, *uvw_br)) + disp[:, 3:]


def _centre_through_h(fx, F, h, x1, y1, x2, y2, disp, uvw_c, Jc) -> None:
    """Rotation-safe: centre c' = g(c) + disp, half-size e' = s(c, H) e with the local scale
    s of :func:`local_scale`; corners c' -/+ e' (rows TL, BR of f and F)."""
    cx, cy = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    e = np.array([0.5 * (x2 - x1), 0.5 * (y2 - y1)])
    s, ds_dc, ds_dh = _local_scale(h, cx, cy, uvw_c[2])
    c_new = np.array(uvw_c[:2]) + disp[:, 0]
    e_new = s * e
    fx[0:2] = c_new - e_new
    fx[2:4] = c_new + e_new
    dc_dc = Jc + disp[:, 1:3]                       # d c' / d c
    dc_dh = np.array(_jh(cx, cy, *uvw_c)) + disp[:, 3:]
    de_dc = np.outer(e, ds_dc)                      # d e' / d c
    de_dh = np.outer(e, ds_dh)
    # c = (tl + br) / 2 and e = (br - tl) / 2: d/dtl = d/dc / 2 - d/de / 2, d/dbr = the sum
    sI = s * np.eye(2)
    F[TL, TL] = 0.5 * (dc_dc - de_dc) + 0.5 * sI
    F[TL, BR] = 0.5 * (dc_dc - de_dc) - 0.5 * sI
    F[BR, TL] = 0.5 * (dc_dc + de_dc) - 0.5 * sI
    F[BR, BR] = 0.5 * (dc_dc + de_dc) + 0.5 * sI
    F[TL, HOM] = dc_dh - de_dh
    F[BR, HOM] = dc_dh + de_dh


def local_scale(H: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Local scale of the homography at ``p``: s = sqrt|det J_g(p)|, with its derivatives
    ds/dp (2,) and ds/dh (9,). Uses det J_g(p) = det(H) / w^3, w = h31 x + h32 y + h33 (the
    area ratio of a homography at a point, Hartley & Zisserman; checked against finite
    differences of :func:`jac_point` in the tests)."""
    h = np.asarray(H, dtype=float).reshape(9).tolist()
    x, y = float(p[0]), float(p[1])
    return _local_scale(h, x, y, h[6] * x + h[7] * y + h[8])


def _local_scale(h: list, x: float, y: float, w: float) -> tuple[float, np.ndarray, np.ndarray]:
    Hm = np.array(h).reshape(3, 3)
    det = float(np.linalg.det(Hm))
    s = float(np.sqrt(abs(det) / abs(w) ** 3))
    ds_dp = -1.5 * s / w * np.array([h[6], h[7]])
    # d ln|det H| / dH = H^-T; d ln|w| / dh = (0, .., x, y, 1) / w
    dlogdet = np.linalg.inv(Hm).T.reshape(9)
    dlogw = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, x, y, 1.0]) / w
    ds_dh = s * (0.5 * dlogdet - 1.5 * dlogw)
    return s, ds_dp, ds_dh


def image_static_velocity(x: np.ndarray, dt: float) -> np.ndarray:
    """The centre velocity v for which the transition keeps the box centre where it is in the
    image: g(c) + J_g(c) v dt = c, i.e. v = J_g(c)^-1 (c - g(c)) / dt (H from the state)."""
    H = x[HOM].reshape(3, 3)
    c = 0.5 * (x[TL] + x[BR])
    return np.linalg.solve(jac_point(H, c), c - project(H, c)) / dt


def velocity_mixture(x: np.ndarray, P: np.ndarray, v_img: np.ndarray, w: float,
                     P0_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The velocity reset to the moment-matched mixture of N(0, P0_v) (probability 1 - w) and
    N(v_img, P0_v) (probability w): mean w v_img, covariance P0_v + w (1 - w) v_img v_img^T,
    uncorrelated with the rest of the state (nothing has measured it yet)."""
    sl = deriv_slice(0)
    x = x.copy()
    x[sl] = w * v_img
    P = P.copy()
    P[sl, :] = 0.0
    P[:, sl] = 0.0
    P[sl, sl] = P0_v + w * (1.0 - w) * np.outer(v_img, v_img)
    return x, P


def relax_velocity(x: np.ndarray, v_ref: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
    """v -> v_ref + a (v - v_ref) (an Ornstein-Uhlenbeck step towards the input ``v_ref``,
    a = exp(-dt / tau)); returns the new state and its Jacobian (identity but a on v)."""
    x = x.copy()
    sl = deriv_slice(0)
    x[sl] = v_ref + a * (x[sl] - v_ref)
    A = np.eye(len(x))
    A[sl, sl] *= a
    return x, A


# --- generic EKF algebra ----------------------------------------------------------------------

def predict_cov(P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """P = F P F^T + Q, symmetrised."""
    P = F @ P @ F.T + Q
    return 0.5 * (P + P.T)


def joseph_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, Hm: np.ndarray,
                  R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear-measurement EKF update in Joseph form:
    K = P H^T S^-1, x += K (z - H x), P = (I - K H) P (I - K H)^T + K R K^T, symmetrised."""
    PHt = P @ Hm.T
    S = Hm @ PHt + R
    K = np.linalg.solve(S, PHt.T).T     # S is symmetric: (S^-1 H P)^T = P H^T S^-1
    x = x + K @ (z - Hm @ x)
    A = np.eye(len(x)) - K @ Hm
    P = A @ P @ A.T + K @ R @ K.T
    return x, 0.5 * (P + P.T)


def joseph_update_block(x: np.ndarray, P: np.ndarray, z: np.ndarray, sl: slice,
                        R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`joseph_update` for a measurement of the state entries ``sl`` (H = selector(sl)),
    the same arithmetic without the products by a 0/1 matrix."""
    PHt = P[:, sl]
    S = PHt[sl] + R
    K = np.linalg.solve(S, PHt.T).T
    x = x + K @ (z - x[sl])
    A = np.eye(len(x))
    A[:, sl] -= K
    P = A @ P @ A.T + K @ R @ K.T
    return x, 0.5 * (P + P.T)


def mahalanobis2(innovation: np.ndarray, S: np.ndarray) -> float:
    """Squared Mahalanobis distance nu^T S^-1 nu of an innovation with covariance S."""
    nu = np.asarray(innovation, dtype=float)
    return float(nu @ np.linalg.solve(S, nu))


def robust_noise(innovation: np.ndarray, P_zz: np.ndarray, R: np.ndarray, chi2: float) -> np.ndarray:
    """R for a measurement with predicted covariance ``P_zz`` (Huber-type bound): unchanged
    while the squared Mahalanobis distance d2 = nu^T (P_zz + R)^-1 nu is at most ``chi2``,
    otherwise multiplied by d2 / chi2. An improbable measurement then moves the state by a
    bounded step instead of being dropped (dropping it locks a confidently wrong filter out)."""
    d2 = mahalanobis2(innovation, P_zz + R)
    if not d2 > chi2:
        return R
    return R * (d2 / chi2)


def normalised_innovation_average(average: float, d2: float, dof: int, cap: float,
                                  alpha: float) -> float:
    """EWMA of the normalised innovation squared d2 / dof (each term capped at cap / dof, so one
    outlier moves it by a bounded step). Its expectation is 1 when the filter's covariances are
    right (d2 ~ chi2(dof)); above 1 the predictions are worse than the filter believes
    (innovation-based covariance matching, Mehra 1972)."""
    term = min(float(d2), cap) / dof
    return float(alpha * term + (1.0 - alpha) * average) if math.isfinite(term) else average


def selector(n: int, sl: slice) -> np.ndarray:
    """Measurement matrix picking the state entries ``sl`` (corners or homography)."""
    idx = np.arange(n)[sl]
    Hm = np.zeros((len(idx), n))
    Hm[np.arange(len(idx)), idx] = 1.0
    return Hm


# --- homography measurements --------------------------------------------------------------

def normalise_h33(H: np.ndarray) -> np.ndarray:
    """H / h33 (the chart of the state and of Motion.cov)."""
    return np.asarray(H, dtype=float) / float(H[2, 2])


def compose(H_old: np.ndarray, C_old: np.ndarray | None, H_new: np.ndarray,
            C_new: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """The motion over two consecutive intervals, ``H_new @ H_old`` in the h33 = 1 chart, with
    its first-order covariance (independent inputs; vec_row(A B) = (A kron I) vec_row(B) =
    (I kron B^T) vec_row(A)). Covariance None if either input has none."""
    P = H_new @ H_old
    p33 = P[2, 2]
    out = P / p33
    if C_old is None or C_new is None:
        return out, None
    A_old = np.kron(H_new, np.eye(3))
    A_new = np.kron(np.eye(3), H_old.T)
    C = A_old @ C_old @ A_old.T + A_new @ C_new @ A_new.T
    N = (np.eye(9) - np.outer(out.reshape(9), np.eye(9)[8])) / p33
    C = N @ C @ N.T
    return out, 0.5 * (C + C.T)


def transferred_sigma(H: np.ndarray, C: np.ndarray, p: np.ndarray) -> float:
    """Standard deviation (px, largest axis) of g(p) induced by the homography covariance C:
    sqrt(lambda_max(G C G^T)), G = dg/dh at p. What ``tau_sigma`` is compared with."""
    G = jac_hom(H, p)
    S = G @ C @ G.T
    return float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (S + S.T))[-1], 0.0)))


def floored(C: np.ndarray | None, floor: np.ndarray) -> np.ndarray:
    """R for a homography measurement: the measured covariance with each variance raised to at
    least ``floor`` (adds a non-negative diagonal, so R stays PSD and becomes PD)."""
    if C is None:
        return np.diag(floor)
    R = 0.5 * (C + C.T)
    d = np.diag(R)
    return R + np.diag(np.maximum(floor - d, 0.0))
