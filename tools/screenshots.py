"""Full-page screenshots of report.html in headless Chromium (``make screenshots``).

For every run directory given (or every ``<out>/<folder>-<name>`` made by ``--run`` from the
bundled projects ``fixtures/*/*.toml``) the page is opened in Debian's ``chromium`` at a
1920 × 1080 viewport, its height measured, and a full-page PNG written to ``docs/images/``
(``report-<folder>-<name>.png``), scaled to ``--width`` pixels to keep the repository small.
The height in screen heights before the appendix of tables is printed per project (issue 23:
≤ 6 screen heights)."""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

VIEW_W, VIEW_H = 1920, 1080
MAX_SCREENS = 6
"""Screen heights (1080 CSS px at a 1920 px wide window) a report may take before its appendix of tables
(issue 23); tests/pipeline/test_fixtures.py checks every bundled project's report with :func:`measure_many`."""
_PROBE = """<!DOCTYPE html><html><body>{frames}<script>
window.addEventListener("load", function () {{
  var out = [];
  document.querySelectorAll("iframe").forEach(function (f) {{
    var d = f.contentDocument, a = d.getElementById("appendix"), h = d.documentElement.scrollHeight;
    var before = a ? a.getBoundingClientRect().top + f.contentWindow.scrollY : h;
    out.push(h + ":" + Math.round(before));
  }});
  document.title = "BAARDA_H=" + out.join(",");
}});
</script></body></html>"""
# Each page in an iframe of the viewport's size, measured at the window's load event: after every image
# (the figures are data: URIs) is decoded and laid out — a script at the end of <body> would run before
# that and measure a page too short.


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    sys.exit("screenshots: no chromium found (Debian: apt-get install chromium)")


def _chrome(exe: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                           "--disable-dev-shm-usage", *args], capture_output=True, text=True, timeout=180)


def measure_many(exe: str, pages) -> list[tuple[int, int]]:
    """(page height, height above the appendix) in CSS pixels at the 1920 × 1080 viewport of every
    report in ``pages``, in one headless Chromium run (the pages in iframes of one probe page)."""
    pages = [Path(p).resolve() for p in pages]
    if not pages:
        return []
    frames = "".join(f'<iframe scrolling="no" src="{p.as_uri()}" style="width:{VIEW_W}px;height:{VIEW_H}px;'
                     f'border:0;display:block"></iframe>' for p in pages)
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.html"
        probe.write_text(_PROBE.format(frames=frames), encoding="utf-8")
        out = _chrome(exe, f"--window-size={VIEW_W},{VIEW_H}", "--allow-file-access-from-files", "--dump-dom",
                      probe.as_uri()).stdout
    m = re.search(r"BAARDA_H=([\d:,]+)", out)
    got = [tuple(int(x) for x in pair.split(":")) for pair in m.group(1).split(",")] if m else []
    if len(got) != len(pages):
        raise RuntimeError(f"could not measure {len(pages)} page(s) in Chromium: {out[-300:]!r}")
    return got


def measure(exe: str, page: Path) -> tuple[int, int]:
    """(page height, height above the appendix) in CSS pixels at the 1920 × 1080 viewport."""
    return measure_many(exe, [page])[0]


def shoot(exe: str, page: Path, png: Path, width: int, max_height: int) -> tuple[int, int]:
    from PIL import Image

    h, before = measure(exe, page)
    height = min(h, max_height)
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.png"
        _chrome(exe, f"--window-size={VIEW_W},{height}", f"--screenshot={raw}", page.resolve().as_uri())
        img = Image.open(raw).convert("RGB")
    # crop the empty margins either side of the page's column (max-width 1300 px), then scale
    col = 1340
    left = max((img.width - col) // 2, 0)
    img = img.crop((left, 0, min(left + col, img.width), img.height))
    if img.width > width:
        img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img = img.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    png.parent.mkdir(parents=True, exist_ok=True)
    img.save(png, optimize=True)
    return h, before


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run directories (default: run every bundled project)")
    ap.add_argument("--run", action="store_true", help="run the bundled projects first (into --out)")
    ap.add_argument("--out", type=Path, default=Path("runs/screenshots"))
    ap.add_argument("--images", type=Path, default=Path("docs/images"))
    ap.add_argument("--width", type=int, default=900, help="PNG width in pixels")
    ap.add_argument("--max-height", type=int, default=16000, help="CSS pixels captured at most")
    ap.add_argument("--baarda", default=str(Path(sys.executable).with_name("baarda")))
    ap.add_argument("--measure-only", action="store_true")
    a = ap.parse_args(argv)
    exe = chromium()
    runs = list(a.runs)
    if not runs:
        for toml in sorted(Path("fixtures").glob("*/*.toml")):
            rd = a.out / f"{toml.parent.name}-{toml.stem}"
            if a.run or not (rd / "report.html").exists():
                print(f"running {toml} → {rd}", flush=True)
                subprocess.run([a.baarda, "run", str(toml), "--out", str(rd), "--quiet"], check=False,
                               stdout=subprocess.DEVNULL)
            runs.append(rd)
    worst = 0.0
    for rd in runs:
        page = rd / "report.html"
        if not page.exists():
            print(f"{rd.name}: no report.html", flush=True)
            continue
        if a.measure_only:
            h, before = measure(exe, page)
        else:
            h, before = shoot(exe, page, a.images / f"report-{rd.name}.png", a.width, a.max_height)
        worst = max(worst, before / VIEW_H)
        print(f"{rd.name:28s} {before / VIEW_H:5.1f} screen heights before the appendix "
              f"({h / VIEW_H:.1f} in all)", flush=True)
    print(f"largest: {worst:.1f} screen heights before the appendix (at most {MAX_SCREENS})")
    return 0 if worst <= MAX_SCREENS else 1


if __name__ == "__main__":
    raise SystemExit(main())
