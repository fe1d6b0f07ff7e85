"""COLMAP models in and out: stages ``colmap`` (source) and ``colmap-export``.

The conversion itself (reading, writing, ``pycolmap.Reconstruction`` ↔ Block) is the engine's
:mod:`baarda.pipeline.colmap`, public through :mod:`baarda.pipeline.api`.
"""
