"""Block A out of process: any tracker that speaks TraX (the VOT toolkit's tracker protocol,
Čehovin 2017, https://github.com/votchallenge/trax), started as its own process with its own
command, environment and working directory, so it can pin its own torch/CUDA or be written in
another language.

One process per sequence, like the VOT toolkit: :meth:`TraxTracker.initialize` starts it and
sends ``initialize``, :meth:`TraxTracker.track` sends ``frame``, :meth:`TraxTracker.close` sends
``quit``. Over the protocol:

- images: the ``path`` of a lossless BMP written to a temporary folder (in ``/dev/shm`` when
  it exists) when the tracker accepts paths, else a raw ``memory`` RGB image (``channels`` must
  include ``color``). Paths first because they are cheaper: on a 1280x720 frame libtrax's text
  encoding of a memory image costs about 90 ms per frame, a BMP written and read back about 12;
- the initial box as a ``rectangle`` (or its 4-corner ``polygon``); the reply's rectangle,
  polygon or mask becomes its axis-aligned box. libtrax writes regions with 4 decimals, so
  boxes cross the pipe rounded to 1e-4 px; a ``special`` region (VOT: no target) is a 0x0 box
  with confidence 0;
- MATA's search centre (the ``prior`` of :class:`mata_eval.interfaces.Tracker`) as the frame
  properties ``prior_x``, ``prior_y`` (``repr`` of the floats, exact); absent when the run has
  no estimator or no feedback. A tracker that does not know them ignores them (TraX properties
  are free-form);
- the confidence from the reply's ``confidence`` object property (what VOT long-term trackers
  report), clipped to [0, 1]; a tracker that reports none gets ``default_confidence`` (1.0: the
  EKF's confidence gate, paper eq. ewma_score, then never rejects its boxes, as for a tracker
  whose score carries no information). Other numeric properties go to ``TrackerOutput.extra``.

A tracker that fails to start, crashes, answers with an error or does not answer within
``timeout_s`` raises :class:`TrackerProcessError` with the reason (exit code or signal, the last
lines of its stderr); the runner then records the sequence as failed. Whatever happens, the
whole process group is killed and reaped (on error, on :meth:`close`, or when the object is
garbage-collected).
"""

from __future__ import annotations

import collections
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import weakref
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .crop import usable_prior

STDERR_LINES = 20  # lines of the tracker's stderr quoted in a failure reason
QUIT_GRACE_S = 2.0  # how long a tracker may take to exit after `quit` before it is killed
SCRATCH_DIR = "/dev/shm"  # frames handed over as files go to memory-backed storage when it exists


class TrackerProcessError(RuntimeError):
    """The tracker process could not start, crashed, timed out or broke the protocol."""


@dataclass
class _Process:
    """A running tracker: the process, its TraX client, where its stderr goes. Holds no
    reference to the :class:`TraxTracker`, so a finalizer can reap it."""

    popen: subprocess.Popen
    stderr_path: Path
    scratch: tempfile.TemporaryDirectory
    client: object = None
    timed_out: bool = False
    reaped: bool = False

    def kill(self) -> None:
        """SIGKILL the whole process group (the tracker and anything it started)."""
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def stderr_tail(self) -> str:
        try:
            with open(self.stderr_path, errors="replace") as f:
                lines = collections.deque(f, maxlen=STDERR_LINES)
        except OSError:
            return ""
        text = "".join(lines).rstrip()
        return f"; last lines of its stderr:\n{text}" if text else "; it wrote nothing to stderr"


def _reap(proc: _Process) -> None:
    """Ask the tracker to quit, then kill its process group and wait for it (idempotent)."""
    if proc.reaped:
        return
    proc.reaped = True
    if proc.client is not None and proc.popen.poll() is None:
        try:
            proc.client.quit()
            proc.popen.wait(QUIT_GRACE_S)
        except Exception:  # a dead or stuck tracker: the kill below handles it
            pass
    if proc.client is not None:
        # vot-trax 4.0.2 may free its log callback before the connection handle, and libtrax
        # logs while closing the handle (a use after free, seen with valgrind): close it now,
        # while the client and its callback are alive
        proc.client._handle = None
    proc.kill()  # also takes down children the tracker left behind
    proc.popen.wait()
    for stream in (proc.popen.stdin, proc.popen.stdout):
        if stream is not None:
            stream.close()
    proc.client = None
    proc.scratch.cleanup()


def region_box(region) -> Box | None:
    """Axis-aligned box of a TraX region; None for a ``special`` region (no target)."""
    from trax.region import Mask, Polygon, Rectangle

    if isinstance(region, Rectangle):
        return Box(*(float(v) for v in region.bounds()))
    if isinstance(region, Polygon):
        pts = np.array([region.get(i) for i in range(region.size())], dtype=float)
        return Box.from_corners(*pts.min(axis=0), *pts.max(axis=0))
    if isinstance(region, Mask):
        ys, xs = np.nonzero(region.array())
        if xs.size == 0:
            return None
        ox, oy = region.offset()
        return Box(float(ox + xs.min()), float(oy + ys.min()),
                   float(xs.max() - xs.min() + 1), float(ys.max() - ys.min() + 1))
    return None


class TraxTracker:
    """Any tracker speaking TraX (VOT toolkit protocol), in its own process and environment."""

    name = "trax"

    @dataclass(frozen=True)
    class Params:
        command: list[str] = field(metadata={"doc": "the tracker's command line, e.g. [python, run_tracker.py]"})
        env: dict = param({}, "environment variables added to mata-eval's for the tracker (e.g. PATH, CUDA_VISIBLE_DEVICES)")
        cwd: str | None = param(None, "working directory of the tracker (default: mata-eval's)")
        timeout_s: float = param(30.0, "seconds the tracker may take to start, to initialise or to answer one frame")
        default_confidence: float = param(1.0, "confidence when the tracker reports no `confidence` property")

        def __post_init__(self) -> None:
            """Checks beyond the declared types (run when the experiment file is loaded)."""
            if not self.command:
                raise ValueError("trax: `command` must be the tracker's command line, a non-empty list "
                                 "such as [python, run_tracker.py]")
            bad = [k for k, v in self.env.items() if not isinstance(v, (str, int, float)) or isinstance(v, bool)]
            if bad:
                raise ValueError(f"trax: `env.{bad[0]}` must be a string (or a number), got {self.env[bad[0]]!r}")
            object.__setattr__(self, "env", {str(k): str(v) for k, v in self.env.items()})
            if not self.timeout_s > 0:
                raise ValueError(f"trax: `timeout_s` must be a positive number of seconds, got {self.timeout_s}")
            if not 0.0 <= self.default_confidence <= 1.0:
                raise ValueError(f"trax: `default_confidence` must be in [0, 1], got {self.default_confidence}")

    def __init__(self, params: Params):
        self.params = params
        self._proc: _Process | None = None
        self._reaper: weakref.finalize | None = None
        self._frame = 0

    def check(self) -> None:
        """Preflight: the TraX client library is installed and the tracker's command exists."""
        from .backends import BackendUnavailable

        try:
            import trax  # noqa: F401
        except ImportError:
            raise BackendUnavailable("the trax tracker needs the TraX client (vot-trax): "
                                     "pip install 'mata-eval[trax]'") from None
        exe = self.params.command[0]
        if shutil.which(exe) is None and not (Path(self.params.cwd or ".") / exe).is_file():
            raise BackendUnavailable(f"trax: command not found: {exe!r} (on PATH, or relative to cwd "
                                     f"{self.params.cwd or '.'!r})")

    # --- process lifecycle ------------------------------------------------------------------

    @property
    def pid(self) -> int | None:
        """Process id of the running tracker (None before ``initialize`` and after ``close``)."""
        return None if self._proc is None or self._proc.reaped else self._proc.popen.pid

    def close(self) -> None:
        """Send ``quit``, then kill and reap the tracker's process group. Idempotent."""
        if self._reaper is not None:
            self._reaper()  # runs _reap once; the finalizer is then dead
        self._proc = self._reaper = None

    def _start(self) -> None:
        p = self.params
        scratch = tempfile.TemporaryDirectory(prefix="mata_trax_", dir=SCRATCH_DIR if os.path.isdir(SCRATCH_DIR) else None)
        stderr_path = Path(scratch.name) / "stderr.log"
        env = {**os.environ, **p.env, "TRAX": "1"}
        try:
            with open(stderr_path, "wb") as err:
                popen = subprocess.Popen(
                    p.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, env=env,
                    cwd=p.cwd, start_new_session=True)  # own group: killpg reaches children
        except OSError as exc:
            scratch.cleanup()
            raise TrackerProcessError(f"trax: cannot start {p.command!r}: {exc}") from None
        self._proc = _Process(popen, stderr_path, scratch)
        self._reaper = weakref.finalize(self, _reap, self._proc)
        from trax.client import Client

        # vot-trax 4.0.2 needs a log callback (log=False fails); its log is the protocol traffic
        # itself, what the tracker says goes to stderr, so it is dropped
        self._proc.client = self._call("the handshake", lambda: Client(
            stream=(popen.stdin.fileno(), popen.stdout.fileno()), log=lambda text: None))
        client = self._proc.client
        if "color" not in client.channels:
            self._fail(f"the tracker accepts only the {', '.join(client.channels)} channel(s); mata-eval sends color")
        if not {"memory", "path"} & set(client.image_formats):
            self._fail(f"the tracker accepts only {', '.join(client.image_formats)} images; "
                       "mata-eval sends memory or path")
        if not {"rectangle", "polygon"} & set(client.region_formats):
            self._fail(f"the tracker accepts only {', '.join(client.region_formats)} regions; "
                       "mata-eval sends a rectangle or a polygon")

    def _fail(self, reason: str):
        """Reap the tracker and raise a :class:`TrackerProcessError` that says why."""
        tail = self._proc.stderr_tail() if self._proc is not None else ""
        self.close()
        raise TrackerProcessError(f"trax: {' '.join(self.params.command)}: {reason}{tail}")

    def _call(self, what: str, fn):
        """Run one blocking exchange with the tracker under the ``timeout_s`` watchdog; any
        failure reaps the process and raises with the reason."""
        from trax import TraxException

        proc = self._proc

        def expire() -> None:
            proc.timed_out = True
            proc.kill()  # unblocks the pending read: the pipe closes

        watchdog = threading.Timer(self.params.timeout_s, expire)
        watchdog.start()
        try:
            return fn()
        except TraxException as exc:
            error = str(exc)
        finally:
            watchdog.cancel()
        if proc.timed_out:
            self._fail(f"no answer to {what} within {self.params.timeout_s:g} s (killed)")
        try:
            code = proc.popen.wait(QUIT_GRACE_S)
        except subprocess.TimeoutExpired:
            self._fail(f"{what} failed: {error}")
        cause = f"killed by signal {-code}" if code < 0 else f"exited with code {code}"
        # a C/C++ server on libtrax's single-object calls answers the object list every client of
        # vot-trax 4 sends with "Invalid mode", and ends the session as if it had finished
        hint = ("; a tracker that ends the session at initialize may use libtrax's single-object calls "
                "(trax_server_wait_sot / trax_server_reply_sot): use trax_server_wait_mot / trax_server_reply_mot "
                "(docs/decisions/trackers.md)") if what == "initialize" and code == 0 else ""
        self._fail(f"the tracker {cause} during {what} ({error}){hint}")

    # --- the Tracker interface --------------------------------------------------------------

    def _image(self, image: np.ndarray):
        from trax.image import FileImage, MemoryImage

        if "path" not in self._proc.client.image_formats:
            return {"color": MemoryImage.create(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))}
        path = Path(self._proc.scratch.name) / "frame.bmp"  # the exchange is synchronous: one file
        if not cv2.imwrite(str(path), image):
            raise TrackerProcessError(f"trax: cannot write the frame to {path}")
        return {"color": FileImage.create(str(path))}

    def initialize(self, image: np.ndarray, box: Box) -> None:
        from trax.region import Polygon, Rectangle

        self.close()  # a new initialisation is a new process, as in the VOT toolkit
        self._frame = 0
        self._start()
        if "rectangle" in self._proc.client.region_formats:
            region = Rectangle.create(box.x, box.y, box.w, box.h)
        else:
            x1, y1, x2, y2 = box.corners()
            region = Polygon.create([(x1, y1), (x2, y1), (x2, y2), (x1, y2)])
        images = self._image(image)
        objects, _ = self._call("initialize", lambda: self._proc.client.initialize(images, [(region, {})], {}))
        if len(objects) != 1:  # the answer's content is not used: block A publishes no initial box
            self._fail(f"expected one object in the answer to initialize, got {len(objects)}")

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        if self._proc is None:
            raise RuntimeError("trax: track() called before initialize()")
        self._frame += 1
        prior = usable_prior(prior, 0.0, 0.0, *image.shape[:2])  # finite and inside the image, or none
        props = {} if prior is None else {"prior_x": repr(float(prior[0])), "prior_y": repr(float(prior[1]))}
        images = self._image(image)
        objects, _ = self._call(f"frame {self._frame}", lambda: self._proc.client.frame(images, props, []))
        return self._reply(objects, f"frame {self._frame}")

    def _reply(self, objects: list, what: str) -> TrackerOutput:
        if len(objects) != 1:
            self._fail(f"expected one object in the answer to {what}, got {len(objects)}")
        region, props = objects[0]
        box = region_box(region)
        numeric = {}
        for key, text in props.items():
            try:
                numeric[key] = float(text)
            except ValueError:
                pass
        if "confidence" in props and not np.isfinite(numeric.get("confidence", np.nan)):
            self._fail(f"the `confidence` property of {what} is not a number: {props['confidence']!r}")
        if box is None:  # VOT's special region: the tracker reports no target
            return TrackerOutput(Box(0.0, 0.0, 0.0, 0.0), 0.0, extra=numeric)
        confidence = numeric.pop("confidence", self.params.default_confidence)
        return TrackerOutput(box, float(np.clip(confidence, 0.0, 1.0)), extra=numeric)


@hookimpl
def mata_eval_trackers():
    return [TraxTracker]
