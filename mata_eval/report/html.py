"""HTML rendering of a :class:`~.tables.Table` (``rowspan`` stub cells, ``colspan`` groups) and
the one-page, self-contained HTML summary of ``mata-eval report --out`` (plots embedded as
base64 PNG)."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Sequence

from .tables import TEXT_MARKS, Table


def to_html(t: Table) -> str:
    """An HTML ``<table>`` with ``rowspan`` stub cells and ``colspan`` group headers."""
    e = html.escape
    spans = t.merged_stub()
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
                cells.append(f"<th{rs}>{e(TEXT_MARKS.get(v, v))}</th>")
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


def html_summary(title: str, sections: Sequence[tuple[Table, Sequence[Path]]],
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


