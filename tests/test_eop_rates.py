"""EOP rates on the camera grid: a rate that is fps / n up to the digits typed runs every n-th
frame; a rate the camera grid cannot give warns with the rate actually run."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mata_eval.run.scheduler import RateWarning, run_sequence
from mata_eval.core.sequence import Sequence
from mata_eval.core.types import TrackerOutput
from mata_eval_plugins.protocols.eop import EOP


class Still:
    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        return TrackerOutput(self.box, 1.0)


def _starts(hz, fps=10.0, n=30):
    seq = Sequence("s", np.tile([10.0, 10.0, 8.0, 8.0], (n, 1)), fps,
                   loader=lambda k: np.zeros((16, 16, 3), np.uint8))
    run = run_sequence(seq, Still(), None, None, EOP(EOP.Params(tracker_hz=hz)), np.random.default_rng(0))
    return [e.frame for e in run.trace if e.block == "tracker" and e.event == "start"], run


def test_a_third_of_the_camera_rate_typed_with_four_decimals_runs_every_third_frame():
    # Hand timeline, 10 fps: ticks every 0.3 s, one-period latency: the call started at frame 3
    # publishes at 0.6 s = frame 6, where the tracker is free again; 10 starts in 3 s.
    with warnings.catch_warnings():
        warnings.simplefilter("error", RateWarning)  # 3.3333 Hz is 10/3 Hz as typed: no warning
        starts, run = _starts(3.3333)
    assert starts == [0, 3, 6, 9, 12, 15, 18, 21, 24, 27]
    assert run.rates_hz["tracker"] == pytest.approx(10 / 3)
    # the box of the call started at frame 3 is the output from frame 6 (one period later)
    assert list(run.source_frame[:10]) == [0, 0, 0, 0, 0, 0, 3, 3, 3, 6]


def test_a_rate_off_the_camera_grid_warns_with_the_rate_actually_run():
    # 4 Hz on 10 fps: ticks at 0, 0.25, 0.5, 0.75 s -> turns at frames 0, 3, 5, 8, 10, 13, ...;
    # each call is busy 0.25 s, so the turns at 5, 10, 15 ... find it busy: it starts at
    # 0, 3, 8, 13, 18, 23, 28: every 5th frame = 2 Hz.
    with pytest.warns(RateWarning, match=r"tracker_hz 4 .* 10 fps .* 2 Hz"):
        starts, _ = _starts(4.0)
    assert starts == [0, 3, 8, 13, 18, 23, 28]


def test_a_rate_above_the_camera_rate_warns_that_it_runs_at_the_camera_rate():
    with pytest.warns(RateWarning, match=r"tracker_hz 1e\+09 .* 10 Hz"):
        starts, _ = _starts(1.0e9)
    assert starts == list(range(30))


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_run_reports_an_off_grid_rate_once_as_a_log_line_not_as_a_python_warning(tmp_path, jobs):
    """The driver reports the rate actually run once, in its log; planning the tasks asked the
    protocol for its timing again and printed Python's RateWarning a second time, with a
    source path (QA pass)."""
    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import run_experiment

    exp_file = tmp_path / "rw.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\n"
                        "dataset: {name: synthetic, n_sequences: 1, n_frames: 20, width: 160, height: 120}\n"
                        "tracker: {name: kcf}\nprotocol: {name: eop, tracker_hz: 7}\n")
    logs = []
    with warnings.catch_warnings():
        warnings.simplefilter("error", RateWarning)
        run_experiment(load_experiment(exp_file), jobs=jobs, progress=False, log=logs.append)
    assert sum("tracker_hz 7 is not 30 fps / n" in line for line in logs) == 1


def test_times_of_a_second_or_more_warn_that_times_are_in_seconds():
    """QA pass 14: `tracker_latency: 100` (meant as ms) ran the tracker at 0.4 Hz without a word."""
    proto = EOP(EOP.Params(tracker_hz=10, tracker_latency=100, link_delay_s={"tracker->estimator": 4},
                           jitter_s={"egomotion": 5}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        proto.timing(30.0)
    assert [str(w.message) for w in caught if w.category is RateWarning] == [
        "eop: tracker_latency 100 s: times are in seconds (for 100 ms write 0.1)",
        "eop: link_delay_s.tracker->estimator 4 s: times are in seconds (for 4 ms write 0.004)",
        "eop: jitter_s.egomotion 5 s: times are in seconds (for 5 ms write 0.005)"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        EOP(EOP.Params(tracker_hz=10, tracker_latency=0.5, jitter_s=0.01)).timing(30.0)   # plausible: silent
