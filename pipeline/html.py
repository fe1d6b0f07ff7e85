"""``report.html``: the run's protocol as one self-contained HTML page.

The engine writes it beside ``report.md`` (:mod:`baarda.pipeline.runner`): a template
(``pipeline/templates/report.html.j2``, Jinja2) filled with

* the **protocol summary** — the numbers a photogrammetrist reads first, taken from the
  ``protocol`` entry of every stage's summary (the same values ``results.json`` holds);
* one section per stage: its warnings, its Markdown report rendered to HTML (markdown-it-py,
  tables kept), its figures embedded as PNG (``data:`` URIs, base64) and links to its files.

Figures come from a stage's optional ``plots(result, ctx)`` method (matplotlib figures, drawn
here with the Agg backend) and from ``StageResult.figures`` (PNG bytes).  Nothing in the page
loads anything from outside the file.  The numerical libraries never import this module or
matplotlib.
"""

from __future__ import annotations

import base64
import html as _html
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

FIGURE_DPI = 100


def use_agg() -> None:
    """matplotlib with the Agg backend (headless; no display is ever opened)."""
    import matplotlib

    matplotlib.use("Agg", force=True)


def png_of(fig: Any) -> bytes:
    """PNG bytes of a matplotlib figure (closed afterwards) or of PNG bytes given as they are."""
    if isinstance(fig, (bytes, bytearray)):
        return bytes(fig)
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=FIGURE_DPI)     # the figures lay themselves out (tight_layout)
    finally:
        plt.close(fig)
    return buf.getvalue()


@dataclass
class HtmlFigure:
    name: str
    file: str
    png: bytes
    caption: str = ""

    @property
    def width(self) -> int:
        """Pixel width from the PNG header (0 when the bytes are not a PNG)."""
        return int.from_bytes(self.png[16:20], "big") if self.png[:8] == b"\x89PNG\r\n\x1a\n" else 0

    @property
    def data_uri(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode("ascii")


@dataclass
class HtmlStage:
    id: str
    use: str
    status: str
    seconds: float
    report: str
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    figures: list[HtmlFigure] = field(default_factory=list)
    protocol: dict | None = None


def markdown_html(text: str) -> str:
    """Markdown → HTML (CommonMark + GFM tables; raw HTML in the text is escaped)."""
    from markdown_it import MarkdownIt

    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    return md.render(text or "")


def fmt(x: Any, nd: int = 4) -> str:
    """A number as the protocol prints it: ``nd`` significant digits, ``–`` for none/nan.

    Tests format the values of ``results.json`` with this very function and look for the string
    in the page."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    try:
        f = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(f):
        return "–"
    return f"{f:.{nd}g}"


def _env():
    from jinja2 import Environment, PackageLoader, select_autoescape

    env = Environment(loader=PackageLoader("baarda.pipeline", "templates"),
                      autoescape=select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True)
    env.filters["num"] = fmt
    env.filters["md"] = markdown_html
    return env


def render_report(*, title: str, description: str, project_file: str, started: str, version: str,
                  recording_id: str, stages: Iterable[HtmlStage]) -> str:
    """The page as a string."""
    stages = list(stages)
    protocols = [(s.id, s.use, s.protocol) for s in stages if s.protocol]
    return _env().get_template("report.html.j2").render(
        title=title, description=description, project_file=project_file, started=started, version=version,
        recording_id=recording_id, stages=stages, protocols=protocols)


_URL = re.compile(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:|//|file:)""", re.I)


def external_references(page: str) -> list[str]:
    """``src``/``href`` attributes that point outside the page (a self-contained report has none)."""
    return _URL.findall(page)


def escape(text: str) -> str:
    return _html.escape(text)
