"""Where circle-centre eccentricity *is* the systematic error: a calibration plate of large circular
dots seen in oblique convergent photos (docs/targets.md, "Where the correction matters").

The plate is a 1.0 × 0.8 (object units, metres) grid of 11 × 9 dots of 0.05 diameter (half the
spacing) in Z = 0, the four corner dots fixed control, as DBAT's camcal sheet; 20 photos as in the
camcal calibration: 8 stations 38° off the vertical around the plate, each with the camera upright and
on its side, and 4 near-vertical photos rolled by 90°; a compact camera (c 7.5 mm, 2272 × 1704 pixels
of 3.2 µm, Brown distortion of ≈ 40 px in the corners).  Each observation is what a detector measures:
the centre of the conic fitted to the dot's rim (128 points on the circle, projected through the
camera with its distortion), plus Gaussian noise.  The dots image ≈ 60–90 px wide and their
eccentricity is ≈ 0.1–0.5 px.

    .venv/bin/python benchmarks/eccentricity_plate.py [--noise-px 0.02] [--figures DIR]

prints the calibration without and with the correction against the truth (in σ), σ̂0, and the share
of the uncorrected residuals that the eccentricity explains; ``--figures`` writes the residual figures
``eccentricity-plate-residuals-uncorrected.png`` and ``…-corrected.png``.  About 5 s.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from baarda.pipeline.adjustment import project_observations
from baarda.pipeline.adjustment.eccentricity import conic_centres
from baarda.pipeline.api import BundleConfig, EccentricityConfig, adjust
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.model import Block, Cameras, CircleTargets, Observations, Photos, Points
from baarda.pipeline.synthetic.closerange import look_at

C_MM, PIXEL_MM, RESOLUTION = 7.5, 0.0032, (2272, 1704)
XP, YP = 0.012, -0.020                                   # mm
#: brown: K1, K2, K3, P1, P2, B1, B2 (mm⁻², mm⁻⁴, …); ≈ −40 px radial in the corners
TRUE_AP = np.array([-1.6e-3, 1.2e-5, 0.0, 1.5e-5, -1.0e-5, 0.0, 0.0])
FREE_AP = np.array([True, True, False, True, True, False, False])
DIAMETER = 0.05
PARAMS = ("c", "xp", "yp", "K1", "K2", "P1", "P2")


def plate_block(rng: np.random.Generator, noise_px: float = 0.02, sigma_px: float | None = None,
                diameter: float = DIAMETER, rim_points: int = 128, wall: bool = False):
    """(block, truth): the plate's block (circle table of ``diameter``, the normals given) whose
    observations are the fitted centres of the dots' distorted rims plus ``noise_px`` Gaussian noise
    (σ of the observations ``sigma_px``, default ``noise_px``); truth = dict(cam, X0, opk, XYZ).
    ``wall``: a second plate of 11 × 4 dots standing upright along the far edge (Y = 0.9, Z 0.1–0.4,
    facing −Y): a field of two planes, a dot seen only from in front (its normal within 75° of the ray)."""
    sigma_px = noise_px if sigma_px is None else sigma_px
    gx, gy = np.meshgrid(np.linspace(0, 1.0, 11), np.linspace(0, 0.8, 9))
    XYZ = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    n = len(XYZ)
    corners = [0, 10, n - 11, n - 1]
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    if wall:
        wx, wz = np.meshgrid(np.linspace(0, 1.0, 11), np.linspace(0.1, 0.4, 4))
        XYZ = np.vstack([XYZ, np.column_stack([wx.ravel(), np.full(wx.size, 0.9), wz.ravel()])])
        normals = np.vstack([normals, np.tile([0.0, -1.0, 0.0], (wx.size, 1))])
        n = len(XYZ)
    centre = np.array([0.5, 0.4, 0.0])
    X0, opk = [], []
    for i in range(8):                                   # 8 stations × (upright, on the side)
        az = np.radians(45 * i + 10)
        tilt = np.radians(38 + 3 * (i % 2))
        dist = 1.55 + 0.05 * (i % 3)
        C = centre + dist * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        for roll in (0.0, np.pi / 2):
            X0.append(C)
            opk.append(opk_from_rotation(look_at(C, centre, roll)))
    for i in range(4):                                   # near-vertical, rolled by 90°
        C = centre + np.array([0.1 * np.cos(i), 0.1 * np.sin(i), 1.45])
        X0.append(C)
        opk.append(opk_from_rotation(look_at(C, centre, np.pi / 2 * i)))
    X0, opk = np.array(X0), np.array(opk)
    m = len(X0)
    cam = np.r_[C_MM, XP, YP, TRUE_AP]
    ph, pt = np.repeat(np.arange(m), n), np.tile(np.arange(n), m)
    ideal = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), cam[None], ["brown"], [{}], jacobians=False)
    half = np.array(RESOLUTION) * PIXEL_MM / 2 - 40 * PIXEL_MM
    ray = X0[ph] - XYZ[pt]
    facing = (ray * normals[pt]).sum(axis=1) > np.cos(np.radians(75)) * np.linalg.norm(ray, axis=1)
    inside = (np.abs(ideal.xy) < half).all(axis=1) & (ideal.W < 0) & facing
    ph, pt = ph[inside], pt[inside]
    # the rims: points on each dot's circle projected with the camera (distortion included)
    t = np.linspace(0, 2 * np.pi, rim_points, endpoint=False)
    nk = normals[pt]
    u = np.cross(nk, np.where(np.abs(nk[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    u /= np.linalg.norm(u, axis=1)[:, None]
    w = np.cross(nk, u)
    P = (XYZ[pt][:, None, :] + diameter / 2 * (np.cos(t)[None, :, None] * u[:, None] + np.sin(t)[None, :, None]
                                                * w[:, None])).reshape(-1, 3)
    k = len(ph)
    rim = project_observations(np.repeat(ph, rim_points), np.arange(k * rim_points), P, X0, opk, np.zeros(m, int),
                               cam[None], ["brown"], [{}], jacobians=False).xy.reshape(k, rim_points, 2)
    xy = conic_centres(rim) + noise_px * PIXEL_MM * rng.standard_normal((k, 2))
    cams = Cameras.make(["plate-cam"], C_MM, 0.0, 0.0, ap_model="brown", ap=np.zeros((1, 7)),
                        sigma_iop=np.full(3, np.inf), sigma_ap=np.where(FREE_AP, np.inf, 0.0)[None],
                        format_mm=np.array(RESOLUTION) * PIXEL_MM, pixel_mm=PIXEL_MM, resolution=RESOLUTION)
    role = np.array(["tie"] * n, dtype=object)
    role[corners] = "full"
    # start: the truth disturbed (orientations by 2 cm and 0.5°, the points by 5 mm in the plane)
    start = XYZ + np.where(role[:, None] == "full", 0.0, 0.005 * rng.standard_normal((n, 3)) * [1, 1, 0])
    points = Points.make([f"D{i:03d}" for i in range(n)], start, role)
    photos = Photos.make([f"P{j + 1:02d}" for j in range(m)], 0, X0 + 0.02 * rng.standard_normal((m, 3)),
                         opk + np.radians(0.5) * rng.standard_normal((m, 3)))
    obs = Observations.make(ph, pt, xy, sigma=sigma_px * PIXEL_MM)
    circles = CircleTargets.make(points.ids, diameter, normals)
    block = Block(cams, photos, points, obs, circles=circles)
    return block, {"cam": cam, "X0": X0, "opk": opk, "XYZ": XYZ}


def calibrate(block, truth, mode: str = "rim"):
    """The bundle (datum on the four control dots) without the correction (``mode = "off"``) or with it
    (``"centre"``, ``"rim"``: `EccentricityConfig.distortion`); returns the report and the differences
    to the truth of ``PARAMS`` in σ."""
    ecc = EccentricityConfig(enabled=mode != "off", distortion="centre" if mode == "off" else mode)
    rep = adjust(block, BundleConfig(datum="control", eccentricity=ecc))
    res = rep.result
    names = list(res.cam_param_names[0])
    cols = [names.index(p) for p in PARAMS]
    est = res.state.cam_params[0, cols]
    true = truth["cam"][[0, 1, 2, 3, 4, 6, 7]]
    sig = np.sqrt(np.diag(res.cov_cameras[0]))[cols]
    return rep, (est - true) / sig


def explained_by_eccentricity(off, on) -> float:
    """Share of the uncorrected vᵀPv that the corrections (at the corrected solution) explain: the
    residuals regressed on them, per coordinate."""
    v = off.result.residuals.ravel()
    e = on.eccentricity.final.correction.ravel()
    b = (v @ e) / (e @ e)
    return float(1 - ((v - b * e) ** 2).sum() / (v ** 2).sum())


def residual_figure(rep, path: Path, title: str, photos, scale_px: float = 0.1):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    block = rep.block
    obs = block.observations
    v = rep.result.residuals / PIXEL_MM                  # px, x right, y up
    uv = obs.xy / PIXEL_MM
    fig, axs = plt.subplots(2, 3, figsize=(13, 7.2))
    arrow = 0.08 * RESOLUTION[0] / scale_px              # format pixels per residual pixel
    for ax, j in zip(axs.ravel(), photos):
        s = obs.photo == j
        ax.quiver(uv[s, 0], uv[s, 1], v[s, 0] * arrow, v[s, 1] * arrow, angles="xy", scale_units="xy", scale=1,
                  width=0.004, color="C0")
        rms = np.sqrt((v[s] ** 2).sum(axis=1).mean())
        ax.set_title(f"photo {block.photos.ids[j]}: RMS {rms:.3f} px", fontsize=9)
        w = block.observations.point[s] >= 99
        ax.plot(uv[s][w, 0], uv[s][w, 1], "o", ms=2, color="C1", label="dots on the wall")
        ax.set_xlim(-RESOLUTION[0] / 2, RESOLUTION[0] / 2)
        ax.set_ylim(-RESOLUTION[1] / 2, RESOLUTION[1] / 2)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    axs.ravel()[0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"{title}: image residuals (observed − computed, px, x right, y up); an arrow of 8 % of the "
                 f"format is {scale_px} px", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise-px", type=float, default=0.02)
    ap.add_argument("--seeds", type=int, default=8, help="noise realisations for the mean bias")
    ap.add_argument("--figures", type=Path)
    args = ap.parse_args(argv)
    modes = ("off", "centre", "rim")
    out = {}
    for wall in (False, True):
        block, truth = plate_block(np.random.default_rng(0), args.noise_px, wall=wall)
        print(f"\n== {'plate and wall' if wall else 'plate only'}: {len(block.photos)} photos, {len(block.points)} "
              f"dots of {DIAMETER} m, {len(block.observations)} image points, noise {args.noise_px} px ==")
        reps = {m: calibrate(block, truth, m) for m in modes}
        e = reps["rim"][0].eccentricity.final.correction / PIXEL_MM
        d = (reps["rim"][0].eccentricity.final.correction - reps["centre"][0].eccentricity.final.correction) / PIXEL_MM
        print(f"eccentricity: RMS {np.sqrt((e ** 2).mean()):.3f} px, largest {np.abs(e).max():.3f} px; rim − centre "
              f"RMS {np.sqrt((d ** 2).mean()):.4f} px, largest {np.abs(d).max():.4f} px")
        z = {m: [reps[m][1]] for m in modes}
        for seed in range(1, args.seeds):
            b, t = plate_block(np.random.default_rng(seed), args.noise_px, wall=wall)
            for m in modes:
                z[m].append(calibrate(b, t, m)[1])
        print(f"difference to the truth / σ, mean (RMS) over {args.seeds} noise realisations; σ̂0 of the first")
        print(f"{'':24s} " + " ".join(f"{p:>13s}" for p in PARAMS) + "    σ̂0")
        for m in modes:
            zz = np.array(z[m])
            lab = {"off": "without the correction", "centre": "corrected, centre", "rim": "corrected, rim"}[m]
            print(f"{lab:24s} " + " ".join(f"{a:+6.2f} ({b:4.2f})" for a, b in
                                           zip(zz.mean(axis=0), np.sqrt((zz ** 2).mean(axis=0))))
                  + f"  {reps[m][0].result.sigma0_hat:.3f}")
        out[wall] = reps, z
        if args.figures and wall:
            args.figures.mkdir(parents=True, exist_ok=True)
            off = reps["off"][0]
            v = off.result.residuals
            ph = off.block.observations.photo
            rms = np.array([np.sqrt((v[ph == j] ** 2).sum(axis=1).mean()) for j in range(len(off.block.photos))])
            worst = np.sort(np.argsort(-rms)[:6])                # the photos with the largest RMS, both figures
            residual_figure(off, args.figures / "eccentricity-plate-residuals-uncorrected.png",
                            "Without the correction", worst)
            residual_figure(reps["rim"][0], args.figures / "eccentricity-plate-residuals-corrected.png",
                            "With the correction (distortion = rim)", worst)
    return out


if __name__ == "__main__":
    main()
