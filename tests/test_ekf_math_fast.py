"""The fast forms of the shared EKF algebra equal the textbook forms to 1e-9 (relative)."""

from __future__ import annotations

import numpy as np

from mata_eval_plugins.estimators import ekf_math as em


def _spd(rng, n, scales):
    A = rng.normal(size=(n, n)) * np.asarray(scales)[:, None]
    return A @ A.T + np.eye(n)


def test_block_joseph_update_equals_the_dense_joseph_form():
    rng = np.random.default_rng(0)
    scales = np.r_[np.full(4, 3.0), np.full(9, 1e-2), np.full(2, 100.0)]
    for _ in range(50):
        P, x = _spd(rng, 15, scales), rng.normal(size=15) * 100
        for sl in (em.CORNERS, em.HOM):
            m = len(range(15)[sl])
            R, z = _spd(rng, m, np.ones(m)), rng.normal(size=m)
            E = em.selector(15, sl)
            K = P @ E.T @ np.linalg.inv(E @ P @ E.T + R)
            A = np.eye(15) - K @ E
            want_P = A @ P @ A.T + K @ R @ K.T
            want_x = x + K @ (z - E @ x)
            got_x, got_P = em.joseph_update_block(x, P, z, sl, R)
            assert np.abs(got_x - want_x).max() <= 1e-9 * np.abs(want_x).max()
            assert np.abs(got_P - want_P).max() <= 1e-9 * np.abs(want_P).max()


def test_transferred_sigma_is_the_largest_axis():
    rng = np.random.default_rng(1)
    for _ in range(50):
        H = np.eye(3) + rng.normal(size=(3, 3)) * np.array([[1e-2, 1e-2, 3], [1e-2, 1e-2, 3], [1e-6, 1e-6, 0]])
        C = _spd(rng, 9, [1e-4, 1e-4, 1, 1e-4, 1e-4, 1, 1e-7, 1e-7, 0])
        p = rng.uniform(0, 1000, 2)
        G = em.jac_hom(H, p)
        want = np.sqrt(np.linalg.eigvalsh(G @ C @ G.T)[-1])
        assert abs(em.transferred_sigma(H, C, p) - want) <= 1e-9 * want


def test_relative_confidence_median_equals_numpy():
    from mata_eval_plugins.estimators.homography_ekf import relative_confidence

    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 50, 99, 100):
        hist = tuple(rng.uniform(0.05, 1.0, n).tolist())
        c = float(rng.uniform(0.01, 1.0))
        assert relative_confidence(hist, c) == float(min(1.0, c / float(np.median(hist))))
