"""Tasks: one sequence and the runs of an experiment that read it, run in lockstep so that each
frame is decoded once for all of them, and only when some run needs it.

A 24-run matrix (trackers x MATA on/off x protocols x occlusion on/off) used to decode every
frame 24 times, 30 to 43 % of each run's CPU. A task instead advances every run's scheduler one
frame at a time (:func:`mata_eval.run.scheduler.sequence_steps`): the first run that asks for
frame k decodes it and the others get the same read-only array; runs with the same occlusion
settings also share the composited frame. Results do not depend on how runs are grouped: each
run has its own blocks and its own generator ``sequence_seed(seed, sequence name)``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import json
import os
import traceback
import warnings
import zlib
from typing import Any, Callable, Generator

import numpy as np

from ..core.sequence import Sequence
from ..core.types import FrameImage
from .config import Experiment, PluginBlock, RunSpec
from .scheduler import RateWarning, SequenceRun, sequence_steps


@dataclasses.dataclass(frozen=True)
class Task:
    """Runs ``runs`` (names) over sequence ``index`` of their dataset, ``frames`` frames long."""

    index: int
    sequence: str
    frames: int
    runs: tuple[str, ...]

    @property
    def cost(self) -> int:
        """Frames to schedule, the unit of work (a run costs about the same on every frame)."""
        return self.frames * len(self.runs)


@dataclasses.dataclass(frozen=True, eq=False)
class SequenceResult:
    """One (run, sequence) result as a task hands it to the driver, which writes the files.
    ``reason`` is empty when the sequence finished."""

    run: str
    sequence: str
    boxes: np.ndarray | None = None
    frames_csv: str = ""
    trace_csv: str = ""
    reason: str = ""
    traceback: str = ""
    bad_frames: tuple[tuple[int, str], ...] = ()  # (frame, why) excluded from scoring (on_bad_frame: skip)


def failed(task: Task, reason: str, tb: str = "") -> list[SequenceResult]:
    """Every run of ``task`` failed for the same ``reason`` (e.g. its worker died)."""
    return [SequenceResult(run, task.sequence, reason=reason, traceback=tb) for run in task.runs]


def _key(*parts: Any) -> str:
    return json.dumps(parts, sort_keys=True, default=str)


def runs_alone(spec: RunSpec, fps: float) -> bool:
    """The run is timed by its blocks' own wall times (VOT real-time, or a live protocol that
    runs the blocks itself): it gets a task of its own, since other runs' work between its calls
    would evict its caches and lengthen its calls."""
    protocol = spec.protocol.create()
    if hasattr(protocol, "run_sequence"):
        return True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RateWarning)  # the driver reported them once
        timing = protocol.timing(fps)
    return any(getattr(b.latency, "measured", False) for b in timing.blocks.values())   # WallTimeLatency and kin


def make_tasks(pending: list[tuple[RunSpec, int, Sequence]]) -> list[Task]:
    """One task per sequence of each dataset, holding every pending run that reads it (runs
    with the same occlusion settings next to each other), except the runs that run alone."""
    groups: dict[str, tuple[Sequence, int, list[RunSpec]]] = {}
    for spec, index, seq in pending:
        alone = spec.name if runs_alone(spec, seq.fps) else ""
        key = _key(spec.resolved["dataset"], index, alone)
        groups.setdefault(key, (seq, index, []))[2].append(spec)
    tasks = []
    for seq, index, specs in groups.values():
        specs.sort(key=lambda s: _key(s.resolved["occlusion"], s.seed))  # stable: experiment order
        tasks.append(Task(index, seq.name, len(seq), tuple(s.name for s in specs)))
    return tasks


def plan(tasks: list[Task], workers: int) -> list[Task]:
    """Longest task first (LPT order: a long task started last would finish last). The biggest
    task is halved (its runs split in two, so fewer runs share its decode) while it is bigger
    than an even share of all the work per worker (the longest task bounds the wall time) or
    while there are fewer than two tasks per worker (the last round would leave workers idle)."""
    share = sum(t.cost for t in tasks) / max(1, workers)
    heap = [(-t.cost, i, t) for i, t in enumerate(tasks)]
    heapq.heapify(heap)
    out: list[Task] = []
    while heap:
        _, i, t = heapq.heappop(heap)
        if len(t.runs) > 1 and (t.cost > share or len(heap) + len(out) + 1 < 2 * workers):
            half = len(t.runs) // 2
            for j, runs in enumerate((t.runs[:half], t.runs[half:])):
                part = dataclasses.replace(t, runs=runs)
                heapq.heappush(heap, (-part.cost, len(tasks) + 2 * i + j, part))
        else:
            out.append(t)
    return out  # popped from a max-heap: longest first


# --- in the worker --------------------------------------------------------------------------

def sequence_seed(seed: int, name: str) -> np.random.Generator:
    """Per-sequence generator from (experiment seed, sequence name): results do not depend on
    the order, the grouping or the process in which sequences run."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


_BASE: dict[str, list[Sequence]] = {}


def base_sequences(spec: RunSpec) -> list[Sequence]:
    """The sequences of the run's dataset (annotations; frames load lazily), cached per process."""
    key = _key(spec.resolved["dataset"], os.getcwd())   # a relative root: another dataset in another folder
    if key not in _BASE:
        _BASE[key] = list(spec.dataset.create().sequences())
    return _BASE[key]


def as_run_sees_it(seq: Sequence, spec: RunSpec) -> Sequence:
    """``seq`` with the run's occlusion augmentation (composited when a frame is read), if any;
    a sequence without usable frames as it is (its run fails, naming why, when it reads frame 0;
    the augmentation would read it for every run now, also of sequences ``--sequences`` leaves out)."""
    from ..data.datasets.annotations import MissingFrames, UnusableFrames

    if spec.occlusion is None or isinstance(seq.loader, (MissingFrames, UnusableFrames)):
        return seq
    from ..data.occlusion import augment_sequence

    return augment_sequence(seq, spec.occlusion, spec.seed)


class LastFrame:
    """``k -> image`` keeping the last frame it read, read-only: the runs of a task ask for frame
    k in turn before any asks for k + 1, so one read serves them all, and one
    :class:`~mata_eval.core.types.FrameImage` shares what their blocks derive from it."""

    def __init__(self, read: Callable[[int], np.ndarray]):
        self.read = read
        self.k = -1
        self.image: np.ndarray | None = None

    def __call__(self, k: int) -> np.ndarray:
        if k != self.k:
            image = FrameImage(self.read(k))
            image.flags.writeable = False  # shared by every run: no block may draw on it
            self.k, self.image = k, image
        return self.image


def shared(seq: Sequence) -> Sequence:
    return dataclasses.replace(seq, loader=LastFrame(seq.image))


def _enter(closing: contextlib.ExitStack, block: PluginBlock | None, spec: RunSpec, seq: str) -> Any:
    """A fresh instance of ``block`` (None for none), closed when ``closing`` ends (within the
    run's ``timeout_s``: a close() that hangs would hold the sequence's results forever)."""
    if block is None:
        return None
    return closing.enter_context(block.instance(spec.timeout_s, f" (run {spec.name}, sequence {seq})"))


def _failure(run: str, seq: str, exc: Exception) -> SequenceResult:
    return SequenceResult(run, seq, reason=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())


def _in_one_step(run: Callable[..., SequenceRun], *args: Any, **kwargs: Any) -> Generator[int, None, SequenceRun]:
    """``run(*args, **kwargs)`` as a generator of one step (for a run alone in its task)."""
    yield 0
    return run(*args, **kwargs)


def run_task(exp: Experiment, task: Task) -> list[SequenceResult]:
    """Run every run of ``task`` over its sequence, frame by frame in turn. A run that fails
    (unreadable frame, a block that raises or returns NaN) is recorded and the others go on."""
    specs = {s.name: s for s in exp.runs}
    try:
        base = base_sequences(specs[task.runs[0]])[task.index]
    except Exception as exc:  # e.g. the dataset is missing on this node
        return failed(task, f"{type(exc).__name__}: {exc}", traceback.format_exc())
    with contextlib.ExitStack() as closing, warnings.catch_warnings():  # blocks closed however it ends
        warnings.simplefilter("ignore", RateWarning)  # the driver reported them once
        return _lockstep(specs, task, base, closing)


def _lockstep(specs: dict[str, RunSpec], task: Task, base: Sequence,
              closing: contextlib.ExitStack) -> list[SequenceResult]:
    share = len(task.runs) > 1  # a run alone reads its frames itself (a live protocol: from threads)
    base = shared(base) if share else base
    views: dict[str, Sequence] = {}  # occlusion settings -> the sequence as those runs see it
    steps, results = {}, {}
    for name in task.runs:
        spec = specs[name]
        try:
            view = _key(spec.resolved["occlusion"], spec.seed)
            if view not in views:
                seq = as_run_sees_it(base, spec)
                views[view] = shared(seq) if share and seq is not base else seq
            blocks = tuple(_enter(closing, block, spec, task.sequence)
                           for block in (spec.tracker, spec.egomotion, spec.estimator))
            protocol = spec.protocol.create()
            rng = sequence_seed(spec.seed, base.name)
            if hasattr(protocol, "run_sequence"):  # a protocol that runs the blocks itself (live)
                steps[name] = _in_one_step(protocol.run_sequence, views[view], *blocks, rng, feedback=spec.feedback)
            else:  # a timing preset of the camera-clock scheduler
                steps[name] = sequence_steps(views[view], *blocks, protocol, rng, feedback=spec.feedback,
                                             call_timeout_s=spec.timeout_s,
                                             skip_bad_frames=spec.on_bad_frame == "skip")
        except Exception as exc:
            results[name] = _failure(name, task.sequence, exc)
    while steps:  # one frame of every run, then the next frame
        for name, step in list(steps.items()):
            try:
                next(step)
            except StopIteration as stop:
                run = stop.value
                results[name] = SequenceResult(name, task.sequence, run.boxes, run.frames_csv(), run.trace_csv(),
                                               bad_frames=tuple(getattr(run, "bad_frames", ())))
                del steps[name]
            except Exception as exc:  # one run must never take the others down
                results[name] = _failure(name, task.sequence, exc)
                del steps[name]
    return [results[name] for name in task.runs]
