"""Issue 27's internal errors and silent acceptances, each a clean InputError now (exit 2, one line
naming file, line and field), in validate where it can be known before the run."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from broken_inputs import AICON, DATA1, SHARED, Case, comparator_project, run_case, source_project  # noqa: E402

if not SHARED.is_dir():  # pragma: no cover
    pytest.skip(f"shared data not found at {SHARED}", allow_module_level=True)


def aicon_files(**changes):
    files = {f"ex{p.suffix}": p.read_text(encoding="latin-1") for p in AICON.iterdir()}
    for suffix, fn in changes.items():
        files[f"ex.{suffix}"] = fn(files[f"ex.{suffix}"])
    return files


def ior_last_line(text, new):
    lines = text.splitlines()
    lines[4] = new
    return "\n".join(lines) + "\n"


def first_obc(text, col, value):
    lines = text.splitlines()
    t = lines[0].split()
    t[col] = value
    return "\n".join([" ".join(t)] + lines[1:]) + "\n"


def second_phc_twice(text):
    lines = text.splitlines()
    t = lines[1].split()
    t[0], t[1] = lines[0].split()[:2]
    return "\n".join([lines[0], " ".join(t)] + lines[2:]) + "\n"


ODM = SHARED / "odm-br-gcp"
GCP_TEXT = (ODM / "gcp_list_floatxy_raw.txt").read_text(encoding="utf-8") if ODM.is_dir() else ""


def odm_camera(extra):
    return ('camera = { width = 4000, height = 3000, focal_px = 2904.0, sensor_width_mm = 6.17' + extra + ' }\n'
            'skip_lines = [19, 51, 52, 55, 70]\n')


CASES = [
    # ODM cameras: a valid principal point accepted (below), an impossible one named, focal length twice
    Case("gcp/principal-point-outside", {"gcp_list.txt": GCP_TEXT},
         source_project("gcp-list", "gcp_list.txt", odm_camera(", principal_point_px = [100000, 0.0]")),
         names="lies outside the 4000 × 3000"),
    Case("gcp/geocentric-crs", {"gcp_list.txt": "+proj=geocent +datum=WGS84 +units=m +no_defs\n"
                                                + "\n".join(GCP_TEXT.splitlines()[1:]) + "\n"},
         source_project("gcp-list", "gcp_list.txt", odm_camera("")), command="validate",
         names="gcp_list.txt:1, field 'crs'"),
    Case("gcp/heights-in-mm", {"gcp_list.txt": "\n".join(
        [GCP_TEXT.splitlines()[0]] + [" ".join(t[:2] + [str(float(t[2]) * 1000)] + t[3:])
                                      for t in (ln.split() for ln in GCP_TEXT.splitlines()[1:] if ln.strip())]) + "\n"},
         source_project("gcp-list", "gcp_list.txt", odm_camera("")), command="validate",
         names="gcp_list.txt:1, field 'crs'"),
    Case("gcp/focal-mm-and-px", {"gcp_list.txt": GCP_TEXT},
         source_project("gcp-list", "gcp_list.txt", odm_camera(", focal_mm = 4.5")), names="focal length twice"),
    # AICON
    Case("aicon/ior-zero-pixels", aicon_files(ior=lambda t: ior_last_line(t, "    23.6 15.6 0 0")),
         source_project("aicon", "ex"), names="ex.ior:5"),
    Case("aicon/ior-positive-c", aicon_files(ior=lambda t: t.replace("-28.78507", "28.78507", 1)),
         source_project("aicon", "ex"), names="ex.ior:1, field 'c'"),
    Case("aicon/obc-negative-sigma", aicon_files(obc=lambda t: first_obc(t, 4, "-0.01")),
         source_project("aicon", "ex"), names="ex.obc:1, field 'sX'"),
    Case("aicon/obc-empty", aicon_files(obc=lambda t: ""), source_project("aicon", "ex"), names="ex.obc"),
    Case("aicon/phc-empty", aicon_files(phc=lambda t: ""), source_project("aicon", "ex"), names="ex.phc"),
    Case("aicon/phc-measured-twice", aicon_files(phc=second_phc_twice), source_project("aicon", "ex"),
         names="ex.phc:2, field 'point'"),
    Case("aicon/validate-ior-zero-pixels", aicon_files(ior=lambda t: ior_last_line(t, "    23.6 15.6 0 0")),
         source_project("aicon", "ex"), command="validate", names="ex.ior:5"),
    # option bounds: validate and run
    Case("options/n-sim-2e9", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "blunder-rejection"\n[stage.options]\nn_sim = 2000000000\n'), command="validate",
        names="field 'n_sim'"),
    Case("options/rho-2-63", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "blunder-rejection"\n[stage.options]\nmethod = "rrr"\nrho = 9223372036854775807\n'),
        command="validate", names="field 'rho'"),
    Case("options/sigma0-denormal", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "helmert-screening"\n[stage.options]\nsigma0_mm = 1e-320\n'), names="field 'sigma0_mm'"),
    Case("options/sigma0-1e300", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "helmert-screening"\n[stage.options]\nsigma0_mm = 1e300\n'), command="validate",
        names="field 'sigma0_mm'"),
    Case("project/seed-negative", {"data.cmp": DATA1}, "[project]\nseed = -1\n" + comparator_project(),
         names="project.toml:2, field 'project.seed'"),
    Case("options/design-seed-negative", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "aicon"\nid = "a"\n[stage.options]\npath = "ex"\nseed = -5\n'), command="validate",
        names="field 'seed'"),
    # bundle options naming unknown points
    Case("bundle/fix-unknown-parameter", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "bundle"\n[stage.options]\nfix = ["NOPE"]\n'), names="project.toml:10, field 'fix'"),
    Case("bundle/ap-models-unknown-camera", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "bundle"\n[stage.options]\nap_models = { nocam = "brown" }\n'),
        names="project.toml:10, field 'ap_models'"),
    Case("bundle/datum-points-unknown", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "bundle"\n[stage.options]\ndatum_points = ["NOPE", "1", "2"]\n'),
        names="field 'datum_points'"),
    Case("bundle/distance-unknown", {"data.cmp": DATA1}, comparator_project(
        '[[stage]]\nuse = "bundle"\n[stage.options]\n'
        'distances = [{ from = "1", to = "NOPE", distance = 1.0, sigma = 0.1 }]\n'), names="field 'distances'"),
]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_issue27_case(case, tmp_path):
    res = run_case(case, tmp_path / "case")
    assert "Traceback" not in res.err and "internal error" not in res.err, res.err
    assert res.code == 2, res.err
    line = [ln for ln in res.err.splitlines() if ln.startswith("baarda:")][0]
    assert case.names in line, line


def test_rrr_rho_beyond_the_clean_set_names_the_option(tmp_path):
    text = (Path(__file__).resolve().parents[2] / "fixtures/paper000/data1.toml").read_text()
    text = text.replace("rho = 4 ", "rho = 14 ").replace("n_sim = 20000", "n_sim = 50")
    case = Case("rrr/rho-too-big", {"data1.cmp": DATA1}, text, names="field 'rho'", extra_args=["--scheduler", "sync"])
    res = run_case(case, tmp_path / "case")
    assert res.code == 2 and "n − u = 14" in res.err and case.names in res.err, res.err


def test_an_odm_principal_point_with_a_zero_is_accepted(tmp_path):
    case = Case("gcp/principal-point-zero", {"gcp_list.txt": GCP_TEXT},
                source_project("gcp-list", "gcp_list.txt", odm_camera(", principal_point_px = [12.5, 0.0]")),
                command="validate")
    res = run_case(case, tmp_path / "case")
    assert res.code == 0, res.err


@pytest.mark.parametrize("line,field", [('datum_points = ["NOPE", "1", "2"]', "datum_points"),
                                        ('fix = ["NOPE"]', "fix"), ('ap_models = { NOPE = "brown" }', "ap_models"),
                                        ('distances = [{ from = "1", to = "NOPE", distance = 1.0, sigma = 0.1 }]',
                                         "distances")])
def test_validate_checks_bundle_point_ids_against_the_block(tmp_path, line, field):
    case = Case("bundle/validate", {"data.cmp": DATA1},
                comparator_project('[[stage]]\nuse = "bundle"\n[stage.options]\n' + line + "\n"), command="validate")
    res = run_case(case, tmp_path / "case")
    assert res.code == 2 and f"field '{field}'" in res.err and "NOPE" in res.err, res.err


def test_with_set_an_error_in_the_file_names_the_users_project(tmp_path):
    proj = comparator_project('[[stage]]\nuse = "helmert-screening"\nid = "screening"\n[stage.options]\n'
                              'alpha0 = 2.0\n')
    for command in ("validate", "run"):
        case = Case("set/file-error", {"data.cmp": DATA1}, proj, command=command,
                    extra_args=["--set", "screening.beta0=0.8"])
        res = run_case(case, tmp_path / command)
        line = [ln for ln in res.err.splitlines() if ln.startswith("baarda:")][0]
        assert res.code == 2 and f"{tmp_path / command / 'project.toml'}:" in line and "alpha0" in line, line
