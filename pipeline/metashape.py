"""Agisoft Metashape camera export (XML) ↔ :class:`~baarda.pipeline.model.Block`.

Metashape's frame-camera model (user manual, appendix *Camera models*), camera frame x right, y down,
z forward, ``x = X/Z``, ``y = Y/Z``, ``r² = x² + y²``::

    x' = x (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + (P1 (r² + 2x²) + 2 P2 x y)(1 + P3 r² + P4 r⁴)
    y' = y (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + (P2 (r² + 2y²) + 2 P1 x y)(1 + P3 r² + P4 r⁴)
    u = W/2 + cx + x' f + x' B1 + y' B2,      v = H/2 + cy + y' f

pixels ``(u, v)`` from the top-left *corner* of the image (baarda's ``"colmap"`` pixel convention).
With a pixel pitch ``p`` this is baarda's ``brown`` model exactly (``docs/metashape-opensfm.md``)::

    c = f p,  xp = cx p,  yp = −cy p,  K1 = k1/c²,  K2 = k2/c⁴,  K3 = k3/c⁶,  P1 = p1/c,  P2 = −p2/c,
    B1 = b1/f,  B2 = −b2/f

except that Metashape applies b1, b2 to the *distorted* x', y' and baarda's brown to the ideal ones:
b1 or b2 together with distortion, and k4, p3, p4, are refused by name (no exact counterpart).

Poses: a camera's ``<transform>`` is the 4×4 camera → chunk matrix; the chunk's ``<transform>``
(``rotation`` R, ``translation`` t, ``scale`` s) maps chunk → world: ``X = s R x + t``.  The block is
in the world frame (the chunk frame when the chunk has no transform).  Markers: reference
coordinates (``<reference x y z enabled>``) become control points (in a georeferenced chunk the
chunk transform maps to geocentric coordinates, and block and references go to a local east-north-up
frame, ``docs/crs.md``); their projections (``<frames><frame><markers><marker marker_id><location camera_id x y>``)
the observations.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from baarda.pipeline.camera.convert import BROWN
from baarda.pipeline.errors import InputError, quote
from baarda.pipeline.geometry.image import mm_from_pixels, pixels_from_mm
from baarda.pipeline.geometry.pose import cv_from_pose, pose_from_cv
from baarda.pipeline.model import FIXED, FREE, Block, Cameras, Observations, Photos, Points, SourceInfo

CALIB_TERMS = ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2", "p3", "p4")
REFUSED = ("k4", "p3", "p4")


def _parse(path: Path):
    from defusedxml import DefusedXmlException
    from defusedxml import ElementTree as ET
    from xml.etree.ElementTree import ParseError

    from baarda.pipeline.xmlsafe import refusal

    try:
        return ET.parse(str(path)).getroot()
    except FileNotFoundError:
        raise InputError("Metashape XML not found", path=path) from None
    except ParseError as e:
        line = e.position[0] if getattr(e, "position", None) else None
        raise InputError(f"not well-formed XML: {e}", path=path, line=line, field="xml") from None
    except DefusedXmlException as e:       # defusedxml refuses entities and external references
        raise refusal(e, path) from None
    except (OSError, ValueError) as e:      # a folder, an unreadable file, bytes that are no text
        raise InputError(f"cannot read the file as XML: {e.strerror if isinstance(e, OSError) else e}",
                         path=path, field="xml") from None


def _float(text, path, where, field, *, positive=False):
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {field} must be a number, got {text!r}", path=path, field=f"{where}/{field}") \
            from None
    if not math.isfinite(v) or (positive and v <= 0):
        raise InputError(f"{where}: {field} must be a finite{' positive' if positive else ''} number, got {text!r}",
                         path=path, field=f"{where}/{field}")
    return v


def _floats(text, n, path, where, field):
    parts = (text or "").split()
    if len(parts) != n:
        raise InputError(f"{where}: {field} must hold {n} numbers, got {len(parts)}", path=path,
                         field=f"{where}/{field}")
    return np.array([_float(p, path, where, field) for p in parts])


def brown_from_metashape(cal: dict, pixel_mm: float) -> dict:
    """``{c, xp, yp, ap (7,)}`` (mm, brown) of Metashape calibration terms (pixels; see the module docstring).

    Raises ValueError naming the term that has no exact counterpart."""
    v = {k: float(cal.get(k, 0.0)) for k in CALIB_TERMS}
    for k in REFUSED:
        if v[k] != 0.0:
            raise ValueError(f"{k} = {v[k]:g} has no exact counterpart in baarda's brown model (only 0 is read)")
    dist = any(v[k] != 0.0 for k in ("k1", "k2", "k3", "p1", "p2"))
    if dist and (v["b1"] != 0.0 or v["b2"] != 0.0):
        bad = "b1" if v["b1"] != 0.0 else "b2"
        raise ValueError(f"{bad} = {v[bad]:g} together with distortion has no exact counterpart in baarda's brown "
                         "model (Metashape applies it to the distorted coordinates)")
    f = v["f"]
    c = f * pixel_mm
    ap = np.array([v["k1"] / c**2, v["k2"] / c**4, v["k3"] / c**6, v["p1"] / c, -v["p2"] / c,
                   v["b1"] / f, -v["b2"] / f], float)
    return {"c": c, "xp": v["cx"] * pixel_mm, "yp": -v["cy"] * pixel_mm, "ap": ap}


METASHAPE_AP = ("K1", "K2", "K3", "K4", "P1", "P2", "P3", "P4", "B1", "B2")
"""Columns of ``Cameras.ap`` for the ``metashape`` AP model (:mod:`baarda.pipeline.camera.metashape_model`)."""


def metashape_ap_from_terms(cal: dict, pixel_mm: float) -> dict:
    """``{c, xp, yp, ap (10,)}`` of the ``metashape`` AP model: every Metashape term, exactly."""
    v = {k: float(cal.get(k, 0.0)) for k in CALIB_TERMS}
    f = v["f"]
    c = f * pixel_mm
    ap = np.array([v["k1"] / c**2, v["k2"] / c**4, v["k3"] / c**6, v["k4"] / c**8, v["p1"] / c, -v["p2"] / c,
                   v["p3"] / c**2, v["p4"] / c**4, v["b1"] / f, -v["b2"] / f], float)
    return {"c": c, "xp": v["cx"] * pixel_mm, "yp": -v["cy"] * pixel_mm, "ap": ap}


def terms_from_metashape_ap(c, xp, yp, ap, pixel_mm) -> dict:
    """Inverse of :func:`metashape_ap_from_terms`."""
    K1, K2, K3, K4, P1, P2, P3, P4, B1, B2 = np.asarray(ap, float)
    f = c / pixel_mm
    return {"f": f, "cx": xp / pixel_mm, "cy": -yp / pixel_mm, "b1": B1 * f, "b2": -B2 * f,
            "k1": K1 * c**2, "k2": K2 * c**4, "k3": K3 * c**6, "k4": K4 * c**8, "p1": P1 * c, "p2": -P2 * c,
            "p3": P3 * c**2, "p4": P4 * c**4}


def metashape_from_brown(c, xp, yp, ap, pixel_mm) -> dict:
    """Metashape calibration terms (pixels) of a brown camera (inverse of :func:`brown_from_metashape`)."""
    ap = np.concatenate([np.asarray(ap if ap is not None else [], float), np.zeros(7)])[:7]
    K1, K2, K3, P1, P2, B1, B2 = ap
    f = c / pixel_mm
    if (B1 or B2) and (K1 or K2 or K3 or P1 or P2):
        raise ValueError("brown B1/B2 together with distortion has no exact Metashape counterpart")
    return {"f": f, "cx": xp / pixel_mm, "cy": -yp / pixel_mm, "b1": B1 * f, "b2": -B2 * f,
            "k1": K1 * c**2, "k2": K2 * c**4, "k3": K3 * c**6, "p1": P1 * c, "p2": -P2 * c}


def read_metashape(path: str | Path, *, pixel_mm: float = 0.001, sigma_px: float = 1.0,
                   sigma_control_mm=(10.0, 10.0, 10.0), intrinsics: str = "metashape",
                   ap_model: str = "brown") -> tuple[Block, dict]:
    """Read a Metashape camera export (``<document><chunk>…``) as a block (see the module docstring).

    ``pixel_mm`` is used when a sensor has no ``<property name="pixel_width">``.  ``intrinsics``:
    ``"metashape"`` frees the terms the file calibrates (non-zero) and f, ``"fixed"`` none, ``"free"``
    all terms and the principal point.  ``ap_model``: ``"brown"`` (k4, p3, p4 and b1/b2 with
    distortion refused by name) or ``"metashape"`` (every term, :mod:`~baarda.pipeline.camera.metashape_model`).
    """
    if ap_model not in ("brown", "metashape"):
        raise ValueError(f"ap_model must be 'brown' or 'metashape', got {ap_model!r}")
    path = Path(path)
    if intrinsics not in ("metashape", "fixed", "free"):
        raise ValueError(f"intrinsics must be 'metashape', 'fixed' or 'free', got {intrinsics!r}")
    root = _parse(path)
    chunk = root if root.tag == "chunk" else root.find("chunk")
    if root.tag not in ("document", "chunk") or chunk is None:
        raise InputError(f"expected <document><chunk>, got <{root.tag}>", path=path, field="document/chunk")
    sensors = chunk.find("sensors")
    if sensors is None or not sensors.findall("sensor"):
        raise InputError("no <sensors><sensor> in the chunk", path=path, field="chunk/sensors")
    cam_ids, cams, cal_names = [], [], []
    for s in sensors.findall("sensor"):
        sid = s.get("id")
        where = f"sensor[@id='{sid}']"
        if sid is None:
            raise InputError("a <sensor> has no id", path=path, field="sensor/@id")
        if s.get("type", "frame") != "frame":
            raise InputError(f"{where}: sensor type {s.get('type')!r} is not supported (frame only; fisheye, "
                             "spherical and cylindrical are refused)", path=path, field=f"{where}/@type")
        cal = s.find("calibration[@class='adjusted']")
        cal = s.find("calibration") if cal is None else cal
        if cal is None:
            raise InputError(f"{where}: no <calibration>", path=path, field=f"{where}/calibration")
        res = cal.find("resolution") if cal.find("resolution") is not None else s.find("resolution")
        if res is None:
            raise InputError(f"{where}: no <resolution width height>", path=path, field=f"{where}/resolution")
        W = _float(res.get("width"), path, where, "resolution/@width", positive=True)
        H = _float(res.get("height"), path, where, "resolution/@height", positive=True)
        terms = {}
        for k in CALIB_TERMS:
            e = cal.find(k)
            if e is not None:
                terms[k] = _float(e.text, path, where, f"calibration/{k}", positive=(k == "f"))
        if "f" not in terms:
            raise InputError(f"{where}: calibration has no <f>", path=path, field=f"{where}/calibration/f")
        pitch = pixel_mm
        for prop in s.findall("property"):
            if prop.get("name") == "pixel_width":
                pitch = _float(prop.get("value"), path, where, "property[@name='pixel_width']/@value", positive=True)
        try:
            b = brown_from_metashape(terms, pitch)
        except ValueError as e:
            if ap_model == "brown":
                bad = str(e).split(" ")[0]
                raise InputError(f"{where}: {e}; read it with ap_model = 'metashape'", path=path,
                                 field=f"{where}/calibration/{bad}") from None
            b = None
        if ap_model == "metashape":
            b = metashape_ap_from_terms(terms, pitch)
        cam_ids.append(sid)
        cams.append((b, (int(W), int(H)), pitch, terms, s.get("label", sid)))
    n = len(cams)
    names = METASHAPE_AP if ap_model == "metashape" else BROWN
    sig_ap = np.full((n, len(names)), FIXED)
    for k, (b, _, _, terms, _) in enumerate(cams):
        for j, name in enumerate(names):
            if intrinsics == "free" or (intrinsics == "metashape" and b["ap"][j] != 0.0):
                sig_ap[k, j] = FREE
    sig_iop = np.array([[0.0 if intrinsics == "fixed" else FREE] + [FREE if intrinsics == "free" else FIXED] * 2] * n)
    cameras = Cameras(ids=np.array(cam_ids, dtype=str), c=[x[0]["c"] for x in cams], xp=[x[0]["xp"] for x in cams],
                      yp=[x[0]["yp"] for x in cams], ap_model=np.array([ap_model] * n, dtype=str),
                      ap=np.array([x[0]["ap"] for x in cams]).reshape(n, len(names)), sigma_iop=sig_iop.reshape(n, 3),
                      sigma_ap=sig_ap, format_mm=np.array([[x[1][0] * x[2], x[1][1] * x[2]] for x in cams]),
                      pixel_mm=[x[2] for x in cams], resolution=np.array([x[1] for x in cams], int).reshape(n, 2))
    cam_index = {c: k for k, c in enumerate(cam_ids)}

    # chunk → world
    s_w, R_w, t_w = 1.0, np.eye(3), np.zeros(3)
    ct = chunk.find("transform")
    if ct is None:                                  # Metashape 2: the active component's transform
        comps = chunk.find("components")
        if comps is not None:
            active = comps.get("active_id")
            for comp in comps.findall("component"):
                if comp.find("transform") is not None and (active is None or comp.get("id") == active):
                    ct = comp.find("transform")
                    break
    if ct is not None:
        if ct.find("rotation") is not None:
            R_w = _floats(ct.find("rotation").text, 9, path, "chunk/transform", "rotation").reshape(3, 3)
        if ct.find("translation") is not None:
            t_w = _floats(ct.find("translation").text, 3, path, "chunk/transform", "translation")
        if ct.find("scale") is not None:
            s_w = _float(ct.find("scale").text, path, "chunk/transform", "scale", positive=True)

    photo_ids, photo_cam, X0, opk, photo_key = [], [], [], [], {}
    cameras_el = chunk.find("cameras")
    for cam in (cameras_el.iter("camera") if cameras_el is not None else []):
        cid = cam.get("id")
        where = f"camera[@id='{cid}']"
        if cid is None:
            raise InputError("a <camera> has no id", path=path, field="camera/@id")
        if cam.get("sensor_id") not in cam_index:
            raise InputError(f"{where}: sensor_id {cam.get('sensor_id')!r} is not a <sensor>", path=path,
                             field=f"{where}/@sensor_id")
        tr = cam.find("transform")
        if tr is None or cam.get("enabled", "true") in ("false", "0"):
            continue                                    # not aligned (or disabled): no orientation
        T = _floats(tr.text, 16, path, where, "transform").reshape(4, 4)
        Rc, tc = T[:3, :3], T[:3, 3]
        if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(Rc.T @ Rc, np.eye(3), atol=1e-6):
            raise InputError(f"{where}: transform is not a rigid 4×4 camera → chunk matrix", path=path,
                             field=f"{where}/transform")
        # world point X = s R_w (Rc p + tc) + t_w  ⇒  p = Rcᵀ R_wᵀ (X − t_w)/s − Rcᵀ tc: rotation Rcᵀ R_wᵀ,
        # centre s R_w tc + t_w (the scale changes no angle)
        R_cw = Rc.T @ R_w.T
        C = s_w * (R_w @ tc) + t_w
        x0, o = pose_from_cv(R_cw, -R_cw @ C)
        photo_key[cid] = len(photo_ids)
        photo_ids.append(cam.get("label") or cid)
        photo_cam.append(cam_index[cam.get("sensor_id")])
        X0.append(x0)
        opk.append(o)
    if len(set(photo_ids)) != len(photo_ids):
        photo_ids = [f"{i}" for i in photo_key]
    photos = Photos.make(photo_ids, camera=np.array(photo_cam, int), X0=np.array(X0).reshape(-1, 3),
                         opk=np.array(opk).reshape(-1, 3))

    crs_el = chunk.find("reference")
    crs = (crs_el.text or "").strip() if crs_el is not None else ""
    local_crs = not crs or crs.startswith("LOCAL_CS") or crs.lower() == "local"
    m_ids, m_xyz, m_role, m_key = [], [], [], {}
    markers_el = chunk.find("markers")
    for m in (markers_el.iter("marker") if markers_el is not None else []):
        mid = m.get("id")
        where = f"marker[@id='{mid}']"
        if mid is None:
            raise InputError("a <marker> of <markers> has no id", path=path, field="markers/marker/@id")
        ref = m.find("reference")
        xyz, role = [np.nan] * 3, "tie"
        if ref is not None and ref.get("x") is not None:
            xyz = [_float(ref.get(a), path, where, f"reference/@{a}") for a in "xyz"]
            role = "full" if ref.get("enabled", "true") not in ("false", "0") else "check"
        if mid in m_key:
            raise InputError(f"{where}: marker id {quote(mid)} is given twice", path=path, field=f"{where}/@id")
        m_key[mid] = len(m_ids)
        m_ids.append(m.get("label") or mid)
        m_xyz.append(xyz)
        m_role.append(role)
    if len(set(m_ids)) != len(m_ids):
        m_ids = list(m_key)
    m_xyz = np.array(m_xyz, float).reshape(-1, 3)
    frame_info = None
    if not local_crs:
        # georeferenced chunk: the chunk transform maps to geocentric (ECEF) coordinates of the CRS's
        # datum; the block is in a local east-north-up frame (docs/crs.md) at the references' centroid
        from baarda.pipeline.crs import LocalFrame, R_enu_from_ecef, ecef_from_geodetic, local_frame

        has_ref = np.isfinite(m_xyz).all(axis=1)
        if has_ref.any():
            frame = local_frame(crs, m_xyz[has_ref], path=path, field="chunk/reference")
        else:
            frame = local_frame("EPSG:4978", np.array(X0).reshape(-1, 3), path=path, field="chunk/reference")
            frame = LocalFrame(crs, frame.origin, frame.a, frame.f)
        if has_ref.any():
            m_xyz[has_ref] = frame.to_local(m_xyz[has_ref])
        Re = R_enu_from_ecef(frame.origin[0], frame.origin[1])
        o = ecef_from_geodetic(*frame.origin, frame.a, frame.f)
        from baarda.pipeline.geometry import rotation_from_opk_many, opk_from_rotation

        if len(X0):
            X0a = np.array(X0).reshape(-1, 3)
            Rs = rotation_from_opk_many(np.array(opk).reshape(-1, 3))       # camera ← ECEF (baarda axes)
            X0 = list((X0a - o) @ Re.T)
            opk = [opk_from_rotation(R @ Re.T) for R in Rs]
            photos = Photos.make(photos.ids, camera=photos.camera, X0=np.array(X0).reshape(-1, 3),
                                 opk=np.array(opk).reshape(-1, 3))
        frame_info = frame.info()
    sig = np.full((len(m_ids), 3), FREE)
    sig[np.array(m_role) == "full"] = np.asarray(sigma_control_mm, float) / 1000.0
    points = Points.make(m_ids, XYZ=m_xyz, role=m_role, sigma=sig)

    o_ph, o_pt, o_uv = [], [], []
    for fr in chunk.findall("frames/frame"):
        for mk in fr.findall("markers/marker"):
            mid = mk.get("marker_id")
            if mid not in m_key:
                raise InputError(f"frame marker_id {mid!r} is not a <marker>", path=path,
                                 field="frames/frame/markers/marker/@marker_id")
            for loc in mk.findall("location"):
                cid = loc.get("camera_id")
                where = f"marker[@marker_id='{mid}']/location[@camera_id='{cid}']"
                if cid not in photo_key:
                    continue                            # a camera without orientation
                if loc.get("valid", "true") in ("false", "0"):
                    continue
                o_ph.append(photo_key[cid])
                o_pt.append(m_key[mid])
                o_uv.append((_float(loc.get("x"), path, where, "@x"), _float(loc.get("y"), path, where, "@y")))
    o_ph = np.array(o_ph, int)
    cam_o = photos.camera[o_ph]
    xy = mm_from_pixels(np.array(o_uv, float).reshape(-1, 2), cameras.resolution[cam_o], cameras.pixel_mm[cam_o],
                        "colmap")
    obs = Observations.make(o_ph, np.array(o_pt, int), xy.reshape(-1, 2), sigma=sigma_px * cameras.pixel_mm[cam_o])
    block = Block(cameras, photos, points, obs, object_unit="m", crs=frame_info,
                  meta={"metashape": {"path": str(path), "crs": crs, "sensor_labels": [x[4] for x in cams],
                                      "chunk_transform": {"scale": s_w, "rotation": R_w, "translation": t_w}}},
                  source=SourceInfo(path=str(path), format="Metashape", pixel_format="Metashape"))
    info = {"crs": crs, "local_crs": local_crs,
            "unaligned_cameras": len(list(cameras_el.iter("camera"))) - len(photo_ids) if cameras_el is not None else 0}
    return block, info


def _fmt(x) -> str:
    return repr(float(x))


def write_metashape(block: Block, path: str | Path) -> dict:
    """Write ``block`` as a Metashape camera XML (chunk frame = the block's frame, no chunk transform)."""
    from xml.etree.ElementTree import Element, ElementTree, SubElement, indent

    path = Path(path)
    cm = block.cameras
    doc = Element("document", version="1.5.0")
    chunk = SubElement(doc, "chunk", label="baarda", enabled="true")
    sensors = SubElement(chunk, "sensors", next_id=str(len(cm)))
    for k, cid in enumerate(cm.ids.tolist()):
        if cm.ap_model[k] not in ("none", "brown", "metashape"):
            raise ValueError(f"camera {cid}: AP model {cm.ap_model[k]!r} has no Metashape counterpart")
        if cm.ap_model[k] == "metashape":
            terms = terms_from_metashape_ap(cm.c[k], cm.xp[k], cm.yp[k], cm.ap[k], cm.pixel_mm[k])
        else:
            ap = cm.ap[k] if cm.ap_model[k] == "brown" else np.zeros(7)
            terms = metashape_from_brown(cm.c[k], cm.xp[k], cm.yp[k], ap, cm.pixel_mm[k])
        W, H = (int(v) for v in cm.resolution[k])
        s = SubElement(sensors, "sensor", id=str(k), label=cid, type="frame")
        SubElement(s, "resolution", width=str(W), height=str(H))
        SubElement(s, "property", name="pixel_width", value=_fmt(cm.pixel_mm[k]))
        SubElement(s, "property", name="pixel_height", value=_fmt(cm.pixel_mm[k]))
        cal = SubElement(s, "calibration", type="frame", **{"class": "adjusted"})
        SubElement(cal, "resolution", width=str(W), height=str(H))
        for name in CALIB_TERMS:
            if name in ("f", "cx", "cy") or terms.get(name, 0.0) != 0.0:
                SubElement(cal, name).text = _fmt(terms[name])
    ph = block.photos
    ok = np.isfinite(ph.X0).all(axis=1) & np.isfinite(ph.opk).all(axis=1)
    R, t = cv_from_pose(ph.X0[ok], ph.opk[ok])
    cams = SubElement(chunk, "cameras", next_id=str(len(ph)))
    okk = np.flatnonzero(ok)
    for k in range(len(ph)):
        c = SubElement(cams, "camera", id=str(k), sensor_id=str(ph.camera[k]), label=str(ph.ids[k]))
        if ok[k]:
            j = int(np.searchsorted(okk, k))
            T = np.eye(4)
            T[:3, :3] = R[j].T
            T[:3, 3] = -R[j].T @ t[j]
            SubElement(c, "transform").text = " ".join(_fmt(v) for v in T.ravel())
    pts = block.points
    mk = SubElement(chunk, "markers", next_id=str(len(pts)))
    for i in range(len(pts)):
        m = SubElement(mk, "marker", id=str(i), label=str(pts.ids[i]))
        if pts.role[i] in ("full", "check") and np.isfinite(pts.XYZ[i]).all():
            SubElement(m, "reference", x=_fmt(pts.XYZ[i, 0]), y=_fmt(pts.XYZ[i, 1]), z=_fmt(pts.XYZ[i, 2]),
                       enabled="true" if pts.role[i] == "full" else "false")
    SubElement(chunk, "reference").text = 'LOCAL_CS["Local Coordinates (m)",LOCAL_DATUM["Local Datum",0],UNIT["metre",1]]'
    frames = SubElement(chunk, "frames", next_id="1")
    fm = SubElement(SubElement(frames, "frame", id="0"), "markers")
    ob = block.observations
    sel = ob.active & ok[ob.photo]
    cam = ph.camera[ob.photo]
    uv = pixels_from_mm(ob.xy, cm.resolution[cam], cm.pixel_mm[cam], "colmap")
    n_obs = 0
    for i in range(len(pts)):
        rows = np.flatnonzero(sel & (ob.point == i))
        if not rows.size:
            continue
        m = SubElement(fm, "marker", marker_id=str(i))
        for r in rows:
            SubElement(m, "location", camera_id=str(ob.photo[r]), pinned="true", x=_fmt(uv[r, 0]), y=_fmt(uv[r, 1]))
            n_obs += 1
    path.parent.mkdir(parents=True, exist_ok=True)
    indent(doc)
    ElementTree(doc).write(path, encoding="UTF-8", xml_declaration=True)
    return {"sensors": len(cm), "cameras": int(ok.sum()), "markers": len(pts), "observations": n_obs,
            "skipped_photos": ph.ids[~ok].tolist()}
