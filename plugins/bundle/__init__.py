"""The ``bundle`` stage: the self-calibrating bundle block adjustment of a block.

The numerics are the adjustment core, :mod:`baarda.pipeline.adjustment`; this package holds the
stage (options, tables, report, recording).
"""
