"""``report.html``: the run's protocol as one self-contained HTML page.

The engine writes it beside ``report.md`` (:mod:`baarda.pipeline.runner`): a template
(``pipeline/templates/report.html.j2``, Jinja2) filled with

* the **protocol summary** — the numbers a photogrammetrist reads first, taken from the
  ``protocol`` entry of every stage's summary (the same values ``results.json`` holds);
* one section per stage: its warnings, its figures embedded as PNG (``data:`` URIs, base64;
  three to a row, each a link to its PNG file), its Markdown report rendered to HTML
  (markdown-it-py) and links to its files;
* an **appendix of tables**, collapsed (``<details>``): a stage's table longer than
  :data:`INLINE_ROWS` rows shows its first rows in place, with the count and a link to the whole
  table in the appendix.

Nothing is printed twice: a stage with a protocol (the summary at the top prints it, cameras
included) loses the sections of its Markdown report that say the same
(:data:`PROTOCOL_SECTIONS`).

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

from .report import cap_text

FIGURE_DPI = 100
PNG_LEVEL = 3
"""zlib compression level of the figures' PNG files (PIL's default is 6: slower, hardly smaller for
plots)."""
INLINE_ROWS = 10
"""Rows of a stage's table shown in place in report.html; a longer table keeps these rows, says how
many there are and goes whole into the collapsed appendix."""
FIGURES_SHOWN = (3, 1)
"""Figures of a stage shown open in report.html (the stage lists its most telling first): 3, or 1
when four or more stages of the page have figures (a study of many adjustments); the rest of the
stage's figures are in a closed ``<details>`` under them, with their count and names."""
SECONDARY_FIGURES_SHOWN = (1, 0)
"""Figures shown open for a *secondary* stage (:func:`secondary_stages`): 1, or 0 for a repeat of a stage
kind already on the page (its first figure is like the one above); its text is folded after its first
paragraph (:func:`fold_after_lead`)."""
PROTOCOL_SECTIONS = ("Protocol summary", "Camera parameters")
"""Markdown sections (``### …``) of a stage report that the page's protocol summary already shows:
dropped from the stage's section of report.html when the stage has a protocol (report.md keeps them)."""


def use_agg() -> None:
    """matplotlib with the Agg backend (headless; no display is ever opened)."""
    import matplotlib

    matplotlib.use("Agg", force=True)


def png_of(fig: Any) -> bytes:
    """PNG bytes of a matplotlib figure (closed afterwards) or of PNG bytes given as they are."""
    if isinstance(fig, (bytes, bytearray)):
        return bytes(fig)
    import matplotlib.pyplot as plt

    from .plots import FIXED_LAYOUT

    buf = io.BytesIO()
    try:
        # zlib level 3: a third faster to encode than PIL's default 6, and these PNGs are no bigger
        png = {"format": "png", "dpi": FIGURE_DPI, "pil_kwargs": {"compress_level": PNG_LEVEL}}
        if getattr(fig, FIXED_LAYOUT, False):
            # margins fixed by the figure (plots.fixed_layout): saved as it is, no text measured again
            fig.savefig(buf, **png)
        else:
            # a figure that lays itself out (tight_layout): the tight bounding box keeps a label that an
            # equal-aspect panel pushes past the canvas (an axis label, a suptitle) and trims empty margins
            fig.savefig(buf, bbox_inches="tight", pad_inches=0.08, **png)
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
    conclusion: bool = False
    """The stage's result is what the project is run for (a congruence test, an acceptance test: its
    summary says ``"conclusion": true``): shown in full, never shortened as a secondary stage."""


@dataclass
class AppendixTable:
    anchor: str
    stage: str
    caption: str
    rows: int
    html: str


def drop_sections(text: str, titles: Iterable[str]) -> str:
    """Markdown ``text`` without the sections whose heading is one of ``titles`` (each up to the
    next heading of the same or a higher level)."""
    titles = {t.strip().lower() for t in titles}
    out, skip = [], None
    for line in (text or "").splitlines():
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
        if m:
            level = len(m.group(1))
            if skip is not None and level <= skip:
                skip = None
            if skip is None and m.group(2).strip().lower() in titles:
                skip = level
                continue
        if skip is None:
            out.append(line)
    return "\n".join(out)


_TABLE = re.compile(r"<table>.*?</table>", re.S)
_BODY_ROW = re.compile(r"<tr>(?:(?!</tr>).)*?<td", re.S)


def _caption_before(page: str, start: int) -> str:
    """The text of the paragraph or heading just before a table (its caption), shortened."""
    head = page[max(0, start - 600):start]
    m = re.search(r"<(p|h[1-6]|li)>((?:(?!<(?:p|h[1-6]|li)>).)*?)(?:</\1>)?\s*$", head, re.S)
    text = re.sub(r"<[^>]+>", "", m.group(2)) if m else ""
    text = _html.unescape(" ".join(text.split())).rstrip(":")
    return text[:160] + ("…" if len(text) > 160 else "")


def split_long_tables(page: str, stage: str, appendix: list[AppendixTable], keep: int = INLINE_ROWS) -> str:
    """Every table of a stage's HTML longer than ``keep`` body rows: its first ``keep`` rows stay in
    place with a line saying how many rows there are and where the rest is (the appendix entry
    added to ``appendix``)."""

    def cut(m: re.Match) -> str:
        table = m.group(0)
        rows = list(_BODY_ROW.finditer(table))
        if len(rows) <= keep:
            return table
        anchor = f"appendix-{stage}-{len(appendix) + 1}"
        cap = _caption_before(page, m.start()) or f"table {len(appendix) + 1} of {stage}"
        appendix.append(AppendixTable(anchor, stage, cap, len(rows), table))
        end = rows[keep].start()
        short = table[:end] + ("</tbody>" if "<tbody>" in table[:end] else "") + "</table>"
        return (short + f'<p class="meta cap">{_html.escape(cap_text(keep, len(rows)))} — '
                f'<a href="#{anchor}">the whole table in the appendix</a></p>')

    return _TABLE.sub(cut, page)


def secondary_stages(stages) -> set[str]:
    """Ids of the stages whose section the page shortens (issue 23: a report fits in six screen heights
    before its appendix).  With an adjustment's protocol on the page, the stages without one (sources,
    comparisons, exports) and every repeat of a stage kind already on the page are secondary; without
    one, the repeats are (a study run three times shows the first in full).  A stage whose result is
    the project's conclusion (``HtmlStage.conclusion``: congruence, acceptance tests) is never secondary."""
    stages = list(stages)
    seen, out = set(), set()
    has_protocol = any(s.protocol for s in stages)
    for s in stages:
        if not getattr(s, "conclusion", False) and (s.use in seen or (has_protocol and not s.protocol)):
            out.add(s.id)
        seen.add(s.use)
    return out


_LEAD_END = re.compile(r"</p>\s*")


def fold_after_lead(page: str, stage: str) -> str:
    """A stage's HTML with everything after its first paragraph in a closed ``<details>`` saying what
    it holds (how many tables); the page unchanged when there is nothing after it."""
    m = _LEAD_END.search(page)
    if not m or m.end() >= len(page.rstrip()):
        return page
    rest = page[m.end():]
    n = rest.count("<table")
    what = f"{n} table{'s' if n != 1 else ''} and the rest of the text" if n else "the rest of the text"
    return (page[:m.end()] + f'<details class="more-text"><summary>{stage}: {what}</summary>\n'
            + rest + "</details>\n")


_H3 = re.compile(r"<h3>(.*?)</h3>\s*", re.S)


def fold_sections(page: str) -> str:
    """A stage's HTML with each ``<h3>`` section (up to the next one) in a closed ``<details>`` titled
    by its heading; the text before the first heading stays open."""
    parts = _H3.split(page)
    if len(parts) < 3:
        return page
    out = [parts[0]]
    for title, body in zip(parts[1::2], parts[2::2]):
        out.append(f'<details class="section"><summary>{title}</summary>\n{body}</details>\n')
    return "".join(out)


def markdown_html(text: str) -> str:
    """Markdown → HTML (CommonMark + GFM tables; raw HTML in the text is escaped)."""
    from markdown_it import MarkdownIt

    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    return md.render(text or "")


def fmt(x: Any, nd: int = 4) -> str:
    """A number as the protocol prints it: ``nd`` significant digits, ``–`` for none/nan.

    Tests format the values of ``results.json`` with this very function and look for the string
    in the page."""
    from .units import as_number

    text, f = as_number(x)
    if text is not None:
        return text
    if not math.isfinite(f):
        return "–"
    return f"{f:.{nd}g}"


def object_scale(values, unit: str) -> dict:
    """How a group of object-space lengths in ``unit`` is printed in the protocol table: in mm when the
    unit is m and every one of them is below 0.5 m (``0.03303`` mm rather than ``3.303e-05`` m, as a
    surveyor writes a precision), else as given.  ``{"f": factor, "u": unit text}``; the values in
    results.json stay in the block's unit."""
    flat = []
    for v in values:
        flat += list(v) if isinstance(v, (list, tuple)) else [v]
    nums = [abs(float(v)) for v in flat if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    if unit == "m" and nums and max(nums) < 0.5:
        return {"f": 1000.0, "u": "mm"}
    return {"f": 1.0, "u": unit}


def zero_columns(cameras: list[dict], key: str = "opencv") -> list[str]:
    """Names of the parameters (``cam[key]``: list of {name, value, sigma}) that are 0 ± 0 in every
    camera: held fixed at zero, folded into one line instead of a column of "0 ± 0"."""
    if not cameras:
        return []
    names = [q["name"] for q in cameras[0][key]]
    return [n for n in names
            if all(float(q.get("value") or 0) == 0 and float(q.get("sigma") or 0) == 0
                   for c in cameras for q in c[key] if q["name"] == n)]


def _env():
    from jinja2 import Environment, PackageLoader, select_autoescape

    env = Environment(loader=PackageLoader("baarda.pipeline", "templates"),
                      autoescape=select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True)
    env.filters["num"] = fmt
    env.filters["md"] = markdown_html
    env.filters["zero_columns"] = zero_columns
    env.filters["objscale"] = object_scale
    env.filters["times"] = lambda v, f: v * f if isinstance(v, (int, float)) and not isinstance(v, bool) else v
    return env


def render_report(*, title: str, description: str, project_file: str, started: str, version: str,
                  recording_id: str, stages: Iterable[HtmlStage]) -> str:
    """The page as a string."""
    stages = list(stages)
    protocols = [(s.id, s.use, s.protocol) for s in stages if s.protocol]
    appendix: list[AppendixTable] = []
    bodies = {}
    secondary = secondary_stages(stages)
    uses = [s.use for s in stages]
    repeat = {s.id for k, s in enumerate(stages) if s.use in uses[:k]}
    for s in stages:
        text = drop_sections(s.report, PROTOCOL_SECTIONS) if s.protocol else s.report
        bodies[s.id] = split_long_tables(markdown_html(text), s.id, appendix)
    busy = sum(1 for s in stages if s.figures) >= 4     # a study of many adjustments
    for s in stages:
        if s.id in secondary:
            bodies[s.id] = fold_after_lead(bodies[s.id], s.id)
        elif busy:
            bodies[s.id] = fold_sections(bodies[s.id])
    shown = FIGURES_SHOWN[1] if busy else FIGURES_SHOWN[0]
    return _env().get_template("report.html.j2").render(
        title=title, description=description, project_file=project_file, started=started, version=version,
        recording_id=recording_id, stages=stages, protocols=protocols, bodies=bodies, appendix=appendix,
        inline_rows=INLINE_ROWS, secondary=secondary,
        figures_shown={s.id: (SECONDARY_FIGURES_SHOWN[s.id in repeat] if s.id in secondary else shown)
                       for s in stages})


_URL = re.compile(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:|//|file:)""", re.I)


def external_references(page: str) -> list[str]:
    """``src``/``href`` attributes that point outside the page (a self-contained report has none)."""
    return _URL.findall(page)


def escape(text: str) -> str:
    return _html.escape(text)
