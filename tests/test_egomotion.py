"""Block B plugins (grid_lk, features, identity): recovered homographies against the exact ones
of the synthetic sequences and of known warps, BoT-SORT's OpenCV pipeline as a reference for
`features`, degenerate input, real footage."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from mata_eval.data import synth
from mata_eval.core.errors import ConfigError
from mata_eval.core.interfaces import EgoMotion
from mata_eval.params import build_params
from mata_eval.core.registry import load_registry
from mata_eval_plugins.egomotion import homography_covariance as hc
from mata_eval_plugins.egomotion.features import FeatureLK
from mata_eval_plugins.egomotion import grid_lk
from mata_eval_plugins.egomotion.grid_lk import GridLK
from mata_eval_plugins.egomotion.identity import IdentityMotion

W, H = 320, 180


@pytest.fixture(scope="module")
def ground() -> np.ndarray:
    """A textured aerial frame (640x360) from the synthetic generator: the source of warps."""
    return synth.render_sequence(synth.make_spec(7, 2, 640, 360, scenario="cruise")).frames[0]


def warp(image: np.ndarray, Hm: np.ndarray) -> np.ndarray:
    return cv2.warpPerspective(image, Hm, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)


def about_centre(A: np.ndarray, w: int, h: int) -> np.ndarray:
    """The transform A applied about the image centre."""
    c = np.array([[1, 0, (w - 1) / 2], [0, 1, (h - 1) / 2], [0, 0, 1.0]])
    return c @ A @ np.linalg.inv(c)


def test_registry_lists_the_three_plugins() -> None:
    reg = load_registry()
    plugins = reg.plugins["egomotion"]
    for name, cls in (("grid_lk", GridLK), ("features", FeatureLK), ("identity", IdentityMotion)):
        assert plugins[name].cls is cls
        assert isinstance(cls(), EgoMotion)


@pytest.mark.parametrize("scenario", ["cruise", "manoeuvre", "crowd"])
def test_grid_lk_recovers_the_synthetic_homographies(scenario: str) -> None:
    r = synth.render_sequence(synth.make_spec(11, 10, W, H, scenario=scenario))
    m = GridLK()
    m.initialize(r.frames[0])
    errors = []
    for k in range(1, len(r.frames)):
        mo = m.estimate(r.frames[k])
        assert mo.valid, f"frame {k}"
        assert mo.H[2, 2] == 1.0 and mo.cov.shape == (9, 9) and mo.inliers >= 100
        errors.append(hc.corner_transfer_error(mo.H, r.homographies[k], W, H))
    assert np.mean(errors) < 0.3 and max(errors) < 1.0, errors


def test_grid_lk_survives_an_out_of_view_pan_and_recovers() -> None:
    """Quick pans beyond LK's reach give invalid motions (or accurate ones), never a wrong valid one."""
    r = synth.render_sequence(synth.make_spec(11, 12, W, H, scenario="outofview"))
    big = [k for k in range(1, 12)
           if np.linalg.norm(hc.project(r.homographies[k], [[W / 2, H / 2]]) - [W / 2, H / 2]) > 50]
    assert big, "the scenario should contain a quick pan"
    m = GridLK()
    m.initialize(r.frames[0])
    for k in range(1, len(r.frames)):
        mo = m.estimate(r.frames[k])
        if mo.valid:
            assert hc.corner_transfer_error(mo.H, r.homographies[k], W, H) < 1.0, f"frame {k}"
        else:
            assert k in big


def test_grid_lk_covariance_is_calibrated_on_synthetic_720p() -> None:
    """The squared transfer error of corners and centre, normalised by the covariance propagated
    to them, averages chi2(2)/2 = 1 when the covariance is right (0.99 on the 145-pair benchmark
    suite); here 3 seeds x 2 scenarios x 5 pairs."""
    W7, H7 = 1280, 720
    pts = np.array([[0, 0], [W7 - 1, 0], [W7 - 1, H7 - 1], [0, H7 - 1], [W7 / 2, H7 / 2]], float)
    z = []
    for seed in (1, 2, 3):
        for scenario in ("cruise", "crowd"):
            r = synth.render_sequence(synth.make_spec(seed, 6, W7, H7, scenario=scenario))
            m = GridLK()
            m.initialize(r.frames[0])
            for k in range(1, len(r.frames)):
                mo = m.estimate(r.frames[k])
                assert mo.valid
                J = hc.transfer_jacobian(mo.H, pts)
                d = hc.project(mo.H, pts) - hc.project(r.homographies[k], pts)
                z += [d[i] @ np.linalg.solve(J[i] @ mo.cov @ J[i].T, d[i]) / 2 for i in range(len(pts))]
    assert 0.5 < np.mean(z) < 2.0, np.mean(z)


@pytest.mark.parametrize("refit,method", [(True, "ransac"), (False, "ransac"), (True, "usac_fast"),
                                          (True, "usac_magsac")])
def test_robust_fit_recovers_an_exact_homography_through_outliers(refit: bool, method: str) -> None:
    """With the least-squares refit (default) and with RANSAC's own fit (``refit: false``, one
    fit per frame), and with the refit after OpenCV's USAC variants (whose own fit, not refined
    by Levenberg-Marquardt, is 3e-4 px off here): exact
    correspondences of a known H on a 16 x 16 grid of a 1280 x 720 frame, 30 % of them moved
    20-80 px, give H back to the precision of OpenCV's float32 points and exactly the untouched
    points as inliers."""
    rng = np.random.default_rng(3)
    src = grid_lk.grid_points(1280, 720, 16, 16).reshape(-1, 2).astype(float)
    Ht = about_centre(np.array([[1.02, 0.015, 4.3], [-0.01, 0.99, -2.7], [2e-5, -3e-5, 1.0]]), 1280, 720)
    dst = hc.project(Ht, src)
    out = rng.choice(len(src), 77, replace=False)
    dst[out] += rng.uniform(20, 80, (77, 2)) * rng.choice([-1.0, 1.0], (77, 2))
    mo = grid_lk.robust_fit(src, dst, image_size=(1280, 720), refit=refit, method=method)
    assert mo.valid and mo.inliers == len(src) - 77
    assert mo.H[2, 2] == 1.0
    assert hc.corner_transfer_error(mo.H, Ht, 1280, 720) < 1e-4  # float32 points: about 1e-5 px
    assert np.abs(mo.H / (Ht / Ht[2, 2]) - 1).max() < 1e-5
    assert mo.sigma < 1e-3 and np.all(np.isfinite(mo.cov))


def test_grid_lk_refit_and_method_options_reach_the_fit(ground: np.ndarray, monkeypatch) -> None:
    """``refit`` (default true) and ``ransac_method`` (default ransac) are what robust_fit gets,
    and the method what OpenCV gets; each way a known warp comes back."""
    h, w = ground.shape[:2]
    Ht = about_centre(np.array([[1.03, 0.02, 3.2], [-0.015, 0.98, -2.1], [4e-5, -6e-5, 1.0]]), w, h)
    seen, fit, find = [], grid_lk.robust_fit, cv2.findHomography
    flags = []
    monkeypatch.setattr(grid_lk, "robust_fit", lambda *a, **k: (seen.append((k["refit"], k["method"])), fit(*a, **k))[1])
    monkeypatch.setattr(cv2, "findHomography", lambda s, d, m=0, *a, **k: (flags.append(m), find(s, d, m, *a, **k))[1])
    for params in (GridLK.Params(), GridLK.Params(refit=False), GridLK.Params(ransac_method="usac_fast")):
        m = GridLK(params)
        m.initialize(ground)
        mo = m.estimate(warp(ground, Ht))
        assert mo.valid and hc.corner_transfer_error(mo.H, Ht, w, h) < 0.25
    assert seen == [(True, "ransac"), (False, "ransac"), (True, "usac_fast")]
    assert flags == [cv2.RANSAC, 0, cv2.RANSAC, cv2.USAC_FAST, 0]   # robust fit, then the refit


def test_usac_fits_the_affine_model_and_is_refused_where_opencv_has_none(ground: np.ndarray) -> None:
    """OpenCV's USAC estimates homographies and affine maps only: an affine warp comes back
    through it; a similarity or translation model with a USAC method is an error at load time
    that names the key, not a cv2 error on the first frame."""
    h, w = ground.shape[:2]
    Ht = about_centre(np.array([[1.03, 0.02, 3.2], [-0.015, 0.98, -2.1], [0.0, 0.0, 1.0]]), w, h)
    m = GridLK(GridLK.Params(model="affine", ransac_method="usac_magsac"))
    m.initialize(ground)
    mo = m.estimate(warp(ground, Ht))
    assert mo.valid and hc.corner_transfer_error(mo.H, Ht, w, h) < 0.25
    for model in ("similarity", "translation"):
        with pytest.raises(ValueError, match="ransac_method usac_fast needs model homography or affine"):
            GridLK.Params(model=model, ransac_method="usac_fast")


@pytest.mark.parametrize("model,A", [
    ("homography", np.array([[1.03, 0.02, 3.2], [-0.015, 0.98, -2.1], [4e-5, -6e-5, 1.0]])),
    ("affine", np.array([[1.03, 0.02, 3.2], [-0.015, 0.98, -2.1], [0.0, 0.0, 1.0]])),
    ("similarity", np.array([[1.02 * np.cos(0.03), -1.02 * np.sin(0.03), 2.7],
                             [1.02 * np.sin(0.03), 1.02 * np.cos(0.03), -1.6], [0.0, 0.0, 1.0]])),
    ("translation", np.array([[1.0, 0.0, 3.4], [0.0, 1.0, -2.6], [0.0, 0.0, 1.0]])),
])
@pytest.mark.parametrize("downscale", [1.0, 2.0])
def test_each_model_recovers_a_known_warp(ground: np.ndarray, model: str, A: np.ndarray,
                                          downscale: float) -> None:
    h, w = ground.shape[:2]
    Ht = about_centre(A, w, h)
    m = GridLK(GridLK.Params(model=model, downscale=downscale))
    m.initialize(ground)
    mo = m.estimate(warp(ground, Ht))
    assert mo.valid
    assert hc.corner_transfer_error(mo.H, Ht, w, h) < 0.25
    # entries outside the model are exactly fixed, and have zero variance
    free = np.abs(hc.tangent_basis(model)).sum(axis=1) > 0
    assert np.array_equal(mo.H.reshape(9)[~free], np.eye(3).reshape(9)[~free])
    if model == "similarity":
        assert mo.H[0, 0] == pytest.approx(mo.H[1, 1]) and mo.H[0, 1] == pytest.approx(-mo.H[1, 0])
    assert np.all(np.diag(mo.cov)[~free] == 0) and np.all(np.diag(mo.cov)[free] > 0)


def test_forward_backward_check_keeps_consistent_tracks_only(ground: np.ndarray) -> None:
    h, w = ground.shape[:2]
    shift = np.array([[1, 0, 2.3], [0, 1, 1.7], [0, 0, 1]])
    nxt = warp(ground, shift)
    nxt[100:220, 200:360] = np.roll(ground[100:220, 200:360], (9, -7), axis=(0, 1))  # a moving object
    results = {}
    for thr in (None, 0.5, 1e-4):
        m = GridLK(GridLK.Params(downscale=1.0, fb_threshold=thr))
        m.initialize(ground)
        results[thr] = m.estimate(nxt)
    assert results[None].valid and results[0.5].valid
    assert hc.corner_transfer_error(results[0.5].H, shift, w, h) < 0.1
    # LK round trips are not exact at sub-pixel shifts: a tiny threshold leaves too few points
    assert not results[1e-4].valid


def test_features_matches_botsort_opencv_pipeline(ground: np.ndarray) -> None:
    """BoT-SORT GMC sparseOptFlow written out with OpenCV calls (downscale 2, Shi-Tomasi corners,
    LK, estimateAffinePartial2D RANSAC, translation times 2) as the reference."""
    h, w = ground.shape[:2]
    Ht = about_centre(np.array([[0.99 * np.cos(-0.02), -0.99 * np.sin(-0.02), -2.2],
                                [0.99 * np.sin(-0.02), 0.99 * np.cos(-0.02), 1.3], [0, 0, 1.0]]), w, h)
    nxt = warp(ground, Ht)
    g0 = cv2.resize(cv2.cvtColor(ground, cv2.COLOR_BGR2GRAY), (w // 2, h // 2))
    g1 = cv2.resize(cv2.cvtColor(nxt, cv2.COLOR_BGR2GRAY), (w // 2, h // 2))
    kp = cv2.goodFeaturesToTrack(g0, 1000, 0.01, 1, blockSize=3, useHarrisDetector=False, k=0.04)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(g0, g1, kp, None)
    ok = st.reshape(-1) == 1
    M, _ = cv2.estimateAffinePartial2D(kp[ok], p1[ok], method=cv2.RANSAC)
    M[:, 2] *= 2
    ref = np.vstack([M, [0, 0, 1]])
    m = FeatureLK()
    m.initialize(ground)
    mo = m.estimate(nxt)
    assert mo.valid and mo.inliers > 50
    assert np.allclose(mo.H[2], [0, 0, 1]) and np.isclose(mo.H[0, 0], mo.H[1, 1]) and np.isclose(mo.H[0, 1], -mo.H[1, 0])
    assert hc.corner_transfer_error(mo.H, ref, w, h) < 0.5
    assert hc.corner_transfer_error(mo.H, Ht, w, h) < 0.5


@pytest.mark.parametrize("cls", [GridLK, FeatureLK])
def test_degenerate_input_gives_invalid_motion_not_an_exception(cls: type, ground: np.ndarray) -> None:
    blank = np.full_like(ground, 127)
    m = cls()
    assert not m.estimate(ground).valid  # before initialize
    m.initialize(ground)
    assert not m.estimate(blank).valid  # blank frame
    assert not m.estimate(ground).valid  # from a blank frame
    assert m.estimate(ground).valid  # recovers
    # too few points: texture only in a small patch, the rest uniform
    patch = blank.copy()
    patch[150:190, 300:340] = ground[150:190, 300:340]
    m.initialize(patch)
    mo = m.estimate(warp(patch, np.array([[1, 0, 1.0], [0, 1, 0.5], [0, 0, 1]])))
    assert not mo.valid and mo.inliers == 0 and np.array_equal(mo.H, np.eye(3))
    # not images, and a size change
    m.initialize(ground)
    for bad in (None, "frame.jpg", np.zeros((0, 0, 3), np.uint8), ground.astype(np.float32),
                np.zeros((4, 5, 6, 3), np.uint8), ground[:, :, :2]):
        assert not m.estimate(bad).valid
    m.initialize(ground)
    assert not m.estimate(ground[:200, :300]).valid
    m.initialize(ground[:40, :40])  # grid_lk: smaller than 2 px per grid cell after downscaling
    tiny = m.estimate(ground[1:41, 1:41])
    if cls is FeatureLK and tiny.valid:  # features have no such limit (it depends on the texture),
        c = tiny.H @ np.array([19.5, 19.5, 1.0])  # but a motion they report is the 1 px shift
        np.testing.assert_allclose(c[:2] / c[2], [18.5, 18.5], atol=0.5)  # (identity: 1 px off)
    else:
        assert tiny.valid is False
    m.initialize(ground[:, :, 0])  # a grey image is fine
    assert m.estimate(np.ascontiguousarray(ground[:, :, 0])).valid


def test_illumination_change_is_compensated(ground: np.ndarray) -> None:
    h, w = ground.shape[:2]
    shift = about_centre(np.array([[1.01, 0, 1.5], [0, 1.01, -0.5], [0, 0, 1]]), w, h)
    darker = cv2.convertScaleAbs(warp(ground, shift), alpha=0.6, beta=10)
    m = GridLK()
    m.initialize(ground)
    assert hc.corner_transfer_error(m.estimate(darker).H, shift, w, h) < 0.3


def test_identity_plugin() -> None:
    m = IdentityMotion()
    m.initialize(np.zeros((4, 4, 3), np.uint8))
    mo = m.estimate(np.zeros((4, 4, 3), np.uint8))
    assert mo.valid and np.array_equal(mo.H, np.eye(3)) and mo.cov is None


def test_params_are_validated_from_yaml_values() -> None:
    p = build_params(GridLK.Params, {"grid_cols": 8, "model": "affine", "fb_threshold": 1})
    assert p.grid_cols == 8 and p.model == "affine" and p.fb_threshold == 1.0
    for bad in ({"grid_cols": 1}, {"model": "projective"}, {"downscale": 0.5}, {"win_size": 20},
                {"fb_threshold": -1.0}, {"ransac_confidence": 1.5}):
        with pytest.raises(ConfigError):
            build_params(GridLK.Params, bad, path=("egomotion",))
    with pytest.raises(ConfigError):
        build_params(FeatureLK.Params, {"quality_level": 0.0})


def photometric_residual(prev: np.ndarray, cur: np.ndarray, Hm: np.ndarray) -> float:
    """Mean absolute grey difference between ``cur`` and ``prev`` warped by ``Hm``, over the
    pixels that the warp covers."""
    g0 = cv2.cvtColor(prev, cv2.COLOR_BGR2GRAY).astype(np.float32)
    g1 = cv2.cvtColor(cur, cv2.COLOR_BGR2GRAY).astype(np.float32)
    size = (g1.shape[1], g1.shape[0])
    warped = cv2.warpPerspective(g0, Hm, size)
    cover = cv2.warpPerspective(np.ones_like(g0), Hm, size, flags=cv2.INTER_NEAREST) > 0
    return float(np.mean(np.abs(warped - g1)[cover]))


def test_real_uav_footage_warp_reduces_the_photometric_residual(shared_data: Path) -> None:
    img = shared_data / "sequences" / "uav123_10fps" / "wakeboard10" / "img"
    frames = [cv2.imread(str(img / f"{k:06d}.jpg")) for k in range(40, 46)]
    m = GridLK()
    m.initialize(frames[0])
    for a, b in zip(frames, frames[1:]):
        mo = m.estimate(b)
        assert mo.valid and mo.inliers > 60 and 0.2 < mo.sigma < 3.0
        assert photometric_residual(a, b, mo.H) < 0.8 * photometric_residual(a, b, np.eye(3))


@pytest.mark.parametrize("cls", [GridLK, FeatureLK])
def test_a_repeated_picture_is_unchanged_a_moved_one_is_not(cls: type, ground: np.ndarray) -> None:
    # A repeated frame comes back through a lossy codec: block B finds the same picture
    # re-encoded as JPEG at quality 75 unchanged (on its grey images shrunk by 2), the picture
    # moved by the camera (1 px) not. Nor a still scene in which a 16 px square of contrast 64
    # moved 2 px: each of the two 16 px blocks its edges cross gains or loses a 2 x 16 px strip,
    # 2 * 16 * 64 / 16^2 = 8 grey levels on average (UNCHANGED_GREY is 4).
    jpeg75 = cv2.imdecode(cv2.imencode(".jpg", ground, [cv2.IMWRITE_JPEG_QUALITY, 75])[1], cv2.IMREAD_COLOR)
    moved = warp(ground, np.array([[1.0, 0, 1.0], [0, 1, 0], [0, 0, 1]]))
    m = cls()
    m.initialize(ground)
    assert m.estimate(jpeg75).unchanged and m.estimate(jpeg75).unchanged
    assert not m.estimate(moved).unchanged
    scene = np.full((384, 640), 100, np.uint8)   # 384 = 24 blocks of 16 px: block edges at 16 k
    before, after = scene.copy(), scene.copy()
    before[64:80, 64:80] = 164
    after[64:80, 66:82] = 164
    d = cv2.resize(cv2.absdiff(before, after).astype(np.float32), (40, 24), interpolation=cv2.INTER_AREA)
    assert d[4, 4] == d[4, 5] == 8.0 and np.count_nonzero(d) == 2
    assert not grid_lk.unchanged(before, after, grid_lk.UNCHANGED_CELL)
    assert grid_lk.unchanged(before, before, grid_lk.UNCHANGED_CELL)


def test_the_block_test_is_skipped_for_a_motion_that_moves_the_image() -> None:
    """flag_unchanged tests the blocks only while the fitted motion moves no image corner by
    UNCHANGED_MOVE px (a repeated picture gives LK no flow): on the same two images, the identity
    flags them, a 1 px pan (valid) does not, an invalid motion is tested."""
    from mata_eval.types import Motion

    img = np.full((180, 320), 90, np.uint8)
    pan = np.array([[1.0, 0, grid_lk.UNCHANGED_MOVE], [0, 1, 0], [0, 0, 1]])
    assert grid_lk.flag_unchanged(Motion.identity(), img, img, 2.0).unchanged
    assert not grid_lk.flag_unchanged(Motion(pan), img, img, 2.0).unchanged
    assert grid_lk.flag_unchanged(Motion.invalid(), img, img, 2.0).unchanged
    assert grid_lk.flag_unchanged(Motion(np.diag([1.001, 1.0, 1.0])), img, img, 2.0).unchanged  # < 1 px at 640 px


@pytest.mark.parametrize("model", ["homography", "affine", "similarity", "translation"])
def test_the_covariance_robust_fit_reports_matches_monte_carlo(model):
    """Through the whole robust fit (RANSAC's inliers, refit, covariance), not the formula alone:
    the variance of points mapped by the fitted motion over 400 noisy draws (0.7 px, 16 x 16 grid
    at 1280 x 720) against the reported covariance's, at the centre and two corners (QA pass:
    OpenCV's affine inlier mask dropped far true inliers and the reported variance was 2-3 times
    too small)."""
    from mata_eval_plugins.egomotion import homography_covariance as hc
    from mata_eval_plugins.egomotion.grid_lk import grid_points, robust_fit

    rng = np.random.default_rng(3)
    src = grid_points(1280, 720, 16, 16).reshape(-1, 2).astype(float)
    c, s = np.cos(0.02), np.sin(0.02)
    true = {"homography": [[1.01, 0.02, 12.0], [-0.015, 0.99, -7.0], [2e-5, -1e-5, 1.0]],
            "affine": [[1.01, 0.02, 12.0], [-0.015, 0.99, -7.0], [0, 0, 1.0]],
            "similarity": [[1.01 * c, -1.01 * s, 12.0], [1.01 * s, 1.01 * c, -7.0], [0, 0, 1.0]],
            "translation": [[1, 0, 12.0], [0, 1, -7.0], [0, 0, 1.0]]}[model]
    Ht = np.array(true)
    clean = hc.project(Ht, src)
    probes = np.array([[640.0, 360.0], [0.0, 0.0], [1279.0, 719.0]])
    mapped, covs, inliers = [], [], []
    for _ in range(400):
        m = robust_fit(src, clean + rng.normal(0, 0.7, clean.shape), model=model, image_size=(1280, 720))
        assert m.valid
        mapped.append(hc.project(m.H, probes))
        covs.append(m.cov)
        inliers.append(m.inliers)
    assert np.mean(inliers) > 0.998 * len(src)   # true points are kept (a 3 px error at 0.7 px noise: 1e-4)
    J = hc.transfer_jacobian(Ht, probes)
    reported = np.mean(covs, axis=0)
    ratio = [np.trace(np.cov(np.array(mapped)[:, i].T)) / np.trace(J[i] @ reported @ J[i].T) for i in range(3)]
    assert all(0.8 < r < 1.25 for r in ratio), ratio
