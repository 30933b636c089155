"""The paper's four results tables, rendered from run folders, and a one-page HTML summary.

Each run is placed in its row / column from its manifest (``manifest.json``: the resolved
configuration), never from its name alone:

- Table 1 (``protocols``, paper tab:result_protocol): rows Protocol x VOT (tracker) x MATA,
  column groups per dataset (``+occ`` when the occlusion augmentation was on), SR and NT2F;
- Table 2 (``challenges``, tab:metrics_per_challenges): rows VOT x MATA, column groups per
  challenge group (occlusion, distractor, high dynamic, out of view), SR and NT2F;
- Table 3 (``ablation``, tab:ablation_study): one row per configuration with its ego-motion /
  EKF / score marks, a description, PR, SR, MSR and NT2F;
- Table 4 (``embedded``, tab:embedded_results): rows VOT x MATA; SR, NT2F and tracker frequency
  of the embedded measurement (``vot_rt``: the tracker's real wall time on the machine that ran
  it), then the absolute differences |X - embedded| of EOP and LTP, with their frequencies.

MATA is "on" when the run has an estimator other than the zero-order hold (``zoh`` only holds the
tracker's box, so it is the baseline). Formats: Markdown and LaTeX booktabs (needs
``\\usepackage{booktabs,multirow,amssymb}``), and HTML for :func:`html_summary`.
"""

from __future__ import annotations

import argparse
import base64
import html
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..score.evaluate import RunScores

PAPER_TABLES = ("protocols", "challenges", "ablation", "embedded")
PAPER_FORMATS = ("markdown", "latex")

TRACKER_NAMES = {"kcf": "KCF", "vittrack": "VitTrack", "nanotrack": "NanoTrack",
                 "mixformerv2": "MixFormerV2", "ostrack": "OSTrack"}
DATASET_NAMES = {"uav123": "UAV123", "uav123_10fps": "UAV123@10fps", "uav20l": "UAV20L", "dtb70": "DTB70",
                 "uavdt": "UAVDT", "vtuav": "VTUAV", "synthetic": "Synthetic", "folder": "Folder"}
CHALLENGE_ORDER = ("occlusion", "distractor", "high dynamic", "out of view")
CAPTIONS = {
    "protocols": "SR and NT2F of each tracker with and without MATA under LTP and EOP (paper Table 1).",
    "challenges": "SR and NT2F per challenge (paper Table 2).",
    "ablation": "Contribution of each MATA block (paper Table 3).",
    "embedded": "Embedded measurement (tracker at its real speed) and the absolute differences of EOP "
                "and LTP with respect to it (paper Table 4). Freq. is the tracker's rate in Hz.",
}


class PlacementError(ValueError):
    """A run cannot be placed in the requested table (the message names the run folder)."""


# --- where a run goes -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PlacedRun:
    """A scored run and the coordinates the paper's tables use for it."""

    scores: RunScores
    config: Mapping[str, Any]
    tracker: str  # display name, e.g. "VitTrack"
    mata: bool
    protocol: str  # display label, e.g. "EOP @ 10 Hz"
    protocol_order: tuple
    dataset: str  # display label, e.g. "Synthetic+occ"
    dataset_key: tuple  # (dataset name, occlusion on)

    @property
    def name(self) -> str:
        return self.scores.name


def _fmt_hz(v: Any) -> str:
    return f"{float(v):g}"


def protocol_label(block: Mapping[str, Any] | None) -> tuple[str, tuple]:
    """Display label and sort key of a protocol block: LTP first, then EOP from the fastest
    tracker rate down, then the others (paper Table 1 order)."""
    block = block or {"name": "ltp"}
    name = block.get("name")
    if name == "ltp":
        return "LTP", (0, 0.0)
    if name == "eop":
        hz = block.get("tracker_hz")
        if hz is None:
            return "EOP @ camera rate", (1, -math.inf)
        if hz == "profile":
            lat = " (profile latencies)" if block.get("tracker_latency") == "profile" else ""
            return f"EOP @ profile rate{lat}", (2, 0.0)
        return f"EOP @ {_fmt_hz(hz)} Hz", (1, -float(hz))
    if name == "dsp":
        return f"DSP (n = {block.get('n', 3)})", (3, float(block.get("n", 3)))
    if name == "vot_rt":
        scale = float(block.get("time_scale", 1.0))
        return ("VOT real-time" + ("" if scale == 1.0 else f" (x{scale:g})")), (4, scale)
    return str(name), (5, 0.0)


def is_mata(config: Mapping[str, Any]) -> bool:
    est = config.get("estimator")
    return isinstance(est, Mapping) and est.get("name") not in (None, "zoh")


def place(scores: RunScores, manifest: Mapping[str, Any] | None) -> PlacedRun:
    """Place a run from its manifest; raises :class:`PlacementError` without one."""
    if not manifest or not isinstance(manifest.get("config"), Mapping):
        raise PlacementError(f"{scores.path}: no manifest.json with the run's configuration; the paper's "
                             f"tables place runs from it (run the experiment with `mata-eval run`)")
    cfg = manifest["config"]
    tracker = (cfg.get("tracker") or {}).get("name", "?")
    dataset = (cfg.get("dataset") or {}).get("name", "?")
    occ = cfg.get("occlusion") is not None
    label, order = protocol_label(cfg.get("protocol"))
    ds = DATASET_NAMES.get(dataset, dataset) + ("+occ" if occ else "")
    return PlacedRun(scores, cfg, TRACKER_NAMES.get(tracker, tracker), is_mata(cfg), label, order, ds,
                     (dataset, occ))


def load_runs(run_dirs: Sequence[str | Path]) -> list[PlacedRun]:
    """Score (when needed) and place every run folder."""
    from ..run import results
    from .tables import scores_for

    placed = []
    for d in run_dirs:
        scores = scores_for(Path(d))
        manifest = results.read_manifest(Path(scores.path)) if Path(scores.path).is_dir() else None
        placed.append(place(scores, manifest))
    return placed


# --- table structure --------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperTable:
    """A results table: ``stub`` leading columns (merged down where equal, like \\multirow),
    column groups (label, span) over the value columns, rows, and the row indices that start a
    new block (a double rule in LaTeX, as in the paper)."""

    key: str
    caption: str
    stub: list[str]
    groups: list[tuple[str, int]]
    columns: list[str]
    rows: list[list[str]]
    blocks: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def header(self) -> list[str]:
        """Flat column names: stub, then "<group> <column>"."""
        names, k = list(self.stub), 0
        for label, span in self.groups:
            names += [f"{label} {c}".strip() for c in self.columns[k:k + span]]
            k += span
        return names + list(self.columns[k:])


CHECK, CROSS, NONE = "yes", "no", "-"


def _pct(v: float | None) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{100.0 * v:.1f}"


def _unique(cells: dict, key, run: PlacedRun, table: str) -> None:
    if key in cells:
        raise PlacementError(f"{table} table: runs {cells[key].name!r} ({cells[key].scores.path}) and "
                             f"{run.name!r} ({run.scores.path}) fall in the same cell {key}; report them separately")
    cells[key] = run


def _tracker_order(runs: Sequence[PlacedRun]) -> list[str]:
    seen: list[str] = []
    for r in runs:
        if r.tracker not in seen:
            seen.append(r.tracker)
    return seen


def _dataset_order(runs: Sequence[PlacedRun]) -> list[tuple[str, bool]]:
    first: dict[str, int] = {}
    for i, r in enumerate(runs):
        first.setdefault(r.dataset_key[0], i)
    keys = {r.dataset_key for r in runs}
    return sorted(keys, key=lambda k: (first[k[0]], k[1]))


def _mark(v: bool | None) -> str:
    return NONE if v is None else (CHECK if v else CROSS)


def protocols_table(runs: Sequence[PlacedRun]) -> PaperTable:
    """Paper Table 1: Protocol x VOT x MATA rows, one SR / NT2F column pair per dataset."""
    cells: dict = {}
    for r in runs:
        _unique(cells, (r.protocol, r.tracker, r.mata, r.dataset_key), r, "protocols")
    datasets = _dataset_order(runs)
    label_of = {r.dataset_key: r.dataset for r in runs}
    protocols = sorted({(r.protocol_order, r.protocol) for r in runs})
    rows, blocks = [], []
    for _, proto in protocols:
        blocks.append(len(rows))
        for tracker in _tracker_order(runs):
            for mata in (False, True):
                vals = [cells.get((proto, tracker, mata, d)) for d in datasets]
                if not any(vals):
                    continue
                row = [proto, tracker, _mark(mata)]
                for v in vals:
                    s = v.scores.summary.overall if v else None
                    row += [_pct(s.sr), _pct(s.nt2f)] if s else ["-", "-"]
                rows.append(row)
    return PaperTable("protocols", CAPTIONS["protocols"], ["Protocol", "VOT", "MATA"],
                      [(label_of[d], 2) for d in datasets], ["SR", "NT2F"] * len(datasets), rows, blocks)


def challenges_table(runs: Sequence[PlacedRun]) -> PaperTable:
    """Paper Table 2: VOT x MATA rows, one SR / NT2F column pair per challenge group (the group's
    sequence count in brackets). Protocol / dataset columns are added when they vary."""
    names: list[str] = [g for g in CHALLENGE_ORDER if any(g in r.scores.summary.groups for r in runs)]
    for r in runs:
        names += [g for g in r.scores.summary.groups if g not in names]
    n = {g: max((r.scores.summary.groups[g].n_sequences for r in runs if g in r.scores.summary.groups), default=0)
         for g in names}
    vary_p = len({r.protocol for r in runs}) > 1
    vary_d = len({r.dataset_key for r in runs}) > 1
    stub = (["Dataset"] if vary_d else []) + (["Protocol"] if vary_p else []) + ["VOT", "MATA"]
    cells: dict = {}
    for r in runs:
        _unique(cells, (r.dataset_key, r.protocol, r.tracker, r.mata), r, "challenges")
    order = sorted({(r.dataset_key, r.protocol_order, r.protocol) for r in runs},
                   key=lambda k: (_dataset_order(runs).index(k[0]), k[1]))
    rows, blocks = [], []
    for dkey, _, proto in order:
        for tracker in _tracker_order(runs):
            if not any((dkey, proto, tracker, m) in cells for m in (False, True)):
                continue
            blocks.append(len(rows))
            for mata in (False, True):
                r = cells.get((dkey, proto, tracker, mata))
                if r is None:
                    continue
                row = ([r.dataset] if vary_d else []) + ([proto] if vary_p else []) + [tracker, _mark(mata)]
                for g in names:
                    s = r.scores.summary.groups.get(g)
                    row += [_pct(s.sr), _pct(s.nt2f)] if s is not None and s.n_sequences else ["-", "-"]
                rows.append(row)
    groups = [(f"{g[:1].upper()}{g[1:]} ({n[g]})", 2) for g in names]
    notes = [f"{g}: attributes {', '.join(runs[0].scores.summary.group_definitions.get(g, ()))}"
             for g in names if runs and runs[0].scores.summary.group_definitions.get(g)]
    return PaperTable("challenges", CAPTIONS["challenges"], stub, groups, ["SR", "NT2F"] * len(names),
                      rows, blocks, notes)


def ablation_marks(config: Mapping[str, Any]) -> tuple[bool, bool, bool | None, str]:
    """(ego-motion used, EKF used, explainable score used or None when the tracker has no choice,
    description) of one configuration, from its resolved config (paper Table 3 columns)."""
    est = config.get("estimator") or {}
    tracker = config.get("tracker") or {}
    ekf = est.get("name") == "homography_ekf"
    ego = config.get("egomotion") is not None and (not ekf or est.get("camera", True))
    conf = tracker.get("confidence")
    score = None if conf is None else conf == "window"
    tname = TRACKER_NAMES.get(tracker.get("name"), tracker.get("name", "?"))
    if not is_mata(config):
        details = f"{tname} (baseline)" + (", explainable score" if score else "")
    elif not ekf:
        details = f"estimator {est.get('name')}"
    else:
        parts = []
        if not est.get("camera", True) or config.get("egomotion") is None:
            parts.append("no camera compensation")
        parts.append({"ca": "constant acceleration model", "cj": "constant jerk model"}.get(est.get("model", "cv"), ""))
        if not est.get("gating", True):
            parts.append("no threshold on measurements")
        if est.get("delay") == "compensate":
            parts.append("delay compensation")
        if est.get("gating", True) and est.get("tau_ewma", PAPER_TAU_EWMA) != PAPER_TAU_EWMA:
            parts.append(f"confidence gate tau_ewma = {est['tau_ewma']:g}")
        details = ", ".join(p for p in parts if p) or "MATA"
    return ego, ekf, score, details


PAPER_TAU_EWMA = 0.25  # homography_ekf's default gate (paper eq. ewma_score)
_CONFIG_NUMBER = re.compile(r"^(\d+)[-_ ]")


def ablation_table(runs: Sequence[PlacedRun]) -> PaperTable:
    """Paper Table 3: one row per configuration (numbered by the run label's leading number, else
    in the order given), its block marks, description, PR, SR, MSR, NT2F. A VOT column is added
    when the runs use more than one tracker (rows then grouped by tracker)."""
    def number(i_r):
        i, r = i_r
        m = _CONFIG_NUMBER.match(r.name)
        return (int(m.group(1)) if m else 10_000 + i)

    trackers = _tracker_order(runs)
    vary = len(trackers) > 1
    ordered = sorted(enumerate(runs), key=lambda i_r: (trackers.index(i_r[1].tracker), number(i_r)))
    rows, blocks = [], []
    count = 0
    for i, r in ordered:
        if vary and (not rows or rows[-1][0] != r.tracker):
            blocks.append(len(rows))
            count = 0
        count += 1
        ego, ekf, score, details = ablation_marks(r.config)
        m = _CONFIG_NUMBER.match(r.name)
        s = r.scores.summary.overall
        rows.append(([r.tracker] if vary else [])
                    + [m.group(1) if m else str(count), _mark(ego), _mark(ekf), _mark(score), details,
                       _pct(s.pr), _pct(s.sr), _pct(s.msr), _pct(s.nt2f)])
    if not vary:
        blocks = [0, 2, 3] if len(rows) >= 4 else [0]
    stub = (["VOT"] if vary else []) + ["Configuration", "Ego motion", "EKF", "Score", "Details"]
    return PaperTable("ablation", CAPTIONS["ablation"], stub, [], ["PR", "SR", "MSR", "NT2F"], rows, blocks)


def embedded_role(run: PlacedRun) -> str:
    """``embedded`` (vot_rt: the tracker's measured wall time sets its rate and latency),
    ``eop`` or ``ltp``; anything else is not part of Table 4."""
    name = (run.config.get("protocol") or {}).get("name")
    return {"vot_rt": "embedded"}.get(name, name)


def _tracker_hz(run: PlacedRun) -> float:
    f = run.scores.frequencies.get("tracker")
    return f.scheduled_hz if f is not None else float("nan")


def _diff(a: float, b: float) -> str:
    return "-" if not (math.isfinite(a) and math.isfinite(b)) else f"{100.0 * abs(a - b):.1f}"


def embedded_table(runs: Sequence[PlacedRun]) -> PaperTable:
    """Paper Table 4: per tracker x MATA, the embedded measurement's SR, NT2F, Freq., then
    |SR - SR_embedded|, |NT2F - NT2F_embedded| and Freq. of EOP and of LTP. A note gives the mean
    discrepancies and their LTP / EOP ratio (the paper's "6.4x for SR and 4.7x for NT2F")."""
    cells: dict = {}
    for r in runs:
        role = embedded_role(r)
        if role not in ("embedded", "eop", "ltp"):
            raise PlacementError(f"embedded table: run {r.name!r} ({r.scores.path}) uses protocol {r.protocol!r}; "
                                 f"expected vot_rt (embedded measurement), eop or ltp")
        _unique(cells, (r.dataset_key, r.tracker, r.mata, role), r, "embedded")
    rows, blocks = [], []
    diffs: dict[str, list[tuple[float, float]]] = {"eop": [], "ltp": []}
    for dkey in _dataset_order(runs):
        for tracker in _tracker_order(runs):
            if not any((dkey, tracker, m, role) in cells for m in (False, True) for role in ("embedded", "eop", "ltp")):
                continue
            blocks.append(len(rows))
            for mata in (False, True):
                emb = cells.get((dkey, tracker, mata, "embedded"))
                if emb is None and not any((dkey, tracker, mata, ro) in cells for ro in ("eop", "ltp")):
                    continue
                e = emb.scores.summary.overall if emb else None
                row = [tracker, _mark(mata)]
                row += [_pct(e.sr), _pct(e.nt2f), f"{_tracker_hz(emb):.1f}"] if e else ["-", "-", "-"]
                for role in ("eop", "ltp"):
                    r = cells.get((dkey, tracker, mata, role))
                    if r is None:
                        row += ["-", "-", "-"]
                        continue
                    s = r.scores.summary.overall
                    if e is not None:
                        row += [_diff(s.sr, e.sr), _diff(s.nt2f, e.nt2f)]
                        diffs[role].append((abs(s.sr - e.sr), abs(s.nt2f - e.nt2f)))
                    else:
                        row += ["-", "-"]
                    row.append(f"{_tracker_hz(r):.1f}")
                rows.append(row)
    notes = []
    if diffs["eop"] and diffs["ltp"]:
        def mean(role, k):
            vals = [d[k] for d in diffs[role] if math.isfinite(d[k])]
            return sum(vals) / len(vals) if vals else float("nan")
        for k, m in ((0, "SR"), (1, "NT2F")):
            e, l_ = mean("eop", k), mean("ltp", k)
            ratio = l_ / e if e > 0 else float("inf")
            notes.append(f"mean |Delta {m}|: EOP {100 * e:.1f}, LTP {100 * l_:.1f} points "
                         f"(LTP / EOP = {ratio:.1f}x)")
    return PaperTable("embedded", CAPTIONS["embedded"], ["VOT", "MATA"],
                      [("Embedded", 3), ("EOP", 3), ("LTP", 3)],
                      ["SR", "NT2F", "Freq.", "|dSR|", "|dNT2F|", "Freq.", "|dSR|", "|dNT2F|", "Freq."], rows, blocks,
                      notes)


def sequence_comparison(base: RunScores, other: RunScores) -> PaperTable:
    """Per-sequence evidence for a pair of runs (e.g. baseline and MATA): attributes, SR and NT2F
    of each, their difference in points, and the frame of the first failure (NT2F's T_f; "-"
    when the tracker never failed). Sequences in both runs, in the base run's order; the last
    row is the mean (the tables' value)."""
    common = [s for s in base.sequences if s in other.sequences]
    if not common:
        raise PlacementError(f"runs {base.name!r} and {other.name!r} have no sequence in common")
    rows = []

    def ff(v):
        return "-" if v is None else str(v)

    for s in common:
        a, b = base.sequences[s], other.sequences[s]
        attrs = " ".join(sorted(base.attributes.get(s, ())))
        rows.append([s, attrs, _pct(a.sr), _pct(b.sr), _signed(b.sr - a.sr), _pct(a.nt2f), _pct(b.nt2f),
                     _signed(b.nt2f - a.nt2f), ff(a.failure_frame), ff(b.failure_frame)])

    def mean(run, m):
        vals = [getattr(run.sequences[s], m) for s in common]
        vals = [v for v in vals if math.isfinite(v)]
        return sum(vals) / len(vals) if vals else float("nan")

    ma, mb = {m: mean(base, m) for m in ("sr", "nt2f")}, {m: mean(other, m) for m in ("sr", "nt2f")}
    rows.append([f"mean ({len(common)})", "", _pct(ma["sr"]), _pct(mb["sr"]), _signed(mb["sr"] - ma["sr"]),
                 _pct(ma["nt2f"]), _pct(mb["nt2f"]), _signed(mb["nt2f"] - ma["nt2f"]), "", ""])
    return PaperTable("sequences", f"Per sequence: {base.name} (A) against {other.name} (B).",
                      ["Sequence", "Attributes"], [("SR", 3), ("NT2F", 3), ("First failure", 2)],
                      ["A", "B", "B-A", "A", "B", "B-A", "A", "B"], rows, [len(rows) - 1])


def _signed(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{100.0 * v:+.1f}"


BUILDERS: dict[str, Callable[[Sequence[PlacedRun]], PaperTable]] = {
    "protocols": protocols_table, "challenges": challenges_table,
    "ablation": ablation_table, "embedded": embedded_table,
}


def build_table(kind: str, runs: Sequence[PlacedRun]) -> PaperTable:
    if kind not in BUILDERS:
        raise ValueError(f"unknown paper table {kind!r}; expected one of {', '.join(PAPER_TABLES)}")
    if not runs:
        raise PlacementError(f"{kind} table: no runs given")
    t = BUILDERS[kind](list(runs))
    for r in runs:  # a mean over fewer sequences must not pass unnoticed
        if r.scores.failures or r.scores.missing:
            t.notes.append(f"{r.name}: {len(r.scores.failures)} failed and {len(r.scores.missing)} missing "
                           f"sequence(s) are not in its means ({r.scores.summary.overall.n_sequences} sequences)")
    return t


# --- rendering --------------------------------------------------------------------------------


def _merged_stub(t: PaperTable) -> list[list[int]]:
    """For each row and stub column, how many rows the cell spans (0: covered by the one above).
    A stub cell merges with the following rows of the same block while it and every stub cell to
    its left are equal."""
    spans = [[1] * len(t.stub) for _ in t.rows]
    starts = set(t.blocks) | {0}
    for c in range(len(t.stub)):
        i = 0
        while i < len(t.rows):
            j = i + 1
            while (j < len(t.rows) and j not in starts
                   and all(t.rows[j][k] == t.rows[i][k] for k in range(c + 1))
                   and (c == 0 or spans[j][c - 1] == 0)):
                j += 1
            spans[i][c] = j - i
            for k in range(i + 1, j):
                spans[k][c] = 0
            i = j
    return spans


_MD_MARK = {CHECK: "✓", CROSS: "✗"}


def to_markdown(t: PaperTable) -> str:
    """GitHub Markdown: merged stub cells left blank below their first row, group labels folded
    into the column names."""
    spans = _merged_stub(t)
    head = t.header
    out = ["| " + " | ".join(h.replace("|", "\\|") for h in head) + " |",
           "|" + "|".join([":---"] * len(t.stub) + ["---:"] * (len(head) - len(t.stub))) + "|"]
    for i, row in enumerate(t.rows):
        cells = [("" if spans[i][c] == 0 else _MD_MARK.get(v, v)) if c < len(t.stub) else v
                 for c, v in enumerate(row)]
        out.append("| " + " | ".join(v.replace("|", "\\|") for v in cells) + " |")
    text = "\n".join(out) + "\n"
    if t.notes:
        text += "\n" + "\n".join(f"- {n}" for n in t.notes) + "\n"
    return text


_TEX_MARK = {CHECK: r"$\checkmark$", CROSS: r"$\times$"}
# column names written in math in LaTeX (a bare "|" is not a bar in every font encoding)
_TEX_COLUMNS = {"|dSR|": r"$\Delta$SR", "|dNT2F|": r"$\Delta$NT2F"}


def to_latex(t: PaperTable, label: str | None = None) -> str:
    """A booktabs ``table*`` like the paper's: ``\\multirow`` stub cells, ``\\multicolumn`` dataset
    / challenge groups, a double ``\\midrule`` between blocks."""
    from .tables import latex_escape

    def tex(v: str, stub: bool) -> str:
        return _TEX_MARK[v] if stub and v in _TEX_MARK else latex_escape(v)

    n_stub, n_val = len(t.stub), len(t.columns)
    spec = "|".join(["c"] * n_stub)
    k = 0
    val_spec = []
    for _, span in (t.groups or [("", n_val)]):
        val_spec.append("c" * span)
        k += span
    if k < n_val:
        val_spec.append("c" * (n_val - k))
    spec += "|" + "|".join(val_spec)
    out = [r"% requires \usepackage{booktabs,multirow,amssymb}", r"\begin{table*}[!h]", r"  \centering",
           rf"  \begin{{tabular}}{{{spec}}}", r"    \toprule"]
    if t.groups:
        cells = [rf"\multirow{{2}}{{*}}{{{latex_escape(s)}}}" for s in t.stub]
        for gi, (g, span) in enumerate(t.groups):
            sep = "" if gi == len(t.groups) - 1 else "|"
            cells.append(rf"\multicolumn{{{span}}}{{c{sep}}}{{{latex_escape(g)}}}")
        out.append("    " + " & ".join(cells) + r" \\")
        out.append("    " + " & ".join([""] * n_stub + [_TEX_COLUMNS.get(c) or latex_escape(c) for c in t.columns])
                   + r" \\")
    else:
        out.append("    " + " & ".join(latex_escape(c) for c in t.stub + t.columns) + r" \\")
    out.append(r"    \midrule")
    spans = _merged_stub(t)
    for i, row in enumerate(t.rows):
        if i in t.blocks:
            out.append(r"    \midrule")
        cells = []
        for c, v in enumerate(row):
            if c < n_stub:
                s = spans[i][c]
                cells.append("" if s == 0 else (tex(v, True) if s == 1 else rf"\multirow{{{s}}}{{*}}{{{tex(v, True)}}}"))
            else:
                cells.append(tex(v, False))
        out.append("    " + " & ".join(cells) + r" \\")
    out += [r"    \bottomrule", r"  \end{tabular}", rf"  \caption{{{latex_escape(t.caption)}}}",
            rf"  \label{{{label or 'tab:' + t.key}}}", r"\end{table*}"]
    out += [f"% {n}" for n in t.notes]
    return "\n".join(out) + "\n"


def render_paper_table(t: PaperTable, fmt: str) -> str:
    if fmt == "markdown":
        return to_markdown(t)
    if fmt == "latex":
        return to_latex(t)
    raise ValueError(f"unknown paper table format {fmt!r}; expected one of {', '.join(PAPER_FORMATS)}")


def to_html(t: PaperTable) -> str:
    """An HTML ``<table>`` with ``rowspan`` stub cells and ``colspan`` group headers."""
    e = html.escape
    spans = _merged_stub(t)
    out = [f'<table class="paper" id="table-{e(t.key)}">', f"<caption>{e(t.caption)}</caption>", "<thead>"]
    if t.groups:
        out.append("<tr>" + "".join(f'<th rowspan="2">{e(s)}</th>' for s in t.stub)
                   + "".join(f'<th colspan="{span}">{e(g)}</th>' for g, span in t.groups) + "</tr>")
        out.append("<tr>" + "".join(f"<th>{e(c)}</th>" for c in t.columns) + "</tr>")
    else:
        out.append("<tr>" + "".join(f"<th>{e(c)}</th>" for c in t.stub + t.columns) + "</tr>")
    out.append("</thead><tbody>")
    for i, row in enumerate(t.rows):
        cls = ' class="block"' if i in t.blocks and i > 0 else ""
        cells = []
        for c, v in enumerate(row):
            if c < len(t.stub):
                if spans[i][c] == 0:
                    continue
                rs = f' rowspan="{spans[i][c]}"' if spans[i][c] > 1 else ""
                cells.append(f"<th{rs}>{e(_MD_MARK.get(v, v))}</th>")
            else:
                cells.append(f"<td>{e(v)}</td>")
        out.append(f"<tr{cls}>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    if t.notes:
        out.append("<ul class=\"notes\">" + "".join(f"<li>{e(n)}</li>" for n in t.notes) + "</ul>")
    return "\n".join(out)


_CSS = """body{font-family:system-ui,sans-serif;margin:1.2em;max-width:1400px;color:#222}
h1{font-size:1.3em;margin:0 0 .3em} h2{font-size:1.05em;margin:.8em 0 .3em}
.meta{color:#555;font-size:.85em}
table.paper{border-collapse:collapse;font-size:.85em;margin:.3em 0}
table.paper caption{caption-side:bottom;font-size:.85em;color:#555;text-align:left;padding-top:.3em}
table.paper th,table.paper td{padding:.15em .55em;text-align:center}
table.paper thead tr:first-child th{border-top:2px solid #222}
table.paper thead tr:last-child th{border-bottom:1px solid #222}
table.paper tbody tr:last-child td,table.paper tbody tr:last-child th{border-bottom:2px solid #222}
table.paper tr.block td,table.paper tr.block th{border-top:3px double #222}
.plots{display:grid;grid-template-columns:repeat(4,1fr);gap:.5em}
.plots img{width:100%;height:auto;border:1px solid #ddd}
ul.notes{font-size:.8em;color:#444;margin:.2em 0}"""


def html_summary(title: str, sections: Sequence[tuple[PaperTable, Sequence[Path]]],
                 meta: Sequence[str] = ()) -> str:
    """One self-contained HTML page: each table followed by its plots embedded as base64 PNG."""
    e = html.escape
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">', f"<title>{e(title)}</title>",
             f"<style>{_CSS}</style></head><body>", f"<h1>{e(title)}</h1>"]
    if meta:
        parts.append('<p class="meta">' + "<br>".join(e(m) for m in meta) + "</p>")
    for t, plots in sections:
        parts += [f"<h2>{e(t.key.capitalize())}</h2>", to_html(t)]
        if plots:
            parts.append('<div class="plots">')
            for p in plots:
                data = base64.b64encode(Path(p).read_bytes()).decode("ascii")
                parts.append(f'<img alt="{e(t.key)} {e(Path(p).stem)}" src="data:image/png;base64,{data}">')
            parts.append("</div>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def run_meta(runs: Sequence[PlacedRun]) -> list[str]:
    """Provenance lines for the summary: experiments, commits and machines of the runs."""
    from ..run import results

    exps, commits, machines = [], [], []
    for r in runs:
        m = results.read_manifest(Path(r.scores.path)) if Path(r.scores.path).is_dir() else None
        if not m:
            continue
        for lst, v in ((exps, m.get("experiment")), (commits, m.get("git_commit")),
                       (machines, _machine_line(m.get("machine")))):
            if v and v not in lst:
                lst.append(v)
    out = [f"{len(runs)} run(s); metric profile {', '.join(sorted({r.scores.profile for r in runs}))}"]
    if exps:
        out.append("experiments: " + ", ".join(exps))
    if commits:
        out.append("git commit: " + ", ".join(str(c)[:12] for c in commits))
    if machines:
        out.append("machine: " + "; ".join(machines))
    return out


def _machine_line(m: Any) -> str | None:
    if not isinstance(m, Mapping):
        return None
    return ", ".join(f"{k}={v}" for k, v in m.items())


def write_paper_report(sections: Sequence[tuple[str, Sequence[PlacedRun]]], out: Path,
                       plots: bool = True) -> list[Path]:
    """For each (table kind, runs): ``<kind>.md``, ``<kind>.tex`` and the success / precision /
    NT2F plots of those runs in ``<kind>/``; then ``summary.html``, one page with every table and
    its plots embedded. Returns the written paths."""
    from .tables import plot_curves

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    body = []
    all_runs: list[PlacedRun] = []
    for kind, runs in sections:
        t = build_table(kind, runs)
        all_runs += list(runs)
        for fmt, ext in (("markdown", "md"), ("latex", "tex")):
            p = out / f"{t.key}.{ext}"
            p.write_text(render_paper_table(t, fmt))
            written.append(p)
        pngs = plot_curves([r.scores for r in runs], out / t.key) if plots else []
        written += pngs
        body.append((t, pngs))
    title = "mata-eval report: " + ", ".join(t.key for t, _ in body)
    p = out / "summary.html"
    p.write_text(html_summary(title, body, run_meta(all_runs)))
    written.append(p)
    return written


def _experiment_runs(path: str) -> tuple[str, list[str]]:
    """(experiment name, its run folders that exist) of an experiment file."""
    from ..run.config import load_experiment

    exp = load_experiment(path)
    dirs = [str(exp.output / r.name) for r in exp.runs if (exp.output / r.name).is_dir()]
    if not dirs:
        raise FileNotFoundError(f"{path}: none of its {len(exp.runs)} run folders exists under {exp.output}; "
                                f"run `mata-eval run {path}` first")
    return exp.name, dirs


def cmd_paper(args: argparse.Namespace) -> int:
    """``mata-eval report --paper KIND RUN...`` or ``--experiment EXP.yaml ...``: print the
    table(s) (Markdown, or LaTeX with ``--format latex``); with ``--out`` also write Markdown,
    LaTeX, plots and the one-page HTML summary. ``--paper auto`` takes each experiment's table
    from its name (protocols, challenges, ablation, embedded)."""
    import sys

    from .tables import ScoresUnavailable

    try:
        plan: list[tuple[str, list[str]]] = []
        for exp_file in args.experiment or []:
            name, dirs = _experiment_runs(exp_file)
            kind = name if args.paper == "auto" else args.paper
            if kind not in PAPER_TABLES:
                raise ValueError(f"{exp_file}: experiment {name!r} is not one of the paper's tables "
                                 f"({', '.join(PAPER_TABLES)}); choose one with --paper")
            plan.append((kind, dirs))
        if args.run_dirs:
            if args.paper == "auto":
                raise ValueError("--paper auto needs --experiment files; name the table for run folders")
            plan.append((args.paper, list(args.run_dirs)))
        if not plan:
            raise ValueError("no runs: give run folders or --experiment files")
        sections = [(kind, load_runs(dirs)) for kind, dirs in plan]
        tables = [build_table(kind, runs) for kind, runs in sections]
    except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    fmt = "latex" if args.format == "latex" else "markdown"
    for t in tables:
        print(render_paper_table(t, fmt))
    if args.out:
        for p in write_paper_report(sections, Path(args.out), plots=not args.no_plots):
            print(f"wrote {p}")
    return 0


def cmd_per_sequence(args: argparse.Namespace) -> int:
    """``mata-eval report --per-sequence A B``: the per-sequence comparison of two runs."""
    import sys

    from .tables import ScoresUnavailable, scores_for

    if len(args.run_dirs) != 2:
        print(f"error: --per-sequence compares exactly two run folders, got {len(args.run_dirs)}", file=sys.stderr)
        return 2
    try:
        t = sequence_comparison(scores_for(Path(args.run_dirs[0])), scores_for(Path(args.run_dirs[1])))
    except (ScoresUnavailable, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(render_paper_table(t, "latex" if args.format == "latex" else "markdown"))
    return 0
