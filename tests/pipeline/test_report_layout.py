"""Report layout (issues 22/23): the one cap of every report list, tables capped in place with
the whole in a collapsed appendix, nothing twice, and figures of big blocks drawn from aggregated
data quickly."""

from __future__ import annotations

import io
import re
import time
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.html import (INLINE_ROWS, drop_sections, markdown_html, png_of, render_report,
                                  split_long_tables, use_agg, zero_columns, HtmlStage)
from baarda.pipeline.report import cap_text, capped_rows, capped_table
from baarda.pipeline.runner import run_project

REPO = Path(__file__).resolve().parents[2]


def test_cap_text_counts_and_says_where_the_rest_is():
    assert cap_text(12, 3402, what="flagged", where="bundle_observations.csv, column decision") == \
        "12 of 3\u2009402 flagged; all in bundle_observations.csv, column decision"
    assert cap_text(7, 7, what="flagged", where="x.csv") == "all 7 flagged; in x.csv"
    assert cap_text(3, 3) == "all 3 rows"


def test_capped_rows_and_table():
    rows = [[f"p{i}", float(i)] for i in range(40)]
    shown, total = capped_rows(rows, 5, order=np.argsort([-r[1] for r in rows]))
    assert total == 40 and [r[0] for r in shown] == ["p39", "p38", "p37", "p36", "p35"]
    lines = capped_table(["point", "w"], rows, most=10, what="points", where="t.csv")
    assert lines[0] == "10 of 40 points; all in t.csv:"
    assert sum(1 for x in lines if re.match(r"\| p\d", x)) == 10
    assert capped_table(["a"], [], most=3) == []


def test_long_tables_are_cut_with_a_link_to_the_appendix():
    md = "Largest flagged:\n\n| a | b |\n|---|---|\n" + "\n".join(f"| {i} | {i * i} |" for i in range(40))
    md += "\n\nShort:\n\n| c |\n|---|\n| 1 |\n"
    appendix = []
    page = split_long_tables(markdown_html(md), "bundle", appendix)
    assert len(appendix) == 1 and appendix[0].rows == 40 and appendix[0].caption == "Largest flagged"
    assert page.count("<tr>") == 1 + INLINE_ROWS + 1 + 1          # header + kept rows; short table whole
    assert f"{INLINE_ROWS} of 40 rows" in page and f'href="#{appendix[0].anchor}"' in page
    assert appendix[0].html.count("<td>") == 80


def test_drop_sections_keeps_the_rest():
    md = "intro\n\n### Protocol summary\n\n- a\n\n#### sub\n\nx\n\n### External reliability\n\ny\n## next\n"
    out = drop_sections(md, ["Protocol summary"])
    assert "Protocol summary" not in out and "- a" not in out and "sub" not in out
    assert "intro" in out and "External reliability" in out and "y" in out and "## next" in out


def test_zero_columns():
    cams = [{"opencv": [{"name": "fx", "value": 5.0, "sigma": 1.0}, {"name": "k2", "value": 0.0, "sigma": 0.0}]},
            {"opencv": [{"name": "fx", "value": 6.0, "sigma": 0.0}, {"name": "k2", "value": 0.0, "sigma": 0.0}]}]
    assert zero_columns(cams) == ["k2"]
    cams[1]["opencv"][1]["sigma"] = 0.1
    assert zero_columns(cams) == []


def test_big_block_figures_are_aggregated_and_quick():
    """200 000 image points: hexbin, not 200 000 markers; a small PNG in a few seconds."""
    use_agg()
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from baarda.pipeline.plots import mark_outside, robust_limits, value_map, w_distribution

    rng = np.random.default_rng(1)
    n = 200_000
    x, y = rng.normal(0, 1000, n), rng.normal(0, 700, n)
    r = rng.uniform(0, 1, n)
    x[:3] = [1e6, -2e6, 3e6]                     # three far points must not scale the axes
    t0 = time.perf_counter()
    fig, ax = plt.subplots()
    h = value_map(ax, x, y, r, vmin=0, vmax=1)
    assert isinstance(h, PolyCollection)
    xl, yl = robust_limits(x), robust_limits(y)
    assert xl[1] - xl[0] < 20_000
    assert mark_outside(ax, x, y, xl, yl) == 3
    png = png_of(fig)
    png2 = png_of(w_distribution(rng.standard_normal(n), 3.29))
    assert time.perf_counter() - t0 < 20
    assert len(png) < 400_000 and len(png2) < 400_000
    fig, ax = plt.subplots()
    assert not isinstance(value_map(ax, x[:500], y[:500], r[:500]), PolyCollection)     # small: one dot each
    plt.close("all")


def test_render_report_drops_what_the_protocol_shows():
    stage = HtmlStage("bundle", "bundle", "ok", 1.0, "text\n\n### Protocol summary\n\n- σ̂0 1\n\n### Camera parameters\n\n"
                      "| camera | parameter |\n|---|---|\n| 1 | c |\n\n### Variance components\n\nv\n",
                      protocol={"sigma0": 1.0, "sigma0_hat": 1.0, "dof": 3, "cameras": []})
    page = render_report(title="t", description="", project_file="p.toml", started="now", version="0",
                         recording_id="r", stages=[stage])
    assert "Camera parameters" not in page and "Variance components" in page
    assert page.count("Protocol summary") == 1


@pytest.mark.slow
def test_bundled_report_has_no_duplicated_section_headings(tmp_path):
    out = run_project(REPO / "fixtures" / "dbat" / "sxb.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    page = (out.run_dir / "report.html").read_text(encoding="utf-8")
    heads = [re.sub(r"<[^>]+>", "", h).strip() for h in re.findall(r"<h[1-4][^>]*>(.*?)</h[1-4]>", page, re.S)]
    dup = {h for h in heads if heads.count(h) > 1}
    assert not dup, f"headings twice: {dup}"
    # every capped table says how many rows it has and links to the appendix
    for m in re.finditer(r'href="#(appendix-[^"]+)"', page):
        assert f'id="{m.group(1)}"' in page
    # no figure twice (blunder-rejection does not repeat the bundle's)
    imgs = re.findall(r'src="(data:image/png;base64,[^"]+)"', page)
    assert len(imgs) == len(set(imgs))


@pytest.mark.slow
def test_bundle_figures_of_a_big_synthetic_block():
    """An aerial block of 60 photos and ~28 000 image points: every bundle figure draws, the maps
    as hexbins, each PNG below 1 MB."""
    use_agg()
    from matplotlib.collections import PolyCollection

    from baarda.pipeline.adjustment import adjust_block
    from baarda.pipeline.synthetic.aerial import simulate_aerial
    from baarda.plugins.bundle.figures import bundle_figures

    noisy, _ = simulate_aerial(np.random.default_rng(2), n_strips=6, photos_per_strip=10, points_per_photo=500)
    assert len(noisy.observations) > 20_000
    rep = adjust_block(noisy)
    t0 = time.perf_counter()
    figs = bundle_figures(rep.result, rep.decision if hasattr(rep, "decision") else None)
    assert {"residuals", "network", "reliability", "w", "redundancy", "convergence"} <= set(figs)
    maps = figs["reliability"][0]
    assert any(isinstance(c, PolyCollection) for ax in maps.axes for c in ax.collections)
    sizes = {name: len(png_of(fig)) for name, (fig, _) in figs.items()}
    assert max(sizes.values()) < 1_000_000, sizes
    assert time.perf_counter() - t0 < 120
