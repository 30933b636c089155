"""``mata-eval profile``: time each block of an experiment run (tracker with its backend,
ego-motion, estimator) on the machine it runs on, and write a timing profile
(:mod:`mata_eval.run.timing_profile`) that the ``eop`` protocol reads instead of fixed rates and
latencies (``tracker_hz: profile``, ``tracker_latency: profile``, ``latency_profile: FILE``).

Method: the blocks are built from the experiment file exactly as a run builds them, and fed real
frames of the run's dataset (decoded beforehand, so disk and JPEG decoding are not timed). Each
block is initialised on frame 0, run ``warmup`` untimed calls (first-call costs: lazy model
loading, allocator, JIT and engine caches), then ``frames`` timed calls. Frames are visited back
and forth (0, 1, ..., m, m-1, ...) so that consecutive frames stay neighbours (the tracker keeps
its target, the ego-motion sees real inter-frame motion) however many calls are asked for. The
estimator is fed, at each call, the ego-motion and tracker outputs of the same frame, stamped at
that frame's time, as in a run at the camera rate. Every block runs on its own, back to back,
in this process: the latency of a block alone on the machine (contention between blocks that
share cores on board is not modelled; see docs/decisions/deploy.md).
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..run.scheduler import BlockError, output_problem, plugin_name
from ..run.timing_profile import TimingProfile, profile_from_samples
from ..core.types import Stamped

DEFAULT_FRAMES = 200
DEFAULT_WARMUP = 20


# --- machine description ------------------------------------------------------------------------

def _read(path: str) -> str | None:
    try:
        return Path(path).read_text(errors="replace").strip()
    except OSError:
        return None


def _command(args: list[str], timeout: float = 5.0) -> str | None:
    if shutil.which(args[0]) is None:
        return None
    try:
        r = subprocess.run(args, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout.strip() or None if r.returncode == 0 else None


def cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (x86 ``model name``; ARM ``Hardware``/``Model`` or the
    device-tree model, as on a Jetson), else :func:`platform.processor`."""
    info = _read("/proc/cpuinfo") or ""
    for key in ("model name", "Hardware", "Model", "cpu model"):
        for line in info.splitlines():
            if line.split(":")[0].strip() == key and ":" in line:
                return line.split(":", 1)[1].strip()
    dt = _read("/proc/device-tree/model")
    if dt:
        return dt.replace("\x00", "")
    return platform.processor() or platform.machine()


def gpu_description() -> list[str] | None:
    """GPU names: ``nvidia-smi`` when present, else torch.cuda when torch is already loaded (a
    Jetson's integrated GPU has no nvidia-smi in older JetPacks)."""
    out = _command(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"])
    if out:
        return [line.strip() for line in out.splitlines() if line.strip()]
    torch = sys.modules.get("torch")
    if torch is not None:
        try:
            if torch.cuda.is_available():
                return [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
        except Exception:  # a broken CUDA install must not stop the profile
            return None
    return None


def jetson_description() -> dict[str, str] | None:
    """L4T release (/etc/nv_tegra_release) and power mode (``nvpmodel -q``) where readable."""
    release = _read("/etc/nv_tegra_release")
    if release is None:
        return None
    out: dict[str, str] = {"l4t_release": release.splitlines()[0]}
    mode = _command(["nvpmodel", "-q"])
    if mode:
        out["power_mode"] = " ".join(line.strip() for line in mode.splitlines() if line.strip())
    model = _read("/proc/device-tree/model")
    if model:
        out["model"] = model.replace("\x00", "")
    return out


def thread_settings() -> dict[str, Any]:
    """CPU cores visible to this process and the thread settings that change latencies."""
    out: dict[str, Any] = {"cpu_count": os.cpu_count()}
    try:
        out["cpus_allowed"] = len(os.sched_getaffinity(0))
    except AttributeError:
        pass
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        if os.environ.get(var):
            out[var] = os.environ[var]
    try:
        import cv2

        out["opencv_threads"] = cv2.getNumThreads()
    except ImportError:
        pass
    torch = sys.modules.get("torch")
    if torch is not None:
        out["torch_threads"] = torch.get_num_threads()
    return out


def describe_machine() -> dict[str, Any]:
    """Free-form description of this machine stored in the profile's ``machine`` block."""
    from ..run.results import package_versions

    desc: dict[str, Any] = {"cpu": cpu_model(), "platform": platform.platform(), "machine": platform.machine(),
                            "threads": thread_settings(), "versions": package_versions()}
    gpu = gpu_description()
    if gpu:
        desc["gpu"] = gpu
    jetson = jetson_description()
    if jetson:
        desc["jetson"] = jetson
        if "power_mode" in jetson:
            desc["power_mode"] = jetson["power_mode"]
    try:
        from importlib import metadata

        desc["versions"]["tensorrt"] = metadata.version("tensorrt")
    except Exception:
        pass
    return desc


# --- timing -------------------------------------------------------------------------------------

def back_and_forth(n_available: int, count: int) -> list[int]:
    """``count`` frame indices 1, 2, ..., m, m-1, ..., 1, 2, ... over frames 1..n-1 (frame 0
    initialises): neighbours stay neighbours however long the run."""
    if n_available < 2:
        raise ValueError("profiling needs a sequence of at least 2 frames")
    path = list(range(1, n_available)) + list(range(n_available - 2, 1, -1))
    return [path[i % len(path)] for i in range(count)]


def time_blocks(sequence: Any, tracker: Any, egomotion: Any = None, estimator: Any = None, *,
                frames: int = DEFAULT_FRAMES, warmup: int = DEFAULT_WARMUP,
                clock: Callable[[], float] = time.perf_counter,
                pace: Mapping[str, float] | None = None) -> dict[str, np.ndarray]:
    """Latency samples (seconds) of each given block: ``warmup`` untimed calls, then ``frames``
    timed calls, on the decoded frames of ``sequence``. ``pace`` (block -> factor s, missing = 1):
    run every block at the duty cycle the ``live`` protocol gives it instead of back to back: a
    call of d seconds is followed by a pause of (s - 1) d (its time_scale stretch), and calls start
    at most once per camera frame (a block waits for a new frame). On a shared machine the kernel
    serves a block that pauses sooner than one that runs back to back, whose latency would be
    overestimated (by 1.5x for the trackers and 2x for grid_lk on the project's 2-core server)."""
    if frames < 1 or warmup < 0:
        raise ValueError(f"profile: frames must be >= 1 and warmup >= 0, got frames={frames}, warmup={warmup}")
    total = warmup + frames
    n_avail = min(len(sequence), total + 1)
    images = [sequence.image(k) for k in range(n_avail)]
    order = back_and_forth(n_avail, total)
    fps = float(sequence.fps)
    samples: dict[str, list[float]] = {}

    def timed(name: str, i: int, k: int, fn: Callable, *args: Any) -> Any:
        """Call ``i`` of block ``name``, on frame ``k``: timed, and checked as a run checks it."""
        t0 = clock()
        try:
            value = fn(*args)
        except Exception as exc:   # which block, which call: not a traceback from inside it
            raise BlockError(name, k, k / fps, f"call {i + 1} of {total}: {type(exc).__name__}: {exc}",
                             plugin_name(getattr(fn, "__self__", None))) from exc
        dt = clock() - t0
        if (problem := output_problem(name, value)) is not None:   # what a run would refuse
            raise BlockError(name, k, k / fps, f"call {i + 1} of {total}: {problem}",
                             plugin_name(getattr(fn, "__self__", None)))
        if i >= warmup:
            samples.setdefault(name, []).append(dt)
        if pace is not None:
            time.sleep(max((pace.get(name, 1.0) - 1.0) * dt, 1.0 / fps - dt, 0.0))
        return value

    outputs, motions = [], []
    tracker.initialize(images[0], sequence.init_box)
    for i, k in enumerate(order):
        outputs.append(timed("tracker", i, k, tracker.track, images[k], None))
    if egomotion is not None:
        egomotion.initialize(images[0])
        for i, k in enumerate(order):
            motions.append(timed("egomotion", i, k, egomotion.estimate, images[k]))
    if estimator is not None:
        estimator.initialize(sequence.init_box, 0.0)
        for i in range(total):
            t = (i + 1) / fps
            ms = (Stamped(motions[i], t, t),) if motions else ()
            timed("estimator", i, i + 1, estimator.step, t, ms, (Stamped(outputs[i], t, t),))
    return {name: np.asarray(v) for name, v in samples.items()}


def profile_run(spec: Any, *, frames: int = DEFAULT_FRAMES, warmup: int = DEFAULT_WARMUP,
                sequence: str | None = None, clock: Callable[[], float] = time.perf_counter,
                experiment: str | None = None, time_scale: dict[str, float] | None = None) -> TimingProfile:
    """Time the blocks of one run (a :class:`mata_eval.run.config.RunSpec`) on one sequence of its
    dataset (the first, or the one named) and build the timing profile. ``time_scale``: block ->
    factor on its measured latencies, the profile of a device that many times slower, as the
    ``live`` protocol emulates it (calls paced the same way, see :func:`time_blocks`); recorded in
    ``machine``."""
    from ..run.runner import load_sequences

    seqs = load_sequences(spec)
    if not seqs:
        raise ValueError(f"run {spec.name!r}: the dataset has no sequences")
    if sequence is None:
        seq = seqs[0]
    else:
        named = [s for s in seqs if s.name == sequence]
        if not named:
            few = ", ".join(s.name for s in seqs[:10]) + (" ..." if len(seqs) > 10 else "")
            raise ValueError(f"run {spec.name!r}: no sequence {sequence!r} in the dataset (it has: {few})")
        seq = named[0]
    create = lambda block: None if block is None else block.create()  # noqa: E731
    with spec.tracker.instance() as tracker:
        samples = time_blocks(seq, tracker, create(spec.egomotion), create(spec.estimator),
                              frames=frames, warmup=warmup, clock=clock, pace=time_scale or None)
    for block, factor in (time_scale or {}).items():
        if block in samples:
            samples[block] = samples[block] * factor
    machine = describe_machine()
    if time_scale:
        machine["time_scale"] = dict(time_scale)
    machine["run"] = {"experiment": experiment, "run": spec.name, "sequence": seq.name, "frames": frames,
                      "warmup": warmup, **{k: spec.resolved.get(k) for k in ("tracker", "egomotion", "estimator")}}
    created = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return profile_from_samples(samples, machine, created=created)


def summary_table(profile: TimingProfile) -> str:
    rows = [f"{'block':<10} {'mean ms':>8} {'p50':>8} {'p90':>8} {'p99':>8} {'rate Hz':>8} {'n':>5}"]
    for name, b in profile.blocks.items():
        p = b.percentiles_s((50, 90, 99))
        n = len(b.samples_s) if b.samples_s is not None else int(np.sum(b.hist_counts))
        rows.append(f"{name:<10} {1e3 * b.mean_s:8.2f} {1e3 * p['50']:8.2f} {1e3 * p['90']:8.2f} "
                    f"{1e3 * p['99']:8.2f} {b.rate_hz:8.1f} {n:5d}")
    return "\n".join(rows)
