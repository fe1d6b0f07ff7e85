"""Stage tables written by pyarrow (baarda.pipeline.tables): CSV and Parquet hold the same values at
full precision, units and descriptions in the Parquet metadata, results.json points to them, and
the run option ``outputs = "summary"`` skips the tables marked ``detail``."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project, validate_inputs
from baarda.pipeline.runner import run_project
from baarda.pipeline.stage import TableData
from baarda.pipeline.tables import column_array, read_table, skipped_note, to_arrow, units_of, write_table, write_tables

ROOT = Path(__file__).resolve().parents[2]
DATA1 = ROOT / "fixtures" / "paper000" / "data1.toml"


def _table(rng) -> TableData:
    n = 50
    v = rng.normal(size=n) * 10.0 ** rng.integers(-12, 6, size=n)
    v[3] = np.nan
    v[4] = 0.1
    v[5] = 1 / 3
    v[6] = -0.0
    labels = [f"P{i}" for i in range(n)]
    labels[7] = None
    labels[8] = 'with, comma and "quote"'
    mixed = np.array([None] * n, dtype=object)
    mixed[::3] = 1.5
    return TableData({"point": labels, "v_px": v, "r": rng.random(n), "flagged": rng.random(n) > 0.5,
                      "rays": np.arange(n), "mixed": mixed, "ints": list(range(n)),
                      "tags": [[1, 2]] * n, "code": np.array(["a", "bb"] * (n // 2))},
                     "a test table", units={"v_px": "px", "r": ""})


def test_csv_and_parquet_hold_the_same_values_at_full_precision(tmp_path):
    t = _table(np.random.default_rng(1))
    entry = write_table(tmp_path, "s_t", t, stage="s", name="t")
    assert entry == {"csv": "s_t.csv", "parquet": "s_t.parquet", "rows": 50,
                     "columns": {c: {"v_px": "px"}.get(c, "") for c in t.columns}}
    rows = list(csv.DictReader((tmp_path / "s_t.csv").open(newline="", encoding="utf-8")))
    pa_t = pq.read_table(tmp_path / "s_t.parquet")
    v = np.asarray(t.columns["v_px"])
    got_csv = np.array([float(r["v_px"]) if r["v_px"] else np.nan for r in rows])
    got_pq = pa_t.column("v_px").to_numpy(zero_copy_only=False)
    ok = ~np.isnan(v)
    assert np.array_equal(got_csv[ok], v[ok]) and np.array_equal(got_pq[ok], v[ok])      # bit for bit
    assert rows[3]["v_px"] == "" and pa_t.column("v_px")[3].as_py() is None               # NaN: no value
    assert rows[4]["v_px"] == "0.1" and rows[5]["v_px"] == repr(1 / 3)
    assert {r["flagged"] for r in rows} <= {"true", "false"}
    assert [r["flagged"] == "true" for r in rows] == list(t.columns["flagged"])
    assert rows[7]["point"] == "" and rows[8]["point"] == 'with, comma and "quote"'
    assert rows[0]["mixed"] == "1.5" and rows[1]["mixed"] == ""
    assert rows[2]["ints"] == "2" and rows[0]["tags"] == "[1, 2]" and rows[1]["code"] == "bb"
    assert pa_t.column("rays").type == "int64" and pa_t.column("flagged").type == "bool"
    # the header is written as Python's csv writes it (no quotes unless needed)
    assert (tmp_path / "s_t.csv").read_text(encoding="utf-8").splitlines()[0] == ",".join(t.columns)


def test_parquet_carries_units_and_descriptions(tmp_path):
    t = _table(np.random.default_rng(2))
    write_table(tmp_path, "s_t", t, stage="s", name="t")
    schema = pq.read_schema(tmp_path / "s_t.parquet")
    assert schema.metadata[b"description"].decode() == "a test table"
    assert schema.metadata[b"stage"] == b"s" and schema.metadata[b"name"] == b"t"
    assert schema.field("v_px").metadata[b"unit"].decode() == "px"
    assert schema.field("v_px").metadata[b"description"]
    assert units_of(tmp_path / "s_t.parquet")["r"] == "" and units_of(tmp_path / "s_t.parquet")["v_px"] == "px"
    assert read_table(tmp_path / "s_t.csv").num_rows == read_table(tmp_path / "s_t.parquet").num_rows == 50


def test_columns_from_numpy_and_lists():
    assert column_array(np.array([1.0, np.nan])).null_count == 1
    assert column_array(np.array([1, 2], np.int32)).type == "int32"
    assert column_array([None, None]).type == "string"
    assert column_array(["a", 1]).to_pylist() == ["a", "1"]          # Arrow cannot type it: the text
    assert column_array(np.array(["x", None, 2.5], dtype=object)).to_pylist() == ["x", None, "2.5"]
    with pytest.raises(ValueError, match="one dimension"):
        column_array(np.zeros((2, 2)), "xy")
    empty = to_arrow(TableData({"a": [], "b": np.zeros(0)}))
    assert empty.num_rows == 0


def test_summary_outputs_skip_detail_tables(tmp_path):
    tables = {"observations": TableData({"a": [1]}, detail=True), "sums": TableData({"b": [2.0]})}
    done = write_tables(tmp_path, "st", tables, outputs="summary")
    assert done.skipped == ["observations"] and list(done.tables) == ["sums"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["st_sums.csv", "st_sums.parquet"]
    assert "st_observations" in skipped_note("st", done.skipped) and skipped_note("st", []) == ""
    (tmp_path / "full").mkdir()
    full = write_tables(tmp_path / "full", "st", tables)
    assert list(full.tables) == ["observations", "sums"] and not full.skipped
    with pytest.raises(ValueError, match="outputs"):
        write_tables(tmp_path, "st", tables, outputs="some")


def test_writing_tables_shows_progress_over_rows(tmp_path):
    """Writing a stage's tables is a phase with a bar: rows written of all rows, the last table."""
    import io

    from baarda.pipeline.stage import Progress

    out = io.StringIO()
    tables = {"observations": TableData({"a": np.arange(300)}, detail=True), "sums": TableData({"b": [2.0]})}
    write_tables(tmp_path, "st", tables, progress=Progress("st", stream=out, enabled=True, live=False, interval=0))
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("  [st] tables 300/301 (100 %), last observations")
    assert lines[-1].startswith("  [st] tables 301/301 (100 %), last sums")


@pytest.fixture(scope="module")
def full_run(tmp_path_factory) -> Path:
    """Paper 000's Data 1 run with every output."""
    run = tmp_path_factory.mktemp("data1") / "full"
    assert run_project(DATA1, run, verbose=False).ok
    return run


def test_run_option_outputs_summary(tmp_path, full_run):
    """``--set run.outputs=summary`` on paper 000's Data 1: the per-observation tables are not written,
    results.json and the report say which; the stages' numbers are those of the full run."""
    short = run_project(DATA1, tmp_path / "short", verbose=False, overrides={"run.outputs": "summary"})
    assert short.ok and short.project.run.outputs == "summary"
    res = json.loads((tmp_path / "short" / "results.json").read_text())
    by_id = {s["id"]: s for s in res["stages"]}
    assert by_id["blunders"]["skipped_tables"] == ["observations"]
    assert by_id["screening"]["skipped_tables"] == ["observations"]
    assert not (tmp_path / "short" / "blunders_observations.csv").exists()
    assert not (tmp_path / "short" / "blunders_observations.parquet").exists()
    assert (full_run / "blunders_observations.parquet").exists()
    report = (tmp_path / "short" / "report.md").read_text(encoding="utf-8")
    assert "blunders_observations" in report and 'outputs = "summary"' in report
    full_res = json.loads((full_run / "results.json").read_text())
    assert [s["summary"] for s in full_res["stages"]] == [s["summary"] for s in res["stages"]]
    assert full_res["stages"][1]["tables"]["observations"]["rows"] == 18
    assert 'outputs = "summary"' in (tmp_path / "short" / "project.resolved.toml").read_text()


def test_results_json_points_to_tables_with_units(full_run):
    res = json.loads((full_run / "results.json").read_text())
    for s in res["stages"]:
        for name, t in s["tables"].items():
            pa_t = pq.read_table(full_run / t["parquet"])
            assert pa_t.num_rows == t["rows"] and pa_t.column_names == list(t["columns"])
            assert t["csv"] in res["files"] and t["parquet"] in res["files"]


def test_outputs_option_is_checked(tmp_path):
    project = tmp_path / "p.toml"
    text = DATA1.read_text(encoding="utf-8").replace("[[stage]]", '[run]\noutputs = "some"\n\n[[stage]]', 1)
    project.write_text(text, encoding="utf-8")
    for f in (DATA1.parent.glob("*")):
        if f.suffix != ".toml" and f.is_file():
            (tmp_path / f.name).write_bytes(f.read_bytes())
    with pytest.raises(InputError) as e:
        load_project(project, PluginManager())
    assert e.value.field == "run.outputs" and e.value.line == text.splitlines().index('outputs = "some"') + 1
    assert "'full'" in str(e.value) and "'summary'" in str(e.value)
    with pytest.raises(InputError) as e:
        load_project(DATA1, PluginManager(), overrides={"run.output": "summary"})
    assert "did you mean 'run.outputs'" in str(e.value)
    with pytest.raises(InputError, match="unknown table 'runs'"):
        project.write_text(text.replace("[run]", "[runs]"), encoding="utf-8")
        load_project(project, PluginManager())
    project.write_text(text.replace('"some"', '"summary"'), encoding="utf-8")
    p = load_project(project, PluginManager())
    assert p.run.outputs == "summary"
    validate_inputs(p)


def test_float64_text_reads_back_as_the_same_number(tmp_path):
    """pyarrow writes the shortest text that reads back as the same double (what compare.py and any
    CSV reader parse)."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(size=2000) * 10.0 ** rng.integers(-300, 300, size=2000),
                        [5e-324, 1.7976931348623157e308, 1e-7, 123456.789e-12]])
    write_table(tmp_path, "x", TableData({"x": x}))
    rows = (tmp_path / "x.csv").read_text().splitlines()[1:]
    assert all(float(a) == b for a, b in zip(rows, x)) and len(rows) == len(x)
    assert not any(math.isnan(float(a)) for a in rows)


def _doc_snippets() -> list[str]:
    text = (ROOT / "docs" / "report.md").read_text(encoding="utf-8")
    section = text.split("## The tables: CSV and Parquet", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_documented_ways_to_read_a_table_work(tmp_path, monkeypatch):
    """docs/report.md's pyarrow / pandas / polars / DuckDB code on a bundle run (a library not
    installed here: its snippet is skipped, the others still run)."""
    import importlib.util
    import io
    from contextlib import redirect_stdout

    snippets = _doc_snippets()
    assert len(snippets) == 3
    out = run_project(ROOT / "fixtures" / "testfield" / "block.toml", tmp_path / "run", verbose=False)
    assert out.ok
    monkeypatch.chdir(tmp_path)
    ran = []
    for code in snippets:
        parts = re.split(r"\n(?=import )", code)              # the pyarrow part runs without pandas
        for part in parts:
            mod = re.match(r"import (\w+)", part.strip()).group(1)
            if importlib.util.find_spec(mod) is None:
                continue
            scope: dict = {}
            with redirect_stdout(io.StringIO()):
                exec(compile(part, "docs/report.md", "exec"), scope)
            ran.append(mod)
            if mod == "pyarrow":
                assert scope["t"].num_rows == json.loads((tmp_path / "run" / "results.json").read_text())[
                    "stages"][-1]["tables"]["observations"]["rows"]
                assert set(scope["units"]) == set(scope["t"].column_names)
            if mod == "pandas":
                assert len(scope["worst"]) == 10 and len(scope["obs_csv"]) == len(scope["obs"])
                assert np.array_equal(scope["obs_csv"]["wx"].to_numpy(), scope["obs"]["wx"].to_numpy(), equal_nan=True)
    assert "pyarrow" in ran
    print("ran:", ran)


def test_single_precision_is_written_as_the_double_it_is(tmp_path):
    x = np.array([0.1, 1 / 3], np.float32)
    write_table(tmp_path, "f", TableData({"x": x, "y": list(x)}))
    rows = list(csv.DictReader((tmp_path / "f.csv").open()))
    assert [float(r["x"]) for r in rows] == [float(v) for v in x] == [float(r["y"]) for r in rows]
    assert pq.read_schema(tmp_path / "f.parquet").field("x").type == "double"


def test_cli_set_run_outputs(tmp_path, capsys):
    """``baarda validate/run --set run.outputs=…``: checked like any option, applied to the run."""
    from baarda.pipeline.cli import main

    assert main(["validate", str(DATA1), "--set", "run.outputs=nope"]) == 2
    err = capsys.readouterr().err
    assert "--set, field 'run.outputs': must be one of 'full', 'summary', got 'nope'" in err
    assert main(["validate", str(DATA1), "--set", "run.outputs=summary"]) == 0
    assert main(["run", str(DATA1), "--out", str(tmp_path / "run"), "--quiet", "--set", "run.outputs=summary"]) == 0
    assert not list((tmp_path / "run").glob("*_observations.*"))      # paper 000's tables are all per observation
    assert (tmp_path / "run" / "results.json").exists() and (tmp_path / "run" / "blunders_w.png").exists()


@pytest.mark.parametrize("quoted", [True, False])
def test_a_table_written_in_chunks_is_the_table_written_at_once(tmp_path, monkeypatch, quoted):
    """Tables longer than CHUNK_ROWS are converted and written chunk by chunk (peak memory): the CSV
    text is byte for byte the same and the Parquet file holds the same values, types and metadata."""
    import baarda.pipeline.tables as tables

    rng = np.random.default_rng(7)
    t = _table(rng)
    if not quoted:
        t.columns["point"] = [f"P{i}" for i in range(50)]
    pair = rng.normal(size=(50, 2))
    t.columns["strided_px"] = pair[:, 1]                   # a strided view, as the stage's columns are
    t.columns["all_none"] = [None] * 50
    write_table(tmp_path, "whole", t, stage="s", name="t")
    monkeypatch.setattr(tables, "CHUNK_ROWS", 7)
    entry = write_table(tmp_path, "parts", t, stage="s", name="t")
    assert entry["rows"] == 50
    assert (tmp_path / "parts.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
    a, b = pq.read_table(tmp_path / "whole.parquet"), pq.read_table(tmp_path / "parts.parquet")
    assert b.equals(a, check_metadata=True)
    assert pq.ParquetFile(tmp_path / "parts.parquet").num_row_groups == 8
