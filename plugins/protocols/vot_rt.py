"""VOT real-time (VOT2021 real-time experiment, cited in paper section 3.1): frames arrive at the
camera rate; a block busy with an earlier frame misses the new ones, and its latency is its own
measured wall-clock time on this machine (hardware dependent by design); outputs are held."""

from __future__ import annotations

from dataclasses import dataclass

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.scheduler import BLOCKS, BlockTiming, Timing, WallTimeLatency


class VotRealTime:
    """VOT real-time: each block's latency is its measured wall time on this machine."""

    name = "vot_rt"

    @dataclass(frozen=True)
    class Params:
        time_scale: float = param(1.0, "factor on measured wall times (e.g. 3 emulates a 3x slower machine)")

        def __post_init__(self) -> None:
            if not self.time_scale > 0:
                raise ValueError(f"vot_rt: time_scale: expected a positive number, got {self.time_scale!r}")

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()

    def timing(self, fps: float) -> Timing:
        lat = WallTimeLatency(self.params.time_scale)
        return Timing(fps, {b: BlockTiming(fps, lat) for b in BLOCKS})


@hookimpl
def mata_eval_protocols():
    return [VotRealTime]
