"""VOT real-time (VOT2021 real-time experiment, cited in paper section 3.1): frames arrive at the
camera rate; the tracker, busy with an earlier frame, misses the new ones, and its latency is its
own measured wall-clock time on this machine (hardware dependent by design); outputs are held.
Ego-motion and estimator run on every frame without latency unless named in ``timed_blocks``
(the scheduler starts blocks on camera frames only, so a block of a few milliseconds that is
timed waits for the next frame to be seen: see docs/decisions/protocols.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.run.scheduler import BLOCKS, BlockTiming, FixedLatency, Timing, WallTimeLatency


class VotRealTime:
    """VOT real-time: the tracker's latency is its measured wall time on this machine."""

    name = "vot_rt"
    paper_role = "Embedded"  # reports: the measured wall time is paper Table 4's embedded reference

    @classmethod
    def table_label(cls, params: Mapping[str, Any]) -> tuple[str, tuple]:
        """Reports: display label and sort key (paper Table 1 order: last)."""
        scale = float(params.get("time_scale", cls.Params().time_scale))
        return "VOT real-time" + ("" if scale == 1.0 else f" (x{scale:g})"), (4, scale)

    @dataclass(frozen=True)
    class Params:
        time_scale: float = param(1.0, "factor on measured wall times (e.g. 3 emulates a 3x slower machine)")
        timed_blocks: list[str] = param(["tracker"], "blocks whose latency is their measured wall time (others: none)")
        grace: int = param(1, "a timed block's first calls (initialisation included) slower than a frame "
                              "interval that count as taking one (the VOT toolkit's realtime grace, default "
                              "1: model loading and first-run allocations, which a device does before its "
                              "first frame); 0: none")

        def __post_init__(self) -> None:
            if not self.time_scale > 0:
                raise ValueError(f"vot_rt: time_scale: expected a positive number, got {self.time_scale!r}")
            if isinstance(self.grace, bool) or self.grace < 0:
                raise ValueError(f"vot_rt: grace: expected a number of calls >= 0, got {self.grace!r}")
            for b in self.timed_blocks:
                if b not in BLOCKS:
                    raise ValueError(f"vot_rt: timed_blocks: unknown block {b!r}; blocks: {', '.join(BLOCKS)}")

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()

    def timing(self, fps: float) -> Timing:
        """Per sequence (a fresh grace for each): the timed blocks' latency is their wall time."""
        p = self.params
        timed = set(p.timed_blocks)

        def latency(b: str):
            if b not in timed:
                return FixedLatency(0.0)
            lat = WallTimeLatency(p.time_scale)
            return GraceLatency(lat, 1.0 / fps, p.grace) if p.grace else lat

        return Timing(fps, {b: BlockTiming(fps, latency(b)) for b in BLOCKS})


class GraceLatency:
    """The VOT toolkit's realtime grace (``RealtimeTrackerRuntime``): the first ``grace`` calls
    whose latency exceeds one frame ``interval`` count as taking exactly one interval (their
    overflow forgotten); later calls keep their own. Stateful: one per block and sequence."""

    measured = True   # measured on this machine, as WallTimeLatency: its run runs alone

    def __init__(self, inner: WallTimeLatency, interval: float, grace: int):
        self.inner, self.interval, self.left = inner, interval, grace

    def draw(self, rng, wall_s: float) -> float:
        latency = self.inner.draw(rng, wall_s)
        if latency > self.interval and self.left > 0:
            self.left -= 1
            return self.interval
        return latency


@hookimpl
def mata_eval_protocols():
    return [VotRealTime]
