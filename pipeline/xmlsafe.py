"""What the hardened XML parser (defusedxml) refused, said in words.

User XML (DBAT scripts, Metashape camera files) is parsed with defusedxml: no entity expansion, no
external entities or DTDs fetched.  When it refuses a document, :func:`refusal` turns its
exception into an :class:`~baarda.pipeline.errors.InputError` that says what is not allowed, where
(the line of the declaration in the file) and what to do — never the exception's class name.
"""

from __future__ import annotations

import re
from pathlib import Path

from .errors import InputError

__all__ = ["refusal", "refusal_text"]

_DECLARATION = {
    "EntitiesForbidden": rb"<!ENTITY",
    "DTDForbidden": rb"<!DOCTYPE",
    "ExternalReferenceForbidden": rb"(SYSTEM|PUBLIC)\s",
}


def _short(value, limit: int = 40) -> str:
    text = str(value)
    return text if len(text) <= limit else text[:limit] + "…"


def refusal_text(e: BaseException, name: str) -> str:
    """The sentence for defusedxml's exception ``e`` in file ``name``."""
    kind = type(e).__name__
    if kind == "EntitiesForbidden":
        ent = getattr(e, "name", None)
        decl = f"<!ENTITY {_short(ent)} …>" if isinstance(ent, str) and ent else "<!ENTITY …>"
        return (f"entity declarations ({decl}) are not allowed in {name}: baarda does not expand XML entities "
                "(nested ones can grow without end); remove the DTD (<!DOCTYPE …>) from the file")
    if kind == "ExternalReferenceForbidden":
        ref = getattr(e, "sysid", None) or getattr(e, "pubid", None)
        what = f" ({_short(ref)!r})" if ref else ""
        return (f"external references{what} are not allowed in {name}: baarda reads no other file or URL a "
                "document points to; remove the reference (and the DTD that holds it)")
    if kind == "DTDForbidden":
        return (f"a document type declaration (<!DOCTYPE …>) is not allowed in {name}: remove the DTD from the "
                "file")
    if kind == "NotSupportedError":
        return (f"{name} uses an XML feature the hardened parser does not support (a DTD, entities or "
                "external references); remove it")
    return (f"{name} holds an XML construct the hardened parser refuses (entities, a DTD or external "
            "references); remove it")


def _line_of(kind: str, data: bytes | None) -> int | None:
    """The 1-based line of the first declaration of ``kind`` in ``data`` (None when not found)."""
    pattern = _DECLARATION.get(kind)
    if not data or pattern is None:
        return None
    m = re.search(pattern, data)
    return data.count(b"\n", 0, m.start()) + 1 if m else None


def refusal(e: BaseException, path: str | Path, data: bytes | None = None, *, line: int | None = None,
            field: str | None = "xml") -> InputError:
    """An :class:`InputError` for defusedxml's refusal ``e`` of file ``path``: the sentence of
    :func:`refusal_text`, the line of the declaration (``line``, or found in the file's bytes
    ``data``) and ``field``."""
    if data is None:
        try:
            data = Path(path).read_bytes()[:1 << 20]       # the declarations come first: the prolog
        except OSError:
            data = None
    return InputError(refusal_text(e, Path(path).name), path=path,
                      line=line if line is not None else _line_of(type(e).__name__, data), field=field)
