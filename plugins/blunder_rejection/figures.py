"""blunder-rejection's protocol entry and figures (w against N(0, 1), redundancy numbers, the
test statistic of each method per row) for report.html."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import stats
from baarda.pipeline.protocol import MOST_LABELS, snapshot_protocol

UNITS = {"helmert-screening": "mm", "independent-models": "mm"}
"""Unit of the residuals of the adjustments baarda knows (image / model coordinates in mm)."""


def protocol(report, art, options) -> dict | None:
    """The adjustment's protocol (σ̂0, global test, RMS, reliability) with what the decisive method
    rejected; None for the bundle, whose own stage prints the fuller protocol."""
    if art.name == "bundle":
        return None
    unit = UNITS.get(art.name, "")
    rows = np.asarray(art.obs_rows, int)
    p = snapshot_protocol(art.snapshot, name=art.name, alpha0=options.alpha0, beta0=options.beta0, unit=unit,
                          alpha_global=options.alpha_global,
                          coordinate_rows=rows[:, 1] if len(rows) == art.snapshot.n else None)
    decisive = report.methods[report.decide_by]
    labels = [str(x) for x in decisive.rejected_labels[:MOST_LABELS]]
    if report.action == "remove":      # rejected = taken out of the block
        p["tests"]["n_rejected"] = len(decisive.rejected_labels)
        p["tests"]["rejected"] = labels
    else:                              # action = flag: the method's rejections are flags, the block is unchanged
        p["tests"]["n_decided"] = len(decisive.rejected_labels)
        p["tests"]["decided"] = labels
    p["tests"]["action"] = report.action
    p["tests"]["decided_by"] = report.decide_by
    return p


def figures(art, options) -> dict:
    """w against N(0, 1) and the redundancy numbers of the adjustment tested — none for the bundle,
    whose own stage draws them from the same snapshot (a report shows each figure once)."""
    from baarda.pipeline.plots import redundancy_numbers, w_distribution

    if art.name == "bundle":
        return {}
    snap = art.snapshot
    ok = stats.controlled(snap)
    ds = stats.data_snooping(snap, alpha0=options.alpha0, beta0=options.beta0)
    return {
        "w": (w_distribution(ds.w[ok], ds.critical, title=f"w of {art.name}"),
              f"w of the {art.name} adjustment against N(0, 1)"),
        "redundancy": (redundancy_numbers(np.asarray(snap.r)[np.asarray(snap.active, bool)]),
                       f"Redundancy numbers of the {art.name} adjustment"),
    }
