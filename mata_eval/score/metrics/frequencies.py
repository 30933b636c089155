"""How often each block ran (paper Table 4 "Freq."): scheduled rate on the camera clock and
wall-clock rate, per sequence and summed over a dataset. Frame 0 is where every block is
initialised (the tracker's template, a model loaded on first use) and is left out: the rates
are those of the calls from frame 1 on, the scheduled one the intervals between those calls
over their span, so a block run every third frame of a 30 fps camera is at 10 Hz whatever the
sequence's length and however the protocol starts it after frame 0 (counting the frame-0 call
gave 10.5 Hz on 40 frames; vot_rt's first call at frame 1, then every fourth, 8.25 Hz for 7.5),
and the wall-clock one 1 / their mean wall time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np

from .measures import json_float


@dataclass(frozen=True)
class BlockFrequency:
    """How often a block ran from frame 1 on: ``calls`` taking ``total_ms`` of wall time,
    ``starts`` intervals between them spanning ``camera_seconds``. ``scheduled_hz``: intervals
    per second of camera time (what the protocol made it do, paper "Freq."); ``wall_hz``: 1 /
    mean wall-clock time of a call (how fast it could go on this machine); NaN where unknown
    (the scheduled rate with fewer than two calls, the wall rate with none)."""

    starts: int
    camera_seconds: float
    total_ms: float
    calls: int = -1   # -1: as many as ``starts`` (a scores.json of an older mata-eval)

    @property
    def scheduled_hz(self) -> float:
        return self.starts / self.camera_seconds if self.camera_seconds > 0 else float("nan")

    @property
    def wall_hz(self) -> float:
        calls = self.starts if self.calls < 0 else self.calls
        return 1000.0 * calls / self.total_ms if self.total_ms > 0 else float("nan")

    def __add__(self, other: "BlockFrequency") -> "BlockFrequency":
        calls = -1 if min(self.calls, other.calls) < 0 else self.calls + other.calls
        return BlockFrequency(self.starts + other.starts, self.camera_seconds + other.camera_seconds,
                              self.total_ms + other.total_ms, calls)

    def to_dict(self) -> dict:
        return {"starts": self.starts, "camera_seconds": self.camera_seconds, "total_ms": self.total_ms,
                "calls": self.calls, "scheduled_hz": json_float(self.scheduled_hz), "wall_hz": json_float(self.wall_hz)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "BlockFrequency":
        return cls(int(d["starts"]), float(d["camera_seconds"]), float(d["total_ms"]), int(d.get("calls", -1)))


def block_frequencies(wall_ms: Mapping[str, np.ndarray], n_frames: int, fps: float) -> dict[str, BlockFrequency]:
    """Frequencies of each block of one sequence from its per-frame wall times in ms (NaN where
    the block did not start at that frame; architecture.md ``<seq>.frames.csv``), frame 0 left
    out (module docstring); ``n_frames`` is the sequence's length (the wall times may be
    shorter: a foreign results file)."""
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    out = {}
    for block, ms in wall_ms.items():
        ms = np.asarray(ms, dtype=float)[:n_frames]
        calls = np.flatnonzero(np.isfinite(ms[1:])) + 1
        span = (calls[-1] - calls[0]) / fps if len(calls) else 0.0
        out[block] = BlockFrequency(max(len(calls) - 1, 0), span, float(ms[calls].sum()), len(calls))
    return out


def combine_frequencies(per_sequence: Iterable[Mapping[str, BlockFrequency]]) -> dict[str, BlockFrequency]:
    """Dataset-level frequencies: intervals, spans, calls and times summed over sequences
    (time-weighted)."""
    out: dict[str, BlockFrequency] = {}
    for seq in per_sequence:
        for block, f in seq.items():
            out[block] = out[block] + f if block in out else f
    return out
