"""The bundle's rig section: each sensor's pose in its rig with σ, the baseline, correlations,
redundancy numbers of weighted sensor poses, the test against the rig's calibration and the
differences to a reference solution (``docs/rigs.md``): results.json's ``rig``, report lines and
the tables ``bundle_rig.csv`` (which reads back as a rig table) and ``bundle_rig_correlations.csv``."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import TableData, rig_result
from baarda.pipeline.adjustment import SENSOR_NAMES
from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.units import fmt_q, length_suffix, object_unit_text

ANGLES = SENSOR_NAMES[3:]


def _reference_entry(s, name: str, names, scale) -> dict:
    """A sensor against a reference solution: the pose's differences in σ, OpenCV's T of both with
    baarda's σ and the differences in σ, and the angle between the two rotations."""
    Tb, Tr = t_cv(s.value), t_cv(s.reference)
    sT = np.sqrt(np.clip(np.diag(t_cv_covariance(s.value, s.cov)), 0, None))
    Rd = rotation_from_opk(*s.value[3:]) @ rotation_from_opk(*s.reference[3:]).T
    ang = float(np.degrees(np.arccos(np.clip((np.trace(Rd) - 1) / 2, -1, 1))))
    with np.errstate(invalid="ignore", divide="ignore"):
        dT = np.where(sT > 0, (Tb - Tr) / sT, np.nan)
    return {"name": name, "value": dict(zip(names, (s.reference * scale).tolist())),
            "difference_in_sigma": dict(zip(names, s.d_reference_sigma.tolist())),
            "T_baarda": Tb.tolist(), "sigma_T": sT.tolist(), "T_reference": Tr.tolist(),
            "T_difference_in_sigma": dT.tolist(), "R_difference_deg": ang}


def _test_text(t) -> str:
    if t is None:
        return ""
    return (f"T = {t['T']:.3g} against {t['critical']:.3g} ({t['distribution']}, α = {t['alpha']:g}, p = {t['p']:.3g}): "
            + ("stable" if t["stable"] else "**changed**"))


def t_cv(pose: np.ndarray) -> np.ndarray:
    """OpenCV's stereo translation ``T`` (``x_s = R x_ref + T``, y-down/z-forward frames) of a
    sensor pose in the rig ``[c (3), ω, φ, κ]``: ``T = −F R_s c`` (F = diag(1, −1, −1))."""
    F = np.diag([1.0, -1.0, -1.0])
    return -F @ rotation_from_opk(*pose[3:]) @ pose[:3]


def t_cv_covariance(pose: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of :func:`t_cv` from the pose's (6, 6) (central differences)."""
    J = np.zeros((3, 6))
    for t in range(6):
        h = 1e-6 * max(1.0, abs(pose[t])) if t < 3 else 1e-7
        e = np.zeros(6)
        e[t] = h
        J[:, t] = (t_cv(pose + e) - t_cv(pose - e)) / (2 * h)
    return J @ cov @ J.T


def rig_parts(rep, alpha: float = 0.05) -> dict | None:
    """``{"summary", "lines", "tables"}`` of the rig part of a bundle report, or None without rigs."""
    res = rep.result
    rr = rig_result(res, alpha=alpha)
    if rr is None:
        return None
    block = res.block_in
    ou = object_unit_text(block)
    o = length_suffix(ou)
    names = [f"{n}{o}" for n in "XYZ"] + [f"{n}_deg" for n in ANGLES]
    scale = np.r_[1.0, 1.0, 1.0, np.degrees(np.ones(3))]
    cols = {k: [] for k in ("rig", "camera", "reference", "status")}
    for n in names:
        cols[n] = []
    for n in names:
        cols["s" + n] = []
    extra = {f"baseline{o}": [], f"sbaseline{o}": [], "r_min": [], "w_max": [], "T_stability": [],
             "T_critical": [], "stable": []}
    ref_cols = {f"d_{n.rsplit('_', 1)[0]}_in_sigma": [] for n in names}
    cols.update(extra)
    cols.update(ref_cols)
    sensors_json = []
    for s in rr.sensors:
        cols["rig"].append(s.rig)
        cols["camera"].append(s.camera)
        cols["reference"].append("yes" if s.reference_sensor else "no")
        st = "fixed" if s.reference_sensor else ("fixed" if all(t == "fixed" for t in s.status) else
                                                  ("weighted" if "weighted" in s.status else "estimated"))
        cols["status"].append(st)
        for t, n in enumerate(names):
            cols[n].append(float(s.value[t] * scale[t]))
            cols["s" + n].append(float(s.sigma[t] * scale[t]))
        cols[f"baseline{o}"].append(s.baseline)
        cols[f"sbaseline{o}"].append(s.sigma_baseline)
        cols["r_min"].append(float(np.nanmin(s.redundancy)) if np.isfinite(s.redundancy).any() else np.nan)
        cols["w_max"].append(float(np.nanmax(np.abs(s.w))) if np.isfinite(s.w).any() else np.nan)
        t = s.stability
        cols["T_stability"].append(t["T"] if t else np.nan)
        cols["T_critical"].append(t["critical"] if t else np.nan)
        cols["stable"].append("" if t is None else ("yes" if t["stable"] else "no"))
        for k, n in zip(ref_cols, names):
            cols[k].append(float(s.d_reference_sigma[names.index(n)]))
        sensors_json.append({
            "rig": s.rig, "camera": s.camera, "reference": s.reference_sensor, "status": list(s.status),
            "unit": ou, "value": dict(zip(names, (s.value * scale).tolist())),
            "sigma": dict(zip(names, (s.sigma * scale).tolist())),
            "baseline": s.baseline, "sigma_baseline": s.sigma_baseline,
            "correlation": np.round(s.correlation, 6).tolist(),
            "redundancy": [None if not np.isfinite(v) else float(v) for v in s.redundancy],
            "w": [None if not np.isfinite(v) else float(v) for v in s.w],
            "stability": s.stability,
            **({"reference": _reference_entry(s, rr.reference_name, names, scale)}
               if np.isfinite(s.reference).all() and not s.reference_sensor else {}),
        })
    summary = {"frames": rr.n_frames, "unit": ou, "sensors": sensors_json, "stability": rr.stability,
               "reference_name": rr.reference_name}
    L = ["", "### Camera rigs", "",
         f"{rr.n_frames} frames (one rig pose each); each sensor's pose in its rig: the projection centre in the rig "
         f"frame (the reference camera's image frame: x right, y up, z back; {ou}) and ω, φ, κ of R_sensor_from_rig "
         "(°), with a-posteriori σ; the baseline is the distance from the reference camera's projection centre.", "",
         "| rig | camera | status | X | Y | Z | ω | φ | κ | baseline |", "|---|---|---|---|---|---|---|---|---|---|"]
    for i, s in enumerate(rr.sensors):
        if s.reference_sensor:
            L.append(f"| {s.rig} | {s.camera} | reference | 0 | 0 | 0 | 0 | 0 | 0 | 0 |")
            continue
        vals = [f"{fmt_q(s.value[t], ou)} ± {fmt_q(s.sigma[t], ou, 2)}" for t in range(3)]
        vals += [f"{np.degrees(s.value[t]):.5f}° ± {np.degrees(s.sigma[t]):.2g}°" for t in range(3, 6)]
        L.append(f"| {s.rig} | {s.camera} | {cols['status'][i]} | " + " | ".join(vals)
                 + f" | {fmt_q(s.baseline, ou)} ± {fmt_q(s.sigma_baseline, ou, 2)} |")
    for s in rr.sensors:
        if s.reference_sensor:
            continue
        if np.isfinite(s.redundancy).any():
            L.append(f"- {s.camera}: weighted pose, redundancy numbers {', '.join(f'{v:.2f}' for v in s.redundancy)}, "
                     f"largest |w| {np.nanmax(np.abs(s.w)):.2f}")
        if s.stability:
            mdc = s.stability.get("mdc") or []
            pars = s.stability["parameters"]
            det = ", ".join(f"{n} {fmt_q(v, ou) if n in 'XYZ' else f'{np.degrees(v):.3g}°'}"
                            for n, v in zip(pars, mdc) if np.isfinite(v))
            L.append(f"- {s.camera} against the rig's calibration ({s.stability['mode']}; "
                     f"{', '.join(pars)}): {_test_text(s.stability)}"
                     + (f"; smallest change detected with 80 % power, each parameter alone: {det}" if det else ""))
        if np.isfinite(s.reference).all():
            d = s.d_reference_sigma
            dc = s.value[:3] - s.reference[:3]
            L.append(f"- {s.camera} − {rr.reference_name or 'reference'}: centre "
                     + ", ".join(f"{'XYZ'[t]} {fmt_q(dc[t], ou)} ({d[t]:+.2f} σ)" for t in range(3))
                     + "; angles " + ", ".join(f"{ANGLES[t]} {np.degrees(s.value[3 + t] - s.reference[3 + t]):+.4f}° "
                                              f"({d[3 + t]:+.2f} σ)" for t in range(3))
                     + f"; baseline {fmt_q(s.baseline - np.linalg.norm(s.reference[:3]), ou)}")
            e = _reference_entry(s, rr.reference_name, names, scale)
            L.append(f"- {s.camera}, OpenCV's T (x_{s.camera} = R x_ref + T, y down, {ou}): baarda ("
                     + ", ".join(f"{v:.4f} ± {sv:.2g}" for v, sv in zip(e["T_baarda"], e["sigma_T"]))
                     + f"), {rr.reference_name or 'reference'} (" + ", ".join(f"{v:.4f}" for v in e["T_reference"])
                     + "), differences " + ", ".join(f"{v:+.2f} σ" for v in e["T_difference_in_sigma"])
                     + f"; R differs by a rotation of {e['R_difference_deg']:.4f}°")
    if rr.stability is not None and sum(s.stability is not None for s in rr.sensors) > 1:
        L.append(f"- all sensors with a calibration together: {_test_text(rr.stability)}")
    L.append("- per sensor in bundle_rig.csv (reads back as a rig table), correlations in bundle_rig_correlations.csv")
    corr = {"rig": [], "camera": [], "p1": [], "p2": [], "rho": []}
    for s in rr.sensors:
        R = s.correlation
        for a in range(6):
            for b in range(a + 1, 6):
                if R[a, a] > 0 and R[b, b] > 0:
                    corr["rig"].append(s.rig)
                    corr["camera"].append(s.camera)
                    corr["p1"].append(SENSOR_NAMES[a])
                    corr["p2"].append(SENSOR_NAMES[b])
                    corr["rho"].append(float(R[a, b]))
    tables = {
        "rig": TableData(cols, f"each sensor's pose in its rig (centre {ou}, ω φ κ of R_sensor_from_rig in degrees) "
                               "with a-posteriori σ, baseline, smallest redundancy number and largest |w| of a weighted "
                               "pose, the stability test against the rig's calibration, differences to the reference "
                               f"solution{' (' + rr.reference_name + ')' if rr.reference_name else ''} in σ",
                               units={"r_min": "", "w_max": "", "T_stability": "", "T_critical": ""}),
        "rig_correlations": TableData(corr, "correlations between the parameters of each sensor's pose in its rig"),
    }
    return {"summary": summary, "lines": L, "tables": tables}
