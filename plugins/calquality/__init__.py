"""Stage ``calibration-quality``: projection uncertainty and cross-validation (docs/calibration-quality.md)."""
