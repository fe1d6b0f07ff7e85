"""Exports of adjusted points (stage export): PLY and CSV in the user's CRS."""
