"""Independent models: external reliability against a dense numpy reference, the points'
ellipsoids against their σ, and RRR through the linearisation in blunder-rejection."""

import numpy as np
import pytest

from baarda.pipeline.testing import run_stage
from baarda.plugins.independent_models.stage import IndependentModels

from baarda.pipeline.synthetic.normalcase import make_block


@pytest.fixture(scope="module")
def im_run(tmp_path_factory):
    block, _ = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(9))
    return block, run_stage(IndependentModels, {"block": block}, {}, tmp_path=tmp_path_factory.mktemp("im"))


def test_external_reliability_against_dense_reference(im_run):
    block, res = im_run
    blk = res.artefacts["independent-models"].block
    model = blk.linear_model()
    A = model.A.toarray()
    P = model.P
    act = np.asarray(blk.snapshot.active, bool)
    Aa, Pa = A[act], P[np.ix_(act, act)]
    Q = np.linalg.inv(Aa.T @ Pa @ Aa)
    PQP = Pa - Pa @ Aa @ Q @ Aa.T @ Pa
    mdb = 4.132147965064808 * model.sigma0 / np.sqrt(np.diag(PQP))
    dx = (Q @ Aa.T @ Pa * mdb[None, :]).T                       # (rows, u)
    sig = model.sigma0 * np.sqrt(np.diag(Q))
    pt = np.array([n.startswith("point ") for n in model.names])
    ratio = np.abs(dx[:, pt]) / sig[pt]
    t = res.tables["external"].columns
    got = np.asarray(t["ext_point_in_sigma"], float)[act]
    assert np.allclose(got, ratio.max(axis=1), rtol=1e-6)
    i = int(np.argmax(ratio.max(axis=1)))
    big = res.summary["external_reliability"]["largest_on_point"]
    assert big["in_sigma"] == pytest.approx(ratio.max(), rel=1e-6)
    assert big["parameter"] == np.array(model.names)[pt][np.argmax(ratio[i])]
    assert "### External reliability" in res.report
    # one unit per column: model rows' MDB in model units, control rows' in the object unit (m here)
    from baarda.pipeline.units import unit_mismatches
    assert not unit_mismatches(res.tables["external"])
    control = np.char.startswith(np.asarray(t["row"]).astype(str), "control")
    mu, mo = np.asarray(t["mdb_mu"], float), np.asarray(t["mdb_m"], float)
    assert np.isnan(mu[control]).all() and np.isnan(mo[~control]).all()
    assert np.allclose(np.where(control, mo, mu)[act], mdb, rtol=1e-6)
    # a model parameter's effect in the column of its unit: ω φ κ in deg, tx ty tz in m, the scale × 1
    kind = np.array([str(n).rsplit(" ", 1)[-1] for n in t["ext_model"]])
    for col, names in (("ext_model_effect_deg", ("omega", "phi", "kappa")), ("ext_model_effect_m", ("tx", "ty", "tz")),
                       ("ext_model_effect_scale", ("scale",))):
        v = np.asarray(t[col], float)
        assert (np.isfinite(v) == (np.isin(kind, names) & act)).all(), col


def test_point_ellipsoids_match_the_sigmas(im_run):
    """Σ semi-axes² = σX² + σY² + σZ² (trace); plan a² + b² = σX² + σY²; height = σZ (1-σ)."""
    _, res = im_run
    p = res.tables["points"].columns
    s2 = np.asarray(p["sX_m"]) ** 2 + np.asarray(p["sY_m"]) ** 2
    e2 = sum(np.asarray(p[f"ellipsoid_a{j}_m"]) ** 2 for j in (1, 2, 3))
    assert np.allclose(e2, s2 + np.asarray(p["sZ_m"]) ** 2, rtol=1e-9)
    assert np.allclose(np.asarray(p["plan_a_m"]) ** 2 + np.asarray(p["plan_b_m"]) ** 2, s2, rtol=1e-9)
    assert np.allclose(p["height_half_m"], p["sZ_m"], rtol=1e-9)


@pytest.mark.slow  # 25-55 s: 500 RRR simulations of the block
def test_rrr_runs_on_the_block_adjustment(im_run, tmp_path):
    from baarda.plugins.blunder_rejection.stage import BlunderRejection

    block, res = im_run
    art = res.artefacts["adjustment"]
    assert art.supports_rrr
    out = run_stage(BlunderRejection, {"adjustment": art, "block": block},
                    {"method": "rrr", "n_sim": 500, "rho": 2}, tmp_path=tmp_path)
    r = out.artefacts["blunders"].methods["rrr"]
    assert r.skipped is None and r.summary["n_sim"] == 500
