"""The columnar recording helpers: per-entity batches written with ``rr.send_columns`` hold exactly
what ``rr.log`` would have written, the blueprint's entity scan is linear, and a later stage's
layout uses what this process wrote instead of reading the file back."""

from __future__ import annotations

import time

import numpy as np
import rerun as rr

from baarda.pipeline import recording as R


def _contents(path):
    """entity → {component: values} of a file's static data (row ids left out)."""
    from rerun.chunk import RrdReader

    out = {}
    for ch in RrdReader(str(path)).stream().to_chunks():
        b = ch.to_record_batch()
        ent = out.setdefault(str(ch.entity_path), {})
        for n in b.schema.names:
            if not n.startswith("rerun.controls"):
                ent[n] = b.column(n).to_pylist()[-1]
    out.pop("/__properties", None)
    return out


def test_log_per_entity_writes_what_log_writes(tmp_path):
    rng = np.random.default_rng(3)
    lengths = [3, 0, 5, 1]
    xy = rng.normal(size=(sum(lengths), 2))
    labels = [f"p{k}" for k in range(len(xy))]
    colors = rng.integers(0, 255, (len(xy), 3)).astype(np.uint8)
    cams = rng.normal(size=(len(lengths), 3))
    paths = [f"images/{k}" for k in range(len(lengths))]

    one = R.open_recording(tmp_path / "one.rrd", "rid", stage_id="s")
    off = np.concatenate([[0], np.cumsum(lengths)])
    for k, p in enumerate(paths):
        a, b = off[k], off[k + 1]
        one.log(p, rr.Points2D(xy[a:b], labels=labels[a:b], colors=colors[a:b], radii=rr.Radius.ui_points(3.0)),
                static=True)
        one.log(f"cams/{k}", rr.Transform3D(translation=cams[k], mat3x3=np.eye(3) * (k + 1)),
                rr.Pinhole(image_from_camera=[[2.0, 0, 1], [0, 2.0, 1], [0, 0, 1]], resolution=[2, 2],
                           camera_xyz=rr.ViewCoordinates.RUB), static=True)
    one.disconnect()

    cols = R.open_recording(tmp_path / "cols.rrd", "rid", stage_id="s")
    R.log_per_entity(cols, paths, lengths,
                     rr.Points2D.columns(positions=xy, labels=labels, colors=colors, radii=rr.Radius.ui_points(3.0)))
    K = np.tile([[2.0, 0, 1], [0, 2.0, 1], [0, 0, 1]], (len(lengths), 1, 1))
    R.log_per_entity(cols, [f"cams/{k}" for k in range(len(lengths))], np.ones(len(lengths), int),
                     rr.Transform3D.columns(translation=cams,
                                            mat3x3=np.stack([np.eye(3) * (k + 1) for k in range(len(lengths))])),
                     rr.Pinhole.columns(image_from_camera=K, resolution=np.full((len(lengths), 2), 2.0),
                                        camera_xyz=rr.ViewCoordinates.RUB))
    assert cols.logged["s/images/0"] == {"Points2D"}
    assert cols.logged["s/cams/2"] == {"Transform3D", "Pinhole"}
    cols.disconnect()

    a, b = _contents(tmp_path / "one.rrd"), _contents(tmp_path / "cols.rrd")
    assert set(a) == set(b) and len(a) == 2 * len(lengths)
    for ent in a:
        assert a[ent] == b[ent], ent


def test_log_per_entity_checks_lengths(tmp_path):
    rec = R.open_recording(tmp_path / "x.rrd", "rid", stage_id="s")
    try:
        import pytest

        with pytest.raises(ValueError, match="values for 4 instances"):
            R.log_per_entity(rec, ["a", "b"], [2, 2], rr.Points2D.columns(positions=np.zeros((3, 2))))
        with pytest.raises(ValueError, match="2 entities but 1 lengths"):
            R.log_per_entity(rec, ["a", "b"], [2], rr.Points2D.columns(positions=np.zeros((2, 2))))
    finally:
        rec.disconnect()


def test_top_entities_is_linear_and_right():
    paths = ["w/points", "w/points/precision", "w/photos/a", "w/photos/b", "w/photos/b/x", "w/photosX"]
    assert R.top_entities(paths) == ["w/photos/a", "w/photos/b", "w/photosX", "w/points"]
    big = [f"w/photos/{k:05d}" for k in range(20000)] + [f"w/photos/{k:05d}/sub" for k in range(20000)]
    t = time.perf_counter()
    tops = R.top_entities(big)
    assert time.perf_counter() - t < 2.0          # the quadratic scan took minutes here
    assert len(tops) == 20000 and all(not p.endswith("/sub") for p in tops)


def test_later_stage_layout_does_not_read_back_what_this_process_wrote(tmp_path, monkeypatch):
    first = R.open_recording(tmp_path / "a.rrd", "rid")
    first.log("world/points", rr.Points3D(np.zeros((2, 3))), static=True)
    R.log_text(first, "summary", "text")
    first.disconnect()
    from_memory = R.earlier_stages(tmp_path / "b.rrd", "rid")
    R._MANIFESTS.clear()
    from_file = R.earlier_stages(tmp_path / "b.rrd", "rid")
    assert [s for s, _ in from_memory] == [s for s, _ in from_file] == ["a"]
    assert from_memory[0][1]["a/world/points"] == from_file[0][1]["a/world/points"] == {"Points3D"}
    assert from_memory[0][1]["a/summary"] == from_file[0][1]["a/summary"] == {"TextDocument"}
    assert R.earlier_stages(tmp_path / "b.rrd", "other") == []
    # a file changed after it was written is read again
    R._remember_manifest(tmp_path / "a.rrd", "rid", {"a/fake": {"Points3D"}})
    (tmp_path / "a.rrd").write_bytes((tmp_path / "a.rrd").read_bytes() + b"")
    import os

    os.utime(tmp_path / "a.rrd", ns=(1, 1))
    assert "a/fake" not in R.earlier_stages(tmp_path / "b.rrd", "rid")[0][1]


def test_log_on_timeline_one_row_per_group(tmp_path):
    lengths = [2, 0, 3]
    xy = np.arange(10, dtype=float).reshape(5, 2)
    rec = R.open_recording(tmp_path / "t.rrd", "rid", stage_id="s")
    R.log_on_timeline(rec, "images/all/observed", "photo", lengths,
                      rr.Points2D.columns(positions=xy, radii=rr.Radius.ui_points(3.0)))
    assert rec.logged["s/images/all/observed"] == {"Points2D"}
    rec.disconnect()
    from rerun.chunk import RrdReader

    rows = []
    for ch in RrdReader(str(tmp_path / "t.rrd")).stream().to_chunks():
        if str(ch.entity_path) == "/s/images/all/observed":
            b = ch.to_record_batch()
            rows += list(zip(b.column("photo").to_pylist(), b.column("Points2D:positions").to_pylist(),
                             b.column("Points2D:radii").to_pylist()))
    rows.sort(key=lambda r: r[0])
    assert [r[0] for r in rows] == [0, 1, 2]
    assert [len(r[1]) for r in rows] == lengths
    assert rows[2][1] == [[4.0, 5.0], [6.0, 7.0], [8.0, 9.0]]
    assert all(r[2] == [-3.0] for r in rows)          # the splat radius on every step
    views = R.read_recording(tmp_path / "t.rrd").views
    assert [v.origin for v in views if v.kind == "2D"] == ["/s/images/all"]


def test_log_block_above_the_entity_limit_draws_centres(tmp_path, monkeypatch):
    from baarda.pipeline.synthetic.aerial import simulate_aerial

    block, _ = simulate_aerial(np.random.default_rng(0), n_strips=2, photos_per_strip=3, points_per_photo=20)
    few = R.open_recording(tmp_path / "few.rrd", "rid", stage_id="s")
    R.log_block(few, block)
    assert few.logged["s/block/photos/" + R.entity_part(block.photos.ids[0])] == {"Transform3D", "Pinhole"}
    few.disconnect()
    monkeypatch.setattr(R, "ENTITIES_MAX", 3)
    many = R.open_recording(tmp_path / "many.rrd", "rid", stage_id="s")
    R.log_block(many, block)
    assert many.logged["s/block/photos"] == {"Points3D"}
    assert not any(p.startswith("s/block/photos/") for p in many.logged)
    assert any("6 oriented photos" in n for n in many.notes)
    many.disconnect()
