"""Geometry shared by every stage: rotations, poses, image coordinates, projections, transformations.

Pure numerics (numpy only).  Conventions: ``docs/conventions.md``.
"""

from .rotations import opk_from_rotation, project, rotation_from_opk, rotation_from_opk_many

__all__ = ["rotation_from_opk", "rotation_from_opk_many", "opk_from_rotation", "project"]
