"""Executors: where the tasks of an experiment run. ``local`` (the default) is a process pool on
this machine; ``ray`` sends the tasks to a Ray cluster (``pip install 'mata-eval[ray]'``).

Both return each task's results to the driver, which writes every file (same atomic writer,
same resume rules, one writer per run folder): the nodes need the datasets, not the output
folder. Both retry a task whose worker process died once, then record its sequences failed
with the reason."""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import platform
import signal
import sys
import threading
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Callable, Iterator, Protocol

from ..core.errors import UserError
from ..core.processes import die_with_parent
from . import results, stop
from .config import Experiment
from .tasks import SequenceResult, Task, failed, run_task

Done = Callable[[Task, list[SequenceResult]], None]

WORKER_DIED = ("worker process died{how} while running this sequence (killed by the operating system, "
               "e.g. out of memory, or a crash in native code); retried once")


def worker_died(exitcodes: list[int]) -> str:
    """The failure reason of a sequence whose worker died, with how it ended (``exitcodes``:
    the pool's workers' non-zero exit codes, minus a signal's number)."""
    how = ", ".join(f"signal {-c} {signal.Signals(-c).name}" if c < 0 and -c in signal.valid_signals()
                    else f"exit code {c}" for c in dict.fromkeys(exitcodes))
    return WORKER_DIED.format(how=f" ({how})" if how else "")


class Executor(Protocol):
    """Runs tasks, handing each task's results to ``done`` (in the driver) as it finishes.
    ``workers``: tasks it runs at once (used to plan the tasks). A context manager: entering
    starts what it needs, leaving (also on Ctrl-C) stops what it started."""

    workers: int

    def __enter__(self) -> "Executor": ...

    def __exit__(self, *exc: object) -> None: ...

    def run(self, exp: Experiment, tasks: list[Task], done: Done) -> None: ...


def default_jobs() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def one_thread_per_process() -> None:
    """One task per core: native libraries must not start a thread per core each."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    import cv2

    cv2.setNumThreads(1)


#: in a local worker: the queue on which it says which task it starts (:func:`_run_marked`)
_STARTED: multiprocessing.queues.SimpleQueue | None = None


def _local_worker(parent: int | None, started: multiprocessing.queues.SimpleQueue | None = None) -> None:
    """A local worker ignores Ctrl-C (the driver stops it: SIGINT to the process group must not
    fail the sequence it runs) and dies with its parent (process id ``parent``: the driver, or
    None under ``forkserver``, whose server process ends with the driver)."""
    global _STARTED
    _STARTED = started
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent(parent)
    one_thread_per_process()


@contextlib.contextmanager
def _opencv_threads_stopped() -> Iterator[None]:
    """OpenCV's thread pool stopped in this process while worker processes are forked from it,
    its thread count restored afterwards. A forked child inherits the pool without its threads,
    and its first ``cv2.setNumThreads`` (:func:`one_thread_per_process`) then waits forever for
    them: 10 of 10 children hung after the parent had run one threaded GaussianBlur (an API user's
    process, or a test session, that used OpenCV before ``run(jobs=2)``). The driver only waits
    on the workers meanwhile."""
    import cv2

    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def _run_marked(exp: Experiment, task: Task, key: int) -> list[SequenceResult]:
    """:func:`run_task`, after saying on the pool's queue that task ``key`` started (a
    SimpleQueue writes at once, so the mark is out before the worker can die)."""
    if _STARTED is not None:
        _STARTED.put(key)
    return run_task(exp, task)


class LocalExecutor:
    """Tasks in ``jobs`` worker processes on this machine (in this process when ``jobs`` is 1)."""

    def __init__(self, jobs: int | None = None):
        self.workers = jobs or default_jobs()

    def __enter__(self) -> "LocalExecutor":
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def run(self, exp: Experiment, tasks: list[Task], done: Done) -> None:
        if self.workers == 1 or len(tasks) <= 1:
            for task in tasks:
                done(task, run_task(exp, task))
                stop.check()
            return
        # A worker killed by the OS breaks the pool and fails every task not finished: those that
        # had not started go to a new pool of as many workers; those that had, one of which killed
        # its worker, run again one run per process, which finds the run that kills its process.
        pending, suspects = tasks, []
        while pending:
            lost, started, _ = self._pool(exp, pending, self.workers, done)
            running = [task for task in lost if task in started] or lost   # (no mark came: all alone)
            suspects += running
            pending = [task for task in lost if task not in running]
        for task in suspects:
            for run in task.runs:
                alone = dataclasses.replace(task, runs=(run,))
                lost_again, _, exitcodes = self._pool(exp, [alone], 1, done)
                if lost_again:
                    done(alone, failed(alone, worker_died(exitcodes)))

    @staticmethod
    def _pool(exp: Experiment, tasks: list[Task], jobs: int,
              done: Done) -> tuple[list[Task], list[Task], list[int]]:
        """Run ``tasks`` in ``jobs`` processes; returns the tasks lost to a broken pool, the tasks
        that started (a lost one among them was running when its worker died) and the non-zero
        exit codes of the workers (how the one that broke the pool died). A stop
        signal is taken between two waits (:func:`stop.deferred`), never inside the pool's own
        code. On any exception (Ctrl-C, SIGTERM above all) the queued tasks are cancelled and the
        workers killed, so that it propagates at once (leaving the pool would wait for every
        task). SIGKILL, not SIGTERM: a worker forked in the same instant runs the driver's
        handler until its initializer resets it, and would swallow the signal and live on while
        the pool's shutdown waits for the tasks queued to it. A worker's SIGTERM is the default
        action anyway, and results are written atomically."""
        lost, marks = [], set()
        context = multiprocessing.get_context()
        method = context.get_start_method()
        parent = None if method == "forkserver" else os.getpid()
        started = context.SimpleQueue()   # read while waiting: a full pipe would block the workers
        with stop.deferred(), (_opencv_threads_stopped() if method == "fork" else contextlib.nullcontext()):
            pool = ProcessPoolExecutor(max_workers=jobs, mp_context=context, initializer=_local_worker,
                                       initargs=(parent, started))
            # pid -> process, for how a dead one ended (no public handle; shutdown drops the attribute,
            # a Python without it loses only the exit code in the failure message)
            workers = getattr(pool, "_processes", None)
            try:
                futures = {pool.submit(_run_marked, exp, task, i): task for i, task in enumerate(tasks)}
                waiting = set(futures)
                while waiting:
                    finished, waiting = wait(waiting, timeout=stop.POLL_S, return_when=FIRST_COMPLETED)
                    while not started.empty():
                        marks.add(started.get())
                    stop.check()
                    for fut in finished:
                        try:
                            results = fut.result()
                        except BrokenProcessPool:
                            lost.append(futures[fut])
                            continue
                        done(futures[fut], results)
            except BaseException:
                for w in list((pool._processes or {}).values()):  # no public handle before Python 3.14
                    w.kill()
                raise
            finally:  # the pool's thread sees its workers gone, fails what was queued, and ends
                pool.shutdown(wait=True, cancel_futures=True)
        while not started.empty():
            marks.add(started.get())
        started.close()
        return (lost, [tasks[i] for i in sorted(marks)],
                [w.exitcode for w in (workers or {}).values() if w.exitcode] if lost else [])


class RayExecutor:
    """Tasks on a Ray cluster: ``address`` ``"auto"`` (the cluster this node belongs to),
    ``"ray://HOST:PORT"`` (Ray Client), or None for ``$RAY_ADDRESS`` when set, else a local
    cluster of its own with ``cpus`` CPUs (default: all). One CPU per task; a task whose worker dies is retried once by Ray
    (``max_retries=1``)."""

    def __init__(self, address: str | None = None, cpus: int | None = None):
        try:
            import ray
        except ImportError:
            raise ImportError("needs Ray, which is not installed: pip install 'mata-eval[ray]'") from None
        self.ray = ray
        self.address, self.cpus = address, cpus
        self.started = False
        self.workers = 1

    def __enter__(self) -> "RayExecutor":
        ray = self.ray
        if not ray.is_initialized():
            # The nodes see this shell's MATA_* settings (model files, caches, shared data).
            env = {k: v for k, v in os.environ.items() if k.startswith("MATA_")}
            # ray.init installs its own SIGTERM handler (a traceback, exit 1): the run's come back
            handlers = {s: signal.getsignal(s) for s in stop.STOP_SIGNALS}
            # no address: $RAY_ADDRESS (`ray job submit` sets it), else a cluster of its own ("local";
            # None would join one that `ray start` left running here, and refuse num_cpus there)
            address = self.address or os.environ.get("RAY_ADDRESS") or None
            print(f"ray: connecting to {address}" if address else
                  f"ray: starting a local cluster of {self.cpus or 'all'} CPU(s)", file=sys.stderr, flush=True)
            ray.init(address=address or "local", num_cpus=None if address else self.cpus,
                     runtime_env={"env_vars": env} if env else None,
                     include_dashboard=False, logging_level="warning", log_to_driver=False)
            self.started = True
            if threading.current_thread() is threading.main_thread():
                for s, handler in handlers.items():
                    if handler is not None:
                        signal.signal(s, handler)
        self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.started:
            self.ray.shutdown()
            self.started = False

    def run(self, exp: Experiment, tasks: list[Task], done: Done) -> None:
        ray = self.ray
        versions = results.package_versions()
        self._check_nodes(versions)
        remote = ray.remote(num_cpus=1, max_retries=1)(_ray_task)
        exp_ref = ray.put(exp)
        pending = {remote.remote(exp_ref, task, os.getcwd(), versions): task for task in tasks}
        # a stop signal is taken between two waits: raised inside ray.wait's compiled code it
        # came out as a SystemError traceback, exit status 1
        with stop.deferred():
            self._wait(pending, done)

    def _check_nodes(self, versions: dict[str, str]) -> None:
        """Refuse the run, naming them, when nodes run other package versions than the driver
        (QA review: such a node failed every task it took in milliseconds, so it took most of
        them, and under --force each failure replaced a good result). A probe per alive node,
        pinned to it; a node that joins later is still checked by each task (:func:`_ray_task`)."""
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        ray = self.ray
        probe = ray.remote(num_cpus=0)(_node_versions)
        nodes = [n for n in ray.nodes() if n.get("Alive")]   # (by node id: nodes may share an address)
        refs = {probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False)).remote():
                f"{n.get('NodeManagerAddress', '?')} ({n['NodeID'][:8]})" for n in nodes}
        ready, late = ray.wait(list(refs), num_returns=len(refs), timeout=120)   # (all at once)
        differ, unread = [], [f"{refs[r]}: no answer in 120 s" for r in late]
        for ref in ready:
            try:
                node, theirs = ray.get(ref)
            except Exception as exc:   # (QA pass 16d: a node without mata-eval was a traceback)
                lines = str(exc).strip().splitlines()
                unread.append(f"{refs[ref]}: {lines[-1] if lines else type(exc).__name__}")
                continue
            if line := version_differences(theirs, versions):
                differ.append(f"{node} ({line})")
        if differ or unread:
            raise OtherVersions("; ".join(
                ([f"{len(differ)} Ray node(s) run other package versions than the driver: {'; '.join(differ)}"]
                 if differ else [])
                + ([f"the package versions of {len(unread)} Ray node(s) could not be read: {'; '.join(unread)}"]
                   if unread else []))
                + f": {INSTALL_THE_DRIVERS}; nothing ran")

    def _wait(self, pending: dict, done: Done) -> None:
        ray = self.ray
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=stop.POLL_S)
                stop.check()
                for ref in ready:
                    task = pending.pop(ref)
                    done(task, self._results(ref, task))
        except BaseException:  # Ctrl-C, SIGTERM: nothing keeps running on the cluster
            for ref in pending:
                ray.cancel(ref, force=True)
            raise

    def _results(self, ref, task: Task) -> list[SequenceResult]:
        from ray.exceptions import RayTaskError

        try:
            return self.ray.get(ref)
        except RayTaskError as exc:  # run_task raised (it records block failures itself)
            return failed(task, f"task raised on the cluster: {exc.cause!r}", str(exc))
        except Exception as exc:  # the worker or its node died twice, the object was lost, ...
            return failed(task, f"Ray worker died while running this sequence, retried once: "
                                f"{type(exc).__name__}: {str(exc).splitlines()[0]}")


#: what to do about a node of other package versions than the driver's
INSTALL_THE_DRIVERS = "install the driver's versions on every node (or its environment with a Ray runtime_env)"


class OtherVersions(UserError, RuntimeError):
    """Ray nodes run other package versions than the driver."""


def _node_versions() -> tuple[str, dict[str, str]]:
    return platform.node(), results.package_versions()


def version_differences(here: dict[str, str], driver: dict[str, str]) -> str:
    """``package X there, Y on the driver; ...`` for the packages whose versions differ
    (:func:`results.comparable_versions`), or nothing."""
    here, driver = results.comparable_versions(here), results.comparable_versions(driver)
    return "; ".join(f"{k} {here.get(k, 'absent')} there, {driver.get(k, 'absent')} on the driver"
                     for k in sorted(set(here) | set(driver)) if here.get(k) != driver.get(k))


def _ray_task(exp: Experiment, task: Task, cwd: str, versions: dict[str, str]) -> list[SequenceResult]:
    """On a node: relative dataset roots mean the same as for the driver when its folder exists
    there too (a shared file system, or data staged at the same path on every node). A node
    whose package versions differ from the driver's (``versions``: what the manifest records)
    fails the task, saying which: its results would be another setup's, mixed in silently."""
    if differ := version_differences(results.package_versions(), versions):
        return failed(task, f"Ray node {platform.node()} runs other package versions than the driver ({differ}): "
                            f"{INSTALL_THE_DRIVERS}, then rerun to resume")
    if os.path.isdir(cwd):
        os.chdir(cwd)
    one_thread_per_process()
    return run_task(exp, task)
