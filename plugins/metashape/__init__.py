"""Agisoft Metashape camera XML source and writer (docs/metashape-opensfm.md)."""
