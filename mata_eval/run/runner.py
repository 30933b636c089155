"""Run an experiment: every (run, sequence) pair through the scheduler, on an executor
(:mod:`mata_eval.run.executors`: local worker processes or a Ray cluster).

A sequence that fails (unreadable frames, a tracker that raises or returns NaN) is recorded in
``<seq>.failed.json`` and the others go on; finished sequences are skipped on a rerun unless
``force``; every file is written atomically, so an interrupted run loses nothing finished."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Callable

from tqdm import tqdm

from ..core.sequence import Sequence
from . import results
from .config import Experiment, RunSpec
from .executors import Executor, LocalExecutor
from .tasks import SequenceResult, Task, as_run_sees_it, base_sequences, make_tasks, plan


class ResultsConflict(RuntimeError):
    """The run folder holds results of a different configuration."""


@dataclasses.dataclass(frozen=True)
class SequenceOutcome:
    run: str
    sequence: str
    status: str  # "done", "skipped" (already finished) or "failed"
    reason: str = ""


_SEQUENCES: dict[str, list[Sequence]] = {}


def load_sequences(spec: RunSpec) -> list[Sequence]:
    """The run's sequences (annotations, lazily loaded frames), with the occlusion augmentation
    applied on the fly when the experiment asks for it. Cached per process."""
    key = json.dumps([spec.resolved["dataset"], spec.resolved["occlusion"], spec.seed], sort_keys=True, default=str)
    if key not in _SEQUENCES:
        _SEQUENCES[key] = [as_run_sees_it(s, spec) for s in base_sequences(spec)]
    return _SEQUENCES[key]


def run_dir(exp: Experiment, spec: RunSpec) -> Path:
    return exp.output / spec.name


def prepare_run_dir(exp: Experiment, spec: RunSpec, force: bool) -> Path:
    """Create the run folder and its manifest; refuse to mix results of another configuration."""
    out = run_dir(exp, spec)
    old = results.read_manifest(out)
    if old is not None and old.get("config_hash") != spec.config_hash and not force:
        raise ResultsConflict(
            f"{out} holds results of a different configuration (config hash {old.get('config_hash')} "
            f"!= {spec.config_hash}); rerun with --force to replace them, or change `output` in {exp.path}")
    results.write_manifest(out, {
        "experiment": exp.name,
        "experiment_file": str(exp.path),
        "run": spec.name,
        "config": spec.resolved,
        "config_hash": spec.config_hash,
        "seed": spec.seed,
        "sequence_seeds": "numpy.random.default_rng([seed, crc32(sequence name)])",
        "metric_profile": spec.metrics_profile,
        "versions": results.package_versions(),
        "git_commit": results.git_commit(),
        "machine": results.machine(),
    })
    return out


def write_result(out: Path, r: SequenceResult) -> SequenceOutcome:
    """Write one returned result into its run folder (atomically, predictions last)."""
    try:
        if r.reason:
            results.write_failure(out, r.sequence, r.reason, r.traceback)
        else:
            results.write_sequence(out, r.sequence, r.boxes, r.frames_csv, r.trace_csv)
    except OSError as exc:  # e.g. disk full: this sequence is lost, the others go on
        return SequenceOutcome(r.run, r.sequence, "failed", f"cannot write its results: {exc}")
    return SequenceOutcome(r.run, r.sequence, "failed" if r.reason else "done", r.reason)


def run_experiment(
    exp: Experiment,
    *,
    jobs: int | None = None,
    force: bool = False,
    only: list[str] | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    executor: Executor | None = None,
) -> list[SequenceOutcome]:
    """Run every selected run of ``exp`` over its dataset. Returns one outcome per sequence.

    The pending (run, sequence) pairs become tasks, one per sequence with every run that reads
    it (each frame decoded once for all, :mod:`mata_eval.run.tasks`), longest first, on
    ``executor`` (default: a local pool of ``jobs`` processes). The executor hands results
    back and this process writes every file: one writer per run folder, on any executor."""
    specs = [r for r in exp.runs if not only or r.name in only]
    if only and len(specs) != len(set(only)):
        known = ", ".join(r.name for r in exp.runs)
        raise KeyError(f"unknown run name(s) {sorted(set(only) - {r.name for r in specs})}; runs: {known}")
    outcomes: list[SequenceOutcome] = []
    pending: list[tuple[RunSpec, int, Sequence]] = []
    for spec in specs:
        out = prepare_run_dir(exp, spec, force)
        for i, seq in enumerate(load_sequences(spec)):
            if force:
                results.clear_sequence(out, seq.name)
            if results.is_finished(out, seq.name):
                outcomes.append(SequenceOutcome(spec.name, seq.name, "skipped"))
            else:
                pending.append((spec, i, seq))
    if outcomes:
        log(f"{len(outcomes)} finished sequence(s) kept from an earlier run (use --force to redo them)")

    by_name = {spec.name: spec for spec in specs}
    bar = tqdm(total=len(pending), desc=exp.name, unit="seq", disable=not progress or not pending)

    def done(task: Task, task_results: list[SequenceResult]) -> None:
        for r in task_results:
            outcomes.append(write_result(run_dir(exp, by_name[r.run]), r))
            bar.set_postfix_str(f"{r.run}/{r.sequence}")
            bar.update()

    try:
        with executor or LocalExecutor(jobs) as ex:
            ex.run(exp, plan(make_tasks(pending), ex.workers), done)
    finally:
        bar.close()
    for o in outcomes:
        if o.status == "failed":
            log(f"FAILED {o.run}/{o.sequence}: {o.reason}")
    return outcomes
