"""The small Markdown subset the benchmark reports write, as HTML (no script, no external file).

``report.md`` holds headings (``#``..``###``), paragraphs, ``-`` bullet lists, pipe tables with a
``|---|`` rule under the header, and inline code in backticks; :func:`markdown_to_html` turns
exactly that into HTML, so ``report.html`` shows tables as tables. Anything else passes as an
escaped paragraph.

>>> print(markdown_to_html(["# T", "", "| a | b |", "|---|---|", "| 1 | `x<y` |", "", "- one", "- two"]))
<h1>T</h1>
<table>
<tr><th>a</th><th>b</th></tr>
<tr><td>1</td><td><code>x&lt;y</code></td></tr>
</table>
<ul>
<li>one</li>
<li>two</li>
</ul>
"""

from __future__ import annotations

import base64
import html
import io
import re

__all__ = ["markdown_to_html", "REPORT_CSS", "new_figure", "figure_base64_png"]

#: Style of the reports' pages (inline, so the page stays self-contained).
REPORT_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em}"
              "table{border-collapse:collapse;margin:0.5em 0}th,td{border:1px solid #bbb;padding:2px 8px;"
              "text-align:right}th{background:#eee}td:first-child,th:first-child{text-align:left}"
              "code{background:#f4f4f4}img{max-width:100%}")


def new_figure(size_px=(900, 520), dpi: int = 100):
    """A matplotlib Figure of ``size_px`` pixels on an Agg canvas: no pyplot (no global state, no
    display; the backend of a user's session is left alone). Axis labels end with their unit in
    parentheses; legends are words, not code names (tests/cli/test_figures_labelled.py)."""
    # matplotlib (heavy: ~0.3 s to import) only when a report draws a figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size_px[0] / dpi, size_px[1] / dpi), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_base64_png(fig) -> str:
    """The figure as a base64 PNG for an ``<img src="data:image/png;base64,...">`` (no timestamp or
    version in the file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _inline(text: str) -> str:
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(f"<code>{html.escape(p[1:-1])}</code>" if p.startswith("`") and p.endswith("`") and len(p) > 1
                   else html.escape(p) for p in parts)


def _cells(row: str) -> list:
    return [c.strip() for c in row.strip().strip("|").split("|")]


def markdown_to_html(lines) -> str:
    """HTML of the reports' Markdown subset (module docstring)."""
    lines = list(lines)
    out = []
    i = 0
    while i < len(lines):
        line = lines[i].rstrip()
        if not line.strip():
            i += 1
            continue
        m = re.match(r"^(#{1,3})\s+(.*)$", line)
        if m:
            n = len(m.group(1))
            out.append(f"<h{n}>{_inline(m.group(2))}</h{n}>")
            i += 1
        elif line.lstrip().startswith("|") and i + 1 < len(lines) and re.match(r"^\s*\|[\s:|-]+\|\s*$", lines[i + 1]):
            out.append("<table>")
            out.append("<tr>" + "".join(f"<th>{_inline(c)}</th>" for c in _cells(line)) + "</tr>")
            i += 2
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                out.append("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in _cells(lines[i])) + "</tr>")
                i += 1
            out.append("</table>")
        elif line.lstrip().startswith("- "):
            out.append("<ul>")
            while i < len(lines) and lines[i].lstrip().startswith("- "):
                out.append(f"<li>{_inline(lines[i].lstrip()[2:])}</li>")
                i += 1
            out.append("</ul>")
        else:
            para = []
            while i < len(lines) and lines[i].strip() and not re.match(r"^(#{1,3}\s|\s*\||\s*- )", lines[i]):
                para.append(lines[i].strip())
                i += 1
            out.append(f"<p>{_inline(' '.join(para))}</p>")
    return "\n".join(out)
