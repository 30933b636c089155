"""The ``mata-eval`` command: the only module that builds argparse parsers. Each subcommand is a
``cmd_*`` function that parses nothing itself and calls the plain functions of the packages
(``run``, ``score``, ``report``, ``data``, ``deploy``)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from . import __version__
from .core.errors import ConfigError, Interrupted, UserError

#: frames a timeline shows by default: about 2 s at 30 fps, labels readable on a screen
TIMELINE_WINDOW = 60
#: file extension of each table format written by ``mata-eval report --out``
EXTENSIONS = {"terminal": "txt", "markdown": "md", "csv": "csv", "latex": "tex"}
REPORT_FOLDER = "report"   # <output>/report: the plots `run` writes beside its run folders

TIMELINE_DOC = """Timeline plot of a scheduler trace (paper section 3.1, fig. "protocol comparison").

``mata-eval timeline RUN_DIR SEQ [--out PNG] [--frames A:B] [--compare RUN_DIR ...]`` draws
``RUN_DIR/SEQ.trace.csv`` (and the same sequence of other runs as panels below it)."""


# --- commands ---------------------------------------------------------------------------------


def cmd_list(args: argparse.Namespace) -> int:
    from .core.hooks import KINDS
    from .core.params import describe
    from .core.registry import load_registry

    reg = load_registry()
    for kind in KINDS:
        entries = [reg.plugins[kind][n] for n in reg.names(kind)]
        print(f"{kind}s:" if kind != "egomotion" else "egomotion:")
        if not entries:
            print("  (none)")
        width = max((len(e.name) for e in entries), default=0)
        for e in entries:
            print(f"  {e.name:<{width}}  [{e.package}]  {e.description}")
            if args.verbose:
                for p in describe(e.cls.Params):
                    value = "(required)" if p.required else f"= {p.default!r}"
                    print(f"      {p.name}: {p.type} {value}  {p.doc}")
    if reg.failures:
        print("plugins that failed to load:")
        for f in reg.failures:
            print(f"  {f.entry_point}  [{f.package}]  {f.error}")
    return 0


def _executor(args: argparse.Namespace) -> Any:
    """The executor ``--executor`` names (None: the runner's default local pool)."""
    if args.address and args.executor != "ray":
        raise ConfigError("--address", (), "--address needs --executor ray")
    if args.executor != "ray":
        return None
    from .run.executors import RayExecutor

    try:
        return RayExecutor(args.address, cpus=args.jobs)
    except ImportError as exc:
        raise ConfigError("--executor ray", (), str(exc)) from None


def cmd_run(args: argparse.Namespace) -> int:
    from .run.config import load_experiment
    from .run.runner import run_experiment
    from .score.evaluate import evaluate_experiment

    exp = load_experiment(args.experiment)
    if args.output is not None:
        if not args.output.strip():   # QA pass: `-o ""` fell back to the file's output without a word
            raise UserError("-o/--output: expected a folder, got an empty name")
        exp = dataclasses.replace(exp, output=Path(args.output).resolve())
    checked = _preflight(exp, args.runs, args.debug, args.sequences)
    if checked is None:   # (before the header: it would announce runs that do not exist)
        return 2
    n = len(checked.runs)   # (optional runs skipped are not counted)
    count = str(n) if n == len(exp.runs) else f"{n} of {len(exp.runs)}"
    print(f"experiment {exp.name} ({exp.path}): {count} run(s) -> {exp.output}", flush=True)
    names = [r.name for r in checked.runs]
    outcomes = run_experiment(exp, jobs=args.jobs, force=args.force, only=names, sequences=args.sequences,
                              progress=not args.quiet, executor=_executor(args))
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:  # printed before the table too: the table does not show what is missing from it
        print(f"{len(failed)} sequence(s) failed; see <run>/<sequence>.failed.json", file=sys.stderr)
    if args.no_report:
        return 1 if failed else 0
    from .report.overview import has_challenges, render_table
    from .report.plots import plot_curves

    scores = evaluate_experiment(exp, only=names)
    print(render_table(scores, "terminal"))
    _print_deltas(scores)
    if has_challenges(scores):
        print(render_table(scores, "terminal", table="challenges"))
    for s in scores:
        occ = s.summary.occluded_frames
        if occ is not None:
            print(f"{s.name}: on the {occ.n_scored} occluded frames of {occ.n_sequences} "
                  f"sequence{'s' if occ.n_sequences != 1 else ''}: "
                  f"SR {100 * occ.sr:.1f}  MSR {100 * occ.msr:.1f}  PR {100 * occ.pr:.1f}")
    order = {r.name: i for i, r in enumerate(exp.runs)}   # (a run's colour is its place in the experiment)
    plotted = sorted(scores + _other_runs_scores(exp, names), key=lambda s: order.get(s.name, len(order)))
    plots = plot_curves(plotted, exp.output / REPORT_FOLDER)
    for p in plots:
        print(f"plot: {p}")
    _print_incomplete(scores)   # failed, unscorable, without results (--sequences), ...
    return 1 if failed or any(s.meta.get("unscorable") for s in scores) else 0


def _other_runs_scores(exp: Any, names: Sequence[str]) -> list:
    """The scores of the experiment's runs not in ``names`` (left out by --runs) whose folders
    hold results of their configuration as the file has it now: the experiment's plots keep them
    (they showed the selected runs alone, and two drivers on disjoint --runs replaced each
    other's). A run that cannot be scored here is left out, with one line."""
    from .run.results import read_manifest
    from .run.runner import run_dir
    from .score.evaluate import ScoresUnavailable, scores_for

    others = []
    for spec in exp.runs:
        d = run_dir(exp, spec)
        if spec.name in names or not any(d.glob("*.txt")):
            continue
        try:
            if spec.made(read_manifest(d) or {}):
                others.append(scores_for(d))
        except (ScoresUnavailable, OSError, ValueError) as exc:
            print(f"plots: {spec.name} left out ({exc})")
    return others


def _preflight(exp: Any, only: Sequence[str] | None, debug: bool = False,
               sequences: Sequence[str] | None = None, sequences_flag: str | None = None) -> Any:
    """Check what the selected runs need (:mod:`mata_eval.run.preflight`); print one line per
    skipped optional run group and per problem (``debug``: raise the first problem's exception,
    with its traceback). Returns the plan, or None when a problem stops the experiment."""
    from .run.preflight import SEQUENCES_FLAG, plan, skipped_lines

    checked = plan(exp, only, sequences, sequences_flag or SEQUENCES_FLAG)
    if debug and checked.errors:
        raise checked.errors[0]
    for line in skipped_lines(checked.skipped):
        print(line, flush=True)
    for line in checked.warnings:
        print(f"warning: {line}", flush=True)
    for line in checked.problems:
        print(f"error: {line}", file=sys.stderr)
    if checked.problems:
        return None
    if not checked.runs:
        print("error: no run left to do", file=sys.stderr)
        return None
    return checked


def _print_deltas(scores: Sequence[Any]) -> None:
    """The MATA-vs-baseline table under the results, when the runs have both."""
    from .report.overview import mata_deltas
    from .report.tables import render

    t = mata_deltas(scores)
    if t is not None and t.rows:
        print(t.caption + ":")
        print(render(t, "terminal"))
    elif t is not None:   # no pair to show: why (e.g. its baseline scored under another profile)
        for note in t.notes:
            print(f"MATA minus its baseline: {note}")


def cmd_validate(args: argparse.Namespace) -> int:
    from .run.config import load_experiment

    exp = load_experiment(args.experiment)
    print(f"{exp.path}: experiment {exp.name!r}, {len(exp.runs)} run(s), output {exp.output}")
    for r in exp.runs:
        blocks = [f"{k}={getattr(r, k).name}" if getattr(r, k) else f"{k}=none"
                  for k in ("dataset", "tracker", "egomotion", "estimator", "protocol")]
        print(f"  {r.name}: {' '.join(blocks)} occlusion={'on' if r.occlusion else 'off'}"
              + ("  (optional)" if r.optional else ""))
    checked = _preflight(exp, args.runs, args.debug, args.sequences)
    if checked is None:
        return 2
    from .run.runner import ResultsConflict, profile_warnings, refuse_conflicts

    for spec in checked.runs:
        for line in profile_warnings(spec):
            print(f"warning: {spec.name}: {line}")
    refused = ""
    try:   # what `run` refuses in the output folder without --force (QA pass 15c: said ready, then refused)
        refuse_conflicts(exp, checked.runs)
    except ResultsConflict as exc:
        print(f"warning: run without --force refuses this: {exc}")
        refused = "; their output folders hold results that `run` refuses without --force (above)"
    print(f"preflight: {len(checked.runs)} run(s) ready" + (f", {len(checked.skipped)} optional run(s) skipped"
                                                          if checked.skipped else "") + refused)
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    import time

    from .data.synth import write_suite

    t0 = time.perf_counter()
    try:
        names = write_suite(args.out, args.n_sequences, args.n_frames, args.width, args.height, args.seed,
                            motion=args.motion, jobs=args.jobs, quality=args.quality, progress=True,
                            overwrite=args.force)
    except (FileExistsError, ValueError) as e:
        print(f"mata-eval synth: {e}")
        return 2
    print(f"wrote {len(names)} sequences to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0


def _dataset_params(name: str, root: str | None, extra: Mapping[str, Any] | None = None) -> tuple[type, Any]:
    """The dataset plugin ``name`` and its parameters built with ``{"root": root, **extra}``
    (a value None: the parameter's default)."""
    from .core.params import build_params
    from .core.registry import load_registry

    from .score.run_dataset import defaults_for_none

    cls = load_registry().get("dataset", name).cls
    values = defaults_for_none(cls.Params, extra or {})
    if root is not None:
        values["root"] = root
    return cls, build_params(cls.Params, values)


def load_dataset(name: str, root: str | None, extra: Mapping[str, Any] | None = None) -> list:
    """Sequences of the dataset plugin ``name`` built with ``{"root": root, **extra}``."""
    cls, params = _dataset_params(name, root, extra)
    return list(cls(params).sequences())


def _dataset_key(params: Mapping[str, Any], cwd: Path) -> dict[str, Any]:
    """A dataset's resolved parameters as compared between a run's manifest and an ``eval``:
    None dropped, ``root`` and ``annotations`` made absolute against the folder ``cwd`` they
    are relative to, values as JSON has them."""
    from .run.config import as_a_set

    out = {k: str((cwd / v).resolve()) if k in ("root", "annotations") and isinstance(v, str) else v
           for k, v in params.items() if v is not None}
    return json.loads(json.dumps(as_a_set(out), default=str))


def _effective_dataset(name: str, root: str | None, values: Mapping[str, Any], cwd: Path) -> dict[str, Any] | None:
    """The parameters (:func:`_dataset_key`) of the dataset ``eval`` loaded, defaults included."""
    try:
        _, params = _dataset_params(name, root, values)
    except (KeyError, ValueError, TypeError):
        return None
    return _dataset_key({"name": name, **dataclasses.asdict(params)}, cwd)


def _runs_own_dataset(manifest: dict[str, Any], effective: dict[str, Any] | None) -> bool:
    """Whether the run folder's ``manifest`` (empty: another dataset) records the dataset
    ``eval`` scored on (``effective``), so that scores.json written there describes the run."""
    ds = (manifest.get("config") or {}).get("dataset")
    return (isinstance(ds, dict) and effective is not None
            and _dataset_key(ds, Path(manifest.get("cwd") or ".")) == effective)


def cmd_eval(args: argparse.Namespace) -> int:
    """Score one or more results folders against one dataset, in one process: the annotations
    are read once and every folder is one row of the table."""
    from .core.params import parse_key_values
    from .report.overview import distinct_names, render_table
    from .score.evaluate import detect_layout, evaluate_results, evaluate_run, save_scores
    from .score.run_dataset import as_the_run_saw_them, dataset_name, manifest_or_nothing, run_dataset_values

    resolved = [str(Path(d).resolve()) for d in args.results_dirs]   # (the folder may change below)
    for twice in sorted({d for d in resolved if resolved.count(d) > 1}):
        print(f"{twice} is given more than once: scored once")
    args.results_dirs = list(dict.fromkeys(resolved))
    if len(args.results_dirs) > 1 and args.name:
        print("error: --name takes one RESULTS_DIR (each folder is named after itself)", file=sys.stderr)
        return 2
    if len(args.results_dirs) > 1 and args.output:   # --output DIR: DIR/<folder name>/scores.json each
        names = [Path(d).name for d in args.results_dirs]
        same = sorted({n for n in names if names.count(n) > 1})
        if same:
            print(f"error: --output with several RESULTS_DIR writes OUTPUT/<folder name>/scores.json, and "
                  f"{', '.join(same)} names more than one folder; score those one at a time", file=sys.stderr)
            return 2
    try:
        sets = parse_key_values(args.set or ())
    except ValueError as exc:
        print(f"error: --set: {exc}", file=sys.stderr)
        return 2
    read = {d: manifest_or_nothing(d) for d in args.results_dirs}   # each read once
    if args.dataset is None:   # the first run folder names it (QA pass 16b: --dataset was required)
        named = {d: dataset_name(m) for d, m in read.items()}
        source = next((d for d, name in named.items() if name), None)
        if source is None:
            outputs = [d for d in named if any(Path(d).glob("*/manifest.json"))]   # an experiment's output folder
            print(f"error: {'no folder given is' if len(named) > 1 else f'{args.results_dirs[0]} is not'} a mata-eval "
                  "run folder with a readable manifest.json naming its dataset: give --dataset NAME (and --root PATH)"
                  + (f"; {outputs[0]} holds run folders: `mata-eval eval {outputs[0]}/*`" if outputs else ""),
                  file=sys.stderr)
            return 2
        if len(names := sorted({n for n in named.values() if n})) > 1:   # (QA review: scored on the first's, unsaid)
            print(f"error: these run folders were made on different datasets ({', '.join(names)}); eval scores them "
                  "against one: give --dataset NAME", file=sys.stderr)
            return 2
        args.dataset = named[source]
        print(f"dataset {args.dataset}, as {Path(source) / 'manifest.json'} names it")
    all_scores = []
    run_cwd = contextlib.nullcontext   # a factory: each `with` needs its own
    values_cwd = Path.cwd()   # what the dataset's relative paths are relative to
    try:
        manifests = {d: m if dataset_name(m) == args.dataset else {} for d, m in read.items()}   # (of this dataset)
        # the first run folder of this dataset (QA pass 16a: a first folder of another dataset hid it)
        source = next((d for d in args.results_dirs if manifests[d]), args.results_dirs[0])
        first = manifests[source]
        if args.root is None and first:
            # a run folder of this dataset: the dataset as that run loaded it, not the default
            # (for synthetic: a 1.1 GB suite rendered, then refused on its frame count), its
            # relative paths from the folder it ran in, --set on top
            from .run.results import in_run_cwd

            given = ", with --set " + " ".join(args.set) if sets else ""
            sets = run_dataset_values(first, sets)
            print(f"dataset {args.dataset} with the parameters of {Path(source) / 'manifest.json'}{given}")
            run_cwd = lambda: in_run_cwd(first)  # noqa: E731
            values_cwd = Path(first.get("cwd") or ".")
        with run_cwd():
            seqs = load_dataset(args.dataset, args.root, sets)
        effective = _effective_dataset(args.dataset, args.root, sets, values_cwd)
    except (FileNotFoundError, ValueError, KeyError) as exc:
        print(f"error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    bad = 0   # a folder that cannot be scored is said, and the others are still scored (QA pass)
    for results_dir in args.results_dirs:
        try:
            layout = args.layout
            if layout == "mata" or (layout == "auto" and detect_layout(Path(results_dir)) == "mata"):
                with run_cwd():   # frame 0 of each sequence, for the run's occlusion augmentation
                    config = manifests[results_dir].get("config", {})
                    run_seqs = as_the_run_saw_them(seqs, config, lambda line: print(f"{results_dir}: {line}"))
                if run_seqs is not seqs:
                    print(f"{results_dir}: with the run's occlusion augmentation (seed {config.get('seed', 0)})")
                # (not saved while a run writes the folder: meta["unsaved"], said under the table)
                scores = evaluate_run(Path(results_dir), run_seqs, args.profile, save=False, dataset=args.dataset)
                own = _runs_own_dataset(manifests[results_dir], effective)
                if not own and not args.no_save:   # (a report would show these numbers as the run's)
                    print(f"{results_dir}: scores.json not written there: scored on another dataset, or other "
                          f"dataset parameters, than the run's (--output DIR writes it elsewhere)")
                if own and not args.no_save and "unsaved" not in scores.meta:
                    try:
                        print(f"wrote {save_scores(results_dir, scores)}")
                    except OSError as exc:
                        raise ValueError(f"cannot write scores.json into {results_dir} ({exc.strerror}); "
                                         f"use --no-save, or --output DIR to write it elsewhere") from None
            else:
                scores = evaluate_results(results_dir, seqs, args.profile, layout=layout, name=args.name,
                                          dataset=args.dataset)
                if layout != "auto" and not scores.sequences and (held := detect_layout(Path(results_dir))) != layout:
                    print(f"{results_dir}: --layout {layout} found no results; the folder holds the "
                          f"{held} layout (leave --layout out to detect it)")
        except (FileNotFoundError, ValueError, KeyError) as exc:
            print(f"error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
            bad += 1
            continue
        all_scores.append(scores)
    if not all_scores:
        return 2
    if args.output:
        for scores in all_scores:
            out = Path(args.output) / Path(scores.path).name if len(args.results_dirs) > 1 else Path(args.output)
            print(f"wrote {save_scores(out, scores)}")
    all_scores = distinct_names(all_scores)   # two folders of one run name: two labels
    print(render_table(all_scores, "terminal"))
    if args.challenges:
        print(render_table(all_scores, "terminal", table="challenges"))
    if args.attributes:
        print(render_table(all_scores, "terminal", table="attributes"))
    _print_incomplete(all_scores, args.dataset)
    if bad:
        return 2
    # (as `run`: a result file that cannot be scored is an error; sequences without one are not)
    return 0 if all(s.sequences and not s.meta.get("unscorable") for s in all_scores) else 1


def _print_incomplete(runs: Sequence, dataset: str | None = None) -> None:
    """After a table: the sequences each scored run has no results for (an interrupted run, a
    results folder short of the dataset; its row averages only the others), its results of no
    sequence of the ``dataset`` (a sequence removed since), the frames it skipped as unreadable
    (``on_bad_frame: skip``: not scored), the sequences run on other ground truth than they are
    scored on, the package versions that differ among its results, the warnings the runs
    recorded when they ran, and rows scored under different metric profiles (their numbers do
    not compare)."""
    from .run.results import versions_line
    from .score.evaluate import older_rates

    profiles: dict[str, list[str]] = {}
    for scores in runs:
        profiles.setdefault(scores.profile, []).append(scores.name)
    if len(profiles) > 1:
        print("these rows use different metric profiles, so their numbers do not compare: "
              + "; ".join(f"{p}: {', '.join(names)}" for p, names in profiles.items()))
    warned: dict[str, list[str]] = {}   # (the warnings `run` printed, kept in each manifest)
    for scores in runs:
        for line in scores.meta.get("run_warnings") or []:
            warned.setdefault(line, []).append(scores.name)
    for line, names in warned.items():
        print(f"warning recorded when {', '.join(names[:5])}{' ...' if len(names) > 5 else ''} ran: {line}")
    datasets: dict[str, list[str]] = {}
    for scores in runs:
        if scores.meta.get("dataset"):   # (older scores.json files of foreign folders have none)
            datasets.setdefault(scores.meta["dataset"], []).append(scores.name)
    if len(datasets) > 1:
        print("these rows are scored on different datasets, so their numbers do not compare: "
              + "; ".join(f"{d}: {', '.join(names)}" for d, names in datasets.items()))
    missing: dict[tuple[str, ...], list[str]] = {}  # runs short of the same sequences share one line
    for scores in runs:
        if scores.missing:
            missing.setdefault(tuple(scores.missing), []).append(str(scores.path))
    for names, paths in missing.items():
        where = ("" if len(runs) == 1 else f" in {paths[0]}" if len(paths) == 1 else
                 f" in each of the {len(paths)} runs" if len(paths) == len(runs) else f" in {', '.join(paths)}")
        print(f"{len(names)} sequence(s) without results{where}: {', '.join(names[:10])}"
              + (" ..." if len(names) > 10 else ""))
    for scores in runs:
        where = f" in {scores.path}" if len(runs) > 1 else ""
        if scores.meta.get("unsaved"):
            print(f"{scores.path}: {scores.meta['unsaved']}")
        failed = sorted(set(scores.failures) - set(scores.meta.get("unscorable") or ()))
        if failed:
            print(f"{len(failed)} sequence(s) failed{where}: {', '.join(failed[:10])}"
                  + (" ..." if len(failed) > 10 else "") + "; <run>/<sequence>.failed.json says why")
        _print_unscorable([scores])
        reps = scores.meta.get("repetitions_left") or []
        if reps:
            print(f"{len(reps)} sequence(s){where} have repetitions beyond <seq>_001.txt: only the first is scored "
                  f"({', '.join(reps[:5])}{' ...' if len(reps) > 5 else ''})")
        fitted = scores.meta.get("length_fitted") or {}
        if fitted:
            from .core.metric_profiles import get_profile

            how = {"truncate": "scored over the shorter of the two", "pad": "padded with empty boxes or cut"}
            policy = how.get(get_profile(scores.profile).length_mismatch, "fitted")
            print(f"{len(fitted)} result file(s){where} have another length than their sequence, "
                  f"{policy} as the {scores.profile} profile does: "
                  + ", ".join(f"{k} ({n} lines, {m} frames)" for k, (n, m) in list(fitted.items())[:5])
                  + (" ..." if len(fitted) > 5 else ""))
        un = scores.meta.get("unmatched_results") or []
        if un:
            print(f"{len(un)} result file(s){where} match no sequence of {dataset or scores.meta.get('dataset') or 'its dataset'}: "
                  f"{', '.join(un[:10])}" + (" ..." if len(un) > 10 else "") + " (not in the table)")
        other = scores.meta.get("other_groundtruth") or []
        if other:
            print(f"{len(other)} sequence(s){where} were run on other ground truth than they are scored on here (their "
                  f"tracker started from another box, or occluders were placed from other boxes): "
                  f"{', '.join(other[:10])}" + (" ..." if len(other) > 10 else "")
                  + f"; rerun them with --force --sequences {' '.join(other)} to run them on this one")
        if older_rates(scores):   # a scores.json given as a file, or of a folder that cannot be scored here
            print(f"{scores.path}: its block rates (Hz) count frame 0, the initialisation, as an older mata-eval did "
                  f"(off by up to a Hz or so on short sequences): `mata-eval eval FOLDER` where its data is (or with "
                  f"--root PATH --output DIR where the data moved) gives today's")
        mixed = scores.meta.get("mixed_versions") or {}
        if mixed:
            print(f"the results{where} were made with different package versions (a run resumed after an upgrade): "
                  f"{versions_line(mixed)} (manifest.json `made_by` says which made each sequence; --force redoes "
                  "them all with this one)")
        bad = scores.meta.get("bad_frames") or {}
        if bad:
            print(f"{sum(bad.values())} unreadable frame(s) skipped and not scored (on_bad_frame: skip){where}: "
                  + ", ".join(f"{seq} ({n})" for seq, n in list(bad.items())[:10]) + (" ..." if len(bad) > 10 else "")
                  + "; see <sequence>.bad_frames.json")


def _print_unscorable(runs: Sequence) -> int:
    """One line per sequence whose results cannot be scored (counted as failed in the table);
    returns how many."""
    n = 0
    for scores in runs:
        for seq, why in (scores.meta.get("unscorable") or {}).items():
            print(f"cannot score {scores.name}/{seq}: {why}")
            n += 1
    return n


def cmd_report(args: argparse.Namespace) -> int:
    if getattr(args, "per_sequence", False):
        return cmd_per_sequence(args)
    if getattr(args, "paper", None) or getattr(args, "experiment", None):
        if not args.paper:
            args.paper = "auto"
        return cmd_paper(args)
    if not args.run_dirs:
        print("error: give run folders (or --experiment EXP.yaml)", file=sys.stderr)
        return 2
    return _report_runs(args.run_dirs, args)


def _report_runs(run_dirs: Sequence[str], args: argparse.Namespace) -> int:
    """The run tables (and, with ``--out``, their files and plots) of ``run_dirs``."""
    from .report.overview import FORMATS, distinct_names, mata_deltas, render_table
    from .report.plots import plot_curves
    from .report.tables import render
    from .score.evaluate import ScoresUnavailable, scores_for

    runs = []
    for d in _without_report_folders(run_dirs):
        try:
            runs.append(scores_for(Path(d)))
        except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    runs = distinct_names(runs)   # two folders of one run name (two outputs of one experiment): two labels
    fmts = FORMATS if args.format == "all" else (args.format,)
    tables = ("overall", "challenges") if args.table == "both" else (args.table,)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    for table in tables:
        for fmt in fmts:
            text = render_table(runs, fmt, table)
            if out:   # every format asked, the terminal's too (<table>.txt: the default format)
                path = out / f"{table}.{EXTENSIONS[fmt]}"
                path.write_text(text)
                print(f"wrote {path}")
            if not out or fmt == "terminal":
                print(text)
                if table == "overall" and fmt == "terminal":
                    _print_deltas(runs)
                    _print_incomplete(runs)
    if out and "overall" in tables:   # MATA minus its baseline as files too (QA pass: the terminal's only)
        deltas = mata_deltas(runs)
        rows = deltas is not None and bool(deltas.rows)
        for fmt in EXTENSIONS if not rows else ():   # (an earlier report's, of other runs, is removed)
            (out / f"mata_vs_baseline.{EXTENSIONS[fmt]}").unlink(missing_ok=True)
        for fmt in fmts if rows else ():
            path = out / f"mata_vs_baseline.{EXTENSIONS[fmt]}"
            caption = "" if fmt in ("csv", "latex") else deltas.caption + ":\n\n"   # (LaTeX: in \caption)
            path.write_text(caption + render(deltas, fmt))
            print(f"wrote {path}")
    if out and not args.no_plots:
        for p in plot_curves(runs, out):
            print(f"plot: {p}")
    return 0


def _without_report_folders(run_dirs: Sequence[str]) -> list[str]:
    """``run_dirs`` less the plots folder ``run`` writes beside the runs (``<output>/report``, no
    run there), which ``report <output>/*/`` picks up, said once."""
    from .run.results import SCORES

    def is_plots(d: str) -> bool:
        p = Path(d)
        return p.name == REPORT_FOLDER and p.is_dir() and not (p / "manifest.json").exists() \
            and not (p / SCORES).exists()

    skipped = [d for d in run_dirs if is_plots(d)]
    if skipped:
        print(f"skipped {', '.join(skipped)}: the plots `mata-eval run` writes beside the runs, not a run",
              file=sys.stderr)   # (not into a table written to stdout: report --format csv > file)
    return [d for d in run_dirs if d not in skipped]


def cmd_paper(args: argparse.Namespace) -> int:
    """``mata-eval report --paper KIND RUN...`` or ``--experiment EXP.yaml ...``: print the
    table(s) (Markdown, or LaTeX with ``--format latex``); with ``--out`` also write Markdown,
    LaTeX, plots and the one-page HTML summary. ``--paper auto`` takes each experiment's table
    from its name (protocols, challenges, ablation, embedded)."""
    from .report.paper import PAPER_TABLES, build_table, experiment_runs, load_runs, write_paper_report
    from .report.tables import render
    from .score.evaluate import ScoresUnavailable

    try:
        plan: list[tuple[str, list[str]]] = []
        generic: list[str] = []  # run folders of experiments that are not one of the paper's tables
        for exp_file in args.experiment or []:
            name, dirs, not_run = experiment_runs(exp_file)
            if not_run:   # (QA pass: the table went without them, and said nothing)
                print(f"{exp_file}: {len(not_run)} of {len(not_run) + len(dirs)} runs have no results yet, not in "
                      f"the report: {', '.join(not_run[:6])}{' ...' if len(not_run) > 6 else ''}", file=sys.stderr)
            kind = name if args.paper == "auto" else args.paper
            if kind in PAPER_TABLES:
                plan.append((kind, dirs))
            elif args.paper == "auto":
                generic += dirs
            else:
                raise ValueError(f"--paper {kind}: expected one of {', '.join(PAPER_TABLES)}")
        if args.run_dirs:
            if args.paper == "auto":
                raise ValueError("--paper auto needs --experiment files; name the table for run folders")
            plan.append((args.paper, _without_report_folders(args.run_dirs)))
        if not plan and generic:
            if args.out:   # the paper's HTML summary is for its tables: say so, not nothing
                print(f"no summary.html: no experiment here is one of the paper's tables "
                      f"({', '.join(PAPER_TABLES)}; name one with --paper KIND); the run tables follow")
            return _report_runs(generic, args)
        if not plan:
            raise ValueError("no runs: give run folders or --experiment files")
        sections = [(kind, load_runs(dirs)) for kind, dirs in plan]
        tables = [build_table(kind, runs) for kind, runs in sections]
    except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    fmt = "latex" if args.format == "latex" else "markdown"
    for t in tables:
        print(render(t, fmt))
    if args.out:
        for p in write_paper_report(sections, Path(args.out), plots=not args.no_plots):
            print(f"wrote {p}")
    if generic:
        return _report_runs(generic, args)
    return 0


def cmd_per_sequence(args: argparse.Namespace) -> int:
    """``mata-eval report --per-sequence A B``: the per-sequence comparison of two runs."""
    from .report.overview import distinct_names
    from .report.paper import sequence_comparison
    from .report.tables import render
    from .score.evaluate import ScoresUnavailable, scores_for

    args.run_dirs = _without_report_folders(args.run_dirs)   # `report out/* --per-sequence` (QA pass)
    if len(args.run_dirs) != 2:
        print(f"error: --per-sequence compares exactly two run folders, got {len(args.run_dirs)}", file=sys.stderr)
        return 2
    try:
        t = sequence_comparison(*distinct_names([scores_for(Path(d)) for d in args.run_dirs]))
    except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    # Markdown on the terminal by default (the table is meant to be pasted); --format picks another,
    # and with --out each format goes into per_sequence.<ext> (all: every one), as for the run tables
    fmts = [f for f in EXTENSIONS if f != "terminal"] if args.format == "all" else \
        ["markdown" if args.format == "terminal" else args.format]
    if not args.out:
        for fmt in fmts:
            print(render(t, fmt))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for fmt in fmts:
        path = out / f"per_sequence.{EXTENSIONS[fmt]}"
        path.write_text(render(t, fmt))
        print(f"wrote {path}")
    return 0


def cmd_augment(args: argparse.Namespace) -> int:
    from .core.params import build_params
    from .core.registry import load_registry
    from .core.sequence import FrameReadError
    from .data.occlusion import OcclusionParams, write_augmented

    values: dict = {}
    if args.config:
        import yaml

        data = yaml.safe_load(Path(args.config).read_text()) or {}
        values = dict(data.get("occlusion", data) or {})
    if args.n_events is not None:
        values["n_events"] = args.n_events
    if args.shapes:
        values["shapes"] = list(args.shapes)
    if args.duration is not None:
        values["duration"] = args.duration
    try:
        params = build_params(OcclusionParams, values, ("occlusion",),
                              (lambda kp: str(args.config)) if args.config else None)
        if args.root and args.dataset == "synthetic" and (Path(args.root) / "synth.json").is_file():
            from .data.datasets.synthetic import read_suite  # a suite written by `mata-eval synth`, as it is

            sequences = read_suite(args.root, args.sequences)
        else:
            from .core.params import parse_key_values

            entry = load_registry().get("dataset", args.dataset)
            block = {**parse_key_values(args.set or ()),   # e.g. fps=10: event durations are in seconds
                     **{k: v for k, v in (("root", args.root), ("sequences", args.sequences)) if v is not None}}
            dataset = entry.cls(build_params(entry.cls.Params, block, ("dataset",)))
            sequences = dataset.sequences()
    except (ConfigError, KeyError, ValueError) as e:
        print(f"mata-eval augment: {e}")
        return 2
    if not sequences:   # e.g. `--sequences` given no name: nothing to augment is a mistake, not a success
        print(f"mata-eval augment: no sequence to augment (--sequences {' '.join(args.sequences or [])!s})")
        return 2
    out = Path(args.out).resolve()
    sources = {Path(args.root).resolve()} if args.root else set()
    sources |= {Path(s.frame_paths[0]).resolve().parent for s in sequences if s.frame_paths}
    clash = next((src for src in sources if out == src or out in src.parents or src in out.parents), None)
    if clash is not None:   # QA pass: `--force` into the root replaced the frames it was reading
        print(f"mata-eval augment: {args.out} overlaps the dataset it reads ({clash}); write the augmented "
              "copy to another folder")
        return 2
    try:
        names = write_augmented(sequences, args.out, params, args.seed, quality=args.quality, progress=True,
                                overwrite=args.force)
    except (FileExistsError, FrameReadError) as e:   # (a frame missing, or a sequence that cannot run)
        print(f"mata-eval augment: {e}")
        return 2
    print(f"wrote {len(names)} augmented sequences to {args.out} (contact sheets in {Path(args.out) / 'contact_sheets'})")
    return 0


def parse_frames(text: str) -> tuple[int, int]:
    """``"A:B"`` -> ``(A, B)``."""
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames: expected A:B (two integers), got {text!r}") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"--frames: expected 0 <= A < B, got {text!r}")
    return a, b


def cmd_timeline(args: argparse.Namespace) -> int:
    from .report.timeline import plot_timeline
    from .run.scheduler import read_trace_csv

    run_dir = Path(args.run_dir)
    trace_path = run_dir / f"{args.seq}.trace.csv"
    if not trace_path.is_file():
        have = sorted(p.name[: -len(".trace.csv")] for p in run_dir.glob("*.trace.csv"))
        print(f"mata-eval timeline: no trace {trace_path}; sequences with a trace: "
              f"{', '.join(have) or '(none)'}", file=sys.stderr)
        return 2
    traces = {}
    for d in [run_dir] + [Path(c) for c in (args.compare or [])]:
        path = d / f"{args.seq}.trace.csv"
        try:
            traces[d.name] = read_trace_csv(path.read_text())
        except OSError as exc:
            print(f"mata-eval timeline: cannot read {path}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        except ValueError as exc:
            print(f"mata-eval timeline: {path}: {exc}", file=sys.stderr)
            return 2
    out = Path(args.out) if args.out else run_dir / f"{args.seq}.timeline.png"
    frames = args.frames
    n_frames = max(e.frame for rows in traces.values() for e in rows) + 1
    if frames is None and n_frames > TIMELINE_WINDOW:
        frames = (0, TIMELINE_WINDOW)
        print(f"frames 0:{TIMELINE_WINDOW} of {n_frames} (--frames A:B for another window)")
    elif frames is not None and frames[0] >= n_frames:   # an empty plot, not an answer
        print(f"mata-eval timeline: --frames {frames[0]}:{frames[1]} starts after the trace of {args.seq}, "
              f"which has frames 0 to {n_frames - 1}", file=sys.stderr)
        return 2
    elif frames is not None and frames[1] > n_frames:   # (QA pass: an empty axis up to B)
        frames = (frames[0], n_frames)
        print(f"frames {frames[0]}:{n_frames}: the trace of {args.seq} ends at frame {n_frames - 1}")
    plot_timeline(traces, out, frames=frames, title=args.seq)
    print(out)
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    from .report.playback import play

    try:
        if args.sheet is not None and args.sheet < 1:   # (0 was read as "no sheet": the video's message)
            raise ValueError(f"--sheet {args.sheet}: expected a number of frames >= 1")
        out, n = play(args.run_dirs, args.sequence, args.out, frames=args.frames, sheet=args.sheet or 0)
    except (FileNotFoundError, ValueError, OSError, KeyError) as exc:
        print(f"mata-eval play: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    print(f"{out}: {n} frames" + (" in a contact sheet" if args.sheet else ""))
    return 0


def cmd_profile(args: argparse.Namespace) -> int:
    from .deploy.profile import profile_run, summary_table
    from .run.config import load_experiment
    from .run.scheduler import BlockError
    from .run.timing_profile import write_profile

    try:   # what the command line says is checked before minutes of timing
        scales = _time_scales(args.time_scale)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)   # (QA pass: a folder failed at the end, naming a temporary file)
    above = next(p for p in out.absolute().parents if p.exists())   # (its folders are made at the end)
    if out.is_dir() or out.suffix.lower() not in (".json", ".yaml", ".yml") or not above.is_dir():
        what = ("is a folder" if out.is_dir() else f"is under {above}, a file" if not above.is_dir()
                else "has neither .json nor .yaml at its end")
        print(f"error: --out {args.out} {what}: give the timing profile file to write (.json, or .yaml)",
              file=sys.stderr)
        return 2
    try:
        exp = load_experiment(args.experiment)
    except ConfigError as exc:
        if "cannot read timing profile" not in str(exc):
            raise
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        print("hint: profile times the blocks only: profile a file whose protocol reads no timing profile "
              "(e.g. a copy with protocol: {name: ltp}; experiments/live_blocks.yaml for experiments/live.yaml), "
              "then name the profile it writes as latency_profile", file=sys.stderr)
        return 2
    if args.run is None:
        if len(exp.runs) > 1:
            names = ", ".join(r.name for r in exp.runs)
            print(f"error: {exp.path} has {len(exp.runs)} runs; choose one with --run (runs: {names})", file=sys.stderr)
            return 2
        spec = exp.runs[0]
    else:
        matches = [r for r in exp.runs if r.name == args.run]
        if not matches:
            print(f"error: {exp.path}: no run {args.run!r} (runs: {', '.join(r.name for r in exp.runs)})", file=sys.stderr)
            return 2
        spec = matches[0]
    if args.threads:   # before the preflight, which builds the blocks
        _set_threads(args.threads)
        tracker = spec.tracker.params   # (ONNX Runtime does not read OMP_NUM_THREADS; torch does)
        if getattr(tracker, "threads", None) == 0 and getattr(tracker, "backend", "onnxruntime") == "onnxruntime":
            print(f"note: --threads {args.threads} does not reach the tracker: its `threads: 0` leaves ONNX Runtime "
                  f"at all cores; set `threads: {args.threads}` in its block to profile it on {args.threads}")
    # what validate and run check first (QA pass: a wrong checkpoint or backend was a traceback here);
    # the run asked for is profiled or refused, also one marked optional (it would be "skipped")
    spec = dataclasses.replace(spec, optional=False)
    if _preflight(dataclasses.replace(exp, runs=(spec,)), [spec.name], args.debug,
                  [args.sequence] if args.sequence else None, "--sequence") is None:
        return 2
    try:
        profile = profile_run(spec, frames=args.frames, warmup=args.warmup, sequence=args.sequence,
                              experiment=str(exp.path), time_scale=scales)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BlockError as exc:   # a block raised or returned what a run refuses: no profile
        print(f"error: run {spec.name}: {exc}; no profile written", file=sys.stderr)
        return 1
    try:   # (docs/jetson.md writes into profiles/, which a fresh checkout does not have)
        out.parent.mkdir(parents=True, exist_ok=True)
        path = write_profile(profile, out)
    except OSError as exc:
        print(f"error: cannot write {out}: {exc.strerror or exc}; nothing written", file=sys.stderr)
        return 1
    print(f"machine: {profile.machine.get('cpu')}" + (f"; GPU {', '.join(profile.machine['gpu'])}" if profile.machine.get("gpu") else "")
          + (f"; power mode {profile.machine['power_mode']}" if profile.machine.get("power_mode") else ""))
    print(f"run {spec.name}, sequence {profile.machine['run']['sequence']}: {args.frames} timed calls per block "
          f"after {args.warmup} warm-up calls")
    print(summary_table(profile))
    print(f"timing profile: {path}  (eop: latency_profile: {path}, tracker_hz: profile, tracker_latency: profile)")
    return 0


def _time_scales(items: list[str] | None) -> dict[str, float]:
    """``--time-scale 20`` (every block) / ``--time-scale tracker=20`` (repeatable) -> block -> factor;
    a block's own factor wins over the one for every block, whatever their order."""
    from .run.scheduler import BLOCKS

    given: dict[str, float] = {}
    for item in items or []:
        block, _, value = item.rpartition("=")
        try:
            factor = float(value)
        except ValueError:
            factor = float("nan")
        if block not in ("",) + BLOCKS or not 1 <= factor < float("inf"):
            raise ValueError(f"--time-scale {item!r}: expected FACTOR or BLOCK=FACTOR with a factor >= 1 (1 = this "
                             f"machine, as the live protocol's time_scale) and a block in {', '.join(BLOCKS)}")
        if block in given:
            raise ValueError(f"--time-scale {item!r}: {'every block' if not block else block} given twice")
        given[block] = factor
    every = given.pop("", None)
    return {**({b: every for b in BLOCKS} if every is not None else {}), **given}


def _set_threads(n: int) -> None:
    """Cap the CPU threads of the libraries the blocks use (before they are built)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(n)
    import cv2

    cv2.setNumThreads(n)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)


def cmd_export(args: argparse.Namespace) -> int:
    from .deploy.export import MANIFEST, ParityError, export_mixformerv2, export_nanotrack, export_ostrack

    if args.model != "mixformerv2" and (args.variant or args.form):   # (they were silently ignored)
        print(f"error: mata-eval export {args.model}: --variant and --form are MixFormerV2's", file=sys.stderr)
        return 2
    if args.checkpoint is None and not args.random_weights and args.model == "nanotrack":
        print(f"error: mata-eval export {args.model}: give --checkpoint PATH (the official weights) or "
              "--random-weights (pipeline tests only)", file=sys.stderr)
        return 2
    common = dict(random_weights=args.random_weights, seed=args.seed, trust_pickle=args.trust_pickle,
                  opset=args.opset, atol=args.atol, rtol=args.rtol)
    try:
        if args.model == "nanotrack":
            result = export_nanotrack(args.out, args.checkpoint, **common)
        elif args.model == "mixformerv2":
            forms = {"both": ("full", "two_graph"), "full": ("full",), "two-graph": ("two_graph",)}[args.form or "both"]
            result = export_mixformerv2(args.out, args.checkpoint, variant=args.variant or "S", forms=forms, **common)
        else:
            result = export_ostrack(args.out, args.checkpoint, **common)
    except ParityError as exc:
        print(f"error: parity check failed: {exc}", file=sys.stderr)
        return 1
    except (FileNotFoundError, ValueError, RuntimeError) as exc:   # (the loader speaks of the tracker's parameter)
        print(f"error: {str(exc).replace('set the tracker parameter trust_pickle: true', 'give --trust-pickle')}",
              file=sys.stderr)
        return 2
    for g in result.graphs:
        print(f"{g.role:9s} {g.path}  inputs {', '.join(g.inputs[:3])}{', ...' if len(g.inputs) > 3 else ''}"
              f"  max |onnxruntime - torch| = {g.max_abs_error:.2e}")
    print(f"manifest  {result.out_dir / MANIFEST}")
    return 0


# --- parsers ----------------------------------------------------------------------------------


def _add_eval(subparsers) -> None:
    from .core.metric_profiles import PROFILES
    from .score.evaluate import LAYOUTS

    p = subparsers.add_parser(
        "eval", help="score results folders (mata-eval run, pysot, got10k or pytracking layout)",
        description="Score results folders against a dataset's annotations (no images are read) and "
                    "print the table. A mata-eval run folder gets its scores.json (re)written when scored on its own dataset parameters.")
    p.add_argument("results_dirs", nargs="+", metavar="RESULTS_DIR",
                   help="folder with one result file per sequence; several folders are scored in one "
                        "process (the annotations read once) and shown as the rows of one table")
    p.add_argument("--dataset", help="dataset plugin name (see `mata-eval list`), e.g. dtb70; default for a "
                                     "mata-eval run folder: its own")
    p.add_argument("--root", help="dataset root folder (the plugin's `root` parameter)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="another dataset parameter (repeatable; KEY=null: its default); for a run folder without "
                        "--root, on top of the run's own")
    p.add_argument("--layout", choices=("auto",) + LAYOUTS, default="auto",
                   help="results layout (default: detected)")
    p.add_argument("--profile", choices=tuple(PROFILES), default="default",
                   help="metric compatibility profile (default: %(default)s)")
    p.add_argument("--name", help="run name shown in the table (default: the folder name)")
    p.add_argument("--output", help="also write scores.json into this folder (with several RESULTS_DIR: into "
                                    "OUTPUT/<folder name>/ each, for `mata-eval report`)")
    p.add_argument("--no-save", action="store_true", help="do not write scores.json into a mata run folder")
    p.add_argument("--challenges", action="store_true", help="also print the per-challenge table")
    p.add_argument("--attributes", action="store_true",
                   help="also print the per-attribute table (SR and NT2F per sequence attribute of the dataset)")
    p.set_defaults(func=cmd_eval)


def _add_report(subparsers) -> None:
    from .report.overview import FORMATS, TABLES
    from .report.paper import PAPER_TABLES

    p = subparsers.add_parser(
        "report", help="tables (terminal, Markdown, CSV, LaTeX) and plots of scored runs",
        description="Report one or more run folders side by side. A run folder without scores.json is "
                    "scored first when its experiment file is still readable.")
    p.add_argument("run_dirs", nargs="*", metavar="RUN_DIR", help="run folders (or scores.json files)")
    p.add_argument("--out", help="write tables (<table>.txt, .md, .csv or .tex, as --format says; MATA minus its "
                                 "baseline as mata_vs_baseline.* when the runs hold such a pair) and success / "
                                 "precision / NT2F plots (PNG) into this folder")
    p.add_argument("--format", choices=FORMATS + ("all",), default="terminal", type=_format_name,
                   help="table format (default: %(default)s; md and tex name markdown and latex too; with --out, "
                        "'all' writes every format)")
    p.add_argument("--table", choices=TABLES + ("both",), default="overall",
                   help="overall metrics, per-challenge SR/NT2F (paper Table 2), both of them, or SR/NT2F per "
                        "sequence attribute of the dataset (pysot's per-attribute analysis)")
    p.add_argument("--no-plots", action="store_true", help="with --out: tables only")
    p.add_argument("--paper", choices=PAPER_TABLES + ("auto",),
                   help="render the paper's table (protocols = Table 1, challenges = 2, ablation = 3, "
                        "embedded = 4) in Markdown (or LaTeX with --format latex), placing each run from its "
                        "manifest; with --out also write <table>.md, <table>.tex, plots and summary.html. "
                        "auto (the default with --experiment): the table named like each experiment")
    p.add_argument("--experiment", action="append", metavar="EXP.yaml",
                   help="report every run folder of this experiment file (repeatable: one HTML page with "
                        "several tables)")
    p.add_argument("--per-sequence", action="store_true",
                   help="two run folders A B: SR, NT2F and first failure frame of each sequence side by side "
                        "(Markdown, or the --format given; with --out written to per_sequence.md / .csv / .tex)")
    p.set_defaults(func=cmd_report)


def _add_augment(subparsers) -> None:
    from .data.occlusion import SHAPES

    p = subparsers.add_parser("augment", help="write an occlusion-augmented copy of a dataset (paper 3.2)",
                              description="Occlusion augmentation (paper section 3.2): writes OUT in the UAV123 "
                                          "layout with per-frame occlusion metadata and contact sheets. To "
                                          "augment at load time instead, add an `occlusion:` block to the experiment.")
    p.add_argument("out", help="output dataset root")
    p.add_argument("--dataset", default="synthetic",
                   help="dataset plugin name (default synthetic: the cached default suite, or the suite "
                        "written by `mata-eval synth` at --root)")
    p.add_argument("--root", help="the dataset's root folder (its `root` parameter)")
    p.add_argument("--sequences", nargs="*", help="only these sequences")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="another dataset parameter, e.g. fps=10 for 10 fps footage (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="experiment seed (default 0)")
    p.add_argument("--n-events", type=int, default=None, help="events per sequence")
    p.add_argument("--shapes", nargs="*", choices=SHAPES, help="shape families, cycled over the events")
    p.add_argument("--duration", type=float, default=None, help="seconds per event")
    p.add_argument("--config", help="YAML file holding an occlusion block (the experiment's `occlusion:` keys)")
    p.add_argument("--quality", type=_int_in(1, 100), default=95, help="JPEG quality 1-100 (default 95)")
    p.add_argument("--force", action="store_true", help="write into OUT even if it is not empty")
    p.set_defaults(func=cmd_augment)


def _add_timeline(subparsers) -> None:
    p = subparsers.add_parser("timeline", help="draw a sequence's scheduler trace (blocks, starts, publishes, held output)",
                              description=TIMELINE_DOC)
    p.add_argument("run_dir", metavar="RUN_DIR", help="run folder holding <SEQ>.trace.csv")
    p.add_argument("seq", metavar="SEQ", help="sequence name")
    p.add_argument("--out", help="image file to write (default: RUN_DIR/SEQ.timeline.png)")
    p.add_argument("--frames", type=parse_frames, default=None, metavar="A:B",
                   help="frame range to draw, half-open (default: the first 60 frames)")
    p.add_argument("--compare", nargs="+", metavar="RUN_DIR",
                   help="more run folders (e.g. other protocols) drawn as panels below, like the paper's figure")
    p.set_defaults(func=cmd_timeline)


def _add_play(subparsers) -> None:
    p = subparsers.add_parser(
        "play", help="draw runs on a sequence's frames: a video (or a PNG contact sheet)",
        description="Draw one sequence of one or more runs on its frames: the ground truth (green), each run's "
                    "scored box in its plot colour (MATA's estimate for a MATA run; the tracker's own box thin), "
                    "the tracker's search region (dashed), occluders (white) and which blocks published at each "
                    "frame. The frames are rebuilt from the first run's dataset and occlusion settings.")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run folders (same dataset)")
    p.add_argument("--sequence", required=True, help="sequence name")
    p.add_argument("--out", required=True, help="video file (.mp4 or .avi), or image file (.png) with --sheet")
    p.add_argument("--frames", type=parse_frames, default=None, metavar="A:B",
                   help="frame range, half-open (default: the whole sequence)")
    p.add_argument("--sheet", type=int, nargs="?", const=9, default=None, metavar="N",
                   help="a PNG contact sheet of N frames spread over the range instead of a video (default N: 9)")
    p.set_defaults(func=cmd_play)


def _add_profile(subparsers) -> None:
    from .deploy.profile import DEFAULT_FRAMES, DEFAULT_WARMUP

    p = subparsers.add_parser(
        "profile", help="time each block of a run on this machine and write a timing profile for eop",
        description="Build the blocks of one run of an experiment file, feed them real frames of its dataset "
                    "(decoded beforehand), and record per-block latencies after a warm-up. Writes a timing "
                    "profile (JSON, or YAML for .yaml) that the eop protocol reads with latency_profile.")
    p.add_argument("experiment", help="experiment YAML file, or the name of a shipped one (quickstart, embedded, ...)")
    p.add_argument("--run", help="which run of the matrix (required when the file has several)")
    p.add_argument("--sequence", help="sequence of the run's dataset to use (default: the first)")
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="timed calls per block (default %(default)s)")
    p.add_argument("--warmup", type=int, default=DEFAULT_WARMUP, help="untimed calls first (default %(default)s)")
    p.add_argument("--threads", type=_int_in(0), default=0,
                   help="cap OpenCV/BLAS/torch CPU threads (0 = leave as is); a tracker's ONNX Runtime threads are "
                        "its `threads:` parameter")
    p.add_argument("--time-scale", action="append", metavar="[BLOCK=]FACTOR",
                   help="the profile of a device FACTOR times slower (one block, or all), as the live protocol's "
                        "time_scale emulates it: latencies multiplied by FACTOR, and every block run at the "
                        "duty cycle live gives it (a pause of FACTOR-1 times each call, at most one call per "
                        "camera frame) instead of back to back (repeatable; 1 = this machine, paced)")
    p.add_argument("--out", required=True, help="timing profile file to write (.json, .yaml)")
    p.set_defaults(func=cmd_profile)


def _add_export(subparsers) -> None:
    from .deploy.export import DEFAULT_ATOL, DEFAULT_OPSET, DEFAULT_RTOL

    p = subparsers.add_parser(
        "export", help="export a PyTorch tracker to ONNX (parity with torch checked)",
        description="Export NanoTrack v2 (.pth), MixFormerV2 or OSTrack to ONNX (opset 17, TorchScript exporter). "
                    "ONNX Runtime's outputs are compared with torch's on random crops; the export fails above "
                    "the tolerance. Writes export.json beside the graphs.")
    p.add_argument("model", choices=("nanotrack", "mixformerv2", "ostrack"))
    p.add_argument("--checkpoint", help="weights: nanotrackv2.pth, mixformerv2_small.pth.tar, OSTrack_ep0300.pth.tar "
                                        "(or the folder holding it; MixFormerV2 and OSTrack default to the tracker's "
                                        "environment variable, $MATA_MIXFORMERV2_S / _B, $MATA_OSTRACK)")
    p.add_argument("--random-weights", action="store_true", help="seeded random weights (pipeline tests and timing only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random weights and of the parity inputs")
    p.add_argument("--trust-pickle", action="store_true",
                   help="allow full unpickling of a trusted legacy checkpoint (default: weights only)")
    p.add_argument("--variant", choices=("S", "B"), help="MixFormerV2 variant (default: S)")
    p.add_argument("--form", choices=("both", "full", "two-graph"),
                   help="MixFormerV2: one graph, template encoder + search step, or both (default)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET)
    p.add_argument("--atol", type=float, default=DEFAULT_ATOL, help="parity: absolute tolerance (default %(default)g)")
    p.add_argument("--rtol", type=float, default=DEFAULT_RTOL, help="parity: relative tolerance (default %(default)g)")
    p.set_defaults(func=cmd_export)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mata-eval",
        description="Evaluate and run single-object trackers on UAVs as they run on board: "
                    "MATA (tracker + ego-motion + homography EKF), the EOP protocol and NT2F.")
    parser.add_argument("--version", action="version", version=f"mata-eval {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("list", help="list installed plugins by kind")
    p.add_argument("-v", "--verbose", action="store_true", help="also list each plugin's parameters")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("run", help="run an experiment file, print its table, write plots")
    p.add_argument("experiment", help="experiment YAML file, or the name of a shipped one (quickstart, protocols, ...)")
    p.add_argument("-j", "--jobs", type=int, default=None, help="worker processes (default: the cores available)")
    p.add_argument("--force", action="store_true", help="redo sequences that already have results")
    p.add_argument("--runs", nargs="+", metavar="RUN", help="only these named runs of the matrix")
    p.add_argument("--sequences", nargs="+", metavar="SEQ", help="only these sequences of the dataset")
    p.add_argument("-o", "--output", help="output folder (overrides `output` in the file)")
    p.add_argument("--no-report", action="store_true", help="do not score and print the table")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where the sequences run: local worker processes (default) or a Ray cluster "
                        "(pip install 'mata-eval[ray]'; docs/cluster.md)")
    p.add_argument("--address", metavar="auto|ray://HOST:PORT",
                   help="Ray cluster to use (default: $RAY_ADDRESS when set, else a local one of -j CPUs)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check an experiment file and what its runs need (data, models, "
                                        "backends), list its runs, run nothing")
    p.add_argument("experiment", help="experiment file (a path or a shipped name)")
    p.add_argument("--runs", nargs="+", help="check only these runs")
    p.add_argument("--sequences", nargs="+", help="check only these sequences (as run --sequences would run)")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("synth", help="generate synthetic UAV sequences (UAV123 layout, true homographies)",
                       description="Synthetic UAV sequences with exact ego-motion (`mata-eval synth`).")
    p.add_argument("out", help="dataset root to create (data_seq/UAV123, anno/UAV123 inside)")
    p.add_argument("--n-sequences", type=int, default=20, help="number of sequences (default 20)")
    p.add_argument("--n-frames", type=int, default=300, help="frames per sequence (default 300, 30 fps)")
    p.add_argument("--width", type=int, default=1280, help="frame width (default 1280)")
    p.add_argument("--height", type=int, default=720, help="frame height (default 720)")
    p.add_argument("--seed", type=int, default=0, help="suite seed (default 0)")
    p.add_argument("--motion", choices=("uav123", "legacy"), default="uav123",
                   help="camera model: uav123 (default; image-plane motion matched to UAV123) or legacy "
                        "(generator version 3, the target nearly still in the image)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--quality", type=_int_in(1, 100), default=90, help="JPEG quality 1-100 (default 90)")
    p.add_argument("--force", action="store_true", help="replace an existing suite in OUT")
    p.set_defaults(func=cmd_synth)

    _add_eval(sub)
    _add_report(sub)
    _add_augment(sub)
    _add_timeline(sub)
    _add_play(sub)
    _add_profile(sub)
    _add_export(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv == ["--version"]:  # answered before the parser imports what its choices come from
        print(f"mata-eval {__version__}")
        return 0
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except Interrupted as exc:  # SIGINT / SIGTERM during a run: the workers are stopped
        done = sum(o.status == "done" for o in exc.outcomes)
        print(f"interrupted ({exc}): {done} sequence(s) finished in this run are saved; "
              "rerun the same command to resume", file=sys.stderr)
        return exc.exit_status
    except KeyboardInterrupt:
        what = {"run": "finished sequences are saved; rerun the same command to resume",
                "profile": "no profile written",
                "export": "an earlier export there is kept, unless its files were being replaced: then export again",
                }.get(args.command, "stopped before the end")
        print(f"interrupted: {what}", file=sys.stderr)
        return 130
    except (UserError, OSError) as exc:  # a mistake to fix, or a file that cannot be read or written
        if args.debug:
            raise
        for one in getattr(exc, "errors", None) or (exc,):   # several problems of a file: a line each
            print(f"error: {_one_line(one)}", file=sys.stderr)
        return 2


def _int_in(low: int, high: int | None = None) -> Callable[[str], int]:
    """argparse type of an integer in [low, high] (``high`` None: no upper bound)."""
    def parse(text: str) -> int:
        v = int(text)
        if v < low or (high is not None and v > high):
            expected = f">= {low}" if high is None else f"in {low}-{high}"
            raise argparse.ArgumentTypeError(f"expected an integer {expected}, got {v}")
        return v
    return parse


def _format_name(text: str) -> str:
    """A --format value, its file extension (md, tex, txt) taken for the format's name."""
    return {ext: fmt for fmt, ext in EXTENSIONS.items()}.get(text, text)


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, FileExistsError) and exc.filename and not Path(exc.filename).is_dir():   # e.g. --out afile
        return f"{exc.filename}: a file is there; expected a folder (or a name that does not exist yet)"
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or exc} (--debug shows the traceback)"
    return " ".join(str(exc).split())


if __name__ == "__main__":
    sys.exit(main())
