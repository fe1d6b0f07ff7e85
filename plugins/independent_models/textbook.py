"""Wolf & DeWitt's sample problems (B. A. DeWitt's public-domain programs) run through baarda.

Readers for the three sample formats (``../shared/data/README.md``) and one function per example
that returns the numbers ``docs/textbook-examples.md`` documents.  Run

    python -m baarda.plugins.independent_models.textbook [folder with dewitt_*_sample.dat]

to print them.  Conventions: DeWitt's image coordinates, rotation (``M = R3(κ) R2(φ) R1(ω)``) and
3-D conformal form (``X = s Mᵀ x + T``) are baarda's; his residuals are *computed − measured*
(baarda: observed − computed, the opposite sign); his relative orientation puts the left
projection centre at ``(0, 0, f)`` (baarda's model frame: at the origin).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from baarda.pipeline.api import InputError
from baarda.pipeline.geometry import opk_from_rotation

from baarda.pipeline.imodels.relor import relative_orientation
from baarda.pipeline.imodels.similarity import similarity_closed_form, similarity_transform

__all__ = ["read_relor", "read_resect", "read_3dconf", "relor_example", "conf3d_example",
           "resection_example", "format_examples"]


def _numbers(tokens, path, line, fields):
    out = []
    for tok, name in zip(tokens, fields):
        try:
            out.append(float(tok))
        except ValueError:
            raise InputError(f"expected a number, got {tok!r}", path, line, name) from None
    return out


def _lines(path):
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror}", path) from None
    return [(i + 1, ln.split()) for i, ln in enumerate(text.splitlines()) if ln.strip()]


def _focal_and_rows(path, fields):
    lines = _lines(path)
    if not lines:
        raise InputError("empty file", path)
    ln, tok = lines[0]
    if len(tok) != 1:
        raise InputError(f"first line must hold the focal length only, got {len(tok)} values", path, ln, "focal")
    focal = _numbers(tok, path, ln, ["focal"])[0]
    ids, rows = [], []
    for ln, tok in lines[1:]:
        if len(tok) != len(fields) + 1:
            raise InputError(f"expected {len(fields) + 1} values (name {' '.join(fields)}), got {len(tok)}",
                             path, ln)
        ids.append(tok[0])
        rows.append(_numbers(tok[1:], path, ln, fields))
    return focal, ids, np.array(rows, float).reshape(-1, len(fields))


def read_relor(path) -> dict:
    """``relor`` format: focal length, then ``name xl yl xr yr`` (mm)."""
    focal, ids, a = _focal_and_rows(path, ["xl", "yl", "xr", "yr"])
    return {"focal": focal, "ids": ids, "xy_left": a[:, :2], "xy_right": a[:, 2:]}


def read_resect(path) -> dict:
    """``resect`` format: focal length, then ``name x y X Y Z``."""
    focal, ids, a = _focal_and_rows(path, ["x", "y", "X", "Y", "Z"])
    return {"focal": focal, "ids": ids, "xy": a[:, :2], "XYZ": a[:, 2:]}


def read_3dconf(path) -> dict:
    """``3DCONF`` format: ``name x y z X Y Z`` common points, ``#``, ``name x y z`` points to
    transform, ``#``."""
    groups = [[], []]
    g = 0
    for ln, tok in _lines(path):
        if tok[0] == "#":
            g += 1
            if g == 2:
                break
            continue
        want = 7 if g == 0 else 4
        if len(tok) != want:
            raise InputError(f"expected {want} values, got {len(tok)}", path, ln)
        fields = ["x", "y", "z", "X", "Y", "Z"][: want - 1]
        groups[g].append((tok[0], _numbers(tok[1:], path, ln, fields)))
    if g < 1:
        raise InputError("missing '#' after the common points", path)
    com = np.array([v for _, v in groups[0]], float).reshape(-1, 6)
    unk = np.array([v for _, v in groups[1]], float).reshape(-1, 3)
    return {"ids": [k for k, _ in groups[0]], "xyz": com[:, :3], "XYZ": com[:, 3:],
            "unknown_ids": [k for k, _ in groups[1]], "unknown_xyz": unk}


def relor_example(path) -> dict:
    """Relative orientation of DeWitt's sample pair, four ways.

    Coplanarity and collinearity, dependent and independent: all four must give the same image
    residuals and σ̂0 (one least-squares problem, four formulations); the dependent collinearity
    solution is DeWitt's own formulation (his model frame = baarda's + (0, 0, f)).
    """
    d = read_relor(path)
    f = d["focal"]
    runs = {}
    for method in ("coplanarity", "collinearity"):
        for par in ("dependent", "independent"):
            runs[(method, par)] = relative_orientation(
                d["xy_left"], d["xy_right"], (f, 0.0, 0.0), method=method, parameters=par,
                point_ids=d["ids"], name="DeWitt relor sample")
    ref = runs[("coplanarity", "dependent")]
    agree = {f"{m}/{p}": {
        "max_dv_mm": float(np.nanmax(np.abs(ro.v - ref.v))),
        "d_sigma0_hat": float(abs(ro.sigma0_hat - ref.sigma0_hat)),
        "max_dR_right_from_left": float(np.abs(ro.R_right_from_left - ref.R_right_from_left).max()),
        "max_dbase_direction": float(np.abs(ro.base_in_left / np.linalg.norm(ro.base_in_left)
                                            - ref.base_in_left / np.linalg.norm(ref.base_in_left)).max()),
    } for (m, p), ro in runs.items()}
    dep = runs[("collinearity", "dependent")]
    return {"focal": f, "ids": d["ids"], "runs": runs, "agreement": agree,
            "dewitt_frame_XYZ": dep.XYZ + np.array([0.0, 0.0, f]),
            "dewitt_right_photo": {"omega_deg": float(np.degrees(dep.p[2])),
                                   "phi_deg": float(np.degrees(dep.p[3])),
                                   "kappa_deg": float(np.degrees(dep.p[4])), "XL": dep.bx,
                                   "YL": float(dep.p[0]), "ZL": float(f + dep.p[1])}}


def conf3d_example(path) -> dict:
    """DeWitt's 3-D conformal sample: least squares (from a deliberately poor start: scale 1,
    zero angles, mean shift) against Horn/Umeyama's closed form; transformed points with
    standard deviations."""
    d = read_3dconf(path)
    cf = similarity_closed_form(d["xyz"], d["XYZ"])
    start = np.r_[1.0, 0.0, 0.0, 0.0, np.mean(d["XYZ"] - d["xyz"], axis=0)]
    ls = similarity_transform(d["xyz"], d["XYZ"], point_ids=d["ids"], initial=start)
    Xu, sdu = ls.transform(d["unknown_xyz"])
    return {"ids": d["ids"], "lsq": ls, "closed_form": cf, "start": start,
            "max_d_params": np.abs(ls.params - cf), "unknown_ids": d["unknown_ids"],
            "transformed": Xu, "transformed_std": sdu}


def resection_example(path) -> dict:
    """DeWitt's space resection sample through the bundle plugin's ``resection``; checked against
    OpenCV's ``solvePnP`` (iterative Levenberg–Marquardt, an independent implementation)."""
    import cv2

    from baarda.pipeline.adjustment import resection

    d = read_resect(path)
    f = d["focal"]
    r = resection(d["xy"], d["XYZ"], f)
    n = len(d["ids"])
    s0 = float(np.sqrt(np.sum(r.residuals ** 2) / (2 * n - 6)))
    # OpenCV: camera looks down +z with y down; baarda's cam frame = diag(1, -1, -1) · OpenCV's
    D = np.diag([1.0, -1.0, -1.0])
    img = np.column_stack([d["xy"][:, 0], -d["xy"][:, 1]])
    K = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
    # start OpenCV from a vertical-photo guess, not from baarda's answer
    centre = d["XYZ"].mean(axis=0) + np.array([0.0, 0.0, 600.0])
    ok, rvec, tvec = cv2.solvePnP(np.ascontiguousarray(d["XYZ"]), np.ascontiguousarray(img), K, None,
                                  cv2.Rodrigues(D)[0], (-D @ centre).reshape(3, 1),
                                  useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    Rcv = cv2.Rodrigues(rvec)[0]
    X0_cv = -Rcv.T @ tvec.ravel()
    opk_cv = opk_from_rotation(D @ Rcv)
    return {"ids": d["ids"], "focal": f, "result": r, "sigma0_hat": s0,
            "opencv": {"ok": bool(ok), "X0": X0_cv, "opk": opk_cv},
            "max_dX0": float(np.abs(X0_cv - r.X0).max()),
            "max_dangle_deg": float(np.degrees(np.abs(opk_cv - r.opk)).max())}


def format_examples(folder) -> str:
    """All three examples as plain text (what ``python -m baarda.plugins.independent_models.textbook`` prints)."""
    folder = Path(folder)
    out = []
    rel = relor_example(folder / "dewitt_relor_sample.dat")
    out.append(f"== relative orientation (dewitt_relor_sample.dat, f = {rel['focal']} mm)")
    for (m, p), ro in rel["runs"].items():
        pv = ", ".join(f"{nm} = {np.degrees(v) if nm.startswith(('omega', 'phi', 'kappa')) else v:.5f}"
                       for nm, v in zip(ro.param_names, ro.p))
        out.append(f"{m:12s} {p:11s} sigma0_hat = {ro.sigma0_hat:.6f} mm  dof = {ro.dof}  "
                   f"iterations = {ro.iterations} ({ro.initial})  {pv}  (angles in degrees)")
    for k, a in rel["agreement"].items():
        out.append(f"  vs coplanarity/dependent: {k:26s} max|dv| = {a['max_dv_mm']:.1e} mm, "
                   f"|d sigma0| = {a['d_sigma0_hat']:.1e}, max|dR| = {a['max_dR_right_from_left']:.1e}, "
                   f"max|d base dir| = {a['max_dbase_direction']:.1e}")
    dw = rel["dewitt_right_photo"]
    out.append("  DeWitt's frame (left centre at (0, 0, f)), right photo: "
               + ", ".join(f"{k} = {v:.4f}" for k, v in dw.items()))
    ro = rel["runs"][("collinearity", "dependent")]
    out.append("  point   X(model)   Y(model)   Z(model)    vxl     vyl     vxr     vyr   (mm, observed - computed)  py [mm]   r")
    for i, pid in enumerate(ro.point_ids):
        X = rel["dewitt_frame_XYZ"][i]
        out.append(f"  {pid:5s} {X[0]:9.4f} {X[1]:9.4f} {X[2]:9.4f}  " + " ".join(f"{v:7.4f}" for v in ro.v[i])
                   + f"   {rel['runs'][('coplanarity', 'dependent')].py[i]:8.5f}  "
                   f"{rel['runs'][('coplanarity', 'dependent')].snapshot.r[i]:.3f}")
    c3 = conf3d_example(folder / "dewitt_3DCONF_sample.dat")
    ls = c3["lsq"]
    out.append("== 3-D conformal transformation (dewitt_3DCONF_sample.dat)")
    sd = ls.std()
    out.append(f"scale = {ls.params[0]:.6f} ± {sd[0]:.6f}, omega = {np.degrees(ls.params[1]):.4f}° ± "
               f"{np.degrees(sd[1]):.4f}, phi = {np.degrees(ls.params[2]):.4f}° ± {np.degrees(sd[2]):.4f}, "
               f"kappa = {np.degrees(ls.params[3]):.4f}° ± {np.degrees(sd[3]):.4f}, "
               f"T = ({ls.params[4]:.3f} ± {sd[4]:.3f}, {ls.params[5]:.3f} ± {sd[5]:.3f}, "
               f"{ls.params[6]:.3f} ± {sd[6]:.3f})")
    out.append(f"sigma0_hat = {ls.sigma0_hat:.5f}, dof = {ls.dof}, iterations = {ls.iterations} "
               f"(from scale 1, zero angles), max|LSQ − closed form| = {c3['max_d_params'].max():.1e}")
    out.append("  point   vX      vY      vZ   (observed - computed)")
    for pid, v in zip(ls.point_ids, ls.residuals):
        out.append(f"  {pid:5s} {v[0]:7.3f} {v[1]:7.3f} {v[2]:7.3f}")
    out.append("  transformed   X          Y          Z        sX     sY     sZ")
    for pid, X, s in zip(c3["unknown_ids"], c3["transformed"], c3["transformed_std"]):
        out.append(f"  {pid:5s} {X[0]:10.3f} {X[1]:10.3f} {X[2]:9.3f}  {s[0]:.3f}  {s[1]:.3f}  {s[2]:.3f}")
    rs = resection_example(folder / "dewitt_resect_sample.dat")
    r = rs["result"]
    out.append(f"== space resection (dewitt_resect_sample.dat, f = {rs['focal']} mm) via baarda.pipeline.adjustment.initial.resection")
    out.append(f"omega = {np.degrees(r.opk[0]):.4f}°, phi = {np.degrees(r.opk[1]):.4f}°, "
               f"kappa = {np.degrees(r.opk[2]):.4f}°, X0 = ({r.X0[0]:.4f}, {r.X0[1]:.4f}, {r.X0[2]:.4f}), "
               f"sigma0_hat = {rs['sigma0_hat']:.5f} mm (dof {2 * len(rs['ids']) - 6}), start: {r.method}")
    out.append(f"  OpenCV solvePnP (independent): max|dX0| = {rs['max_dX0']:.1e}, "
               f"max|d angle| = {rs['max_dangle_deg']:.1e}°")
    for pid, v in zip(rs["ids"], r.residuals):
        out.append(f"  {pid:5s} vx = {v[0]:8.4f}  vy = {v[1]:8.4f}  (mm, observed - computed)")
    return "\n".join(out)


def main(argv=None) -> int:  # pragma: no cover - thin command line
    argv = sys.argv[1:] if argv is None else argv
    folder = Path(argv[0]) if argv else Path(__file__).resolve().parents[2].parent / "shared" / "data" / "textbook"
    print(format_examples(folder))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
