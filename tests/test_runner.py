"""The runner: failures are recorded per sequence and the run goes on; reruns resume; --force
redoes; a changed configuration never mixes with old results."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shlex
import shutil
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from mata_eval.run.config import load_experiment
from mata_eval.params import param
from mata_eval.core.registry import PluginEntry, Registry, load_registry
from mata_eval.run import results
from mata_eval.run.runner import ResultsConflict, prepare_run_dir, run_experiment
from mata_eval.core.sequence import FrameReadError, Sequence
from mata_eval.types import Box, TrackerOutput

CALLS: list[str] = []


def _image(k: int) -> np.ndarray:
    return np.full((48, 64, 3), k, np.uint8)


def _bad_loader(k: int) -> np.ndarray:
    if k == 2:
        raise FrameReadError("cannot read frame 2 of sequence 'broken': /data/broken/0003.jpg")
    return _image(k)


class ToyDataset:
    """Three 6-frame sequences; 'broken' has an unreadable frame, 'nan' makes the tracker fail."""

    name = "toy"

    @dataclass(frozen=True)
    class Params:
        n: int = param(6, "frames")
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")

    def __init__(self, params):
        self.params = params

    def sequences(self):
        gt = np.array([[10.0 + k, 10.0, 8.0, 8.0] for k in range(self.params.n)])
        seqs = {"good": Sequence("good", gt, 30.0, loader=_image),
                "broken": Sequence("broken", gt, 30.0, loader=_bad_loader),
                "nan": Sequence("nan", gt, 30.0, loader=_image)}
        return [seqs[k] for k in self.params.sequences or seqs]


class ShiftTracker:
    """Moves the box 1 px right per call; from call ``nan_after`` on it returns NaN."""

    name = "shift"

    @dataclass(frozen=True)
    class Params:
        nan_after: int = param(-1, "return NaN from this call on (-1: never)")

    def __init__(self, params):
        self.params = params
        self.calls = 0

    def initialize(self, image, box):
        self.box = box

    def track(self, image, prior=None):
        self.calls += 1
        CALLS.append(f"frame{int(image[0, 0, 0])}")
        if 0 <= self.params.nan_after <= self.calls:
            return TrackerOutput(Box(np.nan, np.nan, np.nan, np.nan), 0.0)
        self.box = Box(self.box.x + 1, self.box.y, self.box.w, self.box.h)
        return TrackerOutput(self.box, 1.0)


def _registry():
    real = load_registry()
    if "ltp" not in real.plugins["protocol"]:
        pytest.skip("the ltp protocol plugin is not installed")
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    return Registry({"dataset": {"toy": entry("dataset", ToyDataset)},
                     "tracker": {"shift": entry("tracker", ShiftTracker)},
                     "egomotion": {}, "estimator": {},
                     "protocol": {"ltp": real.plugins["protocol"]["ltp"]}}, ())


def _exp(tmp_path, tracker_block="{name: shift}", dataset_block="{name: toy}"):
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {dataset_block}
        tracker: {tracker_block}
        """))
    return load_experiment(p, _registry())


def test_failures_are_recorded_and_the_run_goes_on(tmp_path):
    exp = _exp(tmp_path)
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    run = tmp_path / "out" / "exp"
    assert outcomes["good"].status == "done" and outcomes["nan"].status == "done"
    assert outcomes["broken"].status == "failed"
    assert "cannot read frame 2" in outcomes["broken"].reason
    failure = json.loads((run / "broken.failed.json").read_text())
    assert failure["sequence"] == "broken" and "FrameReadError" in failure["reason"]
    assert not (run / "broken.txt").exists()
    # LTP: the tracker moves 1 px per frame from the ground-truth box of frame 0.
    pred = np.loadtxt(run / "good.txt", delimiter=",")
    np.testing.assert_allclose(pred[:, 0], 10.0 + np.arange(6))
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["config"]["tracker"] == {"name": "shift", "nan_after": -1}
    assert manifest["seed"] == 0 and "numpy" in manifest["versions"]


def test_nan_from_tracker_fails_only_that_sequence(tmp_path):
    exp = _exp(tmp_path, "{name: shift, nan_after: 3}")
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    assert outcomes["good"].status == "failed" and outcomes["nan"].status == "failed"
    assert all("not four finite numbers" in o.reason or "nan" in o.reason.lower() for o in outcomes.values()
               if o.sequence != "broken")


def test_rerun_skips_finished_retries_failed_and_force_redoes(tmp_path):
    exp = _exp(tmp_path)
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    CALLS.clear()
    again = {o.sequence: o.status for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    assert again == {"good": "skipped", "nan": "skipped", "broken": "failed"}
    # Only the failed sequence ran again, and it stops at its unreadable frame 2.
    assert set(CALLS) <= {"frame1"}
    forced = {o.sequence: o.status for o in run_experiment(exp, jobs=1, force=True, progress=False,
                                                             log=lambda s: None)}
    assert forced == {"good": "done", "nan": "done", "broken": "failed"}


def test_changed_config_does_not_mix_with_old_results(tmp_path):
    run_experiment(_exp(tmp_path), jobs=1, progress=False, log=lambda s: None)
    changed = _exp(tmp_path, "{name: shift, nan_after: 100}")
    with pytest.raises(ResultsConflict, match="different configuration"):
        run_experiment(changed, jobs=1, progress=False, log=lambda s: None)
    # --force on one sequence of the new configuration: the other sequences' results are of the
    # old one, so they go too (they were kept under the new manifest)
    outcomes = run_experiment(changed, jobs=1, force=True, sequences=["good"], progress=False, log=lambda s: None)
    assert [(o.sequence, o.status) for o in outcomes] == [("good", "done")]
    assert sorted(p.name for p in (tmp_path / "out" / "exp").glob("*.txt")) == ["good.txt"]
    outcomes = run_experiment(changed, jobs=1, force=True, progress=False, log=lambda s: None)
    assert {o.status for o in outcomes} == {"done", "failed"}


def test_a_changed_sequence_selection_resumes(tmp_path):
    """Sequences added to, removed from or reordered in the dataset's ``sequences`` list keep
    the run folder: only a new sequence runs, a removed one's results stay (each result depends
    on its sequence alone); another change is still refused, and named (not the list)."""
    quiet = dict(jobs=1, progress=False, log=lambda s: None)
    selection = lambda names, tracker="{name: shift}": _exp(tmp_path, tracker, f"{{name: toy, sequences: {names}}}")
    assert [o.status for o in run_experiment(selection("[good]"), **quiet)] == ["done"]
    CALLS.clear()
    outcomes = {o.sequence: o.status for o in run_experiment(selection("[nan, good]"), **quiet)}
    assert outcomes == {"nan": "done", "good": "skipped"}
    assert CALLS == [f"frame{k}" for k in range(1, 6)]   # nan's five tracked frames, nothing of good's
    outcomes = {o.sequence: o.status for o in run_experiment(selection("[nan]"), **quiet)}
    assert outcomes == {"nan": "skipped"}
    run = tmp_path / "out" / "exp"
    assert sorted(p.name for p in run.glob("*.txt")) == ["good.txt", "nan.txt"]
    assert json.loads((run / "manifest.json").read_text())["config"]["dataset"]["sequences"] == ["nan"]
    with pytest.raises(ResultsConflict, match=r"different configuration \(tracker\.nan_after: -1 then, 100 now;"):
        run_experiment(selection("[good, nan]", "{name: shift, nan_after: 100}"), **quiet)
    # a folder of a mata-eval that hashed the list too (every folder made before: QA pass, all refused)
    manifest = json.loads((run / "manifest.json").read_text())
    exp = selection("[nan]")
    manifest["config_hash"] = hashlib.sha256(json.dumps(exp.runs[0].resolved, sort_keys=True).encode()).hexdigest()[:16]
    results.write_json(run / "manifest.json", manifest)
    assert manifest["config_hash"] != exp.runs[0].config_hash
    outcomes = {o.sequence: o.status for o in run_experiment(selection("[good, nan, broken]"), **quiet)}
    assert outcomes == {"good": "skipped", "nan": "skipped", "broken": "failed"}


def test_the_manifest_says_which_setup_made_each_result(tmp_path, monkeypatch, capsys):
    """A run resumed after an upgrade: the manifest's top-level versions are the last run's, and
    ``setups`` / ``made_by`` keep which setup made each result (they said the new versions made
    them all); scoring names the packages whose versions differ; the command line alone is not
    another setup; --force redoes them all with one."""
    from mata_eval import cli
    from mata_eval.run import runner
    from mata_eval.score.evaluate import evaluate_results

    quiet = dict(jobs=1, progress=False, log=lambda s: None)
    selection = lambda names: _exp(tmp_path, dataset_block=f"{{name: toy, sequences: {names}}}")
    real = runner._setup()
    setup = lambda numpy, argv: {**real, "versions": {**real["versions"], "numpy": numpy},
                                 "machine": {**real["machine"], "argv": argv}}
    monkeypatch.setattr(runner, "_setup", lambda: setup("1.0", ["mata-eval", "run", "a"]))
    run_experiment(selection("[good]"), **quiet)
    monkeypatch.setattr(runner, "_setup", lambda: setup("1.0", ["mata-eval", "run", "b"]))
    run_experiment(selection("[good]"), force=True, **quiet)   # the command line differs: the same setup
    monkeypatch.setattr(runner, "_setup", lambda: setup("2.0", ["mata-eval", "run", "b"]))
    run_experiment(selection("[good, nan]"), **quiet)
    run = tmp_path / "out" / "exp"
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["versions"]["numpy"] == "2.0"
    assert [s["versions"]["numpy"] for s in manifest["setups"]] == ["1.0", "2.0"]
    assert manifest["made_by"] == {"good": 0, "nan": 1}
    assert "argv" not in manifest["setups"][0]["machine"]
    seqs = ToyDataset(ToyDataset.Params(sequences=["good", "nan"])).sequences()
    scores = evaluate_results(run, seqs)
    assert scores.meta["mixed_versions"] == {"numpy": ["1.0", "2.0"]}
    assert evaluate_results(run, seqs[:1]).meta["mixed_versions"] == {}   # good alone: one setup
    cli._print_incomplete([scores])
    assert ("the results were made with different package versions (a run resumed after an upgrade): "
            "numpy 1.0, 2.0 (manifest.json `made_by`") in capsys.readouterr().out
    # a --force rerun stopped after its first result: the others stay their makers' (QA pass: all
    # were credited to it, as the manifest was written before anything ran)
    monkeypatch.setattr(runner, "_setup", lambda: setup("3.0", ["mata-eval", "run", "c"]))
    write, written = results.write_sequence, []

    def write_one_then_stop(*args, **kwargs):
        if written:
            raise KeyboardInterrupt
        written.append(args[1])
        write(*args, **kwargs)

    monkeypatch.setattr(results, "write_sequence", write_one_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(selection("[good, nan]"), force=True, **quiet)
    monkeypatch.setattr(results, "write_sequence", write)
    manifest = json.loads((run / "manifest.json").read_text())
    made = {k: manifest["setups"][i]["versions"]["numpy"] for k, i in manifest["made_by"].items()}
    assert made == {"good": "1.0", "nan": "2.0", written[0]: "3.0"}
    run_experiment(selection("[good, nan]"), force=True, **quiet)
    manifest = json.loads((run / "manifest.json").read_text())
    assert len(manifest["setups"]) == 1 and manifest["made_by"] == {"good": 0, "nan": 0}
    # a record edited into another shape reads as none: kept results go to the manifest's own setup
    for setups, made_by in (({"0": {}}, {"good": 0}), (["x"], {"good": 0}), ([{}], ["good"]), ([{}], {"good": "0"})):
        results.write_json(run / "manifest.json", {**manifest, "setups": setups, "made_by": made_by})
        assert evaluate_results(run, seqs).meta["mixed_versions"] == {}
        run_experiment(selection("[good, nan]"), **quiet)
        assert json.loads((run / "manifest.json").read_text())["made_by"] == {"good": 0, "nan": 0}


def test_a_ray_node_with_other_package_versions_fails_its_task_saying_which(tmp_path):
    """On a cluster, a node with another numpy than the driver's made results that the manifest
    attributes to the driver's setup: its task fails instead, naming the package and both
    versions; a node with the driver's versions runs it (the task function alone, no cluster)."""
    from mata_eval.run.executors import _ray_task
    from mata_eval.run.tasks import Task

    exp = _exp(tmp_path, dataset_block="{name: toy, sequences: [good]}")
    task = Task(0, "good", 6, (exp.runs[0].name,))
    driver = {**results.package_versions(), "numpy": "0.1"}
    (out,) = _ray_task(exp, task, str(tmp_path), driver)
    assert out.boxes is None and out.reason.startswith("Ray node ")
    assert f"numpy {np.__version__} there, 0.1 on the driver" in out.reason
    same = results.package_versions()
    patch = {**same, "python": same["python"].rsplit(".", 1)[0] + ".99"}   # another patch release: the same
    for driver in (same, patch):
        (out,) = _ray_task(exp, task, str(tmp_path), driver)
        assert not out.reason and out.boxes.shape == (6, 4)


def test_an_interrupted_forced_rerun_loses_nothing(tmp_path, monkeypatch):
    """--force redoes finished sequences in place: stopped after its first new result, the
    others still hold their earlier results (QA pass: all were deleted before the run)."""
    exp = _exp(tmp_path)
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    run = tmp_path / "out" / "exp"
    before = sorted(p.name for p in run.glob("*.txt"))
    assert before == ["good.txt", "nan.txt"]
    write = results.write_sequence

    def write_then_stop(*args, **kwargs):
        write(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(results, "write_sequence", write_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, jobs=1, force=True, progress=False, log=lambda s: None)
    assert sorted(p.name for p in run.glob("*.txt")) == before


def test_a_failed_redo_replaces_the_earlier_result(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    results.write_sequence(run, "s", np.ones((2, 4)), "k\n", "t\n")
    results.write_bad_frames(run, "s", {1: "unreadable"})
    results.write_failure(run, "s", "boom", "")
    assert sorted(p.name for p in run.iterdir()) == ["s.failed.json"]
    assert not results.is_finished(run, "s")


def test_worker_processes_write_where_the_driver_says(tmp_path, monkeypatch):
    """With --jobs 2 and an output folder given on the command line, the worker processes (which
    reload the experiment file) write into that folder, not into the file's `output`."""
    reg = load_registry()
    if "synthetic" not in reg.plugins["dataset"] or "kcf" not in reg.plugins["tracker"]:
        pytest.skip("the synthetic dataset or the kcf tracker is not installed")
    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(textwrap.dedent("""\
        output: from_file
        dataset: {name: synthetic, n_sequences: 2, n_frames: 8, width: 160, height: 96, jobs: 1}
        tracker: {name: kcf}
        """))
    from mata_eval.cli import main

    assert main(["run", str(exp_file), "-j", "2", "-q", "-o", str(tmp_path / "given")]) == 0
    written = sorted(p.name for p in (tmp_path / "given" / "exp").glob("*.txt"))
    assert len(written) == 2
    assert not (tmp_path / "from_file").exists()


class KillerTracker(ShiftTracker):
    """Kills its own process (as the OS does on out-of-memory) on the 'nan' sequence."""

    name = "killer"

    def initialize(self, image, box):
        super().initialize(image, box)
        self.victim = box.y == 20.0

    def track(self, image, prior=None):
        if self.victim:
            import signal

            os.kill(os.getpid(), signal.SIGKILL)
        return super().track(image, prior)


class VictimDataset(ToyDataset):
    name = "victims"

    def sequences(self):
        gt = np.array([[10.0 + k, 10.0, 8.0, 8.0] for k in range(self.params.n)])
        gt_victim = gt.copy()
        gt_victim[:, 1] = 20.0
        return [Sequence(f"s{i}", gt_victim if i == 2 else gt, 30.0, loader=_image) for i in range(5)]


def test_a_worker_killed_by_the_os_fails_only_its_sequence(tmp_path, monkeypatch):
    import multiprocessing

    if multiprocessing.get_start_method() != "fork":
        pytest.skip("the fake plugins reach the workers only through fork")
    import mata_eval.run.config

    base = _registry()
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    reg = Registry({**base.plugins, "dataset": {"victims": entry("dataset", VictimDataset)},
                    "tracker": {"killer": entry("tracker", KillerTracker)}}, ())
    monkeypatch.setattr(mata_eval.run.config, "load_registry", lambda: reg)
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: victims}}\ntracker: {{name: killer}}\n")
    exp = load_experiment(p, reg)
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=2, progress=False, log=lambda s: None)}
    assert {k: o.status for k, o in outcomes.items()} == {"s0": "done", "s1": "done", "s2": "failed",
                                                           "s3": "done", "s4": "done"}
    assert "worker process died (signal 9 SIGKILL) while running" in outcomes["s2"].reason   # how (QA pass)
    failure = json.loads((tmp_path / "out" / "exp" / "s2.failed.json").read_text())
    assert "killed by the operating system" in failure["reason"]


def test_a_run_that_kills_its_worker_fails_only_itself_not_the_runs_sharing_its_frames(tmp_path, monkeypatch):
    """The killer and a plain run share the task (and the decode) of each sequence: the task
    whose worker dies is retried one run per process, so only the killer's s2 fails."""
    import multiprocessing

    if multiprocessing.get_start_method() != "fork":
        pytest.skip("the fake plugins reach the workers only through fork")
    import mata_eval.run.config

    base = _registry()
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    reg = Registry({**base.plugins, "dataset": {"victims": entry("dataset", VictimDataset)},
                    "tracker": {"killer": entry("tracker", KillerTracker), "shift": base.plugins["tracker"]["shift"]}}, ())
    monkeypatch.setattr(mata_eval.run.config, "load_registry", lambda: reg)
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: victims}}\ntracker: {{name: killer}}\n"
                 "matrix:\n  tracker:\n    killer: {name: killer}\n    plain: {name: shift}\n")
    exp = load_experiment(p, reg)
    outcomes = {(o.run, o.sequence): o.status for o in run_experiment(exp, jobs=2, progress=False, log=lambda s: None)}
    assert outcomes.pop(("killer", "s2")) == "failed"
    assert set(outcomes.values()) == {"done"} and len(outcomes) == 9


def _pid_task(exp, task):
    """A task's results, as a worker of the pool returns them: each run's process id; the task
    of sequence 'kill' kills its process while the task beside it runs."""
    import time

    from mata_eval.run.tasks import SequenceResult

    if task.sequence == "kill":
        time.sleep(0.05)
        os.kill(os.getpid(), 9)
    time.sleep(0.5)
    return [SequenceResult(run, task.sequence, reason=str(os.getpid())) for run in task.runs]


def test_a_dead_worker_retries_alone_only_the_tasks_that_were_running(monkeypatch):
    """QA pass 15c: after one worker died, every task still queued ran one run per process, one at
    a time (half the speed, no frame shared between runs). Only the tasks running when it died
    run alone; those that had not started go to a new pool of as many workers, whole."""
    import multiprocessing

    from mata_eval.run import executors
    from mata_eval.run.tasks import Task

    if multiprocessing.get_start_method() != "fork":
        pytest.skip("the fake task function reaches the workers only through fork")
    monkeypatch.setattr(executors, "run_task", _pid_task)
    tasks = [Task(i, name, 10, ("a", "b")) for i, name in enumerate(["s0", "s1", "kill", "s3", "s4", "s5", "s6"])]
    got: dict[tuple[str, str], str] = {}
    executors.LocalExecutor(2).run(None, tasks, lambda task, res: got.update({(r.run, r.sequence): r.reason for r in res}))
    assert "worker process died" in got[("a", "kill")] and "worker process died" in got[("b", "kill")]
    whole = [s for s in ("s0", "s1", "s3", "s4", "s5", "s6") if got[("a", s)] == got[("b", s)]]
    # s0, s1 finished before (whole); kill and the task beside it ran alone; s4-s6 queued: whole
    assert {"s0", "s1", "s4", "s5", "s6"} <= set(whole), got


def test_rewriting_a_sequence_makes_the_run_scores_stale(tmp_path):
    """`run --force --no-report` then `report`: the report must not show the scores of the old
    predictions, so a run whose sequence is rewritten loses its scores.json (and is scored again
    when reported); a rerun that writes nothing keeps it."""
    exp = _exp(tmp_path)
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    scores = tmp_path / "out" / "exp" / "scores.json"
    scores.write_text("{}")
    run_experiment(exp, sequences=["good"], jobs=1, progress=False, log=lambda s: None)
    assert scores.exists()  # 'good' is finished: skipped, nothing rewritten
    run_experiment(exp, sequences=["good"], jobs=1, force=True, progress=False, log=lambda s: None)
    assert not scores.exists()
    scores.write_text("{}")
    run_experiment(exp, sequences=["broken"], jobs=1, progress=False, log=lambda s: None)
    assert not scores.exists()  # a failed sequence is rewritten too


def test_a_parallel_run_after_this_process_used_opencv_threads_does_not_hang(tmp_path):
    """A process that has run a threaded OpenCV call (an API user's script, a test session) and
    then runs with jobs=2: the forked workers inherited OpenCV's thread pool without its threads,
    and their cv2.setNumThreads(1) waited for them forever (found as a hung test run). Run in a
    child process so that a regression fails on its timeout instead of hanging the suite."""
    import subprocess
    import sys

    script = tmp_path / "parallel.py"
    script.write_text(textwrap.dedent(f"""
        import cv2, numpy as np
        from mata_eval.run.config import load_experiment
        from mata_eval.run.runner import run_experiment

        if __name__ == "__main__":   # the synthetic suite is rendered by spawned processes
            cv2.setNumThreads(2)
            cv2.GaussianBlur(np.zeros((2160, 3840, 3), np.uint8), (15, 15), 3)   # starts the pool
            exp = load_experiment({str(tmp_path / 'exp.yaml')!r})
            outcomes = run_experiment(exp, jobs=2, progress=False, log=lambda s: None)
            print(sorted(o.status for o in outcomes), cv2.getNumThreads())
        """))
    (tmp_path / "exp.yaml").write_text(
        f"output: {tmp_path / 'out'}\n"
        "dataset: {name: synthetic, n_sequences: 2, n_frames: 8, width: 160, height: 120}\n"
        "tracker: {name: kcf}\n")
    env = {**os.environ, "MATA_EVAL_CACHE": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[-2] == "['done', 'done'] 2"   # and the process's setting is back


def test_a_retuned_preset_does_not_resume_results_of_the_old_values(tmp_path, monkeypatch):
    """Parameters an experiment leaves to homography_ekf's preset are null in its configuration
    (and hash): the manifest records the values the preset gave, and a rerun after the preset
    changed (an upgrade retuning preset mata) does not keep the old results (QA pass)."""
    from mata_eval_plugins.estimators import homography_ekf

    reg = load_registry()
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: toy}}
        tracker: {{name: shift}}
        estimator: {{name: homography_ekf, q_box: 0.5}}
        """))
    registry = Registry({**_registry().plugins, "estimator": reg.plugins["estimator"]}, ())
    quiet = dict(jobs=1, progress=False, log=lambda s: None)
    run_experiment(load_experiment(p, registry), **quiet)
    manifest = json.loads((tmp_path / "out" / "exp" / "manifest.json").read_text())
    recorded = manifest["preset_values"]["estimator"]
    assert recorded["q_v"] == homography_ekf.PRESETS["mata"]["q_v"] and "q_box" not in recorded   # set in YAML
    assert {o.status for o in run_experiment(load_experiment(p, registry), **quiet)} == {"skipped", "failed"}
    monkeypatch.setitem(homography_ekf.PRESETS["mata"], "q_v", 12345.0)
    with pytest.raises(ResultsConflict, match=r"other preset values of the estimator \(q_v: 100.0 then, 12345.0 now\)"):
        run_experiment(load_experiment(p, registry), **quiet)
    assert {o.status for o in run_experiment(load_experiment(p, registry), force=True, **quiet)} == {"done", "failed"}


def test_results_without_a_manifest_are_refused_not_kept(tmp_path):
    """A run folder holding results but no manifest.json (deleted, or copied in by hand): its
    results cannot be matched to this configuration, so the run refuses it; --force clears it
    (QA pass: they were kept as finished and stamped with the new run's manifest)."""
    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    run.mkdir(parents=True)
    (run / "good.txt").write_text("1,2,3,4\n")   # not what this configuration makes
    with pytest.raises(ResultsConflict, match=r"holds results but no manifest.json.*--force"):
        run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert not (run / "manifest.json").exists() and (run / "good.txt").read_text() == "1,2,3,4\n"
    outcomes = {o.sequence: o.status for o in run_experiment(exp, jobs=1, force=True, sequences=["nan"],
                                                             progress=False, log=lambda s: None)}
    assert outcomes == {"nan": "done"}
    assert not (run / "good.txt").exists()   # cleared, not kept under the new manifest


def test_a_write_error_stops_the_run_at_once_naming_the_file(tmp_path, monkeypatch):
    """Disk full: the run stops at the first result it cannot write, naming the file and the
    error (QA pass: every remaining sequence was computed, then failed to write, and the final
    error named no file); what was written stays, and a rerun resumes."""
    import errno

    from mata_eval.run.runner import CannotWrite

    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    replace, refused = os.replace, []

    def disk_full_after_one_sequence(src, dst):
        if str(dst).endswith(".txt") or not list(run.glob("*.txt")) or str(dst).endswith("manifest.json"):
            return replace(src, dst)
        refused.append(os.path.basename(dst))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(src))

    monkeypatch.setattr(os, "replace", disk_full_after_one_sequence)
    with pytest.raises(CannotWrite, match=r"\.tmp: No space left on device; the run stops") as exc:
        run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert str(run) in str(exc.value)
    assert len(refused) == 1   # stopped at the first failure, not one per remaining sequence
    written = [p.stem for p in run.glob("*.txt")]
    assert len(written) == 1
    monkeypatch.setattr(os, "replace", replace)
    outcomes = {o.sequence: o.status for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    assert outcomes.pop(written[0]) == "skipped" and "skipped" not in outcomes.values()


def test_a_full_disk_at_the_manifest_or_the_scores_names_the_file_and_keeps_the_table(tmp_path, monkeypatch):
    """QA pass 14: a disk full when the manifest was rewritten, or when scores.json was saved,
    was a bare "[Errno 28] No space left on device" (no file named), and the latter lost the
    table although every sequence had been scored."""
    import errno

    from mata_eval.run.runner import CannotWrite, load_sequences
    from mata_eval.score.evaluate import evaluate_run

    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    replace = os.replace

    def disk_full_for(name):
        def refuse(src, dst):
            if os.path.basename(dst) == name:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(src))
            return replace(src, dst)
        return refuse

    monkeypatch.setattr(os, "replace", disk_full_for("manifest.json"))
    with pytest.raises(CannotWrite, match=re.escape(f"cannot write {run / 'manifest.json'}: No space left on device; "
                                                    "nothing ran (the results there stay")):
        run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    changed = _exp(tmp_path, "{name: shift, nan_after: 100}")   # --force on another configuration clears first
    with pytest.raises(CannotWrite, match=r"nothing ran \(the folder holds no results: "):
        run_experiment(changed, jobs=1, force=True, progress=False, log=lambda s: None)
    monkeypatch.setattr(os, "replace", replace)
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)   # (the results scored below)
    monkeypatch.setattr(os, "replace", disk_full_for("scores.json"))
    (run / "scores.json").unlink(missing_ok=True)
    scores = evaluate_run(run, load_sequences(exp.runs[0]))
    assert set(scores.sequences) == {"good", "nan"}
    assert scores.meta["unsaved"].startswith(f"cannot write {run / 'scores.json'}: No space left on device; the table")


def test_a_file_of_one_sequence_that_cannot_be_written_fails_that_sequence_only(tmp_path, monkeypatch):
    """Review: a name the file system refuses (ENAMETOOLONG below NAME_MAX on eCryptfs, EINVAL
    for ':' on exFAT) is one sequence's problem: it fails, the others run (it stopped the run,
    and every rerun stopped again at that sequence)."""
    import errno

    exp = _exp(tmp_path)
    replace = os.replace

    def refuse_one_name(src, dst):
        if os.path.basename(dst).startswith("good."):
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG), str(dst))
        return replace(src, dst)

    monkeypatch.setattr(os, "replace", refuse_one_name)
    outcomes = {o.sequence: o for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)}
    assert outcomes["good"].status == "failed" and "File name too long" in outcomes["good"].reason
    assert outcomes["nan"].status == "done" and "cannot read frame 2" in outcomes["broken"].reason   # as without


def test_a_run_folder_deleted_during_the_run_is_not_silently_made_again(tmp_path, monkeypatch):
    """The output folder deleted while a run writes it: the run stops with an error naming the
    lost manifest (QA pass: the next result made the folder again, without manifest or lock)."""
    import shutil

    from mata_eval.run.runner import CannotWrite

    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    write = results.write_sequence

    def write_then_delete(*args, **kwargs):
        write(*args, **kwargs)
        shutil.rmtree(run)

    monkeypatch.setattr(results, "write_sequence", write_then_delete)
    with pytest.raises(CannotWrite, match=r"manifest.json is gone .*the run stops"):
        run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert not run.exists()


def test_a_scores_json_saved_while_the_run_wrote_the_folder_is_scored_again(tmp_path, monkeypatch):
    """`report` while `run --no-report` writes the folder: its scores.json, saved after the run
    removed the old one, covered the sequences finished then; a later report trusted it (QA
    pass). Now scores.json is used only when it covers the folder's finished and failed
    sequences, and scored again otherwise."""
    import shutil

    import mata_eval.run.config
    from mata_eval.score.evaluate import scores_for

    monkeypatch.setattr(mata_eval.run.config, "load_registry", _registry)   # scores_for loads the file
    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    run_experiment(exp, sequences=["good"], jobs=1, progress=False, log=lambda s: None)
    assert set(scores_for(run).sequences) == {"good"}
    shutil.copy(run / "scores.json", tmp_path / "partial.json")
    run_experiment(exp, jobs=1, progress=False, log=lambda s: None)   # nan done, broken failed
    shutil.copy(tmp_path / "partial.json", run / "scores.json")       # the report's late save
    scores = scores_for(run)
    assert set(scores.sequences) == {"good", "nan"} and set(scores.failures) == {"broken"}
    assert set(json.loads((run / "scores.json").read_text())["sequences"]) == {"good", "nan"}


def test_a_report_of_a_folder_a_run_is_writing_does_not_save_its_partial_scores(tmp_path, capsys, monkeypatch):
    import mata_eval.run.config
    from mata_eval import cli
    from mata_eval.run.runner import lock_run_dir

    monkeypatch.setattr(mata_eval.run.config, "load_registry", _registry)

    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    run_experiment(exp, sequences=["good"], jobs=1, progress=False, log=lambda s: None)
    with lock_run_dir(run):   # as a run that is still going holds it
        assert cli.main(["report", str(run)]) == 0
        out = capsys.readouterr().out
        assert "a mata-eval run is writing this folder: scored its sequences finished so far, scores.json not written" in out
        assert not (run / "scores.json").exists()
    assert cli.main(["report", str(run)]) == 0
    assert (run / "scores.json").is_file() and "not written" not in capsys.readouterr().out


def test_a_sequence_that_cannot_be_scored_is_named_and_the_others_are_scored(tmp_path, monkeypatch, capsys):
    """A finished sequence whose files no longer fit (the sequence changed length, a prediction
    file edited): `run` and `report` name the file and how to recompute it, count it as failed
    and score the others (QA pass: a traceback, and no sequence scored)."""
    import mata_eval.run.config
    from mata_eval import cli

    monkeypatch.setattr(mata_eval.run.config, "load_registry", _registry)
    exp = _exp(tmp_path)
    run = tmp_path / "out" / "exp"
    assert cli.main(["run", str(exp.path), "-j", "1", "-q"]) == 1   # 'broken' fails
    frames = (run / "good.frames.csv").read_text().splitlines(keepends=True)
    (run / "good.frames.csv").write_text("".join(frames[:-1]))   # one frame short of the sequence
    capsys.readouterr()
    assert cli.main(["run", str(exp.path), "-j", "1", "-q"]) == 1
    out = capsys.readouterr().out
    assert (f"cannot score exp/good: {run / 'good.frames.csv'}: 5 rows, sequence 'good' has 6 frames (its ground "
            f"truth, or the frames, changed since the run); "
            f"to run it again: mata-eval run {exp.path} -o {run.parent} --runs exp --force --sequences good") in out
    # a copy of the folder: the hint recomputes the sequence in the copy (QA pass: it left out -o)
    copy = tmp_path / "copy" / "exp"
    shutil.copytree(run, copy)
    (copy / "scores.json").unlink()
    assert cli.main(["report", str(copy)]) == 0
    hint = re.search(r"cannot score exp/good: .*; to run it again: mata-eval (run .*)$", capsys.readouterr().out, re.M)
    assert cli.main(shlex.split(hint.group(1)) + ["-j", "1", "-q"]) == 0
    assert len((copy / "good.frames.csv").read_text().splitlines()) == 7   # header + 6 frames
    assert len((run / "good.frames.csv").read_text().splitlines()) == 6    # the original untouched
    # a copy under another name: the run writes its own name's folder, so the hint says to move it
    # into a folder of its own (review: renaming it beside copy/exp collided with that folder)
    other = tmp_path / "copy" / "mine"
    shutil.copytree(run, other)
    (other / "scores.json").unlink()
    assert cli.main(["report", str(other)]) == 0
    hint = re.search(r"; to run it again: move this folder into an empty folder DIR as DIR/exp \(the run writes "
                     r"there\), then mata-eval (run .*)$", capsys.readouterr().out, re.M)
    (tmp_path / "dir").mkdir()
    other.rename(tmp_path / "dir" / "exp")
    assert cli.main([a.replace("DIR", str(tmp_path / "dir")) for a in shlex.split(hint.group(1))] + ["-j", "1", "-q"]) == 0
    assert len((tmp_path / "dir" / "exp" / "good.frames.csv").read_text().splitlines()) == 7
    scores = json.loads((run / "scores.json").read_text())
    assert set(scores["sequences"]) == {"nan"} and set(scores["failures"]) == {"good", "broken"}
    (run / "nan.txt").write_text("1,2,3\n")
    (run / "scores.json").unlink()   # (as a run that writes nan.txt does)
    assert cli.main(["report", str(run)]) == 0
    out = capsys.readouterr().out
    assert f"cannot score exp/nan: {run / 'nan.txt'}:1: expected 4 numbers x,y,w,h, got '1,2,3'" in out
    assert "1 sequence(s) failed: broken;" in out


def test_a_refused_configuration_change_says_what_changed(tmp_path):
    """QA pass: after a plugin's version bump the refusal gave two config hashes, not the plugin."""
    exp = _exp(tmp_path)
    spec = exp.runs[0]
    old = dataclasses.replace(spec, resolved={**spec.resolved, "plugin_versions": {"qa-blocks": "0.1.0"}})
    new = dataclasses.replace(spec, resolved={**spec.resolved, "plugin_versions": {"qa-blocks": "0.2.0"}})
    prepare_run_dir(exp, old, force=False)
    with pytest.raises(ResultsConflict, match=r"different configuration \(plugin_versions\.qa-blocks: '0\.1\.0' then, "
                                              r"'0\.2\.0' now; config hash "):
        prepare_run_dir(exp, new, force=False)
    (tmp_path / "b").mkdir()
    prepare_run_dir(_exp(tmp_path / "b"), _exp(tmp_path / "b").runs[0], force=False)
    changed = _exp(tmp_path / "b", "{name: shift, nan_after: 100}")
    with pytest.raises(ResultsConflict, match=r"different configuration \(tracker\.nan_after: .* then, 100 now;"):
        prepare_run_dir(changed, changed.runs[0], force=False)
    # a block added or removed is named, not printed parameter by parameter (QA pass 14)
    from mata_eval.run.config import config_change

    block = {"name": "grid_lk", "downscale": 2.0, "win_size": 11}
    assert config_change({"egomotion": block}, {"egomotion": None}) == "egomotion: {name: 'grid_lk', ...} then, None now"


def test_git_commit_is_mata_evals_only(tmp_path):
    """Wheel-install QA: a package installed in a virtual environment inside the user's own
    repository recorded that repository's commit as mata-eval's."""
    import subprocess

    def repo_with(package: Path) -> str:
        subprocess.run(["git", "init", "-q", str(tmp_path / "repo")], check=True)
        package.mkdir(parents=True)
        (package / "__init__.py").write_text("")
        git = ["git", "-C", str(tmp_path / "repo"), "-c", "user.name=t", "-c", "user.email=t@t"]
        subprocess.run(git + ["add", "-A"], check=True)
        subprocess.run(git + ["commit", "-qm", "x"], check=True)
        return subprocess.run(git + ["rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()

    installed = tmp_path / "repo" / ".venv" / "lib" / "site-packages" / "mata_eval"
    repo_with(installed)
    assert results.git_commit(installed) is None
    checkout = tmp_path / "repo" / "mata_eval"
    checkout.mkdir()
    (checkout / "__init__.py").write_text("")
    assert results.git_commit(checkout).startswith(
        subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip())


def test_mixed_versions_compare_python_by_its_minor_release_and_name_an_absent_package():
    """QA review: a Python patch release (which Ray nodes may differ by) was reported as mixed
    versions, and a package one setup lacks showed as 'None'; a setup without versions (a very
    old manifest) is not compared."""
    manifest = {"setups": [{"versions": {"python": "3.11.7", "numpy": "1.0"}}, {"versions": {"python": "3.11.8"}},
                           {"git_commit": "abc"}], "made_by": {"a": 0, "b": 1, "c": 2}}
    assert results.mixed_versions(manifest, ["a", "b", "c"]) == {"numpy": ["1.0", "absent"]}
    assert results.versions_line(results.mixed_versions(manifest, ["a", "b"])) == "numpy 1.0, absent"
    assert results.mixed_versions(manifest, ["a", "c"]) == {}
