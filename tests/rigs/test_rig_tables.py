"""Rig and frame tables: reading, the checks with file, line and field, and the written table read
back as a calibration (docs/rigs.md)."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import adjust, rig_result
from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Rigs
from baarda.pipeline.rigs import attach_rigs, read_rig_table
from baarda.pipeline.synthetic.rig import make_rig_block

HEADER = "rig,camera,reference,status,X_m,Y_m,Z_m,omega_deg,phi_deg,kappa_deg,sX_m,sY_m,sZ_m,somega_deg,sphi_deg,skappa_deg\n"


@pytest.fixture
def bare():
    block, truth = make_rig_block(np.random.default_rng(3), n_frames=4, n_points=30, noise_mm=0.001)
    return block.replace(rigs=Rigs()), truth


def _frames(tmp_path, block, rows=None):
    rows = rows or [(f"F{int(pid.split('_')[1])}", pid) for pid in block.photos.ids.tolist()]
    p = tmp_path / "frames.csv"
    p.write_text("frame,photo\n" + "".join(f"{f},{ph}\n" for f, ph in rows))
    return p


def test_rig_and_frame_tables_give_the_simulated_rig(tmp_path, bare):
    block, truth = bare
    t = tmp_path / "rig.csv"
    t.write_text("# a stereo bar\n" + HEADER + "rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,estimated,,,,,,,,,,,,\n")
    b = attach_rigs(block, t, frames=_frames(tmp_path, block))
    assert b.rigs.sensors.line.tolist() == [3, 4] and b.rigs.path == str(t)
    rr = rig_result(adjust(b))
    z = (rr.sensors[1].value - truth["sensor"][1]) / rr.sensors[1].sigma
    assert np.all(np.abs(z) < 4)
    # frames from the photo names instead of a table: the same adjustment
    b2 = attach_rigs(block, t, frames_from_name=r"_(\d+)$")
    np.testing.assert_allclose(rig_result(adjust(b2)).sensors[1].value, rr.sensors[1].value, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("rows, line, field, message", [
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S3,no,estimated,,,,,,,,,,,,\n", 3, "camera", "unknown camera 'S3'"),
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,sometimes,,,,,,,,,,,,\n", 3, "status", "unknown status"),
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,fixed,0.3,,,,,,,,,,,\n", 3, "Y_m", "fixed sensor needs all six"),
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,weighted,0.3,0,0,0,0,0,0.01,0.01,0.01,0.1,0.1,\n", 3,
     "skappa_deg", "positive σ"),
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,estimated,0.3x,,,,,,,,,,,\n", 3, "X_m", "expected a number"),
    ("rig,S1,no,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,estimated,,,,,,,,,,,,\n", 2, "reference", "0 reference sensors"),
    ("rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nother,S1,no,estimated,,,,,,,,,,,,\n", 3, "camera", "belongs to one rig"),
])
def test_rig_table_errors_name_file_line_and_field(tmp_path, bare, rows, line, field, message):
    block, _ = bare
    t = tmp_path / "rig.csv"
    t.write_text(HEADER + rows)
    with pytest.raises(InputError, match=message) as e:
        attach_rigs(block, t, frames=_frames(tmp_path, block))
    assert (e.value.path, e.value.line, e.value.field) == (str(t), line, field)


def test_length_columns_must_be_in_the_object_unit(tmp_path, bare):
    block, _ = bare
    t = tmp_path / "rig.csv"
    t.write_text(HEADER.replace("X_m", "X_mm") + "rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\n")
    with pytest.raises(InputError, match="object unit") as e:
        read_rig_table(t, block)
    assert e.value.line == 1 and e.value.field == "X_mm"


def test_frame_table_errors(tmp_path, bare):
    block, _ = bare
    t = tmp_path / "rig.csv"
    t.write_text(HEADER + "rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,estimated,,,,,,,,,,,,\n")
    cases = [([("A", "S1_01"), ("A", "S2_99")], 3, "photo", "unknown photo 'S2_99'"),
             ([("A", "S1_01"), ("A", "S2_01"), ("B", "S2_01")], 4, "photo", "in frame 'A' already"),
             ([("A", "S1_01"), ("B", "S2_01")], 3, "frame", "no photo of rig 'rig'.s reference sensor"),
             ([("A", "S1_01"), ("A", "S1_02")], 2, "frame", "two photos of camera 'S1'")]
    for rows, line, field, message in cases:
        f = _frames(tmp_path, block, rows)
        with pytest.raises(InputError, match=message) as e:
            attach_rigs(block, t, frames=f)
        assert (e.value.path, e.value.line, e.value.field) == (str(f), line, field), message


def test_written_rig_table_reads_back_as_a_calibration(tmp_path, bare):
    """bundle_rig.csv's columns are a rig table: read back, its values and σ are the calibration the
    next adjustment's stability test compares with (same data: stable)."""
    from baarda.pipeline.api import BundleConfig
    from baarda.pipeline.api import adjust as adjust_block
    from baarda.plugins.bundle.rigreport import rig_parts

    block, _ = bare
    t = tmp_path / "rig.csv"
    t.write_text(HEADER + "rig,S1,yes,fixed,0,0,0,0,0,0,,,,,,\nrig,S2,no,estimated,,,,,,,,,,,,\n")
    b = attach_rigs(block, t, frames=_frames(tmp_path, block))
    rep = adjust_block(b, BundleConfig())
    parts = rig_parts(rep)
    cols = parts["tables"]["rig"].columns
    out = tmp_path / "bundle_rig.csv"
    names = list(cols)
    out.write_text(",".join(names) + "\n" + "".join(
        ",".join("" if isinstance(v, float) and not np.isfinite(v) else repr(v) if isinstance(v, float) else str(v)
                 for v in (cols[n][i] for n in names)) + "\n" for i in range(len(cols["rig"]))))
    b2 = attach_rigs(block, out, frames=_frames(tmp_path, block))
    s = b2.rigs.sensors
    np.testing.assert_allclose(s.centre[1], rep.result.state.sensor[1, :3], rtol=1e-12)
    assert np.isfinite(s.prior_sigma[1]).all() and np.isinf(s.sigma[1]).all()
    rr = rig_result(adjust(b2))
    assert rr.sensors[1].stability["stable"] and rr.sensors[1].stability["T"] < 1e-6
    # the report says it, with the smallest detectable change of each parameter alone: σ0 √(λ0 / (Q_d⁻¹)_ii),
    # at most √λ0 times the marginal σ of the difference (two independent estimates of equal σ: √2 σ)
    lines = rig_parts(adjust_block(b2, BundleConfig()))["lines"]
    assert any("against the rig's calibration" in ln and "smallest change" in ln for ln in lines)
    st = rr.sensors[1].stability
    mdc = np.array(st["mdc"])
    assert np.all(mdc > 0) and np.all(mdc <= np.sqrt(st["lambda0"] * 2) * rr.sensors[1].sigma * (1 + 1e-6))
