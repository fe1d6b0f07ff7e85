"""Errors a user can act on.

Every mistake in a user's input raises :class:`InputError`, which names the file, the line and
the field.  The command line prints ``str(error)`` as one line and exits with status 2; it never
shows a traceback for these.  :class:`AdjustmentError` is raised when an adjustment cannot be
solved (singular or under-determined normal equations, no convergence); its message says which
datum or parameter is missing.
"""

from __future__ import annotations

from pathlib import Path


class BaardaError(Exception):
    """Base class of all errors the command line reports without a traceback."""


class InputError(BaardaError):
    """A user's input is wrong: a file, a line, a field.

    Parameters
    ----------
    message : str
        What is wrong, in the user's words (``"expected a number, got 'l2.5'"``).
    path : str or Path, optional
        The file.
    line : int, optional
        1-based line number in that file.
    field : str, optional
        The field, column or option name.
    """

    def __init__(self, message: str, path: str | Path | None = None,
                 line: int | None = None, field: str | None = None):
        self.message = message
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path
            if self.line is not None:
                where += f":{self.line}"
        fld = self.field
        if fld is not None and not fld.isprintable():
            fld = f"of {len(fld)} characters"                    # never a file's contents
        elif fld is not None and len(fld) > 40:                  # a long element path: its end names the field
            tail = fld[-39:]
            fld = "…" + (tail[tail.index("/"):] if "/" in tail else tail)
        parts = [p for p in (where, f"field '{fld}'" if fld else "") if p]
        prefix = ", ".join(parts)
        return f"{prefix}: {self.message}" if prefix else self.message


class AdjustmentError(BaardaError):
    """An adjustment cannot be computed: singular system, missing datum, no convergence.

    ``state`` may carry the last iterate so that the caller can save it, ``history`` the iterations
    that led to it (a :class:`baarda.pipeline.adjustment.Convergence`; None when the error is not one
    of convergence).
    """

    def __init__(self, message: str, state: object | None = None, history: object | None = None):
        self.state = state
        self.history = history
        super().__init__(message)


QUOTE_LIMIT = 16
"""Longest piece of an input file a message quotes; longer pieces are described, never printed."""


def quote(token: str) -> str:
    """A token of an input file for a message: quoted when short and printable, else described —
    a message never prints a file's contents (``path = "/etc/shadow"`` must not leak a line)."""
    text = str(token)
    if len(text) <= QUOTE_LIMIT and text.isprintable():
        return repr(text)
    return f"a {len(text)}-character value"


def finite_number(tok: str, path, line: int | None, field: str) -> float:
    """A token of an input file as a finite float, or :class:`InputError` naming file, line and field."""
    import math

    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"expected a number, got {quote(tok)}", path=path, line=line, field=field) from None
    if not math.isfinite(v):
        raise InputError(f"expected a finite number, got {quote(tok)}", path=path, line=line, field=field)
    return v


TEXT_MAX_BYTES = 512 * 2**20
"""Largest text input a reader takes by default (a BAL problem of a million observations is ≈ 60 MB):
an endless stream (``/dev/zero``, a FIFO) ends in a size error, never in "out of memory"."""


def read_limited(path, limit: int = TEXT_MAX_BYTES, what: str = "this input") -> bytes:
    """The bytes of ``path``, at most ``limit`` of them: a larger file, or a stream that does not
    end, is an :class:`InputError` naming the file and the limit; a missing file, a folder or an
    unreadable file too."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            import os
            import stat

            st = os.fstat(f.fileno())
            if stat.S_ISREG(st.st_mode) and st.st_size > limit:
                raise InputError(f"{what} is {st.st_size / 2**20:.1f} MB, more than the {limit / 2**20:.0f} MB "
                                 "a reader takes", path=p)
            data = f.read(limit + 1)
    except FileNotFoundError:
        raise InputError("file not found", path=p) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a file", path=p) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror or e}", path=p) from None
    if len(data) > limit:
        raise InputError(f"{what} is larger than the {limit / 2**20:.0f} MB a reader takes (or a stream that "
                         "does not end)", path=p)
    return data


def read_text_limited(path, limit: int = TEXT_MAX_BYTES, what: str = "this input",
                      encoding: str = "utf-8", field: str | None = None) -> str:
    """:func:`read_limited`, decoded: bytes that are not ``encoding`` are an :class:`InputError`
    naming the line, the byte and ``field`` (the file's kind of content, for readers whose every
    error names a field; never a ``UnicodeDecodeError``)."""
    data = read_limited(path, limit, what)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise InputError(f"not {encoding.upper()} text (byte 0x{data[e.start]:02x}); save the file as "
                         f"{encoding.upper()}", path=path, line=line, field=field) from None
