"""Transport, processes, recording and the command line (the outer layer; see ``stages/`` and
``gflow_core/`` for the layers below).

Sub-packages, each importing only from those listed before it:

* ``pipeline.io``: files in and out -- frame readers, training sequences, model files, and the
  MCAP format (the recorder's writer and the reader every tool uses).
* ``pipeline.runtime``: running a graph -- graph files, zenoh transport, one stage per process
  (node, launcher), the stage host and join, in-process runs (inline), preflight checks.
* ``pipeline.recording``: tools over recordings -- re-execution (rerun, step), diff, recover,
  results (boxes from a recording), Foxglove export.
* ``pipeline.cli``: the ``gflow`` command (``main``, ``commands/``, ``trackers/``), live tools,
  ``gflow benchmark``, ``gflow view`` and drawing.

``graphs/`` holds the built-in graph files. ``tests/test_layering.py`` enforces the order.
"""
