"""The live runtime against hand-computed timelines, with fake blocks of controlled duration
(``time.sleep``: GIL-free, like OpenCV / ONNX Runtime calls)."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from mata_eval.core.sequence import Sequence
from mata_eval.run.live import run_live
from mata_eval.run.scheduler import BlockError
from mata_eval.types import Box, Estimate, Motion, TrackerOutput

TOL = 0.015  # s: sleep overshoot and thread wake-up on a loaded machine; every event in the
#              timelines below is >= 25 ms away from a frame boundary
INIT = Box(0.0, 0.0, 10.0, 10.0)


def sequence(n, fps):
    gt = np.tile(INIT.as_array(), (n, 1))
    return Sequence("toy", gt, fps=fps, loader=lambda k: np.full((2, 2, 3), k, np.uint8))


class Tracker:
    """Sleeps ``durations[i]`` at its i-th call (initialisation included); box x = frame seen."""

    def __init__(self, durations):
        self.durations, self.calls = list(durations), []

    def _sleep(self):
        time.sleep(self.durations[min(len(self.calls), len(self.durations) - 1)])

    def initialize(self, image, box):
        self._sleep()
        self.calls.append((int(image[0, 0, 0]), None))

    def track(self, image, prior=None):
        self._sleep()
        k = int(image[0, 0, 0])
        self.calls.append((k, prior))
        return TrackerOutput(Box(float(k), 0.0, 10.0, 10.0), confidence=k / 100)


class EgoMotion:
    def __init__(self, duration):
        self.duration = duration

    def initialize(self, image):
        time.sleep(self.duration)

    def estimate(self, image):
        time.sleep(self.duration)
        H = np.eye(3)
        H[0, 2] = image[0, 0, 0]  # the frame it saw
        return Motion(H)


class Estimator:
    """Box x = the frame of its tick (t * fps); logs (tick frame, motion frames, detection frames)."""

    def __init__(self, duration, fps):
        self.duration, self.fps, self.ticks = duration, fps, []

    def initialize(self, box, t):
        time.sleep(self.duration)
        return Estimate(box)

    def step(self, t, motions=(), detections=()):
        time.sleep(self.duration)
        k = round(t * self.fps)
        self.ticks.append((k, [int(m.value.H[0, 2]) for m in motions], [int(d.value.box.x) for d in detections]))
        return Estimate(Box(float(k), 0.0, 10.0, 10.0))


def starts(run, block):
    return [(e.frame, e.t) for e in run.trace if e.block == block and e.event == "start"]


def publishes(run, block):
    return [(e.frame, e.t) for e in run.trace if e.block == block and e.event == "publish"]


def test_tracker_takes_the_newest_frame_and_the_output_is_held_on_real_times():
    # 20 fps (T_k = 50 k ms). Tracker: init 125 ms, then 100, 150, 100 ms. Free at 125 ms, it takes
    # frame 2 (100 ms), publishes at 225 (frame 5 is the first to see it), takes frame 4 (200),
    # publishes at 375, takes frame 7 (350), publishes at 475, takes frame 9 (450).
    tracker = Tracker([0.125, 0.100, 0.150, 0.100, 0.100, 0.100])
    run = run_live(sequence(12, 20.0), tracker, warmup=0)
    st = starts(run, "tracker")
    assert [f for f, _ in st][:5] == [0, 2, 4, 7, 9]
    np.testing.assert_allclose([t for _, t in st][:5], [0.0, 0.125, 0.225, 0.375, 0.475], atol=TOL)
    pub = publishes(run, "tracker")
    assert [f for f, _ in pub] == [3, 5, 8, 10]    # init at 125 ms, then 225, 375, 475 ms
    np.testing.assert_allclose([t for _, t in pub], [0.125, 0.225, 0.375, 0.475], atol=TOL)
    # held: init until frame 4, frame 2's box at frames 5-7, frame 4's at 8-9, frame 7's at 10-11
    assert run.source_frame.tolist() == [0] * 5 + [2] * 3 + [4] * 2 + [7] * 2
    assert run.boxes[:, 0].tolist() == [0.0] * 5 + [2.0] * 3 + [4.0] * 2 + [7.0] * 2
    # never queued: the frames it did not take are skipped, and it never went back to one
    skips = [e.frame for e in run.trace if e.block == "tracker" and e.event == "skip"]
    assert skips == [1, 3, 5, 6, 8, 10]
    cam = [e.t for e in run.trace if e.block == "camera"]
    np.testing.assert_allclose(cam, np.arange(12) / 20.0, atol=TOL)
    assert np.isfinite(run.wall_ms["tracker"][[0, 2, 4, 7, 9]]).all()
    np.testing.assert_allclose(run.wall_ms["tracker"][[0, 2, 4, 7]], [125, 100, 150, 100], atol=1e3 * TOL)


def test_three_blocks_run_in_parallel_and_the_estimator_ticks_on_every_frame():
    fps = 20.0
    tracker = Tracker([0.125, 0.100, 0.150, 0.100, 0.100, 0.100])
    est = Estimator(0.005, fps)
    run = run_live(sequence(12, fps), tracker, EgoMotion(0.030), est, warmup=0)
    # Overlap: 30 ms ego-motion + 5 ms estimator each frame beside the tracker: if they shared one
    # worker they could not keep up with a 50 ms camera while the tracker sleeps 100-150 ms.
    assert [f for f, _ in starts(run, "egomotion")] == list(range(12))
    assert [f for f, _ in starts(run, "estimator")] == list(range(12))
    assert [f for f, _ in starts(run, "tracker")][:5] == [0, 2, 4, 7, 9]
    # Tick k (at ~T_k) receives the motion of frame k-1 (published at T_{k-1} + 30 ms) and the
    # detections published since tick k-1: frame 2's (225 ms) at tick 5, 4's (375) at 8, 7's at 10.
    ticks = {k: (m, d) for k, m, d in est.ticks}
    assert ticks[1] == ([], [])
    for k in range(2, 12):
        assert ticks[k][0] == [k - 1], k
    assert {k: d for k, (m, d) in ticks.items() if d} == {5: [2], 8: [4], 10: [7]}
    # Frame k scores the estimate of tick k-1 (published at T_{k-1} + 5 ms); tick 0 is the init.
    assert run.source_frame.tolist() == [0, 0] + list(range(1, 11))
    # The tracker's prior is the newest estimate published before it starts (tick 2 at 105 ms
    # for its start at 125 ms, tick 4 at 205 for 225, tick 7 at 355 for 375).
    priors = [p for _, p in tracker.calls[1:4]]
    assert [p[0] - 5.0 for p in priors] == [2.0, 4.0, 7.0]


def test_time_scale_stretches_each_call():
    # work 20 ms, time_scale 5: published 100 ms after the start, the frames.csv keeps the 20 ms.
    tracker = Tracker([0.020])
    run = run_live(sequence(10, 20.0), tracker, time_scale={"tracker": 5.0}, warmup=0)
    st, pub = starts(run, "tracker"), publishes(run, "tracker")
    assert [f for f, _ in st][:4] == [0, 2, 4, 6]  # free at 100, 200, 300 ms: frames 2, 4, 6
    work = run.wall_ms["tracker"][[0, 2, 4, 6]] / 1e3
    np.testing.assert_allclose(work, 0.020, atol=TOL)
    for (_, t0), (_, t1), d in zip(st, pub, work):  # 5 x the work measured (sleep overshoot too)
        assert t1 - t0 == pytest.approx(5 * d, abs=0.005)


def test_a_slow_block_drops_frames_instead_of_queueing_them():
    # 50 fps camera, a 150 ms tracker: each start takes the frame published last before it
    # (a queue would feed it frames 0, 1, 2, ... in turn and fall further behind each call).
    fps, n = 50.0, 50
    run = run_live(sequence(n, fps), Tracker([0.150]), warmup=0)
    cam = {e.frame: e.t for e in run.trace if e.block == "camera"}
    st = starts(run, "tracker")
    for f, t in st:
        assert cam[f] <= t + 1e-9 and (f + 1 not in cam or t < cam[f + 1])
    frames = [f for f, _ in st]
    assert len(frames) == pytest.approx(n / fps / 0.150, abs=1.5)
    assert all(b - a >= 6 for a, b in zip(frames, frames[1:-1]))  # 150 ms / 20 ms = 7.5 frames


def test_a_failing_block_stops_the_run_and_names_itself():
    class Broken(Tracker):
        def track(self, image, prior=None):
            raise RuntimeError("boom")

    t0 = time.perf_counter()
    with pytest.raises(BlockError, match=r"tracker failed at frame 1 .*RuntimeError: boom"):
        run_live(sequence(100, 20.0), Broken([0.0]), EgoMotion(0.001), warmup=0)
    assert time.perf_counter() - t0 < 1.0  # it did not wait for the 5 s sequence


def test_ctrl_c_stops_a_live_run_promptly(tmp_path):
    """SIGINT during a long call stretched by time_scale: the run stops at once (the stretch is
    cut, the camera stops) and KeyboardInterrupt comes out; no thread keeps the process alive."""
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_live import Tracker, sequence
        from mata_eval.run.live import run_live
        print("ready", flush=True)
        try:
            run_live(sequence(600, 30.0), Tracker([0.05]), time_scale=40.0, warmup=0)
        except KeyboardInterrupt:
            print("interrupted", flush=True)
            sys.exit(130)
    """))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.5)
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 130 and "interrupted" in out
    assert time.perf_counter() - t0 < 1.0  # a 20 s sequence; the 2 s stretched call is cut


def test_live_params_are_checked_when_the_experiment_is_loaded():
    from mata_eval_plugins.protocols.live import Live

    assert Live(Live.Params(time_scale={"tracker": 20})).time_scale == {"egomotion": 1.0, "tracker": 20.0,
                                                                          "estimator": 1.0}
    assert Live.table_label({"time_scale": {"tracker": 20}})[0] == "Live (tracker x20)"
    with pytest.raises(ValueError, match=r"live: time_scale.tracker: expected a factor >= 1"):
        Live.Params(time_scale={"tracker": 0.5})
    with pytest.raises(ValueError, match=r"live: time_scale: unknown block 'camera'"):
        Live.Params(time_scale={"camera": 2})


def test_eop_free_start_models_the_live_tracker():
    """EOP ``tracker_start: free``: a 45 ms tracker on a 30 fps camera starts when it becomes
    free, on the newest frame (t = 0, 45, 90, 135, 180 ms on frames 0, 1, 2, 4, 5), as the live
    tracker does (test_tracker_takes_the_newest_frame...); with the paper's start on frames it
    runs every other frame (0, 2, 4, ...)."""
    from mata_eval.run.scheduler import run_sequence
    from mata_eval_plugins.protocols.eop import EOP

    rng = np.random.default_rng(0)
    free = run_sequence(sequence(8, 30.0), Tracker([0.0]), None, None,
                        EOP(EOP.Params(tracker_latency=0.045, tracker_start="free")), rng)
    st = starts(free, "tracker")
    assert [f for f, _ in st] == [0, 1, 2, 4, 5, 6]
    np.testing.assert_allclose([t for _, t in st], [0.0, 0.045, 0.090, 0.135, 0.180, 0.225])
    # frame k holds the newest output published by t_k: frame 1's (90 ms) at frames 3-4 (100,
    # 133 ms), frame 2's (135 ms) at frame 5, frame 4's (180 ms) at 6, frame 5's (225 ms) at 7
    assert free.source_frame.tolist() == [0, 0, 0, 1, 1, 2, 4, 5]
    framed = run_sequence(sequence(8, 30.0), Tracker([0.0]), None, None, EOP(EOP.Params(tracker_latency=0.045)), rng)
    assert [f for f, _ in starts(framed, "tracker")] == [0, 2, 4, 6]
