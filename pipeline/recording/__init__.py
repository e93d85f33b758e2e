"""Tools over recordings: re-execution bit for bit, stepping, diff, recovery, results and export.
Imports :mod:`pipeline.io` and :mod:`pipeline.runtime` from ``pipeline``."""
