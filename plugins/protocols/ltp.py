"""LTP, the long-term protocol (paper section 3.1): every block on every frame, no latency."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from mata_eval.hooks import hookimpl
from mata_eval.run.scheduler import Timing, every_frame


class LTP:
    """Long-term protocol: every block processes every frame with no delay (offline evaluation)."""

    name = "ltp"
    paper_role = "LTP"  # reports: the LTP columns of paper Table 4

    @staticmethod
    def table_label(params: Mapping[str, Any]) -> tuple[str, tuple]:
        """Reports: display label and sort key (paper Table 1 order: LTP first)."""
        return "LTP", (0, 0.0)

    @dataclass(frozen=True)
    class Params:
        pass

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()

    def timing(self, fps: float) -> Timing:
        return every_frame(fps)


@hookimpl
def mata_eval_protocols():
    return [LTP]
