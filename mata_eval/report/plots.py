"""Success, precision, normalised precision and NT2F plots of scored runs (PNG, matplotlib's
Agg canvas; no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..score.evaluate import RunScores
from ..score.metrics import NORM_GRID, PIXEL_GRID, Summary
from .tables import pct


def nt2f_survival(values: Sequence[float], grid: np.ndarray) -> np.ndarray:
    """Fraction of sequences whose NT2F exceeds each normalised time of ``grid``: the share of
    sequences still tracked at that point. Its area over [0, 1] is the mean NT2F."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    if v.size == 0:
        return np.full(len(grid), np.nan)
    g = np.asarray(grid, dtype=float)
    # at t = 1 the never-failed sequences (NT2F = 1) are still tracked: right-continuous end
    return (v[None, :] > np.minimum(g, np.nextafter(1.0, 0.0))[:, None]).mean(axis=1)


def run_colour(i: int) -> tuple[float, float, float]:
    """RGB colour of the ``i``-th run of a report: matplotlib's tab10 colours, then their light
    tab20 shades (18 runs before a colour repeats), without the greens, which are the ground
    truth's in ``mata-eval play``. Every plot of a report, and the playback video, gives run ``i``
    this colour whatever the order of its legend."""
    cycle = _colour_cycle()
    return tuple(cycle[i % len(cycle)])


def _colour_cycle() -> list:
    from matplotlib import colormaps

    tab20 = colormaps["tab20"].colors   # (dark, light) pairs; the dark ones are tab10's
    return [tab20[j] for j in range(0, 20, 2) if j != 4] + [tab20[j] for j in range(1, 20, 2) if j != 5]


def as_text(name: str) -> str:
    """``name`` for a matplotlib label: a ``$`` is text, not mathtext (it failed the plot)."""
    return name.replace("$", r"\$")


def _label(r: RunScores, value: float) -> str:
    """A legend entry: the run's name and ``value``."""
    return as_text(r.name) + f" [{pct(value)}]"


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
    n = len(ax.get_legend_handles_labels()[0])
    if n <= 8:
        ax.legend(loc="lower left" if "Success" in title or "NT2F" in title else "lower right", fontsize=8)
        fig.tight_layout()
    else:   # many runs (a matrix): the legend beside the axes, the figure as tall as it needs
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=7)
        fig.set_size_inches(5.0, max(4.0, 0.16 * n + 0.6))
    fig.savefig(path, bbox_inches="tight")
    return path


def plot_curves(runs: Sequence[RunScores], out_dir: Path) -> list[Path]:
    """Write ``success.png``, ``precision.png``, ``norm_precision.png`` and ``nt2f.png`` into
    ``out_dir``; legends carry MSR, P@20, PR and mean NT2F, runs sorted best first; run ``i``
    has :func:`run_colour` ``(i)`` in every plot."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = list(runs)
    colour = {id(r): run_colour(i) for i, r in enumerate(runs)}  # by position: the same in every plot
    n = len(_colour_cycle())   # past the colours, dashed, then dotted
    style = {id(r): ("-", "--", ":")[(i // n) % 3] for i, r in enumerate(runs)}
    paths = []

    def by(metric: str) -> list[RunScores]:
        return sorted(runs, key=lambda r: -np.nan_to_num(getattr(r.summary.overall, metric), nan=-1.0))

    fig, ax = _figure()
    iou_x = np.linspace(0.0, 1.0, 21)
    for r in by("msr"):
        s: Summary = r.summary.overall
        ax.plot(iou_x, s.success_curve, color=colour[id(r)], linestyle=style[id(r)], label=_label(r, s.msr))
    ax.set_xlim(0, 1)
    paths.append(_finish(fig, ax, "Success plot (MSR)", "IoU threshold", "Success rate", out / "success.png"))

    fig, ax = _figure()
    for r in by("precision20"):
        s = r.summary.overall
        ax.plot(PIXEL_GRID, s.precision_curve, color=colour[id(r)], linestyle=style[id(r)], label=_label(r, s.precision20))
    ax.set_xlim(0, 50)
    paths.append(_finish(fig, ax, "Precision plot (P@20)", "Centre error threshold (px)", "Precision",
                         out / "precision.png"))

    fig, ax = _figure()
    for r in by("pr"):
        s = r.summary.overall
        ax.plot(NORM_GRID, s.norm_precision_curve, color=colour[id(r)], linestyle=style[id(r)], label=_label(r, s.pr))
    ax.set_xlim(0, 0.5)
    paths.append(_finish(fig, ax, "Normalised precision plot (PR)", "Normalised centre error threshold",
                         "Precision", out / "norm_precision.png"))

    fig, ax = _figure()
    grid = np.linspace(0.0, 1.0, 201)
    for r in by("nt2f"):
        surv = nt2f_survival([s.nt2f for s in r.sequences.values()], grid)
        ax.step(grid, surv, where="post", color=colour[id(r)], linestyle=style[id(r)], label=_label(r, r.summary.overall.nt2f))
    ax.set_xlim(0, 1)
    paths.append(_finish(fig, ax, "NT2F plot (sequences not yet failed)", "Normalised time t / N",
                         "Fraction of sequences", out / "nt2f.png"))
    return paths
