"""The bundle stage's external reliability, error ellipses and covariances on demand (tables, report
lines, summary).  Numerics: :mod:`baarda.pipeline.adjustment.reliability`,
:mod:`baarda.pipeline.stats.ellipses`; this module only arranges their results."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.adjustment import EO_LABELS
from baarda.pipeline.api import TableData
from baarda.pipeline.stats.ellipses import ellipse_columns
from baarda.pipeline.units import object_unit_text

from .protocol import image_units

def external_view(rep) -> dict | None:
    """The report's own-point / own-photo effects (:class:`~baarda.pipeline.adjustment.OwnEffects`) as the
    tables and lines use them: the largest effect per coordinate, angles in degrees."""
    if rep.external is None:
        return None
    eff = rep.external
    jp, vp, sp, je, ve, se = eff.largest()
    ve = np.where(je >= 3, np.degrees(ve), ve)
    return {"effects": eff, "point": (jp, vp, sp), "eo": (je, ve, se), "delta0": rep.delta0,
            "r": np.asarray(rep.result.redundancy)}


def observation_columns(ext: dict | None, k: int, suffix: str = "") -> dict:
    """Columns of ``bundle_observations.csv``: per coordinate (x, y) of each image point the
    largest effect of its MDB on its own point (coordinate; ``ext_point_x<suffix>`` in object units
    whose column suffix is ``suffix``; in σ) and on its own photo's orientation (component; a
    projection centre's in ``ext_eo_x<suffix>``, an angle's in ``ext_eo_x_deg``, the other one
    empty; in σ), and Baarda's δ̄0."""
    out = {}
    for c, cn in enumerate("xy"):
        if ext is None:
            for name in ("ext_point_coord", f"ext_point_{{}}{suffix}", "ext_point_in_sigma", "ext_eo_param",
                         f"ext_eo_{{}}{suffix}", "ext_eo_{}_deg", "ext_eo_in_sigma", "bar_delta0"):
                key = name.format(cn) if "{}" in name else f"{name}_{cn}"
                out[key] = [""] * k if name.endswith(("coord", "param")) else np.full(k, np.nan)
            continue
        jp, vp, sp = (a[:, c] for a in ext["point"])
        je, ve, se = (a[:, c] for a in ext["eo"])
        # text columns as numpy string arrays (a list of k str objects is 8 bytes a row more)
        out[f"ext_point_coord_{cn}"] = np.array(["X", "Y", "Z", ""])[jp]                  # j = −1: ""
        out[f"ext_point_{cn}{suffix}"] = np.where(jp >= 0, vp, np.nan)
        out[f"ext_point_in_sigma_{cn}"] = np.where(jp >= 0, sp, np.nan)
        out[f"ext_eo_param_{cn}"] = np.array([*EO_LABELS, ""])[je]
        out[f"ext_eo_{cn}{suffix}"] = np.where((je >= 0) & (je < 3), ve, np.nan)
        out[f"ext_eo_{cn}_deg"] = np.where(je >= 3, ve, np.nan)
        out[f"ext_eo_in_sigma_{cn}"] = np.where(je >= 0, se, np.nan)
        out[f"bar_delta0_{cn}"] = ext["effects"].bar_delta0[:, c]
    return out


def _largest(ext, block, which: str) -> dict | None:
    j, v, s = ext[which]
    sv = np.where(j >= 0, np.nan_to_num(s, nan=-1.0), -1.0)
    if not (sv >= 0).any():
        return None
    k, c = np.unravel_index(int(np.argmax(sv)), sv.shape)
    obs = block.observations
    ph, pt = str(block.photos.ids[obs.photo[k]]), str(block.points.ids[obs.point[k]])
    unit, scale, _ = image_units(block)
    out = {"observation": f"photo {ph} point {pt} {'xy'[c]}", "mdb_mm": float(ext["effects"].bias[k, c]),
           "mdb": float(ext["effects"].bias[k, c]) * scale, "mdb_unit": unit,
           "r": float(ext["r"][k, c]), "in_sigma": float(s[k, c]), "effect": float(v[k, c])}
    if which == "point":
        out.update(point=pt, coordinate="XYZ"[j[k, c]])
    else:
        out.update(photo=ph, parameter=EO_LABELS[j[k, c]], unit="deg" if j[k, c] >= 3 else "object")
    return out


def summary(ext: dict | None, block) -> dict | None:
    """``results.json``: the largest effect on a point and on an orientation, and where."""
    if ext is None:
        return None
    bd = ext["effects"].bar_delta0
    return {"delta0": ext["delta0"], "largest_on_point": _largest(ext, block, "point"),
            "largest_on_orientation": _largest(ext, block, "eo"),
            "bar_delta0_max": float(np.nanmax(bd)) if np.isfinite(bd).any() else None,
            "bar_delta0_median": float(np.nanmedian(bd)) if np.isfinite(bd).any() else None}


def report_lines(ext: dict | None, block, most: int = 5) -> list[str]:
    if ext is None:
        return []
    s = summary(ext, block)
    unit = object_unit_text(block)          # "model units" for a model of arbitrary scale (COLMAP, BAL)
    L = ["", "### External reliability", "",
         f"Effect of each coordinate's minimal detectable bias (δ0 = {ext['delta0']:.2f}) on its own point "
         "and its own photo's orientation (in σ: a-priori σ of that parameter; per coordinate in "
         "bundle_observations.csv, ext_*). Baarda's δ̄0 bounds the effect on any function of the unknowns: "
         f"largest {s['bar_delta0_max']:.2f} σ, median {s['bar_delta0_median']:.2f} σ. Rows with small "
         "redundancy numbers (weakly controlled, e.g. points in two photos) have large MDBs and so the "
         "largest effects; rows with r ≤ 1e-10 are uncontrolled (no MDB, no effect).", ""]
    p, e = s["largest_on_point"], s["largest_on_orientation"]
    if p:
        L.append(f"- largest on a point: {p['observation']} (r = {p['r']:.3g}, MDB {p['mdb']:.4g} {p['mdb_unit']}) moves point "
                 f"{p['point']} {p['coordinate']} by {p['effect']:+.4g} {unit} = {p['in_sigma']:.2f} σ")
    if e:
        u = "°" if e["unit"] == "deg" else f" {unit}"
        L.append(f"- largest on an orientation: {e['observation']} (r = {e['r']:.3g}, MDB {e['mdb']:.4g} {e['mdb_unit']}) moves photo "
                 f"{e['photo']} {e['parameter']} by {e['effect']:+.4g}{u} = {e['in_sigma']:.2f} σ")
    j, v, sg = ext["point"]
    sv = np.where(j >= 0, np.nan_to_num(sg, nan=-1.0), -1.0).reshape(-1)
    order = np.argsort(-sv)[:most]
    order = order[sv[order] >= 0]
    if order.size:
        obs = block.observations
        L += ["", "| observation | point coordinate | effect | in σ |", "|---|---|---|---|"]
        for f in order:
            k, c = divmod(int(f), 2)
            L.append(f"| photo {block.photos.ids[obs.photo[k]]} point {block.points.ids[obs.point[k]]} {'xy'[c]} | "
                     f"{block.points.ids[obs.point[k]]} {'XYZ'[j[k, c]]} | {v[k, c]:+.4g} {unit} | {sg[k, c]:.2f} |")
    return L


def point_columns(res, confidence: float, suffix: str = "") -> dict:
    """Error ellipsoid, plan ellipse and height interval of every point from its covariance (lengths
    named with the coordinates' unit ``suffix``)."""
    return ellipse_columns(res.cov_points, confidence or None, suffix)


def covariance_parts(cov):
    """``(TableData, summary dict, report lines)`` of a :class:`~baarda.pipeline.adjustment.workflow.ParameterCovariance`."""
    names, C, d, R = list(cov.names), cov.matrix, cov.sigma, cov.correlation
    cols = {"parameter": names}
    for j, n in enumerate(names):
        cols[n] = C[:, j]
    table = TableData(cols, "joint a-posteriori covariance of the requested parameters (object units, rad, mm)")
    pairs = [(abs(R[a, b]), names[a], names[b], R[a, b]) for a in range(len(names)) for b in range(a + 1, len(names))
             if d[a] > 0 and d[b] > 0]
    pairs.sort(key=lambda t: -t[0])
    summ = {"parameters": names, "sigma": d.tolist(),
            "largest_correlations": [{"p1": p1, "p2": p2, "rho": float(r)} for _, p1, p2, r in pairs[:10]]}
    L = ["", "### Covariance of the requested parameters", "",
         f"{len(names)} parameters (bundle_covariance.csv: the joint covariance matrix, σ̂0² Q). "
         "Largest correlations:", ""]
    L += [f"- {p1} / {p2}: ρ = {r:+.3f}" for _, p1, p2, r in pairs[:10]] or ["- none (every parameter fixed)"]
    return table, summ, L


# -- the stage's hooks: from the BundleReport ------------------------------------------------------
def summary_entries(rep) -> dict:
    out = {}
    ext = external_view(rep)
    if ext is not None:
        out["external_reliability"] = summary(ext, rep.result.block_in)
    if rep.covariance is not None:
        out["covariance_of"] = covariance_parts(rep.covariance)[1]
    return out


def report_entries(rep, block) -> list[str]:
    L = report_lines(external_view(rep), block)
    if rep.covariance is not None:
        L += covariance_parts(rep.covariance)[2]
    return L


def tables(rep) -> dict:
    return {"covariance": covariance_parts(rep.covariance)[0]} if rep.covariance is not None else {}


def linearisation(res):
    """The ``linearise`` callable of the bundle's :class:`AdjustmentArtefact` (RRR in
    ``blunder-rejection``): the dense linearised model, built only when asked for."""
    from functools import partial

    from baarda.pipeline.adjustment import linearised_model

    return partial(linearised_model, res)
