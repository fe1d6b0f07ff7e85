"""COLMAP models in and out: stages ``colmap`` (source) and ``colmap-export``.

Public to other plugins (the pycolmap cross-check builds its reconstruction with it)::

    from baarda.plugins.colmap import reconstruction_from_block, read_colmap, write_colmap
"""

from .reader import read_colmap
from .writer import reconstruction_from_block, write_colmap

__all__ = ["read_colmap", "reconstruction_from_block", "write_colmap"]
