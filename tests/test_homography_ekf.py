"""Homography EKF (block C): math against independent references (numerical differentiation,
filterpy, Monte Carlo), gating against hand-computed timelines, robustness."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from mata_eval.params import build_params
from mata_eval.core.errors import ConfigError
from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators import ekf_math as em
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF, confidence_gate

P = HomographyEKF.Params
DT = 1 / 30


def random_h(rng: np.random.Generator) -> np.ndarray:
    """A mild projective inter-frame homography (zoom, rotation, shift, perspective)."""
    H = np.eye(3) + rng.normal(0.0, [[1e-2, 1e-2, 3.0], [1e-2, 1e-2, 3.0], [1e-5, 1e-5, 0.0]])
    return H / H[2, 2]


def random_state(rng: np.random.Generator, n_deriv: int) -> np.ndarray:
    tl = rng.uniform(100, 500, 2)
    br = tl + rng.uniform(20, 80, 2)
    return np.concatenate([tl, br, random_h(rng).reshape(9), rng.normal(0, 60, 2 * n_deriv)])


def numerical_jacobian(f, x: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        h = 1e-9 if i in (10, 11) else 1e-6 * max(1.0, abs(x[i]))  # h31, h32 are ~1e-5
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        cols.append((f(xp) - f(xm)) / (2 * h))
    return np.stack(cols, axis=1)


# --- Jacobians ---------------------------------------------------------------------------------

@pytest.mark.parametrize("n_deriv", [1, 2, 3])
def test_transition_jacobian_matches_numerical_differentiation(n_deriv):
    rng = np.random.default_rng(n_deriv)
    for _ in range(5):
        x = random_state(rng, n_deriv)
        fx, F = em.transition(x, DT, n_deriv)
        N = numerical_jacobian(lambda v: em.transition(v, DT, n_deriv)[0], x)
        assert F.shape == (em.state_dim(n_deriv),) * 2
        np.testing.assert_allclose(F, N, rtol=1e-5, atol=1e-6 * np.abs(F).max())


def test_projection_jacobians_match_numerical_differentiation():
    rng = np.random.default_rng(7)
    H, p = random_h(rng), np.array([321.0, 123.0])
    Jp = numerical_jacobian(lambda q: em.project(H, q), p)
    np.testing.assert_allclose(em.jac_point(H, p), Jp, rtol=1e-7, atol=1e-8)
    Jh = numerical_jacobian(lambda h: em.project(h.reshape(3, 3), p), H.reshape(9))
    np.testing.assert_allclose(em.jac_hom(H, p), Jh, rtol=1e-5, atol=1e-9)


def test_transition_is_the_paper_model_for_a_pure_translation():
    """H = translation (tx, ty): corners shift by t + v dt, velocity unchanged (J_g = I)."""
    H = np.array([[1.0, 0, 5.0], [0, 1.0, -3.0], [0, 0, 1.0]])
    x = np.concatenate([[10, 20, 50, 60], H.reshape(9), [30.0, -60.0]])
    fx, _ = em.transition(x, 0.1, 1)
    np.testing.assert_allclose(fx[:4], [10 + 5 + 3, 20 - 3 - 6, 50 + 5 + 3, 60 - 3 - 6])
    np.testing.assert_allclose(fx[13:], [30.0, -60.0])
    # constant acceleration: p += v dt + a dt^2 / 2, v += a dt
    xa = np.concatenate([x, [100.0, 200.0]])
    fa, _ = em.transition(xa, 0.1, 2)
    np.testing.assert_allclose(fa[:2], [10 + 5 + 3 + 0.5, 20 - 3 - 6 + 1.0])
    np.testing.assert_allclose(fa[13:], [30 + 10, -60 + 20, 100, 200])


# --- filterpy cross-check -----------------------------------------------------------------------

class _FilterpyEKF(ExtendedKalmanFilter):
    """filterpy's EKF with a nonlinear f: predict() uses F for P and our f(x) for x
    (MODELS.md section 5, pitfall 3)."""

    fx: np.ndarray

    def predict_x(self, u=0):
        self.x = self.fx.copy()


def _close(a_x, a_P, b_x, b_P, rtol=1e-9):
    sd = np.sqrt(np.diag(b_P))
    assert np.all(np.abs(a_x - b_x) <= rtol * np.maximum(np.abs(b_x), sd)), np.abs(a_x - b_x).max()
    scale = np.outer(sd, sd)
    assert np.all(np.abs(a_P - b_P) <= rtol * scale), (np.abs(a_P - b_P) / scale).max()


@pytest.mark.parametrize("model,preset", [("cv", "paper"), ("ca", "paper"), ("cj", "paper"),
                                          ("cv", "mata"), ("ca", "mata")])
def test_every_step_matches_filterpy(model, preset):
    """Seeded run: each H update, predict and corner update of the plugin equals filterpy's
    ExtendedKalmanFilter given the same F, Q, H, R (relative 1e-9); under the mata preset Q and
    R follow the box size (the plugin's own noise functions give them)."""
    rng = np.random.default_rng(42)
    est = HomographyEKF(P(model=model, gating=False, preset=preset, follow_prior=0.0, velocity_decay_s=0.0,
                          q_adapt=False))
    box0 = Box(200.0, 150.0, 40.0, 30.0)
    est.initialize(box0, 0.0)
    n = est.state.x.size
    ref = _FilterpyEKF(dim_x=n, dim_z=4)
    ref.x, ref.P = est.state.x.copy(), est.state.P.copy()
    mine_x, mine_P = ref.x.copy(), ref.P.copy()
    Hb, Hh = em.selector(n, em.CORNERS), em.selector(n, em.HOM)
    box_motion = est.params.box_motion
    truth = np.array(box0.corners())
    for k in range(1, 60):
        H = random_h(rng)
        C = np.diag(rng.uniform(0.5, 2.0, 9) * [1e-6, 1e-6, 1e-2, 1e-6, 1e-6, 1e-2, 1e-12, 1e-12, 0])
        truth = np.concatenate([em.project(H, truth[:2]), em.project(H, truth[2:])]) + [2, 1, 2, 1]
        motions = [Stamped(Motion(H, C), k * DT, k * DT)] if rng.random() < 0.8 else []
        dets = []
        if k % 3 == 0:
            z = truth + rng.normal(0, 1.0, 4)
            dets = [Stamped(TrackerOutput(Box.from_corners(*z), 0.9), k * DT, k * DT)]
        est.step(k * DT, motions, dets)

        if motions:
            R = em.floored(C, est._h_floor)
            ref_x0, ref_P0 = ref.x.copy(), ref.P.copy()
            ref.update(H.reshape(9), lambda x: Hh, lambda x: Hh @ x, R=R)
            mine_x, mine_P = em.joseph_update_block(mine_x, mine_P, H.reshape(9), em.HOM, R)
            gx, gP = em.joseph_update(ref_x0, ref_P0, H.reshape(9), Hh, R)
            _close(mine_x, mine_P, ref.x, ref.P)
            _close(gx, gP, ref.x, ref.P)
        q = np.diag(est._process_noise(ref.x) * DT)
        fx, F = em.transition(ref.x, DT, est.n_deriv, box_motion)
        ref.F, ref.Q, ref.fx = F, q, fx
        ref.predict()
        mine_x, mine_P = fx, em.predict_cov(mine_P, F, q)
        _close(mine_x, mine_P, ref.x, ref.P)
        if dets:
            z = np.array(dets[0].value.box.corners())
            R = est._box_noise(ref.x, 1.0)   # constant confidence: relative confidence 1
            ref_x0, ref_P0 = ref.x.copy(), ref.P.copy()
            ref.update(z, lambda x: Hb, lambda x: Hb @ x, R=R)
            mine_x, mine_P = em.joseph_update_block(mine_x, mine_P, z, em.CORNERS, R)
            gx, gP = em.joseph_update(ref_x0, ref_P0, z, Hb, R)
            _close(mine_x, mine_P, ref.x, ref.P)
            _close(gx, gP, ref.x, ref.P)
        _close(est.state.x, est.state.P, ref.x, ref.P)


# --- gating -----------------------------------------------------------------------------------

def test_confidence_gate_follows_hand_computed_ewma_timeline():
    # alpha 0.5, tau_ewma 0.4, tau_diff 0.15
    conf = [0.9, 0.9, 0.5, 0.1, 0.3, 0.3, 0.3]
    # S: 0.9, 0.9, 0.7, 0.4, 0.35, 0.325, 0.3125
    # S - P: 0, 0, 0.2 (>0.15 drop), 0.3 (drop), 0.05 (S < 0.4), 0.025 (S < 0.4), 0.0125 (S < 0.4)
    want_s = [0.9, 0.9, 0.7, 0.4, 0.35, 0.325, 0.3125]
    want_ok = [True, True, False, False, False, False, False]
    s = None
    for c, ws, wok in zip(conf, want_s, want_ok):
        s, ok = confidence_gate(s, c, 0.5, 0.4, 0.15)
        assert s == pytest.approx(ws) and ok is wok
    assert confidence_gate(0.8, float("nan"), 0.5, 0.4, 0.15) == (0.8, False)


def _det(box: Box, conf: float, t: float) -> Stamped[TrackerOutput]:
    return Stamped(TrackerOutput(box, conf), t, t)


def _run_dets(params, confs_boxes):
    est = HomographyEKF(params)
    est.initialize(Box(100, 100, 40, 40), 0.0)
    out = []
    for k, (conf, box) in enumerate(confs_boxes, start=1):
        out.append(est.step(k * DT, (), [_det(box, conf, k * DT)] if box is not None else ()))
    return out


def test_gating_rejects_a_sudden_confidence_drop_and_a_low_average():
    good = Box(101, 100, 40, 40)
    far = Box(300, 300, 40, 40)
    seq = [(0.9, good)] * 5 + [(0.2, far)]
    gated = _run_dets(P(preset="paper"), seq)
    without = _run_dets(P(preset="paper"), [(0.9, good)] * 5 + [(0.9, None)])
    # the dropped measurement is a no-op: same estimate as if it never came
    assert gated[-1].box == without[-1].box
    ungated = _run_dets(P(preset="paper", gating=False), seq)
    assert ungated[-1].box.cx > gated[-1].box.cx + 50
    # a low confidence throughout: nothing is used, the box stays where it was initialised
    low = _run_dets(P(preset="paper"), [(0.1, far)] * 6)
    assert low[-1].box.center == pytest.approx((120.0, 120.0))


def test_motion_gate_uses_tau_sigma_on_the_transferred_covariance():
    H = np.array([[1.0, 0, 10.0], [0, 1.0, 0], [0, 0, 1.0]])
    box = Box(100, 100, 40, 40)
    # translation std 5 px moves the centre by 5 px (> tau_sigma = 2): rejected, H held (identity)
    big = np.diag([0, 0, 25.0, 0, 0, 25.0, 0, 0, 0])
    small = np.diag([0, 0, 0.01, 0, 0, 0.01, 0, 0, 0])
    assert em.transferred_sigma(H, big, np.array([120.0, 120.0])) == pytest.approx(5.0)
    for cov, shift in ((big, 0.0), (small, 10.0)):
        est = HomographyEKF(P(p0_v=1e-6, follow_prior=0.0))
        est.initialize(box, 0.0)
        e = est.step(DT, [Stamped(Motion(H, cov), DT, DT)])
        assert e.box.cx == pytest.approx(120.0 + shift, abs=0.05)
    # without thresholds the uncertain homography is used
    est = HomographyEKF(P(p0_v=1e-6, gating=False, follow_prior=0.0))
    est.initialize(box, 0.0)
    assert est.step(DT, [Stamped(Motion(H, big), DT, DT)]).box.cx > 125.0


def test_invalid_or_degenerate_motion_does_not_raise_and_holds_h():
    est = HomographyEKF()
    est.initialize(Box(100, 100, 40, 40), 0.0)
    shift = np.array([[1.0, 0, 6.0], [0, 1.0, 0], [0, 0, 1.0]])
    est.step(DT, [Stamped(Motion(shift, None), DT, DT)])
    h_before = est.state.x[em.HOM].copy()
    bad = [Motion.invalid(), Motion(np.full((3, 3), np.nan)), Motion(np.zeros((3, 3))),
           Motion(np.eye(3), np.full((9, 9), np.inf)), Motion(np.ones((2, 2))),
           Motion(np.array([[1.0, 0, 0], [0, 1, 0], [-1.0, 0, 1]])),  # maps the box behind the camera
           Motion(np.diag([1e300, 1e300, 1.0]))]  # finite but overflows the prediction
    for k, m in enumerate(bad, start=2):
        e = est.step(k * DT, [Stamped(m, k * DT, k * DT)])
        assert e.box.is_valid
        np.testing.assert_allclose(est.state.x[em.HOM], h_before, atol=1e-9)


def test_camera_false_forces_identity():
    est = HomographyEKF(P(camera=False, p0_v=1e-6))
    est.initialize(Box(100, 100, 40, 40), 0.0)
    H = np.array([[1.0, 0, 10.0], [0, 1.0, 0], [0, 0, 1.0]])
    for k in range(1, 4):
        e = est.step(k * DT, [Stamped(Motion(H), k * DT, k * DT)],
                     [_det(Box(100 + k, 100, 40, 40), 0.9, k * DT)] if k == 2 else ())
    np.testing.assert_array_equal(est.state.x[em.HOM], np.eye(3).reshape(9))
    assert e.box.cx < 125


def test_p_stays_symmetric_positive_definite_over_a_long_random_run():
    """1500 ticks of a camera following a wandering target in a 1280x720 image: random
    homographies (10 % invalid, 20 % without covariance), detections at random rates,
    confidences and latencies (delay: compensate replays them)."""
    rng = np.random.default_rng(3)
    for model in ("cv", "cj"):
        est = HomographyEKF(P(model=model, delay="compensate"))
        truth = np.array([600.0, 340.0, 660.0, 390.0])
        est.initialize(Box.from_corners(*truth), 0.0)
        v = np.zeros(2)
        pending: list[Stamped[Motion]] = []
        errors = []
        for k in range(1, 1500):
            pull = 0.05 * (np.array([640.0, 360.0]) - 0.5 * (truth[:2] + truth[2:]))
            H = np.eye(3) + rng.normal(0.0, [[2e-3, 2e-3, 2.0], [2e-3, 2e-3, 2.0], [1e-7, 1e-7, 0.0]])
            H[:2, 2] += pull
            H /= H[2, 2]
            v = 0.95 * v + rng.normal(0.0, 1.0, 2)
            truth = np.concatenate([em.project(H, truth[:2]), em.project(H, truth[2:])]) + np.tile(v, 2)
            if rng.random() < 0.9:
                C = np.diag(10.0 ** rng.uniform(-1, 1, 9) * [1e-6, 1e-6, 1e-2, 1e-6, 1e-6, 1e-2, 1e-14, 1e-14, 0])
                m = Motion(H, C if rng.random() < 0.8 else None, valid=rng.random() < 0.9)
                pending.append(Stamped(m, k * DT, (k + int(rng.integers(0, 3))) * DT))
            motions = [m for m in pending if m.t_publish <= k * DT]
            pending = [m for m in pending if m.t_publish > k * DT]
            dets = []
            if rng.random() < 0.4:
                z = truth + rng.normal(0, 3.0, 4)
                lag = int(rng.integers(0, 4))
                dets = [Stamped(TrackerOutput(Box.from_corners(*z), float(rng.uniform(0, 1))), (k - lag) * DT, k * DT)]
            e = est.step(k * DT, motions, dets)
            errors.append(np.hypot(*(np.array(e.box.center) - 0.5 * (truth[:2] + truth[2:]))))
            Pk = est.state.P
            assert np.array_equal(Pk, Pk.T)
            assert np.linalg.eigvalsh(Pk)[0] > 0, (model, k)
            assert np.all(np.isfinite(est.state.x)) and e.box.is_valid
        assert np.mean(errors) < 30.0  # still on the 60x50 px target on average (sanity, not accuracy)


# --- composition of motions ----------------------------------------------------------------------

def test_compose_covariance_matches_monte_carlo():
    rng = np.random.default_rng(11)
    H1, H2 = random_h(rng), random_h(rng)
    s = np.array([1e-3, 1e-3, 0.5, 1e-3, 1e-3, 0.5, 1e-6, 1e-6, 0.0])
    C1, C2 = np.diag(s ** 2), np.diag((0.5 * s) ** 2)
    H, C = em.compose(H1, C1, H2, C2)
    expected = H2 @ H1
    np.testing.assert_allclose(H, expected / expected[2, 2])
    n = 20000
    h1 = H1.reshape(9) + rng.normal(size=(n, 9)) * s
    h2 = H2.reshape(9) + rng.normal(size=(n, 9)) * 0.5 * s
    prod = np.einsum("nij,njk->nik", h2.reshape(n, 3, 3), h1.reshape(n, 3, 3))
    samples = (prod / prod[:, 2:3, 2:3]).reshape(n, 9)
    mc = np.cov(samples.T)
    d = np.sqrt(np.diag(C)[:8])
    np.testing.assert_allclose(np.sqrt(np.diag(mc)[:8]) / d, 1.0, atol=0.05)
    assert np.diag(C)[8] == pytest.approx(0.0, abs=1e-20)


def test_motions_arriving_together_are_composed():
    """Two translations of 4 px arriving in one tick move the box by 8 px, not 4."""
    T = np.array([[1.0, 0, 4.0], [0, 1.0, 0], [0, 0, 1.0]])
    est = HomographyEKF(P(p0_v=1e-6, follow_prior=0.0))
    est.initialize(Box(100, 100, 40, 40), 0.0)
    e = est.step(DT, [Stamped(Motion(T), DT / 2, DT), Stamped(Motion(T), DT, DT)])
    assert e.box.cx == pytest.approx(128.0, abs=0.05)


# --- parameters -----------------------------------------------------------------------------------

def test_params_from_yaml_and_errors():
    p = build_params(P, {"model": "cj", "camera": False, "q_box": 2, "delay": "compensate"})
    assert p.model == "cj" and p.q_box == 2.0 and p.camera is False
    assert HomographyEKF(p)._p0.shape == (19, 19)
    with pytest.raises(ConfigError, match="model"):
        build_params(P, {"model": "cx"}, ("estimator",))
    with pytest.raises(ValueError, match="q_h.*9"):
        HomographyEKF(P(q_h=[1.0, 2.0]))
    with pytest.raises(ValueError, match="positive size"):
        HomographyEKF().initialize(Box(0, 0, 0, 10), 0.0)
    est = HomographyEKF()
    est.initialize(Box(0, 0, 10, 10), 1.0)
    with pytest.raises(ValueError, match="before the previous tick"):
        est.step(0.5)


# --- the ablation experiment file ------------------------------------------------------------------

def test_ablation_experiment_expands_to_the_seven_configurations_and_the_paper_row():
    import importlib.util
    from pathlib import Path

    from mata_eval.run.config import load_experiment
    from mata_eval.core.registry import load_registry

    reg = load_registry()
    needed = {"dataset": "synthetic", "tracker": "kcf", "egomotion": "grid_lk", "protocol": "eop"}
    missing = [f"{k} {n}" for k, n in needed.items() if n not in reg.names(k)]
    if importlib.util.find_spec("mata_eval.data.occlusion") is None:
        missing.append("mata_eval.data.occlusion")
    if missing:
        pytest.skip(f"plugins not installed yet: {', '.join(missing)}")
    exp = load_experiment(Path(__file__).resolve().parents[1] / "experiments" / "ablation.yaml")
    runs = {r.name: r for r in exp.runs}
    assert list(runs) == ["1-baseline", "2-mata", "3-score", "4-no-camera", "5-ca", "6-cj", "7-no-threshold",
                          "8-paper"]
    for name in ("1-baseline", "3-score"):
        assert runs[name].egomotion is None and runs[name].estimator is None
    est = {n: r.estimator.params for n, r in runs.items() if r.estimator is not None}
    assert est["2-mata"] == HomographyEKF.Params()  # the default preset, mata
    assert est["8-paper"] == HomographyEKF.Params(preset="paper")
    assert runs["4-no-camera"].egomotion is None and est["4-no-camera"].camera is False
    assert (est["5-ca"].model, est["6-cj"].model, est["7-no-threshold"].gating) == ("ca", "cj", False)
    assert all(r.protocol.name == "eop" and r.tracker.name == "kcf" for r in runs.values())
