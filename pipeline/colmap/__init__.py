"""COLMAP models in and out (an engine module: it uses pycolmap, imported when a model is read
or built).

* :func:`read_colmap` / :func:`read_reconstruction` / :func:`block_from_reconstruction` — a COLMAP
  model folder (binary or text) → :class:`baarda.pipeline.model.Block` (``reader``; the files'
  damage is named by ``precheck``);
* :func:`reconstruction_from_block` / :func:`write_colmap` — a Block → ``pycolmap.Reconstruction``
  → a model folder (``writer``).

The stages ``colmap`` and ``colmap-export`` (``baarda.plugins.colmap``) and the pycolmap
cross-check use them; plugins import them from :mod:`baarda.pipeline.api`.
"""

from .reader import block_from_reconstruction, model_format, read_colmap, read_reconstruction
from .writer import colmap_cameras, reconstruction_from_block, write_colmap

__all__ = ["read_colmap", "read_reconstruction", "block_from_reconstruction", "model_format",
           "reconstruction_from_block", "write_colmap", "colmap_cameras"]
