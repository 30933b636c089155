"""Run an experiment: every (run, sequence) pair through the scheduler, on an executor
(:mod:`mata_eval.run.executors`: local worker processes or a Ray cluster).

A sequence that fails (unreadable frames, a tracker that raises, returns NaN or does not return
within ``timeout_s``) is recorded in ``<seq>.failed.json`` and the others go on; finished
sequences are skipped on a rerun unless ``force``; every file is written atomically, so an
interrupted run loses nothing finished. A lock file in each run folder keeps a second run from
writing into it; SIGINT / SIGTERM stop the run within seconds (docs/reliability.md)."""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator

import filelock
from tqdm import tqdm

from ..core.errors import Interrupted, UserError
from ..core.sequence import Sequence
from . import results
from .config import Experiment, PluginBlock, RunSpec, config_change, without_selection
from .executors import Executor, LocalExecutor
from .preflight import random_weights, unknown_sequences_line
from .scheduler import RateWarning
from .stop import stop_on_signals
from .tasks import SequenceResult, Task, as_run_sees_it, base_sequences, make_tasks, plan


class ResultsConflict(UserError):
    """The run folder holds results of a different configuration."""


class RunLocked(UserError):
    """Another mata-eval run is writing into the run folder."""


class CannotWrite(UserError):
    """A result cannot be written into its run folder (disk full, read-only, the folder deleted
    during the run): the run stops at once instead of computing results it cannot keep."""


LOCK = ".lock"
#: errors on writing a result that every later result would hit too: they stop the run
FOLDER_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.ENOENT})


@dataclasses.dataclass(frozen=True)
class SequenceOutcome:
    run: str
    sequence: str
    status: str  # "done", "skipped" (already finished) or "failed"
    reason: str = ""
    bad_frames: tuple[int, ...] = ()  # frames excluded from scoring (on_bad_frame: skip)


_SEQUENCES: dict[str, list[Sequence]] = {}


def load_sequences(spec: RunSpec) -> list[Sequence]:
    """The run's sequences (annotations, lazily loaded frames), with the occlusion augmentation
    applied on the fly when the experiment asks for it. Cached per process."""
    # the working folder too: a relative `root` names another dataset in another folder
    key = json.dumps([spec.resolved["dataset"], spec.resolved["occlusion"], spec.seed, os.getcwd()],
                     sort_keys=True, default=str)
    if key not in _SEQUENCES:
        _SEQUENCES[key] = [as_run_sees_it(s, spec) for s in base_sequences(spec)]
    return _SEQUENCES[key]


def run_dir(exp: Experiment, spec: RunSpec) -> Path:
    return results.inside(exp.output, spec.name)


def model_files(spec: RunSpec) -> dict[str, dict[str, str]]:
    """The files the run's tracker and protocol read (their optional ``model_files(params)``:
    weights, a timing profile), each with its sha256: a file's content is not in the
    configuration (nor, found through an environment variable or the shared data, its path), so
    the manifest records what was read. Empty for a block that names none or whose file is
    missing (the preflight says which)."""
    out = {}
    for block in (spec.tracker, spec.protocol):
        files = getattr(block.cls, "model_files", None)
        try:
            paths = files(block.params) if files is not None else {}
            out.update({key: {"path": str(p), "sha256": results.file_sha256(p)} for key, p in paths.items()})
        except (OSError, ValueError):   # e.g. an unreadable export.json
            pass
    return out


def preset_values(spec: RunSpec) -> dict[str, dict[str, Any]]:
    """Per plugin block, the values its preset gives the parameters the experiment leaves unset
    (a ``Params.resolved()``, e.g. homography_ekf's ``preset: mata``): null in the configuration,
    so not in its hash, but what the run used; a preset retuned by an upgrade changes them."""
    out = {}
    for key in ("dataset", "tracker", "egomotion", "estimator", "protocol"):
        block = getattr(spec, key)
        if block is None or not callable(getattr(block.params, "resolved", None)):
            continue
        given, full = dataclasses.asdict(block.params), dataclasses.asdict(block.params.resolved())
        out[key] = {k: v for k, v in full.items() if given.get(k) is None and v is not None}
    return out


def _read_beyond_the_configuration(old: dict, now: dict) -> str | None:
    """What differs between an earlier manifest's record of the run's inputs that its
    configuration does not hold (model files, preset values) and this run's, or None; an
    earlier manifest without the record (older mata-eval) is not compared."""
    before = old.get("model_files") or {}
    for k, f in now["model_files"].items():
        if k in before and before[k].get("sha256") != f["sha256"]:
            sha = f"sha256 {str(before[k].get('sha256'))[:12]}... then, {f['sha256'][:12]}... now"
            if before[k].get("path") == f["path"]:   # the file itself changed (a new export, a copy over it)
                return f"made with another content of its {k} file {f['path']} ({sha})"
            return f"made with another {k} file ({before[k].get('path')}) than {f['path']} ({sha})"
    if "preset_values" in old:
        for block, values in now["preset_values"].items():
            was = old["preset_values"].get(block, {})
            changed = sorted(k for k in set(values) | set(was)     # as JSON: tuples are lists there
                             if json.dumps(values.get(k)) != json.dumps(was.get(k)))
            if changed:
                k = changed[0]
                return (f"made with other preset values of the {block} ({k}: {was.get(k)!r} then, {values.get(k)!r} "
                        f"now{'' if len(changed) == 1 else f'; and {len(changed) - 1} more'})")
    return None


def _change(old: dict, spec: RunSpec) -> str:
    """``<what changed>; `` between an old manifest's configuration and this run's (e.g. a plugin's
    version), or nothing when the old manifest has none."""
    change = (config_change(without_selection(old["config"]), without_selection(spec.resolved))
              if isinstance(old.get("config"), dict) else None)
    return "" if change is None else f"{change}; "


#: what a result made on other ground truth differs by, without and with the occlusion augmentation
RUN_ON_OTHER_GT = ("their tracker started from another box",
                   "their tracker started from another box or the occluders were placed from other boxes")


def to_compute(out: Path, spec: RunSpec, force: bool, only: list[str] | None) -> set[str]:
    """The sequences a run computes: those not finished in its folder ``out``, and with
    ``force`` the finished ones too (of ``only`` if given)."""
    return {s.name for s in load_sequences(spec)
            if not results.is_finished(out, s.name) or (force and (not only or s.name in only))}


def groundtruth_record(exp: Experiment, spec: RunSpec, old: dict | None, computed: set[str],
                       only: list[str] | None = None) -> dict[str, str]:
    """Sequence -> sha256 of what the run reads of its annotations
    (:func:`results.run_input_sha256`: the start box, all boxes with occlusion) for the manifest:
    today's for a sequence this run computes (``computed``: :func:`to_compute`), the recorded
    one for a sequence it keeps (also one absent from the dataset today). Refuses a kept
    sequence of ``only`` whose record differs now, as a changed model file is refused (one
    ``--sequences`` leaves out is not this run's to judge); one made by an older mata-eval (no
    record) is kept without one."""
    out, before = run_dir(exp, spec), (old or {}).get("groundtruth") or {}
    occluded = spec.occlusion is not None
    record, changed = dict(before), []
    for seq in load_sequences(spec):
        if seq.name in computed:
            record[seq.name] = results.run_input_sha256(seq, occluded)
        elif not only or seq.name in only:
            changed += results.changed_run_inputs(before, [seq], occluded)
            if before.get(seq.name) == results.groundtruth_sha256(seq):   # a development record of every
                record[seq.name] = results.run_input_sha256(seq, occluded)  # box, still true: what was read
    if changed:
        raise ResultsConflict(
            f"{out} holds results of {len(changed)} sequence(s) whose ground truth changed since they were made "
            f"({', '.join(changed[:5])}{' ...' if len(changed) > 5 else ''}): {RUN_ON_OTHER_GT[occluded]}; rerun "
            f"with --force --sequences {' '.join(changed)} to redo them, or change `output` in {exp.path}")
    return record


def _inputs(spec: RunSpec) -> dict[str, Any]:
    """What a run reads beyond its configuration, as its manifest records it."""
    return json.loads(json.dumps({"model_files": model_files(spec), "preset_values": preset_values(spec)}))


def _conflict(exp: Experiment, spec: RunSpec, old: dict[str, Any] | None, inputs: dict[str, Any]) -> str | None:
    """Why the run folder (its manifest ``old``) holds results this run may not resume, or None."""
    out = run_dir(exp, spec)
    redo = f"rerun with --force to replace them, or change `output` in {exp.path}"
    if old is None:
        return (f"{out} holds results but no {results.MANIFEST}: they cannot be matched to this configuration; "
                f"delete them, {redo}") if results.holds_results(out) else None
    if not spec.made(old):
        return (f"{out} holds results of a different configuration ({_change(old, spec)}config hash "
                f"{old.get('config_hash')} != {spec.config_hash}); {redo}")
    changed = _read_beyond_the_configuration(old, inputs)
    return None if changed is None else f"{out} holds results {changed}; {redo}"


def refuse_conflicts(exp: Experiment, specs: list[RunSpec]) -> None:
    """Before any sequence is loaded (a synthetic suite rendered for minutes): the runs whose
    folders hold results they may not resume, every one of them in one error, and how to redo
    only those (``--force`` alone redoes every selected run)."""
    refused: list[tuple[str, str]] = []
    for spec in specs:
        try:
            why = _conflict(exp, spec, results.read_manifest(run_dir(exp, spec)), _inputs(spec))
        except results.CorruptFile as exc:
            why = str(exc)
        if why is not None:
            refused.append((spec.name, why))
    if not refused:
        return
    names = " ".join(name for name, _ in refused)
    also = f" ({len(refused) - 1} more run(s) refused: {' '.join(n for n, _ in refused[1:])})" if len(refused) > 1 else ""
    only = f"; `--force --runs {names}` redoes only {'these runs' if len(refused) > 1 else 'this run'}" \
        if len(specs) > len(refused) else ""
    raise ResultsConflict(f"{refused[0][1]}{also}{only}")


def _setup() -> dict[str, Any]:
    """What this process runs with beyond the configuration (versions, MATA_* variables, commit,
    machine), as the manifest records it."""
    return {"versions": results.package_versions(),
            # the variables that choose what runs (e.g. MATA_EVAL_EKF_BACKEND: numba or numpy tick)
            "environment": {k: v for k, v in sorted(os.environ.items()) if k.startswith("MATA_")},
            "git_commit": results.git_commit(), "machine": results.machine()}


def made_by_record(out: Path, old: dict | None) -> dict[str, Any]:
    """The manifest's ``setups`` and ``made_by`` (:func:`results.setup_record`) for the finished
    results a run keeps in its folder ``out``: the recorded setup of each, or for one without a
    record (a folder of an older mata-eval) the setup its manifest ``old`` names. Each result
    the run writes is then credited to its own setup (:func:`results.record_made_by`): a
    ``--force`` rerun stopped half-way leaves the results it did not redo to their makers."""
    old = old or {}
    before, was = results.setup_record(old)
    fallback = results.setup_identity(old)
    made = {p.stem: before[was[p.stem]] if p.stem in was else fallback for p in out.glob("*.txt")}
    setups = []
    for s in before + [fallback]:   # in the order they first ran
        if s in made.values() and s not in setups:
            setups.append(s)
    return {"setups": setups, "made_by": {k: setups.index(s) for k, s in sorted(made.items())}}


def prepare_run_dir(exp: Experiment, spec: RunSpec, force: bool, notes: list[str] = (),
                    only: list[str] | None = None) -> Path:
    """Create the run folder and its manifest (with the protocol's warnings ``notes``); refuse
    to mix results of another configuration, of other model files or preset values, or made
    on other ground truth (``only``: the sequences ``force`` redoes, default all)."""
    out = run_dir(exp, spec)
    inputs = _inputs(spec)
    try:
        old = results.read_manifest(out)
    except results.CorruptFile:
        if not force:
            raise
        old = None
        results.clear_run(out)   # of a configuration no one can tell: replaced, as --force asks
    if (why := _conflict(exp, spec, old, inputs)) is not None:
        if not force:
            raise ResultsConflict(why)
        results.clear_run(out)   # all of them (not only --sequences'): none may be mixed with the new
    inputs["groundtruth"] = groundtruth_record(exp, spec, old, to_compute(out, spec, force, only), only)
    inputs.update(made_by_record(out, old))   # (none kept once cleared)
    try:
        _write_manifest(out, exp, spec, inputs, notes, _setup())
    except OSError as exc:   # disk full, read-only: one line naming the file (was a bare Errno)
        kept = "the results there stay" if results.holds_results(out) else "the folder holds no results"
        raise CannotWrite(f"cannot write {out / results.MANIFEST}: {exc.strerror or exc}; nothing ran ({kept}: "
                          "free space or make the folder writable, then rerun)") from exc
    return out


def _write_manifest(out: Path, exp: Experiment, spec: RunSpec, inputs: dict, notes: list[str],
                    setup: dict[str, Any]) -> None:
    results.write_manifest(out, {
        "experiment": exp.name,
        "experiment_file": str(Path(exp.path).resolve()),
        "cwd": os.getcwd(),   # where the configuration's relative paths point (results.in_run_cwd)
        "run": spec.name,
        "config": spec.resolved,
        "config_hash": spec.config_hash,
        **inputs,
        "seed": spec.seed,
        "sequence_seeds": "numpy.random.default_rng([seed, crc32(sequence name)])",
        "metric_profile": spec.metrics_profile,
        "timeout_s": spec.timeout_s,
        "warnings": list(notes),
        **setup,
    })


def write_result(out: Path, r: SequenceResult) -> SequenceOutcome:
    """Write one returned result into its run folder (atomically, predictions last). Raises
    :class:`CannotWrite` when the folder lost its manifest (deleted during the run: written
    again, it would hold results no manifest describes) or the folder cannot take any file (disk
    full, read-only: :data:`FOLDER_ERRORS`); a file of its own it cannot write (e.g. a name the
    file system refuses) fails the sequence only."""
    if not (out / results.MANIFEST).is_file():
        raise CannotWrite(f"{out / results.MANIFEST} is gone (the run folder was deleted or emptied during the "
                          f"run); the run stops without writing {r.run}/{r.sequence}: rerun to start the folder again")
    try:
        if r.reason:
            results.write_failure(out, r.sequence, r.reason, r.traceback)
            results.record_made_by(out, r.sequence, made=False)
        else:
            if r.bad_frames:
                results.write_bad_frames(out, r.sequence, dict(r.bad_frames))
            else:   # one an earlier attempt skipped is not this result's
                results.inside(out, r.sequence, ".bad_frames.json").unlink(missing_ok=True)
            results.write_sequence(out, r.sequence, r.boxes, r.frames_csv, r.trace_csv)
            results.record_made_by(out, r.sequence, made=True)
    except OSError as exc:
        if exc.errno not in FOLDER_ERRORS:   # this sequence's own file (a name the file system refuses)
            return SequenceOutcome(r.run, r.sequence, "failed", f"cannot write its results: {exc}")
        raise CannotWrite(f"cannot write the results of {r.run}/{r.sequence}: {exc.filename or out}: "
                          f"{exc.strerror or exc}; the run stops (the sequences written stay: rerun the same "
                          f"command to resume)") from exc
    return SequenceOutcome(r.run, r.sequence, "failed" if r.reason else "done", r.reason,
                           tuple(k for k, _ in r.bad_frames))


def profile_warnings(spec: RunSpec) -> list[str]:
    """A line per block whose rate or latency the run draws from a timing profile measured with
    another plugin, or the same one with other parameters (another backend, model file, ...;
    ``machine.run`` of the profile: ``mata-eval profile`` records the resolved blocks)."""
    path = getattr(spec.protocol.params, "latency_profile", None)
    if not path:
        return []
    from .timing_profile import read_profile

    measured = read_profile(path).machine.get("run") or {}
    out = []
    for key in ("tracker", "egomotion", "estimator"):
        uses = "profile" in (getattr(spec.protocol.params, f"{key}_hz", None),
                             getattr(spec.protocol.params, f"{key}_latency", None))
        block, was = getattr(spec, key), measured.get(key)
        if not (uses and block is not None and isinstance(was, dict) and was.get("name")):
            continue
        if was["name"] != block.name:
            out.append(f"the {key} rate/latency comes from {path}, measured with {key} {was['name']}, not this "
                       f"run's {block.name}: measure one with this run's blocks (mata-eval profile)")
        elif change := config_change(*_comparable(was, block)):   # (QA pass 16b: tensorrt, unsaid)
            out.append(f"the {key} rate/latency comes from {path}, measured with other {key} parameters "
                       f"({change}): measure one with this run's blocks (mata-eval profile)")
    return out


def _comparable(was: dict[str, Any], block: PluginBlock) -> tuple[dict[str, Any], dict[str, Any]]:
    """A profiled block's recorded parameters and the run's, as they compare for timing: only the
    parameters the profile records (one added since is not there: the shipped profiles warned 24
    times of those), each side's values as its preset resolves them (a null is the preset's or
    the parameter's default), and files by name; a file on one side only (the other finds it
    through an environment variable), or a folder, is not compared (the manifests record the
    sha256 of what was read)."""
    mine, theirs = _effective({"name": block.name, **dataclasses.asdict(block.params)}, block), _effective(was, block)

    def differ(k: str) -> bool:
        a, b = theirs.get(k), mine.get(k)
        if _is_path(a) or _is_path(b):
            return _is_path(a) and _is_path(b) and not any(Path(v).is_dir() for v in (a, b)) \
                and _file_name(a) != _file_name(b)
        return json.dumps(a, sort_keys=True, default=str) != json.dumps(b, sort_keys=True, default=str)

    keys = [k for k in was if k in mine and differ(k)]
    return {k: theirs.get(k) for k in keys}, {k: mine.get(k) for k in keys}


def _effective(values: dict[str, Any], block: PluginBlock) -> dict[str, Any]:
    """``values`` (a block's parameters) as its preset resolves them, or as given where they no
    longer build (a parameter renamed since)."""
    from ..core.params import build_params

    try:
        names = {f.name for f in dataclasses.fields(block.cls.Params)}
        params = build_params(block.cls.Params, {k: v for k, v in values.items() if k in names and v is not None})
        params = params.resolved() if callable(getattr(params, "resolved", None)) else params
        return {**values, **dataclasses.asdict(params)}
    except Exception:
        return dict(values)


def _is_path(v: Any) -> bool:
    return isinstance(v, str) and ("/" in v or "\\" in v)


def _file_name(v: str) -> str:
    from pathlib import PureWindowsPath

    return PureWindowsPath(v).name   # (splits on / and \\ alike: a profile written on either system)


def protocol_warnings(spec: RunSpec) -> list[str]:
    """What the protocol warns about on the camera rates of the run's sequences (e.g. an EOP
    rate the camera grid cannot give) and a timing profile of other blocks, each message once."""
    protocol = spec.protocol.create()
    if not hasattr(protocol, "timing"):  # a protocol that runs the blocks itself (live)
        return []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RateWarning)
        for fps in sorted({float(s.fps) for s in load_sequences(spec)}):
            protocol.timing(fps)
    rates = [str(w.message) for w in caught if issubclass(w.category, RateWarning)]
    return list(dict.fromkeys(rates + profile_warnings(spec)))


@contextlib.contextmanager
def lock_run_dir(out: Path) -> Iterator[None]:
    """Hold ``<run>/.lock`` (an OS file lock, released even when the process is killed)."""
    out.mkdir(parents=True, exist_ok=True)
    lock = filelock.FileLock(str(out / LOCK))
    try:
        lock.acquire(timeout=1.0)   # (a report's being_written holds it for an instant: waited out)
    except filelock.Timeout:
        raise RunLocked(f"{out} is being written by another mata-eval run (lock file {out / LOCK}); "
                        f"wait for it to end, or write to another folder with -o") from None
    try:
        yield
    finally:
        lock.release()


def being_written(out: Path) -> bool:
    """Whether a mata-eval run holds ``<run>/.lock`` now (it is writing the folder). False when
    the lock cannot be tried (no lock file, a read-only folder)."""
    if not (Path(out) / LOCK).is_file():
        return False
    lock = filelock.FileLock(str(Path(out) / LOCK))
    try:
        lock.acquire(timeout=0)
    except filelock.Timeout:
        return True
    except OSError:
        return False
    lock.release()
    return False


def select_runs(exp: Experiment, only: list[str] | None) -> list[RunSpec]:
    specs = [r for r in exp.runs if not only or r.name in only]
    if only and len(specs) != len(set(only)):
        known = ", ".join(r.name for r in exp.runs)
        raise UserError(f"unknown run name(s) {', '.join(sorted(set(only) - {r.name for r in specs}))} "
                        f"(--runs, or runs= in Python); the runs of {exp.path} are: {known}")
    return specs


def run_experiment(
    exp: Experiment,
    *,
    jobs: int | None = None,
    force: bool = False,
    only: list[str] | None = None,
    sequences: list[str] | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    executor: Executor | None = None,
) -> list[SequenceOutcome]:
    """Run every selected run of ``exp`` (``only``: run names) over its dataset (``sequences``:
    only these sequence names). Returns one outcome per sequence.

    The pending (run, sequence) pairs become tasks, one per sequence with every run that reads
    it (each frame decoded once for all, :mod:`mata_eval.run.tasks`), longest first, on
    ``executor`` (default: a local pool of ``jobs`` processes). The executor hands results
    back and this process writes every file: one writer per run folder, on any executor.

    Raises :class:`RunLocked` when another run writes into one of the run folders, and
    :class:`Interrupted` on SIGINT / SIGTERM (main thread) once the executor stopped its
    workers; its ``outcomes`` are those of the sequences finished until then."""
    specs = select_runs(exp, only)
    if jobs is not None and jobs < 1:
        raise UserError(f"jobs: expected 1 or more worker processes, got {jobs}")
    if not force:
        refuse_conflicts(exp, specs)
    if sequences and specs:
        known_seqs = {s.name for spec in specs for s in load_sequences(spec)}
        if set(sequences) - known_seqs:
            raise UserError(unknown_sequences_line(set(sequences) - known_seqs, known_seqs))
    outcomes: list[SequenceOutcome] = []
    with contextlib.ExitStack() as locks, stop_on_signals():
        for spec in specs:
            locks.enter_context(lock_run_dir(run_dir(exp, spec)))
        try:
            _run_locked(exp, specs, sequences, jobs, force, progress, log, executor, outcomes)
        except Interrupted as exc:
            exc.outcomes = list(outcomes)
            raise
    for o in outcomes:
        if o.status == "failed":
            log(f"FAILED {o.run}/{o.sequence}: {o.reason}")
        elif o.bad_frames:
            frames = ", ".join(map(str, o.bad_frames[:10])) + (" ..." if len(o.bad_frames) > 10 else "")
            log(f"{o.run}/{o.sequence}: {len(o.bad_frames)} bad frame(s) excluded from scoring "
                f"(on_bad_frame: skip): {frames}; see {o.sequence}.bad_frames.json")
    return outcomes


def _run_locked(exp: Experiment, specs: list[RunSpec], sequences: list[str] | None, jobs: int | None,
                force: bool, progress: bool, log: Callable[[str], None], executor: Executor | None,
                outcomes: list[SequenceOutcome]) -> None:
    pending: list[tuple[RunSpec, int, Sequence]] = []
    for spec in specs:
        notes = protocol_warnings(spec)
        for message in notes:
            log(f"warning: {spec.name}: {message}")
        # (the preflight printed the random-weights line; the manifest keeps it with the others)
        out = prepare_run_dir(exp, spec, force, notes + random_weights([spec]), sequences)
        for i, seq in enumerate(load_sequences(spec)):
            if sequences and seq.name not in sequences:
                continue
            # --force redoes a finished sequence in place: its old result stays until the new
            # one (or the failure) is written, so a run interrupted half-way loses nothing
            if not force and results.is_finished(out, seq.name):
                outcomes.append(SequenceOutcome(spec.name, seq.name, "skipped"))
            else:
                pending.append((spec, i, seq))
    if outcomes:
        log(f"{len(outcomes)} finished sequence(s) kept from an earlier run (--force, or force=True in Python, redoes them)")

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
