"""The Ray executor on a local Ray cluster (2 CPUs, started once for this module): the same
files as the local executor, a task whose worker dies is retried once, then recorded failed,
and Ctrl-C cancels what is still queued or running on the cluster."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'mata-eval[ray]')")

from mata_eval.core.registry import PluginEntry, Registry, load_registry  # noqa: E402
from mata_eval.core.sequence import Sequence  # noqa: E402
from mata_eval.params import param  # noqa: E402
from mata_eval.run.config import load_experiment  # noqa: E402
from mata_eval.run.executors import RayExecutor  # noqa: E402
from mata_eval.run.runner import run_experiment  # noqa: E402
from mata_eval.types import TrackerOutput  # noqa: E402


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The cluster, and the suite cache its workers use: they take the environment of
    ``ray.init``, so the cache is set before it (else they read and fill the user's cache,
    where a suite of the same generator version but older pixels may wait)."""
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a throw-away cluster on this machine
    cache = tmp_path_factory.mktemp("cache")
    before = os.environ.get("MATA_EVAL_CACHE")
    os.environ["MATA_EVAL_CACHE"] = str(cache)
    # "local": a cluster of its own, also where `ray start` left one running on this machine
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="error", log_to_driver=False)
    # The workers cannot import this test module: send its toy plugins by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield cache
    ray.shutdown()
    if before is None:
        os.environ.pop("MATA_EVAL_CACHE", None)
    else:
        os.environ["MATA_EVAL_CACHE"] = before


def _quiet(_: str) -> None:
    pass


def test_ray_writes_the_same_files_as_the_local_executor(cluster, tmp_path, monkeypatch):
    reg = load_registry()
    if "synthetic" not in reg.plugins["dataset"] or "kcf" not in reg.plugins["tracker"] \
            or "grid_lk" not in reg.plugins["egomotion"] or "homography_ekf" not in reg.plugins["estimator"]:
        pytest.skip("the synthetic dataset or the kcf, grid_lk, homography_ekf plugins are not installed")
    monkeypatch.setenv("MATA_EVAL_CACHE", str(cluster))  # the cache the Ray workers were started with
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent("""\
        dataset: {name: synthetic, n_sequences: 2, n_frames: 8, width: 128, height: 96, jobs: 1}
        tracker: {name: kcf}
        egomotion: {name: grid_lk}
        estimator: {name: homography_ekf}
        matrix:
          mata:
            baseline: {egomotion: null, estimator: null}
            mata: {}
        """))
    exp = load_experiment(p)
    exp.runs[0].dataset.create().ensure()  # generate the suite once, before either executor
    local = run_experiment(_with_output(exp, tmp_path / "local"), jobs=1, progress=False, log=_quiet)
    remote = run_experiment(_with_output(exp, tmp_path / "ray"), executor=RayExecutor(), progress=False,
                            log=_quiet)
    assert sorted((o.run, o.sequence, o.status) for o in remote) == \
        sorted((o.run, o.sequence, o.status) for o in local)
    assert len(local) == 4 and {o.status for o in local} == {"done"}
    for path in sorted((tmp_path / "local").rglob("*")):
        if path.suffix in (".txt", ".csv") and not path.name.endswith(".frames.csv"):  # frames.csv: wall times
            twin = tmp_path / "ray" / path.relative_to(tmp_path / "local")
            assert twin.read_bytes() == path.read_bytes(), path


def _with_output(exp, out: Path):
    import dataclasses

    return dataclasses.replace(exp, output=out)


class Toy:
    """Two 5-frame sequences."""

    name = "toy5"

    @dataclass(frozen=True)
    class Params:
        n: int = param(5, "frames")

    def __init__(self, params):
        self.params = params

    def sequences(self):
        gt = np.array([[10.0, 10.0, 8.0, 8.0]] * self.params.n)
        return [Sequence(name, gt, 30.0, loader=lambda k: np.zeros((24, 32, 3), np.uint8)) for name in ("a", "b")]


class Killer:
    """Kills its own worker process (as the OS does on out of memory) on sequence ``a`` while
    fewer than ``kills`` files are in ``folder``, one file per death; counts its calls in
    ``folder``/calls and sleeps ``sleep_s`` per call."""

    name = "killer"

    @dataclass(frozen=True)
    class Params:
        folder: str = param("", "where to count the deaths")
        kills: int = param(0, "deaths before it stops killing")
        sleep_s: float = param(0.0, "seconds per call")

    def __init__(self, params):
        self.params = params

    def initialize(self, image, box):
        self.box = box
        folder = Path(self.params.folder)
        if box.x == 10.0 and len(list(folder.glob("death*"))) < self.params.kills:
            (folder / f"death{os.getpid()}").touch()
            os.kill(os.getpid(), signal.SIGKILL)

    def track(self, image, prior=None):
        if self.params.folder:
            with open(Path(self.params.folder) / "calls", "a") as f:
                f.write("call\n")
        time.sleep(self.params.sleep_s)
        return TrackerOutput(self.box, 1.0)


class ToyB(Toy):
    name = "toy5b"

    def sequences(self):
        a, b = super().sequences()
        return [a, Sequence("b", b.groundtruth + [5.0, 0, 0, 0], 30.0, loader=b.loader)]


def _toy_experiment(tmp_path, tracker: str):
    real = load_registry()
    if "ltp" not in real.plugins["protocol"]:
        pytest.skip("the ltp protocol plugin is not installed")
    entry = lambda kind, cls: PluginEntry(kind, cls.name, cls, "test", "")
    reg = Registry({"dataset": {"toy5b": entry("dataset", ToyB)}, "tracker": {"killer": entry("tracker", Killer)},
                    "egomotion": {}, "estimator": {}, "protocol": real.plugins["protocol"]}, ())
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: toy5b}}\ntracker: {tracker}\n")
    return load_experiment(p, reg)


@pytest.mark.parametrize("kills, status", [(1, "done"), (5, "failed")])
def test_a_task_whose_worker_dies_is_retried_once(cluster, tmp_path, kills, status):
    exp = _toy_experiment(tmp_path, f"{{name: killer, folder: {tmp_path}, kills: {kills}}}")
    outcomes = {o.sequence: o for o in run_experiment(exp, executor=RayExecutor(), progress=False, log=_quiet)}
    assert outcomes["b"].status == "done", outcomes["b"].reason
    assert outcomes["a"].status == status
    # One death, then the retry; or two deaths (the first try and its one retry), then failed.
    assert len(list(tmp_path.glob("death*"))) == (1 if status == "done" else 2)
    if status == "failed":
        assert "retried once" in outcomes["a"].reason
        assert (tmp_path / "out" / "exp" / "a.failed.json").is_file()
    else:
        assert (tmp_path / "out" / "exp" / "a.txt").is_file()


@pytest.mark.parametrize("handler", ["python", "mata-eval"])
def test_ctrl_c_cancels_the_tasks_on_the_cluster(cluster, tmp_path, handler):
    """Interrupted while both tasks run (each needs 4 x 2 s): both are cancelled before either
    finishes, and the cluster's CPUs are free again. Under mata-eval's own handler (`mata-eval
    run`) the stop is its Interrupted (QA pass 15c: a SystemError out of ray.wait, exit 1)."""
    from mata_eval.core.errors import Interrupted
    from mata_eval.run import stop

    exp = _toy_experiment(tmp_path, f"{{name: killer, folder: {tmp_path}, sleep_s: 2.0}}")
    executor = RayExecutor()

    def interrupt(task, results):
        raise AssertionError("no task should finish")

    with executor:
        import threading

        threading.Timer(0.8, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt if handler == "python" else Interrupted), \
                (stop.stop_on_signals() if handler == "mata-eval" else contextlib.nullcontext()):
            from mata_eval.run.tasks import make_tasks
            from mata_eval.run.runner import load_sequences

            spec = exp.runs[0]
            tasks = make_tasks([(spec, i, s) for i, s in enumerate(load_sequences(spec))])
            executor.run(exp, tasks, interrupt)

        @ray.remote(num_cpus=2)
        def free() -> bool:
            return True

        assert ray.get(free.remote(), timeout=60)  # both CPUs are free again
    # Killed mid-sequence: fewer than the 2 x 4 tracker calls of two finished sequences.
    calls = (tmp_path / "calls").read_text().count("call") if (tmp_path / "calls").exists() else 0
    assert calls < 8


def test_nodes_of_other_package_versions_are_refused_before_anything_runs(cluster, tmp_path, monkeypatch):
    """QA review: a node of other versions failed each task it took in milliseconds, so it took
    most of them (and under --force replaced good results with failures): one probe per node
    refuses the run first, naming the node and the package. Here the driver pretends to run
    another numpy than its node."""
    from mata_eval.run import results
    from mata_eval.run.executors import OtherVersions

    real = results.package_versions()
    monkeypatch.setattr(results, "package_versions", lambda: {**real, "numpy": "0.1"})
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 4, "
                 "width: 64, height: 48}\ntracker: {name: kcf}\n")
    with pytest.raises(OtherVersions, match=rf"1 Ray node\(s\) run other package versions than the driver: "
                                            rf".+ \(numpy {np.__version__} there, 0.1 on the driver\).*nothing ran"):
        run_experiment(load_experiment(p), executor=RayExecutor(), progress=False, log=_quiet)
    assert not list((tmp_path / "out").rglob("*.txt"))
    # two nodes at one address (several raylets on a host) are both probed (QA pass 16e: one hid the other)
    node = next(n for n in ray.nodes() if n.get("Alive"))
    monkeypatch.setattr(ray, "nodes", lambda: [node, dict(node)])
    with pytest.raises(OtherVersions, match=r"2 Ray node\(s\) run other package versions"):
        run_experiment(load_experiment(p), executor=RayExecutor(), progress=False, log=_quiet)


def test_a_node_whose_versions_cannot_be_read_is_named_not_a_traceback(cluster, tmp_path, monkeypatch):
    """QA pass 16d: a probe that raised on a node (no mata-eval there, a node lost) ended the run
    in a traceback."""
    from mata_eval.run import executors

    def broken():
        raise ModuleNotFoundError("No module named 'mata_eval'")

    monkeypatch.setattr(executors, "_node_versions", broken)
    p = tmp_path / "exp.yaml"
    p.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, n_frames: 4, "
                 "width: 64, height: 48}\ntracker: {name: kcf}\n")
    with pytest.raises(executors.OtherVersions, match=r"the package versions of 1 Ray node\(s\) could not be read: "
                                                      r".*No module named 'mata_eval'"):
        run_experiment(load_experiment(p), executor=RayExecutor(), progress=False, log=_quiet)
