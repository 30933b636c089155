"""DSP, the down-sampling protocol (paper section 3.1): the camera delivers every n-th frame,
every block runs on each kept frame without delay, and only kept frames are scored."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.run.scheduler import BLOCKS, BlockTiming, Timing


class DSP:
    """Down-sampling protocol: keep every n-th frame, process each kept frame without delay."""

    name = "dsp"

    @classmethod
    def table_label(cls, params: Mapping[str, Any]) -> tuple[str, tuple]:
        """Reports: display label and sort key (paper Table 1 order: after LTP and EOP)."""
        n = params.get("n", cls.Params().n)
        return f"DSP (n = {n})", (3, float(n))

    @dataclass(frozen=True)
    class Params:
        n: int = param(3, "sub-sampling factor: frames 0, n, 2n, ... are kept and scored")

        def __post_init__(self) -> None:
            if self.n < 1:
                raise ValueError(f"dsp: n: expected an integer >= 1, got {self.n!r}")

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()

    def timing(self, fps: float) -> Timing:
        hz = fps / self.params.n
        return Timing(hz, {b: BlockTiming(hz) for b in BLOCKS})


@hookimpl
def mata_eval_protocols():
    return [DSP]
