"""Time the bundle's rerun recording of a simulated aerial block (issue 22, "Recordings that scale").

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/recording.py [--photos 2000] [--out DIR]

Simulates the block of ``benchmarks/scale.py`` (:func:`baarda.pipeline.synthetic.aerial.simulate_aerial`,
``layout(photos)``), adjusts it with the bundle workflow (control datum, covariances on, so the
recording holds every point's ellipsoid), then times only what the bundle stage's ``log`` does:
:func:`baarda.plugins.bundle.rrlog.log_bundle` into a file and ``disconnect`` (blueprint, footer).
It checks the file with ``rerun rrd verify`` and reads it back with ``read_recording``.  The
adjustment itself takes minutes at 10 000 photos; only the recording is timed.  Numbers:
``docs/recordings.md`` ("At scale").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    import numpy as np

    from baarda.pipeline.adjustment import BundleConfig, adjust_block
    from baarda.pipeline.recording import new_recording_id, open_recording, read_recording
    from baarda.pipeline.synthetic.aerial import simulate_aerial
    from baarda.plugins.bundle.rrlog import log_bundle

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from scale import layout

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photos", type=int, default=2000)
    p.add_argument("--out", default=None, help="folder for bundle.rrd (default: a temporary one)")
    a = p.parse_args(argv)
    strips, per_strip = layout(a.photos)
    noisy, _ = simulate_aerial(np.random.default_rng(1), n_strips=strips, photos_per_strip=per_strip)
    t = time.perf_counter()
    rep = adjust_block(noisy, BundleConfig())
    print(f"adjustment: {time.perf_counter() - t:.1f} s; {len(rep.block.photos)} photos, "
          f"{len(rep.block.points)} points, {len(rep.block.observations)} image points", flush=True)
    import tempfile

    out = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="baarda-rec-"))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bundle.rrd"
    path.unlink(missing_ok=True)
    t0 = time.perf_counter()
    rec = open_recording(path, new_recording_id())
    log_bundle(rec, rep, "")
    t1 = time.perf_counter()
    rec.disconnect()
    t2 = time.perf_counter()
    print(f"recording: log {t1 - t0:.2f} s + disconnect {t2 - t1:.2f} s = {t2 - t0:.2f} s; "
          f"{os.path.getsize(path) / 1e6:.1f} MB ({path})", flush=True)
    rerun = Path(sys.executable).with_name("rerun")
    v = subprocess.run([str(rerun), "rrd", "verify", str(path)], capture_output=True, text=True)
    print("rerun rrd verify:", "ok" if v.returncode == 0 else v.stderr.strip().splitlines()[-1])
    t = time.perf_counter()
    r = read_recording(path)
    print(f"read back in {time.perf_counter() - t:.1f} s: {len(r.entities)} entities, {len(r.views)} views")
    return 0 if v.returncode == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
