"""Processing stage ``dbat-bundle``: baarda's bundle with DBAT's residual definition.

The ``bundle`` stage keeps the marks as the observations (baarda's residuals, measured marks);
``dbat-bundle`` takes every option of ``bundle`` and ``residuals``: ``"corrected"`` (the default)
adjusts in DBAT's definition — the corrected marks' residuals weighted with the marks' σ — by the
reweighting of :mod:`.corrected`, so that a DBAT project gives DBAT's camera and σ̂0 with baarda's
statistics on top; ``"measured"`` is the ``bundle`` stage itself.  ``docs/dbat.md``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baarda.pipeline.api import BundleConfig, Context, StageResult, adjust, option
from baarda.plugins.bundle.stage import BundleAdjustment

from .corrected import adjust_corrected, camera_at_dbat_minimum


@dataclasses.dataclass(frozen=True)
class DbatBundleConfig(BundleConfig):
    residuals: str = option("corrected", "'corrected': DBAT's residual definition (the corrected marks, weighted "
                                         "with the marks' σ; reproduces DBAT's camera and σ̂0); 'measured': "
                                         "baarda's (the marks as observations), as the bundle stage")
    max_rounds: int = option(6, "largest number of reweighting rounds with residuals = 'corrected'", ge=1)
    tol_round_sigma: float = option(0.01, "the rounds stop when no camera parameter moves by more than this "
                                          "fraction of its σ", gt=0.0)


def _base(options: DbatBundleConfig) -> BundleConfig:
    return BundleConfig(**{f.name: getattr(options, f.name) for f in dataclasses.fields(BundleConfig)})


class DbatBundle(BundleAdjustment):
    writes = BundleAdjustment.writes + ("dbat_minimum",)
    summary = ("Bundle adjustment in DBAT's residual definition (corrected marks) or baarda's (measured marks): "
               "DBAT's camera and σ̂0 with baarda's statistics")
    Options = DbatBundleConfig

    def run(self, inputs, options: DbatBundleConfig, ctx: Context) -> StageResult:
        if options.residuals not in ("corrected", "measured"):
            raise ctx.option_error(f"residuals is 'corrected' or 'measured', got {options.residuals!r}", "residuals")
        base = _base(options)
        block = inputs["block"]
        if options.residuals == "measured":
            return super().run(inputs, base, ctx)
        cov0 = np.array(block.observations.cov, float)

        def one(b):
            rep = adjust(b, base, threads=ctx.threads)
            return rep.result, rep.result.block

        ctx.progress.message("adjusting in DBAT's residual definition (corrected marks): reweighting rounds")
        _, used, rounds, move = adjust_corrected(block, one, max_outer=options.max_rounds - 1,
                                                 tol_sigma=options.tol_round_sigma)
        cov0.setflags(write=False)
        used = used.replace(meta={**dict(used.meta), "dbat_residuals": {"definition": "corrected",
                                                                         "marks_cov": cov0, "rounds": rounds + 1}})
        result = super().run({**inputs, "block": used}, base, ctx)
        res = result.artefacts["bundle"]
        mini = camera_at_dbat_minimum(used, res, cov0)
        dof = int(res.dof)
        s0_min = float(np.sqrt(max(res.vtpv - mini["F_before"] + mini["F_after"], 0.0) / dof)) if dof > 0 else np.nan
        mini = {**mini, "sigma0": s0_min, "dof": dof}
        result.artefacts["dbat_minimum"] = mini
        result.summary["dbat_minimum"] = {"sigma0_hat": s0_min,
                                          "camera_step_sigma": _step_in_sigma(res, mini["step"])}
        result.summary["residuals"] = "corrected"
        result.summary["reweighting_rounds"] = rounds + 1
        result.report = (f"DBAT's own minimum: one Newton step of DBAT's objective in the camera (its gradient "
                         f"left by the reweighting) moves the camera by up to "
                         f"{max(result.summary['dbat_minimum']['camera_step_sigma'].values(), default=0):.2f} σ; "
                         f"σ̂0 there {s0_min:.6g}. dbat-report shows that camera; orientations and points stay at "
                         "the reweighted solution.\n\n" + result.report)
        result.report = (f"Residual definition: DBAT's (corrected marks `g(l − pp) − x̄` weighted with the marks' σ), "
                         f"by reweighting each mark with `J⁻¹ Σ J⁻ᵀ`, `J = ∂g/∂m` at the adjusted camera "
                         f"({rounds + 1} rounds; the camera moved by {move:.2g} σ in the last but one). "
                         "σ̂0 and the residuals below are in that definition (docs/dbat.md).\n\n" + result.report)
        return result


def _step_in_sigma(res, step) -> dict:
    """|Newton step| / σ per free camera parameter (names of the first camera's model)."""
    out = {}
    for j in range(step.shape[0]):
        C = np.asarray(res.cov_cameras[j], float)
        for k, name in enumerate(res.cam_param_names[j]):
            if C[k, k] > 0:
                out[f"{j}:{name}" if step.shape[0] > 1 else name] = float(abs(step[j, k]) / np.sqrt(C[k, k]))
    return out
