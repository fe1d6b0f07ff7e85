"""``baarda validate`` checks a project's rig table and frame table (file, line, field) before any
detection or adjustment: the stereo chessboard with broken tables."""

from pathlib import Path

import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.project import load_project, validate_inputs

ROOT = Path(__file__).resolve().parents[2]


def _project(tmp_path, shared_data, rig_rows, frames=None):
    text = (ROOT / "fixtures" / "calibration" / "chessboard.toml").read_text()
    text = text.replace("../../../shared/data/opencv-chessboard", str(shared_data / "opencv-chessboard"))
    (tmp_path / "rig.csv").write_text("rig,camera,reference,status,X_mm\n" + rig_rows)
    text = text.replace('rig.table = "stereo-rig.csv"', 'rig.table = "rig.csv"')
    if frames is not None:
        (tmp_path / "frames.csv").write_text("frame,photo\n" + frames)
        text = text.replace("rig.frames_from_name = '(\\d+)$'", 'rig.frames = "frames.csv"')
    p = tmp_path / "p.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("rows, frames, file, line, field, message", [
    ("stereo,left,yes,fixed,0\nstereo,rigth,no,estimated,\n", None, "rig.csv", 3, "camera", "unknown camera 'rigth'"),
    ("stereo,left,yes,fixed,0\nstereo,right,no,estimated,\n", "1,left01\n1,right01\n2,left2\n", "frames.csv", 4,
     "photo", "unknown photo 'left2'"),
    ("stereo,left,yes,fixed,0\nstereo,right,no,estimated,\n", "1,left01\n1,right01\n2,left02\n2,right01\n",
     "frames.csv", 5, "photo", "in frame '1' already"),
    ("stereo,left,yes,fixed,0\nstereo,right,no,estimated,\n", "1,left01\n1,right01\n3,right03\n", "frames.csv", 4,
     "frame", "no photo of rig 'stereo'.s reference sensor"),
])
def test_validate_names_the_rig_tables_mistake(tmp_path, shared_data, rows, frames, file, line, field, message):
    project = load_project(_project(tmp_path, shared_data, rows, frames))
    with pytest.raises(InputError, match=message) as e:
        validate_inputs(project)
    assert (Path(e.value.path).name, e.value.line, e.value.field) == (file, line, field)


def test_the_bundled_rig_validates(shared_data, tmp_path):
    project = load_project(_project(tmp_path, shared_data, "stereo,left,yes,fixed,0\nstereo,right,no,estimated,\n"))
    validate_inputs(project)
