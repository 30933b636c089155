"""Reports of scored runs: tables (terminal, Markdown, CSV, LaTeX booktabs like the paper's
tables) and success / precision / NT2F plots (PNG, matplotlib's Agg canvas).

Two tables: ``overall`` (one row per run: SR, MSR, PR, P@20, NT2F, block frequencies, excluded
frames, failed sequences; the paper's Tables 1 and 3) and ``challenges`` (SR and NT2F per
challenge group, the paper's Table 2)."""

from __future__ import annotations

import argparse
import csv
import io
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..score.evaluate import SCORES, RunScores, load_scores
from ..score.metrics import NORM_GRID, PIXEL_GRID, Summary

FORMATS = ("terminal", "markdown", "csv", "latex")
TABLES = ("overall", "challenges")
METRIC_LABELS = (("sr", "SR"), ("msr", "MSR"), ("pr", "PR"), ("precision20", "P@20"), ("nt2f", "NT2F"))
_EXT = {"terminal": "txt", "markdown": "md", "csv": "csv", "latex": "tex"}


def _pct(v: float) -> str:
    """A fraction as a percentage with one decimal, as in the paper's tables ("-" if unknown)."""
    return "-" if v is None or not np.isfinite(v) else f"{100.0 * v:.1f}"


def _hz(v: float) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.1f}"


def _num(v: float) -> str:
    return "" if v is None or not np.isfinite(v) else f"{v:.6g}"


@dataclass(frozen=True)
class _Table:
    """Header groups (label, span) above the column names, then rows of cells."""

    groups: list[tuple[str, int]]
    columns: list[str]
    rows: list[list[str]]
    separators: list[int]  # column indices after which a vertical rule goes (LaTeX)


def _blocks(runs: Sequence[RunScores]) -> list[str]:
    seen: list[str] = []
    for r in runs:
        for b in r.frequencies:
            if b not in seen:
                seen.append(b)
    return seen


def _overall(runs: Sequence[RunScores], fmt: str) -> _Table:
    blocks = _blocks(runs)
    cols = ["Run", "Seqs"] + [lab for _, lab in METRIC_LABELS]
    if fmt == "latex":
        cols += [f"{b} Freq." for b in blocks]
    else:
        cols += [f"{b} Hz" for b in blocks]
    cols += ["Excl. frames", "Failed"]
    rows = []
    for r in runs:
        s = r.summary.overall
        row = [r.name, str(s.n_sequences)] + [_pct(getattr(s, m)) for m, _ in METRIC_LABELS]
        for b in blocks:
            f = r.frequencies.get(b)
            if f is None:
                row.append("-")
            elif fmt == "latex":
                row.append(_hz(f.scheduled_hz))
            else:  # scheduled rate (camera clock), wall-clock rate in parentheses
                row.append(f"{_hz(f.scheduled_hz)} ({_hz(f.wall_hz)})")
        row += [str(s.n_excluded), str(len(r.failures))]
        rows.append(row)
    return _Table([], cols, rows, sorted({1, 2, 7, 7 + len(blocks)}))


def _group_names(runs: Sequence[RunScores]) -> list[str]:
    names: list[str] = []
    for r in runs:
        for g in r.summary.groups:
            if g not in names:
                names.append(g)
    return names


def _challenges(runs: Sequence[RunScores], fmt: str) -> _Table:
    groups = _group_names(runs)
    n = {g: max((r.summary.groups[g].n_sequences for r in runs if g in r.summary.groups), default=0)
         for g in groups}
    cols = ["Run"] + [c for _ in groups for c in ("SR", "NT2F")]
    rows = []
    for r in runs:
        row = [r.name]
        for g in groups:
            s = r.summary.groups.get(g)
            row += [_pct(s.sr), _pct(s.nt2f)] if s is not None else ["-", "-"]
        rows.append(row)
    # the number of sequences of each group in the header, except in LaTeX (like the paper)
    labels = [(f"{g[:1].upper()}{g[1:]}" + ("" if fmt == "latex" else f" ({n[g]})"), 2) for g in groups]
    return _Table([("", 1)] + labels, cols, rows, [1 + 2 * i for i in range(len(groups))])


def _terminal(t: _Table) -> str:
    cols = t.columns
    if t.groups:  # fold the group label into the column names
        names, k = [], 0
        for label, span in t.groups:
            for j in range(span):
                names.append(f"{label} {cols[k + j]}".strip() if label else cols[k + j])
            k += span
        cols = names
    widths = [max(len(c), *(len(r[i]) for r in t.rows)) if t.rows else len(c) for i, c in enumerate(cols)]
    line = "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cols, widths)))
    out = [line, "-" * len(line)]
    for r in t.rows:
        out.append("  ".join(v.ljust(w) if i == 0 else v.rjust(w) for i, (v, w) in enumerate(zip(r, widths))))
    return "\n".join(out) + "\n"


def _markdown_cell(v: str) -> str:
    return v.replace("|", "\\|")


def _markdown(t: _Table) -> str:
    out = []
    cols = list(t.columns)
    if t.groups:
        k = 0
        for label, span in t.groups:
            for j in range(span):
                cols[k + j] = f"{label} {cols[k + j]}".strip() if label else cols[k + j]
            k += span
    out.append("| " + " | ".join(_markdown_cell(c) for c in cols) + " |")
    out.append("|" + "|".join([":---"] + ["---:"] * (len(cols) - 1)) + "|")
    for r in t.rows:
        out.append("| " + " | ".join(_markdown_cell(v) for v in r) + " |")
    return "\n".join(out) + "\n"


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                  "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def latex_escape(s: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in s)


def _latex(t: _Table) -> str:
    spec = ""
    for i in range(len(t.columns)):
        spec += "l" if i == 0 else "c"
        if i + 1 in t.separators and i + 1 < len(t.columns):
            spec += "|"
    out = [r"\begin{tabular}{" + spec + "}", r"\toprule"]
    if t.groups:
        cells, k = [], 0
        for label, span in t.groups:
            last = k + span >= len(t.columns)
            if span == 1:
                cells.append(latex_escape(label))
            else:
                cells.append(rf"\multicolumn{{{span}}}{{c{'' if last else '|'}}}{{{latex_escape(label)}}}")
            k += span
        out.append(" & ".join(cells) + r" \\")
    out.append(" & ".join(latex_escape(c) for c in t.columns) + r" \\")
    out.append(r"\midrule")
    for r in t.rows:
        out.append(" & ".join(latex_escape(v) for v in r) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def _csv(runs: Sequence[RunScores], table: str) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    if table == "overall":
        blocks = _blocks(runs)
        w.writerow(["run", "profile", "sequences", *(m for m, _ in METRIC_LABELS),
                    *(f"{b}_{k}" for b in blocks for k in ("scheduled_hz", "wall_hz")),
                    "frames", "scored_frames", "excluded_frames", "invalid_gt_frames", "failed", "missing"])
        for r in runs:
            s = r.summary.overall
            freq = []
            for b in blocks:
                f = r.frequencies.get(b)
                freq += [_num(f.scheduled_hz), _num(f.wall_hz)] if f else ["", ""]
            w.writerow([r.name, r.profile, s.n_sequences, *(_num(getattr(s, m)) for m, _ in METRIC_LABELS),
                        *freq, s.n_frames, s.n_scored, s.n_excluded, s.n_invalid_gt, len(r.failures), len(r.missing)])
    else:
        w.writerow(["run", "group", "sequences", *(m for m, _ in METRIC_LABELS)])
        for r in runs:
            for g, s in r.summary.groups.items():
                w.writerow([r.name, g, s.n_sequences, *(_num(getattr(s, m)) for m, _ in METRIC_LABELS)])
    return buf.getvalue()


def render_table(runs: Sequence[RunScores], fmt: str = "terminal", table: str = "overall") -> str:
    """The table of ``runs`` in ``fmt`` (terminal, markdown, csv, latex); ``table`` is
    ``overall`` or ``challenges``. Metrics print as percentages with one decimal (CSV keeps
    fractions at full precision); block frequencies as scheduled Hz (wall-clock Hz)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown table format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if table not in TABLES:
        raise ValueError(f"unknown table {table!r}; expected one of {', '.join(TABLES)}")
    runs = list(runs)
    if fmt == "csv":
        return _csv(runs, table)
    t = _overall(runs, fmt) if table == "overall" else _challenges(runs, fmt)
    return {"terminal": _terminal, "markdown": _markdown, "latex": _latex}[fmt](t)


# --- plots -----------------------------------------------------------------------------------


def nt2f_survival(values: Sequence[float], grid: np.ndarray) -> np.ndarray:
    """Fraction of sequences whose NT2F exceeds each normalised time of ``grid``: the share of
    sequences still tracked at that point. Its area over [0, 1] is the mean NT2F."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    if v.size == 0:
        return np.full(len(grid), np.nan)
    g = np.asarray(grid, dtype=float)
    # at t = 1 the never-failed sequences (NT2F = 1) are still tracked: right-continuous end
    return (v[None, :] > np.minimum(g, np.nextafter(1.0, 0.0))[:, None]).mean(axis=1)


def _figure():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0, 4.0), dpi=120)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot(1, 1, 1)


def _finish(fig, ax, title: str, xlabel: str, ylabel: str, path: Path) -> Path:
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 1.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower left" if "Success" in title or "NT2F" in title else "lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    return path


def plot_curves(runs: Sequence[RunScores], out_dir: Path) -> list[Path]:
    """Write ``success.png``, ``precision.png``, ``norm_precision.png`` and ``nt2f.png`` into
    ``out_dir``; legends carry MSR, P@20, PR and mean NT2F, runs sorted best first."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = list(runs)
    paths = []

    def by(metric: str) -> list[RunScores]:
        return sorted(runs, key=lambda r: -np.nan_to_num(getattr(r.summary.overall, metric), nan=-1.0))

    fig, ax = _figure()
    iou_x = np.linspace(0.0, 1.0, 21)
    for r in by("msr"):
        s: Summary = r.summary.overall
        ax.plot(iou_x, s.success_curve, label=f"{r.name} [{_pct(s.msr)}]")
    ax.set_xlim(0, 1)
    paths.append(_finish(fig, ax, "Success plot (MSR)", "IoU threshold", "Success rate", out / "success.png"))

    fig, ax = _figure()
    for r in by("precision20"):
        s = r.summary.overall
        ax.plot(PIXEL_GRID, s.precision_curve, label=f"{r.name} [{_pct(s.precision20)}]")
    ax.set_xlim(0, 50)
    paths.append(_finish(fig, ax, "Precision plot (P@20)", "Centre error threshold (px)", "Precision",
                         out / "precision.png"))

    fig, ax = _figure()
    for r in by("pr"):
        s = r.summary.overall
        ax.plot(NORM_GRID, s.norm_precision_curve, label=f"{r.name} [{_pct(s.pr)}]")
    ax.set_xlim(0, 0.5)
    paths.append(_finish(fig, ax, "Normalised precision plot (PR)", "Normalised centre error threshold",
                         "Precision", out / "norm_precision.png"))

    fig, ax = _figure()
    grid = np.linspace(0.0, 1.0, 201)
    for r in by("nt2f"):
        surv = nt2f_survival([s.nt2f for s in r.sequences.values()], grid)
        ax.step(grid, surv, where="post", label=f"{r.name} [{_pct(r.summary.overall.nt2f)}]")
    ax.set_xlim(0, 1)
    paths.append(_finish(fig, ax, "NT2F plot (sequences not yet failed)", "Normalised time t / N",
                         "Fraction of sequences", out / "nt2f.png"))
    return paths


# --- CLI -------------------------------------------------------------------------------------


class ScoresUnavailable(RuntimeError):
    """A run folder has no scores.json and cannot be evaluated from here."""


def scores_for(run_dir: Path) -> RunScores:
    """``<run>/scores.json``, evaluating the run first when it is a mata-eval run folder whose
    experiment file can still be loaded; otherwise :class:`ScoresUnavailable` says what to do."""
    d = Path(run_dir)
    if d.is_file() or (d / SCORES).is_file():
        return load_scores(d)
    from ..run import results

    manifest = results.read_manifest(d)
    hint = (f"run `mata-eval eval {d} --dataset NAME --root PATH` to score it")
    if manifest is None:
        raise ScoresUnavailable(f"{d}: no {SCORES} and no manifest.json (not a mata-eval run folder); {hint}")
    exp_file = manifest.get("experiment_file")
    if not exp_file or not Path(exp_file).is_file():
        raise ScoresUnavailable(f"{d}: no {SCORES}, and the experiment file {exp_file!r} named in its "
                                f"manifest cannot be read; {hint}")
    from ..run.config import load_experiment
    from ..score.evaluate import evaluate_run
    from ..run.runner import load_sequences

    exp = load_experiment(exp_file)
    spec = next((r for r in exp.runs if r.name == manifest.get("run")), None)
    if spec is None:
        raise ScoresUnavailable(f"{d}: no {SCORES}, and run {manifest.get('run')!r} is no longer in {exp_file}; {hint}")
    if spec.config_hash != manifest.get("config_hash"):
        raise ScoresUnavailable(f"{d}: no {SCORES}, and {exp_file} now describes run {spec.name!r} differently "
                                f"(config hash changed); {hint}")
    return evaluate_run(d, load_sequences(spec), spec.metrics_profile)


def cmd_report(args: argparse.Namespace) -> int:
    if getattr(args, "per_sequence", False):
        from .paper import cmd_per_sequence

        return cmd_per_sequence(args)
    if getattr(args, "paper", None) or getattr(args, "experiment", None):
        from .paper import cmd_paper

        if not args.paper:
            args.paper = "auto"
        return cmd_paper(args)
    if not args.run_dirs:
        print("error: give run folders (or --experiment EXP.yaml with --paper)", file=sys.stderr)
        return 2
    runs = []
    for d in args.run_dirs:
        try:
            runs.append(scores_for(Path(d)))
        except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    fmts = FORMATS if args.format == "all" else (args.format,)
    tables = TABLES if args.table == "both" else (args.table,)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    for table in tables:
        for fmt in fmts:
            text = render_table(runs, fmt, table)
            if out and fmt != "terminal":
                path = out / f"{table}.{_EXT[fmt]}"
                path.write_text(text)
                print(f"wrote {path}")
            elif not out or fmt == "terminal":
                print(text)
    if out and not args.no_plots:
        for p in plot_curves(runs, out):
            print(f"plot: {p}")
    return 0


def add_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "report", help="tables (terminal, Markdown, CSV, LaTeX) and plots of scored runs",
        description="Report one or more run folders side by side. A run folder without scores.json is "
                    "scored first when its experiment file is still readable.")
    p.add_argument("run_dirs", nargs="*", metavar="RUN_DIR", help="run folders (or scores.json files)")
    p.add_argument("--out", help="write tables and success / precision / NT2F plots (PNG) into this folder")
    p.add_argument("--format", choices=FORMATS + ("all",), default="terminal",
                   help="table format (default: %(default)s; with --out, 'all' writes every format)")
    p.add_argument("--table", choices=TABLES + ("both",), default="overall",
                   help="overall metrics, per-challenge SR/NT2F (paper Table 2), or both")
    p.add_argument("--no-plots", action="store_true", help="with --out: tables only")
    from .paper import PAPER_TABLES

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
                        "(Markdown, or LaTeX with --format latex)")
    p.set_defaults(func=cmd_report)
