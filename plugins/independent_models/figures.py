"""Figures of ``independent-models`` for report.html (matplotlib; the engine draws them with Agg):
check-point errors of the model block beside the bundle's of the same run, the relative
orientations' residual y-parallaxes, and the model-point residuals per model.  Every number is the
stage's (its result and tables) or, for the bundle, the bundle result's own ``check``."""

from __future__ import annotations

import numpy as np


def _plt():
    import matplotlib.pyplot as plt

    return plt


def check_point_sets(result, bundle=None) -> list:
    """The sets :func:`baarda.pipeline.plots.point_errors` draws: the model block's check-point errors
    (adjusted − surveyed) at the surveyed positions, and the bundle's where ``bundle`` is given."""
    blk = result.block
    chk = blk.check
    ids = [str(i) for i in chk.ids]
    where = {str(p): k for k, p in enumerate(blk.point_ids)}
    d = np.asarray(chk.errors, float).reshape(-1, 3)
    xy = (np.asarray(blk.XYZ, float)[[where[i] for i in ids]] - d)[:, :2] if ids else np.zeros((0, 2))
    sets = [{"label": "independent models", "ids": ids, "xy": xy, "d": d, "sigma": None, "color": "#c0392b"}]
    if bundle is not None:
        sid, res = bundle
        pts = res.block_in.points
        pos = {str(p): k for k, p in enumerate(pts.ids)}
        bids = [str(i) for i in res.check.ids]
        bd = np.asarray(res.check.errors, float).reshape(-1, 3)
        sets.append({"label": "bundle" if sid == "bundle" else f"bundle ({sid})", "ids": bids, "xy": np.asarray(pts.XYZ, float)[[pos[i] for i in bids], :2],
                     "d": bd, "sigma": None, "color": "#1f4e9c"})
    return sets


def check_points(result, unit: str, bundle=None):
    from baarda.pipeline.plots import point_errors

    sets = check_point_sets(result, bundle)
    blk = result.block
    bg = np.asarray(blk.XYZ, float)[[not str(p).startswith("pc:") for p in blk.point_ids]][:, :2]
    return point_errors(sets, unit, f"check points: adjusted − surveyed ({unit})", components=("X", "Y", "Z"),
                        background=bg)


def _point_of(label: str, name: str) -> str:
    """The point id in a relative orientation's snapshot label ``"<name> point <id> <coordinate>"``."""
    head = f"{name} point "
    return label[len(head):].rsplit(" ", 1)[0] if label.startswith(head) else label


def y_parallax_points(result, stats) -> list:
    """Per model: (model id, point ids, y-parallax in µm, used, flagged by the w-test, dof) — the
    stage's ``ro_points`` (py) and each model's data snooping."""
    out = []
    for (mid, *_), ro, st in zip(result.pairs, result.relative, stats["models"]):
        ds = st["snooping"]
        flagged = {_point_of(str(lab), ro.name) for lab in ds.flagged_labels}
        ids = [str(i) for i in ro.point_ids]
        out.append((str(mid), ids, np.asarray(ro.py, float) * 1e3, np.asarray(ro.active, bool),
                    np.array([i in flagged for i in ids], bool), int(ro.dof)))
    return out


def y_parallaxes(result, stats):
    """Residual y-parallax of every point per model (µm): used, flagged, removed before the model."""
    plt = _plt()
    data = y_parallax_points(result, stats)
    fig, ax = plt.subplots(figsize=(max(10.0, 0.75 * len(data) + 3), 4.0))
    rng = np.random.default_rng(0)          # horizontal jitter only, for legibility
    seen = set()
    for k, (mid, ids, py, used, flag, _) in enumerate(data):
        x = k + rng.uniform(-0.18, 0.18, len(py))
        for m, style, lab in ((used & ~flag, dict(color="#1f4e9c", ms=4), "used"),
                              (flag, dict(color="#c0392b", ms=6), "flagged (w-test)"),
                              (~used, dict(color="#999", ms=6, mfc="none"), "removed before the model")):
            if m.any():
                ax.plot(x[m], py[m], "o", ls="none", label=lab if lab not in seen else None, **style)
                seen.add(lab)
        for j in np.flatnonzero(flag | ~used):
            ax.annotate(ids[j], (x[j], py[j]), fontsize=7, xytext=(4, 0), textcoords="offset points")
    ax.axhline(0, color="k", lw=0.7)
    ax.set_xticks(range(len(data)), [f"{d[0]}\ndof {d[5]}" for d in data], fontsize=8)
    ax.set_xlabel("model and its redundancy (dof 0: the y-parallaxes are 0 by construction)")
    ax.set_ylabel("residual y-parallax (µm)")
    ax.set_title("relative orientation: residual y-parallax of every point", fontsize=10)
    if seen:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def model_residual_rms(table, projection_centres: bool = False) -> tuple[list, np.ndarray]:
    """(model ids, (m, 3) RMS of vx, vy, vz) from the stage's ``residuals`` table, over the model
    points or (``projection_centres``) over the projection centres (role ``pc``); nan where a model
    has none."""
    model = np.asarray(table.columns["model"]).astype(str)
    pc = np.asarray(table.columns["role"]).astype(str) == "pc"
    names = [next(n for n in table.columns if n == c or (n.startswith(c + "_") and not n.startswith(c + "_model")))
             for c in ("vx", "vy", "vz")]      # vx_m / vx_mm (object frame), not vx_model_mu
    v = np.column_stack([np.asarray(table.columns[c], float) for c in names])
    ids = list(dict.fromkeys(model.tolist()))
    sel = pc if projection_centres else ~pc
    rms = [np.sqrt(np.mean(v[(model == m) & sel] ** 2, axis=0)) if np.any((model == m) & sel) else np.full(3, np.nan)
           for m in ids]
    return ids, np.array(rms).reshape(-1, 3)


def model_residuals(table, unit: str):
    plt = _plt()
    f, u = (1000.0, "mm") if unit == "m" else (1.0, unit)
    has_pc = bool(np.any(np.asarray(table.columns["role"]).astype(str) == "pc"))
    ids = model_residual_rms(table)[0]
    fig, axes = plt.subplots(1, 2 if has_pc else 1, figsize=(max(10.0, 1.3 * len(ids) + 3), 3.6), squeeze=False)
    for ax, pc, what in zip(axes[0], (False, True), ("model points", "projection centres")):
        ids, rms = model_residual_rms(table, pc)
        x = np.arange(len(ids))
        for c, (name, col) in enumerate((("x", "#1f4e9c"), ("y", "#2c7a3f"), ("z", "#c0392b"))):
            ax.bar(x + (c - 1) * 0.27, rms[:, c] * f, width=0.27, color=col, label=f"RMS v{name}")
        ax.set_xticks(x, ids, fontsize=8, rotation=45 if len(ids) > 8 else 0)
        ax.set_xlabel("model")
        ax.set_ylabel(f"RMS residual ({u})")
        ax.set_title(f"{what}: residuals in the object frame (observed − computed)", fontsize=10)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def independent_model_figures(result, stats, tables, unit: str, bundle=None) -> dict:
    """Every figure: name → (figure, caption).  ``bundle`` ``(stage id, BundleResult)`` of the run's
    bundle with check points (the ``bundle`` artefact the stage reads), or None."""
    out = {}
    if len(result.block.check.ids):
        out["checkpoints"] = (check_points(result, unit, bundle),
                              "Check-point errors (adjusted − surveyed) of the independent-model block"
                              + (f" beside the bundle's ({bundle[0]}) of this run" if bundle else "")
                              + ": vectors in plan and per coordinate")
    out["y_parallax"] = (y_parallaxes(result, stats),
                         "Relative orientation of each model: residual y-parallax of every point (µm)")
    out["model_residuals"] = (model_residuals(tables["residuals"], unit),
                              "RMS of the residuals of the block adjustment per model and axis: model points and "
                              "projection centres")
    return out
