"""A self-contained HTML report: tables and figures embedded as base64 PNG, no external files.

Build a :class:`Report` with headings, paragraphs, tables and matplotlib figures, then
:meth:`Report.write` it (atomically). Nothing here computes results; callers pass numbers in.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import math
import re
from dataclasses import dataclass, field

from .. import __version__
from ..io import atomic_path

__all__ = ["Report", "figure_png"]

_CSS = """
body { font-family: system-ui, -apple-system, Segoe UI, Helvetica, Arial, sans-serif; margin: 2em auto;
       max-width: 1100px; color: #222; line-height: 1.45; padding: 0 1em; }
h1 { border-bottom: 2px solid #346; padding-bottom: .2em; }
h2 { color: #346; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .8em 0; font-size: 0.92em; }
th, td { border: 1px solid #bbb; padding: .25em .6em; text-align: right; }
th { background: #eef2f7; }
td.label, th.label { text-align: left; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
p.note { font-size: 0.9em; color: #555; }
dl.glossary { display: grid; grid-template-columns: max-content auto; gap: .2em 1em; }
dl.glossary dt { font-family: ui-monospace, monospace; font-weight: 600; }
dl.glossary dd { margin: 0; }
footer { margin-top: 3em; font-size: 0.8em; color: #777; }
"""


def figure_png(fig, dpi: int = 110) -> bytes:
    """Render a matplotlib figure to PNG bytes and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _fmt(v, digits: int) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        return f"{v:.{digits}g}" if abs(v) >= 1e4 or (v != 0 and abs(v) < 1e-3) else f"{v:.{digits}f}"
    return html.escape(str(v))


@dataclass
class Report:
    """An HTML document assembled block by block.

    ``symbols`` collects what the tables showed (column names, and the symbol of each
    ``parameter`` cell, e.g. ``L_so`` of ``L_so[x, coil X]``) for the glossary
    (:func:`openemt.report.glossary_section`).
    """

    title: str
    blocks: list[str] = field(default_factory=list)
    n_figures: int = 0
    symbols: set = field(default_factory=set)

    def heading(self, text: str, level: int = 2) -> Report:
        self.blocks.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def paragraph(self, text: str, note: bool = False) -> Report:
        cls = ' class="note"' if note else ""
        self.blocks.append(f"<p{cls}>{html.escape(text)}</p>")
        return self

    def table(self, rows: list[dict], columns: list[str] | None = None, *, caption: str = "",
              digits: int = 4) -> Report:
        """A table from a list of dicts; the first column is left-aligned as a label."""
        if not rows:
            return self
        columns = columns or list(rows[0])
        self.symbols.update(columns)
        if "parameter" in columns:
            self.symbols.update(m.group(0) for r in rows
                                if (m := re.match(r"[A-Za-z]+_[A-Za-z]+", str(r["parameter"]))))
        head = "".join(f'<th class="{"label" if i == 0 else ""}">{html.escape(c)}</th>'
                       for i, c in enumerate(columns))
        body = []
        for r in rows:
            cells = "".join(
                f'<td class="{"label" if i == 0 else ""}">{_fmt(r.get(c, ""), digits)}</td>'
                for i, c in enumerate(columns))
            body.append(f"<tr>{cells}</tr>")
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self.blocks.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}"
                           "</tbody></table>")
        return self

    def definitions(self, items, caption: str = "") -> Report:
        """A list of (term, definition) pairs."""
        body = "".join(f"<dt>{html.escape(str(t))}</dt><dd>{html.escape(str(d))}</dd>"
                       for t, d in items)
        cap = f'<p class="note">{html.escape(caption)}</p>' if caption else ""
        self.blocks.append(f'{cap}<dl class="glossary">{body}</dl>')
        return self

    def figure(self, fig, caption: str = "") -> Report:
        """Embed a matplotlib figure as a base64 PNG (the figure is closed)."""
        data = base64.b64encode(figure_png(fig)).decode("ascii")
        self.n_figures += 1
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self.blocks.append(f'<figure><img alt="{html.escape(caption or "figure")}" '
                           f'src="data:image/png;base64,{data}">{cap}</figure>')
        return self

    def html(self) -> str:
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
                f"<h1>{html.escape(self.title)}</h1>" + "\n".join(self.blocks)
                + f"<footer>openemt {html.escape(__version__)} · {stamp}</footer></body></html>\n")

    def write(self, path) -> None:
        """Write the document to ``path`` atomically (UTF-8)."""
        with atomic_path(path, suffix=".html") as tmp:
            tmp.write_text(self.html(), encoding="utf-8")
