"""The one table model of every report and its renderers: terminal, GitHub Markdown, CSV and
LaTeX booktabs (HTML lives in :mod:`.html`).

A :class:`Table` has ``stub`` label columns on the left (merged down where equal, like
``\\multirow``), value ``columns`` under optional column ``groups``, rows of cells (strings), the
row indices that start a new block (a double rule in LaTeX, as in the paper) and notes. The run
tables of ``mata-eval report`` (:mod:`.overview`) and the paper's tables (:mod:`.paper`) are
built as Tables and rendered here."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

FORMATS = ("terminal", "markdown", "csv", "latex")

CHECK, CROSS, NONE = "yes", "no", "-"
TEXT_MARKS = {CHECK: "✓", CROSS: "✗"}
_TEX_MARK = {CHECK: r"$\checkmark$", CROSS: r"$\times$"}
# column names written in math in LaTeX (a bare "|" is not a bar in every font encoding)
_TEX_COLUMNS = {"|dSR|": r"$\Delta$SR", "|dNT2F|": r"$\Delta$NT2F"}
_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                  "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def pct(v: float | None) -> str:
    """A fraction as a percentage with one decimal, as in the paper's tables ("-" if unknown)."""
    return "-" if v is None or not math.isfinite(v) else f"{100.0 * v:.1f}"


def hz(v: float | None) -> str:
    """A rate in Hz with one decimal ("-" if unknown)."""
    return "-" if v is None or not math.isfinite(v) else f"{v:.1f}"


def mark(v: bool | None) -> str:
    """A yes / no / not-applicable cell (✓ / ✗ / - in Markdown, HTML and LaTeX stubs)."""
    return NONE if v is None else (CHECK if v else CROSS)


def latex_escape(s: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in s)


@dataclass(frozen=True)
class Table:
    """A results table: ``stub`` leading columns, column groups (label, span) over the value
    columns (an empty label draws a rule but no header), rows, the row indices that start a new
    block, notes printed under the table, and the LaTeX alignment of the stub columns."""

    key: str
    caption: str
    stub: list[str]
    groups: list[tuple[str, int]]
    columns: list[str]
    rows: list[list[str]]
    blocks: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stub_align: str = "c"

    @property
    def header(self) -> list[str]:
        """Flat column names: stub, then "<group> <column>"."""
        names, k = list(self.stub), 0
        for label, span in self.groups:
            names += [f"{label} {c}".strip() for c in self.columns[k:k + span]]
            k += span
        return names + list(self.columns[k:])

    def merged_stub(self) -> list[list[int]]:
        """For each row and stub column, how many rows the cell spans (0: covered by the one
        above). A stub cell merges with the following rows of the same block while it and every
        stub cell to its left are equal."""
        spans = [[1] * len(self.stub) for _ in self.rows]
        starts = set(self.blocks) | {0}
        for c in range(len(self.stub)):
            i = 0
            while i < len(self.rows):
                j = i + 1
                while (j < len(self.rows) and j not in starts
                       and all(self.rows[j][k] == self.rows[i][k] for k in range(c + 1))
                       and (c == 0 or spans[j][c - 1] == 0)):
                    j += 1
                spans[i][c] = j - i
                for k in range(i + 1, j):
                    spans[k][c] = 0
                i = j
        return spans


def to_terminal(t: Table) -> str:
    """Fixed-width columns: the stub (label) columns left-aligned, the values right-aligned."""
    cols = t.header
    widths = [max(len(c), *(len(r[i]) for r in t.rows)) if t.rows else len(c) for i, c in enumerate(cols)]
    n_left = max(1, len(t.stub))

    def line(cells: list[str]) -> str:
        return "  ".join(v.ljust(w) if i < n_left else v.rjust(w) for i, (v, w) in enumerate(zip(cells, widths)))

    head = line(cols)
    out = [head, "-" * len(head)]
    for r in t.rows:
        out.append(line(r))
    text = "\n".join(out) + "\n"
    if t.notes:
        text += "\n" + "\n".join(f"- {n}" for n in t.notes) + "\n"
    return text


def to_markdown(t: Table) -> str:
    """GitHub Markdown: merged stub cells left blank below their first row, group labels folded
    into the column names."""
    spans = t.merged_stub()
    head = t.header
    out = ["| " + " | ".join(h.replace("|", "\\|") for h in head) + " |",
           "|" + "|".join([":---"] * len(t.stub) + ["---:"] * (len(head) - len(t.stub))) + "|"]
    for i, row in enumerate(t.rows):
        cells = [("" if spans[i][c] == 0 else TEXT_MARKS.get(v, v)) if c < len(t.stub) else v
                 for c, v in enumerate(row)]
        out.append("| " + " | ".join(v.replace("|", "\\|") for v in cells) + " |")
    text = "\n".join(out) + "\n"
    if t.notes:
        text += "\n" + "\n".join(f"- {n}" for n in t.notes) + "\n"
    return text


def to_csv(t: Table) -> str:
    """One header row (the flat column names), then the rows as they are."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(t.header)
    w.writerows(t.rows)
    return buf.getvalue()


def to_latex(t: Table, label: str | None = None) -> str:
    """A booktabs ``tabular`` like the paper's: ``\\multirow`` stub cells, ``\\multicolumn`` column
    groups, a double ``\\midrule`` under the header and between blocks (a table without blocks:
    one under the header); inside a ``table*`` with caption and label
    when the table has a caption."""
    def tex(v: str, stub: bool) -> str:
        return _TEX_MARK[v] if stub and v in _TEX_MARK else latex_escape(v)

    n_stub, n_val = len(t.stub), len(t.columns)
    spec = "|".join([t.stub_align] * n_stub)
    k = 0
    val_spec = []
    for _, span in (t.groups or [("", n_val)]):
        val_spec.append("c" * span)
        k += span
    if k < n_val:
        val_spec.append("c" * (n_val - k))
    spec += "|" + "|".join(s for s in val_spec if s)
    out = [rf"\begin{{tabular}}{{{spec}}}", r"\toprule"]
    if any(g for g, _ in t.groups):
        cells = [rf"\multirow{{2}}{{*}}{{{latex_escape(s)}}}" for s in t.stub]
        for gi, (g, span) in enumerate(t.groups):
            sep = "" if gi == len(t.groups) - 1 else "|"
            cells.append(rf"\multicolumn{{{span}}}{{c{sep}}}{{{latex_escape(g)}}}")
        out.append(" & ".join(cells) + r" \\")
        out.append(" & ".join([""] * n_stub + [_TEX_COLUMNS.get(c) or latex_escape(c) for c in t.columns])
                   + r" \\")
    else:
        out.append(" & ".join(latex_escape(c) for c in t.stub + t.columns) + r" \\")
    out.append(r"\midrule")
    if t.blocks:          # the paper's tables: a double rule under the header and between blocks
        out.append(r"\midrule")
    spans = t.merged_stub()
    for i, row in enumerate(t.rows):
        if i in t.blocks and i > 0:
            out += [r"\midrule", r"\midrule"]
        cells = []
        for c, v in enumerate(row):
            if c < n_stub:
                s = spans[i][c]
                cells.append("" if s == 0 else (tex(v, True) if s == 1 else rf"\multirow{{{s}}}{{*}}{{{tex(v, True)}}}"))
            else:
                cells.append(tex(v, False))
        out.append(" & ".join(cells) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    if t.caption:
        out = ([r"% requires \usepackage{booktabs,multirow,amssymb}", r"\begin{table*}[!h]", r"  \centering"]
               + ["  " + ("  " if i not in (0, len(out) - 1) else "") + o for i, o in enumerate(out)]
               + [rf"  \caption{{{latex_escape(t.caption)}}}", rf"  \label{{{label or 'tab:' + t.key}}}",
                  r"\end{table*}"])
    out += [f"% {n}" for n in t.notes]
    return "\n".join(out) + "\n"


def render(t: Table, fmt: str) -> str:
    """``t`` in ``fmt``: one of :data:`FORMATS`."""
    renderers = {"terminal": to_terminal, "markdown": to_markdown, "csv": to_csv, "latex": to_latex}
    if fmt not in renderers:
        raise ValueError(f"unknown table format {fmt!r}; expected one of {', '.join(FORMATS)}")
    return renderers[fmt](t)
