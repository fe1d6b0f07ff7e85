"""PhotoModeler text exports (``pmexport`` source stage), read as DBAT's ``loadpm`` reads them and set
up as DBAT's demos do.  See ``docs/pmexport.md``."""

from .block import parse_estimate, pm_script, read_control
from .reader import PmExport, read_pmexport

__all__ = ["PmExport", "parse_estimate", "pm_script", "read_control", "read_pmexport"]
