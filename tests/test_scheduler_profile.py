"""Timing profiles: round trips, sampling (Monte-Carlo against the distribution's own moments),
located errors, and an EOP run whose tracker latency is drawn from a profile."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mata_eval.run.config import load_experiment
from mata_eval.run.scheduler import run_sequence
from mata_eval.run.timing_profile import (BlockProfile, ProfileError, profile_from_samples, read_profile,
                                      write_profile)
from mata_eval_plugins.protocols.eop import EOP

from test_scheduler import FrameTracker, make_sequence


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_round_trip(tmp_path, suffix):
    samples = {"tracker": [0.08, 0.1, 0.09, 0.12], "egomotion": [0.004, 0.005]}
    prof = profile_from_samples(samples, {"cpu": "test cpu", "threads": 2}, bins=3, created="2026-01-01")
    path = write_profile(prof, tmp_path / f"p{suffix}")
    back = read_profile(path)
    assert back.machine == {"cpu": "test cpu", "threads": 2} and back.created == "2026-01-01"
    np.testing.assert_array_equal(back.blocks["tracker"].samples_s, samples["tracker"])
    np.testing.assert_array_equal(back.blocks["tracker"].hist_counts, [2, 1, 1])
    assert back.blocks["tracker"].mean_s == pytest.approx(0.0975)
    assert back.blocks["tracker"].rate_hz == pytest.approx(1 / 0.0975)
    assert back.blocks["egomotion"].percentiles_s()["50"] == pytest.approx(0.0045)


def test_histogram_sampling_matches_its_distribution():
    # Two bins of equal mass, [0, 1) and [1, 3): mean 0.25 + 1.0 = 1.25, P(x < 1) = 0.5.
    b = BlockProfile(hist_edges_s=np.array([0.0, 1.0, 3.0]), hist_counts=np.array([5.0, 5.0]))
    x = b.sample(np.random.default_rng(0), size=40000)
    assert x.mean() == pytest.approx(1.25, abs=0.02)
    assert (x < 1).mean() == pytest.approx(0.5, abs=0.01)
    assert x.min() >= 0 and x.max() <= 3
    assert b.mean_s == pytest.approx(1.25)
    assert b.percentiles_s((50, 75)) == {"50": pytest.approx(1.0), "75": pytest.approx(2.0)}
    # Seeded: the same seed draws the same latencies.
    assert b.sample(np.random.default_rng(7)) == b.sample(np.random.default_rng(7))


def test_samples_are_resampled():
    b = BlockProfile(samples_s=np.array([0.01, 0.05]))
    x = b.sample(np.random.default_rng(1), size=10000)
    assert set(np.unique(x)) == {0.01, 0.05}
    assert (x == 0.05).mean() == pytest.approx(0.5, abs=0.02)


@pytest.mark.parametrize("doc,match", [
    ({"format": "other", "version": 1, "blocks": {}}, "key 'format'"),
    ({"format": "mata-eval timing profile", "version": 1, "blocks": {}}, "key 'blocks'"),
    ({"format": "mata-eval timing profile", "version": 1, "blocks": {"tracker": {}}},
     r"blocks.tracker': expected 'samples_s' and/or 'histogram'"),
    ({"format": "mata-eval timing profile", "version": 1, "blocks": {"tracker": {"samples_s": [0.1, -1]}}},
     r"blocks.tracker.samples_s': expected finite non-negative"),
    ({"format": "mata-eval timing profile", "version": 1,
      "blocks": {"tracker": {"histogram": {"edges_s": [0, 1], "counts": [1, 2]}}}}, "len\\(edges_s\\)"),
])
def test_bad_files_name_file_and_key(tmp_path, doc, match):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ProfileError, match=match) as info:
        read_profile(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ProfileError, match="cannot read timing profile"):
        read_profile(tmp_path / "nope.json")


def test_eop_draws_tracker_latency_from_profile(tmp_path):
    path = write_profile(profile_from_samples({"tracker": [0.05, 0.15]}), tmp_path / "p.json")
    proto = EOP(EOP.Params(tracker_latency="profile", latency_profile=str(path)))
    run = run_sequence(make_sequence(200, frame_of=lambda k: k % 256), FrameTracker(), None, None, proto,
                       np.random.default_rng(3))
    starts = [e.t for e in run.trace if e.block == "tracker" and e.event == "start"]
    pubs = [e.t for e in run.trace if e.block == "tracker" and e.event == "publish"]
    lat = np.round(np.array(pubs) - np.array(starts[:len(pubs)]), 9)
    assert set(lat) == {0.05, 0.15}
    # Each call starts at the first frame at or after the previous publish (camera-rate turns).
    for t_pub, t_next in zip(pubs, starts[1:]):
        assert t_next == pytest.approx(np.ceil(t_pub * 30 - 1e-6) / 30)
    # `tracker_hz: profile`: the block runs as fast as the profile says (1 / mean = 10 Hz): a
    # turn at every camera frame and a one-period latency of 0.1 s.
    proto = EOP(EOP.Params(tracker_hz="profile", latency_profile=str(path)))
    timing = proto.timing(30.0)
    assert timing.blocks["tracker"].hz == pytest.approx(30.0)
    assert timing.blocks["tracker"].latency.draw(None, 0.0) == pytest.approx(0.1)


def test_profile_rate_that_does_not_divide_the_camera_rate(tmp_path):
    """A 9.5 Hz tracker (105.3 ms a call) on a 30 Hz camera: busy for 3.16 frames, it starts at
    the first frame after each call, every 4th frame (7.5 Hz), like on the board; it does not lose
    every other turn of a 9.5 Hz grid (frames 0, 4, 10, 16, ... = 5.5 Hz)."""
    path = write_profile(profile_from_samples({"tracker": [1 / 9.5]}), tmp_path / "p.json")
    proto = EOP(EOP.Params(tracker_hz="profile", latency_profile=str(path)))
    run = run_sequence(make_sequence(30), FrameTracker(), None, None, proto, np.random.default_rng(0))
    assert [e.frame for e in run.trace if e.block == "tracker" and e.event == "start"] == [0, 4, 8, 12, 16, 20, 24, 28]


def test_profile_without_the_block(tmp_path):
    path = write_profile(profile_from_samples({"egomotion": [0.01]}), tmp_path / "p.json")
    with pytest.raises(ProfileError, match="no block 'tracker' in the profile \\(it has: egomotion\\)"):
        EOP.Params(tracker_latency="profile", latency_profile=str(path))
    with pytest.raises(ProfileError, match="cannot read timing profile"):
        EOP.Params(tracker_latency="profile", latency_profile=str(tmp_path / "missing.json"))


def test_a_rerun_after_the_profile_was_measured_again_is_refused(tmp_path, monkeypatch, capsys):
    """QA pass 14 (embedded engineer): the manifest held the profile's path only, so a rerun
    after `mata-eval profile` wrote new latencies into it kept the old results as they were."""
    from mata_eval.cli import main

    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    profile = tmp_path / "p.json"
    write_profile(profile_from_samples({"tracker": [0.2, 0.2]}), profile)            # 5 Hz
    (tmp_path / "exp.yaml").write_text(
        f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 12, width: 160, "
        f"height: 120}}\ntracker: {{name: kcf}}\nprotocol: {{name: eop, tracker_hz: profile, "
        f"tracker_latency: profile, latency_profile: {profile}}}\n")
    run = ["run", str(tmp_path / "exp.yaml"), "-q", "-j", "1", "--no-report"]
    assert main(run) == 0
    boxes = tmp_path / "out" / "exp" / "syn001_cruise.txt"
    at_5hz = boxes.read_text()
    write_profile(profile_from_samples({"tracker": [0.04, 0.04]}), profile)          # measured again: 25 Hz
    capsys.readouterr()
    assert main(run) == 2
    assert (f"holds results made with another content of its latency_profile file {profile} (sha256 "
            in capsys.readouterr().err)
    assert main(run + ["--force"]) == 0
    assert boxes.read_text() != at_5hz   # the new latencies give other held boxes


def test_a_profile_measured_with_another_tracker_is_named(tmp_path, monkeypatch, capsys):
    """QA pass 14: a profile of kcf drove a vittrack run's rate without a word."""
    import json

    from mata_eval.cli import main

    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    profile = write_profile(profile_from_samples({"tracker": [0.1, 0.1]}, {"run": {"tracker": {"name": "vittrack"}}}),
                            tmp_path / "p.json")
    exp = tmp_path / "exp.yaml"
    exp.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 12, "
                   f"width: 160, height: 120}}\ntracker: {{name: kcf}}\nprotocol: {{name: eop, "
                   f"tracker_hz: profile, latency_profile: {profile}}}\n")
    line = (f"warning: exp: the tracker rate/latency comes from {profile}, measured with tracker vittrack, not "
            "this run's kcf: measure one with this run's blocks (mata-eval profile)")
    assert main(["validate", str(exp)]) == 0
    assert line in capsys.readouterr().out
    assert main(["run", str(exp), "-q", "-j", "1", "--no-report"]) == 0
    assert line in capsys.readouterr().out
    assert json.loads((tmp_path / "out" / "exp" / "manifest.json").read_text())["warnings"] == [
        line.removeprefix("warning: exp: ")]
    exp.write_text(exp.read_text().replace("tracker_hz: profile", "tracker_hz: 10")   # not read from it: nothing
                   .replace(str(tmp_path / "out"), str(tmp_path / "out2")))   # (out: results of the profile's rate)
    assert main(["validate", str(exp)]) == 0
    assert "warning" not in capsys.readouterr().out
    # the same tracker with other parameters (QA pass 16b: a profile of another backend, unsaid)
    exp.write_text(exp.read_text().replace("tracker_hz: 10", "tracker_hz: profile"))
    kcf = load_experiment(exp).runs[0].resolved["tracker"]
    first = sorted(k for k in kcf if k != "name")[0]
    # not a parameter the profile does not record (added since: QA pass 16c, the shipped profiles
    # warned 24 times of those); the value rules: test_profile_parameters_compare_as_timing_does
    cases = ((kcf, None), ({k: v for k, v in kcf.items() if k != first}, None),
             ({**kcf, first: "other"}, f"measured with other tracker parameters ({first}: 'other' then, "
                                       f"{kcf[first]!r} now)"))
    for record, words in cases:
        write_profile(profile_from_samples({"tracker": [0.1, 0.1]}, {"run": {"tracker": record}}), profile)
        assert main(["validate", str(exp)]) == 0
        out = capsys.readouterr().out
        assert (words in out) if words else "warning" not in out


def test_values_derived_from_the_samples_must_agree_with_them(tmp_path):
    """rate_hz, mean_s and percentiles_s are written for people and every draw comes from the
    samples (then the histogram): one edited by hand is refused, naming the key, instead of being
    ignored (QA pass: rate_hz 30 -> 10 still ran the tracker at 30 Hz); so is a histogram beside
    samples that it does not count."""
    path = write_profile(profile_from_samples({"tracker": [0.03, 0.034, 0.032]}), tmp_path / "p.json")
    doc = json.loads(path.read_text())
    read_profile(path)   # as written: accepted
    for key, value in (("rate_hz", 10.0), ("mean_s", 0.1), ("percentiles_s", {"50": 0.1})):
        bad = tmp_path / f"bad_{key}.json"
        bad.write_text(json.dumps({**doc, "blocks": {"tracker": {**doc["blocks"]["tracker"], key: value}}}))
        with pytest.raises(ProfileError, match=rf"bad_{key}.json: key 'blocks.tracker.{key}.* but its samples give"):
            read_profile(bad)
    entry = {**doc["blocks"]["tracker"], "histogram": {"edges_s": [0.1, 0.2], "counts": [3]}}
    bad = tmp_path / "hist.json"
    bad.write_text(json.dumps({**doc, "blocks": {"tracker": entry}}))
    with pytest.raises(ProfileError, match=r"blocks.tracker.histogram' does not count its samples_s"):
        read_profile(bad)
    alone = {k: v for k, v in doc["blocks"]["tracker"].items() if k == "samples_s"}   # samples alone: fine
    (tmp_path / "alone.json").write_text(json.dumps({**doc, "blocks": {"tracker": alone}}))
    assert read_profile(tmp_path / "alone.json").blocks["tracker"].rate_hz == pytest.approx(1 / 0.032)
    # the histogram alone (its samples deleted, as the message above allows) is read: its values
    # were written from the samples it counts, so they agree to a bin (QA pass 16c: refused); a
    # value set to null is no value
    hist = {k: v for k, v in doc["blocks"]["tracker"].items() if k != "samples_s"}
    for entry in (hist, {**hist, "rate_hz": None}):
        (tmp_path / "hist_only.json").write_text(json.dumps({**doc, "blocks": {"tracker": entry}}))
        assert read_profile(tmp_path / "hist_only.json").blocks["tracker"].samples_s is None
    (tmp_path / "hist_only.json").write_text(json.dumps({**doc, "blocks": {"tracker": {**hist, "rate_hz": 10.0}}}))
    with pytest.raises(ProfileError, match=r"rate_hz' is 10.0, but its histogram gives 31.2"):
        read_profile(tmp_path / "hist_only.json")


def test_a_profile_in_milliseconds_is_warned_of(tmp_path):
    """QA pass: samples_s [50, 60, 70] (ms) ran the tracker at 0.4 Hz without a word."""
    from mata_eval.run.scheduler import RateWarning

    path = write_profile(profile_from_samples({"tracker": [50.0, 60.0, 70.0]}), tmp_path / "ms.json")
    eop = EOP(EOP.Params(tracker_hz="profile", tracker_latency="profile", latency_profile=str(path)))
    with pytest.warns(RateWarning, match=r"the tracker's median latency is 60 s: profile samples are in seconds"):
        eop.timing(30.0)


def test_profile_parameters_compare_as_timing_does():
    """A null reads as the parameter's default on both sides and a file by its name (the same
    model file named another way, or found through an environment variable on one side, is no
    difference), but a null against a set value and another file name are (QA pass 16d: both
    were skipped, so a profile of another model file or with a second LK pass passed unsaid;
    QA pass 16e: a file found through $MATA_SHARED_DATA, a Windows path, warned)."""
    from dataclasses import dataclass
    from types import SimpleNamespace

    from mata_eval.run.runner import _comparable

    @dataclass(frozen=True)
    class Params:
        model: str | None = None
        fb_threshold: float | None = None
        win: int = 11

    block = lambda **p: SimpleNamespace(name="b", cls=SimpleNamespace(Params=Params), params=Params(**p))  # noqa: E731
    same = lambda was, **now: (lambda a, b: a == b)(*_comparable({"name": "b", **was}, block(**now)))  # noqa: E731
    assert same({"win": None}, win=11)                                       # null: the default
    assert same({"model": "../../data/models/x.onnx"}, model="/data/models/x.onnx")
    assert not same({"model": "/data/models/x.onnx"}, model="/data/models/y.onnx")
    assert not same({"fb_threshold": None}, fb_threshold=1.0)                 # a second LK pass
    assert same({"added_since": 3}, win=11)                                   # the profile does not record it
    assert same({"model": "/data/models/x.onnx"}) and same({"model": None}, model="/data/models/x.onnx")
    assert same({"model": "C:\\models\\x.onnx"}, model="/data/models/x.onnx")


def test_profile_parameters_compare_as_their_preset_resolves_them(tmp_path):
    """QA pass 16e: a null that the estimator's preset resolves showed as "None now", and a run
    spelling out its preset's value warned against a profile that left it null."""
    from types import SimpleNamespace

    from mata_eval.core.params import build_params
    from mata_eval.run.runner import _comparable
    from mata_eval_plugins.estimators.homography_ekf import HomographyEKF

    block = lambda **p: SimpleNamespace(name="homography_ekf", cls=HomographyEKF,  # noqa: E731
                                        params=build_params(HomographyEKF.Params, p))
    resolved = build_params(HomographyEKF.Params, {}).resolved()
    assert _comparable({"name": "homography_ekf", "delay": None}, block(delay=resolved.delay)) == ({}, {})
    assert _comparable({"name": "homography_ekf", "delay": "ignore"}, block()) == (
        {"delay": "ignore"}, {"delay": resolved.delay})
