"""report.html: written by every run, parses, self-contained, prints the protocol numbers that
results.json holds, one image per expected figure; no absolute path of the machine in the reports."""

from __future__ import annotations

import base64
import json
import os
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.model import SourceInfo
from baarda.pipeline.html import fmt, object_scale
from baarda.pipeline.runner import run_project

REPO = Path(__file__).resolve().parents[2]


class Page(HTMLParser):
    """Collects tags, <img> sources and attributes that point outside the page."""

    def __init__(self):
        super().__init__()
        self.imgs, self.external, self.figures, self.stack = [], [], [], []
        self.text = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag not in ("img", "br", "meta", "input", "hr", "link"):
            self.stack.append(tag)
        for key in ("src", "href"):
            v = a.get(key)
            if v is not None and not (v.startswith("#") or v.startswith("data:") or "://" not in v and not v.startswith("//")
                                      and not v.startswith("/")):
                self.external.append(v)
        if tag == "link":
            self.external.append(a.get("href", ""))
        if tag == "img":
            self.imgs.append(a.get("src", ""))
        if tag == "figure":
            self.figures.append(a.get("id", ""))

    def handle_endtag(self, tag):
        if tag in self.stack:
            while self.stack and self.stack.pop() != tag:
                pass

    def handle_data(self, data):
        self.text.append(data)


def _run(tmp_path, project):
    out = run_project(REPO / "fixtures" / project, tmp_path / "run", verbose=False)
    assert out.ok, out.message
    page_text = (out.run_dir / "report.html").read_text(encoding="utf-8")
    page = Page()
    page.feed(page_text)
    page.close()
    results = json.loads((out.run_dir / "results.json").read_text(encoding="utf-8"))
    return out, page_text, page, results


def _no_machine_paths(run_dir: Path):
    forbidden = {str(REPO), str(run_dir), str(run_dir.resolve()), str(Path.home()), os.path.realpath("/tmp")}
    for name in ("report.html", "report.md"):
        text = (run_dir / name).read_text(encoding="utf-8")
        text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", text)   # base64 may spell anything
        for p in forbidden:
            assert p not in text, f"{name} names {p}"


def _pngs(page) -> list[bytes]:
    out = []
    for src in page.imgs:
        assert src.startswith("data:image/png;base64,"), src[:40]
        png = base64.b64decode(src.split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        out.append(png)
    return out


def test_paper000_report_html(tmp_path):
    out, text, page, results = _run(tmp_path, "paper000/data1.toml")
    assert not page.external, page.external
    assert not page.stack, f"unclosed tags {page.stack}"
    _pngs(page)
    assert set(page.figures) >= {"fig-screening-residuals_L-R", "fig-blunders-w", "fig-blunders-redundancy"}
    blunders = next(s for s in results["stages"] if s["id"] == "blunders")
    p = blunders["summary"]["protocol"]
    # the numbers printed are results.json's, formatted once
    for value in (p["sigma0_hat"], p["global_test"]["T"], p["rms"]["all"], p["reliability"]["r_min"],
                  p["reliability"]["mdb_max"]):
        assert fmt(value) in text or fmt(value, 3) in text, value
    # and results.json's are right: σ̂0 of paper 000's Data 1 Helmert fit from the screening stage
    screening = next(s for s in results["stages"] if s["id"] == "screening")
    assert p["sigma0_hat"] == pytest.approx(screening["summary"]["pairs"][0]["sigma0_hat"], abs=6e-4)
    # action = flag: RRR's rejections are flags (the block is unchanged), never counted as rejected
    assert blunders["summary"]["action"] == "flag" and p["tests"]["n_rejected"] == 0
    assert p["tests"]["n_decided"] == len(blunders["summary"]["methods"]["rrr"]["rejected"]) == 3
    assert "rejected 3" not in text
    # the RMS is the RMS of the residual column of the observations table
    v = np.loadtxt(out.run_dir / "blunders_observations.csv", delimiter=",", skiprows=1, usecols=_col(
        out.run_dir / "blunders_observations.csv", "v"))
    assert p["rms"]["all"] == pytest.approx(np.sqrt(np.mean(v ** 2)), rel=1e-4)
    _no_machine_paths(out.run_dir)


def _col(path: Path, name: str) -> int:
    return path.read_text(encoding="utf-8").splitlines()[0].split(",").index(name)


def test_bundle_report_html(tmp_path):
    out, text, page, results = _run(tmp_path, "testfield/block.toml")
    assert not page.external and not page.stack
    pngs = _pngs(page)
    expected = {"residuals", "w", "redundancy", "distortion_P31", "network", "checkpoints", "convergence"}
    assert {f"fig-bundle-{n}" for n in expected} <= set(page.figures)
    assert len(pngs) >= len(expected)
    p = next(s for s in results["stages"] if s["id"] == "bundle")["summary"]["protocol"]
    # object lengths below 0.5 m are printed in mm (a precision as a surveyor writes it): the same values × 1000
    pp, ck, ct = p["point_precision"], p["check"], p["control"]
    f_pp = object_scale([pp["rms"], pp["max"]], pp["unit"])
    f_ck = object_scale([ck["Sx"], ck["Sy"], ck["Sz"], ck["Sxy"]], ck["unit"])
    f_ct = object_scale([ct["rms"], ct["max_abs"]], ct["unit"])
    f_ef = object_scale([p["reliability"]["effect_max"]], pp["unit"])
    assert pp["unit"] == "m" and f_pp == {"f": 1000.0, "u": "mm"} and "Point precision (21 points, mm)" in text
    printed = [p["sigma0_hat"], p["global_test"]["T"], p["rms"]["x"], p["rms"]["y"], p["rms"]["all"],
               *(v * f_pp["f"] for v in pp["rms"]), *(v * f_pp["f"] for v in pp["max"]), ck["Sx"] * f_ck["f"],
               ck["Sz"] * f_ck["f"], p["reliability"]["r_min"], p["reliability"]["mdb_max"],
               p["reliability"]["effect_max"] * f_ef["f"], *(v * f_ct["f"] for v in ct["rms"])]
    for value in printed:
        assert fmt(value) in text or fmt(value, 3) in text, value
    # independent references for the protocol's numbers: the run's own CSV tables
    obs = _table(out.run_dir / "bundle_observations.csv")
    um = np.concatenate([obs["vx_um"], obs["vy_um"]])
    assert p["rms"]["all"] == pytest.approx(np.sqrt(np.mean(um ** 2)), rel=1e-9)
    assert p["reliability"]["r_min"] == pytest.approx(min(obs["rx"].min(), obs["ry"].min()), rel=1e-9)
    assert p["reliability"]["mdb_max"] == pytest.approx(max(obs["mdb_x_um"].max(), obs["mdb_y_um"].max()), rel=1e-9)
    pts = _table(out.run_dir / "bundle_points.csv")
    pts = {k[:-2] if k.endswith("_m") else k: c for k, c in pts.items()}     # object unit m
    ok = np.isfinite(pts["sX"]) & (pts["sX"] + pts["sY"] + pts["sZ"] > 0)
    assert p["point_precision"]["rms"][2] == pytest.approx(np.sqrt(np.mean(pts["sZ"][ok] ** 2)), rel=1e-9)
    assert p["point_precision"]["max"][0] == pytest.approx(pts["sX"][ok].max(), rel=1e-12)
    # the MDB's effect on the points is of the order of the MDB projected into object space
    assert 0 < p["reliability"]["effect_max"] < 0.01
    # the per-photo RMS rows: the heading counts the rows it shows (at most 8) of all photos
    head = re.search(r"RMS per photo \(µm; (?:largest (\d+) of (\d+)|all (\d+))\)", text)
    assert head, "no per-photo RMS heading"
    shown = len(re.findall(r"<tr><td>photo [^<]* \(\d+ points\)</td>", text))
    if head.group(3):
        assert int(head.group(3)) == shown == p["n_photos"]
    else:
        assert int(head.group(1)) == shown == 8 and int(head.group(2)) == p["n_photos"] > 8
    _no_machine_paths(out.run_dir)
    md = (out.run_dir / "report.md").read_text(encoding="utf-8")
    assert "### Protocol summary" in md and fmt(p["rms"]["all"]) in md


def _table(path: Path) -> dict:
    lines = path.read_text(encoding="utf-8").splitlines()
    head = lines[0].split(",")
    rows = [ln.split(",") for ln in lines[1:]]
    out = {}
    for k, name in enumerate(head):
        try:
            out[name] = np.array([float(r[k]) if r[k] != "" else np.nan for r in rows])
        except ValueError:
            out[name] = [r[k] for r in rows]
    return out


def test_opencv_style_values_and_sigmas():
    """Values equal OpenCV's (brown_from_opencv inverted); σ equal a finite-difference propagation."""
    from baarda.pipeline.camera.convert import brown_from_opencv, opencv_rms, opencv_style, pixel_source
    from baarda.pipeline.geometry.image import pixels_from_mm

    p, size = 0.0042, (4000, 3000)
    c, ap = brown_from_opencv(3100.0, 3102.0, p, k1=-0.12, k2=0.05, p1=1e-3, p2=-2e-3, k3=0.01)
    ap[5] = 0.0            # fx = fy: brown is exact
    x = np.array([c, 0.03, -0.02, *ap])
    rng = np.random.default_rng(3)
    L = rng.normal(size=(10, 10)) * np.r_[1e-3, 1e-3, 1e-3, 1e-6, 1e-8, 1e-10, 1e-6, 1e-6, 1e-6, 0.0][:, None]
    cov = L @ L.T
    got = opencv_style(x[0], x[1], x[2], "brown", x[3:], cov, size, p)
    assert [g["name"] for g in got] == ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    vals = {g["name"]: g["value"] for g in got}
    assert vals["fy"] == pytest.approx(3102.0) and vals["fx"] == pytest.approx(3102.0)
    assert (vals["k1"], vals["k2"], vals["p1"], vals["p2"], vals["k3"]) == pytest.approx((-0.12, 0.05, 1e-3, -2e-3, 0.01))
    assert (vals["cx"], vals["cy"]) == pytest.approx(tuple(pixels_from_mm([0.03, -0.02], size, p)))

    def f(z):
        r = opencv_style(z[0], z[1], z[2], "brown", z[3:], np.zeros((10, 10)), size, p)
        return np.array([g["value"] for g in r])

    steps = np.diag(np.maximum(np.abs(x), 1e-3) * 1e-6)[:9]       # B2 (shear) stays 0: no OpenCV form
    J = np.column_stack([(f(x + h) - f(x - h)) / (2 * h[k]) for k, h in enumerate(steps)] + [np.zeros(9)])
    want = np.sqrt(np.diag(J @ cov @ J.T))
    assert np.array([g["sigma"] for g in got]) == pytest.approx(want, rel=1e-5)
    assert opencv_style(c, 0, 0, "ebner12", np.zeros(12), np.eye(15), size, p) is None
    # OpenCV's RMS is per image point: √2 × the RMS per coordinate for equal components
    assert opencv_rms(np.full((5, 2), 0.3)) == pytest.approx(0.3 * np.sqrt(2))
    from baarda.pipeline.testing import make_block

    blk = make_block(3, 10)
    assert pixel_source(blk.replace(source=SourceInfo(path="x", format="COLMAP", pixel_format="COLMAP"))) == "COLMAP"
    assert pixel_source(blk.replace(source=SourceInfo(path="x"))) is None


def test_pixel_source_is_reported_in_pixels(tmp_path):
    """The same bundle result, its block marked as from COLMAP (pixel source, pitch p): every image
    quantity of the protocol is the µm value / (1000 p), OpenCV's RMS is per image point, and the
    camera gets its pixel values."""
    import dataclasses

    from baarda.plugins.bundle.protocol import bundle_protocol, protocol_lines

    out = run_project(REPO / "fixtures" / "testfield" / "block.toml", tmp_path / "run", verbose=False)
    res = out.artefacts["bundle"]
    mm = bundle_protocol(res, None, alpha0=0.001, beta0=0.8)
    cams = res.block_in.cameras
    p = 0.005
    block = res.block_in.replace(source=SourceInfo(path="x", format="COLMAP", pixel_format="COLMAP"),
                                 cameras=cams.replace(pixel_mm=np.full(len(cams), p)))
    px = bundle_protocol(dataclasses.replace(res, block_in=block), None, alpha0=0.001, beta0=0.8)
    assert mm["unit"] == "µm" and px["unit"] == "px" and px["pixel_source"] == "COLMAP"
    for k in ("x", "y", "all"):
        assert px["rms"][k] == pytest.approx(mm["rms"][k] / (1000 * p), rel=1e-12)
    assert px["reliability"]["mdb_max"] == pytest.approx(mm["reliability"]["mdb_max"] / (1000 * p), rel=1e-12)
    v = res.residuals[res.obs_active] / p
    assert px["opencv_rms_px"] == pytest.approx(np.sqrt(np.sum(v ** 2) / len(v)), rel=1e-12)
    cam = px["cameras"][0]
    assert cam["pixels"]["c"] == pytest.approx(res.state.cam_params[0, 0] / p)
    assert "opencv" not in cam          # ebner12 has no OpenCV form; baarda's parameters stay
    text = "\n".join(protocol_lines(px))
    assert "px" in text and "µm" not in text


def test_reports_name_paths_relative_to_the_project(tmp_path):
    """A path outside the project and the run directory is written relative to the project file."""
    from types import SimpleNamespace

    from baarda.pipeline.runner import _scrubber

    (tmp_path / "project").mkdir()
    (tmp_path / "data" / "deep").mkdir(parents=True)
    scrub = _scrubber(SimpleNamespace(path=tmp_path / "project" / "p.toml"), tmp_path / "run", tmp_path / "run")
    text = scrub(f"read {tmp_path}/data/deep/model; wrote {tmp_path}/run/bundle_points.csv; 3 km/h")
    assert text == "read ../data/deep/model; wrote bundle_points.csv; 3 km/h"


def test_secondary_stages_are_folded_after_their_first_paragraph():
    from baarda.pipeline.html import HtmlStage, fold_after_lead, secondary_stages

    def st(i, use, protocol=None):
        return HtmlStage(i, use, "ok", 0.0, "", protocol=protocol)

    # with a protocol on the page: stages without one and repeats of a kind are secondary
    assert secondary_stages([st("source", "dbat"), st("bundle", "bundle", {"dof": 1}),
                             st("b2", "bundle", {"dof": 1}), st("dbat", "dbat-report")]) == {"source", "b2", "dbat"}
    # without one: only the repeats (the first study of three is shown in full)
    assert secondary_stages([st("a", "study"), st("b", "study"), st("c", "other")]) == {"b"}
    page = "<p>lead</p>\n<table><tr><td>1</td></tr></table><p>more</p>"
    folded = fold_after_lead(page, "src")
    assert folded.startswith("<p>lead</p>") and "<details" in folded and "src: 1 table and the rest" in folded
    assert folded.count("<table") == 1 and folded.rstrip().endswith("</details>")
    assert fold_after_lead("<p>only</p>\n", "src") == "<p>only</p>\n"
