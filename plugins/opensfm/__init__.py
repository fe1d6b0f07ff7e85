"""OpenSfM / OpenDroneMap reconstruction.json source and writer (docs/metashape-opensfm.md)."""
