"""The column layout of the unknowns: where every image observation's Jacobian columns go in the
global vector, the photo segments of the (photo-sorted) observations and the observation →
eliminated point map (:class:`ColumnLayout`, built once by :class:`~.problem.BundleProblem`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["ColumnLayout"]


@dataclass(frozen=True, slots=True, eq=False)
class ColumnLayout:
    """Per active observation (k of them, sorted by photo), its Jacobian's global columns.

    ``groups`` the column groups ``[cam (P) | eo (6) | global point (3)]`` present, ``keep`` the
    group columns some observation uses; ``cidx`` (k, q) the global column of each (``n_g``: the
    dummy column of a fixed parameter), ``mask`` (k, q) the free ones (``mask_all``: all are);
    ``q_ph`` the photo-constant columns (camera and orientation) first; ``jac_cols`` the columns of
    the camera, orientation and point Jacobians that feed ``cidx``.  Photo segments:
    ``seg_start``, ``seg_end``, ``seg_len`` and their columns ``seg_cols`` (n_seg, q_ph); ``gp_obs``
    the observations of global (scale-bar) points.  Eliminated points: ``pidx`` (k,) the point of
    each observation (``n_e``: none), ``obs_elim`` (k,) whether it has one, ``pt_mask`` (k, 3) its
    free coordinates (``pt_mask_all``), ``obs_to_point`` (n_e + 1, k) the summation matrix."""

    groups: tuple
    keep: np.ndarray
    cidx: np.ndarray
    mask: np.ndarray
    mask_all: bool
    q: int
    q_ph: int
    jac_cols: tuple
    seg_start: np.ndarray
    seg_end: np.ndarray
    seg_len: np.ndarray
    seg_cols: np.ndarray
    gp_obs: np.ndarray
    pidx: np.ndarray
    obs_elim: np.ndarray
    pt_mask: np.ndarray
    pt_mask_all: bool
    obs_to_point: sp.csr_matrix

    @classmethod
    def build(cls, cam_cols: np.ndarray, eo_cols: np.ndarray, pt_cols: np.ndarray, obs_photo: np.ndarray,
              n_g: int, elim: np.ndarray, elim_free: np.ndarray) -> "ColumnLayout":
        """From the global columns of every observation's camera ``cam_cols`` (k, P), orientation
        ``eo_cols`` (k, 6) and point ``pt_cols`` (k, 3) (−1: fixed), the photo of each
        (photo-sorted) observation, ``n_g``, the eliminated point of each observation ``elim``
        (−1: none) and the free coordinates of the eliminated points ``elim_free`` (n_e, 3)."""
        k = len(obs_photo)
        n_e = len(elim_free)
        groups = []
        if (cam_cols >= 0).any():
            groups.append(("cam", cam_cols))
        groups.append(("eo", eo_cols))
        if (pt_cols >= 0).any():
            groups.append(("pt", pt_cols))
        cidx = np.concatenate([c for _, c in groups], axis=1) if groups else np.zeros((k, 0), int)
        # drop columns that no observation uses (parameters fixed everywhere)
        used = (cidx >= 0).any(axis=0)
        n_ph_cols = sum(c.shape[1] for name, c in groups if name != "pt")
        keep = np.flatnonzero(used)
        cidx = cidx[:, used]
        mask = cidx >= 0
        cidx = np.where(mask, cidx, n_g)
        q = cidx.shape[1]
        q_ph = int(used[:n_ph_cols].sum())                               # photo-constant columns
        sel = {"cam": np.zeros(0, int), "eo": np.zeros(0, int), "pt": np.zeros(0, int)}
        off = 0
        for name, c in groups:
            w = c.shape[1]
            sel[name] = keep[(keep >= off) & (keep < off + w)] - off
            off += w
        # photo segments of the (photo-sorted) observations
        starts = np.flatnonzero(np.r_[True, obs_photo[1:] != obs_photo[:-1]]) if k else np.zeros(0, int)
        ends = np.r_[starts[1:], k].astype(int)
        gp_obs = np.flatnonzero((cidx[:, q_ph:] < n_g).any(axis=1)) if q > q_ph else np.zeros(0, int)
        obs_elim = elim >= 0
        pidx = np.where(obs_elim, elim, n_e)
        pt_mask = np.zeros((k, 3), bool)
        pt_mask[obs_elim] = elim_free[elim[obs_elim]]
        # Σ over the observations of each eliminated point (row n_e: observations of no such point)
        obs_to_point = sp.csr_matrix((np.ones(k), (pidx, np.arange(k))), shape=(n_e + 1, k))
        return cls(groups=tuple((name, c.shape[1]) for name, c in groups), keep=keep, cidx=cidx, mask=mask,
                   mask_all=bool(mask.all()), q=q, q_ph=q_ph, jac_cols=(sel["cam"], sel["eo"], sel["pt"]),
                   seg_start=starts, seg_end=ends, seg_len=(ends - starts).astype(np.intp),
                   seg_cols=cidx[starts, :q_ph], gp_obs=gp_obs, pidx=pidx, obs_elim=obs_elim, pt_mask=pt_mask,
                   pt_mask_all=bool(pt_mask.all()), obs_to_point=obs_to_point)
