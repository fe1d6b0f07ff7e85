"""External reliability and error ellipses of the independent-model block adjustment.

The block adjustment is small enough to hold its design densely: its linearisation at the solution
(:meth:`.block.ModelBlockAdjustment.linear_model`) goes through the statistics library's
:func:`~baarda.pipeline.stats.external_reliability` (``∇x_i = Q Aᵀ P e_i ∇_i`` for every row); per
row the largest effect on any point coordinate and on any model's similarity parameter, measured in
σ of that parameter (a-priori ``σ0 √Q``), in object units (angles in degrees, scale × 1).  The
points' ellipsoids / plan ellipses / height intervals come from :mod:`baarda.pipeline.stats.ellipses`
on the a-posteriori covariances.  No I/O here: the stage writes the tables.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import TableData
from baarda.pipeline.stats import external_reliability, mdb
from baarda.pipeline.stats.critical import delta0 as _delta0
from baarda.pipeline.stats.ellipses import ellipse_columns

DENSE_LIMIT = 2.0e7


def block_external(blk, alpha0: float, beta0: float) -> dict | None:
    """Per snapshot row of the block adjustment ``blk``: the largest effect of its MDB on a point
    coordinate and on a model parameter (name, value, in σ), Baarda's δ̄0; ``None`` when the design
    is too large to hold densely."""
    model = blk.linear_model()
    if float(model.n) * model.u > DENSE_LIMIT:
        return None
    act = np.asarray(blk.snapshot.active, bool)
    adj = model.adjust(act)
    d0 = _delta0(alpha0, beta0)
    m = mdb(adj.snapshot, d0)
    er = external_reliability(model, adj, m)
    sig = adj.snapshot.sigma0 * np.sqrt(np.clip(np.diag(adj.Qxx), 0, None))
    names = np.array(model.names)
    is_pt = np.char.startswith(names.astype(str), "point ")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sig > 0, np.abs(er.dx) / np.where(sig > 0, sig, 1.0), 0.0)
    out = {"labels": np.asarray(adj.snapshot.labels), "mdb": m, "bar_delta0": er.bar_delta0, "delta0": d0,
           "active": act}
    for key, mask in (("point", is_pt), ("model", ~is_pt)):
        cols = np.flatnonzero(mask)
        if cols.size == 0:
            out[key] = (np.full(model.n, ""), np.full(model.n, np.nan), np.full(model.n, np.nan))
            continue
        R = np.nan_to_num(ratio[:, cols], nan=-1.0)
        j = cols[np.argmax(R, axis=1)]
        val = er.dx[np.arange(model.n), j]
        ang = np.isin(np.array([str(x).rsplit(" ", 1)[-1] for x in names[j]]), ["omega", "phi", "kappa"])
        val = np.where(ang, np.degrees(val), val)
        s = ratio[np.arange(model.n), j]
        ok = act & np.isfinite(s)
        out[key] = (np.where(ok, names[j], ""), np.where(ok, val, np.nan), np.where(ok, s, np.nan))
    return out


def table(ext: dict, unit: str) -> TableData:
    """Per row of the block adjustment: its MDB and the largest effect of that MDB on a point coordinate
    and on a model parameter.  Every column has one unit (its name's suffix, docs/conventions.md): the MDB
    of a model-coordinate row is in model units (``mdb_mu``), of a control row in the object unit
    ``unit``; a model parameter's effect in degrees (ω, φ, κ), the object unit (tx, ty, tz) or × 1
    (the scale), each in its own column (empty where the row's largest effect is on another kind)."""
    from baarda.pipeline.units import length_suffix

    o = length_suffix(unit)
    labels = np.asarray(ext["labels"]).astype(str)
    control = np.char.startswith(labels, "control")
    m = np.asarray(ext["mdb"], float)
    name, val = np.asarray(ext["model"][0]).astype(str), np.asarray(ext["model"][1], float)
    kind = np.array([x.rsplit(" ", 1)[-1] if x else "" for x in name])
    ang, trans, scale = np.isin(kind, ["omega", "phi", "kappa"]), np.isin(kind, ["tx", "ty", "tz"]), kind == "scale"
    nan = np.full(len(m), np.nan)
    cols = {"row": labels.tolist(), "mdb_mu": np.where(control, nan, m), f"mdb{o}": np.where(control, m, nan),
            "ext_point": ext["point"][0].tolist(), f"ext_point_effect{o}": ext["point"][1],
            "ext_point_in_sigma": ext["point"][2],
            "ext_model": name.tolist(), "ext_model_effect_deg": np.where(ang, val, nan),
            f"ext_model_effect{o}": np.where(trans, val, nan), "ext_model_effect_scale": np.where(scale, val, nan),
            "ext_model_in_sigma": ext["model"][2], "bar_delta0": ext["bar_delta0"]}
    unitless = {"ext_point_in_sigma": "", "ext_model_in_sigma": "", "ext_model_effect_scale": "", "bar_delta0": ""}
    return TableData(cols, "external reliability of the block adjustment: per row its MDB (model rows in model "
                           f"units, control rows in {unit}) and the largest effect of that MDB on any point "
                           f"coordinate ({unit}) and on any model parameter (degrees, {unit} or × 1 for the "
                           "scale, one column each); the effects also in σ of the parameter; δ̄0",
                     units=unitless)


def summary(ext: dict | None) -> dict | None:
    if ext is None:
        return None
    out = {"delta0": ext["delta0"]}
    for key in ("point", "model"):
        name, val, s = ext[key]
        if np.isfinite(s).any():
            i = int(np.nanargmax(s))
            out[f"largest_on_{key}"] = {"row": str(ext["labels"][i]), "parameter": str(name[i]),
                                        "effect": float(val[i]), "in_sigma": float(s[i]),
                                        "mdb": float(ext["mdb"][i])}
    bd = ext["bar_delta0"]
    out["bar_delta0_max"] = float(np.nanmax(bd)) if np.isfinite(bd).any() else None
    return out


def report_lines(ext: dict | None, unit: str) -> list[str]:
    s = summary(ext)
    if not s:
        return []
    L = ["", "### External reliability", "",
         f"Effect of each row's minimal detectable bias (δ0 = {s['delta0']:.2f}) on the unknowns "
         "(independent_models_external.csv); largest δ̄0 = "
         f"{s['bar_delta0_max']:.2f} σ.", ""]
    for key, what in (("point", "a point coordinate"), ("model", "a model parameter")):
        d = s.get(f"largest_on_{key}")
        if d:
            L.append(f"- largest on {what}: {d['row']} (MDB {d['mdb']:.4g}) moves {d['parameter']} by "
                     f"{d['effect']:+.4g} = {d['in_sigma']:.2f} σ")
    return L


def point_columns(cov_XYZ, factor: float, confidence: float | None = None, suffix: str = "") -> dict:
    """Ellipsoid / ellipse / height columns from the covariances scaled by ``factor`` (σ̂0²/σ0²),
    lengths named with the coordinates' unit ``suffix``."""
    return ellipse_columns(np.asarray(cov_XYZ) * factor, confidence, suffix)
