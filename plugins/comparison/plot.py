"""Check-point error chart (matplotlib, drawn on an Agg canvas: no display, no global backend).

One group of bars per method (Sx, Sy, Sxy, Sz RMSE) with the individual check-point errors
|dX|, |dY|, |dZ| drawn as dots over the bars of their component.  :func:`checkpoint_chart`
returns the picture as a BGR array (the stage's recording logs it), :func:`png_bytes` encodes
it for ``report.html`` and ``comparison_checkpoints.png``.
"""

from __future__ import annotations

import textwrap

import cv2
import numpy as np

COLOURS = {"Sx": "#2878c8", "Sy": "#3ca03c", "Sxy": "#dc8c28", "Sz": "#c83c3c"}
KEYS = ("Sx", "Sy", "Sxy", "Sz")


def checkpoint_figure(methods: list[dict], unit: str, title: str = "Check-point errors per method",
                      width: int = 1000, height: int = 520):
    """A matplotlib Figure (not attached to pyplot). ``methods``: dicts with ``name``, ``Sx``,
    ``Sy``, ``Sxy``, ``Sz`` and optional ``errors`` (k, 3) array of per-point (dX, dY, dZ)."""
    from matplotlib.figure import Figure

    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    ax = fig.add_subplot(1, 1, 1)
    n = max(len(methods), 1)
    bw = 0.8 / len(KEYS)
    for j, k in enumerate(KEYS):
        x = np.arange(len(methods)) - 0.4 + (j + 0.5) * bw
        vals = [float(m.get(k, np.nan) or 0.0) for m in methods]
        ax.bar(x, np.nan_to_num(vals), width=bw * 0.92, color=COLOURS[k], label=k)
        comp = {"Sx": 0, "Sy": 1, "Sz": 2}.get(k)
        if comp is None:
            continue
        for xi, m in zip(x, methods):
            e = np.abs(np.asarray(m.get("errors", np.zeros((0, 3))), float).reshape(-1, 3)[:, comp])
            e = e[np.isfinite(e)]
            ax.plot(np.full(e.size, xi), e, "o", ms=3, color="#222", label=None)
    ax.plot([], [], "o", ms=3, color="#222", label="single check point |error|")
    top = ax.get_ylim()[1]
    ax.set_ylim(0, top * 1.15 if top > 0 else 1.0)      # room for the legend above the data
    ax.set_xticks(np.arange(len(methods)),
                  ["\n".join(textwrap.wrap(str(m["name"]), 18)[:3]) for m in methods], fontsize=8)
    ax.set_xlim(-0.6, n - 0.4)
    ax.set_ylabel(unit)
    ax.set_title(title, fontsize=11)
    ax.grid(axis="y", color="#ddd")
    ax.set_axisbelow(True)
    ax.legend(fontsize=8, ncol=5, loc="upper left")
    fig.tight_layout()
    return fig


def checkpoint_chart(methods: list[dict], unit: str, title: str = "Check-point errors per method",
                     width: int = 1000, height: int = 520) -> np.ndarray:
    """The chart as a BGR image (height, width, 3)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = checkpoint_figure(methods, unit, title, width, height)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[:, :, 2::-1])


def png_bytes(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
