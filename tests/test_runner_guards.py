"""The runner's guarantees: workers run the configuration the driver resolved, one writer per
run folder, a block call that never returns or raises SystemExit fails only its sequence."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np
import pytest
from filelock import FileLock

import mata_eval.run.config
from mata_eval.run.config import load_experiment
from mata_eval.core.params import param
from mata_eval.core.registry import PluginEntry, Registry, load_registry
from mata_eval.core.errors import UserError
from mata_eval.run.runner import RunLocked, run_experiment
from mata_eval.core.sequence import Sequence
from mata_eval.core.types import Box, TrackerOutput


class Clips:
    """Four 5-frame sequences; the target of c2 sits at y = 20 (where Faulty misbehaves)."""

    name = "clips"

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params):
        self.params = params

    def sequences(self):
        out = []
        for i in range(4):
            gt = np.array([[10.0 + k, 20.0 if i == 2 else 10.0, 8.0, 8.0] for k in range(5)])
            out.append(Sequence(f"c{i}", gt, 30.0, loader=lambda k: np.full((32, 48, 3), k, np.uint8)))
        return out


class Faulty:
    """Moves the box ``step`` px right per call; on the sequence whose target is at y = 20 it
    does what ``fault`` says at its 2nd call."""

    name = "faulty"

    @dataclass(frozen=True)
    class Params:
        step: float = param(1.0, "px per call")
        fault: str = param("none", "none | hang | exit | interrupt | confidence_nan | confidence_big | "
                                   "confidence_text | tuple_box | text_box | negative_box")

    def __init__(self, params):
        self.params = params
        self.calls = 0

    def initialize(self, image, box):
        self.box = box
        self.victim = box.y == 20.0

    def track(self, image, prior=None):
        self.calls += 1
        fault = self.params.fault if self.victim and self.calls == 2 else "none"
        if fault == "hang":
            time.sleep(60)
        elif fault == "exit":
            raise SystemExit(3)
        elif fault == "interrupt":
            raise KeyboardInterrupt
        self.box = Box(self.box.x + self.params.step, self.box.y, self.box.w, self.box.h)
        confidence = {"confidence_nan": float("nan"), "confidence_big": 7.5, "confidence_text": "0.5"}.get(fault, 1.0)
        if fault == "tuple_box":
            return TrackerOutput(tuple(self.box.as_array()), 0.5)
        if fault == "text_box":
            return TrackerOutput(Box("154.9", self.box.y, self.box.w, self.box.h), 0.5)
        if fault == "negative_box":
            return TrackerOutput(Box(10.0, 10.0, -5.0, 10.0), 0.5)
        return TrackerOutput(self.box, confidence)


@pytest.fixture
def registry(monkeypatch):
    real = load_registry()
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    reg = Registry({**real.plugins, "dataset": {"clips": entry("dataset", Clips)},
                    "tracker": {"faulty": entry("tracker", Faulty)}}, ())
    monkeypatch.setattr(mata_eval.run.config, "load_registry", lambda: reg)
    return reg


def _write(tmp_path, tracker="{name: faulty}", extra=""):
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: clips\ntracker: {tracker}\n{extra}")
    return p


def _statuses(outcomes):
    return {o.sequence: o.status for o in outcomes}


QUIET = dict(progress=False, log=lambda s: None)


def test_workers_run_the_configuration_the_driver_resolved(tmp_path, registry):
    """Editing the file while a run goes on changes nothing: the workers never read it."""
    p = _write(tmp_path, "{name: faulty, step: 1.0}")
    exp = load_experiment(p, registry)
    p.write_text(p.read_text().replace("step: 1.0", "step: 5.0"))  # edited after loading
    run_experiment(exp, jobs=2, **QUIET)
    run = tmp_path / "out" / "exp"
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["config"]["tracker"]["step"] == 1.0
    for i in range(4):
        x = np.loadtxt(run / f"c{i}.txt", delimiter=",")[:, 0]
        np.testing.assert_allclose(x, 10.0 + np.arange(5))  # 1 px per call as loaded, not 5


def test_a_second_writer_is_refused(tmp_path, registry):
    exp = load_experiment(_write(tmp_path), registry)
    (tmp_path / "out" / "exp").mkdir(parents=True)
    with FileLock(str(tmp_path / "out" / "exp" / ".lock")):  # another run holds the folder
        with pytest.raises(RunLocked, match=r"out/exp.*another mata-eval run"):
            run_experiment(exp, jobs=1, **QUIET)
    assert not list((tmp_path / "out" / "exp").glob("*.txt"))
    assert _statuses(run_experiment(exp, jobs=1, **QUIET)) == {f"c{i}": "done" for i in range(4)}


def test_a_report_probing_the_lock_does_not_refuse_a_run_starting_then(tmp_path, registry):
    """Review: `report` tests whether a run writes the folder by taking its lock for an instant;
    a run starting in that instant was refused as a second writer."""
    import threading

    exp = load_experiment(_write(tmp_path), registry)
    (tmp_path / "out" / "exp").mkdir(parents=True)
    probe, taken = FileLock(str(tmp_path / "out" / "exp" / ".lock")), threading.Event()

    def hold_briefly():
        with probe:
            taken.set()
            time.sleep(0.2)

    thread = threading.Thread(target=hold_briefly)
    thread.start()
    taken.wait()
    assert _statuses(run_experiment(exp, jobs=1, **QUIET)) == {f"c{i}": "done" for i in range(4)}
    thread.join()


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_call_that_never_returns_fails_its_sequence_and_the_run_goes_on(tmp_path, registry, jobs):
    exp = load_experiment(_write(tmp_path, "{name: faulty, fault: hang}", "timeout_s: 0.5\n"), registry)
    t0 = time.monotonic()
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=jobs, **QUIET)}
    assert time.monotonic() - t0 < 30
    assert _statuses(outcomes.values()) == {"c0": "done", "c1": "done", "c2": "failed", "c3": "done"}
    assert "did not return within 0.5 s" in outcomes["c2"].reason and "frame 2" in outcomes["c2"].reason
    failure = json.loads((tmp_path / "out" / "exp" / "c2.failed.json").read_text())
    assert "timeout_s" in failure["reason"]


@pytest.mark.parametrize("fault, words", [
    ("exit", "SystemExit"), ("interrupt", "KeyboardInterrupt"), ("confidence_nan", "confidence"),
    ("confidence_big", "confidence"),
    # QA pass: a string confidence passed; a tuple box died in an AttributeError naming no block
    # or frame; a string coordinate was called "non-finite"
    ("confidence_text", "returned confidence '0.5'; expected a number in [0, 1]"),
    ("tuple_box", "tracker 'faulty' failed at frame 2 (t = 0.0667 s): returned a box of type tuple"),
    ("text_box", "returned a box that is not four finite numbers"),
    # QA pass: written to the box file and scored as IoU 0
    ("negative_box", "returned a box of negative size: Box(x=10.0, y=10.0, w=-5.0, h=10.0)")])
def test_a_misbehaving_tracker_fails_only_its_sequence(tmp_path, registry, fault, words):
    exp = load_experiment(_write(tmp_path, f"{{name: faulty, fault: {fault}}}"), registry)
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=1, **QUIET)}
    assert _statuses(outcomes.values()) == {"c0": "done", "c1": "done", "c2": "failed", "c3": "done"}
    assert words in outcomes["c2"].reason


def test_force_with_a_bad_job_count_deletes_nothing(tmp_path, registry):
    exp = load_experiment(_write(tmp_path), registry)
    run_experiment(exp, jobs=1, **QUIET)
    with pytest.raises(UserError, match="jobs"):
        run_experiment(exp, jobs=-1, force=True, **QUIET)
    assert len(list((tmp_path / "out" / "exp").glob("c*.txt"))) == 4


class Escaping(Clips):
    name = "escaping"

    def sequences(self):
        gt = np.tile([10.0, 10.0, 8.0, 8.0], (5, 1))
        return [Sequence("../../escaped", gt, 30.0, loader=lambda k: np.zeros((32, 48, 3), np.uint8))]


def test_a_sequence_name_cannot_leave_the_run_folder(tmp_path, registry):
    reg = Registry({**registry.plugins, "dataset": {"escaping": PluginEntry("dataset", "escaping", Escaping, "test", "")}}, ())
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'a' / 'out'}\ndataset: escaping\ntracker: faulty\n")
    with pytest.raises(UserError, match=r"'\.\./\.\./escaped' is not a single file name"):
        run_experiment(load_experiment(p, reg), jobs=1, **QUIET)
    assert not list(tmp_path.rglob("escaped*"))


def test_the_exit_status_is_1_when_any_sequence_failed(tmp_path, registry, capsys):
    from mata_eval.cli import main

    p = _write(tmp_path, "{name: faulty, fault: exit}")
    assert main(["run", str(p), "-j", "1", "-q", "--no-report"]) == 1
    assert "1 sequence(s) failed" in capsys.readouterr().err
    p = _write(tmp_path, "{name: faulty}")
    assert main(["run", str(p), "-j", "1", "-q", "--no-report", "--force"]) == 0


class LongNames(Clips):
    name = "long_names"

    def sequences(self):
        gt = np.tile([10.0, 10.0, 8.0, 8.0], (5, 1))
        load = lambda k: np.zeros((32, 48, 3), np.uint8)
        return [Sequence("short", gt, 30.0, loader=load), Sequence("s" * 226, gt, 30.0, loader=load)]


def test_a_sequence_name_too_long_for_its_files_is_refused_before_the_run(tmp_path, registry, capsys, monkeypatch):
    """`<seq>.bad_frames.json`'s temporary file must fit in 255 bytes: a 226-byte name is one too
    many (QA pass: validate passed it, its results failed to write, and the table said Failed 0)."""
    from mata_eval.cli import main

    reg = Registry({**registry.plugins, "dataset": {"long_names": PluginEntry("dataset", "long_names", LongNames, "test", "")}}, ())
    monkeypatch.setattr(mata_eval.run.config, "load_registry", lambda: reg)
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: long_names\ntracker: faulty\n")
    for command in ("validate", "run"):
        assert main([command, str(p)]) == 2
        err = capsys.readouterr().err
        assert ("dataset long_names (run exp): 1 of 2 sequences cannot name their result files: sequence name "
                f"'{'s' * 40}'... is too long for its result files (256 bytes") in err
    assert not (tmp_path / "out").exists()


def test_every_block_with_a_close_method_is_closed_after_its_sequence(tmp_path, registry, monkeypatch, capfd):
    """QA pass: only the tracker's close() was called; a block B or C holding a device or a
    process never released it."""
    closed = tmp_path / "closed.txt"
    (tmp_path / "qa_closing.py").write_text(
        "from dataclasses import dataclass\n"
        "from mata_eval.types import Estimate, Motion\n"
        f"LOG = {str(closed)!r}\n"
        "class Closing:\n"
        "    @dataclass(frozen=True)\n    class Params:\n        pass\n"
        "    def __init__(self, params): pass\n"
        "    def close(self):\n        open(LOG, 'a').write(type(self).__name__ + '\\n')\n"
        "class Ego(Closing):\n"
        "    def initialize(self, image): pass\n    def estimate(self, image): return Motion.identity()\n"
        "class Hold(Closing):\n"
        "    def initialize(self, box, t):\n        self.e = Estimate(box)\n        return self.e\n"
        "    def step(self, t, motions=(), detections=()):\n"
        "        self.e = Estimate(detections[-1].value.box) if detections else self.e\n        return self.e\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    p = _write(tmp_path, extra="egomotion: {name: 'qa_closing:Ego'}\nestimator: {name: 'qa_closing:Hold'}\n")
    assert set(_statuses(run_experiment(load_experiment(p, registry), jobs=1, **QUIET)).values()) == {"done"}
    assert sorted(closed.read_text().split()) == ["Ego"] * 4 + ["Hold"] * 4   # once per sequence each
    # a close() that raises is a warning naming the plugin, not the end of the experiment (review:
    # the error left run_task, and the other runs of the sequence were never written)
    (tmp_path / "qa_closing_bad.py").write_text(
        "from qa_closing import Ego\nclass BadEgo(Ego):\n    def close(self):\n        raise OSError('device gone')\n")
    p = _write(tmp_path, extra="matrix:\n  egomotion:\n    none: null\n    bad: {name: 'qa_closing_bad:BadEgo'}\n")
    capfd.readouterr()
    outcomes = run_experiment(load_experiment(p, registry), jobs=1, force=True, **QUIET)
    err = capfd.readouterr().err   # one line each (review: a warning showing contextlib's source line)
    assert sorted(err.splitlines()) == [f"warning: egomotion qa_closing_bad:BadEgo (run bad, sequence {seq}): close() "
                                        "raised OSError: device gone" for seq in sorted(_statuses(outcomes))]
    assert {(o.run, o.status) for o in outcomes} == {("none", "done"), ("bad", "done")}
    assert len(outcomes) == 8
    # one that hangs is given up after timeout_s (QA pass 14: the run waited forever, the
    # sequence's results unwritten)
    (tmp_path / "qa_closing_hang.py").write_text(
        "import time\nfrom qa_closing import Ego\nclass HangEgo(Ego):\n    def close(self):\n        time.sleep(600)\n")
    p = _write(tmp_path, extra="timeout_s: 0.2\negomotion: {name: 'qa_closing_hang:HangEgo'}\n")
    outcomes = run_experiment(load_experiment(p, registry), jobs=1, force=True, **QUIET)
    assert set(_statuses(outcomes).values()) == {"done"} and len(outcomes) == 4
    assert capfd.readouterr().err.count("close() did not return within 0.2 s (timeout_s)") == 4
