"""First-order homography covariance (H&Z Result 5.10) against Monte-Carlo estimates, Jacobians
against finite differences, fits against exact data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mata_eval_plugins.egomotion import homography_covariance as hc

W, H_IMG = 640, 360


def grid(n: int = 12) -> np.ndarray:
    xs = (np.arange(n) + 0.5) * W / n
    ys = (np.arange(n) + 0.5) * H_IMG / n
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


TRUE = {
    "homography": np.array([[1.02, 0.03, -4.0], [-0.02, 0.99, 3.0], [2e-5, -3e-5, 1.0]]),
    "affine": np.array([[1.02, 0.03, -4.0], [-0.02, 0.99, 3.0], [0.0, 0.0, 1.0]]),
    "similarity": np.array([[1.01, -0.04, -4.0], [0.04, 1.01, 3.0], [0.0, 0.0, 1.0]]),
    "translation": np.array([[1.0, 0.0, -4.5], [0.0, 1.0, 2.5], [0.0, 0.0, 1.0]]),
}


def fit(src: np.ndarray, dst: np.ndarray, model: str) -> np.ndarray:
    if model == "homography":
        Hh, _ = cv2.findHomography(src, dst, 0)  # OpenCV's least squares (DLT + LM)
        return Hh / Hh[2, 2]
    return hc.fit_least_squares(src, dst, model)


@pytest.mark.parametrize("model", hc.MODELS)
def test_covariance_matches_monte_carlo(model: str) -> None:
    rng = np.random.default_rng(5)
    src = grid()
    Ht = TRUE[model]
    clean = hc.project(Ht, src)
    sigma = 0.7
    est = np.array([fit(src, clean + rng.normal(0, sigma, clean.shape), model).reshape(9)
                    for _ in range(1500)])
    mc = np.cov(est, rowvar=False)
    an = hc.homography_covariance(Ht, src, sigma, model)
    free = np.flatnonzero(np.abs(hc.tangent_basis(model)).sum(axis=1) > 0)
    fixed = np.setdiff1d(np.arange(9), free)
    ratio = np.diag(mc)[free] / np.diag(an)[free]
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    # entries outside the model are exactly fixed in both
    assert np.allclose(an[fixed], 0) and np.allclose(an[:, fixed], 0)
    assert np.allclose(mc[fixed], 0, atol=1e-20)
    # the whole matrix, not only the diagonal: correlation coefficients agree
    d = np.sqrt(np.diag(an)[free])
    corr_an = an[np.ix_(free, free)] / np.outer(d, d)
    dm = np.sqrt(np.diag(mc)[free])
    corr_mc = mc[np.ix_(free, free)] / np.outer(dm, dm)
    assert np.max(np.abs(corr_an - corr_mc)) < 0.1


def test_homography_covariance_equals_sphere_pseudo_inverse_in_the_h33_chart() -> None:
    """H&Z Result 5.10 on the unit sphere (plain pseudo-inverse, pixel coordinates, no
    normalisation) mapped to the h33 = 1 chart gives the same matrix."""
    src = grid(8)
    Ht = TRUE["homography"]
    sigma = 0.5
    h = Ht.reshape(9) / np.linalg.norm(Ht)
    J = hc.transfer_jacobian(h.reshape(3, 3), src).reshape(-1, 9)
    lam, V = np.linalg.eigh(J.T @ J / sigma**2)
    sphere = (V[:, 1:] / lam[1:]) @ V[:, 1:].T
    _, chart = hc.h33_chart(h.reshape(3, 3), sphere)
    ours = hc.homography_covariance(Ht, src, sigma)
    # pixel-coordinate eigen-decomposition loses ~1e-6 to conditioning (cond ~ 1e20)
    assert np.allclose(chart, ours, rtol=1e-4, atol=1e-10 * np.abs(ours).max())


def test_jacobians_match_finite_differences() -> None:
    Hh = TRUE["homography"]
    pts = np.array([[10.0, 20.0], [600.0, 300.0], [320.0, 5.0]])
    J = hc.transfer_jacobian(Hh, pts)
    Jp = hc.point_jacobian(Hh, pts)
    eps = 1e-7
    for k in range(9):
        d = np.zeros(9)
        d[k] = eps
        num = (hc.project(Hh + d.reshape(3, 3), pts) - hc.project(Hh - d.reshape(3, 3), pts)) / (2 * eps)
        assert np.allclose(J[:, :, k], num, rtol=1e-5, atol=1e-9)
    for k in range(2):
        d = np.zeros(2)
        d[k] = 1e-4
        num = (hc.project(Hh, pts + d) - hc.project(Hh, pts - d)) / 2e-4
        assert np.allclose(Jp[:, :, k], num, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("model", ["affine", "similarity", "translation"])
def test_least_squares_fit_is_exact_on_clean_data_and_matches_opencv(model: str) -> None:
    src = grid(6)
    Ht = TRUE[model]
    assert np.allclose(hc.fit_least_squares(src, hc.project(Ht, src), model), Ht, atol=1e-10)
    # with noise, OpenCV's LMEDS+refinement on outlier-free data converges to the same LS optimum
    rng = np.random.default_rng(1)
    dst = hc.project(Ht, src) + rng.normal(0, 0.5, (len(src), 2))
    ours = hc.fit_least_squares(src, dst, model)
    if model == "translation":
        ref = np.eye(3)
        ref[:2, 2] = (dst - src).mean(axis=0)
    else:
        est = cv2.estimateAffine2D if model == "affine" else cv2.estimateAffinePartial2D
        M, _ = est(src, dst, method=cv2.LMEDS, refineIters=50)
        ref = np.vstack([M, [0, 0, 1]])
    assert np.allclose(ours, ref, atol=1e-6)


def test_residual_sigma_is_unbiased() -> None:
    rng = np.random.default_rng(2)
    src = grid(6)
    Ht = TRUE["homography"]
    vals = []
    for _ in range(300):
        dst = hc.project(Ht, src) + rng.normal(0, 0.8, (len(src), 2))
        vals.append(hc.residual_sigma(fit(src, dst, "homography"), src, dst) ** 2)
    assert np.mean(vals) == pytest.approx(0.64, rel=0.05)
    assert np.isnan(hc.residual_sigma(Ht, src[:4], hc.project(Ht, src[:4])))


def test_degenerate_points_raise_linalg_error() -> None:
    line = np.column_stack([np.linspace(0, 600, 20), np.full(20, 100.0)])
    with pytest.raises(np.linalg.LinAlgError):
        hc.homography_covariance(np.eye(3), line, 0.5, "homography")
    with pytest.raises(np.linalg.LinAlgError):
        hc.homography_covariance(np.eye(3), line[:3], 0.5, "homography")
    with pytest.raises(ValueError, match="unknown motion model"):
        hc.tangent_basis("projective")


def test_corner_transfer_error_of_a_pure_shift() -> None:
    Hs = np.eye(3)
    Hs[:2, 2] = (3.0, 4.0)
    assert hc.corner_transfer_error(Hs, np.eye(3), 640, 360) == pytest.approx(5.0)
