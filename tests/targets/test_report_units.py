"""The targets report names µm only at a real pixel pitch (the default 1 µm is nominal)."""

import dataclasses

from baarda.plugins.targets.report import pitch_note
from baarda.plugins.targets.stage import TargetOptions


def test_sigma_in_px_without_a_nominal_pitch():
    opts = TargetOptions(target="chessboard", squares=[10, 7], square_size=25.0)
    assert pitch_note(opts, 0.2) == ""
    real = dataclasses.replace(opts, pixel_mm=0.0039)
    assert pitch_note(real, 0.2) == " = 0.78 µm at pitch 0.0039 mm"
