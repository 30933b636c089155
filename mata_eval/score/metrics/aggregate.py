"""Means of per-sequence scores over a dataset, per attribute and per challenge group (paper
Table 2; DESIGN.md "Metrics")."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from ...core.metric_profiles import NORM_GRID, PIXEL_GRID, PYSOT_IOU_GRID
from .measures import SequenceScores, json_float


METRIC_NAMES = ("sr", "msr", "pr", "precision20", "nt2f")

#: DESIGN.md challenge groups, each "any of" these sequence attributes (compared upper-case).
#: UAV123: FOC / POC (full / partial occlusion), SOB (similar object), FM (fast motion), OV;
#: AOC marks a sequence with augmented occlusion events (set by the occlusion augmentation).
#: The same concepts in DTB70 (OCC, SOA) and UAVDT (LO, large occlusion) are included; they
#: change nothing on UAV123, whose attribute names differ.
DEFAULT_GROUPS: dict[str, tuple[str, ...]] = {
    "occlusion": ("FOC", "POC", "AOC", "OCC", "LO"),
    "distractor": ("SOB", "SOA"),
    "high dynamic": ("FM",),
    "out of view": ("OV",),
}


@dataclass(frozen=True, eq=False)
class Summary:
    """Means over the sequences of a set (every toolkit averages per sequence first). Sequences
    where a metric is NaN (nothing could be scored) are left out of that metric's mean."""

    n_sequences: int
    sr: float
    msr: float
    pr: float
    precision20: float
    nt2f: float
    success_curve: np.ndarray
    precision_curve: np.ndarray
    norm_precision_curve: np.ndarray
    n_frames: int
    n_scored: int
    n_excluded: int
    n_invalid_gt: int

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            d[k] = [json_float(v) for v in d[k]]
        for k in METRIC_NAMES:
            d[k] = json_float(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "Summary":
        kw = dict(d)
        for k in ("success_curve", "precision_curve", "norm_precision_curve"):
            kw[k] = np.array([np.nan if v is None else v for v in kw[k]], dtype=float)
        for k in METRIC_NAMES:
            kw[k] = float("nan") if kw[k] is None else float(kw[k])
        return cls(**kw)


def _nanmean_rows(rows: list[np.ndarray], width: int) -> np.ndarray:
    if not rows:
        return np.full(width, np.nan)
    a = np.vstack(rows)
    ok = np.isfinite(a)
    counts = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, np.where(ok, a, 0.0).sum(axis=0) / counts, np.nan)


def summarize(scores: Iterable[SequenceScores]) -> Summary:
    """Per-dataset means of a set of sequences."""
    scores = list(scores)
    scorable = [s for s in scores if np.isfinite(s.msr) or np.isfinite(s.nt2f)]

    def mean(name: str) -> float:
        vals = np.array([getattr(s, name) for s in scores], dtype=float)
        vals = vals[np.isfinite(vals)]
        return float(vals.mean()) if vals.size else float("nan")

    return Summary(
        n_sequences=len(scorable),
        **{m: mean(m) for m in METRIC_NAMES},
        success_curve=_nanmean_rows([s.success_curve for s in scores], len(PYSOT_IOU_GRID)),
        precision_curve=_nanmean_rows([s.precision_curve for s in scores], len(PIXEL_GRID)),
        norm_precision_curve=_nanmean_rows([s.norm_precision_curve for s in scores], len(NORM_GRID)),
        n_frames=sum(s.n_frames for s in scores),
        n_scored=sum(s.n_scored for s in scores),
        n_excluded=sum(s.n_excluded for s in scores),
        n_invalid_gt=sum(s.n_invalid_gt for s in scores),
    )


@dataclass(frozen=True, eq=False)
class Aggregate:
    """Dataset-level means, per attribute (every attribute present) and per challenge group
    (every configured group, possibly empty: ``n_sequences == 0`` and NaN values)."""

    overall: Summary
    attributes: dict[str, Summary]
    groups: dict[str, Summary]
    group_definitions: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: means over the frames an augmented occluder covers (sequences with occluded frames only)
    occluded_frames: Summary | None = None

    def to_dict(self) -> dict:
        return {
            "overall": self.overall.to_dict(),
            "attributes": {k: v.to_dict() for k, v in self.attributes.items()},
            "groups": {k: v.to_dict() for k, v in self.groups.items()},
            "group_definitions": {k: list(v) for k, v in self.group_definitions.items()},
            "occluded_frames": None if self.occluded_frames is None else self.occluded_frames.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Aggregate":
        return cls(
            overall=Summary.from_dict(d["overall"]),
            attributes={k: Summary.from_dict(v) for k, v in d["attributes"].items()},
            groups={k: Summary.from_dict(v) for k, v in d["groups"].items()},
            group_definitions={k: tuple(v) for k, v in d.get("group_definitions", {}).items()},
            occluded_frames=Summary.from_dict(d["occluded_frames"]) if d.get("occluded_frames") else None,
        )


def aggregate(
    items: Iterable[tuple[SequenceScores, Iterable[str]]],
    groups: Mapping[str, Iterable[str]] | None = None,
) -> Aggregate:
    """Means over sequences, per attribute and per challenge group. ``items``: (scores,
    attributes of the sequence). ``groups``: name -> attributes, a sequence belongs to the group
    if it has any of them (case-insensitive); default :data:`DEFAULT_GROUPS`."""
    items = [(s, frozenset(attrs)) for s, attrs in items]
    defs = {k: tuple(v) for k, v in (DEFAULT_GROUPS if groups is None else groups).items()}
    present = sorted(set().union(*(a for _, a in items))) if items else []

    def in_group(attrs: frozenset[str], members: Iterable[str]) -> bool:
        return bool({a.upper() for a in attrs} & {m.upper() for m in members})

    return Aggregate(
        overall=summarize(s for s, _ in items),
        attributes={a: summarize(s for s, attrs in items if a in attrs) for a in present},
        groups={name: summarize(s for s, attrs in items if in_group(attrs, members))
                for name, members in defs.items()},
        group_definitions=defs,
    )

