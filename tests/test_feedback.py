"""What MATA hands its tracker (paper L424): an estimate's ``feedback`` flag decides whether the
scheduler gives the tracker a search centre, ``search`` which one (default: the estimate's
centre). ``homography_ekf`` withholds it, with ``feedback_shift``, when it would not move the
tracker's search out of its own newest box (``feedback_hold``: only while that box is fresh and
confident), and with ``feedback_carry`` hands the tracker's own box moved by the predicted
motion; ``repeat_hold`` withholds it on a frame that repeats the previous picture. Checked on
hand-built timelines: camera pans of known size against the box, a world-still target whose
true position is known, a clip padded with repeated pictures."""

from __future__ import annotations


import numpy as np
import pytest

from mata_eval.core.sequence import Sequence
from mata_eval.run.scheduler import run_sequence
from mata_eval.types import Box, Estimate, Motion, Stamped, TrackerOutput
from mata_eval_plugins.estimators.homography_ekf import HomographyEKF
from mata_eval_plugins.protocols.eop import EOP
from mata_eval_plugins.protocols.ltp import LTP

BOX = Box(90.0, 95.0, 20.0, 10.0)  # centre (100, 100), 20 x 10 px
FPS = 30.0


def test_estimate_prior_is_its_centre_unless_withheld():
    assert Estimate(BOX).prior == (100.0, 100.0)
    assert Estimate(BOX, feedback=False).prior is None
    assert Estimate(BOX, search=(1.0, 2.0)).prior == (1.0, 2.0)
    assert Estimate(BOX, feedback=False, search=(1.0, 2.0)).prior is None


class FlagEstimator:
    """Estimate x = frame of the tick; withholds feedback at the frames in ``withhold``."""

    def __init__(self, withhold):
        self.withhold = set(withhold)

    def initialize(self, box, t):
        return Estimate(box)

    def step(self, t, motions=(), detections=()):
        k = round(t * FPS)
        return Estimate(Box(float(k), 0.0, 10.0, 10.0), feedback=k not in self.withhold)


class RecordingTracker:
    """Logs (frame seen, prior); its box never moves."""

    def __init__(self):
        self.calls = []

    def initialize(self, image, box):
        pass

    def track(self, image, prior=None):
        self.calls.append((int(image[0, 0, 0]), prior))
        return TrackerOutput(BOX, confidence=0.9)


def toy_sequence(n, fps=FPS):
    return Sequence("toy", np.tile(BOX.as_array(), (n, 1)), fps=fps,
                    loader=lambda k: np.full((480, 640, 3), k, np.uint8))


def test_scheduler_hands_no_prior_when_the_estimate_withholds_it():
    # EOP at 10 Hz: the tracker starts at frames 3, 6, 9 with the estimate of that frame (the
    # estimator ticks on every frame, before the tracker); frame 6's estimate withholds it.
    tracker = RecordingTracker()
    run_sequence(toy_sequence(12), tracker, None, FlagEstimator({6}), EOP(EOP.Params(tracker_hz=10.0)),
                 np.random.default_rng(0))
    assert [k for k, _ in tracker.calls] == [3, 6, 9]
    assert [p for _, p in tracker.calls] == [(8.0, 5.0), None, (14.0, 5.0)]


class PanEgoMotion:
    """The camera pans by ``pan[k]`` px in x between frames k-1 and k (a pure translation)."""

    def __init__(self, pan):
        self.pan = pan

    def initialize(self, image):
        pass

    def estimate(self, image):
        H = np.eye(3)
        H[0, 2] = self.pan.get(int(image[0, 0, 0]), 0.0)
        return Motion(H, cov=np.eye(9) * 1e-12)


class WorldStillTracker(RecordingTracker):
    """Returns the target where a world-still target is after the pans so far (exact box)."""

    def __init__(self, pan):
        super().__init__()
        self.pan = pan

    def track(self, image, prior=None):
        k = int(image[0, 0, 0])
        self.calls.append((k, prior))
        dx = sum(v for f, v in self.pan.items() if f <= k)
        return TrackerOutput(Box(BOX.x + dx, BOX.y, BOX.w, BOX.h), confidence=0.9)


PAN = {4: 15.0, 6: 15.0, 7: 5.0}  # camera pans (px) before frames 4, 6 and 7


def pan_calls(fps=FPS, **params) -> list:
    """The tracker's (frame, prior) calls on the LTP pan timeline (PAN, 8 frames at ``fps``, a
    target still in the world) with block C's paper preset and ``params``."""
    tracker = WorldStillTracker(PAN)
    est = HomographyEKF(HomographyEKF.Params(preset="paper", **params))
    run_sequence(toy_sequence(8, fps), tracker, PanEgoMotion(PAN), est, LTP(), np.random.default_rng(0))
    return tracker.calls


@pytest.mark.parametrize("shift, fed", [(0.0, [1, 2, 3, 4, 5, 6, 7]), (0.5, [4, 6])])
def test_a_pan_larger_than_half_the_box_is_fed_back_a_smaller_one_is_not(shift, fed):
    # LTP, camera still except pans of 15 px (0.75 of the 20 px box width) before frames 4 and 6
    # and of 5 px (0.25) before frame 7; the target is still in the world, so the estimate of
    # frame k (the camera motion up to k applied to the box of frame k-1) is the tracker's
    # newest box moved by the pan. With feedback_shift 0.5 only the 15 px pans move the search
    # out of that box; the paper (0) feeds every estimate back.
    calls = pan_calls(feedback_shift=shift)
    assert [k for k, p in calls if p is not None] == fed
    for k, p in calls:
        if p is not None:  # the prior is the estimate: the world-still target after the pans
            assert p[0] == pytest.approx(100.0 + sum(v for f, v in PAN.items() if f <= k), abs=0.5)
            assert p[1] == pytest.approx(100.0, abs=0.5)


@pytest.mark.parametrize("one_step", [False, True])
def test_the_reference_is_the_trackers_newest_box_by_capture_time(one_step):
    # A box that arrives late (captured at 0.1 s, after one captured at 0.2 s, in a later step
    # or later in the same step) is not where the tracker searches next: the shift is measured
    # from the box of 0.2 s, 30 px (1.5 box widths) from the initial box, which the estimate
    # follows.
    est = HomographyEKF(HomographyEKF.Params(feedback_shift=0.5))
    est.initialize(BOX, 0.0)
    newest = Box(BOX.x + 30.0, BOX.y, BOX.w, BOX.h)

    def det(box, t_capture):
        return Stamped(TrackerOutput(box, confidence=0.9), t_capture, 0.2)

    if one_step:
        outs = [est.step(0.2, (), [det(newest, 0.2), det(BOX, 0.1)])]
    else:
        outs = [est.step(0.2, (), [det(newest, 0.2)]), est.step(0.2, (), [det(BOX, 0.1)])]
    for out in outs:
        assert abs(out.box.cx - newest.cx) < 0.5 * BOX.w < abs(out.box.cx - BOX.cx)
        assert not out.feedback


@pytest.mark.parametrize("preset", ["paper", "mata"])
def test_carry_hands_the_trackers_box_moved_by_the_camera_not_the_smoothed_estimate(preset):
    # The filter starts 10 px left of a world-still target whose exact box the tracker returns
    # every frame while the camera pans 15 px per frame; with a large R (20 px std) the
    # estimate needs frames to reach the boxes. The truth at frame k is 100 + 15 k px. Carried,
    # the search centre is the previous exact box moved by the pan: within 2.5 px of the truth
    # (what is left is the velocity the filter infers from its own lag); the estimate is 9 px
    # off at frame 2 and 6 px at frame 3 (frame 1 has no box yet).
    pan = {k: 15.0 for k in range(1, 10)}
    start = Box(BOX.x - 10.0, BOX.y, BOX.w, BOX.h)
    seq = Sequence("toy", np.tile(start.as_array(), (10, 1)), fps=FPS,
                   loader=lambda k: np.full((480, 640, 3), k, np.uint8))
    errors = {}
    for carry in (False, True):
        tracker = WorldStillTracker(pan)
        still = {} if preset == "paper" else dict(follow_prior=0.0, velocity_decay_s=0.0, feedback_hold=False)
        est = HomographyEKF(HomographyEKF.Params(preset=preset, r_box=400.0, feedback_carry=carry, **still))
        run_sequence(seq, tracker, PanEgoMotion(pan), est, LTP(), np.random.default_rng(0))
        errors[carry] = [p[0] - (100.0 + 15.0 * k) for k, p in tracker.calls]
        assert all(abs(p[1] - 100.0) < 0.5 for _, p in tracker.calls)
    assert errors[False][0] == errors[True][0] == pytest.approx(-10.0, abs=0.5)  # no box yet at frame 1
    assert max(abs(e) for e in errors[True][1:]) < 2.5
    assert abs(errors[False][1]) > 8.0 and abs(errors[False][2]) > 5.0


def test_carry_only_a_box_the_filter_used():
    # At the tick of a box, the carried search centre is that box's centre (no motion since);
    # a box the gate rejects (confidence 0: "found nothing") is not carried: the estimate is.
    far = Box(BOX.x + 40.0, BOX.y, BOX.w, BOX.h)
    for confidence, search in ((0.9, far.center), (0.0, None)):
        est = HomographyEKF(HomographyEKF.Params(feedback_carry=True, feedback_hold=False))
        est.initialize(BOX, 0.0)
        out = est.step(0.1, (), [Stamped(TrackerOutput(far, confidence), 0.1, 0.1)])
        assert out.search == (pytest.approx(search) if search else None)
        assert out.prior == pytest.approx(search or out.box.center)


@pytest.mark.parametrize("hold, fps, fed", [(False, 30.0, [1, 2, 3, 4, 5, 6, 7]), (True, 30.0, [1, 4, 6]),
                                            (True, 20.0, [1, 4, 6]), (True, 10.0, [1, 2, 3, 4, 5, 6, 7])])
def test_hold_keeps_the_trackers_own_search_while_its_fresh_box_contains_the_estimate(hold, fps, fed):
    # The pan timeline above (15 px = 0.75 box before frames 4 and 6, 5 px before 7), LTP: from
    # frame 2 on the tracker's newest box is from the previous frame and confident, and the
    # estimate of frame k is that box moved by the pan; only the 15 px pans put it outside the
    # box, so with feedback_hold frames 2, 3, 5 and 7 search at their own box, as alone (frame
    # 1 has only the initial box, which the filter did not use: the estimate is handed over).
    # Fresh is at most HOLD_AGE_S = 0.05 s old: the previous frame at 30 or 20 fps, not at 10
    # fps, where every estimate is handed over.
    assert [k for k, p in pan_calls(fps, feedback_hold=hold) if p is not None] == fed


@pytest.mark.parametrize("preset", ["paper", "mata"])
def test_hold_hands_over_the_estimate_when_the_box_is_older_than_one_tick(preset):
    # EOP at 10 Hz with a one-period latency on a still camera: the tracker's box of frame k
    # arrives at k + 3, when the tracker starts again; it is three ticks old, so the estimate
    # (which contains nothing new here) is handed over at every call, where the deadband of
    # feedback_shift 0.5, which looks at the box only, withholds every one.
    n = 13
    for params, want in ((dict(feedback_hold=True), [True] * 3), (dict(feedback_shift=0.5), [False] * 3)):
        tracker = WorldStillTracker({})
        est = HomographyEKF(HomographyEKF.Params(preset=preset, **params))
        run_sequence(toy_sequence(n), tracker, PanEgoMotion({}), est, EOP(EOP.Params(tracker_hz=10.0)),
                     np.random.default_rng(0))
        assert [k for k, _ in tracker.calls] == [3, 6, 9, 12]
        # the call at frame 3 has no box yet but the initial one (frame 0, three ticks old)
        assert [p is not None for _, p in tracker.calls[1:]] == want


def test_hold_hands_over_the_estimate_after_a_doubtful_box():
    # Boxes at confidence 0.9 set the tracker's median; a box at 0.36 (relative 0.4) passes the
    # gate (EWMA 0.3 * 0.4 + 0.7 * 1 = 0.82 >= 0.25, drop 0.82 - 0.4 = 0.42 <= 0.5) and is used,
    # but at R = 1 / 0.4^2 = 6.25 times nominal: the filter doubts it, and the estimate is handed
    # over although it lies inside that box. A box at the median confidence is trusted: withheld.
    for confidence, fed in ((0.36, True), (0.9, False)):
        est = HomographyEKF(HomographyEKF.Params(feedback_hold=True))
        est.initialize(BOX, 0.0)
        for k in range(1, 6):
            est.step(k / FPS, (), [Stamped(TrackerOutput(BOX, 0.9), k / FPS, k / FPS)])
        used = est.state.gate.n_used
        out = est.step(6 / FPS, (), [Stamped(TrackerOutput(BOX, confidence), 6 / FPS, 6 / FPS)])
        assert est.state.gate.n_used == used + 1  # used in both cases
        assert abs(out.box.cx - BOX.cx) < 0.5 * BOX.w and abs(out.box.cy - BOX.cy) < 0.5 * BOX.h
        assert (out.prior is not None) == fed



@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_gate_records_the_relative_confidence_of_its_ticks_last_used_box(backend):
    # What the holds and fresh_output trust. Preset mata's relative gate (alpha 0.3, tau_ewma
    # 0.25, tau_diff 0.5), by hand: three boxes at 0.8 are used at relative confidence 1 (the
    # first has no history, then 0.8 / 0.8); 0.4 at 0.5 (EWMA 0.3 * 0.5 + 0.7 * 1 = 0.85, drop
    # 0.35 <= 0.5); a tick without a box: 0; 0.1 (0.125, EWMA 0.6325, drop 0.5075 > 0.5) is
    # rejected: 0; a tick with two boxes records the second, 0.48 after 0.8 joined the history: 0.6.
    if backend == "numba":
        pytest.importorskip("numba")
    est = HomographyEKF(HomographyEKF.Params(), backend=backend)
    est.initialize(BOX, 0.0)
    recorded = []
    for k, confidences in enumerate([(0.8,), (0.8,), (0.8,), (0.4,), (), (0.1,), (0.8, 0.48)], start=1):
        est.step(k / FPS, (), [Stamped(TrackerOutput(BOX, c), k / FPS, k / FPS) for c in confidences])
        recorded.append(est.state.gate.used_relative)
    assert recorded == pytest.approx([1.0, 1.0, 1.0, 0.5, 0.0, 0.0, 0.6], abs=1e-12)


PICTURE = [0, 1, 2, 2, 3, 3, 3, 4, 5]  # frame k shows picture PICTURE[k]: 3 repeats 2, 5 and 6 repeat 4


class RepeatEgoMotion:
    """A still camera (H = I) on a clip padded with repeated pictures (PICTURE): a frame is
    ``unchanged`` when it shows the previous frame's picture, as block B reports it."""

    def initialize(self, image):
        pass

    def estimate(self, image):
        k = int(image[0, 0, 0])
        return Motion(np.eye(3), cov=np.eye(9) * 1e-12, unchanged=PICTURE[k] == PICTURE[k - 1])


class PictureTracker(RecordingTracker):
    """Returns the exact box of the target, which moves 12 px right with every new picture, at
    confidence 0.9, or 0.3 on the frames in ``doubtful``."""

    def __init__(self, doubtful=()):
        super().__init__()
        self.doubtful = set(doubtful)

    def track(self, image, prior=None):
        k = int(image[0, 0, 0])
        self.calls.append((k, prior))
        confidence = 0.3 if k in self.doubtful else 0.9
        return TrackerOutput(Box(BOX.x + 12.0 * PICTURE[k], BOX.y, BOX.w, BOX.h), confidence)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("hold, doubtful, withheld", [(False, (), []), (True, (), [3, 5, 6]), (True, (4,), [3, 6])])
def test_repeat_hold_keeps_the_trackers_own_search_on_a_repeated_picture(backend, hold, doubtful, withheld):
    # LTP on the padded clip: on frames 3, 5 and 6 nothing moved, so the tracker's box of the
    # previous frame was found on this very picture, and it searches there (no prior), where
    # the target is exactly. The filter's constant velocity (learned from the 12 px steps)
    # predicts motion that did not happen, so the estimate it would hand over lies more than
    # half a step ahead of the target. New pictures (frames 1, 2, 4, 7, 8) get the estimate;
    # frame 1 has only the initial box, which the filter did not use. A box the filter doubts
    # (frame 4 at relative confidence 0.3 / 0.9 = 0.33: used, EWMA 0.3 * 0.33 + 0.7 * 1 = 0.8,
    # drop 0.47 <= 0.5, but under HOLD_CONFIDENCE) is not held on the next frame (5).
    if backend == "numba":
        pytest.importorskip("numba")
    tracker = PictureTracker(doubtful)
    est = HomographyEKF(HomographyEKF.Params(repeat_hold=hold, feedback_hold=False), backend=backend)
    run_sequence(toy_sequence(len(PICTURE)), tracker, RepeatEgoMotion(), est, LTP(), np.random.default_rng(0))
    assert [k for k, p in tracker.calls if p is None] == withheld
    assert est.state.gate.n_used == len(PICTURE) - 1  # every box used, the doubtful one too
    for k, p in tracker.calls:
        if PICTURE[k] == PICTURE[k - 1] and not hold:
            assert p[0] - (100.0 + 12.0 * PICTURE[k]) > 6.0  # ahead of a target that did not move


def fresh_run(last: Box, confidence: float = 0.9, captured: float = 0.0, backend: str = "auto", **params):
    """Preset mata with a large R (20 px std: the estimate lags the boxes), a target moving
    3 px right per frame whose exact box comes at confidence 0.9 on frames 1-5, then ``last``
    at frame 6 at ``confidence``, captured ``captured`` frames before that tick. Returns the
    estimates of frames 1-6 and the filter."""
    est = HomographyEKF(HomographyEKF.Params(r_box=400.0, **params), backend=backend)
    est.initialize(BOX, 0.0)
    outs = []
    for k in range(1, 6):
        box = Box(BOX.x + 3.0 * k, BOX.y, BOX.w, BOX.h)
        outs.append(est.step(k / FPS, (), [Stamped(TrackerOutput(box, 0.9), k / FPS, k / FPS)]))
    t_cap = (6 - captured) / FPS
    outs.append(est.step(6 / FPS, (), [Stamped(TrackerOutput(last, confidence), t_cap, 6 / FPS)]))
    return outs, est


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_fresh_output_reports_a_fresh_trusted_box_and_leaves_the_filter_alone(backend):
    # A box captured at this tick, used at the tracker's typical confidence and containing the
    # estimate's centre is reported as it is (no latency to make up; the filter's centre lags
    # it, by 1.8 px at frame 1 and 0.3 px at frame 6 as it learns the velocity); the filter's
    # state and what is fed back (here nothing: feedback_hold) are those of fresh_output off.
    if backend == "numba":
        pytest.importorskip("numba")
    on, est_on = fresh_run(Box(BOX.x + 18.0, BOX.y, BOX.w, BOX.h), backend=backend)
    off, est_off = fresh_run(Box(BOX.x + 18.0, BOX.y, BOX.w, BOX.h), fresh_output=False, backend=backend)
    for k, (a, b) in enumerate(zip(on, off), start=1):
        assert a.box == Box(BOX.x + 3.0 * k, BOX.y, BOX.w, BOX.h)   # the tracker's box, bit for bit
        assert a.box.cx - b.box.cx > 0.2                              # the filter lags it
        assert a.prior == b.prior and a.feedback == b.feedback
        np.testing.assert_array_equal(a.cov, b.cov)
    np.testing.assert_array_equal(est_on.state.x, est_off.state.x)


@pytest.mark.parametrize("last, confidence, captured", [
    (Box(BOX.x + 60.0, BOX.y, BOX.w, BOX.h), 0.9, 0),   # jumps 3 box widths: a distractor
    (Box(BOX.x + 18.0, BOX.y, BOX.w, BOX.h), 0.3, 0),   # relative confidence 0.33: doubted
    (Box(BOX.x + 18.0, BOX.y, BOX.w, BOX.h), 0.9, 1),   # captured a frame before this tick
])
def test_fresh_output_leaves_the_filters_estimate_for_a_jump_a_doubt_or_latency(last, confidence, captured):
    on, _ = fresh_run(last, confidence, captured)
    off, _ = fresh_run(last, confidence, captured, fresh_output=False)
    assert on[-1].box == off[-1].box != last


def test_fresh_output_is_off_in_the_paper_preset():
    assert HomographyEKF.Params(preset="paper").resolved().fresh_output is False
    assert HomographyEKF.Params().resolved().fresh_output is True
