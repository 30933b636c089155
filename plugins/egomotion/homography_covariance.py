"""Least-squares fits of the 2-D motion models and the first-order covariance of their
homography (paper section 2.2; Hartley & Zisserman 2nd ed., section 5.2, Result 5.10).

Noise model: the source points are exact (grid points, or detected corners, where Lucas-Kanade
starts) and the tracked destination points carry isotropic Gaussian noise of std ``sigma``
pixels, i.e. H&Z's "error in one image" case. For a model with parameters ``p`` embedded in
``vec(H)`` (row-major, h33 = 1 chart) by the tangent basis ``A`` (9 x d), the ML estimate has

    Sigma_h = A (A^T J^T J A / sigma^2)^-1 A^T,     J = d pi(H x_i) / d vec(H), stacked,

which is Result 5.10's ``(J^T Sigma_X^-1 J)^{+A}``. The matrix is computed in Hartley-normalised
coordinates (the same similarity ``T`` for both images, so every model keeps its form) and mapped
back with ``vec(T^-1 H_n T) = (T^-1 kron T^T) vec(H_n)`` followed by the h33 = 1 chart Jacobian.

Models and their embedding (rows/columns of the 9x9 outside the model's tangent space are zero):
homography (h11..h32, d = 8), affine (h11..h23, d = 6), similarity ``[[a, -b, tx], [b, a, ty]]``
(d = 4) and translation ``[[1, 0, tx], [0, 1, ty]]`` (d = 2).
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np

Model = Literal["homography", "affine", "similarity", "translation"]
MODELS: tuple[str, ...] = ("homography", "affine", "similarity", "translation")


_E9 = np.eye(9)
_E9.setflags(write=False)


@functools.cache
def tangent_basis(model: str) -> np.ndarray:
    """(9, d) basis of the model's tangent space in row-major vec(H), h33 = 1 chart (read-only:
    built once per model, it is asked for several times per frame)."""
    e = _E9
    if model == "homography":
        A = e[:, :8].copy()
    elif model == "affine":
        A = e[:, :6].copy()
    elif model == "similarity":  # a -> h11 = h22, b -> h21 = -h12, tx -> h13, ty -> h23
        A = np.stack([e[0] + e[4], e[3] - e[1], e[2], e[5]], axis=1)
    elif model == "translation":
        A = np.stack([e[2], e[5]], axis=1)
    else:
        raise ValueError(f"unknown motion model {model!r}; expected one of {', '.join(MODELS)}")
    A.setflags(write=False)
    return A


def degrees_of_freedom(model: str) -> int:
    return tangent_basis(model).shape[1]


def min_points(model: str) -> int:
    """Smallest number of correspondences that determines the model (2 equations each)."""
    return (degrees_of_freedom(model) + 1) // 2


def project(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """pi(H [x, y, 1]^T) for (N, 2) points (paper eq. homography, g)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    q = pts @ H[:, :2].T + H[:, 2]
    return q[:, :2] / q[:, 2:3]


def transfer_jacobian(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2, 9) derivative of pi(H x_i) with respect to row-major vec(H) (H&Z eq. 5.11's J_i):
    ``(1/w) [[x~^T, 0, -u x~^T], [0, x~^T, -v x~^T]]``."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    xt = np.column_stack([pts, np.ones(len(pts))])
    q = xt @ H.T
    w = q[:, 2]
    u, v = q[:, 0] / w, q[:, 1] / w
    J = np.zeros((len(pts), 2, 9))
    J[:, 0, 0:3] = xt
    J[:, 0, 6:9] = -u[:, None] * xt
    J[:, 1, 3:6] = xt
    J[:, 1, 6:9] = -v[:, None] * xt
    return J / w[:, None, None]


def point_jacobian(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2, 2) derivative of pi(H x_i) with respect to the point (the EKF's J_g)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    q = pts @ H[:, :2].T + H[:, 2]
    w = q[:, 2]
    u, v = q[:, 0] / w, q[:, 1] / w
    J = np.empty((len(pts), 2, 2))
    J[:, 0, 0] = H[0, 0] - u * H[2, 0]
    J[:, 0, 1] = H[0, 1] - u * H[2, 1]
    J[:, 1, 0] = H[1, 0] - v * H[2, 0]
    J[:, 1, 1] = H[1, 1] - v * H[2, 1]
    return J / w[:, None, None]


def similarity_normalisation(pts: np.ndarray) -> np.ndarray:
    """Hartley's normalising similarity (H&Z section 4.4.4): centroid to the origin, mean
    distance from it sqrt(2)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    c = pts.mean(axis=0)
    r = pts - c
    d = float(np.mean(np.sqrt(np.add.reduce(r * r, axis=1))))  # np.linalg.norm(r, axis=1), its arithmetic
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def h33_chart(H: np.ndarray, cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """``H / h33`` and the covariance pushed through its Jacobian ``(I - g e9^T) / h33``,
    ``g = vec(H) / h33``."""
    h9 = float(H[2, 2])
    Hn = H / h9
    if cov is None:
        return Hn, None
    G = (_E9 - np.outer(Hn.reshape(9), _E9[8])) / h9
    return Hn, G @ cov @ G.T


def homography_covariance(H: np.ndarray, src: np.ndarray, sigma: float,
                          model: str = "homography") -> np.ndarray:
    """9x9 covariance of row-major vec(H) (h33 = 1 chart) of the least-squares estimate ``H``
    from exact ``src`` points and destination points with isotropic noise ``sigma`` (px).

    Raises ``np.linalg.LinAlgError`` when the points do not determine the model (e.g. collinear)."""
    src = np.asarray(src, dtype=float).reshape(-1, 2)
    A = tangent_basis(model)
    if len(src) < min_points(model):
        raise np.linalg.LinAlgError(f"{len(src)} points cannot determine a {model}")
    T = similarity_normalisation(src)
    Ti = np.linalg.inv(T)
    Hn, _ = h33_chart(T @ (H / H[2, 2]) @ Ti)
    sigma_n = T[0, 0] * float(sigma)
    J = transfer_jacobian(Hn, src @ T[:2, :2].T + T[:2, 2]).reshape(-1, 9) @ A
    info = J.T @ J
    # The condition number guards the inverse: a near-singular information matrix means a
    # degenerate point set (info is symmetric PSD: its condition number is lambda_max /
    # lambda_min, from eigvalsh at half the cost of np.linalg.cond's SVD).
    if not np.isfinite(info).all():
        raise np.linalg.LinAlgError(f"the points do not determine a {model} (singular information)")
    lo, *_, hi = np.linalg.eigvalsh(info)
    if not (lo > 0 and hi <= 1e12 * lo):
        raise np.linalg.LinAlgError(f"the points do not determine a {model} (singular information)")
    cov_n = sigma_n ** 2 * (A @ np.linalg.inv(info) @ A.T)
    # vec(Ti Hn T) = (Ti kron T^T) vec(Hn); the kron product by broadcasting (the same products,
    # a tenth of np.kron's time)
    M = (Ti[:, None, :, None] * T.T[None, :, None, :]).reshape(9, 9)
    _, cov = h33_chart(Ti @ Hn @ T, M @ cov_n @ M.T)
    return 0.5 * (cov + cov.T)


def residual_sigma(H: np.ndarray, src: np.ndarray, dst: np.ndarray, model: str = "homography") -> float:
    """Unbiased point-noise estimate ``sqrt(sum ||x'_i - pi(H x_i)||^2 / (2n - d))`` (H&Z
    section 5.1.3), NaN when ``2n <= d``."""
    r = np.asarray(dst, dtype=float).reshape(-1, 2) - project(H, src)
    dof = 2 * len(r) - degrees_of_freedom(model)
    return float(np.sqrt(np.sum(r * r) / dof)) if dof > 0 else float("nan")


def fit_least_squares(src: np.ndarray, dst: np.ndarray, model: str) -> np.ndarray:
    """Least-squares (ML under destination noise) fit of an affine, similarity or translation
    model, as a 3x3 matrix. These models are linear in their parameters, so the solution is a
    single linear least-squares solve; OpenCV's estimators for them always run a robust method
    and have no plain least-squares mode (``findHomography(..., 0)`` covers homographies)."""
    src = np.asarray(src, dtype=float).reshape(-1, 2)
    dst = np.asarray(dst, dtype=float).reshape(-1, 2)
    A = tangent_basis(model)
    if model == "homography":
        raise ValueError("use cv2.findHomography(src, dst, 0) for the homography least-squares fit")
    # pi(H x) = (affine part of H) x for these models: rows of vec(H) times [x, y, 1].
    J = transfer_jacobian(np.eye(3), src).reshape(-1, 9)
    base = np.eye(3).reshape(9) if model in ("translation",) else np.zeros(9)
    if model == "translation":
        rhs = (dst - src).reshape(-1)
    else:
        rhs = dst.reshape(-1)
    p, *_ = np.linalg.lstsq(J @ A, rhs, rcond=None)
    h = base + A @ p
    h[8] = 1.0
    return h.reshape(3, 3)


def corner_transfer_error(H_est: np.ndarray, H_true: np.ndarray, width: int, height: int) -> float:
    """Mean distance (px) between the four image corners mapped by the estimated and the true
    homography (the usual homography-estimation accuracy figure)."""
    c = np.array([[0.0, 0.0], [width - 1.0, 0.0], [width - 1.0, height - 1.0], [0.0, height - 1.0]])
    return float(np.mean(np.linalg.norm(project(H_est, c) - project(H_true, c), axis=1)))
