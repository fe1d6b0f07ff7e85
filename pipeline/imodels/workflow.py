"""Independent-model block triangulation of a :class:`baarda.pipeline.model.Block`, end to end.

``independent_model_block(block, ...)`` forms the models (from ``Block.pairs`` or from consecutive
photos), orients each pair relatively (:mod:`baarda.pipeline.imodels.relor`), intersects the model points
and the projection centres, and adjusts all models at once (:mod:`baarda.pipeline.imodels.block`) with
the block's control.  It returns everything a report, a study or a recording needs — the check-point
RMSE is ``result.check`` (:class:`~baarda.pipeline.accuracy.CheckPoints`).  Pure: no files, no rerun.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Literal, Sequence

import numpy as np

from baarda.pipeline.accuracy import CheckPoints
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import Block

from .block import ModelBlockAdjustment, ModelCoordinates, adjust_model_block
from .relor import RelativeOrientation, model_covariance, relative_orientation

__all__ = ["form_pairs", "model_coordinates", "independent_model_block", "IndependentModelResult"]


def form_pairs(block: Block, pairing: Literal["auto", "pairs", "consecutive"] = "auto",
               strips: Sequence[Sequence[str]] = (), min_points: int = 5):
    """Stereo pairs as ``[(left index, right index)]`` plus notes on pairs that were skipped.

    ``pairs`` uses ``Block.pairs``; ``consecutive`` pairs neighbouring photos — within each strip
    of ``strips`` (lists of photo ids) or, without strips, in the order of the photo table, keeping
    only neighbours with at least ``min_points`` common points (so the jump from the end of one
    strip to the start of the next is dropped); ``auto`` is ``pairs`` when the block has pairs.
    """
    notes = []
    if pairing == "pairs" or (pairing == "auto" and len(block.pairs)):
        if not len(block.pairs):
            raise InputError("pairing = 'pairs' but the block has no stereo pairs", field="pairing")
        return list(zip(block.pairs.left.tolist(), block.pairs.right.tolist())), notes
    if strips:
        out = []
        for s, strip in enumerate(strips):
            try:
                idx = block.photos.index_of([str(p) for p in strip])
            except KeyError as e:
                raise InputError(f"strip {s + 1}: {e.args[0]}", field="strips") from None
            out += list(zip(idx[:-1].tolist(), idx[1:].tolist()))
        return out, notes
    out = []
    for i in range(len(block.photos) - 1):
        n = len(_common(block, i, i + 1)[0])
        if n >= min_points:
            out.append((i, i + 1))
        else:
            notes.append(f"photos {block.photos.ids[i]} and {block.photos.ids[i + 1]} share {n} "
                         f"point(s) (< {min_points}): not paired")
    return out, notes


def _common(block: Block, left: int, right: int):
    """Point indices measured (active) in both photos and the observation rows."""
    obs = block.observations
    rows_l = np.flatnonzero((obs.photo == left) & obs.active)
    rows_r = np.flatnonzero((obs.photo == right) & obs.active)
    first_l = dict(zip(obs.point[rows_l][::-1].tolist(), rows_l[::-1].tolist()))
    first_r = dict(zip(obs.point[rows_r][::-1].tolist(), rows_r[::-1].tolist()))
    pts = sorted(set(first_l) & set(first_r))
    return (np.array(pts, int), np.array([first_l[p] for p in pts], int),
            np.array([first_r[p] for p in pts], int))


def _interior(block: Block, photo: int, warnings: list) -> tuple[float, float, float]:
    cams = block.cameras
    c = int(block.photos.camera[photo])
    if cams.ap_model[c] != "none" and cams.ap.shape[1] and np.any(cams.ap[c] != 0):
        msg = (f"camera {cams.ids[c]}: additional parameters ({cams.ap_model[c]}) are not applied "
               "by the independent-model method")
        if msg not in warnings:
            warnings.append(msg)
    return float(cams.c[c]), float(cams.xp[c]), float(cams.yp[c])


def _auto_bx(block: Block, left: int, right: int, parameters: str) -> float | None:
    """Base from approximate exterior orientation (model ≈ object scale), else None."""
    ph = block.photos
    if not (np.all(np.isfinite(ph.X0[[left, right]])) and np.all(np.isfinite(ph.opk[left]))):
        return None
    from baarda.pipeline.geometry import rotation_from_opk

    b = ph.X0[right] - ph.X0[left]
    if parameters == "independent":
        return float(np.linalg.norm(b)) or None
    bx = float((rotation_from_opk(*ph.opk[left]) @ b)[0])
    return bx if abs(bx) > 0.2 * np.linalg.norm(b) else None


def model_coordinates(ro: RelativeOrientation, model_id: str, photos: tuple[str, str], *,
                      weights: Literal["propagated", "intersection", "equal"] = "propagated",
                      projection_centres: bool = True, sigma_pc_scale: float = 1.0,
                      pc_prefix: str = "pc:") -> ModelCoordinates:
    """A model for the block adjustment from a relative orientation.

    Points used in the orientation, intersected in front of both cameras, plus (optionally) the two
    projection centres as ``pc:<photo id>``.  Weights (a-priori covariance per point, correlations
    between points dropped):

    * ``propagated`` — image errors propagated through orientation *and* intersection, in the
      minimum-trace datum of the model (:func:`~baarda.pipeline.imodels.relor.model_covariance`); the
      projection centres get theirs the same way;
    * ``intersection`` — each point's covariance from the space intersection with the orientation
      held fixed; a projection centre gets the median point covariance;
    * ``equal`` — one diagonal covariance per model, the RMS of the ``intersection`` sigmas per axis.

    ``sigma_pc_scale`` scales the projection centres' sigmas.
    """
    ok = ro.active & np.all(np.isfinite(ro.XYZ), axis=1) & ro.in_front
    sel = np.flatnonzero(ok)
    ids = list(ro.point_ids[sel])
    xyz = ro.XYZ[sel]
    if weights == "propagated":
        _, cov_all = model_covariance(ro, sel)
        cov, pc_cov = cov_all[:-2], cov_all[-2:]
    else:
        cov = ro.cov_XYZ[sel]
        if weights == "equal":
            s = np.sqrt(np.mean(np.einsum("nii->ni", cov), axis=0))
            cov = np.broadcast_to(np.diag(s ** 2), cov.shape).copy()
        pc_cov = np.stack([np.median(cov, axis=0)] * 2)
    is_pc = [False] * len(ids)
    if projection_centres:
        ids += [pc_prefix + photos[0], pc_prefix + photos[1]]
        xyz = np.vstack([xyz, ro.X0_left, ro.X0_right])
        cov = np.concatenate([cov, pc_cov * sigma_pc_scale ** 2])
        is_pc += [True, True]
    return ModelCoordinates(id=model_id, point_ids=np.array(ids), xyz=xyz, cov=cov,
                            is_pc=np.array(is_pc), photos=tuple(photos))


@dataclass(frozen=True)
class ModelBlockOptions:
    """The choices :func:`independent_model_block` ran with (its keyword arguments of the same names)."""

    method: str
    parameters: str
    pairing: str
    model_weights: str
    projection_centres: bool
    sigma_pc_scale: float
    sigma0: float


@dataclass(frozen=True, eq=False)
class IndependentModelResult:
    """Everything :func:`independent_model_block` computed.

    pairs : [(model id, left photo id, right photo id)]; relative : the relative orientations
    (same order); models : the model coordinates handed to the block adjustment; block : the
    :class:`~baarda.pipeline.imodels.block.ModelBlockAdjustment`; notes / warnings : text;
    options : the :class:`ModelBlockOptions` it ran with.
    """

    pairs: list
    relative: list
    models: list
    block: ModelBlockAdjustment
    notes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    options: ModelBlockOptions | None = None

    @property
    def check(self) -> CheckPoints:
        """The check points of the block adjustment: ids, errors adjusted − surveyed, ``Sx`` … ``Sz``."""
        return self.block.check

    @property
    def sigma0_hat(self) -> float:
        return self.block.sigma0_hat

    def report(self) -> dict:
        return {"models": [ro.report() for ro in self.relative], "block": self.block.report(),
                "notes": list(self.notes), "warnings": list(self.warnings)}


def independent_model_block(block: Block, *,
                            method: Literal["coplanarity", "collinearity"] = "coplanarity",
                            parameters: Literal["dependent", "independent"] = "dependent",
                            pairing: Literal["auto", "pairs", "consecutive"] = "auto",
                            strips: Sequence[Sequence[str]] = (),
                            model_weights: Literal["propagated", "intersection", "equal"] = "propagated",
                            projection_centres: bool = True, sigma_pc_scale: float = 1.0,
                            initial: str = "auto", sigma0: float = 1.0, min_rcond: float = 1e-10,
                            screen_model: Callable[[RelativeOrientation], RelativeOrientation] | None = None,
                            skip_failed_models: bool = False, max_iter: int = 50,
                            pc_prefix: str = "pc:", progress=None) -> IndependentModelResult:
    """Independent-model block triangulation of ``block``.

    Parameters
    ----------
    method, parameters, initial, min_rcond : relative orientation (see
        :func:`~baarda.pipeline.imodels.relor.relative_orientation`).  The model scale is the base from
        the photos' approximate exterior orientation when known (model ≈ object scale), else the
        mean x-parallax.
    pairing, strips : how models are formed (:func:`form_pairs`).
    model_weights, projection_centres, sigma_pc_scale : see :func:`model_coordinates`.
    sigma0 : a-priori σ0 of the image coordinates' covariance (``Observations.cov``).
    screen_model : optional ``f(ro) -> ro`` applied after each relative orientation (e.g. iterated
        data snooping of the y-parallaxes); points it deactivates are left out of the model.
    skip_failed_models : a pair whose orientation fails is skipped with a note instead of
        stopping the run.
    progress : optional callable ``(iterable, total, what) -> iterable`` (``ctx.progress.track``).

    Raises
    ------
    AdjustmentError : a pair with fewer than 5 points or a critical configuration (naming the
        model), a model without tie to the block, missing datum, no convergence.
    """
    bad = [p for p in block.points.ids.tolist() if p.startswith(pc_prefix)]
    if bad:
        raise InputError(f"point id {bad[0]!r} starts with {pc_prefix!r}, which names projection "
                         "centres in independent models; rename the point", field="points.ids")
    pairs, notes = form_pairs(block, pairing, strips)
    if not pairs:
        raise AdjustmentError("no stereo pairs: the block has no pairs and no neighbouring photos "
                              "with 5 or more common points")
    warnings: list[str] = []
    obs = block.observations
    ph_ids = block.photos.ids
    out_pairs, rel, models = [], [], []
    it = progress(pairs, len(pairs), "models") if progress else pairs
    for left, right in it:
        mid = f"{ph_ids[left]}-{ph_ids[right]}"
        pts, rl, rr = _common(block, left, right)
        try:
            ro = relative_orientation(
                obs.xy[rl], obs.xy[rr], _interior(block, left, warnings), _interior(block, right, warnings),
                cov_left=obs.cov[rl], cov_right=obs.cov[rr], method=method, parameters=parameters,
                bx=_auto_bx(block, left, right, parameters), initial=initial,
                point_ids=block.points.ids[pts], sigma0=sigma0, min_rcond=min_rcond, max_iter=max_iter,
                name=f"model {mid}")
            if screen_model is not None:
                ro = screen_model(ro)
        except AdjustmentError as e:
            if not skip_failed_models:
                raise
            notes.append(f"model {mid} skipped: {e}")
            continue
        out_pairs.append((mid, str(ph_ids[left]), str(ph_ids[right])))
        rel.append(ro)
        models.append(model_coordinates(ro, mid, (str(ph_ids[left]), str(ph_ids[right])),
                                        weights=model_weights, projection_centres=projection_centres,
                                        sigma_pc_scale=sigma_pc_scale, pc_prefix=pc_prefix))
    adj = adjust_model_block(models, block.points, sigma0=sigma0, max_iter=max_iter, pc_prefix=pc_prefix)
    opts = ModelBlockOptions(method=method, parameters=parameters, pairing=pairing, model_weights=model_weights,
                             projection_centres=projection_centres, sigma_pc_scale=sigma_pc_scale, sigma0=sigma0)
    return IndependentModelResult(pairs=out_pairs, relative=rel, models=models, block=adj,
                                  notes=notes, warnings=warnings, options=opts)
