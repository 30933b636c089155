"""Run an experiment: every (run, sequence) pair through the scheduler, in worker processes.

A sequence that fails (unreadable frames, a tracker that raises or returns NaN) is recorded in
``<seq>.failed.json`` and the others go on; finished sequences are skipped on a rerun unless
``force``; every file is written atomically, so an interrupted run loses nothing finished."""

from __future__ import annotations

import dataclasses
import json
import os
import traceback
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Callable

import numpy as np
from tqdm import tqdm

from . import results
from .config import Experiment, PluginBlock, RunSpec, load_experiment
from ..core.sequence import Sequence


class ResultsConflict(RuntimeError):
    """The run folder holds results of a different configuration."""


@dataclasses.dataclass(frozen=True)
class SequenceOutcome:
    run: str
    sequence: str
    status: str  # "done", "skipped" (already finished) or "failed"
    reason: str = ""


def default_jobs() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def sequence_seed(seed: int, name: str) -> np.random.Generator:
    """Per-sequence generator from (experiment seed, sequence name): results do not depend on
    the order or the process in which sequences run."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


_SEQUENCES: dict[str, list[Sequence]] = {}


def load_sequences(spec: RunSpec) -> list[Sequence]:
    """The run's sequences (annotations, lazily loaded frames), with the occlusion augmentation
    applied on the fly when the experiment asks for it. Cached per process."""
    key = json.dumps([spec.resolved["dataset"], spec.resolved["occlusion"], spec.seed], sort_keys=True, default=str)
    if key not in _SEQUENCES:
        seqs = list(spec.dataset.create().sequences())
        if spec.occlusion is not None:
            from ..data.occlusion import augment_sequence

            seqs = [augment_sequence(s, spec.occlusion, spec.seed) for s in seqs]
        _SEQUENCES[key] = seqs
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


def _create(block: PluginBlock | None) -> Any:
    return None if block is None else block.create()


def run_one(exp: Experiment, spec: RunSpec, seq: Sequence) -> SequenceOutcome:
    """Run one sequence and write its files; any failure is recorded, never raised."""
    from .scheduler import run_sequence

    out = run_dir(exp, spec)
    try:
        protocol = spec.protocol.create()
        rng = sequence_seed(spec.seed, seq.name)
        with spec.tracker.instance() as tracker:
            blocks = (tracker, _create(spec.egomotion), _create(spec.estimator))
            if hasattr(protocol, "run_sequence"):  # a protocol that runs the blocks itself (live)
                run = protocol.run_sequence(seq, *blocks, rng, feedback=spec.feedback)
            else:  # a timing preset of the camera-clock scheduler
                run = run_sequence(seq, *blocks, protocol, rng, feedback=spec.feedback)
        results.write_sequence(out, seq.name, run.boxes, run.frames_csv(), run.trace_csv())
    except Exception as exc:  # one sequence must never take the others down
        reason = f"{type(exc).__name__}: {exc}"
        results.write_failure(out, seq.name, reason, traceback.format_exc())
        return SequenceOutcome(spec.name, seq.name, "failed", reason)
    return SequenceOutcome(spec.name, seq.name, "done")


# --- worker processes -------------------------------------------------------------------------

_WORKER_EXP: Experiment | None = None


def _init_worker(exp_path: str, cwd: str, output: str) -> None:
    global _WORKER_EXP
    os.chdir(cwd)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"  # one sequence per core: no oversubscription
    import cv2

    cv2.setNumThreads(1)
    exp = load_experiment(exp_path)
    _WORKER_EXP = dataclasses.replace(exp, output=Path(output))  # e.g. `mata-eval run -o DIR`


def _worker_task(run_name: str, index: int) -> SequenceOutcome:
    assert _WORKER_EXP is not None
    spec = next(r for r in _WORKER_EXP.runs if r.name == run_name)
    return run_one(_WORKER_EXP, spec, load_sequences(spec)[index])


# --- driver -----------------------------------------------------------------------------------

def _run_pool(exp: Experiment, tasks: list, jobs: int,
              done: Callable[[SequenceOutcome], None]) -> list:
    """Run ``tasks`` in ``jobs`` worker processes; returns the tasks lost to a broken pool."""
    lost = []
    with ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker,
                             initargs=(str(exp.path), os.getcwd(), str(exp.output))) as pool:
        futures = {pool.submit(_worker_task, spec.name, i): (spec, i, seq) for spec, i, seq in tasks}
        for fut in as_completed(futures):
            try:
                done(fut.result())
            except BrokenProcessPool:
                lost.append(futures[fut])
    return lost


def run_experiment(
    exp: Experiment,
    *,
    jobs: int | None = None,
    force: bool = False,
    only: list[str] | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> list[SequenceOutcome]:
    """Run every selected run of ``exp`` over its dataset. Returns one outcome per sequence."""
    specs = [r for r in exp.runs if not only or r.name in only]
    if only and len(specs) != len(set(only)):
        known = ", ".join(r.name for r in exp.runs)
        raise KeyError(f"unknown run name(s) {sorted(set(only) - {r.name for r in specs})}; runs: {known}")
    outcomes: list[SequenceOutcome] = []
    tasks: list[tuple[RunSpec, int, Sequence]] = []
    for spec in specs:
        out = prepare_run_dir(exp, spec, force)
        for i, seq in enumerate(load_sequences(spec)):
            if force:
                results.clear_sequence(out, seq.name)
            if results.is_finished(out, seq.name):
                outcomes.append(SequenceOutcome(spec.name, seq.name, "skipped"))
            else:
                tasks.append((spec, i, seq))
    if outcomes:
        log(f"{len(outcomes)} finished sequence(s) kept from an earlier run (use --force to redo them)")

    jobs = jobs or default_jobs()
    bar = tqdm(total=len(tasks), desc=exp.name, unit="seq", disable=not progress or not tasks)

    def done(outcome: SequenceOutcome) -> None:
        outcomes.append(outcome)
        bar.set_postfix_str(f"{outcome.run}/{outcome.sequence}")
        bar.update()

    try:
        if jobs == 1 or len(tasks) <= 1:
            for spec, _, seq in tasks:
                done(run_one(exp, spec, seq))
        else:
            # A worker killed by the OS (out of memory, a crash in native code) breaks the pool
            # and every task in flight with it: rerun those one process each, which finds the
            # sequence that kills its process and records it as failed; the others complete.
            for spec, i, seq in _run_pool(exp, tasks, jobs, done):
                if _run_pool(exp, [(spec, i, seq)], 1, done):
                    reason = ("worker process died while running this sequence (killed by the "
                              "operating system, e.g. out of memory, or a crash in native code)")
                    results.write_failure(run_dir(exp, spec), seq.name, reason, "")
                    done(SequenceOutcome(spec.name, seq.name, "failed", reason))
    finally:
        bar.close()
    for o in outcomes:
        if o.status == "failed":
            log(f"FAILED {o.run}/{o.sequence}: {o.reason}")
    return outcomes
