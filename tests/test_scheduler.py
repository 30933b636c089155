"""Exact timelines of the scheduler, checked against hand-computed expectations with fake blocks
whose outputs encode the frame they saw (DESIGN.md "One scheduler, four protocols")."""

from __future__ import annotations

import csv
import io
import math
import re

import numpy as np
import pytest

from mata_eval.run.scheduler import (BlockError, BlockTiming, FixedLatency, Timing, read_trace_csv,
                                 run_sequence, turn_frames)
from mata_eval.core.sequence import FrameReadError, Sequence
from mata_eval.types import Box, Estimate, Motion, TrackerOutput
from mata_eval_plugins.protocols.dsp import DSP
from mata_eval_plugins.protocols.eop import EOP
from mata_eval_plugins.protocols.ltp import LTP
from mata_eval_plugins.protocols.vot_rt import VotRealTime

INIT = Box(-1.0, 0.0, 10.0, 10.0)


def make_sequence(n=30, fps=30.0, frame_of=lambda k: k, reads=None, broken=None):
    """Toy sequence whose frame k is a 640x480 image filled with ``frame_of(k)`` (the size bounds
    the estimates, ``Estimate.within``)."""
    gt = np.tile(INIT.as_array(), (n, 1))

    def loader(k):
        if reads is not None:
            reads.append(k)
        if broken is not None and k == broken:
            raise FrameReadError(f"cannot read frame {k} of sequence 'toy': missing.jpg")
        return np.full((480, 640, 3), frame_of(k), dtype=np.uint8)

    return Sequence("toy", gt, fps=fps, loader=loader)


class FrameTracker:
    """Returns a box whose x is the frame index it saw; logs (frame, prior) per call."""

    def __init__(self, fail_at=None, nan_at=None, clock=None, cost_s=0.0):
        self.calls = []
        self.fail_at, self.nan_at, self.clock, self.cost_s = fail_at, nan_at, clock, cost_s

    def _spend(self):
        if self.clock is not None:
            self.clock.now += self.cost_s

    def initialize(self, image, box):
        self._spend()
        self.calls.append(("init", int(image[0, 0, 0]), None))

    def track(self, image, prior=None):
        self._spend()
        k = int(image[0, 0, 0])
        self.calls.append(("track", k, prior))
        if k == self.fail_at:
            raise ValueError("boom")
        x = math.nan if k == self.nan_at else float(k)
        return TrackerOutput(Box(x, 0.0, 10.0, 10.0), confidence=k / 1000.0)  # in [0, 1] up to frame 1000


class FrameEgoMotion:
    """H is a translation whose x is the current frame and y the previous frame given."""

    def __init__(self):
        self.prev = None

    def initialize(self, image):
        self.prev = int(image[0, 0, 0])

    def estimate(self, image):
        k = int(image[0, 0, 0])
        H = np.array([[1.0, 0.0, k], [0.0, 1.0, self.prev], [0.0, 0.0, 1.0]])
        self.prev = k
        return Motion(H)


class LogEstimator:
    """Logs its inputs; its estimate is the newest detection's box (or its last one) with y = t."""

    def __init__(self):
        self.ticks = []
        self.box = None

    def initialize(self, box, t):
        self.box = box
        self.ticks.append(("init", t, [], []))
        return Estimate(box)

    def step(self, t, motions=(), detections=()):
        self.ticks.append((t, [(m.value.H[0, 2], m.value.H[1, 2], m.t_capture, m.t_publish) for m in motions],
                           [(d.value.box.x, d.t_capture, d.t_publish) for d in detections]))
        if detections:
            self.box = detections[-1].value.box
        self.box = Box(self.box.x, t, self.box.w, self.box.h)
        return Estimate(self.box)


def events(run, block, event):
    return [e.frame for e in run.trace if e.block == block and e.event == event]


def test_turn_grid():
    assert np.flatnonzero(turn_frames(30, 5.0, 30.0)).tolist() == [0, 6, 12, 18, 24]
    assert np.flatnonzero(turn_frames(16, 7.5, 30.0)).tolist() == [0, 4, 8, 12]
    # 12 Hz on 30 Hz: ticks at 2.5-frame spacing, taken at the first frame at or after each tick.
    assert np.flatnonzero(turn_frames(11, 12.0, 30.0)).tolist() == [0, 3, 5, 8, 10]
    assert turn_frames(5, 60.0, 30.0).all()


def test_5hz_tracker_starts_every_sixth_frame_and_is_scored_one_period_later():
    reads = []
    seq = make_sequence(30, reads=reads)
    run = run_sequence(seq, FrameTracker(), None, None, EOP(EOP.Params(tracker_hz=5.0)),
                       np.random.default_rng(0))
    assert events(run, "tracker", "start") == [0, 6, 12, 18, 24]
    assert events(run, "tracker", "publish") == [6, 12, 18, 24]  # the one at t = 1.0 s is past the end
    x = run.boxes[:, 0]
    expected = np.repeat([-1, -1, 6, 12, 18], 6)  # init box held until frame 6's result at 12
    np.testing.assert_array_equal(x, expected)
    assert np.all(np.isnan(run.confidence[:12]))
    np.testing.assert_allclose(run.confidence[12:], np.repeat([0.006, 0.012, 0.018], 6))
    np.testing.assert_array_equal(run.source_frame, expected.clip(0))
    assert reads == [0, 6, 12, 18, 24]  # images read only where a block starts
    assert run.rates_hz["tracker"] == pytest.approx(5.0)
    assert run.scored.all()
    started = np.isfinite(run.wall_ms["tracker"])
    assert np.flatnonzero(started).tolist() == [0, 6, 12, 18, 24]


def test_ltp_mata_order_and_feedback():
    tracker, est = FrameTracker(), LogEstimator()
    run = run_sequence(make_sequence(6), tracker, FrameEgoMotion(), est, LTP(), np.random.default_rng(0))
    # Each frame: ego-motion, the estimator's first half (camera motion: the estimate of frame k,
    # y = t_k, x still the previous detection), the tracker (prior = that estimate), then the
    # estimator's second half with this frame's detection (zero latency): output x = k.
    np.testing.assert_array_equal(run.boxes[:, 0], [-1, 1, 2, 3, 4, 5])
    assert [c[1] for c in tracker.calls] == [0, 1, 2, 3, 4, 5]
    priors = [c[2] for c in tracker.calls[1:]]
    assert priors[0] == pytest.approx((INIT.cx, 1 / 30 + 5.0))  # the initial box, moved to t_1
    for k, prior in enumerate(priors[1:], start=2):
        assert prior == pytest.approx((k - 1 + 5.0, k / 30 + 5.0))
    ticks = est.ticks[1:]
    assert len(ticks) == 2 * 5
    for k in range(1, 6):
        (t1, motions1, dets1), (t2, motions2, dets2) = ticks[2 * k - 2], ticks[2 * k - 1]
        assert t1 == pytest.approx(k / 30) and t2 == pytest.approx(k / 30)
        assert motions1 == [(k, k - 1, pytest.approx(k / 30), pytest.approx(k / 30))] and dets1 == []
        assert motions2 == [] and dets2 == [(k, pytest.approx(k / 30), pytest.approx(k / 30))]
    assert events(run, "estimator", "start") == [0, 1, 2, 3, 4, 5]  # still one tick per frame


def test_no_feedback_gives_no_prior():
    tracker = FrameTracker()
    run_sequence(make_sequence(5), tracker, FrameEgoMotion(), LogEstimator(), LTP(),
                 np.random.default_rng(0), feedback=False)
    assert all(c[2] is None for c in tracker.calls)


def test_eop_10hz_mata_hand_timeline():
    tracker, est = FrameTracker(), LogEstimator()
    run = run_sequence(make_sequence(12), tracker, FrameEgoMotion(), est,
                       EOP(EOP.Params(tracker_hz=10.0)), np.random.default_rng(0))
    assert events(run, "tracker", "start") == [0, 3, 6, 9]
    assert events(run, "egomotion", "start") == list(range(12))
    assert events(run, "estimator", "start") == list(range(12))
    # Tracker busy from 0 (init) to 3, from 3 to 6, ...: its detection of frame 3 reaches the
    # estimator at frame 6 with its capture time, that of frame 6 at frame 9.
    dets = {round(t * 30): d for t, m, d in est.ticks[1:]}
    assert {k for k, d in dets.items() if d} == {6, 9}
    assert dets[6] == [(3.0, pytest.approx(0.1), pytest.approx(0.2))]
    assert dets[9] == [(6.0, pytest.approx(0.2), pytest.approx(0.3))]
    # The estimator outputs at every frame (y = t), holding the detection's x.
    np.testing.assert_array_equal(run.boxes[:, 0], [-1] * 6 + [3] * 3 + [6] * 3)
    np.testing.assert_allclose(run.boxes[1:, 1], np.arange(1, 12) / 30)
    # The prior of the tracker at frames 3, 6, 9 is the estimate of those frames, which already
    # holds the detections of frames 3 and 6 that arrived at frames 6 and 9.
    priors = [c[2] for c in tracker.calls[1:]]
    assert [p[1] - 5.0 for p in priors] == pytest.approx([3 / 30, 6 / 30, 9 / 30])
    assert [p[0] - 5.0 for p in priors] == pytest.approx([-1, 3, 6])


def test_eop_at_camera_rate_with_zero_latency_equals_ltp_frame_for_frame():
    runs = []
    for proto in (LTP(), EOP(EOP.Params(tracker_hz=30.0, tracker_latency="none"))):
        tracker, est = FrameTracker(), LogEstimator()
        runs.append((run_sequence(make_sequence(20), tracker, FrameEgoMotion(), est, proto,
                                  np.random.default_rng(0)), tracker.calls, est.ticks))
    (a, ca, ea), (b, cb, eb) = runs
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.confidence, b.confidence)
    assert ca == cb and ea == eb
    assert [e[:3] for e in a.trace] == [e[:3] for e in b.trace]


def test_dsp_equals_ltp_on_a_subsampled_copy():
    n, fps = 30, 30.0
    full = make_sequence(n, fps)
    sub = make_sequence(n // 3, fps / 3, frame_of=lambda j: 3 * j)
    t1, e1 = FrameTracker(), LogEstimator()
    t2, e2 = FrameTracker(), LogEstimator()
    a = run_sequence(full, t1, FrameEgoMotion(), e1, DSP(DSP.Params(n=3)), np.random.default_rng(0))
    b = run_sequence(sub, t2, FrameEgoMotion(), e2, LTP(), np.random.default_rng(0))
    np.testing.assert_array_equal(a.scored, np.arange(n) % 3 == 0)
    np.testing.assert_allclose(a.boxes[a.scored], b.boxes, rtol=1e-12)
    assert t1.calls == t2.calls
    assert len(e1.ticks) == len(e2.ticks) == 1 + 2 * 9  # init, then two halves per kept frame
    for x, y in zip(e1.ticks[1:], e2.ticks[1:]):
        assert x[0] == pytest.approx(y[0])
        for a_items, b_items in ((x[1], y[1]), (x[2], y[2])):  # motions, detections
            np.testing.assert_allclose(np.array(a_items, float).reshape(-1), np.array(b_items, float).reshape(-1))
    # Dropped frames hold the previous kept frame's output and are marked unscored.
    np.testing.assert_array_equal(a.boxes[1:3, 0], [-1, -1])
    np.testing.assert_array_equal(a.boxes[4:6, 0], [3, 3])
    assert events(a, "camera", "skip") == [k for k in range(n) if k % 3]


def test_busy_block_skips_its_turn_without_queueing():
    proto = EOP(EOP.Params(tracker_latency=0.05))  # camera rate, 1.5 frames of latency
    run = run_sequence(make_sequence(10), FrameTracker(), None, None, proto, np.random.default_rng(0))
    assert events(run, "tracker", "start") == [0, 2, 4, 6, 8]
    assert events(run, "tracker", "skip") == [1, 3, 5, 7, 9]
    # Frame 2's result is published at 3.5 frames, i.e. visible from frame 4.
    np.testing.assert_array_equal(run.boxes[:, 0], [-1, -1, -1, -1, 2, 2, 4, 4, 6, 6])
    pub = [e for e in run.trace if e.block == "tracker" and e.event == "publish"]
    assert [e.t for e in pub] == pytest.approx([0.05, 2 / 30 + 0.05, 4 / 30 + 0.05, 6 / 30 + 0.05, 8 / 30 + 0.05][:len(pub)])


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_vot_realtime_uses_measured_wall_time():
    clock = FakeClock()
    tracker = FrameTracker(clock=clock, cost_s=0.07)  # 2.1 frames per call at 30 fps
    run = run_sequence(make_sequence(12), tracker, None, None, VotRealTime(VotRealTime.Params(grace=0)),
                       np.random.default_rng(0), clock=clock)
    assert events(run, "tracker", "start") == [0, 3, 6, 9]
    np.testing.assert_array_equal(run.boxes[:, 0], [-1] * 6 + [3] * 3 + [6] * 3)
    np.testing.assert_allclose(run.wall_ms["tracker"][[0, 3, 6, 9]], 70.0)
    # Twice as slow: 4.2 frames per call.
    clock2 = FakeClock()
    run2 = run_sequence(make_sequence(12), FrameTracker(clock=clock2, cost_s=0.07), None, None,
                        VotRealTime(VotRealTime.Params(time_scale=2.0, grace=0)), np.random.default_rng(0),
                        clock=clock2)
    assert events(run2, "tracker", "start") == [0, 5, 10]


def test_vot_realtime_grace_forgives_the_first_slow_call():
    """The VOT toolkit's realtime grace (default 1): the first call slower than a frame interval
    (here the initialisation, 70 ms at 30 fps) counts as taking one interval, so the tracker is
    free at frame 1; later calls keep their 70 ms. Hand-computed: starts at 0, 1 (t = 1/30),
    then 1/30 + 0.07 = 0.103 s -> frame 4, 0.203 s -> frame 7, 0.303 s -> frame 10; each output
    is seen at the first frame after it: the call of frame 1 at frame 4, 4 at 7, 7 at 10."""
    clock = FakeClock()
    run = run_sequence(make_sequence(12), FrameTracker(clock=clock, cost_s=0.07), None, None, VotRealTime(),
                       np.random.default_rng(0), clock=clock)
    assert VotRealTime.Params().grace == 1
    assert events(run, "tracker", "start") == [0, 1, 4, 7, 10]
    np.testing.assert_array_equal(run.boxes[:, 0], [-1] * 4 + [1] * 3 + [4] * 3 + [7] * 2)
    # a fresh grace per sequence (the protocol's timing is built for each)
    clock2 = FakeClock()
    again = run_sequence(make_sequence(12), FrameTracker(clock=clock2, cost_s=0.07), None, None, VotRealTime(),
                         np.random.default_rng(0), clock=clock2)
    assert events(again, "tracker", "start") == [0, 1, 4, 7, 10]


def test_vot_realtime_on_a_fast_machine_equals_ltp():
    clock = FakeClock()
    a = run_sequence(make_sequence(10), FrameTracker(clock=clock, cost_s=0.001), None, None, VotRealTime(),
                     np.random.default_rng(0), clock=clock)
    b = run_sequence(make_sequence(10), FrameTracker(), None, None, LTP(), np.random.default_rng(0))
    # A 1 ms tracker publishes before the next frame, so it gets every frame, one frame late.
    assert events(a, "tracker", "start") == list(range(10))
    np.testing.assert_array_equal(a.boxes[1:, 0], b.boxes[:-1, 0])


def test_link_delays():
    proto = EOP(EOP.Params(tracker_latency="none", link_delay_s={"tracker->output": 0.05,
                                                                 "tracker->estimator": 0.1}))
    run = run_sequence(make_sequence(8), FrameTracker(), None, None, proto, np.random.default_rng(0))
    # Published at t_k, seen by the scoring 0.05 s (1.5 frames) later: from frame k + 2.
    np.testing.assert_array_equal(run.boxes[:, 0], [-1, -1, -1, 1, 2, 3, 4, 5])
    assert events(run, "tracker", "start") == list(range(8))  # the link does not block the tracker
    est = LogEstimator()
    run = run_sequence(make_sequence(8), FrameTracker(), None, est, proto, np.random.default_rng(0))
    dets = {round(t * 30): d for t, m, d in est.ticks[1:]}
    assert dets[4] == [(1.0, pytest.approx(1 / 30), pytest.approx(4 / 30))]  # arrival time stamped
    assert dets[3] == []


def test_egomotion_at_its_own_rate_chains_frames():
    est = LogEstimator()
    run_sequence(make_sequence(7), FrameTracker(), FrameEgoMotion(), est,
                 EOP(EOP.Params(egomotion_hz=15.0, tracker_latency="none")), np.random.default_rng(0))
    motions = [(round(t * 30), m) for t, m, d in est.ticks[1:] if m]
    assert [(k, [(a, b) for a, b, *_ in m]) for k, m in motions] == [(2, [(2, 0)]), (4, [(4, 2)]), (6, [(6, 4)])]


def test_profile_like_latency_and_jitter_are_seeded():
    proto = EOP(EOP.Params(tracker_latency=0.1, jitter_s=0.02))
    runs = [run_sequence(make_sequence(300, frame_of=lambda k: k % 256), FrameTracker(), None, None, proto, np.random.default_rng(s))
            for s in (1, 1, 2)]
    assert runs[0].trace == runs[1].trace and runs[0].trace != runs[2].trace
    # Monte-Carlo: publish - start ~ N(0.1, 0.02) clipped at 0 (clipping is negligible here).
    starts = [e.t for e in runs[0].trace if e.block == "tracker" and e.event == "start"]
    pubs = [e.t for e in runs[0].trace if e.block == "tracker" and e.event == "publish"]
    lat = np.array(pubs) - np.array(starts[:len(pubs)])
    assert len(lat) > 60
    assert abs(lat.mean() - 0.1) < 4 * 0.02 / math.sqrt(len(lat))
    assert 0.014 < lat.std() < 0.026


def test_tracker_failures_name_block_and_frame():
    with pytest.raises(BlockError, match=r"tracker 'FrameTracker' failed at frame 3 .*ValueError: boom"):
        run_sequence(make_sequence(6), FrameTracker(fail_at=3), None, None, LTP(), np.random.default_rng(0))
    with pytest.raises(BlockError, match=r"tracker 'FrameTracker' failed at frame 2 .*not four finite numbers"):
        run_sequence(make_sequence(6), FrameTracker(nan_at=2), None, None, LTP(), np.random.default_rng(0))
    # An unreadable frame is not the tracker's fault: the read error comes out as it is.
    with pytest.raises(FrameReadError, match="cannot read frame 4"):
        run_sequence(make_sequence(6, broken=4), FrameTracker(), None, None, LTP(), np.random.default_rng(0))


def test_missing_block_timing_is_reported():
    class Partial:
        def timing(self, fps):
            return Timing(fps, {"tracker": BlockTiming(fps, FixedLatency(0.0))})

    run_sequence(make_sequence(3), FrameTracker(), None, None, Partial(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="no timing for block 'estimator'"):
        run_sequence(make_sequence(3), FrameTracker(), None, LogEstimator(), Partial(), np.random.default_rng(0))


def test_csv_rows():
    run = run_sequence(make_sequence(7), FrameTracker(), FrameEgoMotion(), LogEstimator(),
                       EOP(EOP.Params(tracker_hz=10.0)), np.random.default_rng(0))
    lines = run.frames_csv().splitlines()
    assert lines[0] == ("frame,scored,confidence,tracker_ms,egomotion_ms,estimator_ms,source_frame,"
                        "tracker_x,tracker_y,tracker_w,tracker_h,search_x,search_y,search_w,search_h,"
                        "prior_x,prior_y,motion_valid,motion_inliers,motion_sigma,motion_unchanged")
    assert len(lines) == 8
    row3 = lines[4].split(",")
    assert row3[0] == "3" and row3[1] == "1" and row3[2] == "nan" and row3[3] != "nan"
    assert "nan" not in row3[7:11] and row3[11:15] == ["nan"] * 4  # its box; no search region reported
    # the prior handed to the call of frame 3: the centre of the estimate of t = 0.1 (LogEstimator: y = t)
    assert float(row3[16]) == pytest.approx(0.1 + INIT.h / 2)
    # block B's call of frame 3: a valid motion (FrameEgoMotion's: no inliers, no noise) on a new picture
    assert row3[17:] == ["1", "0", "nan", "0"] and lines[1].split(",")[17:] == ["nan"] * 4   # frame 0: its init
    assert lines[2].split(",")[3] == "nan" and lines[2].split(",")[7] == "nan"  # no tracker call at frame 1
    assert lines[7].split(",")[6] == "6"  # the estimator output of frame 6 (computed at frame 6)
    assert read_trace_csv(run.trace_csv()) == list(run.trace)
    assert run.trace_csv().splitlines()[0] == "block,event,frame,t"
    assert ("tracker", "start", 3, pytest.approx(0.1)) == run.trace_rows()[
        [i for i, r in enumerate(run.trace_rows()) if r[:3] == ("tracker", "start", 3)][0]]


def test_vot_realtime_with_the_real_clock():
    import time

    class Sleeper(FrameTracker):
        def track(self, image, prior=None):
            time.sleep(0.045)  # at least 1.35 frames at 30 fps, whatever the machine
            return super().track(image, prior)

    run = run_sequence(make_sequence(12), Sleeper(), None, None, VotRealTime(VotRealTime.Params(grace=0)),
                       np.random.default_rng(0))
    starts = [e for e in run.trace if e.block == "tracker" and e.event == "start"]
    pubs = [e for e in run.trace if e.block == "tracker" and e.event == "publish"]
    assert starts[0].frame == 0 and len(starts) >= 3
    for s, p, nxt in zip(starts[1:], pubs[1:], starts[2:]):
        assert p.t - s.t >= 0.045  # latency = measured wall time
        assert nxt.frame == p.frame >= s.frame + 2  # restarts at the first frame after publishing
    assert np.all(run.wall_ms["tracker"][[s.frame for s in starts[1:]]] >= 45.0)


@pytest.mark.filterwarnings("ignore:eop. tracker_hz 7 is not 30 fps")   # an irregular rate on purpose
@pytest.mark.parametrize("proto", [LTP(), EOP(EOP.Params(tracker_hz=10.0)), EOP(EOP.Params(tracker_hz=7.0)),
                                   EOP(EOP.Params(tracker_latency=0.05, jitter_s=0.03))])
def test_trace_alternates_start_and_publish_per_block(proto):
    run = run_sequence(make_sequence(60), FrameTracker(), FrameEgoMotion(), LogEstimator(), proto,
                       np.random.default_rng(5))
    for block in ("egomotion", "tracker", "estimator"):
        seq = [e.event for e in run.trace if e.block == block and e.event != "skip"]
        assert seq[0::2] == ["start"] * len(seq[0::2])
        assert seq[1::2] == ["publish"] * len(seq[1::2])
    frames = [e.frame for e in run.trace]
    assert frames == sorted(frames)


def test_recording_the_estimators_state_adds_columns_and_changes_nothing(monkeypatch):
    """MATA_EVAL_RECORD=1: after each estimator tick the filter's diagnostics() go into est_*
    columns of frames.csv (the diagnosis docs/mata.md did with a patched filter); the boxes are
    the same as without recording, and a run without the variable has no such column."""
    from mata_eval_plugins.estimators.homography_ekf import HomographyEKF

    def run():
        return run_sequence(make_sequence(9), FrameTracker(), FrameEgoMotion(), HomographyEKF(),
                            EOP(EOP.Params(tracker_hz=10.0)), np.random.default_rng(0))

    plain = run()
    assert "est_" not in plain.frames_csv()
    monkeypatch.setenv("MATA_EVAL_RECORD", "1")
    recorded = run()
    np.testing.assert_array_equal(recorded.boxes, plain.boxes)
    rows = list(csv.DictReader(io.StringIO(recorded.frames_csv())))
    assert [c for c in rows[0] if c.startswith("est_")] == ["est_vx", "est_vy", "est_sd_cx", "est_sd_cy",
                                                          "est_boxes_used", "est_ewma", "est_nis"]
    assert rows[0]["est_vx"] == "0" and all(r["est_sd_cx"] != "nan" for r in rows)   # frame 0: the initial state
    # the tracker's first box (captured at frame 3, confidence 0.003) reaches the filter at frame 6
    assert [r["est_boxes_used"] for r in rows] == ["0"] * 6 + ["1"] * 3
    assert [r["est_ewma"] for r in rows] == ["nan"] * 6 + ["1"] * 3


class OddEgoMotion(FrameEgoMotion):
    """FrameEgoMotion whose motion from frame 2 on is ``motion``."""

    name = "odd_ego"

    def __init__(self, motion):
        super().__init__()
        self.motion = motion

    def estimate(self, image):
        m = super().estimate(image)
        return self.motion if int(image[0, 0, 0]) >= 2 else m


NAN_H = np.full((3, 3), np.nan)


@pytest.mark.parametrize("motion, words", [
    (Motion(np.eye(3)[:2]), "returned H of shape (2, 3); expected a 3x3 array"),
    (Motion([[1, 0], [0, 1]]), "returned H of shape (2, 2); expected a 3x3 array"),
    (Motion("eye"), "returned H of type str, not numbers; expected a 3x3 array"),
    (Motion(np.eye(3), cov=np.eye(4)), "returned a covariance of shape (4, 4); expected 9x9"),
    (Motion(NAN_H), "returned a valid motion whose H (or covariance) is not finite or has h33 = 0"),
    (Motion(np.zeros((3, 3))), "returned a valid motion whose H (or covariance) is not finite or has h33 = 0"),
    (Motion(np.eye(3), cov=np.full((9, 9), np.nan)), "returned a valid motion whose H (or covariance) is not finite"),
    (Motion(np.eye(3), inliers="many"), "returned inliers 'many', sigma None; expected inliers a number"),
    (None, "expected a Motion, got NoneType"),
])
def test_a_motion_that_breaks_the_motion_type_names_the_egomotion_and_the_frame(motion, words):
    """QA pass: block B's output was never checked: a 2x3 or NaN H was dropped by the EKF as
    invalid while frames.csv said motion_valid = 1, or failed the estimator, which was blamed."""
    with pytest.raises(BlockError, match=rf"^egomotion 'odd_ego' failed at frame 2 \(t = 0.0667 s\): {re.escape(words)}"):
        run_sequence(make_sequence(6), FrameTracker(), OddEgoMotion(motion), LogEstimator(), LTP(),
                     np.random.default_rng(0))


@pytest.mark.parametrize("motion", [Motion.invalid(), Motion(NAN_H, valid=False), Motion(np.eye(3), inliers=np.int64(3))])
def test_no_motion_this_time_is_a_motion_with_valid_false(motion):
    run = run_sequence(make_sequence(6), FrameTracker(), OddEgoMotion(motion), LogEstimator(), LTP(),
                       np.random.default_rng(0))
    rows = list(csv.DictReader(io.StringIO(run.frames_csv())))
    assert [r["motion_valid"] for r in rows[1:]] == ["1"] + [str(int(motion.valid))] * 4


class OddEstimator(LogEstimator):
    """LogEstimator whose estimates from t = 2/30 on are ``make(box)``."""

    def __init__(self, make):
        super().__init__()
        self.make = make

    def step(self, t, motions=(), detections=()):
        e = super().step(t, motions, detections)
        return self.make(e.box) if t > 0.05 else e


@pytest.mark.parametrize("make, words", [
    (lambda b: Estimate(b, search=(math.nan, 1.0)), "returned search centre (nan, 1.0); expected two finite numbers"),
    (lambda b: Estimate(b, search=(1.0,)), "returned search centre (1.0,); expected two finite numbers"),
    (lambda b: Estimate(b, cov=np.ones((2, 3))), "returned a covariance of shape (2, 3); expected a square matrix"),
    (lambda b: Estimate(b, cov=np.full((3, 3), np.nan)), "returned a covariance holding NaN"),
    (lambda b: b, "expected an Estimate, got Box"),
])
def test_an_estimate_that_breaks_the_estimate_type_names_the_estimator(make, words):
    with pytest.raises(BlockError, match=rf"^estimator 'OddEstimator' failed at frame 2 .*: {re.escape(words)}"):
        run_sequence(make_sequence(6), FrameTracker(), None, OddEstimator(make), LTP(), np.random.default_rng(0))


def test_a_search_centre_given_as_a_numpy_array_is_taken():
    """QA pass: Estimate(search=np.array([cx, cy])) was refused (a list or tuple was taken)."""
    e = Estimate(Box(0.0, 0.0, 4.0, 4.0), search=np.array([np.float32(3.5), 7.0]))
    assert e.search == (3.5, 7.0) and type(e.search[0]) is float
    assert e.within(10.0, 10.0).search == (3.5, 7.0)   # (within compared an array: ambiguous truth value)
    assert Estimate(Box(0.0, 0.0, 4.0, 4.0), search="12").search == "12"   # not numbers: left to be refused
    run = run_sequence(make_sequence(6), FrameTracker(), None,
                       OddEstimator(lambda b: Estimate(b, search=np.array([b.cx, b.cy]))), LTP(), np.random.default_rng(0))
    assert len(run.boxes) == 6


def test_an_empty_estimate_box_is_a_lost_target_not_an_error():
    run = run_sequence(make_sequence(6), FrameTracker(), None, OddEstimator(lambda b: Estimate(Box(b.x, b.y, 0.0, 0.0))),
                       LTP(), np.random.default_rng(0))
    assert run.boxes[5, 2] == 0.0 and run.boxes[5, 3] == 0.0


class DiagEstimator(LogEstimator):
    """LogEstimator whose diagnostics() return ``diag`` (or raise it)."""

    name = "diag_est"

    def __init__(self, diag):
        super().__init__()
        self.diag = diag

    def diagnostics(self):
        if isinstance(self.diag, Exception):
            raise self.diag
        return self.diag


@pytest.mark.parametrize("diag, words", [
    (KeyError("boom"), "diagnostics(): KeyError: 'boom'"),
    (None, "diagnostics() returned NoneType; expected a dict of str -> number"),
    ([1.0], "diagnostics() returned list; expected a dict of str -> number"),
    ({"state": "coasting"}, "diagnostics() key 'state': 'coasting' is not a number"),
    ({"v": [1.0, 2.0]}, "diagnostics() key 'v': [1.0, 2.0] is not a number"),
    ({"a,b": 1.0}, "diagnostics() key 'a,b': expected letters, digits and _ (a frames.csv column name)"),
    ({"c\nd": 1.0}, "diagnostics() key 'c\\nd': expected letters, digits and _"),
    ({"cd\n": 1.0}, "diagnostics() key 'cd\\n': expected letters, digits and _"),
    ({1: 1.0}, "diagnostics() key 1: expected letters, digits and _"),
])
def test_a_diagnostics_that_breaks_its_contract_names_the_estimator_and_the_key(monkeypatch, diag, words):
    """QA pass: diagnostics() raising or returning a str, None or a list failed the sequence with a
    bare reason; a key holding ',' or a newline corrupted frames.csv's header (IndexError later)."""
    monkeypatch.setenv("MATA_EVAL_RECORD", "1")
    with pytest.raises(BlockError, match=rf"^estimator 'diag_est' failed at frame 0 .*: {re.escape(words)}"):
        run_sequence(make_sequence(6), FrameTracker(), None, DiagEstimator(diag), LTP(), np.random.default_rng(0))


def test_diagnostics_numbers_and_flags_are_recorded(monkeypatch):
    monkeypatch.setenv("MATA_EVAL_RECORD", "1")
    diag = {"used": True, "n": np.int64(2), "gated": np.float64(3.0) < 9.0, "d": np.float32(0.5)}
    run = run_sequence(make_sequence(3), FrameTracker(), None, DiagEstimator(diag), LTP(), np.random.default_rng(0))
    rows = list(csv.DictReader(io.StringIO(run.frames_csv())))
    assert [(r["est_used"], r["est_n"], r["est_gated"], r["est_d"]) for r in rows] == [("1", "2", "1", "0.5")] * 3
