"""Processing stage ``dbat-residuals``: the next bundle in DBAT's residual definition.

Placed after a ``bundle`` and before another, it hands on the adjusted block (its values as the
start) with every mark of a backward-model camera weighted as DBAT weighs its corrected residual:
covariance ``J⁻¹ Σ J⁻ᵀ``, ``J = ∂g/∂m`` at the mark and the adjusted camera
(:mod:`.corrected`).  The next ``bundle`` then minimises DBAT's objective to first order: σ̂0,
residuals, σ and tests in DBAT's definition.  ``dbat-report`` after it adds the Newton step to
DBAT's own minimum in the camera.  ``residuals = "measured"`` hands on the marks' own covariances
(baarda's definition).  ``docs/dbat.md``, "Residual definition".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.api import Context, InputError, Stage, StageResult, option

from .corrected import corrected_cov


@dataclass(frozen=True)
class DbatResidualsOptions:
    residuals: str = option("corrected", "'corrected': the next bundle in DBAT's residual definition (the corrected "
                                         "marks weighted with the marks' σ); 'measured': baarda's (the marks' own "
                                         "covariances)")


class DbatResiduals(Stage):
    summary = ("Reweight the marks for the next bundle so that it adjusts in DBAT's residual definition (corrected "
               "marks) or baarda's (measured marks)")
    reads = ("bundle",)
    writes = ("block",)
    Options = DbatResidualsOptions

    def run(self, inputs, options: DbatResidualsOptions, ctx: Context) -> StageResult:
        if options.residuals not in ("corrected", "measured"):
            raise ctx.option_error(f"residuals is 'corrected' or 'measured', got {options.residuals!r}", "residuals")
        res = inputs.get("bundle")
        if res is None:
            raise InputError("dbat-residuals needs the result of a bundle stage before it", path=ctx.project_file,
                             field="use")
        block = res.block
        earlier = (res.block_in.meta.get("dbat_residuals") or {}).get("marks_cov")
        cov0 = np.array(earlier if earlier is not None else res.block_in.observations.cov, float)
        if len(cov0) != len(block.observations):
            raise InputError("the bundle's block has other observations than the block it read", path=ctx.project_file,
                             field="use")
        cov0.setflags(write=False)
        if options.residuals == "measured":
            out = block.replace(observations=block.observations.replace(cov=np.array(cov0)),
                                meta={k: v for k, v in dict(block.meta).items() if k != "dbat_residuals"})
            return StageResult(artefacts={"block": out}, summary={"residuals": "measured", "headline":
                                                                  "marks' own covariances for the next bundle"},
                               report="The marks' own covariances for the next bundle (baarda's residual definition).")
        cov = corrected_cov(block, np.asarray(res.state.cam_params, float), cov0)
        s_old = np.sqrt(np.trace(cov0, axis1=1, axis2=2) / 2)
        s_new = np.sqrt(np.trace(cov, axis1=1, axis2=2) / 2)
        ratio = s_new / s_old
        out = block.replace(observations=block.observations.replace(cov=cov),
                            meta={**dict(block.meta), "dbat_residuals": {"definition": "corrected", "marks_cov": cov0}})
        summary = {"residuals": "corrected", "sigma_ratio_min": float(ratio.min()), "sigma_ratio_max": float(ratio.max()),
                   "headline": f"{len(cov)} marks reweighted for DBAT's residual definition (σ × {ratio.min():.3f}–"
                               f"{ratio.max():.3f})"}
        report = (f"The next bundle adjusts in DBAT's residual definition: each mark weighted with `J⁻¹ Σ J⁻ᵀ`, "
                  f"`J = ∂g/∂m` at the mark and the adjusted camera (its σ scaled by {ratio.min():.3f} to "
                  f"{ratio.max():.3f}); start values: this bundle's result. A further bundle → dbat-residuals round "
                  "moves the camera by less than 0.001 σ on DBAT's demos (docs/dbat.md).")
        return StageResult(artefacts={"block": out}, summary=summary, report=report)
