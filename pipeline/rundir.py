"""Run directories that never lose data.

A run is written into a fresh *staging* directory beside its target (``.<name>.partial-<random>``,
on the same file system) and moved into place only when it ends:

* **complete** (every stage ok) — the staging directory replaces the target.  A target that
  holds an earlier baarda run is replaced only when every file in it is one that run recorded
  having written (its ``results.json`` lists them); anything else there stops the run *before*
  it starts, naming the file.  A non-empty directory that is not a baarda run is refused.
* **failed** (a stage failed or the run was interrupted) — the staging directory becomes the
  target if the target holds no complete run; a complete earlier run is left untouched and the
  failed one goes beside it as ``<name>.failed``.

``results.json`` is written last, after every other file, and lists every file of the run
(``files``).  A staging directory carries the marker ``.baarda-incomplete`` (the process id and
start time) while it is written: a run killed without a chance to clean up is recognisable by the
marker and by its name, and the next run into the same target removes it once its process is gone.

**One run at a time per target.**  :func:`open_run` takes an exclusive ``flock`` on the lock file
``.<name>.lock`` beside the target (it records the process id and host) and :func:`close_run`
releases and removes it.  A second run into the same ``--out`` while the first one runs is refused
by name (an :class:`InputError` naming the other run's process and host).  The kernel drops a
``flock`` when its process ends, however it ends, so a lock file left by a killed run is stale by
construction: the next run takes it over.  When a run ends the target is examined again: a failed
run never replaces a complete run, even one that appeared while it ran.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError

RUN_MARKER = "results.json"
INCOMPLETE_MARKER = ".baarda-incomplete"


@dataclass
class RunTarget:
    """Where a run goes and what was there before."""

    target: Path
    staging: Path
    previous: str            # "none" | "empty" | "complete" | "failed"
    lock: "RunLock | None" = None


def lock_path(target: Path) -> Path:
    """The lock file of run directory ``target``: ``.<name>.lock`` beside it."""
    return target.with_name(f".{target.name}.lock")


class RunLock:
    """An exclusive ``flock`` on ``.<name>.lock`` beside a run directory (see the module text).

    The file carries ``{"pid", "host", "started"}`` for the message a second run prints.  The lock
    dies with its process (``flock`` belongs to the open file), so there is no stale lock to break:
    a leftover file whose lock nobody holds is simply taken over.
    """

    def __init__(self, target: Path):
        self.target = target
        self.path = lock_path(target)
        self.fd: int | None = None

    def acquire(self) -> "RunLock":
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _lock_holder(fd)
                os.close(fd)
                raise InputError(f"another baarda run ({holder}) is writing this run directory; wait for it "
                                 "to end or choose another --out", path=self.target) from None
            except OSError:
                os.close(fd)
                raise
            # the holder before us may have removed the file between our open and our flock: a
            # lock on an unlinked file locks nothing — open the path again
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                 "started": time.strftime("%Y-%m-%dT%H:%M:%S")}).encode())
        self.fd = fd
        return self

    def release(self) -> None:
        if self.fd is None:
            return
        try:
            try:
                self.path.unlink()          # while we hold it: nobody else holds this file
            except FileNotFoundError:
                pass
        finally:
            os.close(self.fd)               # closing drops the flock
            self.fd = None


def _lock_holder(fd: int) -> str:
    """``process 123 on host`` from a lock file, as far as it says."""
    try:
        data = json.loads(os.pread(fd, 4096, 0).decode("utf-8") or "{}")
        who = f"process {int(data['pid'])}"
        if data.get("host"):
            who += f" on {str(data['host'])[:64]}"
        if data.get("started"):
            who += f", started {str(data['started'])[:32]}"
        return who
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "a process that is still running"


def _run_manifest(path: Path) -> dict | None:
    """The ``results.json`` of a baarda run directory, or None when ``path`` is not one."""
    f = path / RUN_MARKER
    if not f.is_file():
        return None
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(data, dict) or "baarda_version" not in data or not isinstance(data.get("stages"), list):
        return None
    return data


def _files_under(path: Path) -> list[str]:
    """Every file below ``path`` as a relative POSIX path (folders implied)."""
    out = []
    for root, _dirs, files in os.walk(path):
        for name in files:
            out.append((Path(root) / name).relative_to(path).as_posix())
    return sorted(out)


def recorded_files(manifest: dict) -> set[str]:
    """What a run recorded having written: its ``files`` list (or, for runs written before that
    list existed, the stages' files and the runner's own)."""
    if isinstance(manifest.get("files"), list):
        return {str(f) for f in manifest["files"]}
    names = {RUN_MARKER, "report.md", "project.resolved.toml"}
    for s in manifest.get("stages", []):
        if isinstance(s, dict):
            names.update(str(f) for f in s.get("files") or [])
            names.add(f"{s.get('id')}.error.txt")
    return names


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def stale_partials(target: Path) -> list[Path]:
    """Staging directories of ``target`` left by runs whose process is gone (interrupted runs)."""
    stale = []
    for p in target.parent.glob(f".{target.name}.partial-*"):
        marker = p / INCOMPLETE_MARKER
        if not (p.is_dir() and marker.is_file()):
            continue
        try:
            pid = int(json.loads(marker.read_text(encoding="utf-8")).get("pid", -1))
        except (OSError, ValueError, AttributeError, json.JSONDecodeError):
            pid = -1
        if pid <= 0 or not _pid_alive(pid):
            stale.append(p)
    return stale


def open_run(target: str | Path) -> RunTarget:
    """Check ``target`` and create the staging directory of a new run (nothing is removed yet,
    but interrupted runs' staging directories of the same target)."""
    target = Path(target).expanduser().absolute()
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot write the run directory: {e.strerror or e}", path=target) from None
    try:
        lock = RunLock(target).acquire()
    except OSError as e:
        raise InputError(f"cannot lock the run directory: {e.strerror or e}", path=target) from None
    try:
        return _open_locked(target, lock)
    except BaseException:
        lock.release()
        raise


def _open_locked(target: Path, lock: RunLock) -> RunTarget:
    previous = "none"
    if target.exists() or target.is_symlink():
        if not target.is_dir():
            raise InputError("the run directory exists and is not a directory; choose another --out", path=target)
        entries = list(target.iterdir())
        if entries:
            manifest = _run_manifest(target)
            if manifest is None:
                raise InputError("refusing to write into a non-empty directory that is not a baarda run "
                                 "directory; choose another --out", path=target)
            foreign = sorted(set(_files_under(target)) - recorded_files(manifest))
            if foreign:
                raise InputError(f"the earlier run here holds '{foreign[0]}'"
                                 + (f" and {len(foreign) - 1} more file(s)" if len(foreign) > 1 else "")
                                 + ", which baarda did not write; move it away or choose another --out",
                                 path=target)
            previous = "complete" if manifest.get("ok") is True else "failed"
        else:
            previous = "empty"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        for p in stale_partials(target):
            shutil.rmtree(p, ignore_errors=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
        (staging / INCOMPLETE_MARKER).write_text(json.dumps({
            "pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%S"), "target": str(target)}),
            encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot write the run directory: {e.strerror or e}", path=target) from None
    return RunTarget(target=target, staging=staging, previous=previous, lock=lock)


def list_files(staging: Path) -> list[str]:
    """The run's files (for ``results.json``), without the staging marker, with ``results.json``."""
    files = set(_files_under(staging)) - {INCOMPLETE_MARKER}
    files.add(RUN_MARKER)
    return sorted(files)


def _swap(new: Path, dest: Path) -> None:
    """Put directory ``new`` at ``dest``; an existing ``dest`` (checked by :func:`open_run`, or a
    ``.failed`` run of ours) is moved aside first and removed after."""
    old = None
    if dest.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old-", dir=dest.parent))
        os.rename(dest, old / "run")
    os.rename(new, dest)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def close_run(run: RunTarget, ok: bool) -> Path:
    """Move the finished staging directory into place; returns where the run now is.  Releases
    the run's lock."""
    try:
        return _close_locked(run, ok)
    finally:
        if run.lock is not None:
            run.lock.release()


def final_place(run: RunTarget, ok: bool) -> Path:
    """Where :func:`close_run` will put the run: the target, or ``<name>.failed`` beside a complete
    run (the one found at the start, or one that appeared since)."""
    if ok:
        return run.target
    manifest = _run_manifest(run.target)
    if run.previous == "complete" or (manifest is not None and manifest.get("ok") is True):
        return run.target.with_name(run.target.name + ".failed")
    return run.target


def _close_locked(run: RunTarget, ok: bool) -> Path:
    marker = run.staging / INCOMPLETE_MARKER
    if marker.exists():
        marker.unlink()
    dest = final_place(run, ok)
    if dest != run.target:
        if dest.exists() and _run_manifest(dest) is None:        # not ours: keep the run where it is
            dest = run.target.with_name(f"{run.target.name}.failed-{time.strftime('%Y%m%d-%H%M%S')}")
            if dest.exists():
                return run.staging
    # the target was checked when the run opened; check again in case something appeared since
    if dest.exists() and any(dest.iterdir()):
        manifest = _run_manifest(dest)
        if manifest is None or set(_files_under(dest)) - recorded_files(manifest):
            return run.staging
    _swap(run.staging, dest)
    return dest
