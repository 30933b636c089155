"""Live: the blocks really run, in parallel, on the wall clock (:mod:`mata_eval.run.live`): the
camera publishes frames at the dataset's fps, each block in its own thread takes the newest frame
when it is free, and frame k scores the newest output published before its real time. What the
paper measures on the Jetson with ROS 2 (section 4, Table 4), on the machine that runs it.

``time_scale`` emulates a slower device: a call whose work took d seconds publishes ``time_scale
x d`` after it starts (the worker sleeps the rest; the same factor as ``vot_rt``). One value for
every block or a value per block (``{tracker: 20}``: the others at this machine's speed).
Run live experiments with ``-j 1``: sequences run side by side would share the cores."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.run.live import run_live
from mata_eval.run.scheduler import BLOCKS, SequenceRun


def _scales(value: float | dict) -> dict[str, float]:
    raw = value if isinstance(value, dict) else {b: value for b in BLOCKS}
    out = {}
    for key, v in raw.items():
        if key not in BLOCKS:
            raise ValueError(f"live: time_scale: unknown block {key!r}; blocks: {', '.join(BLOCKS)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (v >= 1 and math.isfinite(v)):
            raise ValueError(f"live: time_scale{'.' + key if isinstance(value, dict) else ''}: expected a "
                             f"factor >= 1 (1 = this machine's speed), got {v!r}")
        out[key] = float(v)
    return {b: out.get(b, 1.0) for b in BLOCKS}


class Live:
    """Live: the blocks in parallel threads on the real clock, each taking the newest frame."""

    name = "live"
    paper_role = "Embedded"  # reports: a real run of the blocks is paper Table 4's embedded reference

    @classmethod
    def table_label(cls, params: Mapping[str, Any]) -> tuple[str, tuple]:
        """Reports: display label and sort key (after VOT real-time)."""
        scales = _scales(params.get("time_scale", 1.0))
        slow = {b: s for b, s in scales.items() if s != 1.0}
        if not slow:
            return "Live", (5, 1.0)
        if len(set(slow.values())) == 1 and len(slow) == len(BLOCKS):
            return f"Live (x{scales['tracker']:g})", (5, scales["tracker"])
        return "Live (" + ", ".join(f"{b} x{s:g}" for b, s in slow.items()) + ")", (5, max(slow.values()))

    @dataclass(frozen=True)
    class Params:
        time_scale: float | dict = param(
            1.0, "emulated slow-down: a call publishes time_scale x its work time after it starts; "
                 "one factor >= 1, or per block, e.g. {tracker: 20}")
        warmup: int = param(2, "untimed calls of each block before the clock starts (model loading, caches)")
        prefetch: int = param(128, "frames decoded ahead of the camera (all of them before the clock "
                                   "starts when the sequence is that short)")

        def __post_init__(self) -> None:
            _scales(self.time_scale)
            if self.warmup < 0:
                raise ValueError(f"live: warmup: expected a number of calls >= 0, got {self.warmup!r}")
            if self.prefetch < 1:
                raise ValueError(f"live: prefetch: expected a number of frames >= 1, got {self.prefetch!r}")

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()
        self.time_scale = _scales(self.params.time_scale)

    def run_sequence(self, sequence: Any, tracker: Any, egomotion: Any, estimator: Any,
                     rng: np.random.Generator, feedback: bool = True) -> SequenceRun:
        """The runner's entry point for a protocol that runs the blocks itself (no scheduler)."""
        return run_live(sequence, tracker, egomotion, estimator, feedback=feedback, time_scale=self.time_scale,
                        warmup=self.params.warmup, prefetch=self.params.prefetch)


@hookimpl
def mata_eval_protocols():
    return [Live]
