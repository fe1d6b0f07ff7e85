"""AICON as the vendor ran it (fixtures/aicon/vendor.toml, docs/aicon-format.md): with AICON's own
set-up the bundle reproduces AICON's published camera, its standard deviations, correlations, S0 and
redundancy; each departure from that set-up moves the camera by several of AICON's σ, which is what
the earlier "AICON minimised something else" was.  The file's sx, sy get their factor from the
variance components instead of a hand-copied number."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust, estimate_components
from baarda.plugins.aicon.reader import aicon_block, read_aicon

#: AICON's protocol of this run (applied-geodesy/bundle-adjustment f3c0c88, JAICOV/example/example.htm,
#: "Innere Orientierungen"): value and σ; c with baarda's sign (positive).
AICON = {"c": (28.78507, 2.513178e-4), "xp": (1.734892e-2, 3.441658e-4), "yp": (5.668731e-2, 3.262600e-4),
         "A1": (-1.096069e-4, 2.978787e-8), "A2": (1.495660e-7, 7.655524e-11),
         "B1": (5.798428e-6, 1.190972e-7), "B2": (-8.644540e-6, 1.043919e-7)}
AICON_S0_MM = 0.000405          # "S0: 0.000405 (S0 apriori: 0.0005)"
AICON_REDUNDANCY = 18804        # "Gesamtredundanz"
AICON_UNKNOWNS = 1147           # "u"


@pytest.fixture(scope="module")
def export(shared_data):
    return read_aicon(shared_data / "aicon-closerange" / "example")


def _offsets(res) -> dict:
    """Camera minus AICON's, in AICON's σ."""
    t = {r["parameter"]: r for r in res.camera_table(0)}
    return {k: (t[k]["value"] - v) / s for k, (v, s) in AICON.items()}


def test_vendor_setup_reproduces_aicon(export):
    blk = aicon_block(export, sigma_image_um=0.5)            # the reader's default: A3, C1, C2 fixed
    res = adjust(blk, BundleSettings(datum="free"))
    assert res.dof == AICON_REDUNDANCY and res.n_unknowns == AICON_UNKNOWNS
    assert res.sigma0_hat * 0.5e-3 == pytest.approx(AICON_S0_MM, abs=1e-6)       # 0.4056 µm
    off = _offsets(res)
    assert max(abs(v) for v in off.values()) < 0.25, off                          # measured 0.19 (A2)
    t = {r["parameter"]: r for r in res.camera_table(0)}
    for k, (_, s) in AICON.items():
        assert t[k]["sigma"] == pytest.approx(s, rel=0.003), k                    # measured ≤ 0.09 %
    for k in ("A3", "C1", "C2"):
        assert t[k]["status"] == "fixed"
    R = res.correlation_camera(0)
    names = res.cam_param_names[0]
    assert R[names.index("xp"), names.index("B1")] == pytest.approx(0.939, abs=0.001)
    assert R[names.index("A1"), names.index("A2")] == pytest.approx(-0.909, abs=0.001)
    # AICON's outlier test (critical value 4.706 in its protocol) found nothing: no |w| near it here
    from baarda.pipeline import stats

    assert np.abs(stats.w_test(res.snapshot)).max() < 4.706


def test_each_departure_moves_the_camera(export):
    """Freeing C1, C2 or weighting by the .phc's sx, sy each moves the camera by several of AICON's
    σ — together they are the differences the earlier fixture showed."""
    S = BundleSettings(datum="free")
    every = ("A1", "A2", "B1", "B2", "C1", "C2")
    runs = {"C free": adjust(aicon_block(export, sigma_image_um=0.5, free_ap=every), S),
            "file weights": adjust(aicon_block(export), S),
            "both": adjust(aicon_block(export, free_ap=every), S)}
    worst = {k: max(abs(v) for v in _offsets(r).values()) for k, r in runs.items()}
    assert worst["C free"] > 3 and worst["file weights"] > 3 and worst["both"] > 5, worst  # 5.0, 5.9, 8.0


def test_variance_component_of_the_file_sigmas(export):
    """The factor on the .phc's sx, sy is estimated (it was copied by hand as 3.707): one image group,
    the scale bar not estimable (r ≈ 0), the factor ±0.5 %; applied, σ̂0 = 1."""
    every = ("A1", "A2", "B1", "B2", "C1", "C2")
    vc = estimate_components(aicon_block(export, free_ap=every), BundleSettings(datum="free"))
    g = {x.name: x for x in vc.groups}
    img = g["image camera 1"]
    assert vc.converged and img.estimable and not g["scale bars"].estimable
    assert img.factor == pytest.approx(vc.first.sigma0_hat, rel=1e-3)
    assert 3.6 < img.factor < 3.8 and img.sigma_factor == pytest.approx(img.factor / np.sqrt(2 * 18802), rel=1e-3)
    assert img.rejected                                  # the file's σ are not the image σ
    assert vc.result.sigma0_hat == pytest.approx(1.0, abs=1e-3)


def test_per_photo_components_on_the_vendor_setup(export):
    """One factor per photo on AICON's set-up: the photos' image precision differs far more than the
    estimates' own spread (the spread of f about its median is ≈ 4 σ(f)); photo 48 (one of the three
    photos with the largest RMS residual) has the largest factor; re-weighted, the camera stays within 2 of AICON's σ."""
    vc = estimate_components(aicon_block(export, sigma_image_um=0.5), BundleSettings(datum="free"),
                             image_groups="photo")
    assert vc.converged
    g = [x for x in vc.groups if x.kind == "image"]
    assert len(g) == 115
    f = np.array([x.factor for x in g])
    sf = np.array([x.sigma_factor for x in g])
    z = (f - np.median(f)) / sf
    assert z.std() > 2.5                                       # measured 4.0: real differences
    assert g[int(np.argmax(f))].name == "image photo 48" and f.max() > 1.8         # 2.09
    assert f.min() < 0.55 and 0.75 < np.median(f) < 0.9                              # 0.48, 0.83
    off = _offsets(vc.result)
    assert max(abs(v) for v in off.values()) < 2.5, off                               # 1.8 (A1)
