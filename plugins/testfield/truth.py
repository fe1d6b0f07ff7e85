"""Compare what the rendered pipeline recovered with the simulator's truth (pure numerics).

* :func:`detection_errors` — detected image points against the true target images
  (``block.meta["render"]["targets"]``): which targets were found, and the pixel errors;
* :func:`truth_errors` — a bundle result against ``block.meta["truth"]``: every object point,
  projection centre, rotation and camera parameter with its estimate, true value, a-posteriori σ
  and ``z = (estimate − true) / σ``, plus the Mahalanobis distance of each point
  (``e Σ⁻¹ eᵀ``, χ²(3) when the reported covariance is right).

Errors are estimate minus truth (``docs/conventions.md``: adjusted minus true).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .photos import truth_from_meta

__all__ = ["DetectionCheck", "TruthCheck", "detection_errors", "truth_errors"]


@dataclass(frozen=True)
class DetectionCheck:
    """photo, point (k,) of the detections matched to a rendered target; duv (k, 2) pixel error
    (detected − true); missing: (photo, point) of complete targets (disk inside the image) that
    were not detected; missing_partial: the same for targets cut by the image border (a detector
    may skip them); extra: detected ids that were not rendered in that photo."""

    photo: np.ndarray
    point: np.ndarray
    duv: np.ndarray
    missing: list
    missing_partial: list
    extra: list

    @property
    def rms_px(self) -> np.ndarray:
        """(2,) RMS error in u and v (pixels)."""
        return np.sqrt(np.mean(self.duv ** 2, axis=0)) if len(self.duv) else np.full(2, np.nan)

    def summary(self) -> dict:
        a = np.abs(self.duv)
        return {"matched": len(self.duv), "missing": [list(m) for m in self.missing],
                "missing_partial": [list(m) for m in self.missing_partial], "extra": [list(e) for e in self.extra], "rms_px": self.rms_px.tolist(),
                "max_px": float(a.max()) if a.size else float("nan"),
                "mean_px": self.duv.mean(axis=0).tolist() if len(self.duv) else [float("nan")] * 2}


def detection_errors(block) -> DetectionCheck:
    """Detected observations of ``block`` (image mm, converted back to pixels with the camera's
    pitch and resolution, OpenCV convention) against ``block.meta["render"]["targets"]``."""
    from baarda.pipeline.geometry.image import pixels_from_mm

    truth = block.meta["render"]["targets"]
    partial = block.meta["render"].get("partial", {})
    obs, cams, ph = block.observations, block.cameras, block.photos
    ci = ph.camera[obs.photo]
    uv = pixels_from_mm(obs.xy, cams.resolution[ci], cams.pixel_mm[ci], "opencv")
    photo = ph.ids[obs.photo].astype(str)
    point = block.points.ids[obs.point].astype(str)
    keep, duv, extra = [], [], []
    for k, (p, q) in enumerate(zip(photo, point)):
        t = truth.get(p, {}).get(q)
        if t is None:
            extra.append((p, q))
            continue
        keep.append(k)
        duv.append(uv[k] - np.asarray(t, float))
    seen = set(zip(photo.tolist(), point.tolist()))
    missing = [(p, q) for p, t in truth.items() for q in t if (p, q) not in seen]
    cut = [m for m in missing if m[1] in partial.get(m[0], ())]
    keep = np.array(keep, int)
    return DetectionCheck(photo[keep], point[keep], np.array(duv, float).reshape(-1, 2),
                          [m for m in missing if m not in cut], cut, extra)


@dataclass(frozen=True)
class TruthCheck:
    """Estimates against the truth.

    points : dict of arrays — ids (n,), role (n,), error (n, 3), sigma (n, 3), z (n, 3),
        mahalanobis (n,) = e Σ⁻¹ eᵀ;
    photos : ids (m,), error (m, 6) (X0, Y0, Z0 in object units; ω φ κ rad), sigma (m, 6), z (m, 6);
    camera : rows {parameter, estimate, true, sigma, z} for the free parameters of the camera.
    """

    points: dict
    photos: dict
    camera: list

    def share_within(self, k: float = 3.0, what: str = "points") -> float:
        """Share of coordinates (points: per point, all three) with |z| < k."""
        z = np.abs(self.points["z"] if what == "points" else self.photos["z"])
        return float(np.mean(np.all(z < k, axis=1))) if len(z) else float("nan")

    def camera_row(self, name: str) -> dict:
        for r in self.camera:
            if r["parameter"] == name:
                return r
        raise KeyError(f"camera parameter {name!r} is not free in the adjustment")

    def summary(self) -> dict:
        z = np.abs(self.points["z"])
        return {
            "points": len(z), "points_within_3sigma": self.share_within(3.0),
            "max_abs_z_points": float(z.max()) if z.size else float("nan"),
            "rms_z_points": float(np.sqrt(np.mean(z ** 2))) if z.size else float("nan"),
            "mean_mahalanobis": float(np.mean(self.points["mahalanobis"])) if z.size else float("nan"),
            "photos_within_3sigma": self.share_within(3.0, "photos"),
            "camera": {r["parameter"]: {"estimate": r["estimate"], "true": r["true"], "sigma": r["sigma"],
                                        "z": r["z"]} for r in self.camera},
        }


def truth_errors(result, meta: dict | None = None) -> TruthCheck:
    """A :class:`baarda.pipeline.adjustment.BundleResult` against the simulator's truth (``meta`` defaults to
    the adjusted block's ``meta``).  Points and photos are matched by id; the camera's parameters
    are compared with ``c, xp, yp`` and the distortion of the truth as brown parameters (0 for a
    parameter the simulator does not use, e.g. K3)."""
    block = result.block
    truth = truth_from_meta(meta if meta is not None else block.meta)
    # points
    pts = block.points
    used = result.point_used
    t_index = {str(q): k for k, q in enumerate(truth.point_ids)}
    sel = np.array([k for k in range(len(pts)) if used[k] and str(pts.ids[k]) in t_index], int)
    true = truth.XYZ[[t_index[str(q)] for q in pts.ids[sel]]]
    err = pts.XYZ[sel] - true
    cov = result.cov_points[sel]
    sig = np.sqrt(np.einsum("nii->ni", cov))
    maha = np.array([e @ np.linalg.solve(C, e) for e, C in zip(err, cov)])
    points = {"ids": pts.ids[sel].astype(str), "role": pts.role[sel].astype(str), "error": err, "sigma": sig,
              "z": err / sig, "mahalanobis": maha}
    # photos
    ph = block.photos
    p_index = {str(p): k for k, p in enumerate(truth.photo_ids)}
    psel = np.array([k for k in range(len(ph)) if result.photo_used[k] and str(ph.ids[k]) in p_index], int)
    tk = [p_index[str(p)] for p in ph.ids[psel]]
    dang = (ph.opk[psel] - truth.opk[tk] + np.pi) % (2 * np.pi) - np.pi
    perr = np.column_stack([ph.X0[psel] - truth.X0[tk], dang])
    psig = result.eo_sigmas()[psel]
    photos = {"ids": ph.ids[psel].astype(str), "error": perr, "sigma": psig,
              "z": np.where(psig > 0, perr / np.where(psig > 0, psig, 1.0), np.nan)}
    # camera (the first one: the simulator has one)
    true_cam = {"c": truth.c, "xp": truth.xp, "yp": truth.yp, **{k: float(v) for k, v in truth.distortion.items()}}
    rows = []
    for r in result.camera_table(0):
        if not (r["sigma"] is not None and np.isfinite(r["sigma"]) and r["sigma"] > 0):
            continue
        t = float(true_cam.get(r["parameter"], 0.0))
        rows.append({"parameter": r["parameter"], "estimate": float(r["value"]), "true": t,
                     "sigma": float(r["sigma"]), "z": (float(r["value"]) - t) / float(r["sigma"])})
    return TruthCheck(points, photos, rows)
