"""Stage ``calibration-quality``: mrcal-style projection uncertainty over the format and
cross-validation of two calibrations from disjoint photo halves (docs/calibration-quality.md).

Numerics in :mod:`baarda.pipeline.adjustment.calquality`; this module picks the cameras, turns mm
into pixels and writes tables, summary, report and figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.adjustment import calquality as cq
from baarda.pipeline.camera.convert import pixel_source
from baarda.pipeline.api import Context, Stage, StageResult, TableData, option
from baarda.pipeline.units import fmt_obj, fmt_q, object_unit_text


@dataclass(frozen=True)
class CalQualityOptions:
    """Options of the ``calibration-quality`` stage."""

    cameras: list[str] = option([], "ids of the cameras to assess; empty: every camera the bundle estimated")
    distance: float = option(0.0, "distance of the point on each pixel's ray, object unit; 0: the median "
                                  "distance of the photos from the points they observe", ge=0.0)
    grid: int = option(40, "grid cells across the format's width (rows in proportion)", ge=4)
    frame: Literal["mean-pcam", "camera"] = option(
        "mean-pcam", "mean-pcam: camera parameters and the photos' orientations (mrcal's reference-frame "
                     "shift); camera: the camera parameters alone")
    cross_validation: bool = option(True, "calibrate each half of the photos and compare the two cameras")
    split: Literal["even-odd", "halves"] = option("even-odd", "how the photos of a camera are split for "
                                                              "the cross-validation")


def _working_distance(res, j: int) -> float:
    obs = res.block_in.observations
    ph = cq.camera_photos(res, j)
    use = res.obs_active & np.isin(obs.photo, ph)
    d = np.linalg.norm(res.state.XYZ[obs.point[use]] - res.state.X0[obs.photo[use]], axis=1)
    return float(np.median(d))


def _corners(m) -> list[float]:
    s = m.sigma
    return [float(s[0, 0]), float(s[0, -1]), float(s[-1, 0]), float(s[-1, -1])]


class CalibrationQuality(Stage):
    summary = "Projection uncertainty over the format and cross-validation of a calibration (mrcal-style)."
    reads = ("bundle",)
    writes = ("calibration_quality",)
    Options = CalQualityOptions

    def run(self, inputs, options: CalQualityOptions, ctx: Context) -> StageResult:
        res = inputs["bundle"]
        cams = res.block_in.cameras
        ids = [str(i) for i in cams.ids]
        if options.cameras:
            for c in options.cameras:
                if c not in ids:
                    raise ctx.option_error(f"camera {c!r} is not in the block (cameras: {', '.join(ids)})", "cameras")
            todo = [ids.index(c) for c in options.cameras]
        else:
            todo = [j for j in range(len(ids)) if res.camera_used[j] and res.camera_free[j].any()]
        if not todo:
            raise ctx.option_error("no camera with estimated parameters to assess", "cameras")
        out, tables, summary, lines = {}, {}, {"cameras": {}}, []
        src = pixel_source(res.block_in)
        for j in ctx.progress.track(todo, what="cameras"):
            cid = ids[j]
            pix = float(cams.pixel_mm[j])
            # pixels for a pixel source (COLMAP, BAL, libmv, OpenCV targets), µm for one measured in mm
            # (a film or test-field camera, even with a nominal pitch): the units of the bundle's report
            unit, f = ("px", 1.0 / pix) if src and np.isfinite(pix) and pix > 0 else ("µm", 1000.0)
            sfx = "px" if unit == "px" else "um"          # the unit in column names (docs/conventions.md)
            dist = options.distance or _working_distance(res, j)
            m = cq.projection_uncertainty(res, j, dist, nx=options.grid, frame=options.frame)
            mcam = m if options.frame == "camera" else cq.projection_uncertainty(res, j, dist, nx=options.grid,
                                                                                  frame="camera")
            s = m.sigma * f
            n_nan = int(np.isnan(s).sum())
            cs = {"unit": unit, "distance": dist, "frame": options.frame, "photos": m.n_photos,
                  "grid": list(s.shape[::-1]),
                  "sigma_centre": m.at(0.0, 0.0) * f, "sigma_corners": [v * f for v in _corners(m)],
                  "sigma_worst": float(np.nanmax(s)), "sigma_median": float(np.nanmedian(s)),
                  "sigma_camera_only_centre": mcam.at(0.0, 0.0) * f, "cells_outside_model": n_nan}
            if n_nan:
                ctx.warn(f"camera {cid}: {n_nan} grid cells could not be unprojected (the distortion model folds "
                         "over or its inversion diverges there)")
            W, H = np.asarray(res.block_in.cameras.resolution[j], float)
            axes = (f, (W - 1) / 2, -f, (H - 1) / 2, "px") if unit == "px" and W > 0 and H > 0 else None
            cols = {"x_mm": m.xy[:, 0], "y_mm": m.xy[:, 1],
                    **({"x_px": f * m.xy[:, 0] + axes[1], "y_px": -f * m.xy[:, 1] + axes[3]} if axes else {}), f"sigma_{sfx}": s.ravel(),
                    f"sigma_camera_{sfx}": mcam.sigma.ravel() * f,
                    "cov_xx_mm2": m.cov[:, 0, 0], "cov_xy_mm2": m.cov[:, 0, 1], "cov_yy_mm2": m.cov[:, 1, 1]}
            cv = None
            if options.cross_validation:
                try:
                    cv = cq.cross_validate(res, j, split=options.split, distance=dist, nx=options.grid)
                except ValueError as e:
                    ctx.warn(f"camera {cid}: no cross-validation: {e}")
                except Exception as e:   # an adjustment of one half that cannot be solved
                    from baarda.pipeline.api import AdjustmentError

                    if not isinstance(e, AdjustmentError):
                        raise
                    ctx.warn(f"camera {cid}: cross-validation: a half could not be adjusted: {e}")
            if cv is not None:
                cols.update({f"cv_dx_{sfx}": cv.diff[..., 0].ravel() * f, f"cv_dy_{sfx}": cv.diff[..., 1].ravel() * f,
                             f"cv_diff_{sfx}": cv.norm.ravel() * f, f"cv_sigma_pred_{sfx}": cv.sigma_pred.ravel() * f,
                             "cv_ratio": cv.ratio.ravel(), "cv_mahalanobis2": cv.mahalanobis2.ravel(),
                             f"cv_fit_dx_{sfx}": cv.diff_fit[..., 0].ravel() * f,
                             f"cv_fit_dy_{sfx}": cv.diff_fit[..., 1].ravel() * f,
                             f"cv_fit_sigma_pred_{sfx}": cv.sigma_fit.ravel() * f,
                             "cv_fit_ratio": cv.ratio_fit.ravel(), "cv_fit_mahalanobis2": cv.mahalanobis2_fit.ravel()})
                cs["cross_validation"] = {
                    "split": options.split, "photos": [len(cv.photos[0]), len(cv.photos[1])],
                    "rms": cv.rms * f, "sigma_pred_rms": float(np.sqrt(np.nanmean(cv.sigma_pred ** 2))) * f,
                    "fraction_above_2sigma": cv.fraction_above_2sigma,
                    "mean_mahalanobis2": float(np.nanmean(cv.mahalanobis2)),
                    "sigma0_hat": [r.sigma0_hat for r in cv.results],
                    "rotation_fit": {"rotation_deg": [float(v) for v in np.degrees(cv.rotation)],
                                     "rms": cv.rms_fit * f,
                                     "sigma_pred_rms": float(np.sqrt(np.nanmean(cv.sigma_fit ** 2))) * f,
                                     "fraction_above_2sigma": cv.fraction_above_2sigma_fit,
                                     "mean_mahalanobis2": float(np.nanmean(cv.mahalanobis2_fit))}}
            tables[f"map_{cid}"] = TableData(cols)
            summary["cameras"][cid] = cs
            out[cid] = {"map": m, "camera_only": mcam, "cv": cv, "unit": unit, "factor": f, "axes": axes,
                        "object_unit": object_unit_text(res.block_in)}
            lines.append(f"- camera **{cid}**: σ of the projection at {fmt_obj(dist, object_unit_text(res.block_in))} ({options.frame}, {m.n_photos} "
                         f"photos): centre {fmt_q(cs['sigma_centre'], unit)}, corners "
                         f"{', '.join(fmt_q(v, unit) for v in cs['sigma_corners'])}, worst {fmt_q(cs['sigma_worst'], unit)}"
                         f"; camera parameters alone: centre {fmt_q(cs['sigma_camera_only_centre'], unit)}.")
            if cv is not None:
                c2 = cs["cross_validation"]
                lines.append(f"  cross-validation ({options.split}, {c2['photos'][0]} + {c2['photos'][1]} photos): "
                             f"RMS difference {fmt_q(c2['rms'], unit)} against a predicted {fmt_q(c2['sigma_pred_rms'], unit)}"
                             f"; {100 * c2['fraction_above_2sigma']:.0f} % of the format beyond 2σ; mean "
                             f"Δqᵀ(Σ₁+Σ₂)⁻¹Δq {c2['mean_mahalanobis2']:.2f} (2 expected).")
                rf = c2["rotation_fit"]
                lines.append(f"  after fitting the rotation between the two camera frames "
                             f"({np.linalg.norm(rf['rotation_deg']):.3f}°, as mrcal's projection_diff): RMS "
                             f"{fmt_q(rf['rms'], unit)} against a predicted {fmt_q(rf['sigma_pred_rms'], unit)}; "
                             f"{100 * rf['fraction_above_2sigma']:.0f} % beyond 2σ; mean Mahalanobis² "
                             f"{rf['mean_mahalanobis2']:.2f}.")
        first = summary["cameras"][ids[todo[0]]]
        summary["headline"] = (f"projection σ of camera {ids[todo[0]]}: centre {fmt_q(first['sigma_centre'], first['unit'])}"
                               f", worst {fmt_q(first['sigma_worst'], first['unit'])}"
                               + (f"; cross-validation RMS {fmt_q(first['cross_validation']['rms'], first['unit'])}"
                                  if "cross_validation" in first else ""))
        report = ("Projection uncertainty (σ in the worst direction of a point on each pixel's ray, from the "
                  "bundle's covariance) and cross-validation of two calibrations from disjoint photo halves; "
                  "docs/calibration-quality.md.\n\n" + "\n".join(lines))
        return StageResult(artefacts={"calibration_quality": out}, summary=summary, report=report, tables=tables,
                           data=out)

    def plots(self, result: StageResult, ctx: Context) -> dict:
        from .figures import quality_figures

        return quality_figures(result.data)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        for cid, d in result.data.items():
            s = np.nan_to_num(d["map"].sigma * d["factor"], nan=0.0).astype(np.float32)
            rec.log(f"cameras/{cid}/sigma", rr.Tensor(s))
            if d["cv"] is not None:
                rec.log(f"cameras/{cid}/cv_ratio", rr.Tensor(np.nan_to_num(d["cv"].ratio, nan=0.0).astype(np.float32)))
