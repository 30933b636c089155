"""Timing profiles: measured per-block latencies of a machine (written by ``mata-eval profile``,
read by the ``eop`` protocol to draw latencies; beyond the paper, which names constant delays as
a limitation of EOP in its discussion).

File format (JSON, or YAML when the file name ends in ``.yaml`` / ``.yml``)::

    format: mata-eval timing profile
    version: 1
    created: "2026-11-23T10:00:00Z"        # optional
    machine: {cpu: ..., gpu: ..., power_mode: ..., threads: 4}   # free-form description
    blocks:
      tracker:
        samples_s: [0.081, 0.079, ...]     # latency samples in seconds, and/or
        histogram: {edges_s: [0.07, 0.08, 0.09], counts: [12, 30]}
        mean_s: 0.0806                     # these three are written for people: a reader
        percentiles_s: {"50": 0.08, "90": 0.088, "99": 0.095}   # refuses them when they disagree
        rate_hz: 12.4                      # with the samples (1 / mean: back to back)
      egomotion: {...}

Block names are the scheduler's (``tracker``, ``egomotion``, ``estimator``); other names are
kept but unused. A block needs ``samples_s`` or ``histogram`` (or both; draws then use the
samples, and the histogram must count them). To change a profile, edit its samples (e.g. scale
them all) and delete the derived values, or measure with ``mata-eval profile --time-scale``.
Writers: build the profile with :func:`profile_from_samples` and save it with
:func:`write_profile`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .shipped import shipped_file

FORMAT = "mata-eval timing profile"
VERSION = 1
PERCENTILES = (50, 90, 95, 99)


class ProfileError(ValueError):
    """A timing profile file is malformed: the message names the file and the key."""


@dataclass(frozen=True, eq=False)
class BlockProfile:
    """Latency distribution of one block: raw samples (seconds) and/or a histogram."""

    samples_s: np.ndarray | None = None
    hist_edges_s: np.ndarray | None = None
    hist_counts: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.samples_s is None and self.hist_edges_s is None:
            raise ProfileError("a block profile needs latency samples or a histogram")

    @property
    def mean_s(self) -> float:
        if self.samples_s is not None:
            return float(np.mean(self.samples_s))
        mids = 0.5 * (self.hist_edges_s[:-1] + self.hist_edges_s[1:])
        return float(np.sum(mids * self.hist_counts) / np.sum(self.hist_counts))

    @property
    def rate_hz(self) -> float:
        """Effective rate of the block run back to back: one call per mean latency."""
        m = self.mean_s
        return math.inf if m <= 0 else 1.0 / m

    def percentiles_s(self, qs: tuple[int, ...] = PERCENTILES) -> dict[str, float]:
        if self.samples_s is not None:
            return {str(q): float(np.percentile(self.samples_s, q)) for q in qs}
        # Percentiles of the histogram, linear within a bin (its piecewise-linear CDF).
        cdf = np.concatenate([[0.0], np.cumsum(self.hist_counts) / np.sum(self.hist_counts)])
        return {str(q): float(np.interp(q / 100.0, cdf, self.hist_edges_s)) for q in qs}

    def sample(self, rng: np.random.Generator, size: int | None = None) -> float | np.ndarray:
        """Draw latencies (seconds): a resample of the samples, or a histogram bin chosen by its
        count then a uniform position within it."""
        if self.samples_s is not None:
            return rng.choice(self.samples_s, size=size)
        p = self.hist_counts / np.sum(self.hist_counts)
        b = rng.choice(len(p), size=size, p=p)
        lo, hi = self.hist_edges_s[b], self.hist_edges_s[np.asarray(b) + 1]
        return lo + (hi - lo) * rng.random(size=size)


@dataclass(frozen=True, eq=False)
class TimingProfile:
    """Per-block latency profiles measured on one machine."""

    blocks: Mapping[str, BlockProfile]
    machine: Mapping[str, Any] = field(default_factory=dict)
    created: str | None = None

    def block(self, name: str, source: str = "timing profile") -> BlockProfile:
        try:
            return self.blocks[name]
        except KeyError:
            have = ", ".join(sorted(self.blocks)) or "(none)"
            raise ProfileError(f"{source}: no block {name!r} in the profile (it has: {have})") from None


def profile_from_samples(samples: Mapping[str, Any], machine: Mapping[str, Any] | None = None,
                         bins: int = 20, created: str | None = None) -> TimingProfile:
    """A profile from raw latency samples per block (what ``mata-eval profile`` measures); a
    histogram with ``bins`` bins is stored alongside the samples."""
    blocks = {}
    for name, s in samples.items():
        arr = np.asarray(s, dtype=float).reshape(-1)
        _check_samples(arr, f"samples of block {name!r}")
        lo, hi = float(arr.min()), float(arr.max())
        if hi <= lo:  # constant samples: one narrow bin range above the value, never below zero
            hi = lo + max(1e-6, 1e-3 * lo)
        counts, edges = np.histogram(arr, bins=bins, range=(lo, hi))
        blocks[name] = BlockProfile(arr, edges, counts.astype(float))
    return TimingProfile(blocks, dict(machine or {}), created)


def write_profile(profile: TimingProfile, path: str | Path) -> Path:
    """Write ``profile`` as JSON, or YAML for ``.yaml``/``.yml`` (atomically)."""
    from .results import atomic_write_text

    path = Path(path)
    doc: dict[str, Any] = {"format": FORMAT, "version": VERSION}
    if profile.created:
        doc["created"] = profile.created
    doc["machine"] = dict(profile.machine)
    doc["blocks"] = {}
    for name, b in profile.blocks.items():
        entry: dict[str, Any] = {}
        if b.samples_s is not None:
            entry["samples_s"] = [float(v) for v in b.samples_s]
        if b.hist_edges_s is not None:
            entry["histogram"] = {"edges_s": [float(v) for v in b.hist_edges_s],
                                  "counts": [float(v) for v in b.hist_counts]}
        entry["mean_s"] = b.mean_s
        entry["percentiles_s"] = b.percentiles_s()
        entry["rate_hz"] = b.rate_hz
        doc["blocks"][name] = entry
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        text = yaml.safe_dump(doc, sort_keys=False)
    else:
        text = json.dumps(doc, indent=1)
    atomic_write_text(path, text)
    return path


def read_profile(path: str | Path) -> TimingProfile:
    """Read and validate a timing profile; errors name the file and the offending key."""
    path = shipped_file(path)
    try:
        text = path.read_text()
    except OSError as exc:
        from ..data.datasets.annotations import where

        raise ProfileError(f"cannot read timing profile {where(path)}: {exc.strerror or exc}") from None
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            doc = yaml.safe_load(text)
        else:
            doc = json.loads(text)
    except Exception as exc:
        raise ProfileError(f"{path}: not valid {'YAML' if path.suffix.lower() in ('.yaml', '.yml') else 'JSON'}: {exc}") from None
    if not isinstance(doc, dict):
        raise ProfileError(f"{path}: expected a mapping at the top level")
    if doc.get("format") != FORMAT:
        raise ProfileError(f"{path}: key 'format': expected {FORMAT!r}, got {doc.get('format')!r}")
    if doc.get("version") != VERSION:
        raise ProfileError(f"{path}: key 'version': expected {VERSION}, got {doc.get('version')!r}")
    blocks_doc = doc.get("blocks")
    if not isinstance(blocks_doc, dict) or not blocks_doc:
        raise ProfileError(f"{path}: key 'blocks': expected a non-empty mapping block -> latencies")
    blocks = {}
    for name, entry in blocks_doc.items():
        where = f"{path}: key 'blocks.{name}"
        if not isinstance(entry, dict):
            raise ProfileError(f"{where}': expected a mapping")
        samples = edges = counts = None
        if "samples_s" in entry:
            samples = _float_array(entry["samples_s"], f"{where}.samples_s'")
            _check_samples(samples, f"{where}.samples_s'")
        if "histogram" in entry:
            h = entry["histogram"]
            if not isinstance(h, dict) or "edges_s" not in h or "counts" not in h:
                raise ProfileError(f"{where}.histogram': expected a mapping with edges_s and counts")
            edges = _float_array(h["edges_s"], f"{where}.histogram.edges_s'")
            counts = _float_array(h["counts"], f"{where}.histogram.counts'")
            if len(edges) != len(counts) + 1 or len(counts) == 0:
                raise ProfileError(f"{where}.histogram': expected len(edges_s) == len(counts) + 1 >= 2, "
                                   f"got {len(edges)} edges and {len(counts)} counts")
            if np.any(np.diff(edges) <= 0) or edges[0] < 0:
                raise ProfileError(f"{where}.histogram.edges_s': expected increasing non-negative seconds")
            if np.any(counts < 0) or counts.sum() <= 0:
                raise ProfileError(f"{where}.histogram.counts': expected non-negative counts with a positive sum")
        if samples is None and edges is None:
            raise ProfileError(f"{where}': expected 'samples_s' and/or 'histogram'")
        blocks[name] = BlockProfile(samples, edges, counts)
        _check_derived(entry, blocks[name], where)
    machine = doc.get("machine") or {}
    if not isinstance(machine, dict):
        raise ProfileError(f"{path}: key 'machine': expected a mapping")
    return TimingProfile(blocks, machine, doc.get("created"))


def _check_derived(entry: Mapping[str, Any], block: BlockProfile, where: str) -> None:
    """Refuse a profile whose values written for people (``mean_s``, ``rate_hz``,
    ``percentiles_s``) or whose histogram beside the samples say other than what every draw is
    made from (QA pass: ``rate_hz`` edited from 30 to 10, the tracker still ran at 30 Hz without
    a word): its samples, to rounding; a histogram alone, the mean and rate to half its widest
    bin (they were written from the samples it counts, each within its bin; its percentiles,
    interpolated within bins, may differ more and are not compared). A null value is no value."""
    source = "samples" if block.samples_s is not None else "histogram"
    redo = (f"draws use its {source}: edit those (e.g. scale every value), and delete or update the values "
            "derived from them (mean_s, rate_hz, percentiles_s)")
    tol = 0.0 if block.samples_s is not None else 0.5 * float(np.max(np.diff(block.hist_edges_s))) * (1 + 1e-9)
    mean = block.mean_s
    derived = {"mean_s": mean, **{f"percentiles_s.{q}": v for q, v in block.percentiles_s().items()}}
    given = {k: entry[k] for k in ("mean_s", "rate_hz") if entry.get(k) is not None}
    if isinstance(entry.get("percentiles_s"), Mapping) and not tol:
        given.update({f"percentiles_s.{q}": v for q, v in entry["percentiles_s"].items()
                      if f"percentiles_s.{q}" in derived and v is not None})
    for key, value in given.items():
        number = isinstance(value, (int, float)) and not isinstance(value, bool) and (key != "rate_hz" or value > 0)
        seconds = (1.0 / value if key == "rate_hz" else value) if number else math.nan
        want = mean if key == "rate_hz" else derived[key]
        if not math.isclose(seconds, want, rel_tol=1e-6, abs_tol=max(tol, 1e-12)):
            gives = f"{1.0 / mean:.6g}" if key == "rate_hz" and mean > 0 else f"{want:.6g}"
            raise ProfileError(f"{where}.{key}' is {value!r}, but its {source} give{'s' if tol else ''} {gives}: {redo}")
    if block.samples_s is not None and block.hist_edges_s is not None:
        counts, _ = np.histogram(block.samples_s, bins=block.hist_edges_s)
        if not np.array_equal(counts, block.hist_counts):
            raise ProfileError(f"{where}.histogram' does not count its samples_s: {redo}; or keep only one of the two")


def _float_array(value: Any, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ProfileError(f"{where}: expected a list of numbers") from None
    return arr


def _check_samples(arr: np.ndarray, where: str) -> None:
    if arr.size == 0:
        raise ProfileError(f"{where}: expected at least one latency sample")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ProfileError(f"{where}: expected finite non-negative seconds")
