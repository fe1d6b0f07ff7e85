"""Monitoring: the ``epoch`` stage keeps an adjusted epoch, ``congruence`` compares epochs."""
