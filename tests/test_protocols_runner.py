"""Baseline and MATA under LTP and EOP, from one experiment file through the runner: the
predictions, frames and trace files follow the hand-computed timeline, and the timeline command
draws a sequence of the run folder."""

from __future__ import annotations

import csv
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from mata_eval.cli import build_parser
from mata_eval.run.config import load_experiment
from mata_eval.params import param
from mata_eval.core.registry import PluginEntry, Registry, load_registry
from mata_eval.run.runner import run_experiment
from mata_eval.core.sequence import Sequence
from mata_eval.types import Box, Estimate, TrackerOutput


class OneSequence:
    """One 12-frame sequence whose frame k is filled with k; the GT box starts at x = -1."""

    name = "one"

    @dataclass(frozen=True)
    class Params:
        n: int = param(12, "frames")

    def __init__(self, params):
        self.params = params

    def sequences(self):
        gt = np.tile([-1.0, 0.0, 10.0, 10.0], (self.params.n, 1))
        return [Sequence("seqA", gt, 30.0, loader=lambda k: np.full((480, 640, 3), k, np.uint8))]


class FrameIndexTracker:
    """Box x = the frame index it saw."""

    name = "frameidx"

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params):
        pass

    def initialize(self, image, box):
        pass

    def track(self, image, prior=None):
        return TrackerOutput(Box(float(image[0, 0, 0]), 0.0, 10.0, 10.0), 0.9)


class HoldNewest:
    """Holds the newest detection it was given."""

    name = "hold"

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params):
        pass

    def initialize(self, box, t):
        self.box = box
        return Estimate(box)

    def step(self, t, motions=(), detections=()):
        if detections:
            self.box = detections[-1].value.box
        return Estimate(self.box)


def _registry():
    real = load_registry()
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    return Registry({"dataset": {"one": entry("dataset", OneSequence)},
                     "tracker": {"frameidx": entry("tracker", FrameIndexTracker)},
                     "egomotion": {}, "estimator": {"hold": entry("estimator", HoldNewest)},
                     "protocol": {n: real.plugins["protocol"][n] for n in ("ltp", "eop", "dsp")}}, ())


def test_baseline_and_mata_under_ltp_and_eop(tmp_path):
    path = tmp_path / "exp.yaml"
    path.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: one}}
        tracker: {{name: frameidx}}
        egomotion: null
        estimator: {{name: hold}}
        matrix:
          config:
            baseline: {{estimator: null}}
            mata: {{}}
          protocol:
            ltp: {{name: ltp}}
            eop10: {{name: eop, tracker_hz: 10}}
            dsp3: {{name: dsp, n: 3}}
        """))
    exp = load_experiment(path, _registry())
    outcomes = run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert {o.status for o in outcomes} == {"done"}
    out = tmp_path / "out"
    x = {r.name: np.loadtxt(out / r.name / "seqA.txt", delimiter=",")[:, 0] for r in exp.runs}
    for cfg in ("baseline", "mata"):
        np.testing.assert_array_equal(x[f"{cfg}-ltp"], [-1] + list(range(1, 12)))
        np.testing.assert_array_equal(x[f"{cfg}-eop10"], [-1] * 6 + [3] * 3 + [6] * 3)
        np.testing.assert_array_equal(x[f"{cfg}-dsp3"], [-1] * 3 + [3] * 3 + [6] * 3 + [9] * 3)

    with open(out / "mata-eop10" / "seqA.frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["frame", "scored", "confidence", "tracker_ms", "estimator_ms", "source_frame",
                             "tracker_x", "tracker_y", "tracker_w", "tracker_h",
                             "search_x", "search_y", "search_w", "search_h", "prior_x", "prior_y"]
    assert [r["frame"] for r in rows] == [str(k) for k in range(12)]
    assert [k for k, r in enumerate(rows) if r["tracker_ms"] != "nan"] == [0, 3, 6, 9]
    assert [float(r["confidence"]) for r in rows[6:]] == pytest.approx([0.9] * 6)
    with open(out / "baseline-dsp3" / "seqA.frames.csv") as f:
        assert [r["scored"] for r in csv.DictReader(f)] == ["1", "0", "0"] * 4
    with open(out / "mata-eop10" / "seqA.trace.csv") as f:
        trace = list(csv.DictReader(f))
    assert [int(r["frame"]) for r in trace if r["block"] == "tracker" and r["event"] == "start"] == [0, 3, 6, 9]

    parser = build_parser()
    args = parser.parse_args(["timeline", str(out / "mata-eop10"), "seqA", "--out", str(tmp_path / "t.png")])
    assert args.func(args) == 0 and (tmp_path / "t.png").stat().st_size > 1000
