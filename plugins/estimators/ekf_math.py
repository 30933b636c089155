"""Pure math of the homography EKF (paper section 2.3, eqs. homography, ekf_x_z, ekf_velocity_1).

State layout (``n_deriv`` = 1 constant velocity, 2 constant acceleration, 3 constant jerk)::

    x = [x_tl, y_tl, x_br, y_br, h11 .. h33 (row-major), v_x, v_y, (a_x, a_y, (j_x, j_y))]

Derivatives are of the box centre, in pixels per second (``dt`` is in seconds). The homography
``H`` maps the previous estimator tick's frame to the current one. Written by hand (a few lines
of algebra): no library offers the EKF transition of a box carried by a homography with its
analytic Jacobian; the generic filter algebra is checked against filterpy in the tests.
"""

from __future__ import annotations

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


# --- the homography projection g and its derivatives (eq. homography) --------------------------

def project(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """g(p): the point ``p = (x, y)`` mapped through ``H`` (dehomogenised)."""
    w = H[2, 0] * p[0] + H[2, 1] * p[1] + H[2, 2]
    return np.array([(H[0, 0] * p[0] + H[0, 1] * p[1] + H[0, 2]) / w,
                     (H[1, 0] * p[0] + H[1, 1] * p[1] + H[1, 2]) / w])


def _uvw(H: np.ndarray, p: np.ndarray) -> tuple[float, float, float]:
    w = H[2, 0] * p[0] + H[2, 1] * p[1] + H[2, 2]
    u = (H[0, 0] * p[0] + H[0, 1] * p[1] + H[0, 2]) / w
    v = (H[1, 0] * p[0] + H[1, 1] * p[1] + H[1, 2]) / w
    return u, v, w


def jac_point(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """J_g(p) = dg/dp (2x2), MODELS.md section 4.2 (J_p)."""
    u, v, w = _uvw(H, p)
    return np.array([[H[0, 0] - u * H[2, 0], H[0, 1] - u * H[2, 1]],
                     [H[1, 0] - v * H[2, 0], H[1, 1] - v * H[2, 1]]]) / w


def jac_hom(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """dg/dh (2x9) over row-major vec(H), MODELS.md section 4.2 (J_i)."""
    u, v, w = _uvw(H, p)
    pt = np.array([p[0], p[1], 1.0])
    out = np.zeros((2, 9))
    out[0, 0:3] = pt
    out[1, 3:6] = pt
    out[0, 6:9] = -u * pt
    out[1, 6:9] = -v * pt
    return out / w


def jac_point_times(H: np.ndarray, p: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """m = J_g(p) e (a displacement ``e`` mapped to the new frame) and its derivatives
    dm/dp (2x2) and dm/dh (2x9); m is linear in e with dm/de = J_g(p)."""
    u, v, w = _uvw(H, p)
    J = np.array([[H[0, 0] - u * H[2, 0], H[0, 1] - u * H[2, 1]],
                  [H[1, 0] - v * H[2, 0], H[1, 1] - v * H[2, 1]]]) / w
    m = J @ e
    s = H[2, 0] * e[0] + H[2, 1] * e[1]
    dm_dp = -(s / w) * J - np.outer(m, H[2, :2]) / w
    pt = np.array([p[0], p[1], 1.0])
    et = np.array([e[0], e[1], 0.0])
    dm_dh = np.zeros((2, 9))
    dm_dh[0, 0:3] = (et - (s / w) * pt) / w
    dm_dh[1, 3:6] = dm_dh[0, 0:3]
    dm_dh[0, 6:9] = ((u * s / w - m[0]) * pt - u * et) / w
    dm_dh[1, 6:9] = ((v * s / w - m[1]) * pt - v * et) / w
    return m, dm_dp, dm_dh


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


def transition(x: np.ndarray, dt: float, n_deriv: int) -> tuple[np.ndarray, np.ndarray]:
    """``f(x)`` and its analytic Jacobian ``F = df/dx``.

    Paper eq. ekf_velocity_1 for ``n_deriv = 1``: corners -> g(corner) + J_g(c) v dt, H held,
    v -> J_g(c) v, with J_g evaluated at the box centre c = (tl + br) / 2. Higher models add
    the Taylor terms (a dt^2/2, j dt^3/6) and map every derivative through J_g(c)."""
    n = state_dim(n_deriv)
    H = x[HOM].reshape(3, 3)
    tl, br = x[TL], x[BR]
    c = 0.5 * (tl + br)
    D = x[N_BASE:].reshape(n_deriv, 2)
    wdisp, T = taylor(dt, n_deriv)
    e = wdisp @ D                      # displacement of the centre over dt (old frame)
    nd = T @ D                         # derivatives after dt (old frame), one row each

    m, m_p, m_h = jac_point_times(H, c, e)
    Jc = jac_point(H, c)
    fx = np.empty(n)
    fx[TL] = project(H, tl) + m
    fx[BR] = project(H, br) + m
    fx[HOM] = x[HOM]

    F = np.zeros((n, n))
    half = 0.5 * m_p
    F[TL, TL] = jac_point(H, tl) + half
    F[TL, BR] = half
    F[BR, TL] = half
    F[BR, BR] = jac_point(H, br) + half
    F[TL, HOM] = jac_hom(H, tl) + m_h
    F[BR, HOM] = jac_hom(H, br) + m_h
    F[HOM, HOM] = np.eye(9)
    for i in range(n_deriv):
        F[TL, deriv_slice(i)] = wdisp[i] * Jc
        F[BR, deriv_slice(i)] = wdisp[i] * Jc
    for j in range(n_deriv):
        mj, mj_p, mj_h = jac_point_times(H, c, nd[j])
        sj = deriv_slice(j)
        fx[sj] = mj
        F[sj, TL] = 0.5 * mj_p
        F[sj, BR] = 0.5 * mj_p
        F[sj, HOM] = mj_h
        for i in range(j, n_deriv):
            F[sj, deriv_slice(i)] = T[j, i] * Jc
    return fx, F


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
