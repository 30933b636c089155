"""The one discrete-event scheduler behind every protocol (paper section 3.1; DESIGN.md "One
scheduler, four protocols").

Model. The camera delivers frame ``k`` at ``t_k = k / fps`` (DSP delivers only every n-th frame).
Each block (egomotion B, tracker A, estimator C) has a rate and an output latency. A block gets a
*turn* at a delivered frame when its rate grid ``m / hz`` has passed a tick since its previous
turn (a 10 Hz block on a 30 Hz stream: frames 0, 3, 6, ...). At a turn it starts if it is idle;
a block still busy skips the turn (no queueing). A call started at ``t_k`` publishes its output
on the shared board at ``t_k + latency`` (plus an optional per-link communication delay before a
given consumer sees it); the block is busy until it publishes. Within one frame the blocks run
in data-flow order (camera, egomotion, estimator, tracker), so a zero-latency output published at
``t_k`` is seen by the blocks after it in that order at the same frame. The estimator's tick is
split around the tracker (DESIGN.md): it first takes the camera motion and the detections visible
at ``t_k`` (so the tracker's search centre at frame k is the estimate at frame k), then, when the
tracker published a detection at ``t_k`` itself (zero latency), a second ``step(t_k, (), dets)``
at the same time folds it into the estimate of frame k; the two calls are one tick (one start,
one latency, their wall times summed). Every estimate is kept within half a box of the image
(``Estimate.within``: a coasting estimate does not run away, issue 14). The scored value of frame
``k`` is the newest output of the output block (the estimator, or the tracker without one)
visible at ``t_k``: a zero-order hold.

Frame 0 initialises every block (tracker with the ground-truth box, egomotion with image 0,
estimator with the ground-truth box at t = 0); an initialisation is a call like any other (its
latency occupies the block) and publishes nothing new: the initial box is held until the first
output. With an estimator and ``feedback``, the tracker's prior at each start is the search centre
of the estimator's newest estimate visible then (at frame k: the estimate of frame k;
``Estimate.prior``: its centre, another centre it names, or none when it withholds it). The estimator is handed, at each of its ticks, the
outputs that became visible to it since its previous tick, each ``Stamped(value, t_capture,
t_publish)`` with ``t_publish`` the time it reached the estimator (the paper's ``delay: ignore``
is the estimator's business).
"""

from __future__ import annotations

import io
import math
import numbers
import os
import re
import signal
import threading
import time
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Generator, Mapping, NamedTuple, Protocol

import numpy as np

from ..core.sequence import FrameReadError, Sequence
from .timing_profile import BlockProfile
from ..core.types import Box, Estimate, FrameImage, Motion, Stamped, TrackerOutput

#: The blocks. ``camera`` only delivers frames.
BLOCKS = ("egomotion", "tracker", "estimator")
#: Intra-frame order: the estimator's tick is split around the tracker, so the tracker's search
#: centre at frame k is the estimate at frame k (camera motion up to k applied) and a detection
#: published at t_k still reaches the estimate of frame k ("estimator+").
ORDER = ("egomotion", "estimator", "tracker", "estimator+")
LANES = ("camera",) + BLOCKS
EVENTS = ("start", "publish", "skip")
#: ``<seq>.frames.csv`` columns of each tracker call: its box, its search region (where the
#: tracker reports one) and the prior it was handed (MATA's search centre; NaN: none, withheld)
TRACKER_CALL_COLUMNS = ("tracker_x", "tracker_y", "tracker_w", "tracker_h",
                        "search_x", "search_y", "search_w", "search_h", "prior_x", "prior_y")
EPS = 1e-9  # seconds: tolerance of time comparisons on the camera clock


#: set to 1, a run asks its estimator for ``diagnostics()`` (its state, a dict of numbers) after
#: each of its ticks and writes them as ``est_<key>`` columns of ``<seq>.frames.csv`` (a diagnosis:
#: results are the same; the live runtime does not record them)
RECORD_ENV = "MATA_EVAL_RECORD"
#: ``<seq>.frames.csv`` columns of each ego-motion call: whether its motion is valid, its inlier
#: count and point noise (px), and whether it found the picture repeated (1 / 0)
MOTION_CALL_COLUMNS = ("motion_valid", "motion_inliers", "motion_sigma", "motion_unchanged")


def motion_call_row(motion: Motion) -> tuple[float, ...]:
    """The MOTION_CALL_COLUMNS of one ego-motion call."""
    sigma = math.nan if motion.sigma is None else float(motion.sigma)
    return float(bool(motion.valid)), float(motion.inliers), sigma, float(bool(motion.unchanged))


def tracker_call_row(output: TrackerOutput, prior: tuple[float, float] | None) -> tuple[float, ...]:
    """The TRACKER_CALL_COLUMNS of one tracker call: its box, its search region where the tracker
    reports one (``extra`` keys ``search_x, search_y, search_w, search_h``; NaN if not) and the
    prior it was handed (NaN when none)."""
    b, ex = output.box, output.extra or {}
    return ((b.x, b.y, b.w, b.h) + tuple(float(ex.get(c, math.nan)) for c in TRACKER_CALL_COLUMNS[4:8])
            + ((math.nan, math.nan) if prior is None else (float(prior[0]), float(prior[1]))))


# --- timing specs (what a protocol gives the scheduler) ----------------------------------------

class Latency(Protocol):
    """Output latency of one call, in seconds; ``wall_s`` is the call's measured wall time."""

    def draw(self, rng: np.random.Generator, wall_s: float) -> float: ...


@dataclass(frozen=True)
class FixedLatency:
    """A constant latency (the paper's EOP: zero or one period)."""

    seconds: float = 0.0

    def draw(self, rng: np.random.Generator, wall_s: float) -> float:
        return self.seconds


@dataclass(frozen=True, eq=False)
class ProfileLatency:
    """A latency drawn per call from a measured timing profile (seeded by the run's rng)."""

    profile: BlockProfile

    def draw(self, rng: np.random.Generator, wall_s: float) -> float:
        return float(self.profile.sample(rng))


@dataclass(frozen=True)
class WallTimeLatency:
    """The call's own wall-clock time on this machine, times ``scale`` (VOT real-time)."""

    scale: float = 1.0
    #: a latency measured on this machine: its run gets a task of its own (mata_eval.run.tasks)
    measured: ClassVar[bool] = True

    def draw(self, rng: np.random.Generator, wall_s: float) -> float:
        return self.scale * wall_s


@dataclass(frozen=True)
class BlockTiming:
    """Rate (turns per second of camera time), latency, and the standard deviation of a
    Gaussian per-call jitter added to the latency (clipped at zero)."""

    hz: float
    latency: Latency = FixedLatency(0.0)
    jitter_s: float = 0.0
    #: tracker only: free between two frames, it starts at once on the newest frame (as the live
    #: protocol's blocks do) instead of at the next frame (docs/live.md, "What differs from EOP")
    free_start: bool = False


@dataclass(frozen=True)
class Timing:
    """Everything the scheduler needs from a protocol for one sequence.

    ``camera_hz``: rate at which the camera delivers frames (``fps``, or ``fps / n`` for DSP);
    only delivered frames are scored and only they can start blocks.
    ``blocks``: timing of ``egomotion``, ``tracker`` and ``estimator`` (those absent from the
    run are ignored). ``link_delay_s``: ``(producer, consumer) -> seconds`` communication delay,
    consumers being the blocks and ``"output"`` (the scored output)."""

    camera_hz: float
    blocks: Mapping[str, BlockTiming]
    link_delay_s: Mapping[tuple[str, str], float] = field(default_factory=dict)


class ProtocolPreset(Protocol):
    """What a protocol plugin provides: the timing of each block for a camera rate. (A protocol
    that runs the blocks itself, ``live``, provides ``run_sequence(sequence, tracker, egomotion,
    estimator, rng, feedback)`` returning a :class:`SequenceRun` instead; the runner calls it.)"""

    def timing(self, fps: float) -> Timing: ...


def every_frame(fps: float, latency_s: float = 0.0) -> Timing:
    """Every block at the camera rate with a fixed latency (LTP when ``latency_s`` is 0)."""
    return Timing(fps, {b: BlockTiming(fps, FixedLatency(latency_s)) for b in BLOCKS})


# --- results ---------------------------------------------------------------------------------

class TraceEvent(NamedTuple):
    """One scheduler event. ``frame``: the frame at which it happens (for a publish, the first
    frame at or after its publish time ``t``)."""

    block: str
    event: str  # start | publish | skip
    frame: int
    t: float


class RateWarning(UserWarning):
    """A protocol's rate that the camera grid cannot give; names the rate actually run."""


class BlockError(RuntimeError):
    """A block raised or returned an unusable value; names the block, its plugin (when known:
    :func:`plugin_name`) and the frame."""

    def __init__(self, block: str, frame: int, t: float, message: str, plugin: str | None = None):
        self.block, self.frame, self.t, self.plugin = block, frame, t, plugin
        who = block if plugin is None else f"{block} {plugin!r}"
        super().__init__(f"{who} failed at frame {frame} (t = {t:.4f} s): {message}")


def plugin_name(obj: Any) -> str | None:
    """The name a block object's plugin goes by (its ``name``, else its class's name); None for
    None."""
    if obj is None:
        return None
    name = getattr(obj, "name", None)
    return name if isinstance(name, str) and name else type(obj).__name__


@dataclass(frozen=True, eq=False)
class SequenceRun:
    """The scheduler's result for one sequence (N frames).

    ``boxes`` (N, 4): scored box per frame (held value); ``scored`` (N,): frame delivered and
    scored; ``confidence`` (N,): newest tracker confidence visible (NaN before the first
    output); ``source_frame`` (N,): capture frame of the held value (0 = the initial box);
    ``wall_ms``: block -> (N,) wall time of the call started at frame k (NaN where none);
    ``trace``: start/publish/skip events; ``rates_hz``: block -> starts per second of camera
    time (initialisation included); ``bad_frames``: (frame, reason) of the unreadable frames
    that were excluded from scoring (``skip_bad_frames``); ``tracker_calls``: (N, 8) for
    ``mata-eval play``, the box ``x, y, w, h`` returned by the tracker call started at frame k
    and its search region (the tracker's ``extra`` keys ``search_x, search_y, search_w,
    search_h``), NaN where none."""

    fps: float
    boxes: np.ndarray
    scored: np.ndarray
    confidence: np.ndarray
    source_frame: np.ndarray
    wall_ms: Mapping[str, np.ndarray]
    trace: tuple[TraceEvent, ...]
    rates_hz: Mapping[str, float]
    bad_frames: tuple[tuple[int, str], ...] = ()
    tracker_calls: np.ndarray | None = None
    motion_calls: np.ndarray | None = None
    estimator_state: Mapping[str, np.ndarray] | None = None   # MATA_EVAL_RECORD: est_<key> columns

    def frames_csv(self) -> str:
        cols = ["frame", "scored", "confidence"] + [f"{b}_ms" for b in self.wall_ms] + ["source_frame"]
        if self.tracker_calls is not None:
            cols += list(TRACKER_CALL_COLUMNS)
        if self.motion_calls is not None:
            cols += list(MOTION_CALL_COLUMNS)
        state = self.estimator_state or {}
        cols += [f"est_{key}" for key in state]
        out = io.StringIO()
        out.write(",".join(cols) + "\n")
        conf = [_fmt(v) for v in self.confidence]
        walls = [[_fmt(v) for v in ms] for ms in self.wall_ms.values()]
        for k in range(len(self.boxes)):
            cells = [str(k), str(int(self.scored[k])), conf[k]] + [w[k] for w in walls]
            cells.append(str(int(self.source_frame[k])))
            if self.tracker_calls is not None:
                cells += [_fmt(v) for v in self.tracker_calls[k]]
            if self.motion_calls is not None:
                cells += [_fmt(v) for v in self.motion_calls[k]]
            cells += [_fmt(v[k]) for v in state.values()]
            out.write(",".join(cells) + "\n")
        return out.getvalue()

    def trace_rows(self) -> list[tuple[str, str, int, float]]:
        """Rows of ``<seq>.trace.csv``: (block, event, frame, t)."""
        return [tuple(e) for e in self.trace]

    def trace_csv(self) -> str:
        return trace_to_csv(self.trace)


def trace_to_csv(rows: Any) -> str:
    out = io.StringIO()
    out.write("block,event,frame,t\n")
    for block, event, frame, t in rows:
        out.write(f"{block},{event},{int(frame)},{float(t)!r}\n")  # repr: exact round trip
    return out.getvalue()


def read_trace_csv(text: str) -> list[TraceEvent]:
    """Parse the text of a ``<seq>.trace.csv`` file."""
    lines = text.strip().splitlines()
    if not lines or lines[0].strip() != "block,event,frame,t":
        raise ValueError("not a trace file: expected the header 'block,event,frame,t'")
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        parts = line.split(",")
        if len(parts) != 4 or parts[1] not in EVENTS:
            raise ValueError(f"trace line {i}: expected block,start|publish|skip,frame,t; got {line!r}")
        rows.append(TraceEvent(parts[0], parts[1], int(parts[2]), float(parts[3])))
    return rows


def _fmt(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.6g}"


# --- the scheduler ---------------------------------------------------------------------------

def turn_frames(n_frames: int, hz: float, fps: float, delivered: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: frames at which a block of rate ``hz`` gets a turn. Its ticks lie on the grid
    ``m / hz``; the turn is the first delivered frame at or after a tick (several ticks passed
    in one gap give one turn). Frame 0 is always a turn."""
    if not (hz > 0 and math.isfinite(hz)):
        raise ValueError(f"a block rate must be a positive number of Hz, got {hz!r}")
    k = np.arange(n_frames)
    delivered = np.ones(n_frames, bool) if delivered is None else delivered
    ticks = np.floor(k * hz / fps + EPS)  # number of grid ticks at or before t_k
    kd = np.flatnonzero(delivered)
    out = np.zeros(n_frames, bool)
    if kd.size:
        md = ticks[kd]
        out[kd] = np.concatenate([[True], md[1:] > md[:-1]])
    return out


@dataclass
class _Board:
    """One block's published outputs, in publish order (a block never overlaps its own calls,
    so publish times are increasing)."""

    values: list = field(default_factory=list)
    t_capture: list = field(default_factory=list)
    k_capture: list = field(default_factory=list)
    t_publish: list = field(default_factory=list)

    def post(self, value: Any, t_capture: float, k_capture: int, t_publish: float) -> None:
        self.values.append(value)
        self.t_capture.append(t_capture)
        self.k_capture.append(k_capture)
        self.t_publish.append(t_publish)

    def visible(self, t: float, delay: float = 0.0) -> int:
        """Number of outputs visible at ``t`` through a link of ``delay`` seconds."""
        return bisect_right(self.t_publish, t - delay + EPS)


def frames_and_fps(sequence: Sequence) -> tuple[int, float]:
    """The camera clock of ``sequence``: its frame count and fps, checked (no frames, or an fps
    that is not a positive number, is an error naming the sequence)."""
    fps = float(sequence.fps)
    n = len(sequence)
    if n == 0:
        raise ValueError(f"sequence {sequence.name!r} has no frames")
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"sequence {sequence.name!r}: fps must be positive, got {sequence.fps!r}")
    return n, fps


def start_box(sequence: Sequence) -> Box:
    """The box the tracker starts from (:attr:`Sequence.init_box`), checked: an absent or empty
    frame-0 box is an error naming the sequence, not the tracker's complaint about a box."""
    box = sequence.init_box
    if not box.is_valid:
        raise ValueError(f"sequence {sequence.name!r}: no target box in frame 0 to start the tracker from "
                         f"(its first ground-truth line is absent, NaN or of zero size: {box.as_array().tolist()})")
    return box


def run_sequence(
    sequence: Sequence,
    tracker: Any,
    egomotion: Any,
    estimator: Any,
    protocol: ProtocolPreset,
    rng: np.random.Generator,
    feedback: bool = True,
    *,
    clock: Callable[[], float] = time.perf_counter,
    call_timeout_s: float | None = None,
    skip_bad_frames: bool = False,
) -> SequenceRun:
    """Run the blocks over ``sequence`` as ``protocol`` times them (see the module docstring).

    ``egomotion`` / ``estimator`` may be None. ``clock`` measures wall time (seconds).
    ``call_timeout_s``: a block call that runs longer raises :class:`BlockError` (main thread).
    A frame that cannot be read, or whose size differs from frame 0's, raises
    :class:`FrameReadError`; with ``skip_bad_frames`` (any frame but 0) the blocks skip it and
    it is not scored (``SequenceRun.bad_frames``)."""
    steps = sequence_steps(sequence, tracker, egomotion, estimator, protocol, rng, feedback, clock=clock,
                           call_timeout_s=call_timeout_s, skip_bad_frames=skip_bad_frames)
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def sequence_steps(
    sequence: Sequence,
    tracker: Any,
    egomotion: Any,
    estimator: Any,
    protocol: ProtocolPreset,
    rng: np.random.Generator,
    feedback: bool = True,
    *,
    clock: Callable[[], float] = time.perf_counter,
    call_timeout_s: float | None = None,
    skip_bad_frames: bool = False,
) -> Generator[int, None, SequenceRun]:
    """:func:`run_sequence` one frame at a time: yields ``k`` before frame k, returns the
    :class:`SequenceRun`. Several runs of one sequence advanced in turn ask for frame k one
    after the other, so they can share its decode (:mod:`mata_eval.run.tasks`)."""
    n, fps = frames_and_fps(sequence)
    timing = protocol.timing(fps)
    objs = {"egomotion": egomotion, "tracker": tracker, "estimator": estimator}
    active = [b for b in BLOCKS if objs[b] is not None]
    for b in active:
        if b not in timing.blocks:
            raise ValueError(f"protocol {type(protocol).__name__} gives no timing for block {b!r}")
    links = dict(timing.link_delay_s)

    def link(src: str, dst: str) -> float:
        return float(links.get((src, dst), 0.0))

    delivered = turn_frames(n, timing.camera_hz, fps)
    turns = {b: turn_frames(n, timing.blocks[b].hz, fps, delivered).tolist() for b in active}
    is_delivered = delivered.tolist()
    # Link delays, looked up once (the loop below runs once per frame).
    d_est_trk, d_ego_est, d_trk_est = link("estimator", "tracker"), link("egomotion", "estimator"), link("tracker", "estimator")
    d_trk_out = link("tracker", "output")
    boards = {b: _Board() for b in BLOCKS}
    busy_until = {b: -math.inf for b in BLOCKS}
    calls = {b: 0 for b in BLOCKS}
    consumed = {"egomotion": 0, "tracker": 1}  # estimator's read position (tracker: after the init box)
    wall_ms = {b: np.full(n, np.nan) for b in ("tracker", "egomotion", "estimator") if b in active}
    tracker_calls = np.full((n, len(TRACKER_CALL_COLUMNS)), np.nan)
    motion_calls = np.full((n, len(MOTION_CALL_COLUMNS)), np.nan)
    record = (estimator is not None and callable(getattr(estimator, "diagnostics", None))
              and os.environ.get(RECORD_ENV, "") not in ("", "0"))
    est_state: dict[str, np.ndarray] = {}
    trace: list[TraceEvent] = []
    t_end = (n - 1) / fps
    init_box = start_box(sequence)

    # The initial box is held (visible at t = 0) until the first output.
    boards["tracker"].post(TrackerOutput(init_box, math.nan), 0.0, 0, 0.0)

    out_block = "estimator" if estimator is not None else "tracker"
    d_out = link(out_block, "output")
    init_row = init_box.as_array()
    boxes = np.empty((n, 4))
    confidence = np.full(n, np.nan)
    source = np.zeros(n, dtype=int)
    scored = delivered.copy()
    bad_frames: list[tuple[int, str]] = []
    frame_size: tuple[int, int] | None = None  # (width, height) of frame 0

    def read_frame(k: int) -> np.ndarray:
        nonlocal frame_size
        img = sequence.image(k)
        size = (int(img.shape[1]), int(img.shape[0]))
        if frame_size is None:
            frame_size = size
        elif size != frame_size:
            where = f" ({sequence.frame_paths[k]})" if sequence.loader is None and sequence.frame_paths else ""
            raise FrameReadError(f"frame {k} of sequence {sequence.name!r}{where} is {size[0]}x{size[1]} pixels, "
                                 f"frame 0 is {frame_size[0]}x{frame_size[1]}")
        return img

    free_tracker = "tracker" in active and timing.blocks["tracker"].free_start

    def bounded(value: Estimate) -> Estimate:
        """The estimate kept within half a box of the image (:meth:`Estimate.within`)."""
        if frame_size is None:
            frame_image()  # frame 0, which the tracker reads at this frame anyway
        return value.within(*frame_size)

    def prior_at(t: float) -> tuple[float, float] | None:
        """The tracker's search centre: the newest estimate that reached it by ``t``."""
        if feedback and estimator is not None:
            i = boards["estimator"].visible(t, d_est_trk)
            if i:
                return boards["estimator"].values[i - 1].prior
        return None

    def publish(b: str, k: int, t_start: float, value: Any, wall: float, first: bool) -> float:
        """Draw the call's latency, occupy the block until it publishes, post the output
        (captured at frame ``k``); an initialisation posts nothing but the initial estimate."""
        wall_ms[b][k] = 1e3 * wall
        spec = timing.blocks[b]
        latency = float(spec.latency.draw(rng, wall))
        if spec.jitter_s > 0:
            latency += float(rng.normal(0.0, spec.jitter_s))
        t_pub = t_start + max(0.0, latency)
        busy_until[b] = t_pub
        if t_pub <= t_end + EPS:
            trace.append(TraceEvent(b, "publish", _first_frame_at(t_pub, fps), t_pub))
        if not first:
            boards[b].post(value, k / fps, k, t_pub)
        elif b == "estimator":  # the initial estimate (the ground-truth box) is held from t = 0
            boards[b].post(value, t_start, k, t_start)
        return t_pub

    alarm = CallAlarm(call_timeout_s)
    for k in range(n):
        yield k
        tk = k / fps
        if is_delivered[k]:
            trace.append(TraceEvent("camera", "publish", k, tk))
        else:
            trace.append(TraceEvent("camera", "skip", k, tk))
        image: np.ndarray | None = None
        bad = False  # frame k could not be read and is skipped

        def frame_image() -> np.ndarray | None:
            nonlocal image, bad
            if image is None and not bad:
                try:
                    # one read; blocks share what they derive from it (FrameImage)
                    image = FrameImage(read_frame(k))
                except FrameReadError as exc:
                    if not skip_bad_frames or k == 0:
                        raise
                    bad = True
                    bad_frames.append((k, str(exc)))
                    scored[k] = False
            return image

        est_tick = None  # the estimator's call of this frame, finished after the tracker
        for b in ORDER:
            if b == "estimator+":  # second half of this frame's estimator tick (see module doc)
                dets = [] if est_tick is None else _take(boards["tracker"], consumed, "tracker", tk, d_trk_est)
                if dets:
                    t0 = clock()
                    value = _call(alarm, "estimator", k, tk, estimator.step, tk, (), dets)
                    wall_ms["estimator"][k] += 1e3 * (clock() - t0)
                    _check_output("estimator", value, k, tk, estimator)
                    value = bounded(value)
                    boards["estimator"].post(value, tk, k, est_tick)
                continue
            if b not in turns or not turns[b][k]:
                continue
            if busy_until[b] > tk + EPS:
                trace.append(TraceEvent(b, "skip", k, tk))
                continue
            if b in ("egomotion", "tracker") and frame_image() is None:  # a bad frame, skipped
                trace.append(TraceEvent(b, "skip", k, tk))
                continue
            trace.append(TraceEvent(b, "start", k, tk))
            first = calls[b] == 0
            calls[b] += 1
            obj = objs[b]
            if b == "egomotion":
                img = frame_image()
                t0 = clock()
                value = _call(alarm, b, k, tk, obj.initialize if first else obj.estimate, img)
                wall = clock() - t0
                if not first:
                    _check_output(b, value, k, tk, obj)
                    motion_calls[k] = motion_call_row(value)
            elif b == "tracker":
                img = frame_image()
                if first:
                    t0 = clock()
                    value = _call(alarm, b, k, tk, obj.initialize, img, init_box)
                    wall = clock() - t0
                else:
                    prior = prior_at(tk)
                    t0 = clock()
                    value = _call(alarm, b, k, tk, obj.track, img, prior)
                    wall = clock() - t0
                    _check_output("tracker", value, k, tk, obj)
                    tracker_calls[k] = tracker_call_row(value, prior)
            else:  # estimator, first half: the camera motion and the detections visible now
                if first:
                    t0 = clock()
                    value = _call(alarm, b, k, tk, obj.initialize, init_box, tk)
                    wall = clock() - t0
                else:
                    motions = _take(boards["egomotion"], consumed, "egomotion", tk, d_ego_est)
                    dets = _take(boards["tracker"], consumed, "tracker", tk, d_trk_est)
                    t0 = clock()
                    value = _call(alarm, b, k, tk, obj.step, tk, motions, dets)
                    wall = clock() - t0
                _check_output("estimator", value, k, tk, obj)
                value = bounded(value)
            t_pub = publish(b, k, tk, value, wall, first)
            if b == "estimator" and not first:
                est_tick = t_pub

        if record and math.isfinite(wall_ms["estimator"][k]):   # MATA_EVAL_RECORD: the filter's state
            for key, v in _diagnostics(alarm, estimator, k, tk).items():
                est_state.setdefault(key, np.full(n, np.nan))[k] = v

        # A tracker with a free start, free before the next frame, starts at once on this one
        # (the newest) instead of waiting for the next; at the next frame it is busy (skip).
        ts = busy_until["tracker"]
        if (free_tracker and calls["tracker"] and tk + EPS < ts < (k + 1) / fps - EPS and k + 1 < n
                and frame_image() is not None):
            trace.append(TraceEvent("tracker", "start", k, ts))
            calls["tracker"] += 1
            t0 = clock()
            value = _call(alarm, "tracker", k, ts, tracker.track, frame_image(), prior_at(ts))
            wall = clock() - t0
            _check_output("tracker", value, k, ts, tracker)
            publish("tracker", k, ts, value, wall, False)

        # Zero-order hold: the newest output of the output block visible at t_k.
        ob = boards[out_block]
        i = ob.visible(tk, d_out)
        if i == 0:  # nothing reached the output yet: the initial box
            boxes[k] = init_row
            source[k] = 0
        else:
            bx = ob.values[i - 1].box
            boxes[k] = (bx.x, bx.y, bx.w, bx.h)
            source[k] = ob.k_capture[i - 1]
        j = boards["tracker"].visible(tk, d_trk_out)
        if j > 1:
            confidence[k] = float(boards["tracker"].values[j - 1].confidence)

    duration = n / fps
    rates = {b: calls[b] / duration for b in active}
    # Stable sort: events at the same instant keep the order in which they happened (a publish
    # due at t_k before the starts of frame k; a zero-latency publish right after its start).
    trace.sort(key=lambda e: (e.frame, round(e.t / EPS)))  # times equal within EPS tie
    return SequenceRun(fps, boxes, scored, confidence, source, wall_ms, tuple(trace), rates, tuple(bad_frames),
                       tracker_calls, motion_calls if egomotion is not None else None, est_state or None)


def _first_frame_at(t: float, fps: float) -> int:
    """The first frame at which something published at ``t`` is visible (same tolerance)."""
    return int(math.ceil((t - EPS) * fps))


def _take(board: _Board, consumed: dict, name: str, t: float, delay: float) -> list[Stamped]:
    """Outputs of ``board`` that reached the estimator since its previous tick, oldest first."""
    i0, i1 = consumed[name], board.visible(t, delay)
    consumed[name] = max(i0, i1)
    return [Stamped(board.values[i], board.t_capture[i], board.t_publish[i] + delay) for i in range(i0, i1)]


#: an ``est_<key>`` column name of frames.csv
_DIAGNOSTICS_KEY = re.compile(r"[A-Za-z0-9_]+")


def _diagnostics(alarm: "CallAlarm", estimator: Any, k: int, t: float) -> dict[str, float]:
    """The estimator's ``diagnostics()``, checked: a dict of str (letters, digits, _: a frames.csv
    column name) -> number (a bool is 0 / 1); anything else is a :class:`BlockError` naming the
    estimator and the key."""
    def fail(message: str) -> BlockError:
        return BlockError("estimator", k, t, message, plugin_name(estimator))

    try:
        out = alarm.call(estimator.diagnostics)
    except CallTimeout as exc:
        raise fail(f"diagnostics(): {exc}") from None
    except Exception as exc:
        raise fail(f"diagnostics(): {type(exc).__name__}: {exc}") from exc
    if not isinstance(out, Mapping):
        raise fail(f"diagnostics() returned {type(out).__name__}; expected a dict of str -> number")
    for key, v in out.items():
        if not (isinstance(key, str) and _DIAGNOSTICS_KEY.fullmatch(key)):
            raise fail(f"diagnostics() key {key!r}: expected letters, digits and _ (a frames.csv column name)")
        if not isinstance(v, (numbers.Real, np.bool_)):   # (a bool, numpy's too, is 0 / 1)
            raise fail(f"diagnostics() key {key!r}: {v!r} is not a number")
    return {key: float(v) for key, v in out.items()}


class CallTimeout(BaseException):
    """A block call ran past ``timeout_s`` (a BaseException: a block's own ``except Exception``
    does not swallow it)."""


class CallAlarm:
    """Time limit of one block call: a ``SIGALRM`` timer armed around each call. It interrupts
    Python code and sleeps (not native code that never returns to the interpreter); only in the
    main thread, where every worker runs its sequences, and a no-op elsewhere or for None."""

    def __init__(self, seconds: float | None):
        usable = hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
        self.seconds = seconds if usable else None

    def _expire(self, signum: int, frame: Any) -> None:
        raise CallTimeout(f"did not return within {self.seconds:g} s (timeout_s)")

    def call(self, fn: Callable, *args: Any) -> Any:
        if self.seconds is None:
            return fn(*args)
        previous = signal.signal(signal.SIGALRM, self._expire)
        signal.setitimer(signal.ITIMER_REAL, self.seconds)
        try:
            return fn(*args)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)


def _call(alarm: CallAlarm, block: str, k: int, t: float, fn: Callable, *args: Any) -> Any:
    """Call a block; whatever it raises, SystemExit and KeyboardInterrupt included, or a time
    out, fails the sequence as a :class:`BlockError` (a stop of the run passes through)."""
    try:
        return alarm.call(fn, *args)
    except CallTimeout as exc:
        raise BlockError(block, k, t, str(exc), plugin_name(getattr(fn, "__self__", None))) from None
    except (Exception, SystemExit, KeyboardInterrupt) as exc:
        raise BlockError(block, k, t, f"{type(exc).__name__}: {exc}", plugin_name(getattr(fn, "__self__", None))) from exc


#: the type each block's call returns
OUTPUT_TYPES = {"egomotion": Motion, "tracker": TrackerOutput, "estimator": Estimate}


def output_problem(block: str, value: Any) -> str | None:
    """What is wrong with a block's output, or None: the type the block promises; for the
    ego-motion a :func:`motion_problem`; for the tracker and the estimator a :class:`Box` of four
    finite numbers, of size >= 0 (0: "nothing here"); for the tracker a confidence that is a
    number in [0, 1], for the estimator an :func:`estimate_problem`. The scheduler, the live
    runtime and ``mata-eval profile`` check every call with it."""
    want = OUTPUT_TYPES[block]
    if not isinstance(value, want):
        return f"expected {'an' if want.__name__[0] in 'AEIOU' else 'a'} {want.__name__}, got {type(value).__name__}"
    if block == "egomotion":
        return motion_problem(value)
    if not isinstance(value.box, Box):
        return f"returned a box of type {type(value.box).__name__}; expected a mata_eval.types.Box"
    if not _finite(value.box):
        return f"returned a box that is not four finite numbers: {value.box}"
    if value.box.w < 0 or value.box.h < 0:   # an empty box (0) is a tracker's "nothing here"
        return f"returned a box of negative size: {value.box}; expected w, h >= 0"
    if block == "tracker":
        c = value.confidence
        if not (_is_number(c) and 0.0 <= float(c) <= 1.0):
            return f"returned confidence {c!r}; expected a number in [0, 1]"
        return None
    return estimate_problem(value)


def motion_problem(m: Motion) -> str | None:
    """What is wrong with a :class:`Motion`, or None: H a 3x3 array of numbers, ``cov`` None or
    9x9, ``inliers`` a number, ``sigma`` None or a number; a valid motion's H and cov finite, h33
    not 0. "No motion this time" is ``valid=False`` (``Motion.invalid()``), whatever its H holds."""
    H = _array(m.H)
    if H is None or H.shape != (3, 3):
        return f"returned H of {_shape(m.H, H)}; expected a 3x3 array (Motion.invalid() when there is no motion)"
    C = None if m.cov is None else _array(m.cov)
    if m.cov is not None and (C is None or C.shape != (9, 9)):
        return f"returned a covariance of {_shape(m.cov, C)}; expected 9x9 (row-major vec(H)) or None"
    if not _is_number(m.inliers) or not (m.sigma is None or _is_number(m.sigma)):
        return f"returned inliers {m.inliers!r}, sigma {m.sigma!r}; expected inliers a number, sigma a number or None"
    if m.valid and (not np.isfinite(H).all() or abs(H[2, 2]) < 1e-12 or (C is not None and not np.isfinite(C).all())):
        return (f"returned a valid motion whose H (or covariance) is not finite or has h33 = 0: H = {H.tolist()}; "
                f"return Motion.invalid() (valid=False) when there is no motion")
    return None


def estimate_problem(e: Estimate) -> str | None:
    """What is wrong with an :class:`Estimate` beyond its box, or None: ``search`` None or two
    finite numbers, ``cov`` None or a square matrix of numbers (not NaN)."""
    if e.search is not None and not (isinstance(e.search, (tuple, list)) and len(e.search) == 2
                                     and all(_is_number(v) and math.isfinite(v) for v in e.search)):
        return f"returned search centre {e.search!r}; expected two finite numbers (cx, cy) or None"
    if e.cov is not None:
        C = _array(e.cov)
        if C is None or C.ndim != 2 or C.shape[0] != C.shape[1]:
            return f"returned a covariance of {_shape(e.cov, C)}; expected a square matrix or None"
        if np.isnan(C).any():
            return "returned a covariance holding NaN; expected numbers (inf: unknown) or None"
    return None


def _array(value: Any) -> np.ndarray | None:
    """``value`` as an array of floats, or None when it is not numbers."""
    if type(value) is np.ndarray and value.dtype == np.float64:   # what blocks return: no conversion
        return value
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None


def _shape(value: Any, arr: np.ndarray | None) -> str:
    """``shape (2, 3)``, or what ``value`` is when it is not numbers."""
    return f"type {type(value).__name__}, not numbers" if arr is None else f"shape {arr.shape}"


def _check_output(block: str, value: Any, k: int, t: float, obj: Any = None) -> None:
    if (problem := output_problem(block, value)) is not None:
        raise BlockError(block, k, t, problem, plugin_name(obj))


def _is_number(v: Any) -> bool:
    """A real number (numpy's included), not a string or a bool; a float first (every estimate
    of a run passes here: the ABC check costs a few hundred ns)."""
    return type(v) is float or (isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)))


def _finite(box: Box) -> bool:
    return all(_is_number(v) and math.isfinite(v) for v in (box.x, box.y, box.w, box.h))
