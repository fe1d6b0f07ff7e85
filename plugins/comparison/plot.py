"""Check-point error chart drawn with OpenCV (no plotting library needed), returned as PNG bytes.

Pure: data in, image out. One group of bars per method (Sx, Sy, Sxy, Sz RMSE) with the
individual check-point errors |dX|, |dY|, |dZ| drawn as dots over the bars of their component.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

COLOURS = {"Sx": (200, 120, 40), "Sy": (60, 160, 60), "Sxy": (40, 140, 220), "Sz": (60, 60, 200)}
BG, INK, GRID = (255, 255, 255), (30, 30, 30), (225, 225, 225)


def _nice_max(v: float) -> float:
    if not np.isfinite(v) or v <= 0:
        return 1.0
    e = 10 ** math.floor(math.log10(v))
    for m in (1, 2, 2.5, 5, 10):
        if v <= m * e:
            return m * e
    return 10 * e


def _wrap(text: str, width_px: int, font, scale: float) -> list[str]:
    """Greedy word wrap to ``width_px``; a single over-long word is cut."""
    lines, cur = [], ""
    for word in text.replace(":", ": ").split():
        trial = f"{cur} {word}".strip()
        if cv2.getTextSize(trial, font, scale, 1)[0][0] <= width_px or not cur:
            cur = trial
        else:
            lines.append(cur)
            cur = word
    if cur:
        lines.append(cur)
    out = []
    for ln in lines:
        while cv2.getTextSize(ln, font, scale, 1)[0][0] > width_px and len(ln) > 3:
            ln = ln[:-2] + "…" if ln.endswith("…") else ln[:-1]
        out.append(ln)
    return out


def checkpoint_chart(methods: list[dict], unit: str, title: str = "Check-point errors per method",
                     width: int = 1000, height: int = 520) -> np.ndarray:
    """BGR image. ``methods``: dicts with ``name``, ``Sx``, ``Sy``, ``Sxy``, ``Sz`` and optional
    ``errors`` (k, 3) array of per-point (dX, dY, dZ)."""
    img = np.full((height, width, 3), BG, np.uint8)
    left, right, top, bottom = 80, 20, 50, 110
    pw, ph = width - left - right, height - top - bottom
    keys = ["Sx", "Sy", "Sxy", "Sz"]
    vmax = 0.0
    for m in methods:
        vmax = max(vmax, *(float(m.get(k, 0) or 0) for k in keys))
        e = np.asarray(m.get("errors", np.zeros((0, 3))), float)
        if e.size:
            vmax = max(vmax, float(np.nanmax(np.abs(e))))
    vmax = _nice_max(vmax * 1.05)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(img, title, (left, 30), font, 0.7, INK, 2, cv2.LINE_AA)
    for t in range(6):
        val = vmax * t / 5
        y = int(top + ph - ph * t / 5)
        cv2.line(img, (left, y), (left + pw, y), GRID, 1)
        cv2.putText(img, f"{val:.3g}", (5, y + 5), font, 0.45, INK, 1, cv2.LINE_AA)
    cv2.putText(img, unit, (5, top - 10), font, 0.45, INK, 1, cv2.LINE_AA)
    cv2.line(img, (left, top), (left, top + ph), INK, 1)
    cv2.line(img, (left, top + ph), (left + pw, top + ph), INK, 1)
    n = max(len(methods), 1)
    gw = pw / n
    bw = gw * 0.8 / len(keys)
    for i, m in enumerate(methods):
        x0 = left + i * gw + gw * 0.1
        errs = np.asarray(m.get("errors", np.zeros((0, 3))), float).reshape(-1, 3)
        for j, k in enumerate(keys):
            v = float(m.get(k, np.nan) or 0.0)
            xa, xb = int(x0 + j * bw), int(x0 + (j + 1) * bw - 2)
            if np.isfinite(v):
                ya = int(top + ph - ph * min(v, vmax) / vmax)
                cv2.rectangle(img, (xa, ya), (xb, top + ph), COLOURS[k], -1)
            comp = {"Sx": 0, "Sy": 1, "Sz": 2}.get(k)
            if comp is not None and errs.size:
                xm = (xa + xb) // 2
                for e in np.abs(errs[:, comp]):
                    if np.isfinite(e):
                        cv2.circle(img, (xm, int(top + ph - ph * min(e, vmax) / vmax)), 3, INK, -1, cv2.LINE_AA)
        for ln, part in enumerate(_wrap(str(m["name"]), int(gw * 0.9), font, 0.42)[:3]):
            cv2.putText(img, part, (int(x0), top + ph + 20 + 16 * ln), font, 0.42, INK, 1, cv2.LINE_AA)
    lx = left
    for k in keys:
        cv2.rectangle(img, (lx, height - 25), (lx + 14, height - 11), COLOURS[k], -1)
        cv2.putText(img, k, (lx + 20, height - 12), font, 0.5, INK, 1, cv2.LINE_AA)
        lx += 80
    cv2.circle(img, (lx + 7, height - 18), 3, INK, -1, cv2.LINE_AA)
    cv2.putText(img, "single check point |error|", (lx + 20, height - 12), font, 0.5, INK, 1, cv2.LINE_AA)
    return img


def png_bytes(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
