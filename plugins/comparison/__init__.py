"""The ``comparison`` stage: one summary across all stages of a run, with a check-point plot."""
