"""What the residual swirl of DBAT's camcal photos is (docs/dbat.md, "The residual swirl").

Candidate explanations of the residual pattern of `fixtures/dbat/camcal.toml` (PhotoModeler's marks)
and `fixtures/dbat/camcal-detect.toml` (baarda's own detections), each tested with numbers:

* **linearised re-adjustments** from the converged bundle: the design matrix of the bundle (every
  photo's orientation, the 96 free points, the camera's 9 free parameters; the 4 control points
  fixed) with a hypothesis' extra columns; one Gauss–Newton step from the solution gives the vᵀPv
  the hypothesis leaves (exact to first order; checked below against a true re-adjustment).  The
  drop in vᵀPv is compared with the share that as many random columns would take (p / dof);
* **true re-adjustments** with `adjust_block`: one camera per photo (c, xp, yp free per photo, the
  distortion held at the common calibration), and a richer common lens model;
* the per-photo principal points against the direction of **gravity** in each image (the sheet lies
  on the floor: gravity is −Z of the sheet's frame).

    .venv/bin/python benchmarks/camcal_swirl.py [--detections RUN_DIR] [--figure PNG]

``RUN_DIR`` is a run of camcal-detect without the eccentricity correction
(``baarda run fixtures/dbat/camcal-detect.toml --set bundle_detected.eccentricity.enabled=false --out RUN_DIR``);
its ``bundle_detected_observations.csv`` holds the detected centres (mm).  About 20 s.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from baarda.pipeline.adjustment.collinearity import project_observations
from baarda.pipeline.adjustment.settings import BundleSettings, camera_meta
from baarda.pipeline.api import BundleConfig, adjust
from baarda.pipeline.geometry.rotations import rotation_from_opk_many
from baarda.pipeline.model import Cameras, Observations
from baarda.plugins.dbat import dbat_block, read_dbat

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT.parent / "shared" / "data" / "dbat-camcal" / "camcaldemo.xml"


def detections_block(marks, run_dir: Path):
    """The marks' block with the detected centres of a camcal-detect run as its observations."""
    rows = list(csv.DictReader(open(run_dir / "bundle_detected_observations.csv", encoding="utf-8")))
    ph = marks.photos.index_of([r["photo"] for r in rows])
    pt = marks.points.index_of([r["point"] for r in rows])
    xy = np.array([[float(r["x_mm"]), float(r["y_mm"])] for r in rows])
    sigma = float(np.sqrt(marks.observations.cov[0, 0, 0]))          # 0.1 px, as the marks
    return marks.replace(observations=Observations.make(ph, pt, xy, sigma=sigma))


def per_photo_cameras(block, free_ap=False, group=None):
    """The adjusted block with one copy of its camera per photo (or per ``group`` of photos: (m,)
    index): c, xp, yp free in each, the additional parameters held at the common values (or free too)."""
    group = np.arange(len(block.photos)) if group is None else np.asarray(group)
    m, cam = int(group.max()) + 1, block.cameras
    rep = lambda a: np.repeat(a, m, axis=0)
    sa = rep(cam.sigma_ap).copy() if free_ap else np.zeros((m, cam.ap.shape[1]))
    cams = Cameras(ids=np.array([f"c{j}" for j in range(m)]), c=rep(cam.c), xp=rep(cam.xp), yp=rep(cam.yp),
                   ap_model=rep(cam.ap_model), ap=rep(cam.ap), sigma_iop=np.full((m, 3), np.inf), sigma_ap=sa,
                   format_mm=rep(cam.format_mm), pixel_mm=rep(cam.pixel_mm), resolution=rep(cam.resolution))
    return block.replace(cameras=cams, photos=block.photos.replace(camera=group))


class Linearised:
    """The bundle's weighted design matrix at a converged solution (``rep.result.block``), for
    re-adjustments with extra columns to first order."""

    def __init__(self, adj):
        obs, ph, pts, cams = adj.observations, adj.photos, adj.points, adj.cameras
        cam_params = np.column_stack([cams.c, cams.xp, cams.yp, cams.ap])
        pr = project_observations(obs.photo, obs.point, pts.XYZ, ph.X0, ph.opk, ph.camera, cam_params,
                                  cams.ap_model, camera_meta(adj, BundleSettings()), jacobians=True)
        self.adj, self.pr = adj, pr
        self.sigma = np.sqrt(obs.cov[:, 0, 0])                        # mm, the same in x and y
        self.v = (obs.xy - pr.xy) / self.sigma[:, None]                  # observed − computed, in σ
        k, m = len(obs), len(ph)
        free_pts = np.flatnonzero(~(pts.sigma == 0).all(axis=1))
        pcol = -np.ones(len(pts), int)
        pcol[free_pts] = np.arange(len(free_pts))
        cam_free = np.flatnonzero(np.r_[cams.sigma_iop[0], cams.sigma_ap[0]] > 0)
        n = 6 * m + 3 * len(free_pts) + len(cam_free)
        A = np.zeros((k, 2, n))
        rows = np.arange(k)
        for a in range(6):
            A[rows, :, 6 * obs.photo + a] = pr.J_eo[:, :, a]
        ok = pcol[obs.point] >= 0
        for a in range(3):
            A[rows[ok], :, 6 * m + 3 * pcol[obs.point[ok]] + a] = pr.J_point[ok, :, a]
        A[:, :, 6 * m + 3 * len(free_pts):] = pr.J_cam[:, :, cam_free]
        self.A = (A / self.sigma[:, None, None]).reshape(2 * k, n)
        self.dof = 2 * k - n
        pix = cams.pixel_mm[0]
        # the *computed* positions (pixels from the centre, y down): a field of the observed ones
        # would hold the residuals themselves
        self.uv = np.column_stack([pr.xy[:, 0] / pix, -pr.xy[:, 1] / pix])
        self.format_px = cams.resolution[0].astype(float)

    @property
    def vtpv(self) -> float:
        return float((self.v ** 2).sum())

    def with_columns(self, extra: np.ndarray) -> float:
        """vᵀPv after one Gauss–Newton step with ``extra`` (k, 2, q) columns (image mm per unit) added."""
        E = (extra / self.sigma[:, None, None]).reshape(len(self.v) * 2, -1)
        M = np.hstack([self.A, E])
        x, *_ = np.linalg.lstsq(M, self.v.reshape(-1), rcond=None)
        r = self.v.reshape(-1) - M @ x
        return float(r @ r)

    # -- the hypotheses' extra columns -----------------------------------------------------------
    def per_photo(self, cols: np.ndarray) -> np.ndarray:
        """(k, 2, q) columns that act in one photo each → (k, 2, q m)."""
        obs = self.adj.observations
        m = len(self.adj.photos)
        q = cols.shape[2]
        out = np.zeros((len(obs), 2, q * m))
        for a in range(q):
            out[np.arange(len(obs)), :, q * obs.photo + a] = cols[:, :, a]
        return out

    def camera_columns(self, names) -> np.ndarray:
        """Derivatives w.r.t. the camera's parameters ``names`` (of c, xp, yp and the AP model's)."""
        names_all = ["c", "xp", "yp", *self.adj_ap_names()]
        return self.pr.J_cam[:, :, [names_all.index(n) for n in names]]

    def adj_ap_names(self):
        from baarda.pipeline.camera import get_ap_model
        return list(get_ap_model(str(self.adj.cameras.ap_model[0])).params)

    def image_polynomial(self, degree: int) -> np.ndarray:
        """x and y each a polynomial of the format position (normalised to ±1) up to ``degree``."""
        u = self.uv / (self.format_px / 2)
        mono = [u[:, 0] ** i * u[:, 1] ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
        k = len(u)
        cols = np.zeros((k, 2, 2 * len(mono)))
        pix = self.adj.cameras.pixel_mm[0]
        for a, f in enumerate(mono):
            cols[:, 0, 2 * a] = f * pix
            cols[:, 1, 2 * a + 1] = f * pix
        return cols

    def sheet_polynomial(self, degree: int, axes=(0, 1, 2)) -> np.ndarray:
        """The points displaced in the sheet's frame by polynomials of (X, Y) (the sheet spans 0…1),
        seen through each observation's ∂xy/∂XYZ: a sheet that changed shape."""
        XYZ = self.adj.points.XYZ[self.adj.observations.point]
        X, Y = XYZ[:, 0], XYZ[:, 1]
        mono = [X ** i * Y ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
        cols = [self.pr.J_point[:, :, a] * f[:, None] for a in axes for f in mono]
        return np.stack(cols, axis=2)

    def common_field(self, nx=8, ny=6) -> np.ndarray:
        """One correction per cell of an nx × ny grid over the format, the same in every photo."""
        cell = (np.clip(((self.uv[:, 0] / self.format_px[0] + 0.5) * nx).astype(int), 0, nx - 1) * ny
                + np.clip(((self.uv[:, 1] / self.format_px[1] + 0.5) * ny).astype(int), 0, ny - 1))
        cols = np.zeros((len(cell), 2, 2 * nx * ny))
        pix = self.adj.cameras.pixel_mm[0]
        cols[np.arange(len(cell)), 0, 2 * cell] = pix
        cols[np.arange(len(cell)), 1, 2 * cell + 1] = pix
        return cols


def gravity_in_image(adj) -> np.ndarray:
    """(m, 3) gravity's direction in each camera frame (x right, y up in the image, z backwards); the
    sheet lies on the floor, its Z axis up."""
    R = rotation_from_opk_many(adj.photos.opk)
    return R @ np.array([0.0, 0.0, -1.0])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--detections", type=Path, help="a camcal-detect run without the eccentricity correction")
    ap.add_argument("--figure", type=Path, help="write the per-photo principal points against gravity here")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    marks = dbat_block(read_dbat(XML))
    sets = [("marks", marks)]
    if args.detections:
        sets.append(("detections", detections_block(marks, args.detections)))
    results = {}
    for name, block in sets:
        print(f"\n== {name}: {len(block.observations)} image points in {len(block.photos)} photos ==")
        base = adjust(block, BundleConfig(datum="control"))
        adj = base.result.block
        lin = Linearised(adj)
        pix = adj.cameras.pixel_mm[0]
        total = lin.vtpv
        print(f"bundle: vᵀPv {base.result.vtpv:.1f} (recomputed {total:.1f}), dof {lin.dof}, "
              f"σ̂0 {base.result.sigma0_hat:.4f}")
        m = len(adj.photos)
        hyp = {
            "per photo: c": lin.per_photo(lin.camera_columns(["c"])),
            "per photo: xp, yp": lin.per_photo(lin.camera_columns(["xp", "yp"])),
            "per photo: c, xp, yp": lin.per_photo(lin.camera_columns(["c", "xp", "yp"])),
            "per photo: all 9 camera parameters": lin.per_photo(lin.camera_columns(
                ["c", "xp", "yp", "K1", "K2", "K3", "P1", "P2", "aspect"])),
            "per photo: image affinity (scale x, y; shear both ways)": lin.per_photo(
                lin.image_polynomial(1)[:, :, 2:]),
            "per photo: image cubic (20 terms)": lin.per_photo(lin.image_polynomial(3)),
            "per photo: sheet bent, ΔZ cubic in X, Y (10)": lin.per_photo(lin.sheet_polynomial(3, axes=(2,))),
            "per photo: sheet stretched, ΔX, ΔY cubic (20)": lin.per_photo(lin.sheet_polynomial(3, axes=(0, 1))),
            "one field for all photos (8 × 6 cells)": lin.common_field(),
        }
        g = gravity_in_image(adj)
        gcols = lin.camera_columns(["xp", "yp", "c"])
        gk = g[adj.observations.photo]
        hyp["gravity: xp, yp = A g (4), c = c0 + b g_z (1)"] = np.stack(
            [gcols[:, :, 0] * gk[:, :1], gcols[:, :, 0] * gk[:, 1:2], gcols[:, :, 1] * gk[:, :1],
             gcols[:, :, 1] * gk[:, 1:2], gcols[:, :, 2] * gk[:, 2:3]], axis=2)
        hyp["gravity: xp, yp = s (g_x, g_y) (1)"] = (gcols[:, :, 0] * gk[:, :1] + gcols[:, :, 1] * gk[:, 1:2])[:, :, None]
        print(f"{'hypothesis':58s} {'extra':>5s} {'vᵀPv':>8s} {'taken':>6s} {'by chance':>9s}")
        rows = {}
        for label, cols in hyp.items():
            q = np.linalg.matrix_rank(cols.reshape(-1, cols.shape[2]) / pix)
            left = lin.with_columns(cols)
            rows[label] = (q, left, 1 - left / total)
            print(f"{label:58s} {q:5d} {left:8.1f} {1 - left / total:6.1%} {q / lin.dof:9.1%}")
        # the true re-adjustment with one camera per photo (distortion held at the common values)
        pp = adjust(per_photo_cameras(adj), BundleConfig(datum="control"))
        cp = pp.result.state.cam_params
        print(f"re-adjusted, one camera per photo (c, xp, yp free, distortion common): vᵀPv "
              f"{pp.result.vtpv:.1f} ({1 - pp.result.vtpv / total:.1%} taken), σ̂0 {pp.result.sigma0_hat:.4f}, "
              f"dof {pp.result.dof}")
        sc = np.sqrt(np.array([np.diag(c)[:3] for c in pp.result.cov_cameras]))
        tilt = np.degrees(np.arccos(np.clip(-g[:, 2], -1, 1)))
        print(f"{'photo':9s} {'tilt°':>5s} {'g_x':>6s} {'g_y':>6s} {'c px':>8s} {'σ':>5s} {'xp px':>7s} {'σ':>4s} "
              f"{'yp px':>7s} {'σ':>4s}")
        for j in range(m):
            print(f"{adj.photos.ids[j]:9s} {tilt[j]:5.1f} {g[j, 0]:+6.2f} {g[j, 1]:+6.2f} {cp[j, 0] / pix:8.1f} "
                  f"{sc[j, 0] / pix:5.1f} {cp[j, 1] / pix:+7.2f} {sc[j, 1] / pix:4.2f} {cp[j, 2] / pix:+7.2f} "
                  f"{sc[j, 2] / pix:4.2f}")
        # the principal points against gravity: xp, yp = p0 + A (g_x, g_y), weighted by their σ
        G = np.column_stack([np.ones(m), g[:, 0], g[:, 1]])
        fit = {}
        for a, nm in ((1, "xp"), (2, "yp")):
            w = 1 / sc[:, a]
            coef, *_ = np.linalg.lstsq(G * w[:, None], cp[:, a] * w, rcond=None)
            res = cp[:, a] - G @ coef
            r2 = 1 - (res ** 2).sum() / ((cp[:, a] - cp[:, a].mean()) ** 2).sum()
            fit[nm] = (coef / pix, r2, np.sqrt((res ** 2).mean()) / pix)
            print(f"{nm} = {coef[0] / pix:+.2f} {coef[1] / pix:+.2f} g_x {coef[2] / pix:+.2f} g_y px: "
                  f"R² {r2:.3f}, RMS of the rest {np.sqrt((res ** 2).mean()) / pix:.2f} px "
                  f"(their σ {np.median(sc[:, a]) / pix:.2f} px)")
        # richer common lens model
        try:
            rich = adjust(adj, BundleConfig(datum="control", ap_model="metashape", aps="free", fix=["P3", "P4"]))
            print(f"one camera, metashape model (K1–K4, P1, P2, B1, B2): vᵀPv {rich.result.vtpv:.1f} "
                  f"({1 - rich.result.vtpv / total:.1%} taken)")
        except Exception as e:                                          # noqa: BLE001 — reported
            print(f"one camera, metashape model: {type(e).__name__}: {e}")
        # two cameras: the photos taken upright (gravity along the image's y) and on their side (along x)
        side = np.abs(g[:, 0]) > np.abs(g[:, 1])
        two = per_photo_cameras(adj, free_ap=True, group=side.astype(int))
        tw = adjust(two, BundleConfig(datum="control"))
        tc = tw.result.state.cam_params
        ts = np.sqrt(np.array([np.diag(c)[:3] for c in tw.result.cov_cameras]))
        print(f"re-adjusted, two cameras (upright: {int((~side).sum())} photos, on the side: {int(side.sum())}), "
              f"each with all 9 parameters: vᵀPv {tw.result.vtpv:.1f} ({1 - tw.result.vtpv / total:.1%} taken, "
              f"by chance {9 / lin.dof:.1%}), σ̂0 {tw.result.sigma0_hat:.4f}")
        for j, lab in enumerate(("upright", "on the side")):
            print(f"  {lab:12s} c {tc[j, 0] / pix:8.2f} ± {ts[j, 0] / pix:.2f}  xp {tc[j, 1] / pix:+7.2f} ± {ts[j, 1] / pix:.2f}"
                  f"  yp {tc[j, 2] / pix:+7.2f} ± {ts[j, 2] / pix:.2f} px")
        results[name] = dict(lin=lin, pp=pp, g=g, cp=cp, sc=sc, fit=fit, rows=rows, total=total)
    if "detections" in results:
        a, b = results["marks"], results["detections"]
        d = b["cp"] - a["cp"]
        print(f"\nper-photo principal points, detections − marks: RMS ({np.sqrt((d[:, 1] ** 2).mean()) / pix:.2f}, "
              f"{np.sqrt((d[:, 2] ** 2).mean()) / pix:.2f}) px; their spread over the photos "
              f"({a['cp'][:, 1].std() / pix:.1f}, {a['cp'][:, 2].std() / pix:.1f}) px")
    if args.figure:
        figure(results, args.figure)
    print(f"\n{time.perf_counter() - t0:.1f} s")
    return results


def figure(results, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = results["marks"]
    adj = r["lin"].adj
    pix = adj.cameras.pixel_mm[0]
    g, cp, sc = r["g"], r["cp"], r["sc"]
    fig, axs = plt.subplots(1, 3, figsize=(14, 4.6), gridspec_kw={"width_ratios": [1, 1, 1.6]})
    for ax, a, nm in ((axs[0], 0, "xp"), (axs[1], 1, "yp")):
        gk, p = g[:, a], cp[:, 1 + a] / pix
        ax.errorbar(gk, p, yerr=sc[:, 1 + a] / pix, fmt="o", ms=4, color="C3")
        for j in range(len(g)):
            ax.annotate(adj.photos.ids[j][-2:], (gk[j], p[j]), fontsize=7, xytext=(3, 2), textcoords="offset points")
        coef, r2, rest = r["fit"][nm]
        ax.set_xlabel(f"gravity's component along the image's {'x' if a == 0 else 'y'} axis")
        ax.set_ylabel(f"{nm} of the photo (px)")
        ax.set_title(f"{nm} = {coef[0]:+.1f} {coef[1]:+.1f} g_x {coef[2]:+.1f} g_y px (R² {r2:.2f})", fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle("DBAT camcal (PhotoModeler's marks): one camera per photo (c, xp, yp free, distortion common) — "
                 "the principal point moves with the camera's roll against gravity", fontsize=10)
    ax = axs[2]
    labels = list(r["rows"])
    taken = [r["rows"][k][2] * 100 for k in labels]
    chance = [r["rows"][k][0] / r["lin"].dof * 100 for k in labels]
    y = np.arange(len(labels))
    ax.barh(y, taken, color="C0", label="share of vᵀPv taken")
    ax.barh(y, chance, color="0.6", height=0.4, label="by chance (extra parameters / dof)")
    ax.set_yticks(y, [f"{k.split(' (')[0]} [{r['rows'][k][0]}]" for k in labels], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("% of the bundle's vᵀPv (PhotoModeler's marks)")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Share of vᵀPv taken (linearised; [extra parameters])", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"figure: {path}")


if __name__ == "__main__":
    main()
