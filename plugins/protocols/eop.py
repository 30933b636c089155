"""EOP, the Embedded-Oriented Protocol (paper section 3.1, figure "protocol comparison"): each
block at its own rate with its own output latency, hardware independent. The paper's setting is
``tracker_hz: 10`` with a one-period latency (the output of frame 3 is visible from frame 6) and
ego-motion and estimator at the camera rate with none.

Beyond the paper (its discussion names these as limitations): latencies drawn per call from a
measured timing profile (``latency_profile``), communication delays on links
(``link_delay_s: {"tracker->estimator": 0.02}``) and per-call jitter (``jitter_s``)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.run.scheduler import (BLOCKS, EPS, BlockTiming, FixedLatency, Latency, ProfileLatency,
                                     RateWarning, Timing, turn_frames)
from mata_eval.run.shipped import shipped_file
from mata_eval.run.timing_profile import TimingProfile, read_profile

CONSUMERS = BLOCKS + ("output",)
_LATENCY_HELP = "'period' (one period of its rate), 'none', seconds, or 'profile' (drawn from latency_profile)"
_RATE_HELP = ("Hz, null (camera rate) or 'profile' (as fast as the profiled block: it starts at the "
              "first frame after its previous call, whose period is the profile's effective rate)")


def _check_rate(key: str, value: Any) -> None:
    if value is None or value == "profile":
        return
    if isinstance(value, str) or not (value > 0 and math.isfinite(value)):
        raise ValueError(f"eop: {key}: expected {_RATE_HELP}, got {value!r}")


def _check_latency(key: str, value: Any) -> None:
    if value in ("period", "none", "profile"):
        return
    if isinstance(value, str) or not (value >= 0 and math.isfinite(value)):
        raise ValueError(f"eop: {key}: expected {_LATENCY_HELP}, got {value!r}")


#: A rate within this relative distance of ``fps / n`` is ``fps / n`` (the digits typed: 3.3333 Hz
#: on a 10 fps camera is every 3rd frame, although 1 / 3.3333 s is 3 us longer than 3 frames).
GRID_TOLERANCE = 1e-4


def on_camera_grid(hz: float, fps: float) -> float:
    """``fps / n`` when ``hz`` is within :data:`GRID_TOLERANCE` of it for a whole ``n``, else ``hz``."""
    n = round(fps / hz)
    return fps / n if n >= 1 and abs(fps / hz - n) <= GRID_TOLERANCE * fps / hz else hz


def grid_rate(hz: float, latency_s: float, fps: float, n_frames: int = 600) -> tuple[list[int], float]:
    """Start frames of a block with turns on the ``m / hz`` grid and a fixed latency (busy at a
    turn: skipped, as the scheduler does), and its steady rate in Hz (after the first call)."""
    starts, busy_until = [], -math.inf
    for k in np.flatnonzero(turn_frames(n_frames, hz, fps)):
        if busy_until <= k / fps + EPS:
            starts.append(int(k))
            busy_until = k / fps + latency_s
    steady = starts[1:]
    rate = fps * (len(steady) - 1) / (steady[-1] - steady[0]) if len(steady) > 1 else math.nan
    return starts, rate


def parse_link(key: str) -> tuple[str, str]:
    """``"tracker->estimator"`` -> ``("tracker", "estimator")``; consumers include ``output``."""
    parts = [p.strip() for p in str(key).split("->")]
    if len(parts) != 2 or parts[0] not in BLOCKS or parts[1] not in CONSUMERS or parts[0] == parts[1]:
        raise ValueError(f"eop: link_delay_s: key {key!r}: expected 'producer->consumer' with producer in "
                         f"{', '.join(BLOCKS)} and consumer in {', '.join(CONSUMERS)}")
    return parts[0], parts[1]


class EOP:
    """Embedded-oriented protocol: per-block rates and output latencies (optionally measured)."""

    name = "eop"
    paper_role = "EOP"  # reports: the EOP columns of paper Table 4

    @classmethod
    def table_label(cls, params: Mapping[str, Any]) -> tuple[str, tuple]:
        """Reports: display label and sort key (paper Table 1 order: after LTP, from the fastest
        tracker rate down, the profiled rate last)."""
        default = cls.Params()
        hz = params.get("tracker_hz", default.tracker_hz)
        if hz is None:
            return "EOP @ camera rate", (1, -math.inf)
        if hz == "profile":
            profiled = params.get("tracker_latency", default.tracker_latency) == "profile"
            return "EOP @ profile rate" + (" (profile latencies)" if profiled else ""), (2, 0.0)
        return f"EOP @ {float(hz):g} Hz", (1, -float(hz))

    @dataclass(frozen=True)
    class Params:
        tracker_hz: float | str | None = param(None, f"tracker rate: {_RATE_HELP}")
        tracker_latency: float | str = param("period", f"tracker output latency: {_LATENCY_HELP}")
        egomotion_hz: float | str | None = param(None, f"ego-motion rate: {_RATE_HELP}")
        egomotion_latency: float | str = param("none", f"ego-motion output latency: {_LATENCY_HELP}")
        estimator_hz: float | str | None = param(None, f"estimator rate: {_RATE_HELP}")
        estimator_latency: float | str = param("none", f"estimator output latency: {_LATENCY_HELP}")
        latency_profile: str | None = param(None, "timing profile file (mata-eval profile) for 'profile' rates/latencies")
        link_delay_s: dict = param({}, "communication delays, e.g. {'tracker->estimator': 0.02} (consumer 'output' = scoring)")
        jitter_s: float | dict = param(0.0, "std (s) of Gaussian per-call latency jitter: one value, or per block")
        tracker_start: Literal["frame", "free"] = param(
            "frame", "when the tracker becomes free between two frames: start at the next frame (paper), "
                     "or 'free': at once on the newest frame, as the live protocol (docs/live.md)")

        def __post_init__(self) -> None:
            uses_profile = False
            for b in BLOCKS:
                rate, lat = getattr(self, f"{b}_hz"), getattr(self, f"{b}_latency")
                _check_rate(f"{b}_hz", rate)
                _check_latency(f"{b}_latency", lat)
                uses_profile |= rate == "profile" or lat == "profile"
            if uses_profile and not self.latency_profile:
                raise ValueError("eop: latency_profile: a rate or latency is 'profile', so a timing profile "
                                 "file must be given")
            if self.latency_profile:  # fail when the experiment is loaded, not in every sequence
                profile = read_profile(self.latency_profile)
                for b in BLOCKS:
                    if "profile" in (getattr(self, f"{b}_hz"), getattr(self, f"{b}_latency")):
                        profile.block(b, f"eop: latency_profile {self.latency_profile}")
            for key, value in self.link_delay_s.items():
                parse_link(key)
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                    raise ValueError(f"eop: link_delay_s.{key}: expected seconds >= 0, got {value!r}")
            jit = self.jitter_s if isinstance(self.jitter_s, dict) else {b: self.jitter_s for b in BLOCKS}
            for key, value in jit.items():
                if key not in BLOCKS:
                    raise ValueError(f"eop: jitter_s: unknown block {key!r}; blocks: {', '.join(BLOCKS)}")
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
                    raise ValueError(f"eop: jitter_s.{key}: expected seconds >= 0, got {value!r}")

    def __init__(self, params: Params | None = None):
        self.params = params or self.Params()
        p = self.params
        self.profile: TimingProfile | None = read_profile(p.latency_profile) if p.latency_profile else None
        self.links = {parse_link(k): float(v) for k, v in p.link_delay_s.items()}
        jit = p.jitter_s if isinstance(p.jitter_s, dict) else {b: p.jitter_s for b in BLOCKS}
        self.jitter = {b: float(jit.get(b, 0.0)) for b in BLOCKS}

    @classmethod
    def model_files(cls, params: "EOP.Params") -> dict[str, Path]:
        """The timing profile these parameters read: a run's manifest records its sha256, so a
        rerun after the profile was measured again is refused (its rates and latencies changed)."""
        return {"latency_profile": shipped_file(params.latency_profile)} if params.latency_profile else {}

    def _block_profile(self, block: str):
        assert self.profile is not None
        return self.profile.block(block, f"eop latency_profile {self.params.latency_profile}")

    def block_timing(self, block: str, fps: float) -> BlockTiming:
        rate = getattr(self.params, f"{block}_hz")
        lat = getattr(self.params, f"{block}_latency")
        if rate is None:
            hz = period_hz = fps
        elif rate == "profile":
            # As fast as the measured block goes: a turn at every camera frame, busy for its
            # period, so it starts at the first frame after it is free (a 9.5 Hz block on a
            # 30 Hz camera takes every 4th frame, as on the board; a 9.5 Hz grid would make it
            # find itself busy at every other grid tick).
            hz, period_hz = fps, self._block_profile(block).rate_hz
        else:
            hz = period_hz = on_camera_grid(float(rate), fps)
        latency: Latency
        if lat == "period":
            latency = FixedLatency(1.0 / min(period_hz, fps))  # no block runs faster than the camera
        elif lat == "none":
            latency = FixedLatency(0.0)
        elif lat == "profile":
            latency = ProfileLatency(self._block_profile(block))
        else:
            latency = FixedLatency(float(lat))
        if rate not in (None, "profile") and not math.isclose(fps / hz, round(fps / hz), rel_tol=1e-9):
            self._warn_off_grid(block, rate, fps, hz, latency)
        return BlockTiming(hz, latency, self.jitter[block],
                           free_start=block == "tracker" and self.params.tracker_start == "free")

    def _warn_off_grid(self, block: str, rate: float, fps: float, hz: float, latency: Latency) -> None:
        """A block starts only when a frame arrives: a rate that is not fps / n runs at irregular
        frames (and may find itself busy at its turns); name the frames and the rate it runs at."""
        fixed = isinstance(latency, FixedLatency) and not self.jitter[block]
        starts, run_hz = grid_rate(hz, latency.seconds if fixed else 0.0, fps)
        why = f"is faster than the {fps:g} fps camera" if hz > fps else f"is not {fps:g} fps / n"
        warnings.warn(RateWarning(
            f"eop: {block}_hz {rate:g} {why}: the {block} starts at frames "
            f"{', '.join(map(str, starts[:6]))}, ... and runs at {run_hz:.4g} Hz{'' if fixed else ' at most'}; "
            f"use {fps:g} / n Hz ({', '.join(f'{fps / n:.4g}' for n in range(1, 5))}, ...) for a regular rate"))

    def timing(self, fps: float) -> Timing:
        self._warn_long_times()
        return Timing(fps, {b: self.block_timing(b, fps) for b in BLOCKS}, self.links)

    def _warn_long_times(self) -> None:
        """Times of a second or more are valid (a slow link) but more often milliseconds given
        as seconds (QA pass: ``tracker_latency: 100`` ran at 0.4 Hz without a word)."""
        p = self.params
        given = {f"{b}_latency": getattr(p, f"{b}_latency") for b in BLOCKS}
        given.update({f"link_delay_s.{k}": v for k, v in p.link_delay_s.items()})
        given.update({f"jitter_s.{b}": v for b, v in self.jitter.items()} if isinstance(p.jitter_s, dict)
                     else {"jitter_s": p.jitter_s})
        for key, value in given.items():
            if not isinstance(value, str) and value >= 1.0:
                warnings.warn(RateWarning(f"eop: {key} {value:g} s: times are in seconds (for {value:g} ms "
                                          f"write {value / 1000:g})"))
        for b in BLOCKS:   # (QA pass: samples_s [50, 60, 70] ran the tracker at 0.4 Hz without a word)
            if "profile" in (getattr(p, f"{b}_hz"), getattr(p, f"{b}_latency")) and \
                    (median := self._block_profile(b).percentiles_s((50,))["50"]) >= 1.0:
                warnings.warn(RateWarning(f"eop: latency_profile {p.latency_profile}: the {b}'s median latency is "
                                          f"{median:g} s: profile samples are in seconds (if these are milliseconds, "
                                          "divide them by 1000)"))


@hookimpl
def mata_eval_protocols():
    return [EOP]
