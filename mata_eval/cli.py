"""The ``mata-eval`` command."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys
from pathlib import Path

from . import __version__
from .core.errors import ConfigError

# Modules that contribute a subcommand through ``add_cli(subparsers)``.
SUBCOMMAND_MODULES = (
    "mata_eval.score.evaluate",  # eval
    "mata_eval.report.tables",  # report
    "mata_eval.data.occlusion",  # augment
    "mata_eval.report.timeline",  # timeline
    "mata_eval.deploy.profile",  # profile
    "mata_eval.deploy.export",  # export
)


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
                    print(f"      {p.name}: {p.type} = {p.default!r}  {p.doc}")
    if reg.failures:
        print("plugins that failed to load:")
        for f in reg.failures:
            print(f"  {f.entry_point}  [{f.package}]  {f.error}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from .run.config import load_experiment
    from .run.runner import ResultsConflict, evaluate_experiment, run_experiment

    exp = load_experiment(args.experiment)
    if args.output:
        exp = dataclasses.replace(exp, output=Path(args.output).resolve())
    print(f"experiment {exp.name}: {len(exp.runs)} run(s) -> {exp.output}")
    try:
        outcomes = run_experiment(exp, jobs=args.jobs, force=args.force, only=args.runs,
                                  progress=not args.quiet)
    except ResultsConflict as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.no_report:
        return 0
    from .report.tables import plot_curves, render_table

    scores = evaluate_experiment(exp, only=args.runs)
    print(render_table(scores, "terminal"))
    if any(s.summary.groups for s in scores):
        print(render_table(scores, "terminal", table="challenges"))
    for s in scores:
        occ = s.summary.occluded_frames
        if occ is not None:
            print(f"{s.name}: on the {occ.n_scored} occluded frames of {occ.n_sequences} sequences: "
                  f"SR {100 * occ.sr:.1f}  MSR {100 * occ.msr:.1f}  PR {100 * occ.pr:.1f}")
    plots = plot_curves(scores, exp.output / "report")
    for p in plots:
        print(f"plot: {p}")
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:
        print(f"{len(failed)} sequence(s) failed; see <run>/<sequence>.failed.json")
    return 1 if failed and len(failed) == len(outcomes) else 0


def cmd_validate(args: argparse.Namespace) -> int:
    from .run.config import load_experiment

    exp = load_experiment(args.experiment)
    print(f"{exp.path}: experiment {exp.name!r}, {len(exp.runs)} run(s), output {exp.output}")
    for r in exp.runs:
        blocks = [f"{k}={getattr(r, k).name}" if getattr(r, k) else f"{k}=none"
                  for k in ("dataset", "tracker", "egomotion", "estimator", "protocol")]
        print(f"  {r.name}: {' '.join(blocks)} occlusion={'on' if r.occlusion else 'off'}")
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    import time

    from .data.synth import write_suite

    t0 = time.perf_counter()
    try:
        names = write_suite(args.out, args.n_sequences, args.n_frames, args.width, args.height, args.seed,
                            jobs=args.jobs, quality=args.quality, progress=True, overwrite=args.force)
    except (FileExistsError, ValueError) as e:
        print(f"mata-eval synth: {e}")
        return 2
    print(f"wrote {len(names)} sequences to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mata-eval",
        description="Evaluate and run single-object trackers on UAVs as they run on board: "
                    "MATA (tracker + ego-motion + homography EKF), the EOP protocol and NT2F.")
    parser.add_argument("--version", action="version", version=f"mata-eval {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("list", help="list installed plugins by kind")
    p.add_argument("-v", "--verbose", action="store_true", help="also list each plugin's parameters")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("run", help="run an experiment file, print its table, write plots")
    p.add_argument("experiment", help="experiment YAML file")
    p.add_argument("-j", "--jobs", type=int, default=None, help="worker processes (default: the cores available)")
    p.add_argument("--force", action="store_true", help="redo sequences that already have results")
    p.add_argument("--runs", nargs="+", metavar="RUN", help="only these named runs of the matrix")
    p.add_argument("-o", "--output", help="output folder (overrides `output` in the file)")
    p.add_argument("--no-report", action="store_true", help="do not score and print the table")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check an experiment file and list its runs without running")
    p.add_argument("experiment")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("synth", help="generate synthetic UAV sequences (UAV123 layout, true homographies)",
                       description="Synthetic UAV sequences with exact ego-motion (`mata-eval synth`).")
    p.add_argument("out", help="dataset root to create (data_seq/UAV123, anno/UAV123 inside)")
    p.add_argument("--n-sequences", type=int, default=20, help="number of sequences (default 20)")
    p.add_argument("--n-frames", type=int, default=300, help="frames per sequence (default 300, 30 fps)")
    p.add_argument("--width", type=int, default=1280, help="frame width (default 1280)")
    p.add_argument("--height", type=int, default=720, help="frame height (default 720)")
    p.add_argument("--seed", type=int, default=0, help="suite seed (default 0)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--quality", type=int, default=90, help="JPEG quality (default 90)")
    p.add_argument("--force", action="store_true", help="replace an existing suite in OUT")
    p.set_defaults(func=cmd_synth)

    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ImportError as exc:
            if exc.name == name:  # that feature is not part of this installation
                continue
            raise
        module.add_cli(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished sequences are saved; rerun the same command to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
