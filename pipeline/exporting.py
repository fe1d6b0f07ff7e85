"""Writers of the block to another program's format: one mechanism for every export stage.

:func:`block_to_export` chooses the block to write (the adjusted one when a bundle of it ran);
:class:`BlockExport` is the stage around a format's writer: the output path by the one rule of
every writer (:meth:`~baarda.pipeline.stage.Context.output_path`), the block chosen, the writer's
``ValueError`` (a block the format cannot hold) as an :class:`InputError`, and the summary with a
headline.  A format's stage says only what differs: ``write`` and ``headline``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from .errors import InputError
from .stage import Context, Stage, StageResult

__all__ = ["BlockExport", "block_to_export"]


def block_to_export(block, bundle=None) -> tuple[object, str]:
    """The block to write: the adjusted block of the run's ``bundle`` (a BundleResult) when it was
    computed from ``block``, ``block`` itself when it is that adjusted block (the bundle hands it on,
    rejected observations switched off), else ``block`` as given.  Returns ``(block, "adjusted" |
    "as given")``."""
    if bundle is None:
        return block, "as given"
    if bundle.block_in is block:
        return bundle.block, "adjusted"
    done = bundle.block
    if done is block or (
            np.array_equal(done.points.XYZ, block.points.XYZ, equal_nan=True)
            and np.array_equal(done.photos.X0, block.photos.X0, equal_nan=True)):
        return block, "adjusted"            # the bundle hands it on (rejected observations switched off)
    return block, "as given"


class BlockExport(Stage):
    """A stage writing the block (adjusted, if a bundle of it ran before) with a format's writer.

    Subclasses set ``summary``, ``Options`` (with a ``path`` option), ``path_is`` (what ``path``
    names, for the message when it is missing: ``"the output file"``), ``writer`` (a
    ``staticmethod``: ``writer(block, out) -> dict`` of counts, ``ValueError`` for a block the format
    cannot hold) and ``headline_format`` (filled with ``path``, ``which`` and the writer's counts);
    a format with options of its own overrides ``write(block, out, options)`` or ``headline``.
    """

    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    path_is: ClassVar[str] = "the output file"
    headline_format: ClassVar[str] = "{path} (block {which})"

    def write(self, block, out, options) -> dict:
        return type(self).writer(block, out)

    def headline(self, info: dict, options: Any, which: str) -> str:
        return self.headline_format.format(**{**info, "path": options.path, "which": which})

    def run(self, inputs, options, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError(f"option 'path' ({self.path_is}) is required", field="path", path=ctx.project_file)
        out = ctx.output_path(options.path, "path")
        block, which = block_to_export(inputs["block"], inputs.get("bundle"))
        try:
            info = self.write(block, out, options)
        except ValueError as e:
            raise InputError(str(e), path=ctx.project_file, field="block") from None
        info["block"] = which
        info["headline"] = self.headline(info, options, which)
        return StageResult(summary=info, report=info["headline"] + ".")
