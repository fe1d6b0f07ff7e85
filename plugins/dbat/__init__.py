"""DBAT / PhotoModeler script projects (``dbat`` source stage): XML, control and check points, marks,
the backward Brown camera (``brown-backward``); PhotoModeler text exports (``pmexport`` source stage, as
DBAT's ``loadpm``).  See ``docs/dbat.md`` and ``docs/pmexport.md``."""

from .pm_block import parse_estimate, pm_script, read_control
from .pm_reader import PmExport, read_pmexport
from .reader import AP_NAMES, DBAT_SIGN, DbatInfo, DbatMarksInfo, dbat_block, dbat_from_baarda, read_dbat

__all__ = ["AP_NAMES", "DBAT_SIGN", "DbatInfo", "DbatMarksInfo", "PmExport", "dbat_block", "dbat_from_baarda",
           "parse_estimate", "pm_script", "read_control", "read_dbat", "read_pmexport"]
