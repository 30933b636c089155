"""How often each block ran (paper Table 4 "Freq."): scheduled rate on the camera clock and
wall-clock rate, per sequence and summed over a dataset. Both leave out a block's first start,
the tracker's initialisation (a template, a model loaded on first use): the rate is the number
of intervals between starts over their span, so a block run every third frame of a 30 fps
camera is at 10 Hz whatever the sequence's length (counting the initialisation gave 10.5 Hz on
40 frames), and the wall-clock rate is that of the calls that follow it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np

from .measures import json_float


@dataclass(frozen=True)
class BlockFrequency:
    """How often a block ran: ``starts`` counted after its first, over ``camera_seconds`` from
    its first to its last start, and ``total_ms`` the wall time of those calls.
    ``scheduled_hz``: starts per second of camera time (what the protocol made it do, paper
    "Freq."); ``wall_hz``: 1 / mean wall-clock time of a call (how fast it could go on this
    machine); NaN where unknown (fewer than two starts)."""

    starts: int
    camera_seconds: float
    total_ms: float

    @property
    def scheduled_hz(self) -> float:
        return self.starts / self.camera_seconds if self.camera_seconds > 0 else float("nan")

    @property
    def wall_hz(self) -> float:
        return 1000.0 * self.starts / self.total_ms if self.total_ms > 0 else float("nan")

    def __add__(self, other: "BlockFrequency") -> "BlockFrequency":
        return BlockFrequency(self.starts + other.starts, self.camera_seconds + other.camera_seconds,
                              self.total_ms + other.total_ms)

    def to_dict(self) -> dict:
        return {"starts": self.starts, "camera_seconds": self.camera_seconds, "total_ms": self.total_ms,
                "scheduled_hz": json_float(self.scheduled_hz), "wall_hz": json_float(self.wall_hz)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "BlockFrequency":
        return cls(int(d["starts"]), float(d["camera_seconds"]), float(d["total_ms"]))


def block_frequencies(wall_ms: Mapping[str, np.ndarray], n_frames: int, fps: float) -> dict[str, BlockFrequency]:
    """Frequencies of each block of one sequence from its per-frame wall times in ms (NaN where
    the block did not start at that frame; architecture.md ``<seq>.frames.csv``), its first
    start left out (module docstring); ``n_frames`` is the sequence's length (the wall times
    may be shorter: a foreign results file)."""
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    out = {}
    for block, ms in wall_ms.items():
        ms = np.asarray(ms, dtype=float)[:n_frames]
        frames = np.flatnonzero(np.isfinite(ms))
        if len(frames) < 2:
            out[block] = BlockFrequency(0, 0.0, 0.0)
            continue
        out[block] = BlockFrequency(len(frames) - 1, (frames[-1] - frames[0]) / fps, float(ms[frames[1:]].sum()))
    return out


def combine_frequencies(per_sequence: Iterable[Mapping[str, BlockFrequency]]) -> dict[str, BlockFrequency]:
    """Dataset-level frequencies: starts and times summed over sequences (time-weighted)."""
    out: dict[str, BlockFrequency] = {}
    for seq in per_sequence:
        for block, f in seq.items():
            out[block] = out[block] + f if block in out else f
    return out
