"""DBAT / PhotoModeler script projects (``dbat`` source stage): XML, control and check points, marks,
the backward Brown camera (``brown-backward``).  See ``docs/dbat.md``."""

from .reader import AP_NAMES, DBAT_SIGN, DbatInfo, DbatMarksInfo, dbat_block, dbat_from_baarda, read_dbat

__all__ = ["AP_NAMES", "DBAT_SIGN", "DbatInfo", "DbatMarksInfo", "dbat_block", "dbat_from_baarda", "read_dbat"]
