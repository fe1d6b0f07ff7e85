"""Report text of ``opencv-targets`` (``stage.py``): the section, the headline, the pixel pitch note."""

from __future__ import annotations

import dataclasses
from pathlib import Path


def pitch_note(options, sigma_px: float) -> str:
    """The pixel pitch beside a σ in px only when it is a real one (given, or from a render stage):
    the default 1 µm is a nominal scale for pixel sources, and µm at that pitch would mean nothing."""
    default = next(f.default for f in dataclasses.fields(options) if f.name == "pixel_mm")
    if options.pixel_mm == default:
        return ""
    return f" = {sigma_px * options.pixel_mm * 1000:g} µm at pitch {options.pixel_mm:g} mm"


def points_origin(options, block) -> str:
    """Where the object points of the detection's block come from, for the report."""
    if options.target == "circles":
        return "ids and coordinates from the input block's layout"
    return "control, board frame" if (block.points.role == "full").any() else "tie"


def detection_report(options, files, rows, block, ref, sigma_px) -> str:
    """The stage's report: images used, points, a-priori σ, a row per image, OpenCV's reference."""
    used = [r for r in rows if r["status"] == "ok"]
    lines = [f"Target type **{options.target}**: {len(used)} of {len(files)} image(s) used, "
             f"{len(block.observations)} image points, {len(block.points)} object points "
             f"({points_origin(options, block)}); a-priori sigma "
             f"{sigma_px:g} px{pitch_note(options, sigma_px)}.", "",
             "| image | camera | points | status | note |", "|---|---|---:|---|---|"]
    for r in rows:
        lines.append(f"| {Path(r['file']).name} | {r['camera']} | {r['points']} | {r['status']} | {r['message']} |")
    for cid, cal in ref.items():
        d = ", ".join(f"{v:.5g}" for v in cal["dist"])
        flags = cal.get("flags")
        lines += ["", f"cv2.calibrateCamera reference, camera {cid} ({len(cal['views'])} views): fx {cal['fx']:.3f}, "
                      f"fy {cal['fy']:.3f}, cx {cal['cx']:.3f}, cy {cal['cy']:.3f} px; (k1, k2, p1, p2, k3) = ({d}); "
                      f"RMS {cal['rms_px']:.4f} px"
                      + (f"; flags {' | '.join(flags)} — the parameters baarda holds fixed (unknowns = "
                         f"{', '.join(options.unknowns)})" if flags is not None else "")
                      + "".join(f"; {n}" for n in cal.get("notes") or []) + "."]
    return "\n".join(lines)


def headline(target: str, rows: list[dict], block, ref: dict) -> str:
    """One line for ``baarda review``: images used and skipped, the targets detected (image points,
    object points, fewest and most per used image) and cv2.calibrateCamera's RMS per camera."""
    used = [r["points"] for r in rows if r["status"] == "ok"]
    skipped = len(rows) - len(used)
    out = (f"{target}: {len(used)} of {len(rows)} image(s) used" + (f", {skipped} skipped" if skipped else "")
           + f"; {len(block.observations)} image points of {len(block.points)} object points")
    if used:
        out += f" ({min(used)} per image)" if min(used) == max(used) else f" ({min(used)}–{max(used)} per image)"
    if ref:
        out += "; cv2.calibrateCamera RMS " + ", ".join(
            (f"{cid} " if len(ref) > 1 else "") + f"{cal['rms_px']:.4f}" for cid, cal in ref.items()) + " px"
    return out
