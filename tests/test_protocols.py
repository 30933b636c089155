"""Protocol plugins: discovery, YAML parameters and their errors, what each preset asks of the
scheduler; the timeline plot and its CLI."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from mata_eval.cli import build_parser
from mata_eval.params import build_params
from mata_eval.core.registry import load_registry
from mata_eval.run.scheduler import FixedLatency, WallTimeLatency, run_sequence
from mata_eval.report.timeline import calls_from_trace, held_segments, plot_timeline
from mata_eval_plugins.protocols.dsp import DSP
from mata_eval_plugins.protocols.eop import EOP
from mata_eval_plugins.protocols.ltp import LTP

from test_scheduler import FrameTracker, LogEstimator, FrameEgoMotion, make_sequence


def test_registered_through_entry_points():
    reg = load_registry()
    assert {"ltp", "dsp", "vot_rt", "eop"} <= set(reg.names("protocol"))
    for name in ("ltp", "dsp", "vot_rt", "eop"):
        entry = reg.get("protocol", name)
        assert entry.description and hasattr(entry.cls(build_params(entry.cls.Params, {})), "timing")


def test_eop_yaml_parameters():
    cls = load_registry().get("protocol", "eop").cls
    p = build_params(cls.Params, {"tracker_hz": 10, "egomotion_latency": 0.01, "jitter_s": {"tracker": 0.002},
                                  "link_delay_s": {"egomotion->estimator": 0.005}})
    timing = cls(p).timing(30.0)
    tr = timing.blocks["tracker"]
    assert tr.hz == 10.0 and tr.latency == FixedLatency(pytest.approx(0.1)) and tr.jitter_s == 0.002
    assert timing.blocks["egomotion"].latency == FixedLatency(0.01) and timing.blocks["egomotion"].hz == 30.0
    assert timing.blocks["estimator"].latency == FixedLatency(0.0) and timing.blocks["estimator"].jitter_s == 0
    assert timing.link_delay_s == {("egomotion", "estimator"): 0.005}
    # Default: tracker at the camera rate with a one-frame latency (the paper's "EOP @ 30 Hz").
    t30 = cls(build_params(cls.Params, {})).timing(30.0).blocks["tracker"]
    assert t30.hz == 30.0 and t30.latency.seconds == pytest.approx(1 / 30)


@pytest.mark.parametrize("values,match", [
    ({"tracker_latency": "slow"}, "tracker_latency: expected 'period'"),
    ({"tracker_hz": -5}, "tracker_hz: expected"),
    ({"tracker_hz": "fast"}, "tracker_hz: expected"),
    ({"tracker_latency": "profile"}, "latency_profile: a rate or latency is 'profile'"),
    ({"link_delay_s": {"tracker->camera": 0.1}}, "key 'tracker->camera'"),
    ({"link_delay_s": {"tracker->estimator": -1}}, "link_delay_s.tracker->estimator: expected seconds"),
    ({"jitter_s": {"trackr": 0.1}}, "unknown block 'trackr'"),
])
def test_eop_bad_parameters(values, match):
    with pytest.raises(ValueError, match=match):
        build_params(EOP.Params, values)


def test_dsp_and_vot_rt_parameters():
    reg = load_registry()
    with pytest.raises(ValueError, match="dsp: n: expected an integer >= 1"):
        build_params(reg.get("protocol", "dsp").cls.Params, {"n": 0})
    timing = DSP(DSP.Params(n=4)).timing(30.0)
    assert timing.camera_hz == 7.5 and all(b.hz == 7.5 for b in timing.blocks.values())
    vot = reg.get("protocol", "vot_rt").cls
    graced = vot(build_params(vot.Params, {"time_scale": 2})).timing(30.0).blocks["tracker"].latency
    assert (graced.inner, graced.interval, graced.left) == (WallTimeLatency(2.0), 1 / 30, 1)
    assert vot(build_params(vot.Params, {"time_scale": 2, "grace": 0})).timing(30.0).blocks["tracker"].latency \
        == WallTimeLatency(2.0)
    assert vot(build_params(vot.Params, {})).timing(30.0).blocks["estimator"].latency == FixedLatency(0.0)
    timed = vot(build_params(vot.Params, {"timed_blocks": ["tracker", "egomotion"], "grace": 0})).timing(30.0)
    assert timed.blocks["egomotion"].latency == WallTimeLatency(1.0)
    with pytest.raises(ValueError, match="vot_rt: grace: expected a number of calls >= 0"):
        build_params(vot.Params, {"grace": -1})
    with pytest.raises(ValueError, match="time_scale"):
        build_params(vot.Params, {"time_scale": 0})
    with pytest.raises(ValueError, match="unknown block 'ego'"):
        build_params(vot.Params, {"timed_blocks": ["ego"]})


def test_timeline_calls_and_held_output():
    run = run_sequence(make_sequence(12), FrameTracker(), None, None, EOP(EOP.Params(tracker_hz=10.0)),
                       np.random.default_rng(0))
    calls = calls_from_trace(run.trace_rows())
    assert [(c.frame, round(c.t_publish * 30) if c.t_publish else None) for c in calls["tracker"]] == \
        [(0, 3), (3, 6), (6, 9), (9, None)]
    segs = held_segments(run.trace_rows(), 12)
    assert [(round(a * 30), round(b * 30), src) for a, b, src in segs] == [(0, 6, 0), (6, 9, 3), (9, 12, 6)]
    # The held output the plot draws is the one the scheduler scored.
    for a, b, src in segs:
        assert set(run.source_frame[round(a * 30):round(b * 30)]) == {src}


def test_timeline_plot_and_cli(tmp_path):
    run = run_sequence(make_sequence(40), FrameTracker(), FrameEgoMotion(), LogEstimator(),
                       EOP(EOP.Params(tracker_hz=7.5)), np.random.default_rng(0))
    (tmp_path / "seqA.trace.csv").write_text(run.trace_csv())
    out = plot_timeline(run.trace_rows(), tmp_path / "direct.png", frames=(0, 20))
    assert cv2.imread(str(out)) is not None
    odd = r"a|b $\frac$ x"   # run names and titles are text, not mathtext (review: a parse error)
    assert cv2.imread(str(plot_timeline({odd: run.trace_rows(), "b": run.trace_rows()}, tmp_path / "odd.png",
                                        title=odd))) is not None
    parser = build_parser()
    args = parser.parse_args(["timeline", str(tmp_path), "seqA", "--frames", "4:30"])
    assert args.func(args) == 0
    img = cv2.imread(str(tmp_path / "seqA.timeline.png"))
    assert img is not None and img.shape[1] > img.shape[0]
    other = tmp_path / "eop"
    other.mkdir()
    eop = run_sequence(make_sequence(40), FrameTracker(), None, None, EOP(EOP.Params(tracker_hz=10.0)),
                       np.random.default_rng(0))
    (other / "seqA.trace.csv").write_text(eop.trace_csv())
    args = parser.parse_args(["timeline", str(tmp_path), "seqA", "--compare", str(other), "--out",
                              str(tmp_path / "cmp.png")])
    assert args.func(args) == 0
    stacked = cv2.imread(str(tmp_path / "cmp.png"))
    assert stacked.shape[0] > img.shape[0]  # two panels
    args = parser.parse_args(["timeline", str(tmp_path), "seqA", "--compare", str(tmp_path / "none")])
    assert args.func(args) == 2
    args = parser.parse_args(["timeline", str(tmp_path), "nope"])
    assert args.func(args) == 2
    with pytest.raises(SystemExit):
        parser.parse_args(["timeline", str(tmp_path), "seqA", "--frames", "9:3"])


def test_dsp_timeline_draws(tmp_path):
    run = run_sequence(make_sequence(12), FrameTracker(), None, None, DSP(DSP.Params(n=3)), np.random.default_rng(0))
    assert cv2.imread(str(plot_timeline(run.trace_rows(), tmp_path / "dsp.png"))) is not None
    segs = held_segments(run.trace_rows(), 12)
    assert [(round(a * 30), src) for a, b, src in segs] == [(0, 0), (3, 3), (6, 6), (9, 9)]
    assert LTP().timing(25.0).camera_hz == 25.0
