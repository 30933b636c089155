"""Score a results folder: a mata-eval run folder (architecture.md "Run folder") or a foreign one
in pysot / pysot-toolkit, got10k or pytracking layout. Only annotations are read, never images.

Layouts (``detect_layout`` picks one; ``layout=`` overrides):

- ``mata``: ``<seq>.txt`` (``x,y,w,h``), ``<seq>.frames.csv`` (``frame,scored,...,<block>_ms``),
  ``<seq>.failed.json``, ``manifest.json``;
- ``pysot`` (also pysot-toolkit, got10k OTB/UAV123 experiments): ``<dir>/<seq>.txt``, comma
  separated floats;
- ``got10k`` (GOT-10k experiment): ``<dir>/<seq>/<seq>_001.txt`` (first repetition) and
  ``<dir>/<seq>/<seq>_time.txt`` (seconds per frame);
- ``pytracking``: ``<dir>/<seq>.txt``, tab separated integers, and ``<dir>/<seq>_time.txt``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..core.sequence import Sequence
from ..run import results
from ..run.config import Experiment
from . import metrics
from .metrics import Aggregate, BlockFrequency, SequenceScores

SCORES = results.SCORES
LAYOUTS = ("mata", "pysot", "got10k", "pytracking")
SCORES_FORMAT = 1


@dataclass(frozen=True, eq=False)
class RunScores:
    """Everything ``scores.json`` holds: per-sequence scores, their aggregates (overall, per
    attribute, per challenge group), excluded-frame counts, failures and block frequencies.

    ``name``: the run (or results folder); ``path``: its folder; ``profile``: the metric profile;
    ``layout``: the results layout read; ``sequences``: sequence -> scores; ``attributes``:
    sequence -> attributes; ``summary``: ``overall``, ``attributes`` and challenge ``groups``
    means; ``failures``: sequence -> reason it failed; ``missing``: sequences without results;
    ``frequencies``: block -> rates (the table's Hz column); ``meta``: where it came from."""

    name: str
    path: str
    profile: str
    layout: str
    sequences: dict[str, SequenceScores]
    attributes: dict[str, tuple[str, ...]]
    summary: Aggregate
    failures: dict[str, str] = field(default_factory=dict)
    missing: tuple[str, ...] = ()
    frequencies: dict[str, BlockFrequency] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def overall(self) -> metrics.Summary:
        """The dataset means: ``sr``, ``msr``, ``pr``, ``precision20``, ``nt2f`` (fractions in
        [0, 1]), mean curves, frame counts."""
        return self.summary.overall

    def to_dict(self) -> dict:
        return {
            "format": SCORES_FORMAT,
            "name": self.name,
            "path": self.path,
            "profile": self.profile,
            "profile_policies": dataclasses.asdict(metrics.get_profile(self.profile))
            if self.profile in metrics.PROFILES else None,
            "layout": self.layout,
            "summary": self.summary.to_dict(),
            "sequences": {k: v.to_dict() for k, v in self.sequences.items()},
            "attributes": {k: list(v) for k, v in self.attributes.items()},
            "failures": dict(self.failures),
            "missing": list(self.missing),
            "frequencies": {k: v.to_dict() for k, v in self.frequencies.items()},
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "scores") -> "RunScores":
        if not isinstance(d, Mapping) or d.get("format", SCORES_FORMAT) != SCORES_FORMAT:
            got = d.get("format") if isinstance(d, Mapping) else type(d).__name__
            raise ValueError(f"{source}: not a mata-eval scores file of format {SCORES_FORMAT} (got {got!r}); "
                             "score the run again (mata-eval eval)")
        for key in ("name", "path", "profile", "layout"):
            if not isinstance(d.get(key), str):
                raise ValueError(f"{source}: not a mata-eval scores file ({key!r}: expected text, got {d.get(key)!r})")
        try:
            return cls(
                name=d["name"], path=d["path"], profile=d["profile"], layout=d["layout"],
                sequences={k: SequenceScores.from_dict(v) for k, v in d["sequences"].items()},
                attributes={k: tuple(v) for k, v in d["attributes"].items()},
                summary=Aggregate.from_dict(d["summary"]),
                failures=dict(d.get("failures", {})),
                missing=tuple(d.get("missing", ())),
                frequencies={k: BlockFrequency.from_dict(v) for k, v in d.get("frequencies", {}).items()},
                meta=dict(d.get("meta", {})),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:   # a hand-edited file
            raise ValueError(f"{source}: not a mata-eval scores file ({type(exc).__name__}: {exc})") from None


# --- reading results -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SequenceResult:
    """What a results folder holds for one sequence."""

    boxes: np.ndarray
    scored: np.ndarray | None = None
    wall_ms: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""


def detect_layout(results_dir: Path) -> str:
    """``mata`` if the folder has a manifest or frame sidecars; ``got10k`` if it has
    ``<seq>/<seq>_001.txt``; ``pytracking`` if its prediction files are tab separated;
    ``pysot`` otherwise. Raises FileNotFoundError when it holds no results at all."""
    d = Path(results_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"results folder not found: {d}")
    if (d / results.MANIFEST).is_file() or any(d.glob("*.frames.csv")):
        return "mata"
    if any((p / f"{p.name}_001.txt").is_file() for p in d.iterdir() if p.is_dir()):
        return "got10k"
    txts = sorted(p for p in d.glob("*.txt") if not p.name.endswith("_time.txt"))
    if not txts:
        nested = sorted(p.name for p in d.iterdir() if p.is_dir() and any(p.glob("*.txt")))
        hint = (f"; its sub-folders {', '.join(nested[:3])}{' ...' if len(nested) > 3 else ''} hold result "
                f"files: pass them (e.g. {d}/*) to score each as a row" if nested else "")
        raise FileNotFoundError(
            f"{d}: no results found (expected <seq>.txt files, or <seq>/<seq>_001.txt for got10k){hint}")
    first = next((line for line in txts[0].read_text().splitlines() if line.strip()), "")
    return "pytracking" if "\t" in first else "pysot"


def _read_times(path: Path) -> dict[str, np.ndarray]:
    """A got10k / pytracking ``_time.txt`` (seconds per frame; 0 where the frame was not timed,
    e.g. got10k's frame 0 is the initialisation) as tracker wall times in ms."""
    if not path.is_file():
        return {}
    try:
        t = np.loadtxt(path, dtype=float, ndmin=1)
    except ValueError as exc:
        raise ValueError(f"{path}: expected one time in seconds per line ({exc})") from None
    return {"tracker": np.where(t > 0, t * 1000.0, np.nan)}


def _parse_flag(v: str, where: str) -> bool:
    s = v.strip().lower()
    if s in ("1", "true", "yes", "1.0"):
        return True
    if s in ("0", "false", "no", "0.0"):
        return False
    raise ValueError(f"{where}: expected 1/0 or true/false in column 'scored', got {v!r}")


def read_frames_csv(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``<seq>.frames.csv`` -> (scored mask, {block: wall ms per frame, NaN where not started})."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or "scored" not in rows[0]:
        raise ValueError(f"{path}: expected a header with a 'scored' column, got {rows[0] if rows else 'an empty file'}")
    head = rows[0]
    body = [r for r in rows[1:] if r]
    for n, r in enumerate(body, start=2):   # a short or long row: a hand edit, or a header broken by a name
        if len(r) != len(head):
            raise ValueError(f"{path}:{n}: expected {len(head)} comma-separated values as in the header (line 1), "
                             f"got {len(r)}")
    i_scored = head.index("scored")
    scored = np.array([_parse_flag(r[i_scored], f"{path}:{n}") for n, r in enumerate(body, start=2)], dtype=bool)
    wall = {}
    for j, name in enumerate(head):
        if name.endswith("_ms"):
            vals = []
            for n, r in enumerate(body, start=2):
                try:
                    vals.append(float(r[j]) if r[j].strip() != "" else np.nan)
                except ValueError:
                    raise ValueError(f"{path}:{n}: column {name!r}: expected a number of ms or empty, "
                                     f"got {r[j]!r}") from None
            wall[name[:-3]] = np.array(vals, dtype=float)
    return scored, wall


def read_results(results_dir: Path, layout: str = "auto") -> tuple[str, dict[str, SequenceResult]]:
    """All sequence results of a folder as (layout, {sequence: result})."""
    d = Path(results_dir)
    layout = detect_layout(d) if layout == "auto" else layout
    if layout not in LAYOUTS:
        raise ValueError(f"unknown results layout {layout!r}; expected auto or one of {', '.join(LAYOUTS)}")
    out: dict[str, SequenceResult] = {}
    if layout == "got10k":
        for sub in sorted(p for p in d.iterdir() if p.is_dir()):
            f = sub / f"{sub.name}_001.txt"
            if f.is_file():
                out[sub.name] = SequenceResult(results.read_predictions(f), None,
                                               _read_times(sub / f"{sub.name}_time.txt"), str(f))
        return layout, out
    for f in sorted(d.glob("*.txt")):
        if f.name.endswith("_time.txt"):
            continue
        name = f.stem
        scored, wall = None, {}
        if layout == "mata":
            fc = d / f"{name}.frames.csv"
            if fc.is_file():
                scored, wall = read_frames_csv(fc)
        elif layout == "pytracking":
            wall = _read_times(d / f"{name}_time.txt")
        out[name] = SequenceResult(results.read_predictions(f), scored, wall, str(f))
    return layout, out


# --- scoring ---------------------------------------------------------------------------------


def score_results(
    found: Mapping[str, SequenceResult],
    sequences: Iterable[Sequence],
    profile: str = "default",
    groups: Mapping[str, Iterable[str]] | None = None,
) -> tuple[dict[str, SequenceScores], dict[str, tuple[str, ...]], Aggregate, list[str], dict[str, BlockFrequency]]:
    """Score the results of each sequence against its ground truth (annotations only)."""
    per_seq: dict[str, SequenceScores] = {}
    attrs: dict[str, tuple[str, ...]] = {}
    missing: list[str] = []
    freqs = []
    occluded: dict[str, SequenceScores] = {}
    for seq in sequences:
        res = found.get(seq.name)
        if res is None:
            missing.append(seq.name)
            continue
        if len(res.boxes) == 0 and len(seq):   # every profile: the got10k one truncated it to nothing
            raise ValueError(f"{res.source}: empty prediction file; sequence {seq.name!r} has {len(seq)} frames")
        scored = res.scored
        if scored is not None and len(scored) != len(seq):
            raise ValueError(f"{res.source}: frames.csv has {len(scored)} rows, sequence {seq.name!r} has {len(seq)} frames")
        try:
            per_seq[seq.name] = metrics.score_sequence(res.boxes, seq.groundtruth, profile=profile,
                                                       scored=scored, annotated=seq.annotated)
        except ValueError as exc:
            raise ValueError(f"{res.source}: {exc}{_blank_lines_note(res.source)}") from None
        attrs[seq.name] = tuple(sorted(seq.attributes))
        occ = occluded_frame_scores(res, seq, profile)
        if occ is not None:
            occluded[seq.name] = occ
        if res.wall_ms:
            freqs.append(metrics.block_frequencies(res.wall_ms, len(seq), seq.fps))
    summary = metrics.aggregate(((per_seq[n], attrs[n]) for n in per_seq), groups)
    if occluded:
        summary = dataclasses.replace(summary, occluded_frames=metrics.summarize(occluded.values()))
    return per_seq, attrs, summary, missing, metrics.combine_frequencies(freqs)


def _blank_lines_note(source: str) -> str:
    """Where a prediction file has blank lines (skipped when it is read, as np.loadtxt skips
    them in the got10k and pytracking toolkits), for an error about its row count."""
    try:
        lines = Path(source).read_text().rstrip().splitlines()
    except (OSError, UnicodeDecodeError):
        return ""
    blank = [i for i, line in enumerate(lines, start=1) if not line.strip()]
    if not blank:
        return ""
    where = ", ".join(map(str, blank[:5])) + (" ..." if len(blank) > 5 else "")
    return f"; line{'s' if len(blank) > 1 else ''} {where} {'are' if len(blank) > 1 else 'is'} blank (blank lines are skipped)"


def occluded_frame_scores(res: SequenceResult, seq: Sequence, profile: str) -> SequenceScores | None:
    """Scores on the frames that an augmented occluder covers (paper 3.2; the per-frame covered
    fraction is ``seq.meta["occlusion"]``), or None for a sequence without occluded frames."""
    cover = seq.meta.get("occlusion")
    if cover is None:
        return None
    mask = np.nan_to_num(np.asarray(cover, dtype=float)) > 0
    if res.scored is not None:
        mask &= np.asarray(res.scored, dtype=bool)
    if not mask.any():
        return None
    return metrics.score_sequence(res.boxes, seq.groundtruth, profile=profile, scored=mask,
                                  annotated=seq.annotated)


def evaluate_results(
    results_dir: Path,
    sequences: Iterable[Sequence],
    profile: str = "default",
    layout: str = "auto",
    name: str | None = None,
    groups: Mapping[str, Iterable[str]] | None = None,
) -> RunScores:
    """Score any results folder (no file is written). Sequences without results are listed in
    ``missing``; failed sequences of a mata run folder in ``failures``."""
    d = Path(results_dir)
    metrics.get_profile(profile)  # fail early on a bad name
    sequences = list(sequences)
    layout, found = read_results(d, layout)
    failures = results.read_failures(d) if layout == "mata" else {}
    per_seq, attrs, summary, missing, freqs = score_results(found, sequences, profile, groups)
    manifest = (results.read_manifest(d) or {}) if layout == "mata" else {}
    dataset = (manifest.get("config") or {}).get("dataset")
    meta = {
        "experiment": manifest.get("experiment"),
        "config_hash": manifest.get("config_hash"),
        "dataset": dataset.get("name") if isinstance(dataset, dict) else None,
        "unmatched_results": sorted(set(found) - {s.name for s in sequences}),
        "bad_frames": {k: v for k, v in results.read_bad_frames(d).items() if k in per_seq} if layout == "mata" else {},
    }
    return RunScores(
        name=name or manifest.get("run") or d.name,
        path=str(d),
        profile=profile,
        layout=layout,
        sequences=per_seq,
        attributes=attrs,
        summary=summary,
        failures=dict(failures),
        missing=tuple(m for m in missing if m not in failures),
        frequencies=freqs,
        meta=meta,
    )


def evaluate_run(run_dir: Path, sequences: Iterable[Sequence], profile: str = "default") -> RunScores:
    """Score a mata-eval run folder and write ``<run>/scores.json`` atomically."""
    scores = evaluate_results(run_dir, sequences, profile, layout="mata")
    save_scores(run_dir, scores)
    return scores


def save_scores(out_dir: Path, scores: RunScores) -> Path:
    path = Path(out_dir) / SCORES
    results.write_json(path, scores.to_dict())
    return path


def load_scores(run_dir: Path) -> RunScores:
    """Read ``<run>/scores.json`` (or a scores file given directly)."""
    p = Path(run_dir)
    path = p if p.is_file() else p / SCORES
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no scores file (run `mata-eval eval` or `mata-eval run` first)")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON ({exc})") from None
    return RunScores.from_dict(data, source=str(path))


# --- run folders of an experiment ---------------------------------------------------------


class ScoresUnavailable(RuntimeError):
    """A run folder has no scores.json and cannot be evaluated from here."""


def scores_for(run_dir: Path) -> RunScores:
    """``<run>/scores.json``, evaluating the run first when it is a mata-eval run folder whose
    experiment file can still be loaded; otherwise :class:`ScoresUnavailable` says what to do."""
    d = Path(run_dir).resolve()
    if not d.exists():
        raise FileNotFoundError(f"{run_dir}: no such file or folder")
    if d.is_file() or (d / SCORES).is_file():
        return load_scores(d)
    manifest = results.read_manifest(d)
    hint = (f"run `mata-eval eval {d} --dataset NAME --root PATH` to score it")
    if manifest is None:
        raise ScoresUnavailable(f"{d}: no {SCORES} and no manifest.json (not a mata-eval run folder); {hint}")
    exp_file = manifest.get("experiment_file")
    if not exp_file or not Path(exp_file).is_file():
        raise ScoresUnavailable(f"{d}: no {SCORES}, and the experiment file {exp_file!r} named in its "
                                f"manifest cannot be read; {hint}")
    from ..run.config import load_experiment
    from ..run.runner import load_sequences

    with results.in_run_cwd(manifest):   # its relative dataset root, not this folder's namesake
        exp = load_experiment(exp_file)
        spec = next((r for r in exp.runs if r.name == manifest.get("run")), None)
        if spec is None:
            raise ScoresUnavailable(f"{d}: no {SCORES}, and run {manifest.get('run')!r} is no longer in {exp_file}; {hint}")
        if spec.config_hash != manifest.get("config_hash"):
            raise ScoresUnavailable(f"{d}: no {SCORES}, and {exp_file} now describes run {spec.name!r} differently "
                                    f"(config hash changed); {hint}")
        return evaluate_run(d, load_sequences(spec), spec.metrics_profile)


def evaluate_experiment(exp: Experiment, only: list[str] | None = None) -> list[RunScores]:
    """Score every run folder (writes ``scores.json`` in each) and return the run scores."""
    from ..run.runner import load_sequences, run_dir

    scores = []
    for spec in exp.runs:
        if only and spec.name not in only:
            continue
        scores.append(evaluate_run(run_dir(exp, spec), load_sequences(spec), spec.metrics_profile))
    return scores
