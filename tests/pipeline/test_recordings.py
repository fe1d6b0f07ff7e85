"""Every recording of a run, read back from its file: the blueprint, the entity paths, the text.

The bundled projects run through the ordinary runner; each ``<stage>.rrd`` is opened with rerun's
own reader (``baarda.pipeline.recording.read_recording``), not with anything the writer kept.
"""

from __future__ import annotations

import unicodedata
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from baarda.pipeline.recording import (log_series, open_recording, photo_root, point_ellipsoids, read_recording,
                                       thin, view_from_photo, view_vectors, viewer_text)
from baarda.pipeline.runner import run_project

ROOT = Path(__file__).resolve().parents[2]
PROJECTS = ["paper000/data1.toml", "testfield/block.toml", "colmap/colmap.toml", "dbat/camcal.toml",
            "calibration/charuco.toml"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, shared_beside):
    out = {}
    for p in PROJECTS:
        run_dir = tmp_path_factory.mktemp(Path(p).stem) / "run"
        outcome = run_project(ROOT / "fixtures" / p, run_dir, verbose=False)
        assert outcome.ok, (p, [(r.id, r.status, r.error) for r in outcome.records])
        out[p] = run_dir
    return out


def _strings(path: Path):
    """Every string value the file holds (labels, text documents, values)."""
    from rerun.chunk import RrdReader

    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        for i, name in enumerate(batch.schema.names):
            if ":" not in name:
                continue
            col = batch.column(i)
            if "string" not in str(col.type) and "utf8" not in str(col.type):
                continue
            stack = col.to_pylist()
            while stack:
                v = stack.pop()
                if isinstance(v, list):
                    stack.extend(v)
                elif isinstance(v, str):
                    yield v


@pytest.mark.parametrize("project", PROJECTS)
def test_every_recording_has_a_blueprint_and_rooted_paths(runs, project):
    run_dir = runs[project]
    files = sorted(run_dir.glob("*.rrd"))
    assert files
    for f in files:
        stage = f.stem
        s = read_recording(f)
        assert s.views, f"{f.name}: no blueprint"
        for e in s.entities:
            assert e.path == f"/{stage}" or e.path.startswith(f"/{stage}/"), (f.name, e.path)
        stages = {g.stem for g in files}
        for v in s.views:   # this stage's views and the earlier stages' (the run's layout so far)
            assert v.origin.strip("/").split("/")[0] in stages, (f.name, v)
        assert any(v.kind == "TextDocument" and v.origin == f"/{stage}/summary" for v in s.views), (f.name, s.views)
        kinds = {e.path: e.columns for e in s.entities}
        # every entity with a 2-D archetype is inside a 2-D view of its own photo, and that view
        # is one photo: no two photos' entities share a view
        for path, cols in kinds.items():   # (own views only below: origins under /<stage>)
            if any(c.split(":")[0] in ("Points2D", "Arrows2D", "LineStrips2D") for c in cols):
                views = [v for v in s.views if v.kind == "2D" and (path + "/").startswith(v.origin + "/")]
                assert len(views) == 1, (f.name, path, views)
                assert views[0].origin == "/" + photo_root(path.strip("/")), (f.name, path, views[0])
            if any(c.startswith("Scalars:") for c in cols):
                assert any(v.kind == "TimeSeries" and path.startswith(v.origin + "/") for v in s.views), (f.name, path)
            if any(c.split(":")[0] in ("Points3D", "Ellipsoids3D") for c in cols):
                assert any(v.kind == "3D" and any((path + "/").startswith(c.removesuffix("**")) for c in v.contents)
                           for v in s.views), (f.name, path)
        for text in _strings(f):
            bad = [ch for ch in text if unicodedata.combining(ch)]
            assert not bad, (f.name, text[:80])


def test_the_paper000_pair_gets_one_view_per_photo_and_time_series(runs):
    run_dir = runs["paper000/data1.toml"]
    screening = read_recording(run_dir / "screening.rrd")
    assert sorted(v.origin for v in screening.views if v.kind == "2D") == [
        "/screening/photos/L", "/screening/photos/R", "/source/photos/L", "/source/photos/R"]
    blunders = read_recording(run_dir / "blunders.rrd")
    series = sorted(v.origin for v in blunders.views if v.kind == "TimeSeries" and v.origin.startswith("/blunders"))
    assert {"/blunders/ids/global_test", "/blunders/ids/w", "/blunders/pope/tau", "/blunders/pope/sigma0",
            "/blunders/rrr/H"} <= set(series), series
    # each critical value that changed is drawn in its statistic's view (IDS's F, Pope's τ: the dof
    # fell with each rejection; RRR's naive Beta quantile with the recursive residuals), styled as a
    # threshold; the ones that stayed the same (IDS's K, RRR's Monte Carlo H) are static values
    ents = {e.path: e for e in blunders.entities}
    for stat, crit in (("ids/global_test/T", "ids/global_test/F_critical"), ("pope/tau/tau_max", "pope/tau/tau_critical"),
                       ("rrr/H/H_exp", "rrr/H/H_naive")):
        for path in (stat, crit):
            assert "Scalars:scalars" in ents[f"/blunders/{path}"].columns, path
        assert "SeriesLines:interpolation_mode" in ents[f"/blunders/{crit}"].columns      # the threshold style
        assert "SeriesPoints:markers" in ents[f"/blunders/{stat}"].columns                # the statistic's
    assert "/blunders/ids/w/K" not in ents and "K" in ents["/blunders/ids/w/constants"].columns
    assert "/blunders/rrr/H/H" not in ents and "H" in ents["/blunders/rrr/H/constants"].columns


def test_bundle_logs_every_photo_and_point_ellipsoids(runs):
    run_dir = runs["colmap/colmap.toml"]
    import json

    results = json.loads((run_dir / "results.json").read_text())
    bundle_id = next(s["id"] for s in results["stages"] if s["use"] == "bundle")
    s = read_recording(run_dir / f"{bundle_id}.rrd")
    paths = [e.path for e in s.entities]
    photos = [p for p in paths if p.startswith(f"/{bundle_id}/world/photos/")]
    images = {p.split("/")[3] for p in paths if p.startswith(f"/{bundle_id}/images/")}
    assert len(photos) == len(images) > 0
    ell = next(e for e in s.entities if e.path.endswith("/world/points/precision"))
    assert "Ellipsoids3D:half_sizes" in ell.columns
    assert any(v.kind == "2D" for v in s.views) and any(v.kind == "3D" for v in s.views)
    series = {v.origin for v in s.views if v.kind == "TimeSeries"}
    assert {f"/{bundle_id}/convergence/{g}" for g in ("cost", "sigma0", "step")} <= series
    # λ stayed 0 (no damped step): a static value, not a flat line
    ents = {e.path: e for e in s.entities}
    damping = f"/{bundle_id}/convergence/damping"
    assert (damping in series) != ("lambda" in ents.get(damping + "/constants", EMPTY).columns)


EMPTY = type("Empty", (), {"columns": []})()


def test_no_recording_plots_a_constant(runs):
    """No time series of any stage of these runs is constant over the run: a critical value that never
    changed, a damping factor that stayed 0, a value logged once are static values (``…/constants``),
    not flat lines (docs/recordings.md lists the exceptions: none in these projects)."""
    from baarda.pipeline.recording import is_constant, read_series

    n = 0
    for run_dir in runs.values():
        for f in sorted(run_dir.glob("*.rrd")):
            for path, values in read_series(f).items():
                n += 1
                assert not is_constant(values), (f.name, path, values[:5])
    assert n >= 10


def test_log_series_puts_constants_aside_and_thresholds_beside_their_statistic(tmp_path):
    from baarda.pipeline.recording import read_series

    rec = open_recording(tmp_path / "s.rrd", "id")
    const = log_series(rec, "test/tau", [0, 1, 2], {"tau_max": [5.0, 4.0, 2.5], "flat": [1.0, 1.0, 1.0]},
                       {"tau_critical": [2.9, 2.8, 2.7], "K": [3.29, 3.29, 3.29], "gone": [np.nan] * 3})
    rec.disconnect()
    assert const == {"flat": 1.0, "K": 3.29}
    s = read_recording(tmp_path / "s.rrd")
    np.testing.assert_array_equal(sorted(read_series(tmp_path / "s.rrd")["/s/test/tau/tau_critical"]), [2.7, 2.8, 2.9])
    ents = {e.path: e for e in s.entities}
    assert set(ents) >= {"/s/test/tau/tau_max", "/s/test/tau/tau_critical", "/s/test/tau/constants"}
    assert not {"/s/test/tau/flat", "/s/test/tau/K", "/s/test/tau/gone"} & set(ents)
    assert {"K", "flat"} <= set(ents["/s/test/tau/constants"].columns)
    views = [v for v in s.views if v.kind == "TimeSeries"]
    assert [v.origin for v in views] == ["/s/test/tau"]      # statistic and threshold in one view
    with pytest.raises(ValueError, match="2 values for 3 steps"):
        log_series(open_recording(tmp_path / "t.rrd", "id"), "x", [0, 1, 2], {"a": [1.0, 2.0]})


def test_the_last_stage_holds_the_whole_runs_layout(runs):
    """Each file's layout has one tab per stage up to it; the last stage's file has every stage's views,
    so opening the files in run order (baarda view) shows the whole run laid out."""
    import json

    for run_dir in runs.values():
        order = [s["id"] for s in json.loads((run_dir / "results.json").read_text())["stages"]]
        for k, sid in enumerate(order):
            views = read_recording(run_dir / f"{sid}.rrd").views
            shown = {v.origin.strip("/").split("/")[0] for v in views}
            assert shown == set(order[:k + 1]), (run_dir, sid, shown)
        last = read_recording(run_dir / f"{order[-1]}.rrd").views
        for sid in order:   # the same views as the stage's own file has for itself
            own = {(v.kind, v.origin) for v in read_recording(run_dir / f"{sid}.rrd").views
                   if v.origin.strip("/").split("/")[0] == sid}
            assert own <= {(v.kind, v.origin) for v in last}, sid


def test_merged_stages_never_share_an_entity(runs):
    for run_dir in runs.values():
        seen = {}
        for f in run_dir.glob("*.rrd"):
            for e in read_recording(f).entities:
                assert e.path not in seen, (e.path, f.name, seen.get(e.path))
                seen[e.path] = f.name


def test_view_from_photo_turns_y_down_and_keeps_x():
    fmt = (36.0, 24.0)
    xy = np.array([[0.0, 0.0], [18.0, 12.0], [-18.0, -12.0], [5.0, 3.0]])
    uv = view_from_photo(xy, fmt)
    np.testing.assert_allclose(uv, [[18, 12], [36, 0], [0, 24], [23, 9]])  # top right of the photo: v = 0
    np.testing.assert_allclose(view_from_photo(xy), np.column_stack([xy[:, 0], -xy[:, 1]]))
    np.testing.assert_allclose(view_vectors([[1.0, 2.0]]), [[1.0, -2.0]])
    # a vector from a to b in the photo is the vector between their views
    a, b = xy[1:2], xy[3:4]
    np.testing.assert_allclose(view_from_photo(b, fmt) - view_from_photo(a, fmt), view_vectors(b - a))


def test_viewer_text_removes_combining_marks():
    assert viewer_text("∇̂ and σ̂0 = 1") == "∇^ and σ^0 = 1"
    assert viewer_text("é") == "é" and len(viewer_text("é")) == 1  # composed, not dropped
    assert viewer_text("x̃ q̄") == "x~ q-"


def test_point_ellipsoids_against_the_covariance():
    rng = np.random.default_rng(3)
    XYZ = rng.normal(size=(4, 3)) * 100
    A = rng.normal(size=(4, 3, 3))
    cov = A @ A.transpose(0, 2, 1) * 1e-6
    c, half, q, scale = point_ellipsoids(XYZ, cov)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(q).as_matrix()
    # the ellipsoid R diag(half²) Rᵀ / scale² is the covariance itself (1 σ)
    np.testing.assert_allclose(R @ (half[:, :, None] ** 2 * np.eye(3)) @ R.transpose(0, 2, 1) / scale ** 2, cov,
                               rtol=1e-9, atol=1e-18)
    ext = np.linalg.norm(np.ptp(XYZ, axis=0))
    assert np.isclose(np.median(half[:, 0]), 0.01 * ext)


def test_thinning_is_said_and_unthinned_is_everything(tmp_path):
    rec = open_recording(tmp_path / "x.rrd", "id")
    assert len(thin(rec, np.arange(10), None, "photos")) == 10
    kept = thin(rec, np.arange(10), 3, "photos")
    assert len(kept) <= 3 and rec.notes == [f"photos: {len(kept)} of 10 logged (every 4th)"]
    rec.disconnect()
    s = read_recording(tmp_path / "x.rrd")
    assert any(e.path == "/x/notes" for e in s.entities)


def test_a_stage_blueprint_is_kept(tmp_path):
    import rerun.blueprint as rrb

    rec = open_recording(tmp_path / "mine.rrd", "id")
    rec.log("world/p", rr.Points3D([[0, 0, 0]]))
    rec.send_blueprint(rrb.Blueprint(rrb.Spatial3DView(origin="/mine/world", name="only")))
    rec.disconnect()
    views = read_recording(tmp_path / "mine.rrd").views
    assert [(v.kind, v.origin) for v in views] == [("3D", "/mine/world")]
