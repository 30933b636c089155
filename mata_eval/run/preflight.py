"""Preflight: what an experiment needs, checked before anything runs (``mata-eval validate``,
and ``mata-eval run`` before its first sequence): dataset roots, sequences and their frames,
model files, inference backends, and each plugin's own optional ``check()``.

Each distinct plugin block is checked once, however many runs share it; every problem is one
line naming the block, the runs it stops and what to do. Runs marked ``optional`` in the
experiment file (their matrix label is listed under ``optional:``) are skipped instead."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Iterable

from ..data.datasets.annotations import (IMAGE_EXTENSIONS, OTHER_IMAGE_EXTENSIONS, DatasetError, MissingFrames,
                                         UnusableFrames)
from .config import Experiment, PluginBlock, RunSpec
from .results import sequence_name_problem

BLOCK_KEYS = ("dataset", "tracker", "egomotion", "estimator", "protocol")


@dataclass(frozen=True)
class Problem:
    """Something that stops runs: the block (``"tracker vittrack"``), the runs it stops and a
    one-line message saying what is wrong and what to do."""

    block: str
    runs: tuple[str, ...]
    message: str
    error: BaseException | None = field(default=None, compare=False, repr=False)  # for --debug


@dataclass(frozen=True)
class Plan:
    """The runs that can go, the optional runs skipped (with the problem that skips them), the
    problems that stop the experiment (one line each) and the exceptions behind them."""

    runs: tuple[RunSpec, ...]
    skipped: tuple[tuple[RunSpec, Problem], ...]
    problems: tuple[str, ...]
    errors: tuple[BaseException, ...] = ()
    warnings: tuple[str, ...] = ()   # what a dataset says of what it leaves out (its optional warnings())


def _one_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def check_dataset(block: PluginBlock, only: Iterable[str] | None = None) -> BaseException | None:
    """The dataset's sequences load (annotations) and each (of ``only``, the names ``--sequences``
    selects) has its frames on disk, fitting its annotations. A dataset plugin may instead
    provide ``check()`` (the synthetic suite: generated on first use)."""
    try:
        dataset = block.create()
        if hasattr(dataset, "check"):
            dataset.check()
            return None
        sequences = dataset.sequences()
    except Exception as exc:  # any failure is the problem to report
        return exc
    if not sequences:
        return DatasetError("no sequences found")
    if only:
        sequences = [s for s in sequences if s.name in set(only)]
    unusable = [s.loader.reason for s in sequences if isinstance(s.loader, UnusableFrames)]
    if unusable:
        return DatasetError(f"{len(unusable)} of {len(sequences)} sequences cannot run: "
                            + "; ".join(unusable[:3]) + (f"; and {len(unusable) - 3} more" if len(unusable) > 3 else "")
                            + " (fix them, or leave them out with --sequences)")
    bad = [s.name for s in sequences if isinstance(s.loader, MissingFrames)
           or (s.loader is None and not (s.frame_paths and os.path.isfile(s.frame_paths[0])
                                         and os.path.isfile(s.frame_paths[-1])))]
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        where = next((s.loader.looked_in for s in sequences if isinstance(s.loader, MissingFrames)), None)
        first = next((s.frame_paths[0] for s in sequences if s.name == bad[0] and s.frame_paths), None)
        types = f"; frames are {', '.join(IMAGE_EXTENSIONS + OTHER_IMAGE_EXTENSIONS)} files"   # (a listed folder's)
        hint = f" (looked in {' or '.join(where)}{types})" if where else f" (looked for {first})" if first else ""
        return DatasetError(f"{len(bad)} of {len(sequences)} sequences have no frames: {shown}{hint}")
    misnamed = [why for s in sequences if (why := sequence_name_problem(s.name))]
    if misnamed:
        return DatasetError(f"{len(misnamed)} of {len(sequences)} sequences cannot name their result files: "
                            f"{misnamed[0]}" + (f" (and {len(misnamed) - 1} more)" if len(misnamed) > 1 else ""))
    no_start = [s.name for s in sequences if not s.init_box.is_valid]
    if no_start:
        shown = ", ".join(no_start[:5]) + (f" and {len(no_start) - 5} more" if len(no_start) > 5 else "")
        return DatasetError(f"{len(no_start)} of {len(sequences)} sequences have no target box in frame 0 to "
                            f"start the tracker from (first ground-truth line absent, NaN or of zero size): {shown}")
    return None


def check_block(block: PluginBlock) -> BaseException | None:
    """The plugin can be built here (model files found) and its optional ``check()`` passes
    (e.g. an ONNX tracker opens its model with the chosen backend)."""
    try:
        with block.instance() as obj:   # closed afterwards, as in a run
            if hasattr(obj, "check"):
                obj.check()
    except Exception as exc:  # any failure is the problem to report
        return exc
    return None


def find_problems(runs: Iterable[RunSpec], sequences: Iterable[str] | None = None) -> list[Problem]:
    """Every problem of ``runs`` (over ``sequences``, default all), each distinct plugin block
    checked once."""
    checked: dict[tuple[str, str], tuple[BaseException | None, list[str]]] = {}
    for spec in runs:
        for key in BLOCK_KEYS:
            block: Any = getattr(spec, key)
            if block is None:
                continue
            ident = (f"{key} {block.name}", json.dumps(spec.resolved[key], sort_keys=True, default=str))
            if ident not in checked:
                checked[ident] = (check_dataset(block, sequences) if key == "dataset" else check_block(block), [])
            checked[ident][1].append(spec.name)
    return [Problem(what, tuple(names), _one_line(error), error)
            for (what, _), (error, names) in checked.items() if error is not None]


#: how the sequences to run are given (``profile`` names its own ``--sequence``)
SEQUENCES_FLAG = "--sequences, or sequences= in Python"


def unknown_sequences_line(unknown: Iterable[str], known: Iterable[str], flag: str = SEQUENCES_FLAG) -> str:
    """The problem of ``--sequences`` (``flag``) names that are in no dataset of the selected runs."""
    return (f"unknown sequence name(s) {', '.join(sorted(unknown))} ({flag}); "
            f"the sequences are: {', '.join(sorted(known))}")


def _unknown_sequences(specs: Iterable[RunSpec], sequences: Iterable[str], flag: str) -> str | None:
    """:func:`unknown_sequences_line` for ``sequences`` outside every dataset of ``specs``, or None.
    A generated dataset (``check()``: built on first use) is asked for its ``sequence_names()``
    (without one, or when a dataset cannot be read, its own problem, nothing is said here: the
    run says it then)."""
    known: set[str] = set()
    for block in _datasets(specs):
        try:
            dataset = block.create()
            if hasattr(dataset, "check"):
                if not hasattr(dataset, "sequence_names"):
                    return None
                known.update(dataset.sequence_names())
            else:
                known.update(s.name for s in dataset.sequences())
        except Exception:
            return None
    unknown = set(sequences) - known
    return unknown_sequences_line(unknown, known, flag) if unknown else None


def _runs_text(names: tuple[str, ...], n_all: int) -> str:
    if len(names) == n_all and n_all > 1:
        return "all runs"
    shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
    return f"run{'s' if len(names) > 1 else ''} {shown}"


def plan(exp: Experiment, only: Iterable[str] | None = None, sequences: Iterable[str] | None = None,
         sequences_flag: str = SEQUENCES_FLAG) -> Plan:
    """Check the selected runs (``only``: run names; default all) over the selected sequences
    (``sequences``: names, given as ``sequences_flag``; default all) and sort them into runs to do,
    optional runs to skip, and problems that stop the experiment."""
    only = list(only or [])
    known = {r.name for r in exp.runs}
    unknown = [n for n in only if n not in known]
    if unknown:
        return Plan((), (), (f"unknown run name(s) {', '.join(unknown)}; runs: {', '.join(sorted(known))}",))
    specs = [r for r in exp.runs if not only or r.name in only]
    if sequences and (line := _unknown_sequences(specs, sequences, sequences_flag)):
        return Plan((), (), (line,))
    problems = find_problems(specs, sequences)
    by_name = {r.name: r for r in specs}
    skipped: dict[str, Problem] = {}
    stopping = []
    for p in problems:
        if all(by_name[n].optional for n in p.runs):
            for n in p.runs:
                skipped.setdefault(n, p)
        else:
            stopping.append(p)
    warned: list[str] = []
    for block in _datasets(specs):
        try:
            warned += getattr(block.create(), "warnings", list)()
        except Exception:   # (a dataset that cannot be read is a problem above)
            pass
    warned += random_weights(specs)
    return Plan(tuple(r for r in specs if r.name not in skipped),
                tuple((by_name[n], p) for n, p in skipped.items()),
                tuple(f"{p.block} ({_runs_text(p.runs, len(specs))}): {p.message}" for p in stopping),
                tuple(p.error for p in stopping if p.error is not None), tuple(dict.fromkeys(warned)))


def random_weights(specs: Iterable[RunSpec]) -> list[str]:
    """A line per tracker of ``specs`` that runs random weights: ``random_weights: true``, or the
    graphs of a ``mata-eval export --random-weights`` (its export.json says so; QA pass 16b: such
    an export ran and scored like a real one without a word). Their scores measure timing and
    plumbing, not tracking."""
    from pathlib import Path

    lines = []
    for spec in specs:
        params, files = spec.tracker.params, getattr(spec.tracker.cls, "model_files", None)
        if getattr(params, "random_weights", False):
            lines.append(f"tracker {spec.tracker.name} (run {spec.name}): random_weights: true, so its scores "
                         "measure timing and plumbing, not tracking")
            continue
        try:
            folders = {Path(p).parent for p in (files(params) if files is not None else {}).values()}
        except (OSError, ValueError):   # (a missing file is the preflight's problem above)
            continue
        for folder in sorted(folders):
            try:
                doc = json.loads((folder / "export.json").read_text())
            except (OSError, ValueError):
                continue
            if isinstance(doc, dict) and doc.get("random_weights_seed") is not None:
                lines.append(f"tracker {spec.tracker.name} (run {spec.name}) reads {folder}, an export of random "
                             f"weights (seed {doc['random_weights_seed']}): its scores measure timing and plumbing, "
                             "not tracking")
    return lines


def _datasets(specs: Iterable[RunSpec]) -> list[PluginBlock]:
    """The distinct dataset blocks of ``specs``."""
    return list({json.dumps(s.resolved["dataset"], sort_keys=True, default=str): s.dataset for s in specs}.values())


def skipped_lines(skipped: Iterable[tuple[RunSpec, Problem]]) -> list[str]:
    """One line per problem that skips optional runs: which runs, and why."""
    grouped: dict[Problem, list[RunSpec]] = {}
    for spec, p in skipped:
        grouped.setdefault(p, []).append(spec)
    lines = []
    for p, specs in grouped.items():
        common = set(specs[0].labels).intersection(*(s.labels for s in specs[1:]))
        label = next((lab for lab in specs[0].labels if lab in common), None)
        which = (f"the {len(specs)} '{label}' run{'s' if len(specs) > 1 else ''}" if label
                 else ", ".join(s.name for s in specs))
        lines.append(f"skipping {which}: {p.block}: {p.message}")
    return lines
