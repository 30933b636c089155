"""The live runtime: MATA's blocks A, B and C in parallel on the real clock, as on board (issue 20;
the paper's ROS 2 run on the Jetson, section 4, which EOP is meant to predict).

Model of time (docs/live.md):

- **Camera.** Frame ``k`` is published at wall time ``t0 + k / fps``; its real publish time ``T_k``
  (seconds since ``t0``) is its capture time. Frames are decoded ahead (``prefetch``), so decoding
  is not on the camera's clock.
- **Blocks** run each in its own thread. A block that is free takes the newest published frame;
  the frames published while it was busy are dropped, never queued (``skip`` in the trace).
  Egomotion: ``estimate(image)``, the motion from the previous frame *it* took. Tracker:
  ``track(image, prior)``, the prior being the search centre of the newest estimate published
  before it starts (``Estimate.prior``: its centre, or none when it withholds it). Estimator: one
  tick per frame it takes, ``step(T_k, motions, detections)`` with every output published since
  its previous tick, oldest first, each ``Stamped(value, T_capture, t_publish)``; its estimate is
  kept within half a box of the image (``Estimate.within``, as in the scheduler).
- **time_scale** ``s`` (one value or per block): a call whose work took ``d`` seconds publishes
  ``s d`` after it started; the worker sleeps ``(s - 1) d`` (a device ``s`` times slower, each block
  on its own core; the sleep leaves the CPU to the other blocks).
- **Scoring.** Frame ``k``'s box is the newest output of the output block (the estimator, or the
  tracker without one) published at or before ``T_k``: a zero-order hold on real times. The
  initial box is held until the first output; frame 0 initialises every block.

Threads, not processes: the blocks spend their time in OpenCV, ONNX Runtime and numpy, which
release the GIL (``benchmarks/live_overlap.py`` measures threads against processes); processes
would copy every frame and output between address spaces and load each model once per process.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from .scheduler import (BLOCKS, EPS, MOTION_CALL_COLUMNS, TRACKER_CALL_COLUMNS, BlockError, SequenceRun,
                        TraceEvent, frames_and_fps, motion_call_row, output_problem, plugin_name, start_box,
                        tracker_call_row)
from ..core.sequence import Sequence
from ..core.types import Box, Stamped


@dataclass(frozen=True, eq=False)
class Call:
    """One block call as it happened: the frame it took, its start and publish times (seconds
    since the camera's ``t0``; ``t_publish`` is None for a call cut short at the end), the
    measured work time (before ``time_scale``) and its output (None for an initialisation)."""

    block: str
    frame: int
    t_start: float
    t_publish: float | None
    work_s: float
    value: Any = None
    prior: tuple[float, float] | None = None   # a tracker call's search centre handed over


@dataclass
class _Bus:
    """What the threads share, under one condition variable: the newest frame, every published
    output, and the run state."""

    cond: threading.Condition = field(default_factory=threading.Condition)
    frame: tuple[int, float, np.ndarray] | None = None
    camera_t: list[float] = field(default_factory=list)
    calls: dict[str, list[Call]] = field(default_factory=lambda: {b: [] for b in BLOCKS})
    done: bool = False          # the camera published its last frame: take it if not yet taken
    stopped: bool = False       # a block failed or Ctrl-C: take nothing more
    error: BaseException | None = None
    ending: threading.Event = field(default_factory=threading.Event)  # cuts time_scale sleeps

    def published(self, block: str, t: float | None = None) -> list[Call]:
        """Outputs of ``block`` (initialisations excluded) published so far / at or before ``t``."""
        return [c for c in self.calls[block]
                if c.value is not None and c.t_publish is not None and (t is None or c.t_publish <= t + EPS)]


class _Prefetcher:
    """Decodes frames ahead of the camera in a thread, at most ``ahead`` frames in memory."""

    def __init__(self, sequence: Sequence, ahead: int):
        self.sequence, self.ahead = sequence, max(1, ahead)
        self.images: dict[int, np.ndarray] = {}
        self.error: BaseException | None = None
        self.next_k = 0          # next frame the camera wants
        self.cond = threading.Condition()
        self.stop = False
        self.thread = threading.Thread(target=self._run, name="live-prefetch", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        for k in range(len(self.sequence)):
            with self.cond:
                self.cond.wait_for(lambda: self.stop or k < self.next_k + self.ahead)
                if self.stop:
                    return
            try:
                img = self.sequence.image(k)
            except BaseException as exc:  # reported to the camera, which raises it
                with self.cond:
                    self.error = exc
                    self.cond.notify_all()
                return
            with self.cond:
                self.images[k] = img
                self.cond.notify_all()

    def wait_ready(self, count: int) -> None:
        with self.cond:
            self.cond.wait_for(lambda: self.error is not None or len(self.images) >= count)

    def take(self, k: int) -> np.ndarray:
        with self.cond:
            self.cond.wait_for(lambda: self.error is not None or k in self.images)
            if k not in self.images:
                raise self.error  # type: ignore[misc]
            self.next_k = k + 1
            self.cond.notify_all()
            return self.images.pop(k)

    def close(self) -> None:
        """Stop decoding and wait for the frame being decoded: a daemon thread still inside
        OpenCV when the interpreter exits (Ctrl-C before the clock started) aborted the process
        ("terminate called without an active exception", SIGABRT). A frame source that blocks
        for good is left after 10 s, with a line saying so (the exit may then abort)."""
        with self.cond:
            self.stop = True
            self.cond.notify_all()
        self.thread.join(timeout=10.0)
        if self.thread.is_alive():
            print(f"warning: live: reading a frame of {self.sequence.name} did not return within 10 s; "
                  "left running", file=sys.stderr, flush=True)


def run_live(
    sequence: Sequence,
    tracker: Any,
    egomotion: Any = None,
    estimator: Any = None,
    *,
    feedback: bool = True,
    time_scale: Mapping[str, float] | float = 1.0,
    warmup: int = 2,
    prefetch: int = 128,
) -> SequenceRun:
    """Run the blocks over ``sequence`` on the wall clock (see the module docstring) and return
    the same result as the scheduler: boxes held at each frame's real time, per-frame work times,
    and a trace of real start / publish / skip times. Ctrl-C (KeyboardInterrupt) stops the camera,
    lets each block finish the call it is in, and is raised again."""
    n, fps = frames_and_fps(sequence)
    scale = {b: float(time_scale.get(b, 1.0) if isinstance(time_scale, Mapping) else time_scale) for b in BLOCKS}
    objs = {"egomotion": egomotion, "tracker": tracker, "estimator": estimator}
    active = [b for b in BLOCKS if objs[b] is not None]
    init_box = start_box(sequence)
    prefetcher = _Prefetcher(sequence, prefetch)
    bus = _Bus()
    switch = sys.getswitchinterval()
    # A thread woken by a new frame waits for the GIL until the running thread's switch
    # interval expires (5 ms by default, a sixth of a 30 Hz frame): 0.5 ms cuts the p90 of the
    # ego-motion's and estimator's start delay from ~5 to ~3 ms on the shared 2-core machine.
    sys.setswitchinterval(5e-4)
    try:
        prefetcher.wait_ready(min(n, prefetch))
        if warmup > 0:
            _warm_up(objs, sequence.image(0), init_box, warmup)
        now = lambda: time.perf_counter() - t0  # noqa: E731  (t0 is set below, before frame 0)
        threads = [threading.Thread(target=_worker, name=f"live-{b}", daemon=True,
                                    args=(b, objs, bus, now, scale[b], init_box, feedback and estimator is not None))
                   for b in active]
        for th in threads:
            th.start()
        # The clock starts once the workers run (they call now() only on a published frame), so
        # frame 0 is not late by the threads' start-up.
        t0 = time.perf_counter()
        camera_error: list[BaseException] = []
        camera = threading.Thread(target=_camera_thread, name="live-camera", daemon=True,
                                  args=(bus, prefetcher, n, fps, t0, camera_error))
        camera.start()
        try:
            # The camera has its own thread, so that Ctrl-C arrives here, where this thread holds
            # no lock: a KeyboardInterrupt raised just after a `with bus.cond:` took the lock left
            # it held, and a worker waiting for it kept the process alive (a hung test, once).
            while camera.is_alive():
                camera.join(0.05)
        except BaseException:  # Ctrl-C
            with bus.cond:
                bus.stopped = True
            raise
        finally:  # normal end, a block error, Ctrl-C: every worker finishes the call it is in
            with bus.cond:
                bus.done = True
                bus.cond.notify_all()
            bus.ending.set()
            for th in threads:
                th.join()
        if camera_error:   # a frame that cannot be read
            raise camera_error[0]
    finally:
        prefetcher.close()
        sys.setswitchinterval(switch)
    if bus.error is not None:
        raise bus.error
    return assemble(bus.camera_t, bus.calls, fps, init_box, estimator is not None)


def _camera_thread(bus: _Bus, prefetcher: _Prefetcher, n: int, fps: float, t0: float,
                   error: list[BaseException]) -> None:
    """:func:`_camera` in its thread; what stops it (an unreadable frame) stops the run and goes
    into ``error`` for the caller to raise."""
    try:
        _camera(bus, prefetcher, n, fps, t0)
    except BaseException as exc:
        error.append(exc)
        with bus.cond:
            bus.stopped = True


def _camera(bus: _Bus, prefetcher: _Prefetcher, n: int, fps: float, t0: float) -> None:
    """Publish frame k at ``t0 + k / fps`` (in the camera thread, :func:`_camera_thread`)."""
    for k in range(n):
        image = prefetcher.take(k)
        while (wait := t0 + k / fps - time.perf_counter()) > 0:
            if bus.ending.wait(wait):  # a block failed
                return
        with bus.cond:
            if bus.stopped:
                return
            t_k = time.perf_counter() - t0
            bus.frame = (k, t_k, image)
            bus.camera_t.append(t_k)
            bus.cond.notify_all()


def _warm_up(objs: Mapping[str, Any], image: np.ndarray, box: Box, calls: int) -> None:
    """Untimed calls before the clock starts (model loading, first-call allocations: a node's
    start-up, not tracking); every block is initialised again when the clock starts."""
    steps = {"tracker": (lambda o: o.initialize(image, box), lambda o: o.track(image, None)),
             "egomotion": (lambda o: o.initialize(image), lambda o: o.estimate(image)),
             "estimator": (lambda o: o.initialize(box, 0.0), lambda o: o.step(0.0, (), ()))}
    for block, (init, call) in steps.items():
        obj = objs[block]
        if obj is None:
            continue
        try:
            init(obj)
            for _ in range(calls):
                call(obj)
        except Exception as exc:
            raise BlockError(block, 0, 0.0, f"warm-up: {type(exc).__name__}: {exc}", plugin_name(obj)) from exc


def _worker(block: str, objs: Mapping[str, Any], bus: _Bus, now: Callable[[], float], scale: float,
            init_box: Box, feedback: bool) -> None:
    """One block's loop: wait for a frame newer than the last one taken, take the newest, call,
    stretch by ``scale``, publish."""
    obj = objs[block]
    last = -1
    read = {"egomotion": 0, "tracker": 0}  # the estimator's read positions in the outputs
    while True:
        with bus.cond:
            bus.cond.wait_for(lambda: bus.stopped or bus.done or (bus.frame is not None and bus.frame[0] > last))
            if bus.stopped or bus.frame is None or bus.frame[0] <= last:
                return
            k, t_k, image = bus.frame
            t_start = now()
            first = last < 0
            prior = None
            if first:
                call = _initializer(block, obj, image, init_box, t_k)
            elif block == "egomotion":
                call = lambda: obj.estimate(image)  # noqa: E731
            elif block == "tracker":
                if feedback:
                    est = bus.published("estimator")
                    if est:
                        prior = est[-1].value.prior
                call = lambda: obj.track(image, prior)  # noqa: E731
            else:
                inputs = {}
                for src in ("egomotion", "tracker"):
                    outs = bus.published(src)
                    inputs[src] = [Stamped(c.value, bus.camera_t[c.frame], c.t_publish) for c in outs[read[src]:]]
                    read[src] = len(outs)
                call = lambda: obj.step(t_k, inputs["egomotion"], inputs["tracker"])  # noqa: E731
        c0 = time.perf_counter()
        try:
            value = call()
            _check(block, value, first)
            if block == "estimator":  # kept within half a box of the image, as in the scheduler
                value = value.within(image.shape[1], image.shape[0])
        except Exception as exc:
            err = BlockError(block, k, t_k, f"{type(exc).__name__}: {exc}", plugin_name(obj))
            err.__cause__ = exc
            with bus.cond:
                bus.error = bus.error or err
                bus.stopped = True
                bus.cond.notify_all()
            bus.ending.set()
            return
        work = time.perf_counter() - c0
        cut = scale > 1 and bus.ending.wait((scale - 1.0) * work)
        with bus.cond:
            t_pub = None if cut else now()
            if first and block != "estimator":
                value = None  # an initialisation publishes nothing (the initial box is held)
            bus.calls[block].append(Call(block, k, t_start, t_pub, work, value, prior))
        last = k


def _initializer(block: str, obj: Any, image: np.ndarray, box: Box, t: float) -> Callable[[], Any]:
    if block == "tracker":
        return lambda: obj.initialize(image, box)
    if block == "egomotion":
        return lambda: obj.initialize(image)
    return lambda: obj.initialize(box, t)


def _check(block: str, value: Any, first: bool) -> None:
    """The scheduler's check of a block's output (:func:`output_problem`); an initialisation
    returns nothing to check, except the estimator's first estimate."""
    if first and block != "estimator":
        return
    if (problem := output_problem(block, value)) is not None:
        raise ValueError(problem)


def assemble(camera_t: list[float], calls: Mapping[str, list[Call]], fps: float, init_box: Box,
             has_estimator: bool) -> SequenceRun:
    """The run's result from what happened: frame ``k`` scores the newest output of the output
    block published at or before ``T_k`` (``camera_t[k]``); the trace holds the camera's
    publishes, each call's start (at the frame it took) and publish (at the first frame at or after
    it; none after the last frame) and a skip for every frame a block did not take."""
    n = len(camera_t)
    t_cam = np.asarray(camera_t, dtype=float)
    t_last = t_cam[-1]
    out_block = "estimator" if has_estimator else "tracker"

    def held(block: str) -> tuple[np.ndarray, list[Call]]:
        """Index (into the block's outputs) of the newest output visible at each frame, -1: none."""
        outs = [c for c in calls.get(block, [])[1:] if c.t_publish is not None]
        t_pub = np.array([c.t_publish for c in outs], dtype=float)
        return np.searchsorted(t_pub, t_cam + EPS, side="right") - 1, outs

    idx, outs = held(out_block)
    boxes = np.tile(init_box.as_array(), (n, 1))
    source = np.zeros(n, dtype=int)
    for k, i in enumerate(idx):
        if i >= 0:
            boxes[k] = outs[i].value.box.as_array()
            source[k] = outs[i].frame
    cidx, couts = held("tracker")
    confidence = np.array([float(couts[i].value.confidence) if i >= 0 else math.nan for i in cidx])

    trace = [TraceEvent("camera", "publish", k, float(t)) for k, t in enumerate(t_cam)]
    wall_ms = {}
    for block in BLOCKS:
        cs = calls.get(block, [])
        if not cs:
            continue
        ms = np.full(n, np.nan)
        for c in cs:
            ms[c.frame] = 1e3 * c.work_s
            trace.append(TraceEvent(block, "start", c.frame, c.t_start))
            if c.t_publish is not None and c.t_publish <= t_last + EPS:
                j = int(np.searchsorted(t_cam, c.t_publish - EPS, side="left"))
                trace.append(TraceEvent(block, "publish", j, c.t_publish))
        taken = {c.frame for c in cs}
        trace.extend(TraceEvent(block, "skip", k, float(t_cam[k])) for k in range(n) if k not in taken)
        wall_ms[block] = ms
    trace.sort(key=lambda e: (e.frame, e.t))
    rates = {b: len(calls[b]) * fps / n for b in wall_ms}
    tracker_calls = np.full((n, len(TRACKER_CALL_COLUMNS)), np.nan)   # for `mata-eval play`, as EOP's
    for c in calls.get("tracker", [])[1:]:
        tracker_calls[c.frame] = tracker_call_row(c.value, c.prior)
    motion_calls = None
    if calls.get("egomotion"):
        motion_calls = np.full((n, len(MOTION_CALL_COLUMNS)), np.nan)
        for c in calls["egomotion"][1:]:
            motion_calls[c.frame] = motion_call_row(c.value)
    return SequenceRun(fps, boxes, np.ones(n, bool), confidence, source, wall_ms, tuple(trace), rates,
                       tracker_calls=tracker_calls, motion_calls=motion_calls)
