"""Tasks: every run of a sequence in lockstep, each frame decoded once and only when some run
needs it, with the same files as one run at a time; longest-first planning."""

from __future__ import annotations

import collections
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from mata_eval.core.registry import PluginEntry, Registry, load_registry
from mata_eval.core.sequence import Sequence
from mata_eval.params import param
from mata_eval.run import results
from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_experiment
from mata_eval.run.scheduler import run_sequence
from mata_eval.run.tasks import Task, base_sequences, as_run_sees_it, plan, sequence_seed
from mata_eval.types import Box, TrackerOutput

READS: collections.Counter = collections.Counter()


def _reader(name: str):
    def read(k: int) -> np.ndarray:
        READS[name, k] += 1
        return np.full((48, 64, 3), k, np.uint8)
    return read


class CountingDataset:
    """Two 12-frame sequences whose loader counts the frames it reads."""

    name = "counting"

    @dataclass(frozen=True)
    class Params:
        n: int = param(12, "frames")

    def __init__(self, params):
        self.params = params

    def sequences(self):
        gt = np.array([[10.0, 10.0, 8.0, 8.0]] * self.params.n)
        return [Sequence(name, gt, 30.0, loader=_reader(name)) for name in ("a", "b")]


class StepTracker:
    """Moves the box ``step`` px right per call; ``scribble`` draws on the image it is given."""

    name = "step"

    @dataclass(frozen=True)
    class Params:
        step: float = param(1.0, "pixels per call")
        scribble: bool = param(False, "write into the input image")

    def __init__(self, params):
        self.params = params

    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        if self.params.scribble:
            image[0, 0] = 255
        self.box = Box(self.box.x + self.params.step, self.box.y, self.box.w, self.box.h)
        return TrackerOutput(self.box, 1.0)


def _registry():
    real = load_registry()
    if not {"ltp", "dsp"} <= set(real.plugins["protocol"]):
        pytest.skip("the ltp and dsp protocol plugins are not installed")
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    return Registry({"dataset": {"counting": entry("dataset", CountingDataset)},
                     "tracker": {"step": entry("tracker", StepTracker)},
                     "egomotion": {}, "estimator": {}, "protocol": real.plugins["protocol"]}, ())


def _alone(spec, seq) -> tuple[str, str]:
    """One run over its own freshly loaded sequence (its own decode): what the runner wrote
    before tasks shared frames."""
    run = run_sequence(seq, spec.tracker.create(), None, None, spec.protocol.create(),
                       sequence_seed(spec.seed, seq.name), feedback=spec.feedback)
    return results.format_predictions(run.boxes), run.trace_csv()


def test_each_frame_is_decoded_once_and_only_when_a_run_needs_it(tmp_path):
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: counting}}
        tracker: {{name: step}}
        protocol: {{name: dsp, n: 3}}
        matrix:
          tracker:
            one: {{name: step}}
            two: {{name: step, step: 2.0}}
            scribble: {{name: step, scribble: true}}
        """))
    exp = load_experiment(p, _registry())
    READS.clear()
    outcomes = {(o.run, o.sequence): o for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    # DSP n=3 delivers frames 0, 3, 6, 9 and nothing reads the others; three runs, one read each.
    assert READS == {(s, k): 1 for s in ("a", "b") for k in (0, 3, 6, 9)}
    # A block that draws on the shared frame fails its own run, never the others' images.
    for s in ("a", "b"):
        assert outcomes["scribble", s].status == "failed"
        assert "read-only" in outcomes["scribble", s].reason
    for spec in exp.runs[:2]:
        for seq in spec.dataset.create().sequences():
            out = tmp_path / "out" / spec.name
            boxes, trace = _alone(spec, seq)
            assert (out / f"{seq.name}.txt").read_text() == boxes
            assert (out / f"{seq.name}.trace.csv").read_text() == trace
    # DSP n=3: the box moves `step` px at each delivered frame and is held in between.
    pred = np.loadtxt(tmp_path / "out" / "two" / "a.txt", delimiter=",")
    np.testing.assert_allclose(pred[:, 0], 10.0 + 2.0 * (np.arange(12) // 3))


def test_real_blocks_with_occlusion_give_the_same_files_as_one_run_at_a_time(tmp_path, monkeypatch):
    """kcf, grid_lk and the homography EKF on two small synthetic sequences, clean and occluded,
    MATA on and off, LTP and EOP@10Hz: 8 runs in two tasks, each frame decoded once."""
    reg = load_registry()
    needed = {("dataset", "synthetic"), ("tracker", "kcf"), ("egomotion", "grid_lk"),
              ("estimator", "homography_ekf"), ("protocol", "eop")}
    if any(name not in reg.plugins[kind] for kind, name in needed):
        pytest.skip("the synthetic dataset or the kcf, grid_lk, homography_ekf, eop plugins are not installed")
    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: synthetic, n_sequences: 2, n_frames: 12, width: 160, height: 96, jobs: 1}}
        occlusion: null
        tracker: {{name: kcf}}
        egomotion: {{name: grid_lk}}
        estimator: {{name: homography_ekf}}
        matrix:
          data:
            clean: {{occlusion: null}}
            occ: {{occlusion: {{n_events: 1, duration: 0.2, skip_start: 2}}}}
          mata:
            baseline: {{egomotion: null, estimator: null}}
            mata: {{}}
          protocol:
            ltp: {{name: ltp}}
            eop10: {{name: eop, tracker_hz: 10}}
        """))
    exp = load_experiment(p)
    base_sequences(exp.runs[0])  # the suite is generated (and read) before counting
    reads: collections.Counter = collections.Counter()
    import mata_eval.core.sequence as sequence_module

    read_image = sequence_module.read_image

    def counting_read(path):
        reads[path] += 1
        return read_image(path)

    monkeypatch.setattr(sequence_module, "read_image", counting_read)
    outcomes = run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert len(outcomes) == 16 and {o.status for o in outcomes} == {"done"}
    # 8 runs, 2 sequences of 12 frames: 24 reads in all (the occluded runs composite onto it).
    assert len(reads) == 24 and set(reads.values()) == {1}
    monkeypatch.setattr(sequence_module, "read_image", read_image)
    for spec in exp.runs:
        for seq in spec.dataset.create().sequences():
            seq = as_run_sees_it(seq, spec)
            run = run_sequence(seq, spec.tracker.create(), spec.egomotion and spec.egomotion.create(),
                               spec.estimator and spec.estimator.create(), spec.protocol.create(),
                               sequence_seed(spec.seed, seq.name), feedback=spec.feedback)
            out = tmp_path / "out" / spec.name
            assert (out / f"{seq.name}.txt").read_text() == results.format_predictions(run.boxes), spec.name
            assert (out / f"{seq.name}.trace.csv").read_text() == run.trace_csv(), spec.name


def test_plan_runs_the_longest_first_and_splits_what_would_keep_workers_waiting():
    a = Task(0, "long", 100, ("r1", "r2", "r3", "r4"))  # 400 frames to schedule
    b = Task(1, "mid", 50, ("r1", "r2"))                 # 100
    c = Task(2, "short", 10, ("r1",))                    # 10
    assert plan([c, b, a], workers=1) == [a, b, c]
    # 4 workers: an even share is 510 / 4 = 127.5 frames: `long` is halved twice, down to one
    # run each (100 frames); then, with 6 tasks for 4 workers (fewer than 2 each), `mid` too.
    planned = plan([c, b, a], workers=4)
    assert [(t.sequence, t.cost) for t in planned] == [("long", 100)] * 4 + [("mid", 50)] * 2 + [("short", 10)]
    for name, runs in (("long", ["r1", "r2", "r3", "r4"]), ("mid", ["r1", "r2"])):
        parts = [t for t in planned if t.sequence == name]
        assert sorted(r for t in parts for r in t.runs) == runs and all(len(t.runs) == 1 for t in parts)
    # 2 workers, 2 tasks of 4 runs: halved once each, 4 tasks of 2 runs.
    d = Task(3, "other", 100, ("r1", "r2", "r3", "r4"))
    assert [len(t.runs) for t in plan([a, d], workers=2)] == [2, 2, 2, 2]
