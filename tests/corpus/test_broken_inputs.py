"""Every broken input of the corpus (broken_inputs.py): the exit code, one ``baarda:`` line naming the
file, no traceback, nothing outside ``--out`` changed, the earlier stages' files intact."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from broken_inputs import SHARED, all_cases, run_case  # noqa: E402

if not SHARED.is_dir():  # pragma: no cover - the data sets live beside the repository
    pytest.skip(f"shared data not found at {SHARED}", allow_module_level=True)

CASES = all_cases()


def test_the_corpus_is_large_and_covers_every_reader():
    assert len(CASES) >= 600
    kinds = {c.name.split("/")[0] for c in CASES}
    assert {"comparator", "bal", "libmv", "aicon", "colmap", "targets", "dbat", "gcp", "options", "project", "run",
            "review", "stage-options", "set", "writers", "batch", "pmexport", "metashape", "opensfm"} <= kinds
    assert sum(c.command == "validate" for c in CASES) >= 200


def _quick_sample(cases) -> set[str]:
    """The cases `make test` runs: every second case the generators mark quick, per kind (the first of
    each kind always), so that `make test` stays within its time; `make test-slow` runs them all."""
    seen: dict[str, int] = {}
    keep = set()
    for c in cases:
        if not c.quick:
            continue
        kind = c.name.split("/")[0]
        if seen.get(kind, 0) % 2 == 0:
            keep.add(c.name)
        seen[kind] = seen.get(kind, 0) + 1
    return keep


QUICK = _quick_sample(CASES)
PARAMS = [pytest.param(c, id=c.name, marks=() if c.name in QUICK else pytest.mark.slow) for c in CASES]


@pytest.mark.parametrize("case", PARAMS)
def test_broken_input(case, tmp_path):
    res = run_case(case, tmp_path / "case")
    err = res.err
    assert "Traceback" not in err and "Traceback" not in res.out, err
    assert res.code == case.code, f"exit {res.code}, expected {case.code}: {err}"
    lines = [ln for ln in err.splitlines() if ln.startswith("baarda:")]
    assert lines, err
    message = lines[0]
    assert case.names in message, f"the message does not name {case.names!r}: {message}"
    assert case.also in message, f"the message does not name {case.also!r}: {message}"
    assert not [ln for ln in err.splitlines() if ln.startswith("[") and "ERROR" in ln], err   # no library log lines
    # nothing outside the run directory changed; no file that was there before changed
    out = case.out.split("/")[0]
    ours = (out, out + ".failed")
    for name, data in res.before.items():
        assert res.after.get(name) == data, f"{name} changed or vanished"
    new = sorted(set(res.after) - set(res.before))
    assert all(n.split("/")[0] in ours for n in new), f"written outside --out: {new}"
    assert not [n for n in res.after if n.split("/")[0].startswith(f".{out}.")], "a staging directory was left"
    # earlier stages' results intact (a later stage failed)
    if case.earlier:
        run = res.folder / out
        results = json.loads((run / "results.json").read_text())
        assert results["ok"] is False
        for f in case.earlier:
            assert (run / f).is_file(), f
