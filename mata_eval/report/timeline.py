"""Timeline plot of a scheduler trace, in the style of the paper's protocol-comparison figure
(section 3.1, fig. "protocol comparison"): one lane per block, a bar from each call's start to
its publish, skipped turns, and the held (zero-order-hold) output with the frame it comes from.

``mata-eval timeline RUN_DIR SEQ [--out PNG] [--frames A:B] [--compare RUN_DIR ...]`` draws
``RUN_DIR/SEQ.trace.csv`` (and the same sequence of other runs as panels below it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from ..run.scheduler import BLOCKS, LANES, TraceEvent
from .plots import as_text

COLORS = {"camera": "#7f7f7f", "egomotion": "#2ca02c", "tracker": "#1f77b4", "estimator": "#d62728"}


@dataclass(frozen=True)
class Call:
    """One call of a block: started at frame ``frame`` (time ``t_start``), published at
    ``t_publish`` (None: still running when the sequence ended)."""

    block: str
    frame: int
    t_start: float
    t_publish: float | None


def _rows(trace_rows: Iterable[Sequence]) -> list[TraceEvent]:
    return [TraceEvent(str(b), str(e), int(f), float(t)) for b, e, f, t in trace_rows]


def calls_from_trace(trace_rows: Iterable[Sequence]) -> dict[str, list[Call]]:
    """Pair each block's starts with its publishes. A block never overlaps its own calls, so
    the i-th publish belongs to the i-th start."""
    rows = _rows(trace_rows)
    out: dict[str, list[Call]] = {}
    for block in BLOCKS:
        starts = [r for r in rows if r.block == block and r.event == "start"]
        pubs = sorted(r.t for r in rows if r.block == block and r.event == "publish")
        if not starts:
            continue
        out[block] = [Call(block, s.frame, s.t, pubs[i] if i < len(pubs) else None)
                      for i, s in enumerate(starts)]
    return out


def infer_fps(trace_rows: Iterable[Sequence], default: float = 30.0) -> float:
    """Camera rate from the trace: ``frame / t`` of its last camera event (a live run's camera
    times are real, a little late: the last frame makes the error smallest), else of any start or
    skip after frame 0 (traces written before the camera lane existed)."""
    rows = _rows(trace_rows)
    cam = [r for r in rows if r.block == "camera" and r.frame > 0 and r.t > 0]
    if cam:
        last = max(cam, key=lambda r: r.frame)
        return last.frame / last.t
    for r in rows:
        if r.event in ("start", "skip") and r.frame > 0 and r.t > 0:
            return r.frame / r.t
    return default


def held_segments(trace_rows: Iterable[Sequence], n_frames: int | None = None) -> list[tuple[float, float, int]]:
    """The scored output over time as ``(t_from, t_to, capture_frame)`` segments: the output
    block is the estimator when the trace has one, else the tracker; its initialisation
    publishes nothing, so the initial box (capture frame 0) is held until its first output.
    Link delays to the scoring are not in the trace and are not drawn."""
    rows = _rows(trace_rows)
    calls = calls_from_trace(rows)
    block = "estimator" if "estimator" in calls else "tracker"
    fps = infer_fps(rows)
    t_end = (n_frames if n_frames is not None else max((r.frame for r in rows), default=0) + 1) / fps
    pubs = [(c.t_publish, c.frame) for c in calls.get(block, [])[1:] if c.t_publish is not None]
    if block == "estimator":  # the estimator's initial estimate (the ground-truth box) holds from t = 0
        pubs = [(0.0, 0)] + pubs
    segs: list[tuple[float, float, int]] = []
    t_prev, src = 0.0, 0
    for t, frame in pubs:
        if t > t_prev:
            segs.append((t_prev, t, src))
        t_prev, src = t, frame
    if t_end > t_prev:
        segs.append((t_prev, t_end, src))
    return segs


def plot_timeline(trace_rows: Iterable[Sequence] | Mapping[str, Iterable[Sequence]], path: str | Path,
                  frames: tuple[int, int] | None = None, title: str | None = None,
                  fps: float | None = None) -> Path:
    """Draw a trace as the paper's protocol figure and save it (PNG, PDF or SVG by extension).

    ``trace_rows``: one trace, or ``{label: trace}`` for one panel per run stacked on a shared
    frame axis (e.g. LTP, DSP and EOP of one sequence, as in the paper's figure).
    ``frames``: the half-open frame range ``(A, B)`` to show (default: the whole trace)."""
    from matplotlib.figure import Figure  # no pyplot: no global backend state

    panels = ({str(k): _rows(v) for k, v in trace_rows.items()} if isinstance(trace_rows, Mapping)
              else {"": _rows(trace_rows)})
    if not panels or any(not rows for rows in panels.values()):
        raise ValueError("empty trace: nothing to draw")
    n_frames = max(r.frame for rows in panels.values() for r in rows) + 1
    a, b = frames if frames is not None else (0, n_frames)
    if not 0 <= a < b:
        raise ValueError(f"frame range {a}:{b}: expected 0 <= A < B")
    heights = [len(_lanes(rows)) for rows in panels.values()]
    width = min(40.0, max(8.0, 0.25 * (b - a) + 3))
    fig = Figure(figsize=(width, 0.6 * sum(heights) + 0.5 * len(panels) + 1.0))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False, height_ratios=heights)[:, 0]
    for ax, (label, rows) in zip(axes, panels.items()):
        panel_fps = fps or infer_fps(rows)
        _draw_panel(ax, rows, a, b, panel_fps)
        if label:
            ax.set_title(as_text(label), loc="left", fontsize=9)
    axes[-1].set_xlabel(f"camera frame ({fps or infer_fps(next(iter(panels.values()))):g} Hz)\nbars: start -> "
                        "publish, labelled with the frame processed; x: skipped turn; arrows: detections")
    if title:
        fig.suptitle(as_text(title))
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _lanes(rows: list[TraceEvent]) -> list[str]:
    blocks = {r.block for r in rows if r.event == "start"}
    return [lane for lane in LANES if lane == "camera" or lane in blocks] + ["output"]


def _draw_panel(ax, rows: list[TraceEvent], a: int, b: int, fps: float) -> None:
    """One run's lanes: camera ticks, start -> publish bars, skips, detection arrows, held output."""
    n_frames = max(r.frame for r in rows) + 1
    calls = calls_from_trace(rows)
    lanes = _lanes(rows)
    y = {lane: len(lanes) - 1 - i for i, lane in enumerate(lanes)}
    for lane in lanes:
        ax.axhline(y[lane], color="#dddddd", lw=0.8, zorder=0)
    for k in range(a, b + 1):
        ax.axvline(k, color="#f0f0f0", lw=0.6, zorder=0)

    # Camera: delivered frames as ticks, dropped ones (DSP) greyed out.
    for r in rows:
        if r.block == "camera" and a <= r.frame < b:
            ax.plot([r.frame], [y["camera"]], marker="|" if r.event == "publish" else "x", ms=10,
                    color=COLORS["camera"] if r.event == "publish" else "#cccccc")

    for block, cs in calls.items():
        for c in cs:
            x0 = c.t_start * fps
            x1 = (c.t_publish * fps) if c.t_publish is not None else float(n_frames)
            if x1 < a or x0 >= b:
                continue
            w = max(x1 - x0, 0.12)  # a zero-latency call is drawn as a thin bar
            ax.broken_barh([(x0, w)], (y[block] - 0.3, 0.6), facecolors=COLORS[block], alpha=0.75,
                           edgecolor="black", linewidth=0.5)
            if x1 - x0 >= 0.9:
                ax.text(x0 + 0.1, y[block], str(c.frame), va="center", ha="left", fontsize=7, color="white")
        for r in rows:
            if r.block == block and r.event == "skip" and a <= r.frame < b:
                ax.plot([r.frame], [y[block]], marker="x", color="black", ms=5)

    # Each detection (not the initialisation) goes down to its consumer when it is published.
    out_block = "estimator" if "estimator" in calls else "tracker"
    consumer = "estimator" if out_block == "estimator" else "output"
    for c in calls.get("tracker", [])[1:]:
        if c.t_publish is not None and a <= c.t_publish * fps < b:
            x = c.t_publish * fps
            ax.annotate("", xy=(x, y[consumer] + 0.32), xytext=(x, y["tracker"] - 0.3),
                        arrowprops={"arrowstyle": "->", "color": COLORS["tracker"], "lw": 1.0})

    # Held output: alternate shades, labelled with the capture frame of the held value.
    for i, (t0, t1, src) in enumerate(held_segments(rows, n_frames)):
        x0, x1 = max(t0 * fps, a), min(t1 * fps, b)
        if x1 <= x0:
            continue
        ax.broken_barh([(x0, x1 - x0)], (y["output"] - 0.3, 0.6), facecolors=COLORS[out_block],
                       alpha=0.25 if i % 2 else 0.45, edgecolor="none")
        if x1 - x0 >= 0.9:
            ax.text(x0 + 0.1, y["output"], "init" if (src == 0 and i == 0) else str(src),
                    va="center", ha="left", fontsize=7)

    ax.set_yticks([y[lane] for lane in lanes])
    ax.set_yticklabels([f"held {out_block}" if lane == "output" else lane for lane in lanes])
    ax.set_xlim(a - 0.2, b + 0.2)
    ax.set_ylim(-0.7, len(lanes) - 0.3)
