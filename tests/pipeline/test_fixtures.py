"""Every bundled project validates and runs end to end through the runner, every stage ok and
with a finding on its line of ``baarda review``.

The quick projects (under ~10 s on the 2-core machine) run in ``make test``, the others under the
``slow`` marker (``make test-slow``).  ``SECONDS`` holds each project's measured time (the time
column of fixtures/README.md); a project missing from it fails :func:`test_every_project_is_timed`,
so a new fixture has to be measured and placed.  Projects reading ``../shared/data`` beside the
repository skip with the reason when that folder is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project
from baarda.pipeline.review import _finding
from baarda.pipeline.runner import run_project
from baarda.pipeline.stage import TableData
from baarda.pipeline.units import unit_mismatches

from conftest import SHARED_BESIDE, needs_shared_beside

from tests.pipeline.protocol_consistency import check_run

ROOT = Path(__file__).resolve().parents[2]
PROJECTS = sorted((ROOT / "fixtures").rglob("*.toml"))

#: seconds of each run, measured with ``pytest -m "slow or not slow" tests/pipeline/test_fixtures.py
#: --durations=0`` (one process, ``OPENBLAS_NUM_THREADS=1``, the shared 2-core machine while other
#: jobs ran on it)
SECONDS = {
    "aicon/aicon.toml": 23.3,
    "aicon/vendor.toml": 6.6,
    "bal/bal.toml": 1.8,
    "bal/libmv.toml": 14.4,
    "calibration/charuco.toml": 0.5,
    "calibration/chessboard.toml": 8.8,   # a stereo rig since issue 25: IDS rejects 19 coordinates (2 before)
    "colmap/colmap.toml": 0.6,
    "colmap/rig.toml": 4.6,              # a three-camera COLMAP rig against a prior calibration (issue 25)
    "dbat/camcal-detect.toml": 5.2,
    "dbat/camcal-corrected.toml": 4.0,
    "dbat/camcal.toml": 0.4,
    "dbat/sxb.toml": 0.3,
    "design/design.toml": 4.2,
    "fisheye/fisheye.toml": 1.2,
    "gnss/gnss.toml": 3.8,
    "metashape/metashape.toml": 4.9,
    "monitoring/aicon-epochs.toml": 20.7,
    "monitoring/panel-epochs.toml": 9.0,
    "monitoring/testfield-epochs.toml": 7.5,
    "monitoring/vdi2634.toml": 3.0,
    "odm/odm-br-gcp.toml": 5.6,
    "pmexport/camcal-1ray.toml": 1.0,
    "pmexport/camcal-missing-obs.toml": 1.0,
    "pmexport/camcal.toml": 1.0,
    "opensfm/opensfm.toml": 6.6,
    "opensfm/gcp/gcp.toml": 7.0,
    "opensfm/berlin/berlin.toml": 11.0,
    "paper000/data1.toml": 0.6,
    "paper000/data2.toml": 0.6,
    "paper000/data3.toml": 0.6,
    "paper000/data4.toml": 0.6,
    "paper000/fiducial.toml": 0.5,
    "paper000/printed.toml": 0.5,
    "rendered/rendered.toml": 14.0,
    "study/study.toml": 6.7,
    "testfield/block.toml": 0.3,
    "testfield/study.toml": 31.9,
}
QUICK_LIMIT = 10.0

#: projects that another test of ``make test`` already runs end to end through the runner (and checks
#: in detail): their run here is under ``slow`` so that ``make test`` runs each project once
COVERED = {
    "dbat/camcal-detect.toml": "tests/dbat/test_detect.py",
    "study/study.toml": "tests/testfield/test_method_study_project.py",
    "design/design.toml": "tests/design/test_design.py",
    "gnss/gnss.toml": "tests/gcp/test_gnss_fixture.py",
    "paper000/data1.toml": "tests/pipeline/test_recordings.py",
    "testfield/block.toml": "tests/pipeline/test_recordings.py",
    "colmap/colmap.toml": "tests/pipeline/test_recordings.py",
    "dbat/camcal.toml": "tests/pipeline/test_recordings.py",
    "calibration/charuco.toml": "tests/pipeline/test_recordings.py",
    "monitoring/panel-epochs.toml": "tests/congruence/test_congruence_stage.py",
    "monitoring/testfield-epochs.toml": "tests/congruence/test_testfield_epochs.py",
    "dbat/camcal-corrected.toml": "tests/dbat/test_corrected.py",
    "monitoring/vdi2634.toml": "tests/acceptance/test_length_test.py",
}


def _rel(path: Path) -> str:
    return path.relative_to(ROOT / "fixtures").as_posix()


def _runs():
    """One parameter per project; the slow ones carry the ``slow`` marker."""
    out = []
    for p in PROJECTS:
        rel = _rel(p)
        slow = SECONDS.get(rel, float("inf")) >= QUICK_LIMIT or rel in COVERED
        out.append(pytest.param(rel, id=rel, marks=[pytest.mark.slow] if slow else []))
    return out


def test_every_project_is_timed():
    names = {_rel(p) for p in PROJECTS}
    assert names, "no bundled projects under fixtures/"
    assert names == set(SECONDS), (f"untimed: {sorted(names - set(SECONDS))}; "
                                   f"gone: {sorted(set(SECONDS) - names)}")


def test_covered_projects_are_run_by_the_test_named():
    """Each project moved under ``slow`` because another test runs it names a test file that does run
    it (its path in the file; ``make test`` collects that file)."""
    for rel, test in COVERED.items():
        assert (ROOT / "fixtures" / rel).exists(), rel
        text = (ROOT / test).read_text(encoding="utf-8")
        assert rel in text or rel.split("/")[-1] in text, f"{test} does not mention {rel}"
        assert "run_project" in text or 'main(["run"' in text, f"{test} runs no project"


@pytest.mark.parametrize("path", PROJECTS, ids=_rel)
def test_bundled_project_validates(path):
    project = load_project(path, PluginManager())
    assert project.stages


@pytest.fixture
def tables_made(monkeypatch):
    """Every :class:`TableData` made while the test runs (the run's tables, checked for their units)."""
    made = []
    init = TableData.__post_init__

    def record(self):
        self.declared_units = dict(self.units)         # what the stage said, before the suffixes fill in
        init(self)
        made.append(self)

    monkeypatch.setattr(TableData, "__post_init__", record)
    return made


#: names of lengths that must carry their unit in the tables of the stages converted so far
BARE_LENGTHS = {"x", "y", "vx", "vy", "X", "Y", "Z", "sX", "sY", "sZ", "dX", "dY", "dZ", "mdb_x", "mdb_y",
                "nabla_x", "nabla_y", "dX_check", "dY_check", "dZ_check"}


#: numeric columns without a unit suffix that are lengths all the same — still to be named with their unit
#: (their owners are changing those tables: the error ellipses of pipeline/stats/ellipses.py's
#: ``ellipse_columns`` in the bundle, independent-models and datum-transform point tables; the bundle's
#: external reliability per observation)
NOT_YET_SUFFIXED: set[str] = set()


def undeclared_numeric(table) -> list[str]:
    """Numeric columns of ``table`` with no unit in their name that nothing declares unitless: not the
    table (``units={"col": ""}`` given by the stage), not the conventional unitless names
    (``baarda.pipeline.units.known_unitless``: w, r, counts, ratios …), not a per-row ``unit`` column
    of the table (camera parameters, blunder-rejection rows: one unit per row)."""
    import numpy as np

    from baarda.pipeline.units import column_unit, known_unitless

    declared = getattr(table, "declared_units", {})
    if "unit" in table.columns:
        return []
    out = []
    for name, values in table.columns.items():
        if column_unit(name) or name in declared or known_unitless(name):
            continue
        try:
            a = np.asarray(values)
        except (TypeError, ValueError):
            continue
        if a.size and a.dtype.kind in "iuf":          # an empty column says nothing of its kind
            out.append(name)
    return out


def check_table_units(tables) -> None:
    """Column names and ``units`` agree in every table (docs/conventions.md, *Column names carry their
    unit*); a numeric column without a unit suffix is declared unitless (:func:`undeclared_numeric`);
    the bundle's observation and point tables name no length without its unit."""
    bad = {t.description[:60]: unit_mismatches(t) for t in tables if unit_mismatches(t)}
    assert not bad, bad
    bare = {t.description[:60]: sorted(set(undeclared_numeric(t)) - NOT_YET_SUFFIXED) for t in tables}
    bare = {k: v for k, v in bare.items() if v}
    assert not bare, f"numeric columns with no unit in their name and not declared unitless: {bare}"
    bundle = [t for t in tables if t.description.startswith(("every image observation", "adjusted object points"))]
    bare = {t.description[:40]: sorted(BARE_LENGTHS & set(t.columns)) for t in bundle if BARE_LENGTHS & set(t.columns)}
    assert not bare, bare


def test_table_unit_check_finds_a_disagreement():
    assert unit_mismatches(TableData({"v_px": [1.0], "w": [0.5]})) == []
    assert unit_mismatches(TableData({"v_px": [1.0]}, units={"v_px": "mm"}))
    assert unit_mismatches(TableData({"v": [1.0]}, units={"v": "px"}))
    assert unit_mismatches(TableData({"v_um": [1.0]}, units={"x_um": "µm"}))


def test_numeric_columns_without_a_unit_must_be_declared_unitless(tables_made):
    TableData({"v_px": [1.0], "w": [0.5], "n_flagged": [3], "rho": [0.1], "point": ["a"]})
    TableData({"gain": [2.0]}, units={"gain": ""})                                   # declared by its table
    TableData({"parameter": ["c", "K1"], "value": [24.0, 1e-4], "unit": ["mm", "mm⁻²"]})   # one unit per row
    assert [undeclared_numeric(t) for t in tables_made] == [[], [], []]
    assert undeclared_numeric(TableData({"sigma": [0.1], "flag": [True], "id": ["p"]})) == ["sigma"]
    with pytest.raises(AssertionError, match="not declared unitless"):
        check_table_units([TableData({"mdb": [0.3]})])


@pytest.mark.parametrize("rel", _runs())
def test_bundled_project_runs(rel, tmp_path, tables_made):
    project = ROOT / "fixtures" / rel
    if needs_shared_beside(project):
        pytest.skip(f"{rel} reads ../shared/data beside the repository ({SHARED_BESIDE}), absent here")
    out = run_project(project, tmp_path / "run", verbose=False)
    assert tables_made, "the run made no table in this process"
    check_table_units(tables_made)
    assert out.ok, out.message
    res = json.loads((tmp_path / "run" / "results.json").read_text())
    stages = load_project(project, PluginManager()).stages
    assert [s["id"] for s in res["stages"]] == [s.id for s in stages]
    bad = {s["id"]: s.get("error") or s["status"] for s in res["stages"] if s["status"] != "ok"}
    assert not bad, bad
    assert all((tmp_path / "run" / f"{s['id']}.rrd").exists() for s in res["stages"])
    # every stage says what it found on its line of `baarda review` (its summary's headline, or a
    # source's "read N photo(s) …")
    blank = [f"{s['id']} ({s['use']})" for s in res["stages"] if not _finding(s).strip()]
    assert not blank, f"stages without a finding in `baarda review`: {blank}"
    # results.json holds summaries and pointers to the tables, never per-observation / per-point arrays
    long = _long_lists(res)
    assert not long, f"lists longer than {MOST_IN_RESULTS} in results.json (belong in a table): {long}"
    for s in res["stages"]:
        for name, t in s["tables"].items():
            assert (tmp_path / "run" / t["csv"]).exists() and (tmp_path / "run" / t["parquet"]).exists(), t
    # one truth per number: the protocol summary is results.json's, its counts and RMS the tables'
    check_run(tmp_path / "run")
    REPORTS.append((rel, tmp_path / "run" / "report.html"))


REPORTS: list[tuple[str, Path]] = []
"""(project, report.html) of every bundled project run by :func:`test_bundled_project_runs` in this
session, for :func:`test_bundled_reports_fit_six_screens` (defined after it: pytest runs it later)."""


def _screenshots_tool():
    import importlib.util

    spec = importlib.util.spec_from_file_location("baarda_screenshots_tool", ROOT / "tools" / "screenshots.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("session", [pytest.param("quick"), pytest.param("slow", marks=pytest.mark.slow)])
def test_bundled_reports_fit_six_screens(session):
    """Every report.html of the bundled projects run in this session is at most six screen heights
    (1920 × 1080) before its appendix of tables (issue 23), measured as ``make screenshots`` measures
    it: the page's layout in headless Chromium, after its figures are decoded.  One Chromium run for
    all reports; skipped without Chromium (``make screenshots`` installs Debian's package)."""
    import shutil

    if not REPORTS:
        pytest.skip("no bundled project ran in this session")
    exe = next((shutil.which(n) for n in ("chromium", "chromium-browser") if shutil.which(n)), None)
    if exe is None:
        pytest.skip("no chromium on PATH (make screenshots installs it)")
    tool = _screenshots_tool()
    got = tool.measure_many(exe, [page for _, page in REPORTS])
    screens = {rel: before / tool.VIEW_H for (rel, _), (_, before) in zip(REPORTS, got)}
    assert all(h > 0.5 for h in screens.values()), screens          # measured: a report is never empty
    long = {rel: round(h, 2) for rel, h in screens.items() if h > tool.MAX_SCREENS}
    assert not long, f"reports longer than {tool.MAX_SCREENS} screen heights before the appendix: {long}"


MOST_IN_RESULTS = 100
"""The longest list results.json may hold (issue 22: summaries and pointers to tables, not arrays)."""


def _long_lists(obj, where="results.json") -> list[str]:
    """``where[…]: length`` of every list in ``obj`` longer than :data:`MOST_IN_RESULTS`; the run's
    manifest (``files``, every file of the run: what the next run may replace, pipeline/rundir.py)
    is no data and not counted."""
    out = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k == "files" and isinstance(v, list) and all(isinstance(f, str) for f in v):
                continue
            out += _long_lists(v, f"{where}.{k}")
    elif isinstance(obj, list):
        if len(obj) > MOST_IN_RESULTS:
            out.append(f"{where}: {len(obj)}")
        for i, v in enumerate(obj):
            out += _long_lists(v, f"{where}[{i}]")
    return out
