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
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from ..core.sequence import FrameReadError, Sequence
from ..run import results
from ..run.config import Experiment, RunSpec
from . import metrics
from .metrics import Aggregate, BlockFrequency, SequenceScores

SCORES = results.SCORES
LAYOUTS = ("mata", "pysot", "got10k", "pytracking")
SCORES_FORMAT = 1
#: what to do about a scores file that cannot be read
REDO = "delete it (report then scores a run folder again) or score the folder again with `mata-eval eval`"


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
            raise ValueError(f"{source}: not a mata-eval scores file of format {SCORES_FORMAT} (got {got!r}); {REDO}")
        for key in ("name", "path", "profile", "layout"):
            if not isinstance(d.get(key), str):
                raise ValueError(f"{source}: not a mata-eval scores file ({key!r}: expected text, got "
                                 f"{d.get(key)!r}); {REDO}")
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
            raise ValueError(f"{source}: not a mata-eval scores file ({type(exc).__name__}: {exc}); {REDO}") from None


# --- reading results -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SequenceResult:
    """What a results folder holds for one sequence (``error``: why its files cannot be read)."""

    boxes: np.ndarray
    scored: np.ndarray | None = None
    wall_ms: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""
    error: str = ""


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
    first = next((line for line in txts[0].read_text(errors="replace").splitlines() if line.strip()), "")   # (a binary file: named when read)
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
    """All sequence results of a folder as (layout, {sequence: result}); a sequence whose files
    cannot be read has its reason in ``error`` (the others are still read)."""
    d = Path(results_dir)
    layout = detect_layout(d) if layout == "auto" else layout
    if layout not in LAYOUTS:
        raise ValueError(f"unknown results layout {layout!r}; expected auto or one of {', '.join(LAYOUTS)}")
    out: dict[str, SequenceResult] = {}
    if layout == "got10k":
        for sub in sorted(p for p in d.iterdir() if p.is_dir()):
            f = sub / f"{sub.name}_001.txt"
            if f.is_file():
                out[sub.name] = _read_one(f, lambda: SequenceResult(
                    results.read_predictions(f), None, _read_times(sub / f"{sub.name}_time.txt"), str(f)))
        return layout, out
    for f in sorted(d.glob("*.txt")):
        if layout != "mata" and f.name.endswith("_time.txt"):   # timings (a run folder writes none)
            continue
        out[f.stem] = _read_one(f, lambda: _read_sequence(d, f, layout))
    return layout, out


def _read_sequence(d: Path, f: Path, layout: str) -> SequenceResult:
    """The result of the sequence whose prediction file is ``f`` (pysot, pytracking, mata)."""
    scored, wall = None, {}
    if layout == "mata":
        fc = d / f"{f.stem}.frames.csv"
        if fc.is_file():
            scored, wall = read_frames_csv(fc)
    elif layout == "pytracking":
        wall = _read_times(d / f"{f.stem}_time.txt")
    return SequenceResult(results.read_predictions(f), scored, wall, str(f))


def _read_one(f: Path, read: Callable[[], SequenceResult]) -> SequenceResult:
    """``read()``, or a result holding the reason its files cannot be read."""
    try:
        return read()
    except UnicodeDecodeError as exc:   # (a ValueError that names no file)
        return SequenceResult(np.empty((0, 4)), source=str(f), error=f"{f.with_suffix('')}.*: not text ({exc})")
    except ValueError as exc:   # names the file and line
        return SequenceResult(np.empty((0, 4)), source=str(f), error=str(exc))


# --- scoring ---------------------------------------------------------------------------------


def score_results(
    found: Mapping[str, SequenceResult],
    sequences: Iterable[Sequence],
    profile: str = "default",
    groups: Mapping[str, Iterable[str]] | None = None,
    unscorable: dict[str, str] | None = None,
) -> tuple[dict[str, SequenceScores], dict[str, tuple[str, ...]], Aggregate, list[str], dict[str, BlockFrequency]]:
    """Score the results of each sequence against its ground truth (annotations only). A
    sequence whose results cannot be scored (a file that cannot be read, a row count that is
    not the sequence's) raises ValueError naming the file, or, given the dict ``unscorable``,
    is recorded there (sequence -> that message) and left out."""
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
        try:
            per_seq[seq.name] = _score_one(res, seq, profile)
        except ValueError as exc:
            if unscorable is None:
                raise
            unscorable[seq.name] = str(exc)
            continue
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


def _score_one(res: SequenceResult, seq: Sequence, profile: str) -> SequenceScores:
    """The scores of one sequence's results; ValueError naming the file when they cannot be."""
    if res.error:
        raise ValueError(res.error)
    if len(res.boxes) == 0 and len(seq):   # every profile: the got10k one truncated it to nothing
        raise ValueError(f"{res.source}: empty prediction file; sequence {seq.name!r} has {len(seq)} frames")
    if res.scored is not None and len(res.scored) != len(seq):
        raise ValueError(f"{Path(res.source).with_suffix('.frames.csv')}: {len(res.scored)} rows, "
                         f"sequence {seq.name!r} has {len(seq)} frames (its ground truth, or the frames, "
                         f"changed since the run)")
    try:
        return metrics.score_sequence(res.boxes, seq.groundtruth, profile=profile, scored=res.scored,
                                      annotated=seq.annotated)
    except ValueError as exc:
        raise ValueError(f"{res.source}: {exc}{_blank_lines_note(res.source)}") from None


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
    dataset: str | None = None,
) -> RunScores:
    """Score any results folder (no file is written). Sequences without results are listed in
    ``missing``; failed sequences of a mata run folder in ``failures``. ``dataset``: the name
    of the dataset plugin that loaded ``sequences`` (recorded in ``meta``; default: the one a
    mata run folder's manifest names)."""
    d = Path(results_dir)
    metrics.get_profile(profile)  # fail early on a bad name
    sequences = list(sequences)
    layout, found = read_results(d, layout)
    failures = results.read_failures(d) if layout == "mata" else {}
    unscorable: dict[str, str] = {}
    per_seq, attrs, summary, missing, freqs = score_results(found, sequences, profile, groups, unscorable)
    manifest = (results.read_manifest(d) or {}) if layout == "mata" else {}
    if manifest.get("experiment_file"):   # what recomputes the sequence, in this folder (-o: copied or moved)
        run = manifest.get("run")
        # a folder named otherwise: the run writes <-o>/<run>, and a rename beside it may collide
        moved = d.resolve().name != run
        again = (f"mata-eval run {shlex.quote(manifest['experiment_file'])} "
                 f"-o {'DIR' if moved else shlex.quote(str(d.resolve().parent))} --runs {run} --force --sequences")
        move = f"move this folder into an empty folder DIR as DIR/{run} (the run writes there), then " if moved else ""
        unscorable = {k: f"{why}; to run it again: {move}{again} {k}" for k, why in unscorable.items()}
    run_dataset = (manifest.get("config") or {}).get("dataset")
    scored = [s for s in sequences if s.name in per_seq]
    meta = {
        "experiment": manifest.get("experiment"),
        "config_hash": manifest.get("config_hash"),
        "dataset": dataset or (run_dataset.get("name") if isinstance(run_dataset, dict) else None),
        "unmatched_results": sorted(set(found) - {s.name for s in sequences}),
        # got10k layout: sequences with more repetitions than the first, the one scored
        "repetitions_left": sorted(k for k in per_seq if (d / k / f"{k}_002.txt").is_file()) if layout == "got10k"
        else [],
        "unscorable": unscorable,   # sequence -> why its results cannot be scored (counted as failed)
        # result files of another length than their sequence, which the profile cut or padded
        # (got10k, pytracking; the default profile refuses them): sequence -> [lines, frames]
        "length_fitted": {s.name: [len(found[s.name].boxes), len(s)] for s in scored
                          if len(found[s.name].boxes) != len(s)},
        "bad_frames": {k: v for k, v in results.read_bad_frames(d).items() if k in per_seq} if layout == "mata" else {},
        # what a report compares: the ground truth of each sequence scored or found unscorable (an
        # annotation file fixed later makes the unscorable one scorable)
        "groundtruth": {s.name: results.groundtruth_sha256(s) for s in sequences
                        if s.name in per_seq or s.name in unscorable},
        # the result files scored (a report scores the run again when one was edited since)
        "results_sha256": {k: results.results_sha256(d, k) for k in list(per_seq) + list(unscorable)
                           if (d / f"{k}.txt").is_file()} if layout == "mata" else {},
        "frequency_rule": FREQUENCY_RULE,   # (scores.json of an older rule are scored again: scores_for)
        # what the run warned of when it ran (random weights, a profile of other blocks, off-grid rates)
        "run_warnings": list(manifest.get("warnings") or []),
        # packages whose version differs among the setups that made the scored results (a resume after an upgrade)
        "mixed_versions": results.mixed_versions(manifest, per_seq),
        # sequences whose tracker results were made on other ground truth (the manifest's record)
        "other_groundtruth": results.changed_run_inputs(
            manifest.get("groundtruth"), scored, (manifest.get("config") or {}).get("occlusion") is not None),
    }
    return RunScores(
        name=name or manifest.get("run") or d.name,
        path=str(d),
        profile=profile,
        layout=layout,
        sequences=per_seq,
        attributes=attrs,
        summary=summary,
        failures={**failures, **{k: f"cannot be scored: {why}" for k, why in unscorable.items()}},
        missing=tuple(m for m in missing if m not in failures),
        frequencies=freqs,
        meta=meta,
    )


BEING_WRITTEN = ("a mata-eval run is writing this folder: scored its sequences finished so far, "
                 f"{SCORES} not written")


def evaluate_run(run_dir: Path, sequences: Iterable[Sequence], profile: str = "default",
                 save: bool = True, dataset: str | None = None) -> RunScores:
    """Score a mata-eval run folder and (``save``) write ``<run>/scores.json`` atomically, unless
    a run is writing the folder: its scores are then of the sequences finished so far, not
    written, and ``meta["unsaved"]`` says why. ``dataset``: the plugin that loaded
    ``sequences`` (default: the run's own, from its manifest)."""
    from ..run.runner import being_written

    busy = being_written(run_dir)
    scores = evaluate_results(run_dir, sequences, profile, layout="mata", dataset=dataset)
    if busy or being_written(run_dir):
        return dataclasses.replace(scores, meta={**scores.meta, "unsaved": BEING_WRITTEN})
    if save:
        try:
            save_scores(run_dir, scores)
        except OSError as exc:   # disk full, read-only: the table is still printed (was a bare Errno, no table)
            return dataclasses.replace(scores, meta={**scores.meta, "unsaved": (
                f"cannot write {Path(run_dir) / SCORES}: {exc.strerror or exc}; the table above is not saved "
                "(free space or make the folder writable, then `mata-eval report` this folder)")})
    return scores


#: how the block rates of a scores.json were computed (metrics.frequencies): an older mata-eval
#: counted frame 0, the initialisation (10.5 Hz for 10 Hz on 40 frames)
FREQUENCY_RULE = "from frame 1"


def stale_reason(scores: RunScores, run_dir: Path) -> str | None:
    """Why the scores read from a run folder's scores.json no longer describe its results
    (sequences finished or failed after they were written: a report made while a run was
    writing the folder; a result file edited, truncated or copied over since), or None."""
    d = Path(run_dir)
    finished = {p.stem for p in d.glob("*.txt")}
    unscorable = set(scores.meta.get("unscorable") or ())
    scored = set(scores.sequences) | set(scores.meta.get("unmatched_results") or ()) | unscorable
    if finished != scored:
        return f"it scores {len(scored)} sequence(s), the folder has {len(finished)} finished"
    failed = set(results.read_failures(d))
    if failed != set(scores.failures) - unscorable:
        return f"it lists {len(set(scores.failures) - unscorable)} failed sequence(s), the folder {len(failed)}"
    recorded = scores.meta.get("results_sha256") or {}   # (none: an older mata-eval; not compared)
    edited = [k for k, sha in recorded.items() if k in finished and results.results_sha256(d, k) != sha]
    if edited:
        return f"the result files of {', '.join(edited[:5])}{' ...' if len(edited) > 5 else ''} changed since"
    return None


def older_rates(scores: RunScores) -> bool:
    """Whether the block rates of ``scores`` count frame 0, as a mata-eval before FREQUENCY_RULE did."""
    return bool(scores.frequencies) and scores.meta.get("frequency_rule") != FREQUENCY_RULE


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
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: invalid JSON ({exc}); {REDO}") from None
    scores = RunScores.from_dict(data, source=str(path))
    if (path.parent / results.MANIFEST).is_file():   # a run folder copied or moved: its own path, not
        # the one saved (the reports read the configuration there: a copy showed the original's tracker)
        scores = dataclasses.replace(scores, path=str(path.parent.resolve()))
    return scores


# --- run folders of an experiment ---------------------------------------------------------


class ScoresUnavailable(RuntimeError):
    """A run folder has no scores.json and cannot be evaluated from here."""


def _to_stderr(message: str) -> None:
    print(message, file=sys.stderr)   # (not into a table written to stdout: report --format csv > file)


def scores_for(run_dir: Path, log: Callable[[str], None] = _to_stderr) -> RunScores:
    """``<run>/scores.json``, evaluating the run first when it is a mata-eval run folder whose
    experiment file can still be loaded and it has no scores.json, one that does not cover its
    finished and failed sequences (:func:`stale_reason`), or one scored on ground truth the
    dataset no longer has or on other sequences than its experiment lists now
    (:func:`changed_since_scored`; ``log`` says so); otherwise :class:`ScoresUnavailable` says
    what to do. A scores.json whose only fault is rates of an older rule (:func:`older_rates`)
    is scored again where it can be, else shown as it is (a copied folder: the table notes it)."""
    d = Path(run_dir).resolve()
    if not d.exists():
        raise FileNotFoundError(f"{run_dir}: no such file or folder")
    if d.is_file():
        return load_scores(d)
    manifest = results.read_manifest(d)
    stale = None
    changed: list[str] = []
    if (d / SCORES).is_file():
        scores = load_scores(d)
        stale = stale_reason(scores, d) if manifest is not None else None
        if stale is None and manifest is not None:
            changed, stale = changed_since_scored(scores, d, manifest)
        if stale is None and not changed:
            if manifest is None or not older_rates(scores):
                return scores
            try:
                again = _score_again(d, manifest, "", "", render=False)
            except Exception as exc:   # (a copied folder, its data not here: QA review, the report failed)
                log(f"{d}: its block rates (Hz) count frame 0, as an older mata-eval did; not scored again here "
                    f"({str(exc).strip().rstrip(';') or type(exc).__name__}); the numbers are as they were")
                return scores
            log(f"{d}: scored again: its {SCORES} counted frame 0 in its block rates, as an older mata-eval did")
            return again
        if stale and stale.startswith(("the result files", "the sequences of its experiment")):
            log(f"{d}: scored again: {stale} its {SCORES} was written")
        if changed:
            log(f"{d}: scored again against the experiment's annotations: those of {', '.join(changed[:5])}"
                f"{' ...' if len(changed) > 5 else ''} differ from the ones its {SCORES} was scored on")
    hint = (f"run `mata-eval eval {d} --dataset NAME --root PATH` to score it")
    if manifest is None and any(d.glob(f"*/{results.MANIFEST}")):   # an experiment's output folder
        raise ScoresUnavailable(f"{d}: no {SCORES} and no manifest.json: it holds run folders; report them "
                                f"(`mata-eval report {d}/*`, or `--experiment EXP.yaml`)")
    if manifest is None:   # another toolkit's results: eval keeps no scores.json there unless told where
        raise ScoresUnavailable(f"{d}: no {SCORES} and no manifest.json (not a mata-eval run folder); run `mata-eval "
                                f"eval {d} --dataset NAME --root PATH` to score it (with --output DIR, then "
                                f"`mata-eval report DIR` reports it again)")
    what = (f"its {SCORES} is out of date ({stale or 'the annotations of ' + ', '.join(changed[:5]) + ' differ'})"
            if stale or changed else f"no {SCORES}")
    return _score_again(d, manifest, what, hint)


def _score_again(d: Path, manifest: dict, what: str, hint: str, render: bool = True) -> RunScores:
    """Evaluate the run folder ``d`` on its experiment's dataset (:class:`ScoresUnavailable`,
    starting with ``what``, when that cannot be done here; ``render=False``: nor when the
    dataset is generated, a plugin with ``check()``: not rendered for block rates alone)."""
    from ..run.runner import load_sequences

    lead = f"{d}: {what}, and" if what else ""   # (none: the caller says what was tried)
    with results.in_run_cwd(manifest):   # its relative dataset root, not this folder's namesake
        spec = _run_spec(d, manifest, lead, hint)
        if not render and hasattr(spec.dataset.cls, "check"):
            raise ScoresUnavailable("its dataset is generated, and not rendered again for the rates alone")
        try:
            return evaluate_run(d, load_sequences(spec), spec.metrics_profile)
        except FrameReadError as exc:   # the occlusion augmentation reads frame 0: frames not on this machine
            raise ScoresUnavailable(f"{lead} it cannot be scored here: {exc}".strip()) from None


def _run_spec(d: Path, manifest: dict, what: str, hint: str) -> RunSpec:
    """The run of the experiment file its manifest names, as it ran (same configuration hash);
    :class:`ScoresUnavailable` (``what``: its start) when the file, the run or its configuration
    is not that one any more. Relative paths: inside :func:`results.in_run_cwd`."""
    from ..run.config import load_experiment

    exp_file = manifest.get("experiment_file")
    if not exp_file or not Path(exp_file).is_file():
        raise ScoresUnavailable(f"{what} the experiment file {exp_file!r} named in its manifest cannot be read; {hint}")
    exp = load_experiment(exp_file)
    spec = next((r for r in exp.runs if r.name == manifest.get("run")), None)
    if spec is None:
        raise ScoresUnavailable(f"{what} run {manifest.get('run')!r} is no longer in {exp_file}; {hint}")
    if not spec.made(manifest):
        raise ScoresUnavailable(f"{what} {exp_file} now describes run {spec.name!r} differently "
                                f"(config hash changed); {hint}")
    return spec


def changed_since_scored(scores: RunScores, run_dir: Path, manifest: dict) -> tuple[list[str], str | None]:
    """What the experiment file says now that the run's scores.json does not reflect: (the
    sequences whose ground truth, its sha256 in ``meta["groundtruth"]``, differs from their
    annotations now, read once per dataset and process; why the sequences the experiment lists
    for the run are not those scored, or None). Nothing when the experiment or its dataset
    cannot be read (a copied folder): the scores are trusted then. The ground truth is not
    compared where the scores have no record (an older mata-eval) or the dataset is generated
    (a plugin with ``check()``, the synthetic suite: reading it would build it, and no one
    edits it by hand)."""
    from ..run.tasks import base_sequences

    try:
        with results.in_run_cwd(manifest):
            spec = _run_spec(Path(run_dir), manifest, "", "")
            generated = hasattr(spec.dataset.cls, "check")
            # the sequences listed now (not in the config hash: run.config.without_selection)
            listed = spec.resolved["dataset"].get("sequences")
            names = set(listed) if listed is not None else None if generated else \
                {s.name for s in base_sequences(spec)}
            scored = set(scores.sequences) | set(scores.missing)   # (a failure of a sequence left out stays)
            reselected = ("the sequences of its experiment's dataset changed since" if names is not None and (
                names - scored - set(scores.failures) or scored - names) else None)
            if not scores.meta.get("groundtruth") or generated:
                return [], reselected
            return results.changed_groundtruth(scores.meta["groundtruth"], base_sequences(spec)), reselected
    except Exception:   # whatever a dataset plugin raises: this check only adds to what scores.json says
        return [], None


def evaluate_experiment(exp: Experiment, only: list[str] | None = None) -> list[RunScores]:
    """Score every run folder (writes ``scores.json`` in each) and return the run scores."""
    from ..run.runner import load_sequences, run_dir

    scores = []
    for spec in exp.runs:
        if only and spec.name not in only:
            continue
        scores.append(evaluate_run(run_dir(exp, spec), load_sequences(spec), spec.metrics_profile))
    return scores
