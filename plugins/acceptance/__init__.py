"""Acceptance tests of optical 3-D measuring systems (VDI/VDE 2634 Part 1: length measurement error)."""
