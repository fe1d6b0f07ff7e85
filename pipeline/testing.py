"""Test helpers for plugin authors (also loaded as a pytest plugin, ``-p baarda``).

Filled in below; see ``docs/plugins.md``.
"""
