"""Rendered photos of the simulated test field (stage ``testfield-render``, docs/rendered-pipeline.md)."""
