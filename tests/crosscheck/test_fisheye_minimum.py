"""pycolmap's bundle adjustment and baarda's reach the same minimum on a fisheye block (every COLMAP
fisheye-type model): same start, same free parameters, weights equal (pycolmap's pixel = σ)."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.colmap.writer import reconstruction_from_block
from baarda.pipeline.synthetic.fisheye import make_fisheye_block

pycolmap = pytest.importorskip("pycolmap")

SIGMA = 0.0015          # mm: one pycolmap pixel


def _start(block, rng):
    cams, ph, pts = block.cameras, block.photos, block.points
    XYZ = pts.XYZ.copy()
    tie = pts.role == "tie"
    XYZ[tie] += 0.01 * rng.standard_normal((tie.sum(), 3))
    return block.replace(cameras=cams.replace(c=cams.c * 1.005, ap=cams.ap * 0.9),
                         points=pts.replace(XYZ=XYZ),
                         photos=ph.replace(X0=ph.X0 + 0.005 * rng.standard_normal(ph.X0.shape),
                                           opk=ph.opk + 0.003 * rng.standard_normal(ph.opk.shape)))


def _pycolmap_cost(start):
    """pycolmap's final ½ Σ ‖r‖² (pixels of σ mm) from baarda's start values."""
    from baarda.plugins.crosscheck.pycolmap_ba import SolverSettings, run_adjuster

    cams = start.cameras
    fmt = np.asarray(cams.format_mm, float)
    blk = start.replace(cameras=cams.replace(pixel_mm=np.full(len(cams), SIGMA),
                                             resolution=np.ceil(fmt / SIGMA).astype(int)), meta={})
    rec, _ = reconstruction_from_block(blk, camera_model="auto")
    config = pycolmap.BundleAdjustmentConfig()
    for iid in rec.images:
        config.add_image(iid)
    # the control points ("full", fixed in baarda) are constant (found by their coordinates)
    fixed = start.points.XYZ[(start.points.sigma == 0).all(axis=1)]
    n_const = 0
    for pid, p3 in rec.points3D.items():
        if (np.abs(fixed - p3.xyz).max(axis=1) == 0).any():
            config.add_constant_point(pid)
            n_const += 1
    assert n_const >= 3
    out, _ = run_adjuster(rec, config, {"focal": True, "principal_point": True, "extra": True},
                          SolverSettings(num_threads=1))
    return out


@pytest.mark.parametrize("model", ["opencv-fisheye", "eucm", "division",
                                   pytest.param("simple-radial-fisheye", marks=pytest.mark.slow),
                                   pytest.param("fov", marks=pytest.mark.slow),
                                   pytest.param("thin-prism-fisheye", marks=pytest.mark.slow),
                                   pytest.param("rad-tan-thin-prism-fisheye", marks=pytest.mark.slow)])
def test_same_minimum_as_pycolmap(model):
    rng = np.random.default_rng(3)
    # COLMAP's fisheye models compute θ = atan(ρ/z) and reject z ≤ 0: rays within 85° only
    block, _ = make_fisheye_block(model, noise_mm=SIGMA, sigma_mm=SIGMA, rng=rng, max_angle_deg=85.0)
    start = _start(block, rng)
    res = adjust(start, BundleSettings(covariance=False, tol_rel=1e-15))
    out = _pycolmap_cost(start)
    assert out["usable"], out["message"]
    assert out["initial_cost"] > 10 * out["final_cost"]
    baarda = 0.5 * res.vtpv                               # ½ vᵀPv with P = σ⁻² I
    rel = abs(out["final_cost"] - baarda) / baarda
    print(f"{model}: ½vᵀPv baarda {baarda:.10g}, pycolmap {out['final_cost']:.10g}, relative difference {rel:.1e}")
    assert rel <= 1e-6


def test_crosscheck_stage_compares_a_fisheye_camera(tmp_path):
    """The pycolmap-crosscheck stage maps a ray-model camera onto its COLMAP model (refine switches,
    intrinsics, covariance) and finds both solutions equal."""
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.crosscheck.stage import PycolmapCrossCheck

    rng = np.random.default_rng(4)
    block, _ = make_fisheye_block("opencv-fisheye", noise_mm=SIGMA, sigma_mm=SIGMA, rng=rng, max_angle_deg=85.0)
    start = _start(block, rng)
    res = adjust(start, BundleSettings())
    out = run_stage(PycolmapCrossCheck, {"block": start, "bundle": res}, {"num_threads": 1}, tmp_path=tmp_path)
    s, q = out.summary, out.summary["quantities"]
    assert s["equivalent"] and s["passed"], s.get("notes")
    assert q["cost"]["pycolmap"] == pytest.approx(res.vtpv / 2, rel=1e-9)
    assert q["intrinsics"]["n"] == 8 and q["intrinsics"]["max"] < 1e-4          # c, xp, yp, B1, k1 … k4 in σ
    assert q["points"]["max"] < 1e-6 * s["object_size"]
    assert q["covariance_intrinsics"]["n"] == 8 and q["covariance_intrinsics"]["max"] < 1e-3
