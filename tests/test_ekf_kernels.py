"""Block C's compiled tick (numba, ekf_kernels.py) equals the numpy reference (ekf_math and
HomographyEKF._tick_state) to rounding, and the filter runs without numba."""

from __future__ import annotations

import dataclasses
import pickle
import sys

import numpy as np
import pytest

from mata_eval.types import Box, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators.homography_ekf import CONFIDENCE_HISTORY, HomographyEKF

P = HomographyEKF.Params
FPS = 30.0
numba = pytest.importorskip("numba", reason="the compiled tick needs the `fast` extra (numba)")
from mata_eval_plugins.estimators import ekf_kernels  # noqa: E402  (needs numba)


def scenario(seed: int, n: int = 90, delay: bool = False, box_every: int = 2):
    """Per tick: (t, motions, detections). A rolling, zooming, panning camera with measured
    covariances and every kind of input the filter has to survive: boxes of varying confidence
    (some rejected by the confidence gates; ties in the relative gate's history; NaN, infinite
    and negative confidences), far outliers (chi2 inflation), invalid boxes (NaN, a NaN or
    infinite corner, zero width), invalid motions (flag, NaN, h33 = 0, a plane behind the
    camera, an absurd H that overflows), covariances too large for tau_sigma, two motions in one
    tick (composition), two boxes in one tick, and with ``delay`` boxes that arrive late."""
    rng = np.random.default_rng(seed)
    box = np.array([300.0, 200.0, 340.0, 230.0])
    ticks, pending = [], []
    for k in range(1, n):
        t = k / FPS
        a, s = rng.normal(0, 0.01), 1.0 + rng.normal(0, 0.004)
        H = np.array([[s * np.cos(a), -s * np.sin(a), rng.normal(3.0, 2.0)],
                      [s * np.sin(a), s * np.cos(a), rng.normal(-1.0, 2.0)],
                      [rng.normal(0, 1e-6), rng.normal(0, 1e-6), 1.0]])
        cov = np.diag(np.abs(rng.normal(0, [1e-7, 1e-7, 1e-2, 1e-7, 1e-7, 1e-2, 1e-13, 1e-13, 0.0])))
        if k % 11 == 0:
            cov = cov * 1e6                                     # tau_sigma rejects it
        kind = k % 17
        motion = Motion(H, None if k % 5 == 0 else cov, valid=kind != 3)
        if kind == 6:
            motion = Motion(np.full((3, 3), np.nan), cov)
        elif kind == 9:
            motion = Motion(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 0.0]]), cov)
        elif kind == 12:
            motion = Motion(np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 1.0]]), cov)  # w < 0 at the box
        elif kind == 14:                                        # H / h33 overflows: the tick holds
            motion = Motion(np.array([[1e300, 0, 0], [0, 1.0, 0], [0, 0, 1e-11]]), None)
        motions = [Stamped(motion, t, t)]
        if k % 13 == 0:                                         # two intervals in one tick
            motions = [Stamped(Motion(H, cov), t - 0.5 / FPS, t - 0.5 / FPS), Stamped(Motion(H, cov), t, t)]
        box = box + np.array([H[0, 2], H[1, 2], H[0, 2], H[1, 2]]) + rng.normal(0, 0.5, 4)
        if k % box_every == 0:
            conf = round(float(np.clip(0.7 + 0.25 * rng.normal(), 0, 1)), 2) if k % 7 else 0.03  # R's floor
            if 64 <= k < 80:                                    # a gradual decline (follow_consistent)
                conf = round(0.8 ** (k - 62), 3)
            conf = {4: np.nan, 34: np.nan, 44: -0.2, 52: np.inf}.get(k, conf)  # 4: a NaN median
            z = box + rng.normal(0, 2.0, 4)
            if k % 19 == 0:
                z = z + 80.0                                    # far outlier: chi2 inflation
            if k % 23 == 0:
                z = np.full(4, np.nan)
            if k % 29 == 0:
                z[2] = z[0]                                     # zero width
            lag = rng.integers(0, 4) / FPS if delay else 0.0
            b = Box.from_corners(*z)
            b = {56: Box(np.nan, b.y, b.w, b.h), 62: Box(b.x, np.inf, b.w, b.h)}.get(k, b)
            pending.append(Stamped(TrackerOutput(b, conf), t, t + lag))
            if k % 31 == 0:
                pending.append(Stamped(TrackerOutput(Box.from_corners(*(z + 1.0)), 0.9), t, t + lag))
        dets = [d for d in pending if d.t_publish <= t + 1e-9]
        pending = [d for d in pending if d.t_publish > t + 1e-9]
        ticks.append((t, motions, dets))
    return ticks


def run(est: HomographyEKF, ticks) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (with the search centre fed back, NaN when withheld) and covariances."""
    out = [est.initialize(Box(300.0, 200.0, 40.0, 30.0), 0.0)]
    for t, motions, dets in ticks:
        out.append(est.step(t, motions, dets))
    boxes = [tuple(e.box.as_array()) + (e.prior or (np.nan, np.nan)) for e in out]
    return np.array(boxes), np.array([e.cov for e in out])


CASES = [dict(), dict(delay="compensate"), dict(delay="ignore"), dict(h_update="after_predict"),
         dict(model="ca"), dict(model="cj"), dict(gating=False), dict(camera=False),
         dict(box_motion="corners"), dict(box_motion="centre"),
         dict(feedback_carry=True, feedback_shift=0.25), dict(feedback_hold=True), dict(q_adapt=True), dict(q_adapt=False),
         dict(q_adapt=True, chi2_gate=0.0, follow_consistent=False), dict(follow_consistent=False),
         dict(follow_consistent=True, chi2_gate=18.47),     # (follow_consistent reads chi2_gate: > 0)
         dict(follow_consistent=True, chi2_gate=18.47, gate="absolute", tau_diff=0.5)]


def skip_while_the_kernel_lags() -> None:
    """A new filter parameter not yet in the kernel: the filter runs numpy meanwhile (auto), and
    the tests of the compiled path say so instead of failing the suite of whoever added it."""
    missing = {f.name for f in dataclasses.fields(P)} - ekf_kernels.IMPLEMENTS
    if missing:
        pytest.skip(f"ekf_kernels does not implement {sorted(missing)} yet")


@pytest.mark.parametrize("preset", ["mata", "paper"])
@pytest.mark.parametrize("case", CASES, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()) or "preset")
def test_compiled_tick_equals_the_numpy_reference(preset, case):
    skip_while_the_kernel_lags()
    for seed in range(3):
        ticks = scenario(seed, delay=seed > 0)
        ref = HomographyEKF(P(preset=preset, **case), backend="numpy")
        ref_boxes, ref_covs = run(ref, ticks)
        est = HomographyEKF(P(preset=preset, **case), backend="numba")
        boxes, covs = run(est, ticks)
        assert np.all(np.isfinite(boxes[:, :4]))
        assert np.array_equal(np.isnan(boxes), np.isnan(ref_boxes))
        assert np.nanmax(np.abs(boxes - ref_boxes)) <= 1e-9     # px
        assert np.abs(covs - ref_covs).max() <= 1e-9 * max(1.0, np.abs(ref_covs).max())
        assert_same_gate(est, ref)


def assert_same_gate(est: HomographyEKF, ref: HomographyEKF) -> None:
    """The compiled gate memory reads as the reference's: exactly, but for the innovation
    average (rounding)."""
    gate, ref_gate = est.state.gate, ref.state.gate
    assert ((gate.ewma, gate.n_used, gate.following, gate.used_relative)
            == (ref_gate.ewma, ref_gate.n_used, ref_gate.following, ref_gate.used_relative))
    for field in ("accepted", "ranked"):    # NaN where gating is off (a NaN confidence is used)
        np.testing.assert_array_equal(getattr(gate, field), getattr(ref_gate, field), field)
    assert gate.nis == pytest.approx(ref_gate.nis, rel=1e-12)


@pytest.mark.parametrize("preset", ["mata", "paper"])
def test_the_relative_gate_history_rolls_over_alike(preset):
    """Past CONFIDENCE_HISTORY accepted boxes the oldest leaves the compiled history as it
    leaves the reference's (a box every tick, some late: replays re-run the history)."""
    skip_while_the_kernel_lags()
    ticks = scenario(3, n=160, delay=True, box_every=1)
    ref = HomographyEKF(P(preset=preset, gate="relative"), backend="numpy")
    ref_boxes, _ = run(ref, ticks)
    assert ref.state.gate.n_used > len(ref.state.gate.accepted) == CONFIDENCE_HISTORY
    est = HomographyEKF(P(preset=preset, gate="relative"), backend="numba")
    boxes, _ = run(est, ticks)
    assert np.nanmax(np.abs(boxes - ref_boxes)) <= 1e-9
    assert_same_gate(est, ref)


def test_the_scenario_exercises_what_it_claims():
    """The degenerate inputs above do reach the filter's guards (else the equality is vacuous)."""
    est = HomographyEKF(P(preset="mata"), backend="numpy")
    ticks = scenario(0)
    est.initialize(Box(300.0, 200.0, 40.0, 30.0), 0.0)
    held = used = 0
    for t, motions, dets in ticks:
        before = est.state
        est.step(t, motions, dets)
        held += est.state.x is before.x
        used += est.state.gate.n_used - before.gate.n_used
    n_dets = sum(len(d) for _, _, d in ticks)
    assert held >= 3                      # the overflowing H holds its tick (k = 14, 31, 48, ...)
    assert 0 < used < n_dets              # some boxes used, some rejected (NaN, zero width, gate)
    level = HomographyEKF(P(preset="mata", follow_consistent=False), backend="numpy")
    run(level, ticks)                     # the decline's boxes: follow_consistent spares some
    assert est.state.gate.n_used > level.state.gate.n_used


def test_backend_choice(monkeypatch):
    # the choice itself, whatever parameters the kernel covers today (a new filter parameter
    # falls back to numpy, and the comparison above says so; it must not fail this test)
    monkeypatch.setattr(ekf_kernels, "IMPLEMENTS", frozenset(f.name for f in dataclasses.fields(P)))
    monkeypatch.delenv("MATA_EVAL_EKF_BACKEND", raising=False)
    assert HomographyEKF(P(preset="mata"))._kernel is ekf_kernels.tick  # auto: numba for mata
    assert HomographyEKF(P(preset="paper"))._kernel is None            # auto: the reference for paper
    assert HomographyEKF(P(preset="paper"), backend="numba")._kernel is ekf_kernels.tick
    monkeypatch.setenv("MATA_EVAL_EKF_BACKEND", "numpy")
    assert HomographyEKF(P(preset="mata"))._kernel is None
    monkeypatch.setenv("MATA_EVAL_EKF_BACKEND", "fortran")
    with pytest.raises(ValueError, match="MATA_EVAL_EKF_BACKEND.*'fortran'"):
        HomographyEKF()


def test_a_filter_on_the_compiled_path_pickles_and_goes_on_alike():
    skip_while_the_kernel_lags()
    ticks = scenario(2, n=40)
    est = HomographyEKF(P(preset="mata"), backend="numba")
    run(est, ticks[:20])
    twin = pickle.loads(pickle.dumps(est))
    for t, motions, dets in ticks[20:]:
        a, b = est.step(t, motions, dets), twin.step(t, motions, dets)
        assert a.box == b.box and np.array_equal(a.cov, b.cov)


def test_a_parameter_the_kernel_does_not_implement_falls_back_to_numpy(monkeypatch):
    monkeypatch.setattr(ekf_kernels, "IMPLEMENTS", frozenset(f.name for f in dataclasses.fields(P)) - {"q_v"})
    assert HomographyEKF(P(preset="mata"))._kernel is None
    with pytest.raises(ValueError, match=r"does not implement \['q_v'\]"):
        HomographyEKF(P(preset="mata"), backend="numba")


class TenfoldR(HomographyEKF):
    """A subclass with its own measurement noise (a plugin author's override)."""

    def _box_noise(self, x, relative_conf):
        return 10.0 * super()._box_noise(x, relative_conf)


def test_a_subclass_overriding_a_tick_method_runs_it_on_either_backend_or_is_refused(monkeypatch):
    """QA pass: a subclass's _box_noise was silently ignored on the numba path (the kernel
    computes R itself); auto now runs such a subclass on numpy, and numba is refused."""
    monkeypatch.delenv("MATA_EVAL_EKF_BACKEND", raising=False)
    ticks = scenario(0, n=40)
    plain, _ = run(HomographyEKF(P(preset="mata"), backend="numpy"), ticks)
    ref, _ = run(TenfoldR(P(preset="mata"), backend="numpy"), ticks)
    assert np.nanmax(np.abs(ref - plain)) > 1.0          # the override changes the estimates
    auto = TenfoldR(P(preset="mata"))
    assert auto._kernel is None
    boxes, _ = run(auto, ticks)
    np.testing.assert_array_equal(boxes, ref)
    with pytest.raises(ValueError, match=r"backend numba .* would ignore the subclass's _box_noise; use backend numpy"):
        TenfoldR(P(preset="mata"), backend="numba")


def test_the_filter_runs_without_numba(monkeypatch):
    """Without numba (a core install) the numpy path runs; asking for numba says what to install."""
    monkeypatch.delenv("MATA_EVAL_EKF_BACKEND", raising=False)
    monkeypatch.setitem(sys.modules, "numba", None)   # `import numba` raises ImportError
    monkeypatch.delitem(sys.modules, "mata_eval_plugins.estimators.ekf_kernels")
    monkeypatch.delattr(sys.modules["mata_eval_plugins.estimators"], "ekf_kernels")
    est = HomographyEKF()
    assert est._kernel is None
    boxes, _ = run(est, scenario(0, n=20))
    assert np.all(np.isfinite(boxes[:, :4]))
    with pytest.raises(ImportError, match=r"pip install 'mata-eval\[fast\]'"):
        HomographyEKF(backend="numba")


def test_without_a_writable_cache_directory_the_kernel_compiles_quietly(monkeypatch, recwarn):
    """A read-only install with no writable user cache: numba finds no cache locator; the
    kernels then compile per process, without a warning."""
    from numba.core import caching

    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])
    add = ekf_kernels._njit(lambda a: a + 1.0)
    assert add(1.0) == 2.0
    assert isinstance(add._cache, caching.NullCache)
    assert not [w for w in recwarn if "cache" in str(w.message).lower()]


@pytest.mark.parametrize("history", [(), (0.5,), (0.2, 0.6), (0.0, 0.0, 0.4), (0.1, 0.3, 0.7, 0.9),
                                     (0.3, float("nan"), 0.8), tuple(np.linspace(0.05, 1.0, CONFIDENCE_HISTORY))])
def test_the_compiled_gate_reads_a_relative_confidence_as_the_python_gate(history):
    """The kernel's relative confidence, on the packed history, equals relative_confidence on
    the same ranked history, NaN medians included."""
    from mata_eval_plugins.estimators.homography_ekf import relative_confidence

    ranked = tuple(sorted(history, key=lambda v: (v != v, v)))   # NaN last, as a sorted history can hold
    g = ekf_kernels.new_gate(CONFIDENCE_HISTORY)
    m = (len(g) - ekf_kernels.G_ACCEPTED) // 2
    g[ekf_kernels.G_N_ACC] = len(ranked)
    g[ekf_kernels.G_ACCEPTED + m:ekf_kernels.G_ACCEPTED + m + len(ranked)] = ranked
    for c in (0.0, -0.1, 0.05, 0.3, 0.45, 0.9, 1.0, 2.0, float("nan"), float("inf")):
        want = relative_confidence(ranked, c, ranked=True)
        got = ekf_kernels._relative_confidence(g[ekf_kernels.G_ACCEPTED + m:], len(ranked), c)
        assert np.array_equal(got, want, equal_nan=True), (history, c, got, want)


def test_the_filter_is_compiled_when_built_not_in_its_first_tick():
    """Loading the compiled tick (0.3 s from the cache, 12-17 s to compile) happens when the
    filter is built, with the argument types of every tick, so no timed tick pays it (QA pass:
    the first frame's estimator time held it, 10.7 s, and the run's estimator rate looked a
    sixth of the numpy path's)."""
    import subprocess

    code = ("from mata_eval_plugins.estimators import ekf_kernels as k\n"
            "from mata_eval_plugins.estimators.homography_ekf import HomographyEKF as F\n"
            "before = len(k.tick.signatures); F(F.Params(), backend='numba'); print(before, len(k.tick.signatures))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["0", "1"]                  # a fresh process: compiled (or loaded) by the constructor
    f = HomographyEKF(HomographyEKF.Params(), backend="numba")
    f.initialize(Box(10.0, 10.0, 20.0, 20.0), 0.0)
    H = np.eye(3)
    f.step(0.1, [Stamped(Motion(H, np.eye(9) * 1e-6), 0.1, 0.1)], [Stamped(TrackerOutput(Box(11, 10, 20, 20), 0.9), 0.1, 0.1)])
    f.step(0.2, [Stamped(Motion(H), 0.2, 0.2)], [])
    f.step(0.3)
    assert len(ekf_kernels.tick.signatures) == 1     # the same compiled function served every tick
