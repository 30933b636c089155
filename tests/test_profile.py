"""``mata-eval profile``: a tracker that sleeps a known time gets latency percentiles near that
time; the written profile reads back and drives an ``eop`` run whose tracker starts follow the
hand-computed timeline; warm-up calls are not timed; the machine is described."""

from __future__ import annotations

import csv
import re
import textwrap
import time
from dataclasses import dataclass

import numpy as np
import pytest

from mata_eval.cli import build_parser, main
from mata_eval.run.config import load_experiment
from mata_eval.params import param
from mata_eval.deploy.profile import back_and_forth, describe_machine, profile_run, time_blocks
from mata_eval.core.registry import PluginEntry, Registry, load_registry
from mata_eval.run.runner import run_experiment
from mata_eval.run.scheduler import BlockError
from mata_eval.core.sequence import Sequence
from mata_eval.run.timing_profile import read_profile
from mata_eval.types import Box, Estimate, Motion, TrackerOutput


class Frames:
    """One sequence of ``n`` 8x8 frames at ``fps``; frame k is filled with k."""

    name = "frames"

    @dataclass(frozen=True)
    class Params:
        n: int = param(32, "frames")
        fps: float = param(32.0, "frame rate")

    def __init__(self, params):
        self.params = params

    def sequences(self):
        gt = np.tile([1.0, 1.0, 4.0, 4.0], (self.params.n, 1))
        return [Sequence("seqA", gt, self.params.fps, loader=lambda k: np.full((8, 8, 3), k, np.uint8))]


class SleepTracker:
    """Sleeps ``sleep_s`` per track() call (a real wall-clock cost)."""

    name = "sleeper"

    @dataclass(frozen=True)
    class Params:
        sleep_s: float = param(0.02, "seconds per call")
        threads: int = param(1, "library threads (0 = all cores), as the ONNX trackers have")
        backend: str = param("onnxruntime", "as the exported transformer trackers have")

    def __init__(self, params):
        self.params = params

    def initialize(self, image, box):
        pass

    def track(self, image, prior=None):
        time.sleep(self.params.sleep_s)
        return TrackerOutput(Box(float(image[0, 0, 0]), 0.0, 4.0, 4.0), 0.5)


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


class CostTracker:
    """Advances a fake clock by ``costs[i]`` at its i-th track() call; logs the frames it saw."""

    def __init__(self, clock, costs):
        self.clock, self.costs, self.seen = clock, list(costs), []

    def initialize(self, image, box):
        self.clock.now += 100.0     # initialisation is never timed

    def track(self, image, prior=None):
        self.clock.now += self.costs[len(self.seen)]
        self.seen.append(int(image[0, 0, 0]))
        return TrackerOutput(Box(1.0, 1.0, 4.0, 4.0), 0.5)


class CountingEgo:
    def __init__(self):
        self.seen = []

    def initialize(self, image):
        self.seen.append(int(image[0, 0, 0]))

    def estimate(self, image):
        self.seen.append(int(image[0, 0, 0]))
        return Motion.identity()


class RecordingEstimator:
    def __init__(self):
        self.calls = []

    def initialize(self, box, t):
        return Estimate(box)

    def step(self, t, motions=(), detections=()):
        self.calls.append((t, len(motions), len(detections)))
        return Estimate(detections[-1].value.box)


def _registry():
    real = load_registry()
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")  # noqa: E731
    return Registry({"dataset": {"frames": entry("dataset", Frames)},
                     "tracker": {"sleeper": entry("tracker", SleepTracker)},
                     "egomotion": {}, "estimator": {},
                     "protocol": {"eop": real.plugins["protocol"]["eop"]}}, ())


def test_back_and_forth_keeps_neighbours():
    assert back_and_forth(5, 10) == [1, 2, 3, 4, 3, 2, 1, 2, 3, 4]
    assert back_and_forth(2, 3) == [1, 1, 1]
    with pytest.raises(ValueError, match="at least 2 frames"):
        back_and_forth(1, 3)


def test_warmup_is_not_timed_and_every_block_is_fed():
    seq = Frames(Frames.Params(n=4, fps=10.0)).sequences()[0]
    clock = FakeClock()
    costs = [5.0, 5.0] + [0.01 * (i + 1) for i in range(6)]     # two slow warm-up calls
    tracker, ego, est = CostTracker(clock, costs), CountingEgo(), RecordingEstimator()
    samples = time_blocks(seq, tracker, ego, est, frames=6, warmup=2, clock=clock)
    np.testing.assert_allclose(samples["tracker"], [0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    assert tracker.seen == [1, 2, 3, 2, 1, 2, 3, 2]
    assert ego.seen == [0, 1, 2, 3, 2, 1, 2, 3, 2]
    assert len(samples["egomotion"]) == 6 and len(samples["estimator"]) == 6
    # The estimator gets one motion and one detection per call, at increasing camera times.
    assert [c[1:] for c in est.calls] == [(1, 1)] * 8
    np.testing.assert_allclose([c[0] for c in est.calls], np.arange(1, 9) / 10.0)


class Misbehaving(CostTracker):
    """Fails at its 3rd call: raises, or returns what a run would refuse."""

    def __init__(self, clock, fault):
        super().__init__(clock, [0.01] * 10)
        self.fault = fault

    def track(self, image, prior=None):
        out = super().track(image, prior)
        if len(self.seen) == 3:
            if self.fault == "raise":
                raise RuntimeError("exploded on purpose")
            return TrackerOutput(out.box, 7.5)
        return out


@pytest.mark.parametrize("fault, words", [("raise", "RuntimeError: exploded on purpose"),
                                          ("confidence", "returned confidence 7.5; expected a number in [0, 1]")])
def test_a_block_that_fails_while_profiled_is_named_with_its_call(fault, words):
    """QA pass: a raising tracker gave a raw traceback, and one returning confidence 7.5 got a
    profile; both now stop with the block, the frame and the call, as a run would."""
    seq = Frames(Frames.Params(n=4, fps=10.0)).sequences()[0]
    clock = FakeClock()
    with pytest.raises(BlockError, match=rf"tracker 'Misbehaving' failed at frame 3 .*: call 3 of 8: {re.escape(words)}"):
        time_blocks(seq, Misbehaving(clock, fault), frames=6, warmup=2, clock=clock)


def test_sleeping_tracker_profile_is_near_its_sleep(tmp_path):
    path = tmp_path / "exp.yaml"
    path.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: frames, n: 12}}
        tracker: {{name: sleeper, sleep_s: 0.02}}
        protocol: {{name: eop}}
        """))
    spec = load_experiment(path, _registry()).runs[0]
    prof = profile_run(spec, frames=10, warmup=2)
    b = prof.block("tracker")
    assert len(b.samples_s) == 10
    p = b.percentiles_s((50, 90))
    assert 0.02 <= p["50"] < 0.035            # sleep() never returns early; a loaded machine adds a little
    assert b.rate_hz == pytest.approx(1.0 / np.mean(b.samples_s))
    assert set(prof.blocks) == {"tracker"}    # no ego-motion or estimator in this run
    assert prof.machine["run"]["tracker"]["sleep_s"] == 0.02


def test_profile_file_drives_an_eop_run(tmp_path, monkeypatch):
    # A profile with exactly known latencies: 0.125 s per call (rate 8 Hz), measured on a fake clock.
    seq = Frames(Frames.Params()).sequences()[0]
    clock = FakeClock()
    samples = time_blocks(seq, CostTracker(clock, [0.125] * 12), frames=10, warmup=2, clock=clock)
    from mata_eval.run.timing_profile import profile_from_samples, write_profile

    prof_path = write_profile(profile_from_samples(samples, describe_machine()), tmp_path / "prof.json")
    back = read_profile(prof_path)
    assert back.block("tracker").rate_hz == pytest.approx(8.0)
    assert back.block("tracker").percentiles_s()["99"] == pytest.approx(0.125)

    exp = tmp_path / "exp.yaml"
    exp.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: frames}}
        tracker: {{name: sleeper, sleep_s: 0.0}}
        matrix:
          protocol:
            rate: {{name: eop, tracker_hz: profile, tracker_latency: profile, latency_profile: {prof_path}}}
            fast: {{name: eop, tracker_hz: 16, tracker_latency: profile, latency_profile: {prof_path}}}
        """))
    experiment = load_experiment(exp, _registry())
    outcomes = run_experiment(experiment, jobs=1, progress=False, log=lambda s: None)
    assert {o.status for o in outcomes} == {"done"}

    def starts(run):
        with open(tmp_path / "out" / run / "seqA.trace.csv") as f:
            rows = [r for r in csv.DictReader(f) if r["block"] == "tracker"]
        return ([int(r["frame"]) for r in rows if r["event"] == "start"],
                [int(r["frame"]) for r in rows if r["event"] == "skip"])

    # `tracker_hz: profile` on a 32 fps camera: a turn at every frame; each call is busy
    # 0.125 s = 4 frames, so it starts at frames 0, 4, ..., 28 and finds itself busy in between.
    assert starts("rate") == (list(range(0, 32, 4)), [k for k in range(32) if k % 4])
    # 16 Hz turns (every 2 frames) but a call still takes 0.125 s: every other turn is skipped.
    assert starts("fast") == (list(range(0, 32, 4)), list(range(2, 32, 4)))


def test_cli_writes_the_profile_and_asks_for_a_run(tmp_path, capsys, monkeypatch):
    path = tmp_path / "exp.yaml"
    path.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: frames, n: 6}}
        tracker: {{name: sleeper, sleep_s: 0.001}}
        matrix:
          protocol:
            a: {{name: eop}}
            b: {{name: eop, tracker_hz: 10}}
        """))
    import mata_eval.run.config as config

    real_load = config.load_experiment
    monkeypatch.setattr(config, "load_experiment", lambda p, registry=None: real_load(p, _registry()))
    parser = build_parser()
    args = parser.parse_args(["profile", str(path), "--out", str(tmp_path / "p.yaml"), "--frames", "5", "--warmup", "1"])
    assert args.func(args) == 2 and "choose one with --run (runs: a, b)" in capsys.readouterr().err
    args = parser.parse_args(["profile", str(path), "--run", "b", "--out", str(tmp_path / "p.yaml"),
                              "--frames", "5", "--warmup", "1"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "tracker" in out and "rate Hz" in out
    prof = read_profile(tmp_path / "p.yaml")
    assert len(prof.block("tracker").samples_s) == 5
    m = prof.machine
    assert m["cpu"] and m["threads"]["cpu_count"] >= 1 and "numpy" in m["versions"]
    assert m["run"]["run"] == "b" and m["run"]["sequence"] == "seqA"


def test_machine_description_of_a_jetson(monkeypatch):
    """ARM /proc/cpuinfo without 'model name' falls back to the device-tree model; the L4T
    release and nvpmodel's power mode are recorded (texts as a JetPack 6 Orin prints them)."""
    import mata_eval.deploy.profile as prof

    files = {
        "/proc/cpuinfo": "processor\t: 0\nBogoMIPS\t: 62.50\nCPU implementer\t: 0x41\nCPU part\t: 0xd42\n",
        "/proc/device-tree/model": "NVIDIA Jetson AGX Orin Developer Kit\x00",
        "/etc/nv_tegra_release": "# R36 (release), REVISION: 4.0, GCID: 37537400, BOARD: generic, EABI: aarch64\nx",
    }
    monkeypatch.setattr(prof, "_read", lambda path: files.get(path))
    commands = {"nvpmodel": "NV Power Mode: MODE_30W\n2\n", "nvidia-smi": None}
    monkeypatch.setattr(prof, "_command", lambda args, timeout=5.0: commands.get(args[0]))
    assert prof.cpu_model() == "NVIDIA Jetson AGX Orin Developer Kit"
    m = prof.describe_machine()
    assert m["jetson"]["l4t_release"].startswith("# R36 (release), REVISION: 4.0")
    assert m["power_mode"] == "NV Power Mode: MODE_30W 2"
    files["/proc/cpuinfo"] = "processor\t: 0\nmodel name\t: AMD EPYC 7B13\n"
    assert prof.cpu_model() == "AMD EPYC 7B13"


def test_time_scale_gives_the_profile_of_a_slower_device(tmp_path, capsys, monkeypatch):
    path = tmp_path / "exp.yaml"
    path.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: frames, n: 12}}
        tracker: {{name: sleeper, sleep_s: 0.02}}
        protocol: {{name: eop}}
        """))
    import mata_eval.run.config as config

    real_load = config.load_experiment
    monkeypatch.setattr(config, "load_experiment", lambda p, registry=None: real_load(p, _registry()))
    parser = build_parser()
    args = parser.parse_args(["profile", str(path), "--out", str(tmp_path / "p.json"), "--frames", "5",
                              "--warmup", "1", "--time-scale", "tracker=5"])
    assert args.func(args) == 0
    prof = read_profile(tmp_path / "p.json")
    assert 0.1 <= prof.block("tracker").percentiles_s((50,))["50"] < 0.175  # 5 x (20 ms + overshoot)
    assert prof.machine["time_scale"] == {"tracker": 5.0}
    for scales, words in ((["camera=2"], "--time-scale 'camera=2': expected FACTOR or BLOCK=FACTOR"),
                          (["0.5"], "--time-scale '0.5': expected FACTOR or BLOCK=FACTOR with a factor >= 1"),
                          (["tracker=6", "tracker=3"], "--time-scale 'tracker=3': tracker given twice"),
                          (["2", "3"], "--time-scale '3': every block given twice")):
        args = parser.parse_args(["profile", str(path), "--out", str(tmp_path / "q.json")]
                                 + [a for v in scales for a in ("--time-scale", v)])
        assert args.func(args) == 2
        assert words in capsys.readouterr().err
    from mata_eval.cli import _time_scales   # a block's own factor wins, in either order (review)

    assert _time_scales(["tracker=3", "2"]) == _time_scales(["2", "tracker=3"]) == {
        "tracker": 3.0, "egomotion": 2.0, "estimator": 2.0}
    # QA pass 14: a bad --out failed after the timing, naming a temporary file; profile of a file
    # whose eop reads the profile it is to write; --sequence named as --sequences
    for out, words in ((tmp_path, f"--out {tmp_path} is a folder: give the timing profile file to write"),
                       (tmp_path / "p.txt", "p.txt has neither .json nor .yaml at its end"),   # (QA pass 16b: JSON in .txt)
                       (path / "sub" / "p.json", f"is under {path}, a file")):   # (16c: said after the timing)
        assert main(["profile", str(path), "--out", str(out)]) == 2
        assert words in capsys.readouterr().err
    # its folder is made (QA pass 16b: docs/jetson.md's `--out profiles/orin-30W.json` failed on a fresh checkout)
    import mata_eval.cli as cli

    monkeypatch.setattr(cli, "_set_threads", lambda n: None)   # (not this test process's threads)
    assert main(["profile", str(path), "--out", str(tmp_path / "profiles" / "p.json"), "--frames", "3",
                 "--warmup", "1", "--threads", "1"]) == 0
    assert read_profile(tmp_path / "profiles" / "p.json").block("tracker")
    assert "does not reach the tracker" not in capsys.readouterr().out
    # --threads does not reach ONNX Runtime: a tracker left at all cores is named (QA pass 16b)
    path.write_text(path.read_text().replace("sleep_s: 0.02}", "sleep_s: 0.02, threads: 0}"))
    assert main(["profile", str(path), "--out", str(tmp_path / "p.json"), "--frames", "3", "--warmup", "1",
                 "--threads", "1"]) == 0
    assert "note: --threads 1 does not reach the tracker: its `threads: 0`" in capsys.readouterr().out
    path.write_text(path.read_text().replace("threads: 0}", "threads: 0, backend: torch}"))   # torch reads it
    assert main(["profile", str(path), "--out", str(tmp_path / "p.json"), "--frames", "3", "--warmup", "1",
                 "--threads", "1"]) == 0
    assert "does not reach" not in capsys.readouterr().out
    args = parser.parse_args(["profile", str(path), "--out", str(tmp_path / "q.json"), "--sequence", "nope"])
    assert args.func(args) == 2
    assert "unknown sequence name(s) nope (--sequence); the sequences are: " in capsys.readouterr().err
    path.write_text(path.read_text().replace("{name: eop}", f"{{name: eop, tracker_hz: profile, "
                                                            f"latency_profile: {tmp_path / 'new.json'}}}"))
    args = parser.parse_args(["profile", str(path), "--out", str(tmp_path / "new.json")])
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert "cannot read timing profile" in err and "hint: profile times the blocks only" in err


def test_profile_checks_what_validate_and_run_check_first(tmp_path, capsys, monkeypatch):
    """QA pass 13: profile never ran the preflight, so a wrong checkpoint, a missing backend or
    device ended in a traceback where validate and run give one line."""
    from mata_eval.cli import main

    (tmp_path / "qa_prof_broken.py").write_text(
        "from dataclasses import dataclass\n"
        "class Broken:\n"
        "    @dataclass(frozen=True)\n    class Params:\n        pass\n"
        "    def __init__(self, params):\n        raise RuntimeError('TensorRT is not installed')\n"
        "    def initialize(self, image, box): pass\n    def track(self, image, prior=None): pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    path = tmp_path / "exp.yaml"
    path.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 8, "
                    "width: 160, height: 120}\ntracker: {name: 'qa_prof_broken:Broken'}\n")
    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    assert main(["profile", str(path), "--out", str(tmp_path / "p.json"), "--frames", "2"]) == 2
    err = capsys.readouterr().err
    assert "error: tracker qa_prof_broken:Broken" in err and "TensorRT is not installed" in err
    assert not (tmp_path / "p.json").exists()
    # a run marked optional is profiled or refused with the same line (review: "skipping ..." then
    # "no run left to do")
    path.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 8, "
                    "width: 160, height: 120}\ntracker: {name: kcf}\n"
                    "matrix:\n  tracker:\n    kcf: {name: kcf}\n    broken: {name: 'qa_prof_broken:Broken'}\n"
                    "optional: [broken]\n")
    assert main(["profile", str(path), "--run", "broken", "--out", str(tmp_path / "p.json"), "--frames", "2"]) == 2
    captured = capsys.readouterr()
    assert "skipping" not in captured.out + captured.err and "no run left" not in captured.err
    assert "error: tracker qa_prof_broken:Broken (run broken): TensorRT is not installed" in captured.err   # (QA pass 16b: "(the run)")
